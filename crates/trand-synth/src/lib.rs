//! Synthetic transparent-object sequences with exact ground truth.
//!
//! [`generate`] builds one sequence in the layout of the reference Blender data
//! (`shared/data/blender/seq_*`):
//!
//! 1. [`layout`]: a random table scene of procedural glassware ([`shapes`]) with one stacked pair;
//! 2. [`physics`]: drop and settle with rapier3d (t = 0), remove the supporting object and
//!    re-settle (t = 1);
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
pub mod error;
pub mod layout;
pub mod material;
pub mod physics;
pub mod scene;
pub mod sequence;
pub mod shapes;
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

/// Objects per scene: at least the stacked pair, at most what fits the placement disc.
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
/// Layouts tried until the stacked pair really rests on each other after settling.
pub const MAX_LAYOUT_ATTEMPTS: u32 = 6;

/// Named settings bundles.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Preset {
    /// 640×480, 4 objects, 30 test views per state, 4 samples per pixel.
    Default,
    /// 160×120, 3 objects, 3 test views per state, 2 samples per pixel: for tests (seconds).
    Tiny,
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
    pub width: u32,
    pub height: u32,
    pub objects: u32,
    pub test_views: u32,
    pub samples_per_pixel: u32,
    /// Angular resolution of the lathed meshes.
    pub lathe_slices: u32,
    pub existing: ExistingOutput,
    pub progress: Progress,
}

impl SynthConfig {
    pub fn new(preset: Preset, seed: u64, out: impl Into<PathBuf>) -> Self {
        let (width, height, objects, test_views, samples_per_pixel, lathe_slices) = match preset {
            Preset::Default => (640, 480, 4, 30, 4, 72),
            Preset::Tiny => (160, 120, 3, 3, 2, 32),
        };
        Self {
            seed,
            out: out.into(),
            width,
            height,
            objects,
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
        if !(MIN_OBJECTS..=MAX_OBJECTS).contains(&self.objects) {
            return bad(
                "objects",
                format!(
                    "{} must be between {MIN_OBJECTS} and {MAX_OBJECTS}",
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
    pub stack_verified: bool,
    pub physics_s: f64,
    pub render_s: f64,
    pub total_s: f64,
}

/// Generates one sequence into `config.out` (see the crate docs).
pub fn generate(config: &SynthConfig) -> Result<Summary, SynthError> {
    config.validate()?;
    let target = config.out.clone();
    if target.exists() {
        if !target.is_dir() {
            return Err(SynthError::OutputNotADirectory { path: target });
        }
        let non_empty = std::fs::read_dir(&target)
            .map_err(|source| SynthError::Io {
                path: target.clone(),
                source,
            })?
            .next()
            .is_some();
        if non_empty && config.existing == ExistingOutput::Refuse {
            return Err(SynthError::OutputNotEmpty { path: target });
        }
    }
    let name = target
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "sequence".into());
    let parent = target
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let tmp = parent.join(format!(".{name}.synth-tmp-{}", std::process::id()));
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).map_err(|source| SynthError::Io {
            path: tmp.clone(),
            source,
        })?;
    }
    std::fs::create_dir_all(&tmp).map_err(|source| SynthError::OutputUnwritable {
        path: target.clone(),
        source,
    })?;
    let result = generate_into(config, &tmp);
    let finish = result.and_then(|mut summary| {
        if target.exists() {
            std::fs::remove_dir_all(&target).map_err(|source| SynthError::Io {
                path: target.clone(),
                source,
            })?;
        }
        std::fs::rename(&tmp, &target).map_err(|source| SynthError::Io {
            path: target.clone(),
            source,
        })?;
        summary.out = target.clone();
        Ok(summary)
    });
    if finish.is_err() {
        let _ = std::fs::remove_dir_all(&tmp);
    }
    finish
}

/// How well the stacked pair rests after settling.
fn check_stack(layout: &layout::Layout, rest: &[Pose]) -> Relation {
    let (s, t) = layout.stack;
    let world_z = |i: usize| {
        world_points(layout, rest, i)
            .map(|p| p.z)
            .fold(f32::MAX, f32::min)
    };
    let height = |i: usize| {
        let (lo, hi) = layout.objects[i].model.mesh.bounds();
        hi.z - lo.z
    };
    let tilt = |i: usize| {
        (rest[i].rotation * glam::Vec3::Z)
            .z
            .abs()
            .clamp(0.0, 1.0)
            .acos()
            .to_degrees()
    };
    let min_z = world_z(t);
    let all_on_table = (0..rest.len()).filter(|&i| i != t).all(|i| {
        world_z(i) < ON_TABLE_M
            && rest[i].translation.truncate().length() < layout.env.table.half_size_m
    });
    let verified = all_on_table && min_z > 0.7 * height(s) && tilt(t) < 15.0 && tilt(s) < 5.0;
    Relation {
        kind: "stack",
        support_obj_id: layout.objects[s].id,
        supported_obj_id: layout.objects[t].id,
        supported_min_z_mm: min_z * 1000.0,
        supported_tilt_deg: tilt(t),
        all_on_table,
        verified,
    }
}

/// t = 0 settling in two phases: everything but the supported object first; then the supported
/// object alone onto the (now fixed) settled scene. A resting support does not move anyway, and
/// a static support gives the stiff, creep-free contact that a dynamic one lacks in rapier.
fn settle_stack(
    layout: &layout::Layout,
    params: &PhysicsParams,
) -> (Vec<Pose>, physics::SettleStats, Option<SeatCorrection>) {
    let top = layout.stack.1;
    fn spec(o: &layout::ObjectSpec) -> BodySpec<'_> {
        BodySpec {
            hull_points: &o.model.hull_points,
            mass_kg: o.mass_kg,
            plate: o.plate,
        }
    }
    let rest_idx: Vec<usize> = (0..layout.objects.len()).filter(|&i| i != top).collect();
    let specs: Vec<BodySpec> = rest_idx.iter().map(|&i| spec(&layout.objects[i])).collect();
    let start: Vec<Pose> = rest_idx.iter().map(|&i| layout.start[i]).collect();
    let (phase_a, stats_a) = physics::settle(
        &specs,
        &start,
        &vec![physics::Wake::Awake; specs.len()],
        params,
    );
    // The supported object keeps its height above its support's settled pose.
    let mut poses = layout.start.clone();
    for (k, &i) in rest_idx.iter().enumerate() {
        poses[i] = phase_a[k];
    }
    let support = layout.stack.0;
    let lift = poses[support].translation - layout.start[support].translation;
    poses[top].translation += lift;
    let specs: Vec<BodySpec> = layout.objects.iter().map(spec).collect();
    let wake: Vec<physics::Wake> = (0..specs.len())
        .map(|i| {
            if i == top {
                physics::Wake::Awake
            } else {
                physics::Wake::Fixed
            }
        })
        .collect();
    let (mut rest, stats_b) = physics::settle(
        &specs,
        &poses,
        &wake,
        &PhysicsParams {
            linear_damping: SETTLE_ONTO_DAMPING.0,
            angular_damping: SETTLE_ONTO_DAMPING.1,
            ..*params
        },
    );
    let seat = seat_on_support(layout, &mut rest);
    let steps = stats_a.steps + stats_b.steps;
    (
        rest,
        physics::SettleStats {
            steps,
            seconds: steps as f32 * params.dt,
            converged: stats_a.converged && stats_b.converged,
        },
        seat,
    )
}

/// The mesh vertices of object `i` at its pose in `rest`, in world coordinates.
fn world_points<'a>(
    layout: &'a layout::Layout,
    rest: &[Pose],
    i: usize,
) -> impl Iterator<Item = glam::Vec3> + 'a {
    let pose = rest[i];
    layout.objects[i]
        .model
        .mesh
        .positions
        .iter()
        .map(move |p| pose.apply(*p))
}

/// Contact projection of the supported object: rapier leaves a glass on a glass rocking by a
/// degree or two (see [`settle_stack`]); when it came to rest on its support within
/// [`SEAT_MAX_TILT_DEG`] of the support's axis, it is turned about its centre to stand exactly
/// along that axis (yaw kept) and moved along it so that its base is [`SEAT_GAP_M`] above the
/// support's top. The glasses then neither float on one side nor intersect.
fn seat_on_support(layout: &layout::Layout, rest: &mut [Pose]) -> Option<SeatCorrection> {
    let (s, t) = layout.stack;
    let axis_s = rest[s].rotation * glam::Vec3::Z;
    let up = if axis_s.z >= 0.0 { axis_s } else { -axis_s };
    let axis_t = rest[t].rotation * glam::Vec3::Z;
    let tilt_deg = axis_t.angle_between(up).to_degrees();
    if tilt_deg > SEAT_MAX_TILT_DEG {
        return None;
    }
    let before = rest[t].translation;
    let fix = glam::Quat::from_rotation_arc(axis_t, up);
    // Untilt about the object's centre (its translation is kept), then slide it along the axis.
    rest[t].rotation = (fix * rest[t].rotation).normalize();
    let top_of_support = world_points(layout, rest, s)
        .map(|p| p.dot(up))
        .fold(f32::MIN, f32::max);
    let base_of_top = world_points(layout, rest, t)
        .map(|p| p.dot(up))
        .fold(f32::MAX, f32::min);
    rest[t].translation += (top_of_support + SEAT_GAP_M - base_of_top) * up;
    Some(SeatCorrection {
        tilt_deg,
        shift_mm: 1000.0 * rest[t].translation.distance(before),
    })
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

fn generate_into(config: &SynthConfig, dir: &Path) -> Result<Summary, SynthError> {
    let t_start = Instant::now();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(config.seed);
    let params = PhysicsParams::default();

    // 1-2. Layout and t = 0 settling, retried until the stack holds.
    let mut attempts = Vec::new();
    let (layout, rest0, stats0, relation, seat) = loop {
        let layout = layout::sample(&mut rng, config.objects, config.lathe_slices);
        let (rest, stats, seat) = settle_stack(&layout, &params);
        let rel = check_stack(&layout, &rest);
        let done = rel.verified || attempts.len() as u32 + 1 >= MAX_LAYOUT_ATTEMPTS;
        attempts.push(rel.clone());
        if done {
            break (layout, rest, stats, rel, seat);
        }
    };
    // t = 1: remove the support (or, if no stack held, the object closest to another one).
    let removed = if relation.verified {
        layout.stack.0
    } else {
        let n = rest0.len();
        (0..n)
            .min_by(|&a, &b| {
                let d = |i: usize| {
                    (0..n)
                        .filter(|&j| j != i)
                        .map(|j| rest0[i].translation.distance(rest0[j].translation))
                        .fold(f32::MAX, f32::min)
                };
                d(a).total_cmp(&d(b))
            })
            .unwrap_or(0)
    };
    let keep: Vec<usize> = (0..layout.objects.len())
        .filter(|&i| i != removed)
        .collect();
    let specs: Vec<BodySpec> = keep
        .iter()
        .map(|&i| BodySpec {
            hull_points: &layout.objects[i].model.hull_points,
            mass_kg: layout.objects[i].mass_kg,
            plate: layout.objects[i].plate,
        })
        .collect();
    let start1: Vec<Pose> = keep.iter().map(|&i| rest0[i]).collect();
    // Objects that rest on something other than the table (their lowest point is above
    // ON_TABLE_M) may have lost their support: they start awake. Everything standing on the table
    // starts asleep and only moves if something falling hits it.
    let wake: Vec<physics::Wake> = keep
        .iter()
        .map(|&i| {
            let lowest = layout.objects[i]
                .model
                .hull_points
                .iter()
                .map(|p| rest0[i].apply(*p).z)
                .fold(f32::MAX, f32::min);
            if lowest > ON_TABLE_M {
                physics::Wake::Awake
            } else {
                physics::Wake::Asleep
            }
        })
        .collect();
    let (mut rest1, stats1) = physics::settle(&specs, &start1, &wake, &params);
    let mut displacement = BTreeMap::new();
    let mut snapped = Vec::new();
    for (k, &i) in keep.iter().enumerate() {
        let pts = &layout.objects[i].model.mesh.positions;
        let max_mm = physics::max_vertex_displacement_mm(pts, &rest0[i], &rest1[k]);
        let snap = max_mm < physics::STATIC_SNAP_MM;
        if snap {
            rest1[k] = rest0[i];
            snapped.push(layout.objects[i].id);
        }
        displacement.insert(
            layout.objects[i].id.to_string(),
            Displacement {
                translation_mm: rest0[i].translation.distance(rest1[k].translation) * 1000.0,
                rotation_deg: physics::rotation_deg(&rest0[i], &rest1[k]),
                max_vertex_displacement_mm: if snap { 0.0 } else { max_mm },
                static_snapped: snap,
            },
        );
    }
    let physics_s = t_start.elapsed().as_secs_f64();

    // 3. Cameras around the workspace centre.
    let k = cameras::intrinsics(config.width, config.height);
    let mean = rest0
        .iter()
        .map(|p| p.translation.as_dvec3())
        .sum::<DVec3>()
        / rest0.len() as f64;
    let centre = DVec3::new(mean.x, mean.y, 0.03);
    let (train, ring) = cameras::train_views(k, centre, &mut rng);
    let test0 = cameras::test_views(k, centre, config.test_views, &mut rng);
    let test1 = cameras::test_views(k, centre, config.test_views, &mut rng);

    // 4-5. Render and write.
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
    let state0: Vec<(usize, Pose)> = rest0.iter().copied().enumerate().collect();
    let state1: Vec<(usize, Pose)> = keep.iter().copied().zip(rest1.iter().copied()).collect();
    let scenes = [
        RenderScene::new(&placed(&state0), layout.env),
        RenderScene::new(&placed(&state1), layout.env),
    ];
    let states = [&state0, &state1];
    let splits: [(&str, usize, Vec<trand_core::camera::Camera>); 4] = [
        ("train_0", 0, train.clone()),
        ("test_0", 0, test0),
        ("train_1", 1, vec![train[0]]),
        ("test_1", 1, test1),
    ];
    let total_rows: u64 = splits
        .iter()
        .map(|s| s.2.len() as u64 * config.height as u64)
        .sum();
    let bar = match config.progress {
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
    };
    let t_render = Instant::now();
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
    let render_s = t_render.elapsed().as_secs_f64();

    // Models and sequence.json.
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
    bop_writer::write_json(&models.join("models_info.json"), &FrameMap(infos))?;

    let objects = layout
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
            params_m: o.model.params.iter().copied().collect(),
            initial_mode: o.orientation,
            pose_t0: pose_info(&rest0[i]),
            pose_t1: keep
                .iter()
                .position(|&j| j == i)
                .map(|k| pose_info(&rest1[k])),
            removed_at_t1: i == removed,
        })
        .collect();
    let seq = Sequence {
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
            "t0": {"train": "train_0 (frame 0 bird's-eye, 1..12 ring)", "test": "test_0"},
            "t1": {"train": "train_1 (frame 0 only, same pose as train_0 frame 0)", "test": "test_1"}
        }),
        objects,
        relation_t0: relation,
        removed_obj_id: layout.objects[removed].id,
        removed_obj_kind: layout.objects[removed].model.kind,
        displacement_t0_to_t1: displacement,
        workspace_center_m: centre.to_array(),
        cameras: CamerasInfo {
            train_ring: ring,
            test: "uniform azimuth, elevation 20-70 deg, distance 0.45-0.8 m, looking at centre + U(+-4 cm, +-4 cm, +-2 cm)",
            test_views_per_state: config.test_views,
        },
        environment: layout.env,
        physics: PhysicsInfo {
            engine: "rapier3d 0.36 (single-threaded, fixed step)",
            collision_shape: "CONVEX_HULL (table: BOX)",
            params,
            static_snap_max_vertex_mm: physics::STATIC_SNAP_MM,
            t0: stats0,
            t1: stats1,
            layout_attempts: attempts,
            static_snapped_t1: snapped,
            t0_seat_correction: seat,
        },
        render: RenderInfo {
            engine: "trand-synth Whitted ray tracer (Fresnel/Snell dielectrics, Beer-Lambert absorption, area-light shadows)",
            spp: config.samples_per_pixel,
            rgb_filter: "box 1 px, jittered samples",
            data_passes: "1 ray at each pixel centre (exact depth and masks)",
            max_depth: trace::MAX_DEPTH,
            lathe_slices: config.lathe_slices,
        },
    };
    bop_writer::write_json(&dir.join("sequence.json"), &seq)?;
    let stack_verified = seq.relation_t0.verified;
    Ok(Summary {
        out: dir.to_path_buf(),
        views,
        removed_obj_id: seq.removed_obj_id,
        stack_verified,
        physics_s,
        render_s,
        total_s: t_start.elapsed().as_secs_f64(),
    })
}
