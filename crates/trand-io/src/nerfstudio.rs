//! Reader of nerfstudio `transforms.json` files (what nerfstudio's `ns-process-data` and many tools write).
//!
//! ```text
//! { "fl_x", "fl_y", "cx", "cy", "w", "h",            (top level, each overridable per frame)
//!   "depth_unit_scale_factor": 0.001,                (metres per depth-PNG unit; default 0.001 = mm)
//!   "train_filenames": [...], "test_filenames": [...] (optional split; default: every frame trains)
//!   "frames": [ { "file_path", "transform_matrix": 4x4 camera-to-world, OpenGL axes,
//!                 "mask_path": instance-id PNG (8 or 16 bit, 0 = background),
//!                 "depth_file_path": uint16 PNG, or float .npy in metres
//!                                    (times depth_unit_scale_factor only if given) } ] }
//! ```
//! Conversions to trand's conventions:
//! * **Axes**: nerfstudio cameras look down −z with y up (OpenGL); trand's look down +z with y down
//!   (OpenCV), so the camera's y and z axes (columns 1 and 2 of `c2w`) are negated.
//! * **Pixel centres**: nerfstudio puts pixel centres at `+½` (a centred camera has `cx = W/2`); trand at
//!   integer coordinates, so ½ is subtracted from `cx` and `cy`.
//! * Distortion coefficients are ignored (our data is undistorted).
//!
//! The file is the t=0 state. A sibling `transforms_t1.json` in the same format, if present, is the t=1
//! state (a trand convention). View names are `train_0/000003`, the frame being the number at the end
//! of the image file name (else the position in `frames`); two images of a split with the same frame
//! are an error. Every training image is used at t = 0 ([`crate::TrainSelection::Listed`]): the
//! paper's ring selection (`--views`) applies to BOP and the authors' layout only.

use std::path::Path;

use trand_core::Intrinsics;

use crate::error::IoError;
use crate::image::{read_depth_png, read_instance_mask, read_rgb8};
use crate::json::{Obj, read_json};
use crate::npy::read_npy_f32;
use crate::paths::{frame_number, resolve};
use crate::pose;
use crate::view::{LoadOptions, Sequence, Split, State, View};

/// nerfstudio's pixel-centre offset: its pixel `(i, j)` is sampled at `(i + ½, j + ½)`.
const PIXEL_CENTRE_OFFSET: f64 = 0.5;
/// nerfstudio's default depth unit: millimetres.
const DEFAULT_DEPTH_UNIT_M: f64 = 0.001;

pub const T0_FILE: &str = "transforms.json";
pub const T1_FILE: &str = "transforms_t1.json";

pub fn is_nerfstudio(root: &Path) -> bool {
    root.join(T0_FILE).is_file()
}

fn intrinsics(f: &Obj, top: &Obj) -> Result<Intrinsics, IoError> {
    let num = |key: &str| -> Result<f64, IoError> {
        match f.opt_f64(key)? {
            Some(v) => Ok(v),
            None => top.f64(key),
        }
    };
    let int = |key: &str| -> Result<u32, IoError> {
        match f.opt_u32(key)? {
            Some(v) => Ok(v),
            None => top
                .opt_u32(key)?
                .ok_or_else(|| top.err(key, "missing (top level and frame)")),
        }
    };
    let fx = num("fl_x")?;
    let fy = f.opt_f64("fl_y")?.or(top.opt_f64("fl_y")?).unwrap_or(fx);
    Ok(Intrinsics {
        fx,
        fy,
        cx: num("cx")? - PIXEL_CENTRE_OFFSET,
        cy: num("cy")? - PIXEL_CENTRE_OFFSET,
        width: int("w")?,
        height: int("h")?,
    })
}

fn string_list(top: &Obj, key: &str) -> Result<Option<Vec<String>>, IoError> {
    let Some(v) = top.opt(key) else {
        return Ok(None);
    };
    let a = v
        .as_array()
        .ok_or_else(|| top.err(key, "expected an array of file names"))?;
    a.iter()
        .map(|s| {
            s.as_str()
                .map(str::to_string)
                .ok_or_else(|| top.err(key, "expected strings"))
        })
        .collect::<Result<_, _>>()
        .map(Some)
}

fn read_file(
    path: &Path,
    state: State,
    opts: &LoadOptions,
    seq: &mut Sequence,
    ids: &mut Vec<u16>,
) -> Result<(), IoError> {
    let base = path.parent().unwrap_or(Path::new("."));
    let v = read_json(path)?;
    let top = Obj::root(path, &v)?;
    let explicit_unit = top.opt_f64("depth_unit_scale_factor")?;
    let depth_unit = explicit_unit.unwrap_or(DEFAULT_DEPTH_UNIT_M);
    let test_names = string_list(&top, "test_filenames")?;
    let train_names = string_list(&top, "train_filenames")?;
    let in_list = |list: &Option<Vec<String>>, p: &str| {
        list.as_ref().is_some_and(|l| {
            l.iter()
                .any(|n| n == p || Path::new(n).file_name() == Path::new(p).file_name())
        })
    };
    for (i, f) in top.objects("frames")?.into_iter().enumerate() {
        let k = intrinsics(&f, &top)?;
        pose::check_intrinsics(&k, path, &f.name("fl_x/fl_y/cx/cy"), &f.name("w/h"))?;
        let mut c2w = f.mat4("transform_matrix")?;
        for row in c2w.iter_mut().take(3) {
            row[1] = -row[1];
            row[2] = -row[2];
        }
        let camera = pose::from_c2w_opencv(k, c2w, path, &f.name("transform_matrix"))?;
        let file = f.str("file_path")?;
        let frame = frame_number(file).unwrap_or(i as u32);
        let split = if in_list(&test_names, file) && !in_list(&train_names, file) {
            Split::Test
        } else {
            Split::Train
        };
        let size_check =
            |w: u32, h: u32, p: &Path, field: &str| IoError::check_size(w, h, &k, p, f.name(field));
        let rgb = if opts.rgb.yes() {
            let p = resolve(base, file);
            let img = read_rgb8(&p)?;
            size_check(img.width, img.height, &p, "w/h")?;
            Some(img)
        } else {
            None
        };
        let instance = match (opts.masks.yes(), f.opt_str("mask_path")?) {
            (true, Some(mp)) => {
                let p = resolve(base, mp);
                let img = read_instance_mask(&p)?;
                size_check(img.width, img.height, &p, "w/h")?;
                let found = img.ids();
                opts.check_ids(&found, &p, &f.name("mask_path"))?;
                if state == State::T0 {
                    ids.extend(found);
                }
                Some(img)
            }
            _ => None,
        };
        let depth = match (opts.depth.yes(), f.opt_str("depth_file_path")?) {
            (true, Some(dp)) => {
                let p = resolve(base, dp);
                let d = if p.extension().is_some_and(|e| e == "npy") {
                    let mut d = read_npy_f32(&p)?;
                    let s = explicit_unit.unwrap_or(1.0);
                    d.data.iter_mut().for_each(|v| *v = (*v as f64 * s) as f32);
                    d
                } else {
                    read_depth_png(&p, depth_unit * 1000.0)?
                };
                size_check(d.width, d.height, &p, "w/h")?;
                Some(d)
            }
            _ => None,
        };
        let name = format!("{}/{frame:06}", split.folder(state));
        seq.views_mut(split, state).push(View {
            name,
            frame,
            camera,
            rgb,
            instance,
            depth,
        });
    }
    Ok(())
}

/// Reads `root/transforms.json` (and `root/transforms_t1.json` if present).
pub fn read_nerfstudio(root: &Path, opts: &LoadOptions) -> Result<Sequence, IoError> {
    let mut seq = Sequence {
        root: root.into(),
        train_selection: crate::view::TrainSelection::Listed,
        ..Default::default()
    };
    let mut ids = Vec::new();
    read_file(&root.join(T0_FILE), State::T0, opts, &mut seq, &mut ids)?;
    let t1 = root.join(T1_FILE);
    if t1.is_file() {
        read_file(&t1, State::T1, opts, &mut seq, &mut ids)?;
    }
    ids.sort_unstable();
    ids.dedup();
    seq.object_ids = ids;
    for state in [State::T0, State::T1] {
        for split in [Split::Train, Split::Test] {
            let views = seq.views_mut(split, state);
            views.sort_by_key(|v| v.frame);
            if let Some(w) = views.windows(2).find(|w| w[0].frame == w[1].frame) {
                let file = if state == State::T0 { T0_FILE } else { T1_FILE };
                return Err(IoError::field(
                    root.join(file),
                    "frames[].file_path",
                    format!(
                        "two {} images are frame {} (the number ending the file name; a name \
                         without one is numbered by its position in `frames`): give every image \
                         its own number",
                        split.folder(state),
                        w[0].frame
                    ),
                ));
            }
        }
    }
    Ok(seq)
}
