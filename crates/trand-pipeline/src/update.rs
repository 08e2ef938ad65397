//! The t = 1 scene update after objects are taken away (paper §3.4, official-code notes §5 with the
//! choices of §10):
//!
//! 1. **Detection** ([`crate::detect`]): the t = 0 objects missing from the new mask's ids were
//!    removed; for per-image ids, overlap matching of the rendered t = 0 objects (Hungarian on IoU and
//!    centroid distance). `removed` overrides both. Finding nothing removed is a valid outcome.
//! 2. **Deletion** of every surfel whose softmax probability of a removed object exceeds ½.
//! 3. **Meshing** ([`crate::simulate`]): depth of the remaining surfels (expected depth by default, §10 row 14) from a ring of
//!    virtual views plus one from below the table, TSDF fusion, surface nets, vertices labelled by the
//!    nearest object surfel.
//! 4. **Particles**: object surfel centres plus mesh vertices (optional interior fill).
//! 5. **MLS-MPM**, all objects in one solver; each surfel moves with its particle (optionally also
//!    rotating by the particle's polar rotation).
//! 6. **Relocalisation** (trand's addition, [`crate::relocalise`]): every object the simulation could
//!    move is searched for the pose at rest (on the table or on the other objects, in any
//!    orientation) that best explains its instance mask and colours in the new image, with the
//!    simulated pose as a prior; it replaces the simulated pose only when clearly better. An object the
//!    simulation could not move is searched only when its silhouette misses its mask or fits it far
//!    better shifted alone (knocked aside by a falling one: [`crate::new_camera`]).
//! 7. **Refinement**: 100 iterations on the single new image (no object-aware loss, opacity lr 0.5,
//!    object lr 0.1, densification with the t = 0 scene extent). Afterwards every object that may not
//!    have moved (not movable, not searched) gets its t = 0 surfels back ([`RefineScope::Moved`]): one
//!    image with a segmenter's boundaries only drags what six views fixed (BENCHMARKS.md §1).

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use trand_core::{Mesh, Surfels};
use trand_io::View;
use trand_render::{GeometryMaps, Maps, RenderSettings};

pub use crate::detect::{Identity, Match, detect};
use crate::new_camera::CameraCorrection;
use crate::relocalise::{NewImage, Object, Reason, Relocation, relocalise};
pub use crate::simulate::{Simulation, simulate, virtual_cameras};
use crate::surfel_ops::channel_probs;
use crate::targets::{self, Supervision};
use crate::trainer::{StepReport, Trainer};
pub use crate::update_options::{
    MeshDepth, RefineScope, SceneScale, Stage, SurfelMotion, UpdateOptions,
};
use crate::{PipelineError, Result};

/// Result of an update.
#[derive(Clone, Debug)]
pub struct Update {
    pub surfels: Surfels,
    pub matches: Vec<Match>,
    pub removed: Vec<u16>,
    pub deleted_surfels: usize,
    /// Which detection rule was used (`Auto` resolved).
    pub identity: Identity,
    pub relocations: Vec<Relocation>,
    /// The new photo's camera as corrected by the unmoved objects (`None`: not tried).
    pub camera_correction: Option<CameraCorrection>,
    /// Objects in contact (transitively) with a removed one: the only ones the simulation may move.
    pub movable: Vec<u16>,
    pub mesh: Option<Mesh>,
    pub num_particles: usize,
    /// MPM frames simulated (fewer than configured when the scene came to rest; 0 without physics).
    pub simulated_frames: u32,
    pub max_displacement_m: f32,
    pub detection_s: f64,
    pub meshing_s: f64,
    pub simulation_s: f64,
    pub relocalisation_s: f64,
    pub refinement_s: f64,
    pub curve: Vec<(u32, f32)>,
}

/// Runs the whole update of `surfels` (the t = 0 run's object surfels) given the new view.
#[allow(clippy::too_many_arguments)]
pub fn update(
    surfels: Surfels,
    channels: &[(u16, usize)],
    new_view: &View,
    scale: SceneScale,
    supervision: Supervision,
    opts: &UpdateOptions,
    progress: &mut dyn FnMut(&str, u32, u32),
    on_step: &mut dyn FnMut(&StepReport),
) -> Result<Update> {
    let never = AtomicBool::new(false);
    update_with_cancel(
        surfels,
        channels,
        new_view,
        scale,
        supervision,
        opts,
        progress,
        on_step,
        &never,
    )
}

/// [`update`] that stops with [`PipelineError::Interrupted`] soon after `cancel` is set: between
/// stages, after every meshing view and simulated frame, and after every refinement iteration.
#[allow(clippy::too_many_arguments)]
pub fn update_with_cancel(
    mut surfels: Surfels,
    channels: &[(u16, usize)],
    new_view: &View,
    scale: SceneScale,
    supervision: Supervision,
    opts: &UpdateOptions,
    progress: &mut dyn FnMut(&str, u32, u32),
    on_step: &mut dyn FnMut(&StepReport),
    cancel: &AtomicBool,
) -> Result<Update> {
    let stop = |it: u32| {
        if cancel.load(Ordering::SeqCst) {
            Err(PipelineError::Interrupted(it))
        } else {
            Ok(())
        }
    };
    let settings = RenderSettings {
        background: opts.train.background,
        near: opts.train.near as f64,
        sh_degree: Some(opts.train.sh_degree),
        maps: Maps::Rgb,
        geometry: GeometryMaps::Rendered,
    };
    let t0 = Instant::now();
    let object_aware = supervision == Supervision::ObjectAware;
    opts.validate()?;
    if object_aware {
        targets::check_channels(channels, surfels.num_objects)
            .map_err(|r| PipelineError::Invalid(format!("object channels: {r}")))?;
    }
    let ground = match opts.mpm.ground {
        trand_physics::Ground::Sticky { height } => height as f64,
        trand_physics::Ground::None => 0.0,
    };
    let centres = crate::contact::object_centres(&surfels, channels);
    let alone: Vec<u16> = centres
        .iter()
        .filter(|(_, p)| crate::contact::stands_alone(p, ground as f32))
        .map(|(id, _)| *id)
        .collect();
    // Which objects a removal could move, for telling the removed from the fallen without ids.
    let movable_if = |removed: &[u16]| -> Vec<u16> {
        let mut m = crate::contact::may_move(&centres, removed);
        m.retain(|id| !alone.contains(id));
        m
    };
    let (matches, identity) = if object_aware {
        detect(
            &surfels,
            channels,
            new_view,
            &settings,
            opts.centroid_weight,
            opts.identity,
            &movable_if,
        )?
    } else {
        (Vec::new(), opts.identity)
    };
    let removed: Vec<u16> = match &opts.removed {
        Some(r) => {
            for id in r {
                if !channels.iter().any(|&(i, _)| i == *id) {
                    return Err(PipelineError::Invalid(format!(
                        "--removed {id}: no such object at t=0 (objects: {:?})",
                        channels.iter().map(|c| c.0).collect::<Vec<_>>()
                    )));
                }
            }
            r.clone()
        }
        None => matches
            .iter()
            .filter(|m| m.new_id.is_none())
            .map(|m| m.object_id)
            .collect(),
    };
    let movable = crate::contact::may_move(&centres, &removed);
    // A t = 0 object's instance id in the new mask, if it was found there.
    let new_id_of = |id: u16| matches.iter().find(|m| m.object_id == id)?.new_id;
    // The new camera, turned to fit the objects the removal cannot have moved.
    let mut new_view = std::borrow::Cow::Borrowed(new_view);
    let mut camera_correction = None;
    if let (true, Some(inst)) = (object_aware, new_view.instance.as_ref()) {
        let unmoved: Vec<(usize, u16)> = channels
            .iter()
            .filter(|(id, _)| !removed.contains(id) && !movable.contains(id))
            .filter_map(|&(id, c)| Some((c, new_id_of(id)?)))
            .collect();
        let (camera, report) = crate::new_camera::correct(
            &surfels,
            &unmoved,
            &new_view.camera,
            inst,
            &settings,
            opts.correct_camera,
        )?;
        if report.as_ref().is_some_and(|r| r.applied) {
            new_view.to_mut().camera = camera;
        }
        camera_correction = report;
    }
    let new_view: &View = &new_view;
    let relocalising = opts.relocalise == Stage::On && object_aware;
    // The removed objects as they were, for the relocalisation's t = 0 scene.
    let mut removed_surfels: Vec<Surfels> = Vec::new();
    let before = surfels.len();
    for &id in &removed {
        let c = channels
            .iter()
            .find(|x| x.0 == id)
            .expect("checked above")
            .1;
        let p = channel_probs(&surfels, c);
        let keep: Vec<bool> = p.iter().map(|&v| v <= 0.5).collect();
        if relocalising {
            let idx: Vec<usize> = (0..p.len()).filter(|&i| !keep[i]).collect();
            removed_surfels.push(surfels.gather(&idx));
        }
        surfels.retain(&keep);
    }
    let deleted = before - surfels.len();
    let detection_s = t0.elapsed().as_secs_f64();
    stop(0)?;

    let remaining: Vec<(u16, usize)> = channels
        .iter()
        .copied()
        .filter(|c| !removed.contains(&c.0))
        .collect();
    // The undeformed shapes, for the relocalisation's candidates (only copied when it will run).
    let unmoved = relocalising.then(|| surfels.clone());
    let (mesh, num_particles, simulated_frames, max_disp, meshing_s, simulation_s) =
        if opts.physics == Stage::On && object_aware && !surfels.is_empty() {
            let s = simulate(
                &mut surfels,
                &remaining,
                &movable,
                scale,
                opts,
                &settings,
                progress,
                cancel,
            )?;
            (
                Some(s.mesh),
                s.num_particles,
                s.frames,
                s.max_displacement_m,
                s.meshing_s,
                s.simulation_s,
            )
        } else {
            (None, 0, 0, 0.0, 0.0, 0.0)
        };

    let t_reloc = Instant::now();
    // Objects knocked aside (their new ids), searched although the removal could not move them.
    let displaced = camera_correction
        .as_ref()
        .map_or(Vec::new(), |c| c.displaced.clone());
    let mut relocations = Vec::new();
    if let (Some(unmoved), Some(inst)) = (&unmoved, new_view.instance.as_ref()) {
        let objects: Vec<Object> = remaining
            .iter()
            .filter_map(|&(id, c)| {
                let new_id = new_id_of(id)?;
                Some(Object {
                    id,
                    surfels: crate::simulate::channel_members(&surfels, c),
                    new_id,
                    displaced: displaced.contains(&new_id),
                })
            })
            .collect();
        let image = NewImage {
            camera: &new_view.camera,
            instance: inst,
            rgb: new_view.rgb.as_ref(),
        };
        relocations = relocalise(
            &mut surfels,
            unmoved,
            &removed_surfels,
            &objects,
            &movable,
            &image,
            ground,
            &settings,
            &opts.relocalise_settings,
        )?;
    }
    drop(unmoved);
    let relocalisation_s = t_reloc.elapsed().as_secs_f64();
    stop(0)?;

    let t3 = Instant::now();
    let mut curve = Vec::new();
    if opts.refine == Stage::On && !surfels.is_empty() {
        // Targets of the new image: new instance ids take the channel of the t = 0 object they matched;
        // unmatched new instances are treated as background.
        let mut view = new_view.clone();
        let mut map: Vec<(u16, usize)> = Vec::new();
        if object_aware {
            if let Some(inst) = view.instance.as_mut() {
                let lookup: Vec<(u16, u16)> = matches
                    .iter()
                    .filter(|m| !removed.contains(&m.object_id))
                    .filter_map(|m| m.new_id.map(|n| (n, m.object_id)))
                    .collect();
                for v in inst.data.iter_mut() {
                    *v = lookup.iter().find(|l| l.0 == *v).map_or(0, |l| l.1);
                }
            }
            map = remaining.clone();
        }
        let ds = opts.downsample.unwrap_or(scale.downsample);
        let edges = targets::MaskEdges::for_view(&opts.train.image_loss, &view);
        let build = |factor: u32| {
            targets::build(
                &view,
                &map,
                surfels.num_objects,
                opts.train.background,
                supervision,
                (factor, &edges),
            )
        };
        let views = [build(ds)?];
        let native = view.rgb.as_ref().map_or((0, 0), |i| (i.width, i.height));
        let coarse =
            targets::coarse_views(&opts.train.resolution, ds, native, |f| Ok(vec![build(f)?]))?;
        // Objects nothing moved keep their t = 0 surfels (RefineScope::Moved): put back after.
        let frozen: Vec<usize> = match opts.refine_scope {
            RefineScope::All => Vec::new(),
            RefineScope::Moved => remaining
                .iter()
                .filter(|(id, _)| {
                    !movable.contains(id)
                        && !relocations
                            .iter()
                            .any(|r: &Relocation| r.object_id == *id && r.reason != Reason::Static)
                })
                .map(|&(_, c)| c)
                .collect(),
        };
        let kept = members_of(&surfels, &frozen);
        let kept = surfels.gather(&kept);
        let mut trainer = Trainer::new(
            surfels,
            opts.train.clone(),
            &views,
            scale.extent,
            supervision,
        )
        .with_coarse(&coarse);
        let last = opts.train.start_iteration + opts.train.iterations;
        for it in opts.train.start_iteration + 1..=last {
            let rep = trainer.step(it, it == last)?;
            curve.push((it, rep.loss));
            on_step(&rep);
            if it < last {
                stop(it)?;
            }
            if opts.train.early_stop.stops(&curve) {
                break;
            }
        }
        surfels = trainer.surfels;
        let refined_frozen = members_of(&surfels, &frozen);
        let mut keep = vec![true; surfels.len()];
        for i in refined_frozen {
            keep[i] = false;
        }
        surfels.retain(&keep);
        surfels.append(&kept);
    }
    let refinement_s = t3.elapsed().as_secs_f64();
    Ok(Update {
        surfels,
        matches,
        removed,
        deleted_surfels: deleted,
        identity,
        relocations,
        camera_correction,
        movable,
        mesh,
        num_particles,
        simulated_frames,
        max_displacement_m: max_disp,
        detection_s,
        meshing_s,
        simulation_s,
        relocalisation_s,
        refinement_s,
        curve,
    })
}

/// Indices of the surfels of objects `channels` (channel probability above ½), ascending.
fn members_of(surfels: &Surfels, channels: &[usize]) -> Vec<usize> {
    let mut out: Vec<usize> = channels
        .iter()
        .flat_map(|&c| crate::simulate::channel_members(surfels, c))
        .map(|i| i as usize)
        .collect();
    out.sort_unstable();
    out.dedup();
    out
}
