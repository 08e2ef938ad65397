//! How well one parabola fits a sweep's scores: the test that tells a plain table's broad hump
//! from a comb of alias peaks or a curve with no top ([`crate::table_height`], module docs).
//!
//! A least-squares fit of `s ≈ a x² + b x + c` over the sweep (heights centred on its middle for
//! conditioning), solved from its 3×3 normal equations with `glam`'s `DMat3`.

use glam::{DMat3, DVec3};

/// Share of the variance of `scores` (at `heights`) that the least-squares parabola explains, or 0
/// when that parabola opens upwards or has its vertex outside `heights`' range. A single hump scores
/// near 1; a comb of alias peaks, or a curve with no top, near 0.
pub fn hump(heights: &[f64], scores: &[f64]) -> f64 {
    let (Some(&first), Some(&last)) = (heights.first(), heights.last()) else {
        return 0.0;
    };
    if scores.len() < 3 {
        return 0.0;
    }
    // Normal equations of s ≈ a x² + b x + c, with x = h − mid centred on the sweep for conditioning.
    let mid = 0.5 * (first + last);
    let basis = |h: f64| {
        let x = h - mid;
        DVec3::new(x * x, x, 1.0)
    };
    let (mut m, mut r) = (DMat3::ZERO, DVec3::ZERO);
    for (&h, &s) in heights.iter().zip(scores) {
        let f = basis(h);
        m += DMat3::from_cols(f * f.x, f * f.y, f * f.z);
        r += f * s;
    }
    if m.determinant().abs() < 1e-300 {
        return 0.0;
    }
    let coef = m.inverse() * r;
    let vertex = mid - coef.y / (2.0 * coef.x);
    if coef.x >= 0.0 || !(first.min(last)..=first.max(last)).contains(&vertex) {
        return 0.0;
    }
    let mean = scores.iter().sum::<f64>() / scores.len() as f64;
    let total: f64 = scores.iter().map(|s| (s - mean).powi(2)).sum();
    let residual: f64 = heights
        .iter()
        .zip(scores)
        .map(|(&h, &s)| (s - coef.dot(basis(h))).powi(2))
        .sum();
    if total <= 0.0 {
        return 0.0;
    }
    (1.0 - residual / total).max(0.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::table_height::{MIN_HUMP, STEP_M};

    /// Scores measured on public seq_109 (plain table, refined cameras 3 mm low) and on a `trand
    /// synth` wood table whose rings alias (perturbed poses), every 0.5 mm from −10 to +10 mm.
    const PLAIN_SEQ_109: [f64; 41] = [
        0.865, 0.867, 0.868, 0.870, 0.872, 0.874, 0.874, 0.875, 0.877, 0.878, 0.878, 0.879, 0.880,
        0.879, 0.879, 0.878, 0.878, 0.878, 0.878, 0.877, 0.876, 0.876, 0.875, 0.873, 0.871, 0.869,
        0.868, 0.866, 0.865, 0.863, 0.861, 0.858, 0.856, 0.854, 0.851, 0.849, 0.848, 0.845, 0.842,
        0.840, 0.837,
    ];
    const ALIASING_RINGS: [f64; 41] = [
        0.410, 0.439, 0.443, 0.433, 0.418, 0.403, 0.389, 0.376, 0.367, 0.366, 0.374, 0.383, 0.388,
        0.394, 0.405, 0.410, 0.402, 0.380, 0.366, 0.375, 0.402, 0.425, 0.428, 0.416, 0.403, 0.398,
        0.391, 0.377, 0.364, 0.367, 0.388, 0.412, 0.423, 0.419, 0.410, 0.402, 0.392, 0.381, 0.377,
        0.388, 0.405,
    ];

    fn sweep_heights() -> Vec<f64> {
        (-20..=20).map(|k| k as f64 * STEP_M).collect()
    }

    #[test]
    fn one_smooth_hump_is_broad_and_a_comb_of_aliases_is_not() {
        let h = sweep_heights();
        assert!(
            hump(&h, &PLAIN_SEQ_109) >= MIN_HUMP,
            "{}",
            hump(&h, &PLAIN_SEQ_109)
        );
        assert!(
            hump(&h, &ALIASING_RINGS) < 0.5,
            "{}",
            hump(&h, &ALIASING_RINGS)
        );
    }

    #[test]
    fn a_curve_without_a_top_inside_the_sweep_is_no_hump() {
        let h = sweep_heights();
        let flat = vec![0.9; h.len()];
        let rising: Vec<f64> = h.iter().map(|x| 0.5 + 10.0 * x).collect();
        let valley: Vec<f64> = h.iter().map(|x| 0.5 + 1e3 * x * x).collect();
        let top_outside: Vec<f64> = h.iter().map(|x| 0.5 - 1e3 * (x - 0.02).powi(2)).collect();
        for (name, s) in [
            ("flat", flat),
            ("rising", rising),
            ("valley", valley),
            ("top outside", top_outside),
        ] {
            assert_eq!(hump(&h, &s), 0.0, "{name}");
        }
        let top_inside: Vec<f64> = h.iter().map(|x| 0.5 - 1e3 * (x - 0.004).powi(2)).collect();
        assert!(hump(&h, &top_inside) > 0.999);
    }
}
