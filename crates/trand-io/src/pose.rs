//! Building [`Camera`]s from the poses found in dataset files, with errors naming the file and field.

use std::path::Path;

use trand_core::{Camera, CameraError, Intrinsics};

use crate::error::IoError;

fn check_camera(cam: Camera, path: &Path, field: &str) -> Result<Camera, IoError> {
    match cam.validate() {
        Ok(()) => Ok(cam),
        Err(CameraError::NonFinitePose) => Err(IoError::NonFinitePose {
            path: path.into(),
            field: field.into(),
        }),
        Err(e) => Err(IoError::BadCamera {
            path: path.into(),
            field: field.into(),
            reason: e.to_string(),
        }),
    }
}

/// Checks intrinsics read from `path`: size errors name `size_field`, focal length and principal
/// point errors name `k_field`.
pub(crate) fn check_intrinsics(
    k: &Intrinsics,
    path: &Path,
    k_field: &str,
    size_field: &str,
) -> Result<(), IoError> {
    let cam = Camera::new(
        *k,
        [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        [0.0; 3],
    );
    cam.validate_intrinsics().map_err(|e| {
        let field = match e {
            CameraError::EmptyImage { .. } | CameraError::ImageTooLarge { .. } => size_field,
            _ => k_field,
        };
        IoError::BadCamera {
            path: path.into(),
            field: field.into(),
            reason: e.to_string(),
        }
    })
}

/// A camera from a world-to-camera rotation (row-major) and translation in metres.
pub(crate) fn from_w2c(
    k: Intrinsics,
    r: [[f64; 3]; 3],
    t: [f64; 3],
    path: &Path,
    field: &str,
) -> Result<Camera, IoError> {
    check_camera(Camera::new(k, r, t), path, field)
}

/// A camera from an OpenCV-convention camera-to-world 4x4 matrix (row-major, metres).
pub(crate) fn from_c2w_opencv(
    k: Intrinsics,
    c2w: [[f64; 4]; 4],
    path: &Path,
    field: &str,
) -> Result<Camera, IoError> {
    if c2w.iter().flatten().any(|v| !v.is_finite()) {
        return Err(IoError::NonFinitePose {
            path: path.into(),
            field: field.into(),
        });
    }
    // R_w2c = R_c2wᵀ, t_w2c = −R_c2wᵀ · C.
    let mut r = [[0.0; 3]; 3];
    for (i, row) in r.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = c2w[j][i];
        }
    }
    let c = [c2w[0][3], c2w[1][3], c2w[2][3]];
    let t = [0, 1, 2].map(|i| -(r[i][0] * c[0] + r[i][1] * c[1] + r[i][2] * c[2]));
    from_w2c(k, r, t, path, field)
}

/// Right-multiplies two 4x4 row-major matrices.
pub(crate) fn mat4_mul(a: &[[f64; 4]; 4], b: &[[f64; 4]; 4]) -> [[f64; 4]; 4] {
    let mut m = [[0.0; 4]; 4];
    for i in 0..4 {
        for j in 0..4 {
            m[i][j] = (0..4).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    m
}
