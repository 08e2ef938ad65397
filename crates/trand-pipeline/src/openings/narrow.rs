//! The axis of an object seen from one side (a narrow baseline).
//!
//! From directions a few degrees apart the masks fix an object only across the viewing direction;
//! with the support prior (see [`crate::support`]) its hull is exact at its front but reaches
//! behind it by `(H − z) cot e` at height `z` (the table the object hides), and above its top by a
//! lens that shrinks from the back. The centres of such slices drift backwards with depth, so the
//! ring's axis (the centre of the foot, [`super::Profile::of`]) reads every object as leaning.
//!
//! Here each slice is read from its front instead: for a round cross-section the front-most
//! voxels lie on the centre's line of sight, and the centre stands one radius behind them, the
//! radius being the half-width across the view on the side nearer that line (a handle widens one
//! side only). An upright object's slice centres stand on one vertical line; a tilted or lying
//! one's front drifts with height.

use glam::DVec2;

/// Voxels within this many voxel edges of a slice's front are its front-most ones.
const FRONT_BAND_VOXELS: f64 = 1.5;

/// The centre of one slice (horizontal centres of voxels of edge `voxel`) seen along `toward`
/// (horizontal, unit), or `None` for an empty slice.
fn slice_centre(pts: &[DVec2], toward: DVec2, voxel: f64) -> Option<DVec2> {
    let across = toward.perp();
    let depth = |p: &DVec2| p.dot(toward);
    let front = pts.iter().map(depth).fold(f64::INFINITY, f64::min);
    if !front.is_finite() {
        return None;
    }
    let mut band: Vec<f64> = pts
        .iter()
        .filter(|p| depth(p) <= front + FRONT_BAND_VOXELS * voxel)
        .map(|p| p.dot(across))
        .collect();
    band.sort_by(f64::total_cmp);
    let line = band[band.len() / 2];
    let (lo, hi) = pts
        .iter()
        .map(|p| p.dot(across))
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), u| {
            (lo.min(u), hi.max(u))
        });
    let radius = (hi - line).min(line - lo).max(0.0) + 0.5 * voxel;
    Some(across * line + toward * (front - 0.5 * voxel + radius))
}

/// The centres of the non-empty `slices` (voxels of edge `voxel`) seen along `toward`.
pub(super) fn slice_centres(slices: &[Vec<DVec2>], toward: DVec2, voxel: f64) -> Vec<DVec2> {
    slices
        .iter()
        .filter_map(|s| slice_centre(s, toward, voxel))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    const VOXEL_M: f64 = 0.002;

    /// Voxel centres of a disc of radius `r` about `c`, swept `behind` m along `toward`.
    fn swept_disc(c: DVec2, r: f64, behind: f64, toward: DVec2) -> Vec<DVec2> {
        let n = ((r + behind) / VOXEL_M) as i32 + 2;
        let mut out = Vec::new();
        for i in -n..=n {
            for j in -n..=n {
                let p = DVec2::new(i as f64, j as f64) * VOXEL_M;
                let d = p - c;
                let t = d.dot(toward).clamp(0.0, behind);
                if (d - toward * t).length() <= r {
                    out.push(p);
                }
            }
        }
        out
    }

    #[test]
    fn a_disc_with_the_table_it_hides_is_centred_at_the_disc() {
        let toward = DVec2::new(0.6, 0.8);
        let c = DVec2::new(0.01, -0.02);
        let got = slice_centre(&swept_disc(c, 0.03, 0.08, toward), toward, VOXEL_M).unwrap();
        assert!((got - c).length() < 1.5 * VOXEL_M, "{got:?} against {c:?}");
    }

    #[test]
    fn a_handle_on_one_side_does_not_move_the_centre() {
        let toward = DVec2::new(1.0, 0.0);
        let c = DVec2::ZERO;
        let mut pts = swept_disc(c, 0.03, 0.05, toward);
        // A handle 2.5 cm out to one side, 1 cm thick, swept back with the body.
        pts.extend(
            swept_disc(DVec2::new(0.0, 0.045), 0.006, 0.05, toward)
                .into_iter()
                .filter(|p| p.y > 0.03),
        );
        let got = slice_centre(&pts, toward, VOXEL_M).unwrap();
        assert!((got - c).length() < 1.5 * VOXEL_M, "{got:?}");
    }
}
