//! The camera rig of a sequence (same as the reference Blender data).
//!
//! * `train_0` frame 0: bird's-eye view straight down from [`BIRDSEYE_HEIGHT_M`] above the
//!   workspace centre, image x along world x (so `R_w2c = diag(1, −1, −1)`).
//! * `train_0` frames 1..=12: a ring at 30° azimuth steps (random start azimuth), elevation
//!   [`RING_ELEVATION_DEG`], distance [`RING_DISTANCE_M`], looking at the workspace centre.
//! * test views: azimuth uniform, elevation U(20°, 70°), distance U(0.45, 0.8) m, looking at the
//!   centre jittered by U(±4 cm, ±4 cm, ±2 cm).
//! * `train_1` frame 0 is the same pose as `train_0` frame 0.
//!
//! The reference sequences draw the bird's-eye height, ring elevation and ring distance per
//! sequence (0.69–0.78 m, 38–45°, 0.54–0.64 m); [`Rig::Fixed`] uses one value of each,
//! [`Rig::Varied`] draws them from [`VARIED_BIRDSEYE_HEIGHT_M`], [`VARIED_RING_ELEVATION_DEG`] and
//! [`VARIED_RING_DISTANCE_M`], ranges that span the reference values.
//!
//! [`Rig::Narrow`] is a robot's capture instead: a stereo rig or a wrist camera moved a few
//! centimetres. Its axis has a random azimuth and the varied ring's elevation and distance; frame 0
//! (and `train_1` frame 0) looks along the axis, frames 1..=12 lie on a circle of
//! [`NARROW_TRAIN_RADIUS_DEG`] around it at 30° steps (so any six odd frames span 12°, as the KeyPose
//! stereo captures do), and the test views are drawn within [`NARROW_TEST_RADIUS_DEG`] of the axis:
//! the depth a robot wants is at its own cameras, not behind the objects.
//!
//! Intrinsics: `f = 600 · W / 640` (the reference's 600 px at 640 px width), centred principal
//! point `c = ((W − 1)/2, (H − 1)/2)` (integer pixel centres).

use glam::DVec3;
use rand::RngExt;
use serde::Serialize;
use trand_core::camera::{Camera, Intrinsics};

pub const BIRDSEYE_HEIGHT_M: f64 = 0.75;
pub const RING_VIEWS: u32 = 12;
pub const RING_ELEVATION_DEG: f64 = 38.0;
pub const RING_DISTANCE_M: f64 = 0.54;
pub const TEST_ELEVATION_DEG: (f64, f64) = (20.0, 70.0);
pub const TEST_DISTANCE_M: (f64, f64) = (0.45, 0.8);
pub const TEST_TARGET_JITTER_M: [f64; 3] = [0.04, 0.04, 0.02];
/// Focal length in pixels at 640 px image width.
pub const FOCAL_AT_640: f64 = 600.0;
/// Bird's-eye height range of [`Rig::Varied`] (m).
pub const VARIED_BIRDSEYE_HEIGHT_M: (f64, f64) = (0.68, 0.78);
/// Ring elevation range of [`Rig::Varied`] (degrees).
pub const VARIED_RING_ELEVATION_DEG: (f64, f64) = (37.0, 46.0);
/// Ring distance range of [`Rig::Varied`] (m).
pub const VARIED_RING_DISTANCE_M: (f64, f64) = (0.53, 0.65);

/// Angular radius of [`Rig::Narrow`]'s circle of training views (degrees).
pub const NARROW_TRAIN_RADIUS_DEG: f64 = 6.0;
/// Angular radius of the cone [`Rig::Narrow`]'s test views are drawn in (degrees).
pub const NARROW_TEST_RADIUS_DEG: f64 = 10.0;

/// How the training rig is laid out and its height, elevation and distance chosen.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Rig {
    /// [`BIRDSEYE_HEIGHT_M`], [`RING_ELEVATION_DEG`], [`RING_DISTANCE_M`] for every sequence.
    Fixed,
    /// Drawn per sequence from the `VARIED_*` ranges, as the reference sequences are.
    Varied,
    /// Every view within a few degrees of one axis (see the module docs).
    Narrow,
}

/// Intrinsics for a `width × height` image (focal scaled with width).
pub fn intrinsics(width: u32, height: u32) -> Intrinsics {
    Intrinsics::centered(FOCAL_AT_640 * width as f64 / 640.0, width, height)
}

/// The ring parameters as written to `sequence.json` (`cameras.train_ring`).
#[derive(Clone, Copy, Debug, Serialize)]
pub struct RingInfo {
    pub birdseye_height_m: f64,
    pub ring_azimuth0_deg: f64,
    pub ring_elevation_deg: f64,
    pub ring_distance_m: f64,
    /// [`Rig::Narrow`]: the angular radius of the training circle around the axis whose azimuth,
    /// elevation and distance the `ring_*` fields give (frame 0 then looks along that axis and
    /// `birdseye_height_m` is unused).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub narrow_radius_deg: Option<f64>,
}

/// Camera on a sphere around `target`: azimuth from +x towards +y, elevation above the table.
pub fn orbit(
    k: Intrinsics,
    target: DVec3,
    azimuth_deg: f64,
    elevation_deg: f64,
    distance: f64,
) -> Camera {
    let (az, el) = (azimuth_deg.to_radians(), elevation_deg.to_radians());
    let eye = target + distance * DVec3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin());
    Camera::look_at(k, eye, target, DVec3::Z)
}

/// The ring's parameters: the start azimuth is always drawn, the rest as `rig` says.
fn ring_info(rig: Rig, rng: &mut impl rand::Rng) -> RingInfo {
    let ring_azimuth0_deg: f64 = rng.random_range(0.0..360.0);
    match rig {
        Rig::Fixed => RingInfo {
            birdseye_height_m: BIRDSEYE_HEIGHT_M,
            ring_azimuth0_deg,
            ring_elevation_deg: RING_ELEVATION_DEG,
            ring_distance_m: RING_DISTANCE_M,
            narrow_radius_deg: None,
        },
        Rig::Varied | Rig::Narrow => {
            let (h, e, d) = (
                VARIED_BIRDSEYE_HEIGHT_M,
                VARIED_RING_ELEVATION_DEG,
                VARIED_RING_DISTANCE_M,
            );
            RingInfo {
                birdseye_height_m: rng.random_range(h.0..h.1),
                ring_azimuth0_deg,
                ring_elevation_deg: rng.random_range(e.0..e.1),
                ring_distance_m: rng.random_range(d.0..d.1),
                narrow_radius_deg: (rig == Rig::Narrow).then_some(NARROW_TRAIN_RADIUS_DEG),
            }
        }
    }
}

/// A camera `radius_deg` away from the axis at (`azimuth_deg`, `elevation_deg`), in direction `phi`
/// around it (azimuth offsets are scaled by `1 / cos(elevation)` so that both offsets are angles).
fn off_axis(
    k: Intrinsics,
    target: DVec3,
    (azimuth_deg, elevation_deg): (f64, f64),
    radius_deg: f64,
    phi: f64,
    distance: f64,
) -> Camera {
    let el = elevation_deg + radius_deg * phi.sin();
    let az = azimuth_deg + radius_deg * phi.cos() / elevation_deg.to_radians().cos();
    orbit(k, target, az, el, distance)
}

/// Bird's-eye view plus the 12-view ring, or for [`Rig::Narrow`] the axis view plus the circle.
pub fn train_views(
    k: Intrinsics,
    centre: DVec3,
    rig: Rig,
    rng: &mut impl rand::Rng,
) -> (Vec<Camera>, RingInfo) {
    let info = ring_info(rig, rng);
    if let Some(radius) = info.narrow_radius_deg {
        let axis = (info.ring_azimuth0_deg, info.ring_elevation_deg);
        let d = info.ring_distance_m;
        let mut cams = vec![orbit(k, centre, axis.0, axis.1, d)];
        cams.extend((0..RING_VIEWS).map(|i| {
            let phi = (30.0 * i as f64).to_radians();
            off_axis(k, centre, axis, radius, phi, d)
        }));
        return (cams, info);
    }
    let top = Camera::look_at(
        k,
        centre + DVec3::new(0.0, 0.0, info.birdseye_height_m),
        centre,
        DVec3::Y,
    );
    let mut cams = vec![top];
    cams.extend((0..RING_VIEWS).map(|i| {
        orbit(
            k,
            centre,
            info.ring_azimuth0_deg + 30.0 * i as f64,
            info.ring_elevation_deg,
            info.ring_distance_m,
        )
    }));
    (cams, info)
}

/// `n` random views on the upper hemisphere or, for a narrow rig (`ring.narrow_radius_deg`), within
/// [`NARROW_TEST_RADIUS_DEG`] of its axis (uniform over that disc of directions).
pub fn test_views(
    k: Intrinsics,
    centre: DVec3,
    n: u32,
    ring: &RingInfo,
    rng: &mut impl rand::Rng,
) -> Vec<Camera> {
    (0..n)
        .map(|_| {
            let (az, el) = match ring.narrow_radius_deg {
                None => (
                    rng.random_range(0.0..360.0),
                    rng.random_range(TEST_ELEVATION_DEG.0..TEST_ELEVATION_DEG.1),
                ),
                Some(_) => (ring.ring_azimuth0_deg, ring.ring_elevation_deg),
            };
            let (radius, phi) = match ring.narrow_radius_deg {
                None => (0.0, 0.0),
                Some(_) => (
                    NARROW_TEST_RADIUS_DEG * rng.random_range(0.0f64..1.0).sqrt(),
                    rng.random_range(0.0..std::f64::consts::TAU),
                ),
            };
            let dist = rng.random_range(TEST_DISTANCE_M.0..TEST_DISTANCE_M.1);
            let j = TEST_TARGET_JITTER_M;
            let target = centre
                + DVec3::new(
                    rng.random_range(-j[0]..j[0]),
                    rng.random_range(-j[1]..j[1]),
                    rng.random_range(-j[2]..j[2]),
                );
            off_axis(k, target, (az, el), radius, phi, dist)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn birdseye_view_looks_straight_down_with_x_along_world_x() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(1);
        let (cams, _) = train_views(
            intrinsics(640, 480),
            DVec3::new(0.01, 0.02, 0.03),
            Rig::Fixed,
            &mut rng,
        );
        let r = cams[0].rotation();
        let want = glam::DMat3::from_diagonal(DVec3::new(1.0, -1.0, -1.0));
        assert!(
            (r - want).to_cols_array().iter().all(|v| v.abs() < 1e-12),
            "{r:?}"
        );
        assert_eq!(cams.len(), 13);
        assert!(
            (cams[0].intrinsics.cx - 319.5).abs() < 1e-12
                && (cams[0].intrinsics.fx - 600.0).abs() < 1e-12
        );
    }

    #[test]
    fn a_varied_rig_draws_its_height_elevation_and_distance_within_the_reference_ranges() {
        let centre = DVec3::new(0.0, 0.0, 0.03);
        for seed in 0..20 {
            let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
            let (cams, info) = train_views(intrinsics(320, 240), centre, Rig::Varied, &mut rng);
            let within = |v: f64, (lo, hi): (f64, f64)| (lo..hi).contains(&v);
            assert!(within(info.birdseye_height_m, VARIED_BIRDSEYE_HEIGHT_M));
            assert!(within(info.ring_elevation_deg, VARIED_RING_ELEVATION_DEG));
            assert!(within(info.ring_distance_m, VARIED_RING_DISTANCE_M));
            assert!((cams[0].center().z - centre.z - info.birdseye_height_m).abs() < 1e-9);
            for c in &cams[1..] {
                let v = c.center() - centre;
                assert!((v.length() - info.ring_distance_m).abs() < 1e-9);
                let el = (v.z / v.length()).asin().to_degrees();
                assert!((el - info.ring_elevation_deg).abs() < 1e-9);
            }
        }
    }

    /// The angle in degrees between the directions from `centre` to two cameras.
    fn angle_deg(a: &Camera, b: &Camera, centre: DVec3) -> f64 {
        let (u, v) = (a.center() - centre, b.center() - centre);
        (u.dot(v) / (u.length() * v.length()))
            .clamp(-1.0, 1.0)
            .acos()
            .to_degrees()
    }

    #[test]
    fn a_narrow_rig_keeps_every_view_within_its_cone() {
        let centre = DVec3::new(0.02, -0.01, 0.03);
        for seed in 0..10 {
            let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
            let (cams, info) = train_views(intrinsics(320, 240), centre, Rig::Narrow, &mut rng);
            assert_eq!(cams.len(), 13);
            assert_eq!(info.narrow_radius_deg, Some(NARROW_TRAIN_RADIUS_DEG));
            for c in &cams[1..] {
                let off = angle_deg(c, &cams[0], centre);
                assert!((off - NARROW_TRAIN_RADIUS_DEG).abs() < 0.3, "{off}");
                assert!(((c.center() - centre).length() - info.ring_distance_m).abs() < 1e-9);
            }
            // Opposite frames of the six odd ones are the circle's diameter apart.
            let spread = angle_deg(&cams[1], &cams[7], centre);
            assert!(
                (spread - 2.0 * NARROW_TRAIN_RADIUS_DEG).abs() < 0.5,
                "{spread}"
            );
            for t in test_views(intrinsics(320, 240), centre, 20, &info, &mut rng) {
                // The test target is jittered a few cm, which turns the direction by < 4°.
                assert!(angle_deg(&t, &cams[0], centre) < NARROW_TEST_RADIUS_DEG + 4.0);
            }
        }
    }

    #[test]
    fn ring_views_sit_at_the_ring_elevation_and_distance() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(2);
        let centre = DVec3::new(0.0, 0.0, 0.03);
        let (cams, _) = train_views(intrinsics(320, 240), centre, Rig::Fixed, &mut rng);
        for c in &cams[1..] {
            let v = c.center() - centre;
            assert!((v.length() - RING_DISTANCE_M).abs() < 1e-9);
            assert!(((v.z / v.length()).asin().to_degrees() - RING_ELEVATION_DEG).abs() < 1e-9);
        }
    }
}
