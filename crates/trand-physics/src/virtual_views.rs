//! Virtual cameras for depth fusion (TRAN-D §5.3): the caller renders depth from these views of
//! the remaining objects and fuses them with [`crate::tsdf`].
//!
//! The authors fuse the t=1 test poses plus one camera under the table looking up (+z), which
//! closes the objects' bottoms; [`ring_views`] gives the same kind of coverage without data
//! poses: rings of cameras at given elevations around a centre, all looking at it, plus the
//! camera from below.

use glam::{DMat3, DVec3};
use trand_core::camera::focus_point;
use trand_core::{Camera, Intrinsics};

/// Cameras on rings around `center` (world z up): for each elevation (radians above the
/// horizontal plane through `center`), `n_azimuth` cameras at distance `radius`, evenly spaced
/// in azimuth starting at +x, looking at `center` with world +z as image up; then one camera at
/// `center − radius·ẑ` looking up along +z ([`below_view`]).
pub fn ring_views(
    center: DVec3,
    radius: f64,
    elevations: &[f64],
    n_azimuth: usize,
    intrinsics: Intrinsics,
) -> Vec<Camera> {
    let mut cams = Vec::with_capacity(elevations.len() * n_azimuth + 1);
    for &el in elevations {
        for a in 0..n_azimuth {
            let az = std::f64::consts::TAU * a as f64 / n_azimuth as f64;
            let dir = DVec3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin());
            cams.push(Camera::look_at(
                intrinsics,
                center + radius * dir,
                center,
                DVec3::Z,
            ));
        }
    }
    cams.push(below_view(center, radius, intrinsics));
    cams
}

/// The camera under the table: at `center − radius·ẑ`, optical axis world +z. With the OpenCV
/// frame (x right, y down, z forward) and image x = world x, the camera frame is the world
/// frame: `R_w2c = I` (a proper rotation; the authors' synthetic pose, a reflection-looking
/// `diag(1, −1, 1)` in their mixed OpenGL/OpenCV bookkeeping, also sits at z = −1 looking up).
pub fn below_view(center: DVec3, radius: f64, intrinsics: Intrinsics) -> Camera {
    let eye = center - DVec3::Z * radius;
    let r_w2c = DMat3::IDENTITY;
    Camera::from_glam(intrinsics, r_w2c, -(r_w2c * eye))
}

/// The scene radius of a camera set: the mean distance of the camera centres to [`focus_point`]
/// (`None` when there is no focus point). The fusion depth range (2·radius) and voxel size
/// (2·radius / 256) follow from it ([`crate::TsdfSettings::tran_d`]); the update takes it from
/// the t = 0 training cameras (`trand_pipeline::update::SceneScale`).
///
/// TRAN-D takes the smallest distance instead, over the cameras it fuses (its test views). For a
/// rig at one distance, a ring, the two agree; trand fuses virtual views placed around the surfels
/// rather than data cameras, and the mean of the training cameras' distances depends on every one
/// of them rather than on the nearest alone.
pub fn scene_radius(cameras: &[Camera]) -> Option<f64> {
    let f = focus_point(cameras)?;
    let total = cameras
        .iter()
        .map(|c| (c.center() - f).length())
        .sum::<f64>();
    Some(total / cameras.len() as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn focus_point_of_a_ring_is_its_center_and_radius_its_distance() {
        let c = DVec3::new(0.2, 0.1, 0.03);
        let cams = ring_views(c, 0.7, &[0.4, 0.8], 6, Intrinsics::centered(300.0, 64, 64));
        assert!((focus_point(&cams).unwrap() - c).length() < 1e-9);
        assert!((scene_radius(&cams).unwrap() - 0.7).abs() < 1e-9);
        assert_eq!(scene_radius(&[]), None);
        // One camera: its axis meets the table, the focus point's fallback.
        let one = focus_point(&cams[..1]).unwrap();
        assert!(
            one.z.abs() < 1e-9 && (one - cams[0].center()).cross(cams[0].forward()).length() < 1e-9
        );
    }

    #[test]
    fn scene_radius_is_the_mean_camera_distance_not_the_nearest() {
        let c = DVec3::new(0.1, 0.0, 0.02);
        let k = Intrinsics::centered(300.0, 64, 64);
        // Two rings of 2 × 6 + 1 views each, at 0.5 m and 0.9 m: the mean distance is 0.7 m.
        let mut cams = ring_views(c, 0.5, &[0.3, 0.9], 6, k);
        cams.extend(ring_views(c, 0.9, &[0.3, 0.9], 6, k));
        assert!((focus_point(&cams).unwrap() - c).length() < 1e-9);
        assert!((scene_radius(&cams).unwrap() - 0.7).abs() < 1e-9);
    }

    #[test]
    fn every_ring_view_sees_the_center_on_its_principal_point() {
        let k = Intrinsics::centered(300.0, 160, 120);
        let c = DVec3::new(0.1, -0.2, 0.05);
        let cams = ring_views(c, 0.6, &[0.3, 0.9], 8, k);
        assert_eq!(cams.len(), 17);
        for cam in &cams {
            cam.validate().unwrap();
            let (x, y, z) = cam.project(c).unwrap();
            assert!((x - k.cx).abs() < 1e-9 && (y - k.cy).abs() < 1e-9 && (z - 0.6).abs() < 1e-9);
        }
    }

    #[test]
    fn below_view_looks_up() {
        let cam = below_view(DVec3::ZERO, 1.0, Intrinsics::centered(300.0, 64, 64));
        cam.validate().unwrap();
        assert!((cam.center() - DVec3::new(0.0, 0.0, -1.0)).length() < 1e-12);
        assert!((cam.forward() - DVec3::Z).length() < 1e-12);
        assert!((cam.rotation().determinant() - 1.0).abs() < 1e-12);
    }
}
