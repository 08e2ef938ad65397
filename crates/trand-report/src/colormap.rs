//! Colour maps of the report: one perceptual map for every unsigned scalar image (depth, |error|), a
//! diverging map for the signed error, and a categorical palette for object ids.
//!
//! The scalar map is viridis, given by nine samples at t = 0, 1/8, …, 1; the diverging map is
//! blue–white–red, given by three samples at t = −1, 0, 1 ([`diverging`]). Both are interpolated
//! linearly in sRGB, and colour bars use the same samples as SVG gradient stops (which also
//! interpolate in sRGB), so images and bars agree.

/// Viridis sampled at t = k/8, k = 0..=8 (sRGB).
pub const VIRIDIS: [[u8; 3]; 9] = [
    [68, 1, 84],
    [72, 40, 120],
    [62, 73, 137],
    [49, 104, 142],
    [38, 130, 142],
    [31, 158, 137],
    [53, 183, 121],
    [110, 206, 88],
    [253, 231, 37],
];

/// Pixels without a value (no depth, not evaluated).
pub const NO_VALUE: [u8; 3] = [40, 40, 40];

/// The colour of `t` in [0, 1] (clamped; NaN gives [`NO_VALUE`]).
pub fn viridis(t: f64) -> [u8; 3] {
    if t.is_nan() {
        return NO_VALUE;
    }
    let x = t.clamp(0.0, 1.0) * (VIRIDIS.len() - 1) as f64;
    let i = (x.floor() as usize).min(VIRIDIS.len() - 2);
    let f = x - i as f64;
    let (a, b) = (VIRIDIS[i], VIRIDIS[i + 1]);
    std::array::from_fn(|c| (a[c] as f64 + f * (b[c] as f64 - a[c] as f64)).round() as u8)
}

/// The signed-error map, sampled at t = −1, 0, 1: blue (prediction nearer than the truth: a lid
/// over an opening, a floater), white (exact), red (farther: a hole, a surface seen through).
pub const DIVERGING: [[u8; 3]; 3] = [[33, 102, 172], [247, 247, 247], [178, 24, 43]];

/// The colour of `t` in [−1, 1] on [`DIVERGING`] (clamped; NaN gives [`NO_VALUE`]).
pub fn diverging(t: f64) -> [u8; 3] {
    if t.is_nan() {
        return NO_VALUE;
    }
    let x = (t.clamp(-1.0, 1.0) + 1.0) * 0.5 * (DIVERGING.len() - 1) as f64;
    let i = (x.floor() as usize).min(DIVERGING.len() - 2);
    let f = x - i as f64;
    let (a, b) = (DIVERGING[i], DIVERGING[i + 1]);
    std::array::from_fn(|c| (a[c] as f64 + f * (b[c] as f64 - a[c] as f64)).round() as u8)
}

/// `#rrggbb`.
pub fn hex(c: [u8; 3]) -> String {
    format!("#{:02x}{:02x}{:02x}", c[0], c[1], c[2])
}

/// Distinct colours for object ids 1, 2, … (cycled); id 0 (background) is black.
const PALETTE: [[u8; 3]; 10] = [
    [230, 25, 75],
    [60, 180, 75],
    [255, 225, 25],
    [0, 130, 200],
    [245, 130, 48],
    [145, 30, 180],
    [70, 240, 240],
    [240, 50, 230],
    [210, 245, 60],
    [250, 190, 212],
];

/// Colour of object `id`.
pub fn object_colour(id: u16) -> [u8; 3] {
    if id == 0 {
        [0, 0, 0]
    } else {
        PALETTE[(id as usize - 1) % PALETTE.len()]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn viridis_hits_its_samples_and_clamps() {
        assert_eq!(viridis(0.0), VIRIDIS[0]);
        assert_eq!(viridis(0.5), VIRIDIS[4]);
        assert_eq!(viridis(1.0), VIRIDIS[8]);
        assert_eq!(viridis(7.0), VIRIDIS[8]);
        assert_eq!(viridis(-1.0), VIRIDIS[0]);
        assert_eq!(viridis(f64::NAN), NO_VALUE);
        assert_eq!(hex(VIRIDIS[0]), "#440154");
        assert_eq!(object_colour(11), object_colour(1));
    }

    #[test]
    fn diverging_map_is_blue_below_zero_white_at_zero_red_above() {
        let blue = |c: [u8; 3]| c[2] > c[0] + 60;
        let red = |c: [u8; 3]| c[0] > c[2] + 60;
        assert!(blue(diverging(-1.0)) && blue(diverging(-0.5)), "too near");
        assert!(red(diverging(1.0)) && red(diverging(0.5)), "too far");
        assert_eq!(diverging(0.0), DIVERGING[1]);
        assert!(DIVERGING[1].iter().all(|&v| v > 240), "zero is white");
        // Saturates beyond ±1; NaN is no value.
        assert_eq!(diverging(-7.0), diverging(-1.0));
        assert_eq!(diverging(7.0), diverging(1.0));
        assert_eq!(diverging(f64::NAN), NO_VALUE);
        // Halfway to −1: the midpoint of white and blue.
        let mid: [u8; 3] = std::array::from_fn(|c| {
            ((DIVERGING[0][c] as f64 + DIVERGING[1][c] as f64) / 2.0).round() as u8
        });
        assert_eq!(diverging(-0.5), mid);
    }
}
