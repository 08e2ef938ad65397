//! Imperfect training inputs, made on purpose: what a robot's segmenter and calibration give instead
//! of exact masks and poses, so that their cost can be measured.
//!
//! [`perturb_bop`] copies a BOP sequence and degrades its training splits (`train_0`, `train_1`);
//! test splits stay exact, so evaluation still compares against the truth. Each [`Imperfection`]
//! draws from its own seeded stream, so the same seed perturbs a view the same way whether an
//! imperfection is applied alone or together with the others:
//!
//! * [`Imperfection::Ids`]: per-image instance ids. Every view's masks are renamed by a random
//!   permutation of the sequence's t = 0 object ids, as a segmenter without tracking numbers its
//!   instances: the ids still lie in 1..N, but they no longer name the same object in two views.
//! * [`Imperfection::Boundary`]: every mask is eroded or dilated by 1–3 px (a disc), then 1–3 blobs
//!   of radius 2–4 px centred on boundary pixels are added or cut out.
//! * [`Imperfection::Miss`]: one object's mask is deleted from one of the given training frames.
//! * [`Imperfection::Pose`]: every camera is turned by a fixed angle about a random axis through its
//!   centre and its centre moved by a fixed distance in a random direction (hand-eye calibration
//!   error).
//!
//! `perturbation.json` in the copy records what was done to every view.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use glam::{DMat3, DQuat, DVec3};
use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64;
use serde::Serialize;
use serde_json::Value;

use crate::SynthError;

/// One kind of input error.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Imperfection {
    Ids,
    Boundary,
    Miss,
    Pose,
}

impl Imperfection {
    /// Seed of this imperfection's own random stream.
    fn stream(self, seed: u64) -> Pcg64 {
        let salt = match self {
            Imperfection::Ids => 0x6964_7300,
            Imperfection::Boundary => 0x626f_756e,
            Imperfection::Miss => 0x6d69_7373,
            Imperfection::Pose => 0x706f_7365,
        };
        Pcg64::seed_from_u64(seed ^ salt)
    }
}

/// What to degrade and how much.
#[derive(Clone, Debug, Serialize)]
pub struct Perturbation {
    pub imperfections: Vec<Imperfection>,
    pub seed: u64,
    /// Largest erosion or dilation of a mask boundary (px); each mask draws from 1..=this.
    pub boundary_px: u32,
    /// Frames of `train_0` one of which loses one object's mask (the views a run trains on).
    pub miss_frames: Vec<u32>,
    /// Rotation of every camera (degrees) and displacement of its centre (metres).
    pub pose_deg: f64,
    pub pose_m: f64,
}

impl Perturbation {
    /// The levels: 1–3 px boundaries, a miss among the six ring views, 0.5° and 3 mm.
    pub fn new(imperfections: Vec<Imperfection>, seed: u64) -> Self {
        Self {
            imperfections,
            seed,
            boundary_px: 3,
            miss_frames: vec![1, 3, 5, 7, 9, 11],
            pose_deg: 0.5,
            pose_m: 0.003,
        }
    }

    fn has(&self, i: Imperfection) -> bool {
        self.imperfections.contains(&i)
    }
}

/// What was done, per split and frame.
#[derive(Clone, Debug, Default, Serialize)]
pub struct PerturbReport {
    /// `split/frame` → (original id → written id).
    pub ids: BTreeMap<String, BTreeMap<u16, u16>>,
    /// `(frame, object id)` whose `train_0` mask was deleted.
    pub missed: Option<(u32, u16)>,
    /// `split/frame` → (boundary offset in px, negative = eroded).
    pub boundary: BTreeMap<String, Vec<(u16, i32)>>,
}

/// A permutation of `ids` (sorted, distinct) drawn from `rng`: original → new.
pub fn permute_ids(ids: &[u16], rng: &mut Pcg64) -> BTreeMap<u16, u16> {
    let mut shuffled = ids.to_vec();
    for i in (1..shuffled.len()).rev() {
        let j = rng.random_range(0..=i);
        shuffled.swap(i, j);
    }
    ids.iter().copied().zip(shuffled).collect()
}

/// Erodes (`offset < 0`) or dilates a row-major `w`-wide mask by a disc of radius `|offset|`.
pub fn offset_mask(mask: &[bool], w: usize, offset: i32) -> Vec<bool> {
    let h = mask.len() / w;
    let r = offset.unsigned_abs() as i64;
    let grow = offset > 0;
    (0..mask.len())
        .map(|p| {
            let (x, y) = ((p % w) as i64, (p / w) as i64);
            // Dilation: any pixel of the disc inside; erosion: every pixel of the disc inside (the
            // image border counts as outside).
            let mut any = false;
            let mut all = true;
            for dy in -r..=r {
                for dx in -r..=r {
                    if dx * dx + dy * dy > r * r {
                        continue;
                    }
                    let (u, v) = (x + dx, y + dy);
                    let inside = u >= 0
                        && v >= 0
                        && (u as usize) < w
                        && (v as usize) < h
                        && mask[v as usize * w + u as usize];
                    any |= inside;
                    all &= inside;
                }
            }
            if grow { any } else { all }
        })
        .collect()
}

/// Boundary pixels of a mask: inside, with a 4-neighbour outside (or on the image border).
fn boundary_pixels(mask: &[bool], w: usize) -> Vec<usize> {
    let h = mask.len() / w;
    (0..mask.len())
        .filter(|&p| {
            let (x, y) = (p % w, p / w);
            mask[p]
                && (x == 0
                    || y == 0
                    || x + 1 == w
                    || y + 1 == h
                    || !mask[p - 1]
                    || !mask[p + 1]
                    || !mask[p - w]
                    || !mask[p + w])
        })
        .collect()
}

/// A segmenter's boundary: offset by ±1..=`max_px` px, then 1–3 blobs added or cut at the edge.
/// Returns the mask and the offset applied.
pub fn perturb_boundary(mask: &[bool], w: usize, max_px: u32, rng: &mut Pcg64) -> (Vec<bool>, i32) {
    let r = rng.random_range(1..=max_px.max(1)) as i32;
    let offset = if rng.random_bool(0.5) { r } else { -r };
    let mut out = offset_mask(mask, w, offset);
    let edge = boundary_pixels(mask, w);
    let blobs = rng.random_range(1..=3u32);
    let h = mask.len() / w;
    for _ in 0..blobs {
        if edge.is_empty() {
            break;
        }
        let c = edge[rng.random_range(0..edge.len())];
        let radius: i64 = rng.random_range(2..=4);
        let fill = rng.random_bool(0.5);
        let (cx, cy) = ((c % w) as i64, (c / w) as i64);
        for dy in -radius..=radius {
            for dx in -radius..=radius {
                let (u, v) = (cx + dx, cy + dy);
                if dx * dx + dy * dy <= radius * radius
                    && u >= 0
                    && v >= 0
                    && (u as usize) < w
                    && (v as usize) < h
                {
                    out[v as usize * w + u as usize] = fill;
                }
            }
        }
    }
    (out, offset)
}

/// A camera `(R_w2c, t_w2c)` turned by `deg` about a random axis through its centre and moved by
/// `dist` (same unit as `t`) in a random direction.
pub fn perturb_pose(
    r_w2c: DMat3,
    t_w2c: DVec3,
    deg: f64,
    dist: f64,
    rng: &mut Pcg64,
) -> (DMat3, DVec3) {
    let unit = |rng: &mut Pcg64| loop {
        let v = DVec3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        );
        let n = v.length();
        if n > 0.1 && n <= 1.0 {
            return v / n;
        }
    };
    let axis = unit(rng);
    let dir = unit(rng);
    let centre = -(r_w2c.transpose() * t_w2c);
    let r = DMat3::from_quat(DQuat::from_axis_angle(axis, deg.to_radians())) * r_w2c;
    let c = centre + dir * dist;
    (r, -(r * c))
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> SynthError + '_ {
    move |source| SynthError::Io {
        path: path.into(),
        source,
    }
}

fn copy_tree(src: &Path, dst: &Path) -> Result<(), SynthError> {
    std::fs::create_dir_all(dst).map_err(io_err(dst))?;
    let mut entries: Vec<_> = std::fs::read_dir(src)
        .map_err(io_err(src))?
        .collect::<Result<_, _>>()
        .map_err(io_err(src))?;
    entries.sort_by_key(|e| e.file_name());
    for e in entries {
        let (from, to) = (e.path(), dst.join(e.file_name()));
        if from.is_dir() {
            copy_tree(&from, &to)?;
        } else {
            std::fs::copy(&from, &to).map_err(io_err(&to))?;
        }
    }
    Ok(())
}

/// Mask files of a split's `mask_visib/`: frame → [(object id, path)], sorted.
fn masks(split: &Path) -> Result<BTreeMap<u32, Vec<(u16, PathBuf)>>, SynthError> {
    let dir = split.join("mask_visib");
    let mut out: BTreeMap<u32, Vec<(u16, PathBuf)>> = BTreeMap::new();
    if !dir.is_dir() {
        return Ok(out);
    }
    for e in std::fs::read_dir(&dir).map_err(io_err(&dir))? {
        let e = e.map_err(io_err(&dir))?;
        let name = e.file_name().to_string_lossy().into_owned();
        let Some((f, o)) = name.strip_suffix(".png").and_then(|s| s.split_once('_')) else {
            continue;
        };
        if let (Ok(f), Ok(o)) = (f.parse::<u32>(), o.parse::<u16>()) {
            out.entry(f).or_default().push((o, e.path()));
        }
    }
    for v in out.values_mut() {
        v.sort();
    }
    Ok(out)
}

fn read_mask(path: &Path) -> Result<(Vec<bool>, u32, u32), SynthError> {
    let img = image::open(path)
        .map_err(|source| SynthError::Png {
            path: path.into(),
            source,
        })?
        .into_luma8();
    let (w, h) = img.dimensions();
    Ok((img.into_raw().into_iter().map(|v| v > 127).collect(), w, h))
}

fn write_mask(path: &Path, mask: &[bool], w: u32, h: u32) -> Result<(), SynthError> {
    let data = mask.iter().map(|&b| if b { 255 } else { 0 }).collect();
    image::GrayImage::from_raw(w, h, data)
        .expect("mask size matches")
        .save(path)
        .map_err(|source| SynthError::Png {
            path: path.into(),
            source,
        })
}

/// Degrades the masks of one split (boundaries, then ids); `missed` names a mask already deleted.
fn perturb_masks(
    split: &str,
    dir: &Path,
    object_ids: &[u16],
    p: &Perturbation,
    rngs: &mut (Pcg64, Pcg64),
    report: &mut PerturbReport,
) -> Result<(), SynthError> {
    for (frame, files) in masks(dir)? {
        let key = format!("{split}/{frame:06}");
        let mut written = Vec::with_capacity(files.len());
        for (id, path) in &files {
            let (mut mask, w, h) = read_mask(path)?;
            if p.has(Imperfection::Boundary) {
                let (m, offset) = perturb_boundary(&mask, w as usize, p.boundary_px, &mut rngs.0);
                mask = m;
                report
                    .boundary
                    .entry(key.clone())
                    .or_default()
                    .push((*id, offset));
            }
            written.push((*id, mask, w, h));
            std::fs::remove_file(path).map_err(io_err(path))?;
        }
        let perm = if p.has(Imperfection::Ids) {
            let perm = permute_ids(object_ids, &mut rngs.1);
            report.ids.insert(key.clone(), perm.clone());
            perm
        } else {
            BTreeMap::new()
        };
        for (id, mask, w, h) in written {
            let new = perm.get(&id).copied().unwrap_or(id);
            let path = dir
                .join("mask_visib")
                .join(format!("{frame:06}_{new:06}.png"));
            write_mask(&path, &mask, w, h)?;
        }
    }
    Ok(())
}

/// Rewrites `scene_camera.json` of a split with every pose perturbed.
fn perturb_cameras(dir: &Path, p: &Perturbation, rng: &mut Pcg64) -> Result<(), SynthError> {
    let path = dir.join("scene_camera.json");
    let text = std::fs::read_to_string(&path).map_err(io_err(&path))?;
    let bad = |source| SynthError::Json {
        path: path.clone(),
        source,
    };
    let mut cams: BTreeMap<String, Value> = serde_json::from_str(&text).map_err(bad)?;
    let mut frames: Vec<String> = cams.keys().cloned().collect();
    frames.sort_by_key(|k| k.parse::<u64>().unwrap_or(u64::MAX));
    for f in frames {
        let cam = cams.get_mut(&f).expect("listed");
        let nums = |key: &str, n: usize| -> Option<Vec<f64>> {
            let v: Vec<f64> = cam
                .get(key)?
                .as_array()?
                .iter()
                .filter_map(Value::as_f64)
                .collect();
            (v.len() == n).then_some(v)
        };
        let (Some(r), Some(t)) = (nums("cam_R_w2c", 9), nums("cam_t_w2c", 3)) else {
            return Err(SynthError::InvalidConfig {
                field: "scene_camera.json",
                reason: format!(
                    "{}: frame {f} lacks cam_R_w2c[9] or cam_t_w2c[3]",
                    path.display()
                ),
            });
        };
        // Row-major rotation; translation in millimetres.
        let rm = DMat3::from_cols_array(&[r[0], r[3], r[6], r[1], r[4], r[7], r[2], r[5], r[8]]);
        let (r2, t2) = perturb_pose(
            rm,
            DVec3::new(t[0], t[1], t[2]),
            p.pose_deg,
            p.pose_m * 1000.0,
            rng,
        );
        let rows = r2.transpose().to_cols_array();
        cam["cam_R_w2c"] = serde_json::json!(rows);
        cam["cam_t_w2c"] = serde_json::json!(t2.to_array());
    }
    let out = serde_json::to_string_pretty(&cams).map_err(bad)?;
    std::fs::write(&path, out).map_err(io_err(&path))
}

/// Copies the BOP sequence `src` to `dst` (which must not exist) with its training inputs degraded
/// by `p`; returns what was done (also written to `dst/perturbation.json`).
pub fn perturb_bop(src: &Path, dst: &Path, p: &Perturbation) -> Result<PerturbReport, SynthError> {
    if dst.exists() {
        return Err(SynthError::OutputNotEmpty { path: dst.into() });
    }
    copy_tree(src, dst)?;
    let train0 = dst.join("train_0");
    let t0_masks = masks(&train0)?;
    let mut object_ids: Vec<u16> = t0_masks.values().flatten().map(|m| m.0).collect();
    object_ids.sort_unstable();
    object_ids.dedup();
    let mut report = PerturbReport::default();
    if p.has(Imperfection::Miss) {
        let mut rng = Imperfection::Miss.stream(p.seed);
        let frames: Vec<_> = t0_masks
            .iter()
            .filter(|(f, m)| p.miss_frames.contains(f) && !m.is_empty())
            .collect();
        if !frames.is_empty() {
            let (frame, files) = frames[rng.random_range(0..frames.len())];
            let (id, path) = &files[rng.random_range(0..files.len())];
            std::fs::remove_file(path).map_err(io_err(path))?;
            report.missed = Some((*frame, *id));
        }
    }
    let mut rngs = (
        Imperfection::Boundary.stream(p.seed),
        Imperfection::Ids.stream(p.seed),
    );
    let mut pose_rng = Imperfection::Pose.stream(p.seed);
    for split in ["train_0", "train_1"] {
        let dir = dst.join(split);
        if !dir.join("scene_camera.json").is_file() {
            continue;
        }
        perturb_masks(split, &dir, &object_ids, p, &mut rngs, &mut report)?;
        if p.has(Imperfection::Pose) {
            perturb_cameras(&dir, p, &mut pose_rng)?;
        }
    }
    let json = serde_json::json!({ "perturbation": p, "report": report });
    let path = dst.join("perturbation.json");
    std::fs::write(
        &path,
        serde_json::to_string_pretty(&json).expect("serialises"),
    )
    .map_err(io_err(&path))?;
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn disc(w: usize, h: usize, cx: f64, cy: f64, r: f64) -> Vec<bool> {
        (0..w * h)
            .map(|p| ((p % w) as f64 - cx).hypot((p / w) as f64 - cy) <= r)
            .collect()
    }

    #[test]
    fn id_permutations_are_bijections_of_the_object_ids_and_seeded() {
        let ids = [1, 2, 3, 4, 7];
        let a = permute_ids(&ids, &mut Pcg64::seed_from_u64(3));
        let b = permute_ids(&ids, &mut Pcg64::seed_from_u64(3));
        assert_eq!(a, b);
        let mut image: Vec<u16> = a.values().copied().collect();
        image.sort_unstable();
        assert_eq!(image, ids);
    }

    #[test]
    fn offsetting_a_disc_changes_its_radius_by_the_offset() {
        let (w, h) = (40, 40);
        let m = disc(w, h, 20.0, 20.0, 10.0);
        let area = |m: &[bool]| m.iter().filter(|&&b| b).count() as f64;
        for off in [-3, -1, 2, 3] {
            let r = (area(&offset_mask(&m, w, off)) / std::f64::consts::PI).sqrt();
            assert!(
                (r - (10.0 + off as f64)).abs() < 0.8,
                "offset {off}: radius {r}"
            );
        }
    }

    #[test]
    fn boundary_noise_stays_within_a_few_pixels_of_the_boundary() {
        let (w, h) = (60, 60);
        let m = disc(w, h, 30.0, 30.0, 15.0);
        let mut rng = Pcg64::seed_from_u64(1);
        for _ in 0..10 {
            let (out, off) = perturb_boundary(&m, w, 3, &mut rng);
            assert!((1..=3).contains(&off.abs()));
            for p in 0..w * h {
                if out[p] != m[p] {
                    let d = ((p % w) as f64 - 30.0).hypot((p / w) as f64 - 30.0);
                    assert!((d - 15.0).abs() <= 5.5, "changed pixel {d} from the centre");
                }
            }
        }
    }

    /// A two-frame BOP `train_0` with discs for objects 1 and 2 in each frame.
    fn tiny_bop(root: &Path) {
        let split = root.join("train_0");
        std::fs::create_dir_all(split.join("mask_visib")).unwrap();
        let cam = serde_json::json!({
            "cam_K": [100.0, 0.0, 15.5, 0.0, 100.0, 15.5, 0.0, 0.0, 1.0],
            "cam_R_w2c": [1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0],
            "cam_t_w2c": [0.0, 0.0, 500.0], "depth_scale": 1.0, "width": 32, "height": 32
        });
        let cams = serde_json::json!({ "1": cam, "3": cam });
        std::fs::write(split.join("scene_camera.json"), cams.to_string()).unwrap();
        for f in [1u32, 3] {
            for (o, cx) in [(1u16, 8.0), (2, 24.0)] {
                let m = disc(32, 32, cx, 16.0, 5.0);
                let path = split.join("mask_visib").join(format!("{f:06}_{o:06}.png"));
                write_mask(&path, &m, 32, 32).unwrap();
            }
        }
    }

    #[test]
    fn a_perturbed_copy_renames_drops_and_moves_what_its_report_says() {
        let base = std::env::temp_dir().join(format!("trand-perturb-{}", std::process::id()));
        let (src, dst) = (base.join("src"), base.join("dst"));
        let _ = std::fs::remove_dir_all(&base);
        tiny_bop(&src);
        let p = Perturbation {
            miss_frames: vec![3],
            ..Perturbation::new(
                vec![Imperfection::Ids, Imperfection::Miss, Imperfection::Pose],
                5,
            )
        };
        let report = perturb_bop(&src, &dst, &p).unwrap();
        let (frame, missed) = report.missed.unwrap();
        assert_eq!(frame, 3);
        let written = masks(&dst.join("train_0")).unwrap();
        assert_eq!(written[&1].len(), 2);
        assert_eq!(written[&3].len(), 1);
        // Each written mask is the disc of the object its report maps there.
        for (f, files) in &written {
            let perm = &report.ids[&format!("train_0/{f:06}")];
            for (id, path) in files {
                let (orig, _) = perm.iter().find(|(_, n)| *n == id).unwrap();
                assert!(!(*f == 3 && *orig == missed));
                let (m, _, _) = read_mask(path).unwrap();
                let cx = if *orig == 1 { 8 } else { 24 };
                assert!(m[16 * 32 + cx], "frame {f}: {id} should be object {orig}");
            }
        }
        let cams: Value = serde_json::from_str(
            &std::fs::read_to_string(dst.join("train_0/scene_camera.json")).unwrap(),
        )
        .unwrap();
        assert_ne!(cams["1"]["cam_t_w2c"], serde_json::json!([0.0, 0.0, 500.0]));
        assert!(dst.join("perturbation.json").is_file());
        assert!(
            perturb_bop(&src, &dst, &p).is_err(),
            "an existing output is refused"
        );
        std::fs::remove_dir_all(&base).unwrap();
    }

    #[test]
    fn pose_error_has_the_asked_angle_and_centre_shift() {
        let r = DMat3::from_quat(DQuat::from_rotation_x(2.0));
        let t = DVec3::new(10.0, -20.0, 800.0);
        let (r2, t2) = perturb_pose(r, t, 0.5, 3.0, &mut Pcg64::seed_from_u64(9));
        let d = r2 * r.transpose();
        let angle = ((d.x_axis.x + d.y_axis.y + d.z_axis.z - 1.0) / 2.0)
            .clamp(-1.0, 1.0)
            .acos();
        assert!(
            (angle.to_degrees() - 0.5).abs() < 1e-6,
            "{}",
            angle.to_degrees()
        );
        let (c, c2) = (-(r.transpose() * t), -(r2.transpose() * t2));
        assert!(((c2 - c).length() - 3.0).abs() < 1e-6);
    }
}
