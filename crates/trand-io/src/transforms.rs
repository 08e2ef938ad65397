//! Reader of the TRAN-D authors' camera files, `transforms_sparse_{train,test}[_01].json`.
//!
//! ```text
//! { "num_obj": int, "hand_eye_init": 4x4 (optional, default I),
//!   "frames": [ { "original_path": RGB png, "file_path": colour-mask png (RGB fallback),
//!                 "class_path": uint8 label png (0 = background, ids 1..), "depth_path": uint16 png (mm),
//!                 "transform_matrix": 4x4 camera-to-world, OpenCV axes (x right, y down, z forward), metres,
//!                 "cam": { fl_x, fl_y, cx, cy, w, h, camera_angle_x }, "obj_idx": [ids] } ] }
//! ```
//! * The camera is `c2w = transform_matrix · hand_eye_init`; there is **no** OpenGL flip.
//! * Intrinsics come from `cam` (or the same keys at the top level). `cx, cy` are the BOP values, so
//!   already in trand's integer-pixel-centre convention. Without `fl_x`, `fx = fy = w / (2 tan(camera_angle_x/2))`
//!   and the principal point is centred.
//! * Depth PNGs are divided by 1000 (the authors' code ignores BOP's `depth_scale`).
//! * `_01` files are the t=1 state. View names are `train_0/000003` etc., the frame being the number in
//!   the RGB file name (else the position in `frames`).
//! * Paths are absolute on the authors' machine; see [`crate::paths`] for how they are re-rooted.

use std::path::Path;

use trand_core::Intrinsics;

use crate::error::IoError;
use crate::image::{Image, read_depth_png, read_instance_mask, read_rgb8};
use crate::json::{Obj, read_json};
use crate::paths::{frame_number, resolve};
use crate::pose;
use crate::view::{LoadOptions, Sequence, Split, State, View};

/// Depth PNG unit assumed by the authors' loader: millimetres, so one unit is 1 mm.
const DEPTH_MM_PER_UNIT: f64 = 1.0;

/// File name of the camera file of a split and state.
pub fn file_name(split: Split, state: State) -> &'static str {
    match (split, state) {
        (Split::Train, State::T0) => "transforms_sparse_train.json",
        (Split::Train, State::T1) => "transforms_sparse_train_01.json",
        (Split::Test, State::T0) => "transforms_sparse_test.json",
        (Split::Test, State::T1) => "transforms_sparse_test_01.json",
    }
}

pub fn is_transforms(root: &Path) -> bool {
    root.join(file_name(Split::Train, State::T0)).is_file()
}

fn intrinsics(f: &Obj, top: &Obj) -> Result<Intrinsics, IoError> {
    let c = if f.opt("cam").is_some() {
        f.child("cam")?
    } else {
        Obj {
            path: top.path,
            at: top.at.clone(),
            value: top.value,
        }
    };
    let w = c.opt_u32("w")?.ok_or_else(|| c.err("w", "missing"))?;
    let h = c.opt_u32("h")?.ok_or_else(|| c.err("h", "missing"))?;
    match c.opt_f64("fl_x")? {
        Some(fx) => Ok(Intrinsics {
            fx,
            fy: c.opt_f64("fl_y")?.unwrap_or(fx),
            cx: c.f64("cx")?,
            cy: c.f64("cy")?,
            width: w,
            height: h,
        }),
        None => {
            let a = c.f64("camera_angle_x")?;
            Ok(Intrinsics::centered(0.5 * w as f64 / (0.5 * a).tan(), w, h))
        }
    }
}

fn read_file(
    path: &Path,
    folder: &str,
    opts: &LoadOptions,
    ids: &mut Vec<u16>,
) -> Result<Vec<View>, IoError> {
    let base = path.parent().unwrap_or(Path::new("."));
    let v = read_json(path)?;
    let top = Obj::root(path, &v)?;
    let hand_eye = if top.opt("hand_eye_init").is_some() {
        Some(top.mat4("hand_eye_init")?)
    } else {
        None
    };
    let mut views = Vec::new();
    for (i, f) in top.objects("frames")?.into_iter().enumerate() {
        let k = intrinsics(&f, &top)?;
        pose::check_intrinsics(&k, path, &f.name("cam"), &f.name("w/h"))?;
        let mut c2w = f.mat4("transform_matrix")?;
        if let Some(h) = &hand_eye {
            c2w = pose::mat4_mul(&c2w, h);
        }
        let camera = pose::from_c2w_opencv(k, c2w, path, &f.name("transform_matrix"))?;
        let rgb_field = if f.opt("original_path").is_some() {
            "original_path"
        } else {
            "file_path"
        };
        let rgb_rel = f.str(rgb_field)?;
        let frame = frame_number(rgb_rel).unwrap_or(i as u32);
        let size_check =
            |w: u32, h: u32, p: &Path| IoError::check_size(w, h, &k, p, f.name("cam.w/h"));
        let rgb = if opts.rgb.yes() {
            let p = resolve(base, rgb_rel);
            let img = read_rgb8(&p)?;
            size_check(img.width, img.height, &p)?;
            Some(img)
        } else {
            None
        };
        let instance = match (opts.masks.yes(), f.opt_str("class_path")?) {
            (true, Some(cp)) => {
                let p = resolve(base, cp);
                let img: Image<u16> = read_instance_mask(&p)?;
                size_check(img.width, img.height, &p)?;
                let found = img.ids();
                opts.check_ids(&found, &p, "class_path")?;
                ids.extend(found);
                Some(img)
            }
            _ => None,
        };
        if let Some(list) = f.opt("obj_idx") {
            let a = list
                .as_array()
                .ok_or_else(|| f.err("obj_idx", "expected an array"))?;
            let found: Vec<u16> = a
                .iter()
                .map(|x| {
                    x.as_u64()
                        .and_then(|u| u16::try_from(u).ok())
                        .ok_or_else(|| f.err("obj_idx", "expected object ids"))
                })
                .collect::<Result<_, _>>()?;
            let found: Vec<u16> = found.into_iter().filter(|&id| id != 0).collect();
            opts.check_ids(&found, path, &f.name("obj_idx"))?;
            ids.extend(found);
        }
        let depth = match (opts.depth.yes(), f.opt_str("depth_path")?) {
            (true, Some(dp)) => {
                let p = resolve(base, dp);
                let d = read_depth_png(&p, DEPTH_MM_PER_UNIT)?;
                size_check(d.width, d.height, &p)?;
                Some(d)
            }
            _ => None,
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

/// Reads the authors' camera files in `root` (the t=0 train file must exist; the others are optional).
pub fn read_transforms(root: &Path, opts: &LoadOptions) -> Result<Sequence, IoError> {
    let mut seq = Sequence {
        root: root.into(),
        ..Default::default()
    };
    for state in [State::T0, State::T1] {
        let mut ids = Vec::new();
        for split in [Split::Train, Split::Test] {
            let path = root.join(file_name(split, state));
            if !path.is_file() {
                if (split, state) == (Split::Train, State::T0) {
                    return Err(IoError::Missing {
                        path,
                        what: "t=0 training cameras".into(),
                    });
                }
                continue;
            }
            *seq.views_mut(split, state) = read_file(&path, split.folder(state), opts, &mut ids)?;
        }
        if state == State::T0 {
            ids.sort_unstable();
            ids.dedup();
            seq.object_ids = ids;
        }
    }
    Ok(seq)
}
