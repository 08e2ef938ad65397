//! The support prior: objects stand on the table, so the table under every object point is hidden
//! behind an object in every view.
//!
//! Masks alone fix an object's position only across the cameras' viewing directions. Along them the
//! visual hull stretches by about the object's width over the sine of the angle between the views:
//! 60° apart (the paper's ring) that is a few millimetres, but a stereo rig or a wrist camera moved a
//! few centimetres sees the scene from directions 10–15° apart, and the hull of a 3 cm bottle is then
//! some 15 cm deep. Nothing else in the losses pins the depth of a transparent object (its colours are
//! the refracted background), so mask-fitted surfels end at the front of that hull, centimetres too
//! near.
//!
//! The world frame puts the table at z = 0 (see the README). An object point `(x, y, z)` resting on
//! the table, directly or through other objects, has solid matter under it down to the table, so its
//! footprint `(x, y, ε)` is behind an object in every view that sees it: it projects onto some
//! object's pixel. Hull points in front of the object fail this, since the table under them is seen
//! beside the object's base. The test is the upright-column assumption, which overhangs break (the
//! bowl of a wine glass, the rim of a flaring bowl seen from a low camera), so
//! [`SupportPrior::Auto`] applies it only where it is needed: when the training views' directions
//! span less than [`NARROW_BASELINE_DEG`].

use glam::DVec3;
use trand_core::Camera;

use crate::targets::TrainView;

/// Below this angle between the most different training viewing directions, the views are a narrow
/// baseline and the support prior is applied by [`SupportPrior::Auto`].
pub const NARROW_BASELINE_DEG: f64 = 30.0;
/// The footprint is tested this far above the table, as a fraction of the mean camera distance
/// (1 mm at 50 cm): above the table's own pixels, inside the object's base.
const FOOTPRINT_HEIGHT: f64 = 0.002;

/// Whether the visual hull is restricted to points whose footprint on the table is hidden behind an
/// object in every view (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum SupportPrior {
    /// Applied when the training views span less than [`NARROW_BASELINE_DEG`].
    Auto,
    On,
    Off,
}

/// The largest angle in degrees between two cameras' directions towards `target`.
pub fn view_spread_deg(cameras: &[Camera], target: DVec3) -> f64 {
    let dirs: Vec<DVec3> = cameras
        .iter()
        .filter_map(|c| (target - c.center()).try_normalize())
        .collect();
    let mut widest: f64 = 0.0;
    for (i, a) in dirs.iter().enumerate() {
        for b in &dirs[i + 1..] {
            widest = widest.max(a.dot(*b).clamp(-1.0, 1.0).acos().to_degrees());
        }
    }
    widest
}

/// The footprint test of [`SupportPrior`] for the views, or `None` when the prior is not applied.
pub struct Support<'a> {
    views: &'a [TrainView],
    height: f64,
}

impl<'a> Support<'a> {
    /// The test for `views` whose objects lie around `target`, if `prior` applies to them.
    pub fn new(views: &'a [TrainView], prior: SupportPrior, target: DVec3) -> Option<Self> {
        let cams: Vec<Camera> = views.iter().map(|v| v.camera).collect();
        let applies = match prior {
            SupportPrior::On => true,
            SupportPrior::Off => false,
            SupportPrior::Auto => view_spread_deg(&cams, target) < NARROW_BASELINE_DEG,
        };
        let dist = cams
            .iter()
            .map(|c| (c.center() - target).length())
            .sum::<f64>()
            / cams.len().max(1) as f64;
        applies.then_some(Self {
            views,
            height: FOOTPRINT_HEIGHT * dist,
        })
    }

    /// Whether the table under `p` projects onto an object pixel in every view that sees it.
    pub fn holds(&self, p: DVec3) -> bool {
        let q = DVec3::new(p.x, p.y, self.height);
        self.views
            .iter()
            .all(|v| v.pixel_of(q).is_none_or(|o| v.given_ids[o] != 0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use trand_core::Intrinsics;

    fn cam(azimuth_deg: f64) -> Camera {
        let a = azimuth_deg.to_radians();
        Camera::look_at(
            Intrinsics::centered(200.0, 64, 48),
            DVec3::new(a.cos(), a.sin(), 0.5),
            DVec3::ZERO,
            DVec3::Z,
        )
    }

    #[test]
    fn spread_is_the_widest_angle_between_viewing_directions() {
        let ring: Vec<Camera> = (0..6).map(|i| cam(60.0 * i as f64)).collect();
        assert!(view_spread_deg(&ring, DVec3::ZERO) > 120.0);
        let rig = [cam(0.0), cam(6.0), cam(12.0)];
        let s = view_spread_deg(&rig, DVec3::ZERO);
        assert!((9.0..12.0).contains(&s), "{s}");
    }
}
