//! A perturbed copy of a sequence: what a robot's segmenter and calibration give instead of exact
//! masks and poses (`trand perturb`).
//!
//! Only the training inputs (`train_0`, `train_1`) change; the test views are copied exactly, so the
//! evaluation measures what the imperfection costs. Each perturbation is chosen by its own flag:
//! * [`IdMode::PerView`]: each view numbers its instances by its own random permutation of `1..=N`
//!   (N = the objects of the sequence), as a segmenter without video propagation does;
//! * `boundary_px = B`: every instance mask is eroded or dilated (random sign) by a random radius in
//!   `1..=B` pixels (a disc), and two small blobs (radius 1–2 px) are stuck to its edge;
//! * `miss = M`: M (view, object) pairs of the t = 0 training views lose that object's mask;
//! * `pose = (deg, mm)`: every training camera is turned by `deg` degrees about a random axis
//!   through its centre and moved by `mm` millimetres in a random direction;
//! * `shift_mm = s`: every training camera sees the world moved by `s` (`t' = t + R s`): the part of
//!   a calibration error all views share, which no image shows (see `trand_train::pose`).
//!
//! Random draws come from one PCG stream per view, seeded from the seed and the view's name, so the
//! copy is the same for a seed whatever the order the views are processed in. The output is BOP
//! (`scene_camera.json`, `rgb/`, `depth/` in millimetres, `mask_visib/{frame}_{id}.png`), written
//! under a temporary name and renamed when complete; `perturbation.json` lists what was done to
//! every view.

use std::path::Path;

use glam::{DMat3, DVec3};
use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64;
use trand_core::Camera;

use crate::error::IoError;
use crate::image::{Image, InstanceMap};
use crate::view::{Sequence, Split, State, View};
use crate::write::{RunDir, write_atomic, write_depth_png_mm, write_gray8_png, write_rgb_png};

/// How the training masks number their instances.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum IdMode {
    /// As the sequence does: one id per object in every view.
    Consistent,
    /// A random permutation of `1..=N` per view.
    PerView,
}

/// What to do to the training views.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Perturbation {
    pub seed: u64,
    pub ids: IdMode,
    /// Largest erosion/dilation radius in pixels (0 = masks untouched).
    pub boundary_px: u32,
    /// Number of (view, object) masks removed from the t = 0 training views.
    pub miss: u32,
    /// Rotation (degrees) and translation (millimetres) error per training camera.
    pub pose: Option<(f64, f64)>,
    /// World shift (millimetres) every training camera sees, after `pose`.
    pub shift_mm: Option<[f64; 3]>,
}

/// What was done to one view.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ViewReport {
    pub view: String,
    /// `(original id, id written)`.
    pub id_map: Vec<(u16, u16)>,
    /// `(id, radius)`: positive dilates, negative erodes.
    pub boundary: Vec<(u16, i32)>,
    /// Original ids whose mask was removed.
    pub missed: Vec<u16>,
    pub rotation_deg: f64,
    pub translation_mm: f64,
}

fn view_rng(seed: u64, name: &str) -> Pcg64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325 ^ seed;
    for b in name.bytes() {
        h ^= b as u64;
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    Pcg64::seed_from_u64(h)
}

/// Pixels within `r` (Euclidean) of a pixel of `mask`, or (for `r < 0`) whose `|r|`-disc is inside it.
fn morph(mask: &[bool], w: usize, h: usize, r: i32) -> Vec<bool> {
    let a = r.abs();
    let disc: Vec<(i32, i32)> = (-a..=a)
        .flat_map(|dy| (-a..=a).map(move |dx| (dx, dy)))
        .filter(|(dx, dy)| dx * dx + dy * dy <= a * a)
        .collect();
    let at = |x: i32, y: i32| {
        x >= 0
            && y >= 0
            && (x as usize) < w
            && (y as usize) < h
            && mask[y as usize * w + x as usize]
    };
    (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as i32, (i / w) as i32);
            if r >= 0 {
                disc.iter().any(|(dx, dy)| at(x + dx, y + dy))
            } else {
                disc.iter().all(|(dx, dy)| at(x + dx, y + dy))
            }
        })
        .collect()
}

/// Erodes or dilates each object's mask and sticks two blobs to its edge; dilation only claims
/// background pixels.
fn perturb_boundary(inst: &mut InstanceMap, max_px: u32, rng: &mut Pcg64) -> Vec<(u16, i32)> {
    let (w, h) = (inst.width as usize, inst.height as usize);
    let mut done = Vec::new();
    for id in inst.ids() {
        let mask = inst.mask(id);
        let r = rng.random_range(1..=max_px as i32) * if rng.random::<bool>() { 1 } else { -1 };
        let mut new = morph(&mask, w, h, r);
        let edge: Vec<usize> = (0..w * h)
            .filter(|&i| mask[i] && morph_edge(&mask, w, h, i))
            .collect();
        for _ in 0..2 {
            if edge.is_empty() {
                break;
            }
            let c = edge[rng.random_range(0..edge.len())];
            let br = rng.random_range(1..=2);
            let mut blob = vec![false; w * h];
            blob[c] = true;
            for (i, b) in morph(&blob, w, h, br).into_iter().enumerate() {
                new[i] |= b;
            }
        }
        for (px, &inside) in inst.data.iter_mut().zip(&new) {
            if inside && (*px == 0 || *px == id) {
                *px = id;
            } else if !inside && *px == id {
                *px = 0;
            }
        }
        done.push((id, r));
    }
    done
}

/// Whether pixel `i` of `mask` has a 4-neighbour outside it.
fn morph_edge(mask: &[bool], w: usize, h: usize, i: usize) -> bool {
    let (x, y) = (i % w, i / w);
    x == 0
        || y == 0
        || x + 1 == w
        || y + 1 == h
        || !mask[i - 1]
        || !mask[i + 1]
        || !mask[i - w]
        || !mask[i + w]
}

/// A unit vector uniform on the sphere.
fn direction(rng: &mut Pcg64) -> DVec3 {
    let z: f64 = rng.random_range(-1.0..1.0);
    let phi: f64 = rng.random_range(0.0..std::f64::consts::TAU);
    let s = (1.0 - z * z).sqrt();
    DVec3::new(s * phi.cos(), s * phi.sin(), z)
}

/// The camera turned by `deg` about a random axis through its centre and moved `mm` millimetres.
fn perturb_pose(cam: &Camera, deg: f64, mm: f64, rng: &mut Pcg64) -> Camera {
    let r_c2w = cam.rotation().transpose();
    let turn = DMat3::from_axis_angle(direction(rng), deg.to_radians());
    let r_c2w = turn * r_c2w;
    let centre = cam.center() + direction(rng) * (mm / 1000.0);
    let r_w2c = r_c2w.transpose();
    Camera::from_glam(cam.intrinsics, r_w2c, -(r_w2c * centre))
}

/// Applies `p` to one training view.
fn perturb_view(view: &mut View, p: &Perturbation, all_ids: &[u16], missed: &[u16]) -> ViewReport {
    let mut rng = view_rng(p.seed, &view.name);
    let mut rep = ViewReport {
        view: view.name.clone(),
        id_map: Vec::new(),
        boundary: Vec::new(),
        missed: missed.to_vec(),
        rotation_deg: 0.0,
        translation_mm: 0.0,
    };
    if let Some(inst) = view.instance.as_mut() {
        for v in inst.data.iter_mut() {
            if missed.contains(v) {
                *v = 0;
            }
        }
        if p.boundary_px > 0 {
            rep.boundary = perturb_boundary(inst, p.boundary_px, &mut rng);
        }
        if p.ids == IdMode::PerView {
            let mut new: Vec<u16> = (1..=all_ids.len() as u16).collect();
            for i in (1..new.len()).rev() {
                new.swap(i, rng.random_range(0..=i));
            }
            rep.id_map = all_ids.iter().copied().zip(new).collect();
            let mut lut = vec![0u16; u16::MAX as usize + 1];
            rep.id_map.iter().for_each(|&(a, b)| lut[a as usize] = b);
            inst.data.iter_mut().for_each(|v| *v = lut[*v as usize]);
        }
    }
    if let Some((deg, mm)) = p.pose {
        view.camera = perturb_pose(&view.camera, deg, mm, &mut rng);
        rep.rotation_deg = deg;
        rep.translation_mm = mm;
    }
    if let Some(s) = p.shift_mm {
        view.camera = view
            .camera
            .seeing_world_moved(DVec3::from_array(s) / 1000.0);
    }
    rep
}

/// Writes one split as BOP (depth in millimetres, `depth_scale` 1).
fn write_split(dir: &Path, views: &[View]) -> Result<(), IoError> {
    let mut cams = serde_json::Map::new();
    for v in views {
        let k = &v.camera.intrinsics;
        let r = v.camera.r_w2c;
        cams.insert(
            v.frame.to_string(),
            serde_json::json!({
                "cam_K": [k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0],
                "cam_R_w2c": r.iter().flatten().collect::<Vec<_>>(),
                "cam_t_w2c": v.camera.t_w2c.map(|t| t * 1000.0),
                "depth_scale": 1.0, "width": k.width, "height": k.height,
            }),
        );
        let name = format!("{:06}", v.frame);
        if let Some(rgb) = &v.rgb {
            write_rgb_png(&dir.join(format!("rgb/{name}.png")), rgb)?;
        }
        if let Some(d) = &v.depth {
            write_depth_png_mm(&dir.join(format!("depth/{name}.png")), d)?;
        }
        if let Some(inst) = &v.instance {
            for id in inst.ids() {
                let m = inst
                    .data
                    .iter()
                    .map(|&i| if i == id { 255 } else { 0 })
                    .collect();
                let m = Image::from_vec(inst.width, inst.height, 1, m).expect("sizes agree");
                write_gray8_png(&dir.join(format!("mask_visib/{name}_{id:06}.png")), &m)?;
            }
        }
    }
    for sub in ["rgb", "depth", "mask_visib"] {
        std::fs::create_dir_all(dir.join(sub)).map_err(|e| IoError::io(dir.join(sub), e))?;
    }
    let json = serde_json::to_vec_pretty(&cams).expect("JSON values serialise");
    write_atomic(&dir.join("scene_camera.json"), &json)
}

/// Copies a folder tree byte for byte (the test views of a BOP sequence).
fn copy_dir(from: &Path, to: &Path) -> Result<(), IoError> {
    std::fs::create_dir_all(to).map_err(|e| IoError::io(to, e))?;
    for e in std::fs::read_dir(from).map_err(|e| IoError::io(from, e))? {
        let e = e.map_err(|e| IoError::io(from, e))?;
        let (src, dst) = (e.path(), to.join(e.file_name()));
        if src.is_dir() {
            copy_dir(&src, &dst)?;
        } else {
            std::fs::copy(&src, &dst).map_err(|err| IoError::io(&src, err))?;
        }
    }
    Ok(())
}

/// Writes the perturbed copy of `seq` to `out`, which must not exist. The test views of a BOP
/// sequence are copied byte for byte; those of other layouts are rewritten as BOP.
pub fn write_perturbed(
    seq: &Sequence,
    out: &Path,
    p: &Perturbation,
) -> Result<Vec<ViewReport>, IoError> {
    let dir = RunDir::create(out)?;
    let mut seq = seq.clone();
    let mut rng = Pcg64::seed_from_u64(p.seed ^ 0x6d69_7373);
    // The missed masks: distinct (view, object) pairs of the t = 0 training views.
    let mut pairs: Vec<(usize, u16)> = seq
        .train_t0
        .iter()
        .enumerate()
        .flat_map(|(i, v)| {
            v.instance
                .iter()
                .flat_map(move |m| m.ids().into_iter().map(move |id| (i, id)))
        })
        .collect();
    let mut missed: Vec<Vec<u16>> = vec![Vec::new(); seq.train_t0.len()];
    for _ in 0..p.miss.min(pairs.len() as u32) {
        let (i, id) = pairs.swap_remove(rng.random_range(0..pairs.len()));
        missed[i].push(id);
    }
    let ids = seq.object_ids.clone();
    let mut reports = Vec::new();
    for (i, v) in seq.train_t0.iter_mut().enumerate() {
        reports.push(perturb_view(v, p, &ids, &missed[i]));
    }
    for v in seq.train_t1.iter_mut() {
        reports.push(perturb_view(v, p, &ids, &[]));
    }
    let bop = crate::bop::is_bop(&seq.root);
    for state in [State::T0, State::T1] {
        for split in [Split::Train, Split::Test] {
            let views = seq.views(split, state);
            let target = dir.path().join(split.folder(state));
            let source = seq.root.join(split.folder(state));
            if bop && split == Split::Test && source.is_dir() {
                copy_dir(&source, &target)?;
            } else if !views.is_empty() || (split, state) == (Split::Train, State::T0) {
                write_split(&target, views)?;
            }
        }
    }
    let src_json = seq.root.join("sequence.json");
    if src_json.is_file() {
        std::fs::copy(&src_json, dir.path().join("sequence.json"))
            .map_err(|e| IoError::io(&src_json, e))?;
    } else if let Some(removed) = &seq.removed_ids {
        let j = serde_json::json!({ "removed_obj_ids": removed });
        write_atomic(&dir.path().join("sequence.json"), j.to_string().as_bytes())?;
    }
    let report = serde_json::json!({ "source": seq.root, "perturbation": p, "views": reports });
    let json = serde_json::to_vec_pretty(&report).expect("JSON values serialise");
    write_atomic(&dir.path().join("perturbation.json"), &json)?;
    dir.commit()?;
    Ok(reports)
}

#[cfg(test)]
mod tests {
    use super::*;
    use trand_core::Intrinsics;

    fn view(name: &str) -> View {
        let mut inst = Image::filled(40, 30, 1, 0u16);
        for y in 5..25 {
            for x in 5..15 {
                inst.set(x, y, 0, 1);
            }
            for x in 22..35 {
                inst.set(x, y, 0, 2);
            }
        }
        View {
            name: name.into(),
            frame: 1,
            camera: Camera::look_at(
                Intrinsics::centered(40.0, 40, 30),
                DVec3::new(0.0, -1.0, 0.5),
                DVec3::ZERO,
                DVec3::Z,
            ),
            rgb: None,
            instance: Some(inst),
            depth: None,
        }
    }

    fn all() -> Perturbation {
        Perturbation {
            seed: 9,
            ids: IdMode::PerView,
            boundary_px: 3,
            miss: 0,
            pose: Some((0.5, 3.0)),
            shift_mm: None,
        }
    }

    #[test]
    fn a_shifted_camera_sees_each_point_where_the_shifted_point_was() {
        let mut v = view("v");
        let before = v.camera;
        let p = Perturbation {
            ids: IdMode::Consistent,
            boundary_px: 0,
            pose: None,
            shift_mm: Some([4.0, -1.0, 2.5]),
            ..all()
        };
        perturb_view(&mut v, &p, &[1, 2], &[]);
        let x = DVec3::new(0.02, 0.01, 0.04);
        let (u, w, _) = v.camera.project(x).expect("in front");
        let (u0, w0, _) = before
            .project(x + DVec3::new(0.004, -0.001, 0.0025))
            .expect("in front");
        assert!((u - u0).abs() < 1e-9 && (w - w0).abs() < 1e-9);
    }

    #[test]
    fn the_same_seed_gives_the_same_perturbation_and_another_seed_another() {
        let (mut a, mut b, mut c) = (
            view("train_0/000001"),
            view("train_0/000001"),
            view("train_0/000001"),
        );
        perturb_view(&mut a, &all(), &[1, 2], &[]);
        perturb_view(&mut b, &all(), &[1, 2], &[]);
        perturb_view(&mut c, &Perturbation { seed: 10, ..all() }, &[1, 2], &[]);
        assert_eq!(a.instance, b.instance);
        assert_eq!(a.camera, b.camera);
        assert_ne!(a.camera, c.camera);
    }

    #[test]
    fn pose_error_has_the_asked_angle_and_distance() {
        let v0 = view("v");
        let mut v = view("v");
        perturb_view(
            &mut v,
            &Perturbation {
                ids: IdMode::Consistent,
                boundary_px: 0,
                ..all()
            },
            &[1, 2],
            &[],
        );
        let moved_mm = (v.camera.center() - v0.camera.center()).length() * 1000.0;
        assert!((moved_mm - 3.0).abs() < 1e-6, "{moved_mm}");
        let rel = v.camera.rotation() * v0.camera.rotation().transpose();
        let angle = ((rel.x_axis.x + rel.y_axis.y + rel.z_axis.z - 1.0) / 2.0)
            .clamp(-1.0, 1.0)
            .acos();
        assert!((angle.to_degrees() - 0.5).abs() < 1e-6);
        assert_eq!(v.instance, v0.instance);
    }

    #[test]
    fn boundaries_move_by_at_most_the_radius_and_ids_stay_a_permutation() {
        let v0 = view("v");
        let mut v = view("v");
        let rep = perturb_view(&mut v, &all(), &[1, 2], &[]);
        let inst = v.instance.unwrap();
        let mut new_ids: Vec<u16> = rep.id_map.iter().map(|m| m.1).collect();
        new_ids.sort();
        assert_eq!(new_ids, vec![1, 2]);
        assert_eq!(inst.ids(), vec![1, 2]);
        for &(id, r) in &rep.boundary {
            assert!((1..=3).contains(&r.abs()));
            let new_id = rep.id_map.iter().find(|m| m.0 == id).unwrap().1;
            let before = v0.instance.as_ref().unwrap().mask(id);
            let after = inst.mask(new_id);
            let changed = before.iter().zip(&after).filter(|(a, b)| a != b).count();
            // A 10x20 or 13x20 rectangle's outline moved by r plus two blobs of at most 13 pixels.
            assert!(
                changed > 0
                    && changed
                        <= 2 * (13 + 20 + 2 * r.unsigned_abs() as usize)
                            * r.unsigned_abs() as usize
                            + 26
            );
        }
    }

    #[test]
    fn a_missed_object_leaves_its_view_and_nothing_else() {
        let mut v = view("v");
        let p = Perturbation {
            ids: IdMode::Consistent,
            boundary_px: 0,
            pose: None,
            ..all()
        };
        perturb_view(&mut v, &p, &[1, 2], &[2]);
        assert_eq!(v.instance.unwrap().ids(), vec![1]);
    }
}
