//! Reader of BOP / BlenderProc `train_pbr`-style sequences (our Blender data and the paper's synthetic data).
//!
//! ```text
//! SEQ/
//!   sequence.json                         optional: `removed_obj_id` (int) or `removed_obj_ids` (list)
//!   train_0/ train_1/ test_0/ test_1/     each optional except train_0; may hold a `data/` level
//!     scene_camera.json                   {"<frame>": {cam_K[9], cam_R_w2c[9], cam_t_w2c[3] mm,
//!                                                     depth_scale, width, height}}
//!     rgb/{frame:06}.png                  8-bit RGB
//!     depth/{frame:06}.png                uint16; value · depth_scale = millimetres
//!     mask_visib/{frame:06}_{obj:06}.png  0/255, one per object present (named by object id)
//!     scene_gt.json                       only needed for masks named by annotation index (see below)
//! ```
//! Masks are combined into one [`InstanceMap`] per view. Classic BOP names masks by the annotation
//! index (`_000000` is the first object of `scene_gt.json[frame]`); our data names them by object id,
//! which is never 0. A folder with a `_000000` mask is therefore read in index mode and mapped through
//! `scene_gt.json`. Every file in `mask_visib/` except hidden ones must be named so. A pixel claimed by two masks keeps the lower object id (visible masks of an exact
//! render do not overlap). `depth_scale` must agree across every frame of the sequence.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use trand_core::Intrinsics;

use crate::error::IoError;
use crate::image::{Image, InstanceMap, read_depth_png, read_gray8, read_rgb8};
use crate::json::{Obj, read_json};
use crate::pose;
use crate::view::{LoadOptions, Sequence, Split, State, View};

/// Millimetres per metre: BOP translations and depth are in millimetres.
const MM_PER_M: f64 = 1000.0;

/// Mask pixels above this are inside (masks are 0/255; the midpoint tolerates resampled masks).
const MASK_THRESHOLD: u8 = 127;

/// The folder holding `scene_camera.json` for a split, if the split exists.
fn split_dir(root: &Path, folder: &str) -> Option<PathBuf> {
    let d = root.join(folder);
    if d.join("scene_camera.json").is_file() {
        Some(d)
    } else if d.join("data").join("scene_camera.json").is_file() {
        Some(d.join("data"))
    } else {
        None
    }
}

/// True if `root` looks like a BOP sequence.
pub fn is_bop(root: &Path) -> bool {
    split_dir(root, "train_0").is_some()
}

/// `(frame, object id)` of a mask file named `{frame}_{object id}.png`; why not otherwise.
fn parse_mask_name(name: &std::ffi::OsStr) -> Result<(u32, u16), String> {
    let name = name.to_str().ok_or("not valid UTF-8")?;
    let stem = name.strip_suffix(".png").ok_or("not a `.png` file")?;
    let (f, o) = stem
        .split_once('_')
        .ok_or("no `_` between frame and object id")?;
    let f = f
        .parse::<u32>()
        .map_err(|_| format!("frame `{f}` is not an integer below 2^32"))?;
    let o = o
        .parse::<u16>()
        .map_err(|_| format!("object id `{o}` is not an integer below 65536"))?;
    Ok((f, o))
}

/// Mask files of a split: frame → [(object id, path)]. A file whose name does not parse is an
/// error, not skipped: a mask left out would silently turn its object into background.
fn mask_files(dir: &Path) -> Result<BTreeMap<u32, Vec<(u16, PathBuf)>>, IoError> {
    let mdir = dir.join("mask_visib");
    let mut out: BTreeMap<u32, Vec<(u16, PathBuf)>> = BTreeMap::new();
    if !mdir.is_dir() {
        return Ok(out);
    }
    let entries = std::fs::read_dir(&mdir).map_err(|e| IoError::io(&mdir, e))?;
    for e in entries {
        let e = e.map_err(|e| IoError::io(&mdir, e))?;
        let name = e.file_name();
        if name.as_encoded_bytes().starts_with(b".") {
            continue; // hidden files (editor and desktop leftovers)
        }
        let (f, o) = parse_mask_name(&name).map_err(|reason| {
            IoError::field(
                e.path(),
                "file name",
                format!("{reason}; mask files are named {{frame}}_{{object id}}.png"),
            )
        })?;
        out.entry(f).or_default().push((o, e.path()));
    }
    for v in out.values_mut() {
        v.sort();
    }
    // Index mode: map annotation indices to object ids through scene_gt.json.
    if out.values().flatten().any(|(o, _)| *o == 0) {
        let gt_path = dir.join("scene_gt.json");
        let gt = read_json(&gt_path)?;
        for (frame, v) in out.iter_mut() {
            let key = frame.to_string();
            let anns = gt
                .get(&key)
                .and_then(|a| a.as_array())
                .ok_or_else(|| IoError::field(&gt_path, &key, "missing annotation list"))?;
            for (o, _) in v.iter_mut() {
                let field = format!("{key}[{o}].obj_id");
                let id = anns
                    .get(*o as usize)
                    .and_then(|a| a.get("obj_id"))
                    .and_then(|i| i.as_u64())
                    .and_then(|i| u16::try_from(i).ok())
                    .filter(|&i| i > 0)
                    .ok_or_else(|| {
                        IoError::field(&gt_path, field, "missing or not a positive integer")
                    })?;
                *o = id;
            }
            v.sort();
        }
    }
    Ok(out)
}

/// `depth_scale` seen first: value, file, field; every frame must agree with it.
struct DepthScale(Option<(f64, PathBuf, String)>);

impl DepthScale {
    fn check(&mut self, value: f64, path: &Path, field: String) -> Result<(), IoError> {
        if !(value.is_finite() && value > 0.0) {
            return Err(IoError::field(
                path,
                field,
                format!("depth_scale {value} must be finite and positive"),
            ));
        }
        match &self.0 {
            None => {
                self.0 = Some((value, path.into(), field));
                Ok(())
            }
            Some((v, _, _)) if *v == value => Ok(()),
            Some((v, _, _)) => Err(IoError::DepthScaleMismatch {
                path: path.into(),
                field,
                found: value,
                expected: *v,
            }),
        }
    }
}

fn image_size(path: &Path) -> Result<(u32, u32), IoError> {
    if !path.is_file() {
        return Err(IoError::Missing {
            path: path.into(),
            what: "needed for the image size (no width/height in scene_camera.json)".into(),
        });
    }
    image::image_dimensions(path).map_err(|source| IoError::Image {
        path: path.into(),
        source,
    })
}

fn check_size<T>(img: &Image<T>, k: &Intrinsics, path: &Path) -> Result<(), IoError> {
    if img.width != k.width || img.height != k.height {
        return Err(IoError::SizeMismatch {
            path: path.into(),
            field: "camera image".into(),
            found_w: img.width,
            found_h: img.height,
            expected_w: k.width,
            expected_h: k.height,
        });
    }
    Ok(())
}

fn read_split(
    dir: &Path,
    folder: &str,
    opts: &LoadOptions,
    scale: &mut DepthScale,
    ids_seen: &mut Vec<u16>,
) -> Result<Vec<View>, IoError> {
    let cam_path = dir.join("scene_camera.json");
    let cams = read_json(&cam_path)?;
    let cams = Obj::root(&cam_path, &cams)?;
    let masks = mask_files(dir)?;
    for (frame, v) in &masks {
        for (id, path) in v {
            opts.check_ids(&[*id], path, &format!("object id of frame {frame}'s mask"))?;
            ids_seen.push(*id);
        }
    }
    let mut frames: Vec<(u32, &str)> = Vec::new();
    for key in cams.value.as_object().into_iter().flat_map(|m| m.keys()) {
        let f = key
            .parse::<u32>()
            .map_err(|_| IoError::field(&cam_path, key, "frame keys must be integers"))?;
        frames.push((f, key));
    }
    frames.sort();
    let mut views = Vec::with_capacity(frames.len());
    for (frame, key) in frames {
        let c = cams.child(key)?;
        let kk = c.floats("cam_K", 9)?;
        let r = c.floats("cam_R_w2c", 9)?;
        let t = c.floats("cam_t_w2c", 3)?;
        let depth_scale = c.opt_f64("depth_scale")?.unwrap_or(1.0);
        scale.check(depth_scale, &cam_path, c.name("depth_scale"))?;
        let rgb_path = dir.join("rgb").join(format!("{frame:06}.png"));
        let ((width, height), size_field) = match (c.opt_u32("width")?, c.opt_u32("height")?) {
            (Some(w), Some(h)) => ((w, h), c.name("width/height")),
            _ => (
                image_size(&rgb_path)?,
                format!("size of {}", rgb_path.display()),
            ),
        };
        let k = Intrinsics {
            fx: kk[0],
            fy: kk[4],
            cx: kk[2],
            cy: kk[5],
            width,
            height,
        };
        pose::check_intrinsics(&k, &cam_path, &c.name("cam_K"), &size_field)?;
        let r = [[r[0], r[1], r[2]], [r[3], r[4], r[5]], [r[6], r[7], r[8]]];
        let t = [t[0] / MM_PER_M, t[1] / MM_PER_M, t[2] / MM_PER_M];
        let camera = pose::from_w2c(k, r, t, &cam_path, &c.name("cam_R_w2c/cam_t_w2c"))?;
        let rgb = if opts.rgb.yes() {
            let img = read_rgb8(&rgb_path)?;
            check_size(&img, &k, &rgb_path)?;
            Some(img)
        } else {
            None
        };
        let instance = if opts.masks.yes() {
            let mut inst: InstanceMap = Image::filled(width, height, 1, 0);
            for (id, path) in masks.get(&frame).map(|v| v.as_slice()).unwrap_or(&[]) {
                let m = read_gray8(path)?;
                check_size(&m, &k, path)?;
                for (dst, &src) in inst.data.iter_mut().zip(&m.data) {
                    if src > MASK_THRESHOLD && *dst == 0 {
                        *dst = *id;
                    }
                }
            }
            Some(inst)
        } else {
            None
        };
        let depth = if opts.depth.yes() {
            let p = dir.join("depth").join(format!("{frame:06}.png"));
            let d = read_depth_png(&p, depth_scale)?;
            check_size(&d, &k, &p)?;
            Some(d)
        } else {
            None
        };
        views.push(View {
            name: format!("{folder}/{frame:06}"),
            frame,
            camera,
            rgb,
            instance,
            depth,
        });
    }
    Ok(views)
}

fn removed_ids(root: &Path) -> Result<Option<Vec<u16>>, IoError> {
    let path = root.join("sequence.json");
    if !path.is_file() {
        return Ok(None);
    }
    let v = read_json(&path)?;
    let o = Obj::root(&path, &v)?;
    let as_id = |v: &serde_json::Value, key: &str| {
        v.as_u64()
            .and_then(|i| u16::try_from(i).ok())
            .ok_or_else(|| o.err(key, "expected an object id"))
    };
    if let Some(list) = o.opt("removed_obj_ids") {
        let a = list
            .as_array()
            .ok_or_else(|| o.err("removed_obj_ids", "expected an array"))?;
        let mut ids = a
            .iter()
            .map(|v| as_id(v, "removed_obj_ids"))
            .collect::<Result<Vec<_>, _>>()?;
        ids.sort_unstable();
        return Ok(Some(ids));
    }
    o.opt("removed_obj_id")
        .map(|v| as_id(v, "removed_obj_id").map(|i| vec![i]))
        .transpose()
}

/// Reads a BOP sequence folder.
pub fn read_bop(root: &Path, opts: &LoadOptions) -> Result<Sequence, IoError> {
    if !is_bop(root) {
        return Err(IoError::Missing {
            path: root.join("train_0").join("scene_camera.json"),
            what: "BOP sequence needs train_0/".into(),
        });
    }
    let mut seq = Sequence {
        root: root.into(),
        removed_ids: removed_ids(root)?,
        ..Default::default()
    };
    let mut scale = DepthScale(None);
    for state in [State::T0, State::T1] {
        let mut ids = Vec::new();
        for split in [Split::Train, Split::Test] {
            let folder = split.folder(state);
            if let Some(dir) = split_dir(root, folder) {
                *seq.views_mut(split, state) =
                    read_split(&dir, folder, opts, &mut scale, &mut ids)?;
            }
        }
        if state == State::T0 {
            ids.sort_unstable();
            ids.dedup();
            seq.object_ids = ids;
        }
    }
    Ok(seq)
}
