//! Reader of a KeyPose capture folder as the dataset ships it (google-research `keypose`).
//!
//! ```text
//! NNNNNN_L.png, NNNNNN_R.png      the stereo pair's RGB images
//! NNNNNN_L.pbtxt, NNNNNN_R.pbtxt  text protobuf: kp_target { transform { element: ×16 }  (row-major
//!                                 world-to-camera, metres, OpenCV axes)  camera { fx fy cx cy resx
//!                                 resy }  keypoints { u v z } ... }
//! NNNNNN_mask.png                 the object's mask in the LEFT image (0/255, or instance ids)
//! ```
//! Every image with a mask trains (the left ones); every image without one (the right ones) is a
//! test view, so a run writes its depth at the rig's other cameras too. The frame of `NNNNNN_L` is
//! `2·NNNNNN`, of `NNNNNN_R` `2·NNNNNN + 1`. KeyPose's principal point is in OpenCV's convention
//! (integer pixel centres), as trand's. The world frame is the table's, z up, metres (the dataset's
//! own convention), so it satisfies trand's.
//!
//! **Why by hand.** Only two blocks of a small text protobuf are read; the protobuf crates need the
//! message schema compiled in to parse text format, which would tie trand to KeyPose's `.proto`.
//! [`TextProto`] is a tokenizer and a tree of `key: value` and `key { ... }` entries, nothing more.

use std::path::Path;

use trand_core::Intrinsics;

use crate::error::IoError;
use crate::image::{read_instance_mask, read_rgb8};
use crate::pose;
use crate::view::{LoadOptions, Sequence, Split, State, TrainSelection, View};

/// A parsed text protobuf: entries in file order (repeated fields repeat).
#[derive(Debug, Default)]
pub struct TextProto(Vec<(String, Entry)>);

#[derive(Debug)]
enum Entry {
    Scalar(String),
    Block(TextProto),
}

impl TextProto {
    /// Parses `text`; the error says what was expected where.
    pub fn parse(text: &str) -> Result<Self, String> {
        let tokens = tokenize(text)?;
        let mut pos = 0;
        let tree = Self::block(&tokens, &mut pos)?;
        match tokens.get(pos) {
            None => Ok(tree),
            Some(t) => Err(format!("unexpected `{t}` at the top level")),
        }
    }

    fn block(tokens: &[String], pos: &mut usize) -> Result<Self, String> {
        let mut out = Vec::new();
        while let Some(key) = tokens.get(*pos) {
            if key == "}" {
                break;
            }
            *pos += 1;
            match tokens.get(*pos).map(String::as_str) {
                Some(":") => {
                    *pos += 1;
                    let v = tokens
                        .get(*pos)
                        .ok_or_else(|| format!("`{key}:` without a value"))?;
                    *pos += 1;
                    out.push((key.clone(), Entry::Scalar(v.clone())));
                }
                Some("{") => {
                    *pos += 1;
                    let inner = Self::block(tokens, pos)?;
                    if tokens.get(*pos).map(String::as_str) != Some("}") {
                        return Err(format!("`{key} {{` is not closed"));
                    }
                    *pos += 1;
                    out.push((key.clone(), Entry::Block(inner)));
                }
                _ => return Err(format!("expected `:` or `{{` after `{key}`")),
            }
        }
        Ok(Self(out))
    }

    /// The first block named `key`.
    pub fn block_of(&self, key: &str) -> Option<&TextProto> {
        self.0.iter().find_map(|(k, e)| match e {
            Entry::Block(b) if k == key => Some(b),
            _ => None,
        })
    }

    /// Every number named `key`, in order; `None` if one of them is not a number.
    pub fn numbers(&self, key: &str) -> Option<Vec<f64>> {
        self.0
            .iter()
            .filter(|(k, _)| k == key)
            .map(|(_, e)| match e {
                Entry::Scalar(s) => s.parse().ok(),
                Entry::Block(_) => None,
            })
            .collect()
    }

    /// The first number named `key`.
    pub fn number(&self, key: &str) -> Option<f64> {
        self.numbers(key)?.first().copied()
    }
}

fn tokenize(text: &str) -> Result<Vec<String>, String> {
    let mut out = Vec::new();
    let mut chars = text.chars().peekable();
    while let Some(&c) = chars.peek() {
        match c {
            c if c.is_whitespace() => {
                chars.next();
            }
            '#' => while chars.next().is_some_and(|c| c != '\n') {},
            '{' | '}' | ':' => {
                out.push(c.to_string());
                chars.next();
            }
            '"' | '\'' => {
                chars.next();
                let mut s = String::new();
                loop {
                    match chars.next() {
                        Some(q) if q == c => break,
                        Some('\\') => s.extend(chars.next()),
                        Some(x) => s.push(x),
                        None => return Err("unterminated string".into()),
                    }
                }
                out.push(s);
            }
            _ => {
                let mut s = String::new();
                while let Some(&x) = chars.peek() {
                    if x.is_whitespace() || "{}:#\"'".contains(x) {
                        break;
                    }
                    s.push(x);
                    chars.next();
                }
                out.push(s);
            }
        }
    }
    Ok(out)
}

/// Whether `root` holds a KeyPose capture: some `NNNNNN_L.pbtxt`.
pub fn is_keypose(root: &Path) -> bool {
    !pairs(root).is_empty()
}

/// The capture numbers `NNNNNN` of `root`'s `NNNNNN_L.pbtxt` files, sorted.
fn pairs(root: &Path) -> Vec<u32> {
    let Ok(dir) = std::fs::read_dir(root) else {
        return Vec::new();
    };
    let mut out: Vec<u32> = dir
        .filter_map(|e| {
            let name = e.ok()?.file_name().into_string().ok()?;
            name.strip_suffix("_L.pbtxt")?.parse().ok()
        })
        .collect();
    out.sort_unstable();
    out
}

/// One view's camera from its `.pbtxt`.
fn camera_of(path: &Path) -> Result<trand_core::Camera, IoError> {
    let text = std::fs::read_to_string(path).map_err(|e| IoError::io(path, e))?;
    let proto = TextProto::parse(&text).map_err(|r| IoError::field(path, "text protobuf", r))?;
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

    const SAMPLE: &str = "kp_target {\n  transform {\n    element: 1.0\n    element: 0\n \
        element: 0\n element: 0.1\n element: 0\n element: -1\n element: 0\n element: 0.2\n \
        element: 0\n element: 0\n element: -1\n element: 0.9\n element: 0\n element: 0\n \
        element: 0\n element: 1\n  }\n  camera {\n    fx: 600.5\n    fy: 600.5\n    cx: 319.5 \
        cy: 239.5  # a comment\n    resx: 640.0\n    resy: 480.0\n  }\n  keypoints { u: 1 v: 2 }\n \
        keypoints { u: 3 v: 4 }\n}\nname: \"a } b\"\n";

    #[test]
    fn text_protobuf_blocks_repeated_fields_comments_and_strings_are_read() {
        let p = TextProto::parse(SAMPLE).unwrap();
        let t = p.block_of("kp_target").unwrap();
        let e = t.block_of("transform").unwrap().numbers("element").unwrap();
        assert_eq!(e.len(), 16);
        assert_eq!((e[3], e[5], e[11]), (0.1, -1.0, 0.9));
        let cam = t.block_of("camera").unwrap();
        assert_eq!(cam.number("cy"), Some(239.5));
        assert_eq!(cam.number("resx"), Some(640.0));
        assert!(p.block_of("name").is_none());
        assert!(TextProto::parse("a { b: 1").is_err());
        assert!(TextProto::parse("a b").is_err());
    }

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
        // World point (0.1, 0, 0.5): camera x = 0.1 + 0.1, y = 0.2, z = −0.5 + 0.9.
        let (x, y, z) = seq.train_t0[0]
            .camera
            .project(glam::DVec3::new(0.1, 0.0, 0.5))
            .unwrap();
        assert!((z - 0.4).abs() < 1e-9);
        assert!((x - (319.5 + 600.5 * 0.2 / 0.4)).abs() < 1e-6, "{x}");
        assert!((y - (239.5 + 600.5 * 0.2 / 0.4)).abs() < 1e-6, "{y}");
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
