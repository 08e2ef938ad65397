//! Reader of a KeyPose capture folder as the dataset ships it (google-research `keypose`).
//!
//! ```text
//! NNNNNN_L.png, NNNNNN_R.png      the stereo pair's RGB images
//! NNNNNN_L.pbtxt, NNNNNN_R.pbtxt  text protobuf: kp_target { transform { element: ×16 }  (row-major
//!                                 world-to-camera, metres, OpenCV axes)  camera { fx fy cx cy resx
//!                                 resy ... }  keypoints { u v x y z visible } ... }
//! NNNNNN_mask.png                 the object's mask in the LEFT image (0/255, or instance ids)
//! ```
//! Every image with a mask trains (the left ones); every image without one (the right ones) is a
//! test view, so a run writes its depth at the rig's other cameras too. The frame of `NNNNNN_L` is
//! `2·NNNNNN`, of `NNNNNN_R` `2·NNNNNN + 1`. KeyPose's principal point is in OpenCV's convention
//! (integer pixel centres), as trand's. The world frame is the table's, z up, metres (the dataset's
//! own convention), so it satisfies trand's. The `.pbtxt` files are read by [`crate::textproto`].

use std::path::Path;

use trand_core::Intrinsics;

use crate::error::IoError;
use crate::image::{read_instance_mask, read_rgb8};
use crate::pose;
use crate::textproto::TextProto;
use crate::view::{LoadOptions, Sequence, Split, State, TrainSelection, View};

/// Whether `root` holds a KeyPose capture: some `NNNNNN_L.pbtxt`.
pub fn is_keypose(root: &Path) -> bool {
    !pairs(root).is_empty()
}

/// The capture numbers `NNNNNN` (six digits, as the dataset names them) of `root`'s
/// `NNNNNN_L.pbtxt` files, sorted.
fn pairs(root: &Path) -> Vec<u32> {
    let Ok(dir) = std::fs::read_dir(root) else {
        return Vec::new();
    };
    let mut out: Vec<u32> = dir
        .filter_map(|e| {
            let name = e.ok()?.file_name().into_string().ok()?;
            let stem = name.strip_suffix("_L.pbtxt")?;
            let six = stem.len() == 6 && stem.bytes().all(|b| b.is_ascii_digit());
            six.then(|| stem.parse().ok())?
        })
        .collect();
    out.sort_unstable();
    out
}

/// One view's camera from its `.pbtxt`.
fn camera_of(path: &Path) -> Result<trand_core::Camera, IoError> {
    let text = std::fs::read_to_string(path).map_err(|e| IoError::io(path, e))?;
    let proto = TextProto::parse(&text).map_err(|r| IoError::field(path, "(syntax)", r))?;
    let target = proto
        .block_of("kp_target")
        .ok_or_else(|| IoError::field(path, "kp_target", "missing"))?;
    let m = target
        .block_of("transform")
        .and_then(|t| t.numbers("element"))
        .filter(|e| e.len() == 16)
        .ok_or_else(|| {
            IoError::field(
                path,
                "kp_target.transform",
                "expected 16 numeric `element`s",
            )
        })?;
    let cam = target
        .block_of("camera")
        .ok_or_else(|| IoError::field(path, "kp_target.camera", "missing"))?;
    let num = |key: &str| {
        cam.number(key).ok_or_else(|| {
            IoError::field(
                path,
                format!("kp_target.camera.{key}"),
                "missing or not a number",
            )
        })
    };
    let size = |key: &str| -> Result<u32, IoError> {
        let v = num(key)?;
        if v.fract() != 0.0 || !(1.0..=65535.0).contains(&v) {
            return Err(IoError::field(
                path,
                format!("kp_target.camera.{key}"),
                format!("{v} is not an image size in pixels"),
            ));
        }
        Ok(v as u32)
    };
    let k = Intrinsics {
        fx: num("fx")?,
        fy: num("fy")?,
        cx: num("cx")?,
        cy: num("cy")?,
        width: size("resx")?,
        height: size("resy")?,
    };
    pose::check_intrinsics(&k, path, "kp_target.camera", "kp_target.camera.resx/resy")?;
    if m[12..15].iter().any(|&v| v != 0.0) || m[15] != 1.0 {
        return Err(IoError::field(
            path,
            "kp_target.transform",
            "the last row must be 0 0 0 1",
        ));
    }
    let r = [0, 1, 2].map(|i| [m[4 * i], m[4 * i + 1], m[4 * i + 2]]);
    let t = [m[3], m[7], m[11]];
    pose::from_w2c(k, r, t, path, "kp_target.transform")
}

/// Reads a KeyPose capture folder (see the module docs). It has one state, t = 0.
pub fn read_keypose(root: &Path, opts: &LoadOptions) -> Result<Sequence, IoError> {
    let mut seq = Sequence {
        root: root.into(),
        train_selection: TrainSelection::Listed,
        ..Default::default()
    };
    let mut ids = Vec::new();
    for n in pairs(root) {
        for (side, frame) in [("L", 2 * n), ("R", 2 * n + 1)] {
            let pb = root.join(format!("{n:06}_{side}.pbtxt"));
            if !pb.is_file() {
                continue;
            }
            let camera = camera_of(&pb)?;
            let k = camera.intrinsics;
            let image = root.join(format!("{n:06}_{side}.png"));
            let rgb = if opts.rgb.yes() {
                let img = read_rgb8(&image)?;
                IoError::check_size(img.width, img.height, &k, &image, pb_size(&pb))?;
                Some(img)
            } else {
                None
            };
            let mask = root.join(format!("{n:06}_mask.png"));
            let has_mask = side == "L" && mask.is_file();
            let instance = if has_mask && opts.masks.yes() {
                let img = read_instance_mask(&mask)?;
                IoError::check_size(img.width, img.height, &k, &mask, pb_size(&pb))?;
                let found = img.ids();
                opts.check_ids(&found, &mask, "mask")?;
                ids.extend(found);
                Some(img)
            } else {
                None
            };
            let split = if has_mask { Split::Train } else { Split::Test };
            seq.views_mut(split, State::T0).push(View {
                name: format!("{}/{frame:06}", split.folder(State::T0)),
                frame,
                camera,
                rgb,
                instance,
                depth: None,
            });
        }
    }
    if seq.train_t0.is_empty() {
        return Err(IoError::Missing {
            path: root.join("NNNNNN_mask.png"),
            what: "a KeyPose capture needs the object's mask of at least one left image".into(),
        });
    }
    ids.sort_unstable();
    ids.dedup();
    seq.object_ids = ids;
    Ok(seq)
}

fn pb_size(pb: &Path) -> String {
    format!(
        "{} kp_target.camera.resx/resy",
        pb.file_name().and_then(|n| n.to_str()).unwrap_or("pbtxt")
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A view file: the world-to-camera rotation's rows are (0 0 1), (−1 0 0), (0 −1 0) (not
    /// symmetric, so a transposed read is caught), its translation (0.1, 0.2, 0.9).
    const SAMPLE: &str = "kp_target {\n  transform {\n    element: 0\n    element: 0\n \
        element: 1.0\n element: 0.1\n element: -1\n element: 0\n element: 0\n element: 0.2\n \
        element: 0\n element: -1\n element: 0\n element: 0.9\n element: 0\n element: 0\n \
        element: 0\n element: 1\n  }\n  camera {\n    fx: 600.5\n    fy: 600.5\n    cx: 319.5 \
        cy: 239.5  # a comment\n    resx: 640.0\n    resy: 480.0\n  }\n  keypoints { u: 1 v: 2 }\n \
        keypoints { u: 3 v: 4 }\n}\nproj_targets { transform { element: 1 } }\n";

    #[test]
    fn a_keypose_folder_trains_on_the_masked_left_views_and_tests_on_the_right_ones() {
        let tmp = crate::ScratchDir::new("keypose-reader").unwrap();
        let dir = tmp.path();
        let img = image::RgbImage::new(640, 480);
        let mut mask = image::GrayImage::new(640, 480);
        mask.put_pixel(10, 10, image::Luma([255]));
        for side in ["L", "R"] {
            std::fs::write(dir.join(format!("000002_{side}.pbtxt")), SAMPLE).unwrap();
            img.save(dir.join(format!("000002_{side}.png"))).unwrap();
        }
        mask.save(dir.join("000002_mask.png")).unwrap();
        assert!(is_keypose(dir));
        let seq = read_keypose(dir, &LoadOptions::default()).unwrap();
        assert_eq!(seq.train_t0.len(), 1);
        assert_eq!(seq.test_t0.len(), 1);
        assert_eq!(seq.train_t0[0].name, "train_0/000004");
        assert_eq!(seq.test_t0[0].name, "test_0/000005");
        assert_eq!(seq.object_ids, vec![1]);
        // World point (0.05, −0.3, 0.02): camera x = 0.02 + 0.1, y = −0.05 + 0.2, z = 0.3 + 0.9.
        let (x, y, z) = seq.train_t0[0]
            .camera
            .project(glam::DVec3::new(0.05, -0.3, 0.02))
            .unwrap();
        assert!((z - 1.2).abs() < 1e-9, "{z}");
        assert!((x - (319.5 + 600.5 * 0.12 / 1.2)).abs() < 1e-6, "{x}");
        assert!((y - (239.5 + 600.5 * 0.15 / 1.2)).abs() < 1e-6, "{y}");
    }

    #[test]
    fn a_transform_with_too_few_elements_is_an_error_naming_the_file_and_field() {
        let tmp = crate::ScratchDir::new("keypose-bad").unwrap();
        let p = tmp.path().join("000001_L.pbtxt");
        std::fs::write(&p, SAMPLE.replacen("element: 1.0", "", 1)).unwrap();
        let e = camera_of(&p).unwrap_err().to_string();
        assert!(
            e.contains("000001_L.pbtxt") && e.contains("kp_target.transform"),
            "{e}"
        );
    }
}
