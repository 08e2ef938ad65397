//! Cameras and sequences from in-memory arrays instead of a folder: what a host program (the Python
//! package, a robot's driver) hands over when its images, masks and poses are already in memory.
//!
//! * [`camera_from_matrices`]: a [`Camera`] from a 3x3 `K` and a 4x4 world-to-camera matrix (row-major,
//!   metres, OpenCV axes, integer pixel centres, as everywhere in trand), checked as strictly as a
//!   camera read from a file; the error names the entry (`K[0][1]`, `world_to_camera[3]`).
//! * [`view_from_arrays`]: a [`View`] from an interleaved RGB buffer, an instance-id buffer and a
//!   camera, with the sizes checked.
//! * [`Sequence::from_train_views`]: a sequence whose t = 0 training views are exactly the given ones,
//!   in the given order ([`TrainSelection::Listed`]), so a reconstruction trains on what the host
//!   passed. No test views: the caller renders wherever it likes.

use std::path::PathBuf;

use trand_core::{Camera, Intrinsics};

use crate::image::Image;
use crate::view::{LoadOptions, Sequence, TrainSelection, View};

/// A bad array, naming the entry at fault (e.g. `world_to_camera[2][3]`) and why.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{field}: {reason}")]
pub struct ArrayError {
    pub field: String,
    pub reason: String,
}

impl ArrayError {
    fn new(field: impl Into<String>, reason: impl Into<String>) -> Self {
        Self {
            field: field.into(),
            reason: reason.into(),
        }
    }
}

/// How far the bottom row of a world-to-camera matrix may be from `[0, 0, 0, 1]`.
const AFFINE_TOLERANCE: f64 = 1e-9;

/// A camera from `K` (3x3, row-major, `[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`), a world-to-camera
/// matrix (4x4, row-major, bottom row `[0, 0, 0, 1]`) and the image size. Every value must be finite,
/// the skew zero, the rotation proper (orthonormal, determinant +1), and the camera must pass
/// [`Camera::validate`]. Errors name the fields `K`, `world_to_camera`, `width` and `height`.
pub fn camera_from_matrices(
    k: &[[f64; 3]; 3],
    w2c: &[[f64; 4]; 4],
    width: u32,
    height: u32,
) -> Result<Camera, ArrayError> {
    finite("K", k.iter().map(|r| r.as_slice()))?;
    finite("world_to_camera", w2c.iter().map(|r| r.as_slice()))?;
    if k[0][1] != 0.0 {
        return Err(ArrayError::new(
            "K[0][1]",
            "skew is not supported; it must be 0",
        ));
    }
    if k[1][0] != 0.0 || k[2] != [0.0, 0.0, 1.0] {
        return Err(ArrayError::new(
            "K",
            "the bottom rows must be [0, fy, cy] and [0, 0, 1]",
        ));
    }
    if w2c[3]
        .iter()
        .zip([0.0, 0.0, 0.0, 1.0])
        .any(|(a, b)| (a - b).abs() > AFFINE_TOLERANCE)
    {
        return Err(ArrayError::new(
            "world_to_camera[3]",
            format!("the bottom row must be [0, 0, 0, 1], found {:?}", w2c[3]),
        ));
    }
    let intrinsics = Intrinsics {
        fx: k[0][0],
        fy: k[1][1],
        cx: k[0][2],
        cy: k[1][2],
        width,
        height,
    };
    let r = [0, 1, 2].map(|i| [w2c[i][0], w2c[i][1], w2c[i][2]]);
    let t = [w2c[0][3], w2c[1][3], w2c[2][3]];
    let cam = Camera::new(intrinsics, r, t);
    cam.validate_intrinsics().map_err(|e| {
        let bad_side = |s: u32| s == 0 || s > trand_core::camera::MAX_IMAGE_SIDE;
        let field = match e {
            trand_core::CameraError::EmptyImage { .. }
            | trand_core::CameraError::ImageTooLarge { .. } => {
                if bad_side(width) {
                    "width"
                } else {
                    "height"
                }
            }
            _ => "K",
        };
        ArrayError::new(field, e.to_string())
    })?;
    cam.validate_pose()
        .map_err(|e| ArrayError::new("world_to_camera", e.to_string()))?;
    Ok(cam)
}

fn finite<'a>(name: &str, rows: impl Iterator<Item = &'a [f64]>) -> Result<(), ArrayError> {
    for (i, row) in rows.enumerate() {
        if let Some((j, v)) = row.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(ArrayError::new(
                format!("{name}[{i}][{j}]"),
                format!("is {v}; every value must be finite"),
            ));
        }
    }
    Ok(())
}

/// A view named `name` from an interleaved 8-bit RGB buffer (`height · width · 3` bytes, row-major) and
/// an instance-id buffer (`height · width` ids, 0 = background), of the camera's size.
pub fn view_from_arrays(
    name: impl Into<String>,
    frame: u32,
    camera: Camera,
    rgb: Vec<u8>,
    instance: Vec<u16>,
) -> Result<View, ArrayError> {
    let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
    let n = w as usize * h as usize;
    if rgb.len() != 3 * n {
        return Err(ArrayError::new(
            "image",
            format!(
                "{} values, but the camera's {w}x{h} image needs {}",
                rgb.len(),
                3 * n
            ),
        ));
    }
    if instance.len() != n {
        return Err(ArrayError::new(
            "mask",
            format!(
                "{} values, but the camera's {w}x{h} image needs {n}",
                instance.len()
            ),
        ));
    }
    Ok(View {
        name: name.into(),
        frame,
        camera,
        rgb: Image::from_vec(w, h, 3, rgb),
        instance: Image::from_vec(w, h, 1, instance),
        depth: None,
    })
}

impl Sequence {
    /// A sequence whose t = 0 training views are `views`, all of them, in this order
    /// ([`TrainSelection::Listed`]); `object_ids` are the ids found in their masks. `root` only names
    /// the sequence in messages. Fails when a view has no instance mask, or an id does not fit
    /// `opts.object_channels`.
    pub fn from_train_views(
        root: impl Into<PathBuf>,
        views: Vec<View>,
        opts: &LoadOptions,
    ) -> Result<Self, ArrayError> {
        let mut ids: Vec<u16> = Vec::new();
        for (i, v) in views.iter().enumerate() {
            let inst = v
                .instance
                .as_ref()
                .ok_or_else(|| ArrayError::new(format!("masks[{i}]"), "missing"))?;
            let mut found: Vec<u16> = inst.data.iter().copied().filter(|&d| d != 0).collect();
            found.sort_unstable();
            found.dedup();
            if let Some(k) = opts.object_channels
                && let Some(&id) = found.iter().find(|&&id| id as usize >= k)
            {
                return Err(ArrayError::new(
                    format!("masks[{i}]"),
                    format!(
                        "object id {id} does not fit {k} object channels (ids must be 1..{}; 0 is background)",
                        k - 1
                    ),
                ));
            }
            ids.extend(found);
        }
        ids.sort_unstable();
        ids.dedup();
        Ok(Sequence {
            root: root.into(),
            train_t0: views,
            object_ids: ids,
            train_selection: TrainSelection::Listed,
            ..Default::default()
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const K: [[f64; 3]; 3] = [[100.0, 0.0, 7.5], [0.0, 100.0, 5.5], [0.0, 0.0, 1.0]];
    const W2C: [[f64; 4]; 4] = [
        [1.0, 0.0, 0.0, 0.0],
        [0.0, -1.0, 0.0, 0.0],
        [0.0, 0.0, -1.0, 0.5],
        [0.0, 0.0, 0.0, 1.0],
    ];

    fn field_of(k: [[f64; 3]; 3], w2c: [[f64; 4]; 4]) -> String {
        camera_from_matrices(&k, &w2c, 16, 12).unwrap_err().field
    }

    #[test]
    fn matrices_give_the_camera_they_spell() {
        let cam = camera_from_matrices(&K, &W2C, 16, 12).unwrap();
        assert_eq!(cam.intrinsics.cx, 7.5);
        assert_eq!(cam.t_w2c, [0.0, 0.0, 0.5]);
        assert_eq!(cam.r_w2c[1], [0.0, -1.0, 0.0]);
    }

    #[test]
    fn bad_entries_are_named() {
        let mut w = W2C;
        w[2][3] = f64::NAN;
        assert_eq!(field_of(K, w), "world_to_camera[2][3]");
        let mut k = K;
        k[0][1] = 1.0;
        assert_eq!(field_of(k, W2C), "K[0][1]");
        let mut w = W2C;
        w[3][2] = 1.0;
        assert_eq!(field_of(K, w), "world_to_camera[3]");
        let mut w = W2C;
        w[0][0] = 2.0;
        let e = camera_from_matrices(&K, &w, 16, 12).unwrap_err();
        assert!(e.reason.contains("orthonormal"), "{e}");
        let mut w = W2C;
        w[0][0] = -1.0;
        assert!(
            camera_from_matrices(&K, &w, 16, 12)
                .unwrap_err()
                .reason
                .contains("reflection")
        );
        assert_eq!(
            camera_from_matrices(&K, &W2C, 0, 12).unwrap_err().field,
            "width"
        );
        assert_eq!(
            camera_from_matrices(&K, &W2C, 16, 9000).unwrap_err().field,
            "height"
        );
    }

    #[test]
    fn a_sequence_of_views_trains_on_exactly_them() {
        let cam = camera_from_matrices(&K, &W2C, 16, 12).unwrap();
        let mask = |id: u16| (0..192).map(|i| if i % 7 == 0 { id } else { 0 }).collect();
        let views = vec![
            view_from_arrays("b", 5, cam, vec![0; 576], mask(3)).unwrap(),
            view_from_arrays("a", 2, cam, vec![0; 576], mask(1)).unwrap(),
        ];
        let seq = Sequence::from_train_views("arrays", views, &LoadOptions::default()).unwrap();
        assert_eq!(seq.object_ids, vec![1, 3]);
        assert_eq!(seq.train_selection, TrainSelection::Listed);
        assert_eq!(seq.train_t0[0].name, "b");
        let bad = vec![view_from_arrays("c", 0, cam, vec![0; 576], mask(40)).unwrap()];
        let e = Sequence::from_train_views("arrays", bad, &LoadOptions::default()).unwrap_err();
        assert_eq!(e.field, "masks[0]");
        assert!(view_from_arrays("d", 0, cam, vec![0; 575], mask(1)).is_err());
    }
}
