//! Synthetic transparent-object sequences with exact ground truth.
//!
//! [`generate`] builds one sequence in the layout of the reference Blender data
//! (`shared/data/blender/seq_*`):
//!
//! 1. a random table scene of procedural glassware ([`shapes`]) with one supporting pair, the
//!    t = 1 event: [`layout`] (the stacked family: a stacked pair among random objects) or
//!    [`containers`] (upright open containers, lying tumblers, and a stack or a lean);
//! 2. [`physics`]: drop and settle with rapier3d (t = 0, checked by [`stack`] or [`lean`]),
//!    remove the supporting object and re-settle (t = 1);
//! 3. [`cameras`]: bird's-eye + 12-view ring for training, random hemisphere views for testing;
//! 4. [`trace`]: a ray tracer over a [`bvh`] with real dielectrics ([`material`]) for colour, and
//!    one exact ray per pixel centre for depth and instance masks;
//! 5. [`bop_writer`]: PNGs and BOP JSON, plus `sequence.json` ([`sequence`]).
//!
//! Output is written into a temporary sibling folder and renamed into place at the end, so an
//! interrupted or failed run leaves no partial sequence. Everything is a pure function of the
//! configuration (seed included): bytes do not depend on the thread count.
//!
//! ```no_run
//! use trand_synth::{Preset, SynthConfig, generate};
//! let config = SynthConfig::new(Preset::Tiny, 7, "/tmp/seq_tiny");
//! let summary = generate(&config)?;
//! println!("{} views, object {} removed", summary.views, summary.removed_obj_id);
//! # Ok::<(), trand_synth::SynthError>(())
//! ```

pub mod bop_writer;
pub mod bvh;
pub mod cameras;
pub mod contact;
pub mod containers;
pub mod error;
pub mod layout;
pub mod lean;
pub mod material;
pub mod physics;
pub mod relation;
pub mod scene;
pub mod sequence;
pub mod shapes;
pub mod stack;
pub mod trace;

pub use error::SynthError;

use crate::bop_writer::FrameMap;
use crate::physics::{BodySpec, PhysicsParams, Pose};
use crate::scene::{Placed, RenderScene};
use crate::sequence::*;
use crate::trace::{RenderSettings, render_view};
use glam::DVec3;
use rand::SeedableRng;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;
use trand_io::output;

/// Objects per scene: at least the supporting pair, at most what fits the placement disc.
pub const MIN_OBJECTS: u32 = 2;
pub const MAX_OBJECTS: u32 = 6;
/// Largest accepted image side (16-bit PNG and memory sanity).
pub const MAX_IMAGE_SIDE: u32 = 8192;
/// Largest tilt of the supported object against its support's axis that the t = 0 seating
/// corrects; beyond it the object is leaning or falling and keeps its simulated pose.
pub const SEAT_MAX_TILT_DEG: f32 = 6.0;
/// Gap left between a seated object and its support (m): keeps the two glass surfaces from
/// coinciding (which would make the first hit ambiguous) while far below a pixel.
pub const SEAT_GAP_M: f32 = 5e-5;
/// (linear, angular) damping while the supported object settles onto its fixed support: only
/// its rest pose matters there, and strong damping stops tall glasses rocking on the contact.
pub const SETTLE_ONTO_DAMPING: (f32, f32) = (5.0, 20.0);
/// Objects whose lowest point is below this height stand on the table (m).
pub const ON_TABLE_M: f32 = 0.001;
/// Layouts tried until the supporting pair really rests on each other after settling.
pub const MAX_LAYOUT_ATTEMPTS: u32 = 6;

/// Named settings bundles.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Preset {
    /// Stacked family, 640×480, 4 objects, 30 test views per state, 4 samples per pixel.
    Default,
    /// Stacked family, 160×120, 3 objects, 3 test views per state, 2 samples per pixel: for
    /// tests (seconds).
    Tiny,
    /// Containers family ([`containers`]), 640×480, 3–6 objects, the reference sequences'
    /// varied camera rig and 10 test views per state, 4 samples per pixel.
    Containers,
    /// Containers family at 160×120, 3 test views per state, 2 samples per pixel: for tests.
    ContainersTiny,
}

/// Which kind of scene [`generate`] composes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SceneFamily {
    /// A stacked pair among random objects ([`layout::sample`]).
    Stacked,
    /// Upright open containers, lying tumblers and a stack or a lean ([`containers::sample`]).
    Containers,
}

/// How many objects a scene has.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ObjectCount {
    Exactly(u32),
    /// Drawn uniformly from `min..=max` by the scene's seed.
    Between(u32, u32),
}

impl ObjectCount {
    /// The count for one scene; `Exactly` draws nothing from `rng`.
    fn draw(self, rng: &mut impl rand::Rng) -> u32 {
        use rand::RngExt;
        match self {
            ObjectCount::Exactly(n) => n,
            ObjectCount::Between(lo, hi) => rng.random_range(lo..=hi),
        }
    }

    fn bounds(self) -> (u32, u32) {
        match self {
            ObjectCount::Exactly(n) => (n, n),
            ObjectCount::Between(lo, hi) => (lo, hi),
        }
    }
}

/// What to do when the output folder already exists and is not empty.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ExistingOutput {
    Refuse,
    Replace,
}

/// Whether to draw a progress bar on stderr.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Progress {
    Bar,
    Hidden,
}

/// Everything [`generate`] needs.
#[derive(Clone, Debug)]
pub struct SynthConfig {
    pub seed: u64,
    pub out: PathBuf,
    pub family: SceneFamily,
    pub width: u32,
    pub height: u32,
    pub objects: ObjectCount,
    pub rig: cameras::Rig,
    pub test_views: u32,
    pub samples_per_pixel: u32,
    /// Angular resolution of the lathed meshes.
    pub lathe_slices: u32,
    pub existing: ExistingOutput,
    pub progress: Progress,
}

impl SynthConfig {
    pub fn new(preset: Preset, seed: u64, out: impl Into<PathBuf>) -> Self {
        use ObjectCount::{Between, Exactly};
        use SceneFamily::{Containers, Stacked};
        use cameras::Rig::{Fixed, Varied};
        let (family, rig, objects) = match preset {
            Preset::Default => (Stacked, Fixed, Exactly(4)),
            Preset::Tiny => (Stacked, Fixed, Exactly(3)),
            Preset::Containers | Preset::ContainersTiny => (Containers, Varied, Between(3, 6)),
        };
        let (width, height, test_views, samples_per_pixel, lathe_slices) = match preset {
            Preset::Default => (640, 480, 30, 4, 72),
            Preset::Containers => (640, 480, 10, 4, 72),
            Preset::Tiny | Preset::ContainersTiny => (160, 120, 3, 2, 32),
        };
        Self {
            seed,
            out: out.into(),
            family,
            width,
            height,
            objects,
            rig,
            test_views,
            samples_per_pixel,
            lathe_slices,
            existing: ExistingOutput::Refuse,
            progress: Progress::Hidden,
        }
    }

    /// Checks every field; the error names the field.
    pub fn validate(&self) -> Result<(), SynthError> {
        let bad = |field, reason: String| Err(SynthError::InvalidConfig { field, reason });
        for (field, v) in [("width", self.width), ("height", self.height)] {
            if v == 0 || v > MAX_IMAGE_SIDE {
                return bad(
                    field,
                    format!("{v} must be between 1 and {MAX_IMAGE_SIDE} pixels"),
                );
            }
        }
        let (lo, hi) = self.objects.bounds();
        let least = match self.family {
            SceneFamily::Stacked => MIN_OBJECTS,
            SceneFamily::Containers => containers::MIN_OBJECTS,
        };
        if lo > hi || lo < least || hi > MAX_OBJECTS {
            return bad(
                "objects",
                format!(
                    "{:?} must lie between {least} and {MAX_OBJECTS}",
                    self.objects
                ),
            );
        }
        if self.test_views == 0 || self.test_views > 1000 {
            return bad(
                "test_views",
                format!("{} must be between 1 and 1000", self.test_views),
            );
        }
        if self.samples_per_pixel == 0 || self.samples_per_pixel > 4096 {
            return bad(
                "samples_per_pixel",
                format!("{} must be between 1 and 4096", self.samples_per_pixel),
            );
        }
        if self.lathe_slices < 8 || self.lathe_slices > 1024 {
            return bad(
                "lathe_slices",
                format!("{} must be between 8 and 1024", self.lathe_slices),
            );
        }
        if self.out.as_os_str().is_empty() {
            return bad("out", "the output path is empty".into());
        }
        Ok(())
    }
}

/// What [`generate`] produced.
#[derive(Clone, Debug)]
pub struct Summary {
    pub out: PathBuf,
    pub views: usize,
    pub removed_obj_id: u32,
    /// How the removed object supported another at t = 0, and whether that held.
    pub relation: layout::RelationKind,
    pub relation_verified: bool,
    pub physics_s: f64,
    pub render_s: f64,
    pub total_s: f64,
}

/// Generates one sequence into `config.out` (see the crate docs).
///
/// The output is checked before any work: it must not be the current folder or one of its
/// ancestors, and an existing non-empty folder is replaced only with [`ExistingOutput::Replace`]
/// and only when trand wrote it (its marker file, [`trand_io::output::MARKER`]). The sequence is
/// built in a hidden sibling folder and swapped in at the end; the old folder is removed only
/// after the new one is in place.
pub fn generate(config: &SynthConfig) -> Result<Summary, SynthError> {
    config.validate()?;
    let target = output::resolve_target(&config.out)?;
    if output::occupied(&target) {
        let meta = target.symlink_metadata().map_err(|source| SynthError::Io {
            path: config.out.clone(),
            source,
        })?;
        if !meta.is_dir() {
            return Err(SynthError::OutputNotADirectory {
                path: config.out.clone(),
            });
        }
        let non_empty = std::fs::read_dir(&target)
            .map_err(|source| SynthError::Io {
                path: config.out.clone(),
                source,
            })?
            .next()
            .is_some();
        if non_empty {
            if config.existing == ExistingOutput::Refuse {
                return Err(SynthError::OutputNotEmpty {
                    path: config.out.clone(),
                });
            }
            output::check_replaceable(&target)?;
        }
    }
    let name = target
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let parent = target.parent().unwrap_or(Path::new("/"));
    output::clean_stale_temps(parent, &format!(".{name}.synth-tmp-"));
    output::clean_stale_temps(parent, &format!(".{name}.synth-old-"));
    let tmp = output::temp_sibling(&target, "synth-tmp");
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).map_err(|source| SynthError::Io {
            path: tmp.clone(),
            source,
        })?;
    }
    std::fs::create_dir_all(&tmp).map_err(|source| SynthError::OutputUnwritable {
        path: config.out.clone(),
        source,
    })?;
    let result = output::write_marker(&tmp, output::OutputKind::Sequence)
        .map_err(SynthError::from)
        .and_then(|()| generate_into(config, &tmp));
    let finish = result.and_then(|mut summary| {
        swap_into_place(&tmp, &target, &config.out)?;
        summary.out = config.out.clone();
        Ok(summary)
    });
    if finish.is_err() {
        let _ = std::fs::remove_dir_all(&tmp);
    }
    finish
}

/// Renames `tmp` to `target`; an existing `target` (already checked replaceable) is first renamed
/// aside and removed only once the new folder is in place.
fn swap_into_place(tmp: &Path, target: &Path, shown: &Path) -> Result<(), SynthError> {
    let io = |source| SynthError::Io {
        path: shown.into(),
        source,
    };
    if !output::occupied(target) {
        return std::fs::rename(tmp, target).map_err(io);
    }
    let old = output::temp_sibling(target, "synth-old");
    std::fs::rename(target, &old).map_err(io)?;
    if let Err(e) = std::fs::rename(tmp, target) {
        let _ = std::fs::rename(&old, target);
        return Err(io(e));
    }
    let _ = std::fs::remove_dir_all(&old);
    Ok(())
}

/// How the remaining objects are simulated at t = 1.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum T1Motion {
    /// Objects that lost their support start awake, all others asleep; rapier wakes what they
    /// touch (and, at times, more: see [`physics::settle_spreading`]).
    AsleepUntilWoken,
    /// Objects that lost their support move, all others are fixed until something moving
    /// touches them ([`physics::settle_spreading`]).
    SpreadByContact,
}

/// The t = 1 simulation of each scene family (the stacked family keeps its original one).
pub fn t1_motion(family: SceneFamily) -> T1Motion {
    match family {
        SceneFamily::Stacked => T1Motion::AsleepUntilWoken,
        SceneFamily::Containers => T1Motion::SpreadByContact,
    }
}

/// Whether object `i` may have lost its support when another is removed: it rests on something
/// other than the table alone (its lowest hull point is above [`ON_TABLE_M`], or it leans).
fn lost_support(layout: &layout::Layout, rest0: &[Pose], i: usize) -> bool {
    let lowest = layout.objects[i]
        .model
        .hull_points
        .iter()
        .map(|p| rest0[i].apply(*p).z)
        .fold(f32::MAX, f32::min);
    lowest > ON_TABLE_M || layout.objects[i].orientation == layout::Orientation::Tilted
}

/// Settles the objects `keep` from their t = 0 poses after the removal. Returns their poses,
/// the stats and the ids of the objects that were simulated (`None` for
/// [`T1Motion::AsleepUntilWoken`], where every object is).
fn settle_t1(
    layout: &layout::Layout,
    rest0: &[Pose],
    keep: &[usize],
    motion: T1Motion,
    params: &PhysicsParams,
) -> (Vec<Pose>, physics::SettleStats, Option<Vec<u32>>) {
    let specs: Vec<BodySpec> = keep
        .iter()
        .map(|&i| stack::spec(&layout.objects[i]))
        .collect();
    let start: Vec<Pose> = keep.iter().map(|&i| rest0[i]).collect();
    let lost: Vec<bool> = keep
        .iter()
        .map(|&i| lost_support(layout, rest0, i))
        .collect();
    match motion {
        T1Motion::AsleepUntilWoken => {
            let wake: Vec<physics::Wake> = lost
                .iter()
                .map(|&l| {
                    if l {
                        physics::Wake::Awake
                    } else {
                        physics::Wake::Asleep
                    }
                })
                .collect();
            let (rest, stats) = physics::settle(&specs, &start, &wake, params);
            (rest, stats, None)
        }
        T1Motion::SpreadByContact => {
            let (rest, stats, moved) = physics::settle_spreading(&specs, &start, &lost, params);
            let ids = keep
                .iter()
                .zip(&moved)
                .filter(|(_, m)| **m)
                .map(|(&i, _)| layout.objects[i].id)
                .collect();
            (rest, stats, Some(ids))
        }
    }
}

fn pose_info(p: &Pose) -> PoseInfo {
    let r = bop_writer::pose_rotation(p).transpose().to_cols_array();
    PoseInfo {
        r_m2w: r.map(|v| bop_writer::round(v, 9)),
        t_m2w_mm: (p.translation.as_dvec3() * 1000.0)
            .to_array()
            .map(|v| bop_writer::round(v, 4)),
    }
}

/// The t = 0 scene: the layout, its settled poses and how its supporting pair turned out.
struct SceneT0 {
    layout: layout::Layout,
    rest: Vec<Pose>,
    stats: physics::SettleStats,
    seat: Option<SeatCorrection>,
    relation: Relation,
    /// The relation of every layout tried, the kept one last.
    attempts: Vec<Relation>,
}

/// The t = 1 scene: which object was removed and where the others came to rest.
struct SceneT1 {
    removed: usize,
    /// Indices (into the layout's objects) of the remaining objects, in order.
    keep: Vec<usize>,
    /// Poses of the objects `keep`, in the same order.
    rest: Vec<Pose>,
    stats: physics::SettleStats,
    simulated: Option<Vec<u32>>,
    displacement: BTreeMap<String, Displacement>,
    snapped: Vec<u32>,
}

/// The cameras of every split, around the workspace centre.
struct SceneCameras {
    k: trand_core::Intrinsics,
    centre: DVec3,
    train: Vec<trand_core::camera::Camera>,
    ring: cameras::RingInfo,
    test0: Vec<trand_core::camera::Camera>,
    test1: Vec<trand_core::camera::Camera>,
}

/// Steps 1-2: samples layouts and settles them until the supporting pair holds (at most
/// [`MAX_LAYOUT_ATTEMPTS`] tries; the last one is kept either way).
fn settle_t0(config: &SynthConfig, rng: &mut impl rand::Rng, params: &PhysicsParams) -> SceneT0 {
    let n_objects = config.objects.draw(rng);
    let mut attempts = Vec::new();
    loop {
        let layout = match config.family {
            SceneFamily::Stacked => layout::sample(rng, n_objects, config.lathe_slices),
            SceneFamily::Containers => containers::sample(rng, n_objects, config.lathe_slices),
        };
        let settled = relation::settle_event(&layout, params);
        let done = settled.relation.verified || attempts.len() as u32 + 1 >= MAX_LAYOUT_ATTEMPTS;
        attempts.push(settled.relation.clone());
        if done {
            return SceneT0 {
                layout,
                rest: settled.rest,
                stats: settled.stats,
                seat: settled.seat,
                relation: settled.relation,
                attempts,
            };
        }
    }
}

/// The object taken away at t = 1: the support, or, if the pair did not hold, the object closest to
/// another.
fn removed_object(t0: &SceneT0) -> usize {
    if t0.relation.verified {
        return t0.layout.event.support;
    }
    let rest = &t0.rest;
    let nearest = |i: usize| {
        (0..rest.len())
            .filter(|&j| j != i)
            .map(|j| rest[i].translation.distance(rest[j].translation))
            .fold(f32::MAX, f32::min)
    };
    (0..rest.len())
        .min_by(|&a, &b| nearest(a).total_cmp(&nearest(b)))
        .unwrap_or(0)
}

/// Step 2 at t = 1: removes an object ([`removed_object`]) and settles the others; an object whose
/// vertices moved less than [`physics::STATIC_SNAP_MM`] keeps its t = 0 pose exactly.
fn settle_after_removal(config: &SynthConfig, t0: &SceneT0, params: &PhysicsParams) -> SceneT1 {
    let removed = removed_object(t0);
    let keep: Vec<usize> = (0..t0.layout.objects.len())
        .filter(|&i| i != removed)
        .collect();
    let (mut rest, stats, simulated) = settle_t1(
        &t0.layout,
        &t0.rest,
        &keep,
        t1_motion(config.family),
        params,
    );
    let mut displacement = BTreeMap::new();
    let mut snapped = Vec::new();
    for (k, &i) in keep.iter().enumerate() {
        let (object, before) = (&t0.layout.objects[i], &t0.rest[i]);
        let pts: Vec<glam::Vec3> = object.model.mesh.points().collect();
        let max_mm = physics::max_vertex_displacement_mm(&pts, before, &rest[k]);
        let snap = max_mm < physics::STATIC_SNAP_MM;
        if snap {
            rest[k] = *before;
            snapped.push(object.id);
        }
        displacement.insert(
            object.id.to_string(),
            Displacement {
                translation_mm: before.translation.distance(rest[k].translation) * 1000.0,
                rotation_deg: physics::rotation_deg(before, &rest[k]),
                max_vertex_displacement_mm: if snap { 0.0 } else { max_mm },
                static_snapped: snap,
            },
        );
    }
    SceneT1 {
        removed,
        keep,
        rest,
        stats,
        simulated,
        displacement,
        snapped,
    }
}

/// Step 3: the training rig and the two test sets, around the objects' mean position at 3 cm
/// height.
fn draw_cameras(config: &SynthConfig, rest0: &[Pose], rng: &mut impl rand::Rng) -> SceneCameras {
    let k = cameras::intrinsics(config.width, config.height);
    let mean = rest0
        .iter()
        .map(|p| p.translation.as_dvec3())
        .sum::<DVec3>()
        / rest0.len() as f64;
    let centre = DVec3::new(mean.x, mean.y, 0.03);
    let (train, ring) = cameras::train_views(k, centre, config.rig, rng);
    let test0 = cameras::test_views(k, centre, config.test_views, &ring, rng);
    let test1 = cameras::test_views(k, centre, config.test_views, &ring, rng);
    SceneCameras {
        k,
        centre,
        train,
        ring,
        test0,
        test1,
    }
}

/// A progress bar over `total_rows` image rows, drawn or hidden as the configuration says.
fn progress_bar(progress: Progress, total_rows: u64) -> indicatif::ProgressBar {
    match progress {
        Progress::Bar => {
            let b = indicatif::ProgressBar::new(total_rows);
            b.set_style(
                indicatif::ProgressStyle::with_template(
                    "{msg:>8} [{bar:40}] {percent:>3}% {elapsed_precise} eta {eta}",
                )
                .expect("static template")
                .progress_chars("=> "),
            );
            b
        }
        Progress::Hidden => indicatif::ProgressBar::hidden(),
    }
}

/// Steps 4-5: renders every split of both states and writes its images and BOP JSON under `dir`;
/// returns the number of views written.
fn render_splits(
    config: &SynthConfig,
    dir: &Path,
    t0: &SceneT0,
    t1: &SceneT1,
    cams: &SceneCameras,
) -> Result<usize, SynthError> {
    let layout = &t0.layout;
    let placed = |poses: &[(usize, Pose)]| -> Vec<Placed<'_>> {
        poses
            .iter()
            .map(|(i, p)| {
                let o = &layout.objects[*i];
                Placed {
                    obj_id: o.id,
                    mesh: &o.model.mesh,
                    material: o.material,
                    rotation: p.rotation,
                    translation: p.translation,
                }
            })
            .collect()
    };
    let state0: Vec<(usize, Pose)> = t0.rest.iter().copied().enumerate().collect();
    let state1: Vec<(usize, Pose)> = t1
        .keep
        .iter()
        .copied()
        .zip(t1.rest.iter().copied())
        .collect();
    let scenes = [
        RenderScene::new(&placed(&state0), layout.env),
        RenderScene::new(&placed(&state1), layout.env),
    ];
    let states = [&state0, &state1];
    let splits: [(&str, usize, &[trand_core::camera::Camera]); 4] = [
        ("train_0", 0, &cams.train),
        ("test_0", 0, &cams.test0),
        ("train_1", 1, &cams.train[..1]),
        ("test_1", 1, &cams.test1),
    ];
    let total_rows: u64 = splits
        .iter()
        .map(|s| s.2.len() as u64 * config.height as u64)
        .sum();
    let bar = progress_bar(config.progress, total_rows);
    let settings = RenderSettings {
        samples_per_pixel: config.samples_per_pixel,
    };
    let mut views = 0;
    for (split_index, (name, state, cams)) in splits.iter().enumerate() {
        bar.set_message(*name);
        let split = dir.join(name);
        bop_writer::create_split_dirs(&split)?;
        let present: Vec<u32> = states[*state]
            .iter()
            .map(|(i, _)| layout.objects[*i].id)
            .collect();
        let (mut cam_map, mut gt_map, mut info_map) = (Vec::new(), Vec::new(), Vec::new());
        for (frame, cam) in cams.iter().enumerate() {
            let view_seed = config.seed.wrapping_mul(0x2545_f491_4f6c_dd1d)
                ^ ((split_index as u64) << 32 | frame as u64);
            let img = render_view(&scenes[*state], cam, settings, view_seed, &|| bar.inc(1));
            bop_writer::write_view(&split, frame as u32, &img, &present)?;
            cam_map.push((frame as u32, bop_writer::camera_entry(cam)));
            gt_map.push((
                frame as u32,
                states[*state]
                    .iter()
                    .map(|(i, p)| bop_writer::gt_entry(cam, layout.objects[*i].id, p))
                    .collect::<Vec<_>>(),
            ));
            info_map.push((
                frame as u32,
                present
                    .iter()
                    .map(|&id| bop_writer::gt_info_entry(&img, id))
                    .collect::<Vec<_>>(),
            ));
            views += 1;
        }
        bop_writer::write_json(&split.join("scene_camera.json"), &FrameMap(cam_map))?;
        bop_writer::write_json(&split.join("scene_gt.json"), &FrameMap(gt_map))?;
        bop_writer::write_json(&split.join("scene_gt_info.json"), &FrameMap(info_map))?;
    }
    bar.finish_and_clear();
    Ok(views)
}

/// Writes every object's model (`models/obj_{id}.ply`, millimetres) and `models_info.json`.
fn write_models(dir: &Path, layout: &layout::Layout) -> Result<(), SynthError> {
    let models = dir.join("models");
    std::fs::create_dir_all(&models).map_err(|source| SynthError::Io {
        path: models.clone(),
        source,
    })?;
    let mut infos = Vec::new();
    for o in &layout.objects {
        bop_writer::write_ply(&models.join(format!("obj_{:06}.ply", o.id)), &o.model.mesh)?;
        infos.push((o.id, bop_writer::model_info(&o.model.mesh)));
    }
    bop_writer::write_json(&models.join("models_info.json"), &FrameMap(infos))
}

/// Each object as `sequence.json` lists it: kind, material, dimensions and its poses in both states.
fn object_infos(t0: &SceneT0, t1: &SceneT1) -> Vec<ObjectInfo> {
    t0.layout
        .objects
        .iter()
        .enumerate()
        .map(|(i, o)| ObjectInfo {
            id: o.id,
            kind: o.model.kind,
            transparent: o.material.is_transparent(),
            model: format!("models/obj_{:06}.ply", o.id),
            material: o.material,
            mass_kg: o.mass_kg,
            params_m: ParamsInfo {
                dimensions_m: o.model.params.iter().copied().collect(),
                initial_mode: o.orientation,
            },
            initial_mode: o.orientation,
            pose_t0: pose_info(&t0.rest[i]),
            pose_t1: t1
                .keep
                .iter()
                .position(|&j| j == i)
                .map(|k| pose_info(&t1.rest[k])),
            removed_at_t1: i == t1.removed,
        })
        .collect()
}

/// The record written as `sequence.json`: conventions, objects, the t = 0 relation and the t = 1
/// change, cameras, physics and rendering settings.
fn sequence_record(
    config: &SynthConfig,
    t0: SceneT0,
    t1: SceneT1,
    cams: SceneCameras,
    params: PhysicsParams,
) -> Sequence {
    let k = cams.k;
    let narrow = cams.ring.narrow_radius_deg.is_some();
    let objects = object_infos(&t0, &t1);
    let removed = &t0.layout.objects[t1.removed];
    Sequence {
        format: "BlenderProc/BOP train_pbr-like transparent-object sequence (trand-synth)",
        generator: format!("trand-synth {}", env!("CARGO_PKG_VERSION")),
        seed: config.seed,
        resolution: Resolution {
            width: config.width,
            height: config.height,
        },
        intrinsics: IntrinsicsInfo {
            fx: k.fx,
            fy: k.fy,
            cx: k.cx,
            cy: k.cy,
            cam_k: [k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0],
            convention: "OpenCV; integer pixel coordinates are pixel centres",
        },
        units: Units {
            world: "metres, z up, table top z = 0",
            poses_t: "millimetres",
            depth_png: "uint16 mm",
        },
        depth: "planar camera-z depth of first surface at pixel centre (glass surfaces included), 0 = no surface",
        mask_visib_naming: "mask_visib/{frame:06d}_{obj_id:06d}.png (obj_id, not BOP gt index); files only for objects present in that state",
        states: serde_json::json!({
            "t0": {"train": match narrow {
                false => "train_0 (frame 0 bird's-eye, 1..12 ring)",
                true => "train_0 (frame 0 along the rig's axis, 1..12 a circle around it)",
            }, "test": "test_0"},
            "t1": {"train": "train_1 (frame 0 only, same pose as train_0 frame 0)", "test": "test_1"}
        }),
        objects,
        relation_t0: t0.relation,
        removed_obj_id: removed.id,
        removed_obj_kind: removed.model.kind,
        displacement_t0_to_t1: t1.displacement,
        workspace_center_m: cams.centre.to_array(),
        cameras: CamerasInfo {
            train_ring: cams.ring,
            test: match narrow {
                false => {
                    "uniform azimuth, elevation 20-70 deg, distance 0.45-0.8 m, looking at centre + U(+-4 cm, +-4 cm, +-2 cm)"
                }
                true => {
                    "uniform within 10 deg of the rig's axis, distance 0.45-0.8 m, looking at centre + U(+-4 cm, +-4 cm, +-2 cm)"
                }
            },
            test_views_per_state: config.test_views,
        },
        environment: t0.layout.env,
        physics: PhysicsInfo {
            engine: "rapier3d 0.36 (single-threaded, fixed step)",
            collision_shape: "CONVEX_HULL (table: BOX)",
            params,
            static_snap_max_vertex_mm: physics::STATIC_SNAP_MM,
            t0: t0.stats,
            t1: t1.stats,
            layout_attempts: t0.attempts,
            static_snapped_t1: t1.snapped,
            t1_simulated_obj_ids: t1.simulated,
            t0_seat_correction: t0.seat,
        },
        render: RenderInfo {
            engine: "trand-synth Whitted ray tracer (Fresnel/Snell dielectrics, Beer-Lambert absorption, area-light shadows)",
            spp: config.samples_per_pixel,
            rgb_filter: "box 1 px, jittered samples",
            data_passes: "1 ray at each pixel centre (exact depth and masks)",
            max_depth: trace::MAX_DEPTH,
            lathe_slices: config.lathe_slices,
        },
    }
}

/// The steps of [`generate`] (see the crate docs), writing into `dir`. One random stream, seeded by
/// the configuration, is drawn from in a fixed order: the object count and layouts, then the
/// cameras; each view's render has its own seed.
fn generate_into(config: &SynthConfig, dir: &Path) -> Result<Summary, SynthError> {
    let t_start = Instant::now();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(config.seed);
    let params = PhysicsParams::default();
    let t0 = settle_t0(config, &mut rng, &params);
    let t1 = settle_after_removal(config, &t0, &params);
    let physics_s = t_start.elapsed().as_secs_f64();

    let cams = draw_cameras(config, &t0.rest, &mut rng);
    let t_render = Instant::now();
    let views = render_splits(config, dir, &t0, &t1, &cams)?;
    let render_s = t_render.elapsed().as_secs_f64();

    write_models(dir, &t0.layout)?;
    let seq = sequence_record(config, t0, t1, cams, params);
    bop_writer::write_json(&dir.join("sequence.json"), &seq)?;
    Ok(Summary {
        out: dir.to_path_buf(),
        views,
        removed_obj_id: seq.removed_obj_id,
        relation: seq.relation_t0.kind,
        relation_verified: seq.relation_t0.verified,
        physics_s,
        render_s,
        total_s: t_start.elapsed().as_secs_f64(),
    })
}
