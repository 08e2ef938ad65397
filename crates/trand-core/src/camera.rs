//! Pinhole camera in the OpenCV convention.
//!
//! # Conventions (the one place they are stated)
//! * Camera frame: x right, y down, z forward; world units are metres.
//! * Pose: world-to-camera, `p_cam = R_w2c · p_world + t_w2c` (row-major `R`).
//! * Projection: `x = fx · X/Z + cx`, `y = fy · Y/Z + cy`.
//! * **Pixel centres are at integer coordinates**: pixel `(i, j)` (column `i`, row `j`) covers
//!   `[i − ½, i + ½] × [j − ½, j + ½]` and is sampled at `(i, j)`. A centred principal point is
//!   therefore `cx = (W − 1)/2`. This is the convention of the 2DGS CUDA rasterizer, of the BOP
//!   `cam_K` in our data (`cx = 319.5` for 640 px) and of the `surfel-raster` fixtures. Readers of
//!   formats with the `+½` convention (nerfstudio) subtract ½ from `cx, cy` when loading.

use glam::{DMat3, DVec3};
use serde::{Deserialize, Serialize};

/// Why a camera cannot be used.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum CameraError {
    #[error("image size {width}x{height} is empty")]
    EmptyImage { width: u32, height: u32 },
    #[error("image size {width}x{height} is above the supported {MAX_IMAGE_SIDE} pixels a side")]
    ImageTooLarge { width: u32, height: u32 },
    #[error(
        "focal length fx={fx}, fy={fy} must be finite, positive and at most {MAX_FOCAL_PER_SIDE} times the image side"
    )]
    BadFocal { fx: f64, fy: f64 },
    #[error(
        "principal point cx={cx}, cy={cy} must be finite and within {MAX_FOCAL_PER_SIDE} image sides of the image"
    )]
    BadPrincipalPoint { cx: f64, cy: f64 },
    #[error("pose contains a non-finite value")]
    NonFinitePose,
    #[error("pose translation {0:?} is beyond {MAX_TRANSLATION_M} m")]
    FarTranslation([f64; 3]),
    #[error("pose rotation is not orthonormal (|RᵀR − I| = {0:.3e})")]
    NotARotation(f64),
    #[error("pose rotation has determinant {0:.3} (a reflection), not +1")]
    Reflection(f64),
}

/// The largest image side accepted (pixels): 8192 covers an 8K sensor, and keeps every per-pixel
/// buffer (the training targets hold a dozen floats a pixel) within memory.
pub const MAX_IMAGE_SIDE: u32 = 8192;

/// Focal lengths and principal points beyond this many image sides (a field of view under 0.006°)
/// are taken as corrupt.
pub const MAX_FOCAL_PER_SIDE: f64 = 1e4;

/// Camera translations beyond this distance (metres) are taken as corrupt: scenes are a table top,
/// and larger values overflow single-precision squares in the rasterizer.
pub const MAX_TRANSLATION_M: f64 = 1e4;

/// Pinhole intrinsics with the integer-pixel-centre convention (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub width: u32,
    pub height: u32,
}

impl Intrinsics {
    /// A camera with the principal point at the image centre, `cx = (W−1)/2`.
    pub fn centered(f: f64, width: u32, height: u32) -> Self {
        Self {
            fx: f,
            fy: f,
            cx: (width as f64 - 1.0) / 2.0,
            cy: (height as f64 - 1.0) / 2.0,
            width,
            height,
        }
    }

    /// Scales the image by `s` (e.g. 0.5 to halve the resolution), keeping the pixel-centre convention:
    /// a continuous image coordinate `u` maps to `(u + ½)·s − ½`.
    pub fn scaled(&self, s: f64) -> Self {
        Self {
            fx: self.fx * s,
            fy: self.fy * s,
            cx: (self.cx + 0.5) * s - 0.5,
            cy: (self.cy + 0.5) * s - 0.5,
            width: ((self.width as f64) * s).round().max(1.0) as u32,
            height: ((self.height as f64) * s).round().max(1.0) as u32,
        }
    }

    pub fn num_pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }
}

/// A calibrated view: intrinsics and world-to-camera pose.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Camera {
    pub intrinsics: Intrinsics,
    /// World-to-camera rotation, row-major.
    pub r_w2c: [[f64; 3]; 3],
    /// World-to-camera translation in metres.
    pub t_w2c: [f64; 3],
}

impl Camera {
    pub fn new(intrinsics: Intrinsics, r_w2c: [[f64; 3]; 3], t_w2c: [f64; 3]) -> Self {
        Self {
            intrinsics,
            r_w2c,
            t_w2c,
        }
    }

    /// A camera at `eye` looking at `target`, with the image "up" as close as possible to `up`
    /// (world vector). OpenCV frame: z towards the target, y down.
    pub fn look_at(intrinsics: Intrinsics, eye: DVec3, target: DVec3, up: DVec3) -> Self {
        let z = (target - eye).normalize();
        let mut x = z.cross(up);
        if x.length_squared() < 1e-12 {
            x = z.cross(DVec3::X).try_normalize().unwrap_or(DVec3::Y);
        }
        let x = x.normalize();
        let y = z.cross(x);
        let r = DMat3::from_cols(x, y, z).transpose();
        let t = -(r * eye);
        Self::from_glam(intrinsics, r, t)
    }

    pub fn from_glam(intrinsics: Intrinsics, r_w2c: DMat3, t_w2c: DVec3) -> Self {
        let rows = r_w2c.transpose().to_cols_array_2d();
        Self {
            intrinsics,
            r_w2c: rows,
            t_w2c: t_w2c.to_array(),
        }
    }

    /// Rotation as a glam matrix.
    pub fn rotation(&self) -> DMat3 {
        DMat3::from_cols_array_2d(&self.r_w2c).transpose()
    }

    pub fn translation(&self) -> DVec3 {
        DVec3::from_array(self.t_w2c)
    }

    /// Camera centre in world coordinates, `C = −Rᵀ t`.
    pub fn center(&self) -> DVec3 {
        -(self.rotation().transpose() * self.translation())
    }

    /// Optical axis (camera +z) in world coordinates.
    pub fn forward(&self) -> DVec3 {
        self.rotation().transpose() * DVec3::Z
    }

    /// This camera seeing the world moved by `s` (m): a point `x` projects where `x + s` did
    /// (`t' = t + R s`, the rotation unchanged).
    pub fn seeing_world_moved(&self, s: DVec3) -> Self {
        Self::from_glam(
            self.intrinsics,
            self.rotation(),
            self.translation() + self.rotation() * s,
        )
    }

    /// World point to camera frame.
    pub fn world_to_camera(&self, p: DVec3) -> DVec3 {
        self.rotation() * p + self.translation()
    }

    /// Projects a world point: `(x_pixel, y_pixel, z_camera)`; `None` when `z ≤ 0`.
    pub fn project(&self, p: DVec3) -> Option<(f64, f64, f64)> {
        let c = self.world_to_camera(p);
        if c.z <= 0.0 {
            return None;
        }
        let k = &self.intrinsics;
        Some((k.fx * c.x / c.z + k.cx, k.fy * c.y / c.z + k.cy, c.z))
    }

    /// World-space ray direction (unit) through the continuous pixel coordinate `(x, y)`.
    pub fn ray_direction(&self, x: f64, y: f64) -> DVec3 {
        let k = &self.intrinsics;
        let d = DVec3::new((x - k.cx) / k.fx, (y - k.cy) / k.fy, 1.0);
        (self.rotation().transpose() * d).normalize()
    }

    /// Checks the camera can be rendered from: [`Camera::validate_intrinsics`] and
    /// [`Camera::validate_pose`].
    pub fn validate(&self) -> Result<(), CameraError> {
        self.validate_intrinsics()?;
        self.validate_pose()
    }

    /// Checks the image size, focal length and principal point.
    pub fn validate_intrinsics(&self) -> Result<(), CameraError> {
        let k = &self.intrinsics;
        if k.width == 0 || k.height == 0 {
            return Err(CameraError::EmptyImage {
                width: k.width,
                height: k.height,
            });
        }
        if k.width > MAX_IMAGE_SIDE || k.height > MAX_IMAGE_SIDE {
            return Err(CameraError::ImageTooLarge {
                width: k.width,
                height: k.height,
            });
        }
        let side = k.width.max(k.height) as f64;
        let bound = MAX_FOCAL_PER_SIDE * side;
        let focal_ok = |f: f64| f.is_finite() && f > 0.0 && f <= bound;
        if !(focal_ok(k.fx) && focal_ok(k.fy)) {
            return Err(CameraError::BadFocal { fx: k.fx, fy: k.fy });
        }
        if !(k.cx.is_finite() && k.cy.is_finite() && k.cx.abs() <= bound && k.cy.abs() <= bound) {
            return Err(CameraError::BadPrincipalPoint { cx: k.cx, cy: k.cy });
        }
        Ok(())
    }

    /// Checks that the pose is finite, near, and a proper rotation (orthonormal, determinant +1).
    pub fn validate_pose(&self) -> Result<(), CameraError> {
        if self
            .r_w2c
            .iter()
            .flatten()
            .chain(&self.t_w2c)
            .any(|v| !v.is_finite())
        {
            return Err(CameraError::NonFinitePose);
        }
        if self.t_w2c.iter().any(|v| v.abs() > MAX_TRANSLATION_M) {
            return Err(CameraError::FarTranslation(self.t_w2c));
        }
        let r = self.rotation();
        let e = (r.transpose() * r - DMat3::IDENTITY)
            .to_cols_array()
            .iter()
            .fold(0.0f64, |a, v| a.max(v.abs()));
        if e > 1e-3 {
            return Err(CameraError::NotARotation(e));
        }
        let det = r.determinant();
        if det < 0.0 {
            return Err(CameraError::Reflection(det));
        }
        Ok(())
    }
}

/// The point the cameras look at: the least-squares point closest to every optical axis,
/// `argmin_p Σ |(I − d dᵀ)(p − o)|²` over the centres `o` and unit forward directions `d` (the
/// 2DGS / TRAN-D `focus_point_fn`).
///
/// When the axes do not determine it (all nearly parallel: the normal matrix's determinant below
/// `1e-6·n³`), the mean of the axes' intersections with the table plane z = 0 stands in: cameras
/// that all look the same way still look at the table, and a point on it beats no point (the
/// scene radius and slab box that follow stay finite). `None` without cameras, or when no axis
/// looks down onto the table either.
pub fn focus_point(cameras: &[Camera]) -> Option<DVec3> {
    if cameras.is_empty() {
        return None;
    }
    let mut a = DMat3::ZERO;
    let mut b = DVec3::ZERO;
    for c in cameras {
        let d = c.forward().normalize();
        let proj = DMat3::IDENTITY - DMat3::from_cols(d * d.x, d * d.y, d * d.z);
        a += proj;
        b += proj * c.center();
    }
    // Well conditioned when the axes span at least two directions; relative threshold on the determinant.
    if a.determinant().abs() > 1e-6 * (cameras.len() as f64).powi(3) {
        return Some(a.inverse() * b);
    }
    let hits: Vec<DVec3> = cameras
        .iter()
        .filter_map(|c| {
            let (o, d) = (c.center(), c.forward());
            (d.z < -1e-9).then(|| o + d * (-o.z / d.z))
        })
        .collect();
    (!hits.is_empty()).then(|| hits.iter().copied().sum::<DVec3>() / hits.len() as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn look_at_puts_target_on_principal_point() {
        let k = Intrinsics::centered(600.0, 640, 480);
        let cam = Camera::look_at(
            k,
            DVec3::new(0.3, -0.4, 0.5),
            DVec3::new(0.0, 0.0, 0.05),
            DVec3::Z,
        );
        cam.validate().unwrap();
        let (x, y, z) = cam.project(DVec3::new(0.0, 0.0, 0.05)).unwrap();
        assert!(
            (x - 319.5).abs() < 1e-9 && (y - 239.5).abs() < 1e-9,
            "({x}, {y})"
        );
        assert!((z - (0.3f64.powi(2) + 0.4f64.powi(2) + 0.45f64.powi(2)).sqrt()).abs() < 1e-12);
        // World up appears as image up (negative y).
        let (_, y_up, _) = cam.project(DVec3::new(0.0, 0.0, 0.10)).unwrap();
        assert!(y_up < y);
    }

    #[test]
    fn degenerate_cameras_are_rejected() {
        let good = Camera::look_at(
            Intrinsics::centered(500.0, 64, 48),
            DVec3::new(0.0, 0.0, 1.0),
            DVec3::ZERO,
            DVec3::Y,
        );
        assert!(good.validate().is_ok());
        let mut c = good;
        c.intrinsics.fx = 0.0;
        assert!(matches!(c.validate(), Err(CameraError::BadFocal { .. })));
        let mut c = good;
        c.intrinsics.width = 0;
        assert!(matches!(c.validate(), Err(CameraError::EmptyImage { .. })));
        let mut c = good;
        c.t_w2c[1] = f64::NAN;
        assert_eq!(c.validate(), Err(CameraError::NonFinitePose));
        let mut c = good;
        c.r_w2c[0][0] = 2.0;
        assert!(matches!(c.validate(), Err(CameraError::NotARotation(_))));
    }

    #[test]
    fn reflection_is_not_a_rotation() {
        let good = Camera::look_at(
            Intrinsics::centered(500.0, 64, 48),
            DVec3::new(0.0, 0.0, 1.0),
            DVec3::ZERO,
            DVec3::Y,
        );
        let mut c = good;
        c.r_w2c[1] = c.r_w2c[1].map(|v| -v);
        assert!(matches!(c.validate(), Err(CameraError::Reflection(d)) if (d + 1.0).abs() < 1e-9));
    }

    #[test]
    fn absurd_focal_size_and_translation_are_rejected() {
        let good = Camera::look_at(
            Intrinsics::centered(500.0, 64, 48),
            DVec3::new(0.0, 0.0, 1.0),
            DVec3::ZERO,
            DVec3::Y,
        );
        let mut c = good;
        c.intrinsics.fx = 1e308;
        assert!(matches!(
            c.validate_intrinsics(),
            Err(CameraError::BadFocal { .. })
        ));
        let mut c = good;
        c.intrinsics.cy = -1e300;
        assert!(matches!(
            c.validate_intrinsics(),
            Err(CameraError::BadPrincipalPoint { .. })
        ));
        let mut c = good;
        c.intrinsics.width = 100_000;
        assert!(matches!(
            c.validate_intrinsics(),
            Err(CameraError::ImageTooLarge { .. })
        ));
        let mut c = good;
        c.t_w2c[0] = 1e308;
        assert!(matches!(
            c.validate_pose(),
            Err(CameraError::FarTranslation(_))
        ));
        assert!(c.validate_intrinsics().is_ok());
    }

    #[test]
    fn scaled_intrinsics_keep_pixel_centre_convention() {
        let k = Intrinsics::centered(600.0, 640, 480).scaled(0.5);
        assert_eq!((k.width, k.height), (320, 240));
        assert!((k.cx - 159.5).abs() < 1e-12 && (k.cy - 119.5).abs() < 1e-12);
    }
}
