//! A reconstructed scene held in memory: what `trand.Scene` wraps, in plain Rust (no Python types),
//! so that it is tested by `cargo test` like the rest of the workspace.
//!
//! A [`Scene`] is what a run folder holds — surfels, object channels, the render settings and far
//! clamp — plus what the t = 1 update needs from t = 0 (the options and the scene scale). It is made by
//! [`Scene::reconstruct`] from in-memory views, by [`Scene::update`] from another scene, or read from a
//! run folder by [`Scene::load`]; [`Scene::save`] writes a run folder that `trand render` and
//! `trand update` read. Nothing here changes a scene: an update returns a new one.

use std::path::Path;
use std::sync::atomic::AtomicBool;

use serde_json::json;
use trand_core::{Camera, Surfels};
use trand_io::{IoError, LoadOptions, Sequence, State, View};
use trand_pipeline::associate::Identity;
use trand_pipeline::at_cameras::{CameraMaps, render_at};
use trand_pipeline::update::{SceneScale, UpdateOptions, update_with_cancel};
use trand_pipeline::{PipelineError, ReconstructOptions, StepReport, Supervision};
use trand_render::RenderSettings;

/// Why a scene operation failed.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// A bad argument: the argument's name and what is wrong with it.
    #[error("{arg}: {reason}")]
    Argument { arg: String, reason: String },
    #[error(transparent)]
    Pipeline(#[from] PipelineError),
    #[error(transparent)]
    Io(#[from] IoError),
}

impl SceneError {
    pub fn argument(arg: impl Into<String>, reason: impl Into<String>) -> Self {
        Self::Argument {
            arg: arg.into(),
            reason: reason.into(),
        }
    }
}

pub type Result<T> = std::result::Result<T, SceneError>;

/// Surfels and everything needed to render and update them.
#[derive(Clone, Debug)]
pub struct Scene {
    pub surfels: Surfels,
    /// `(object id, channel)`.
    pub channels: Vec<(u16, usize)>,
    pub settings: RenderSettings,
    /// Far clamp of rendered depth, metres (infinity: none).
    pub clamp: f32,
    pub state: State,
    /// The t = 0 options (`None` for a t = 1 scene, which cannot be updated again).
    pub options: Option<ReconstructOptions>,
    /// The t = 0 scene's scale, which the update needs; `None` when a loaded run records neither it
    /// nor a readable sequence.
    pub scale: Option<SceneScale>,
    /// How the t = 0 masks' ids were taken (`ObjectIds` or `Overlap`).
    pub identity_used: Identity,
    /// Objects taken away at t = 1.
    pub removed: Vec<u16>,
    /// What `run.json` holds when saved.
    pub report: serde_json::Value,
    /// What `config.toml` holds when saved.
    pub config: String,
}

/// Depth beyond twice the distance of the nearest camera from the point the cameras look at is
/// clamped, the rule `trand reconstruct` applies with its test cameras.
fn clamp_of(views: &[View]) -> f32 {
    trand_pipeline::outputs::depth_clamp(views)
}

fn render_settings(opts: &ReconstructOptions) -> RenderSettings {
    RenderSettings {
        background: opts.train.background,
        near: opts.train.near as f64,
        sh_degree: Some(opts.train.sh_degree),
        ..Default::default()
    }
}

fn scale_json(s: &SceneScale) -> serde_json::Value {
    json!({ "extent": s.extent, "radius": s.radius, "downsample": s.downsample })
}

fn scale_from_json(v: &serde_json::Value) -> Option<SceneScale> {
    Some(SceneScale {
        extent: v.get("extent")?.as_f64()? as f32,
        radius: v.get("radius")?.as_f64()? as f32,
        downsample: v.get("downsample")?.as_u64()?.try_into().ok()?,
    })
}

impl Scene {
    /// The t = 0 reconstruction from `views` (their images, instance masks and cameras), trained on
    /// all of them in this order. `on_step` sees every iteration; setting `cancel` stops after the
    /// current one with [`PipelineError::Interrupted`].
    pub fn reconstruct(
        views: Vec<View>,
        opts: &ReconstructOptions,
        on_step: &mut dyn FnMut(&StepReport),
        cancel: &AtomicBool,
    ) -> Result<Scene> {
        opts.validate()?;
        let load = LoadOptions {
            object_channels: Some(opts.num_objects),
            ..Default::default()
        };
        let seq = Sequence::from_train_views("(arrays)", views, &load)
            .map_err(|e| SceneError::argument(e.field, e.reason))?;
        if seq.object_ids.is_empty() && opts.method.supervision() == Supervision::ObjectAware {
            return Err(SceneError::argument(
                "masks",
                "no object pixels in any mask (0 is background)",
            ));
        }
        let rec = trand_pipeline::reconstruct(&seq, opts, None, &mut |r, _| on_step(r), cancel)?;
        let cams: Vec<Camera> = seq.train_t0.iter().map(|v| v.camera).collect();
        let scale = SceneScale::from_cameras(&cams, opts.downsample);
        let clamp = clamp_of(&seq.train_t0);
        let report = json!({
            "state": "t0",
            "method": opts.method,
            "views": seq.train_t0.len(),
            "data": null,
            "source": "arrays (the Python package)",
            "sequence_fingerprint": null,
            "train_views": rec.train_views,
            "depth_clamp_m": clamp.is_finite().then_some(clamp),
            "depth_views": "none",
            "scene_scale": scale_json(&scale),
            "object_channels": rec.channels,
            "vessel_tops": rec.vessel_tops,
            "mask_agreement": { "measured": rec.mask_agreement, "rule": opts.overhangs, "overhangs": rec.overhangs },
            "identity": rec.identity,
            "mask_edges": { "rule": opts.train.image_loss.snap_masks, "grown_to_image_edges": rec.grown_to_image_edges },
            "table_height": rec.table,
            "support_prior": { "mode": opts.support, "applied": rec.support_applied },
            "front_fill": { "mode": opts.front_fill, "surfels_added": rec.front_fill_added },
            "table_alignment": { "mode": opts.table_align, "found": rec.table_alignment },
            "missed_masks": {
                "mode": opts.missed_masks,
                "fill": opts.missed_fill,
                "redrawn": rec.missed_masks,
            },
            "timings": {
                "preprocess_s": rec.preprocess_s,
                "optimise_s": rec.optimise_s,
                "total_s": rec.preprocess_s + rec.optimise_s,
            },
            "initial_surfels": rec.initial_surfels,
            "num_trained": rec.num_trained,
            "num_surfels": rec.surfels.len(),
            "loss_curve": rec.curve,
            "threads": rayon::current_num_threads(),
            "trand_version": env!("CARGO_PKG_VERSION"),
        });
        let config = toml::to_string(opts)
            .map_err(|e| PipelineError::Invalid(format!("serialising the options: {e}")))?;
        Ok(Scene {
            surfels: rec.surfels,
            channels: rec.channels,
            settings: render_settings(opts),
            clamp,
            state: State::T0,
            options: Some(opts.clone()),
            scale: Some(scale),
            identity_used: rec.identity.used,
            removed: Vec::new(),
            report,
            config,
        })
    }

    /// Depth, object ids, alpha and normals at `camera`, as `trand render` gives them; depth beyond
    /// `far` metres (default: the scene's clamp) is clamped to it.
    pub fn render(&self, camera: &Camera, far: Option<f32>) -> Result<CameraMaps> {
        Ok(render_at(
            &self.surfels,
            camera,
            &self.settings,
            far.unwrap_or(self.clamp),
            &self.channels,
        )?)
    }

    /// The object ids present: the t = 0 objects less those removed.
    pub fn object_ids(&self) -> Vec<u16> {
        self.channels
            .iter()
            .map(|c| c.0)
            .filter(|id| !self.removed.contains(id))
            .collect()
    }

    /// Surfel centres, all of them or those of object `id` (its channel's probability above ½, the
    /// update's rule for which surfels belong to an object).
    pub fn points(&self, id: Option<u16>) -> Result<Vec<[f32; 3]>> {
        let Some(id) = id else {
            return Ok(self.surfels.means.clone());
        };
        let c = self
            .channels
            .iter()
            .find(|c| c.0 == id)
            .filter(|_| !self.removed.contains(&id))
            .ok_or_else(|| {
                SceneError::argument(
                    "object_id",
                    format!(
                        "no object {id} in the scene (objects: {:?})",
                        self.object_ids()
                    ),
                )
            })?
            .1;
        Ok(trand_pipeline::simulate::channel_members(&self.surfels, c)
            .into_iter()
            .map(|i| self.surfels.means[i as usize])
            .collect())
    }

    /// The t = 1 update from one new view (its image, instance mask and camera), as `trand update`
    /// does it: `removed` overrides the detection, `identity` says how the new mask's ids are read
    /// (`Auto` becomes `Overlap` when the t = 0 masks needed association). `self` is left unchanged.
    pub fn update(
        &self,
        view: &View,
        removed: Option<Vec<u16>>,
        identity: Identity,
        progress: &mut dyn FnMut(&str, u32, u32),
        cancel: &AtomicBool,
    ) -> Result<Scene> {
        let (Some(ropts), State::T0) = (&self.options, self.state) else {
            return Err(SceneError::argument(
                "self",
                "the update needs a t=0 scene (this one is already updated)",
            ));
        };
        let scale = self.scale.ok_or_else(|| {
            SceneError::argument(
                "self",
                "this run records neither `scene_scale` nor a readable sequence (`data` in run.json), \
                 so the t=0 scene scale the update needs is unknown",
            )
        })?;
        let inst = view
            .instance
            .as_ref()
            .ok_or_else(|| SceneError::argument("mask", "missing"))?;
        if inst.data.iter().all(|&i| i == 0) {
            return Err(SceneError::argument(
                "mask",
                "the new image's mask is empty (no object pixels)",
            ));
        }
        if let Some(id) = removed
            .iter()
            .flatten()
            .find(|id| !self.channels.iter().any(|c| c.0 == **id))
        {
            return Err(SceneError::argument(
                "removed",
                format!("no object {id} at t=0 (objects: {:?})", self.object_ids()),
            ));
        }
        let mut opts = UpdateOptions {
            removed,
            identity,
            ..UpdateOptions::default()
        };
        if identity == Identity::Auto && self.identity_used == Identity::Overlap {
            opts.identity = Identity::Overlap;
        }
        opts.train.background = ropts.train.background;
        opts.train.sh_degree = ropts.train.sh_degree;
        opts.train.near = ropts.train.near;
        let (first, iterations) = (opts.train.start_iteration, opts.train.iterations);
        let progress = std::cell::RefCell::new(progress);
        let up = update_with_cancel(
            self.surfels.clone(),
            &self.channels,
            view,
            scale,
            ropts.method.supervision(),
            &opts,
            &mut |stage, i, n| (progress.borrow_mut())(stage, i, n),
            &mut |r| (progress.borrow_mut())("refinement", r.iteration - first, iterations),
            cancel,
        );
        let up = up?;
        let mut report = json!({
            "state": "t1",
            "method": ropts.method,
            "views": self.report["views"],
            "t0_run": null,
            "data": null,
            "source": "arrays (the Python package)",
            "sequence_fingerprint": null,
            "new_image": view.name,
            "depth_clamp_m": self.clamp.is_finite().then_some(self.clamp),
            "object_channels": self.channels,
            "matching": up.matches,
            "removed": up.removed,
            "removed_by": if opts.removed.is_some() { "user" } else { "detection" },
            "identity": up.identity,
            "identity_from_t0": self.identity_used == Identity::Overlap,
            "relocations": up.relocations,
            "camera_correction": up.camera_correction,
            "movable": up.movable,
            "deleted_surfels": up.deleted_surfels,
            "num_particles": up.num_particles,
            "simulated_frames": up.simulated_frames,
            "max_surfel_displacement_m": up.max_displacement_m,
            "timings": {
                "detection_s": up.detection_s,
                "meshing_s": up.meshing_s,
                "simulation_s": up.simulation_s,
                "relocalisation_s": up.relocalisation_s,
                "refinement_s": up.refinement_s,
            },
            "num_surfels": up.surfels.len(),
            "loss_curve": up.curve,
            "trand_version": env!("CARGO_PKG_VERSION"),
        });
        report["scene_scale"] = scale_json(&scale);
        let config = toml::to_string(&opts)
            .map_err(|e| PipelineError::Invalid(format!("serialising the options: {e}")))?;
        Ok(Scene {
            surfels: up.surfels,
            channels: self.channels.clone(),
            settings: self.settings,
            clamp: self.clamp,
            state: State::T1,
            options: None,
            scale: Some(scale),
            identity_used: self.identity_used,
            removed: up.removed,
            report,
            config,
        })
    }

    /// Writes a run folder at `path` (which must not exist): `surfels.ply`, `config.toml` and
    /// `run.json`, as `trand reconstruct` / `trand update` write them, without test-view depth.
    pub fn save(&self, path: &Path) -> Result<()> {
        trand_io::output::check_new_output(path)?;
        let mut report = self.report.clone();
        report["num_surfels"] = json!(self.surfels.len());
        let manifest: trand_io::RunManifest = serde_json::from_value(report)
            .map_err(|e| PipelineError::Invalid(format!("the run report: {e}")))?;
        trand_pipeline::outputs::write_run(path, &manifest, &self.config, &self.surfels, &[])?;
        Ok(())
    }

    /// Reads a run folder written by `trand reconstruct`, `trand update` or [`Scene::save`].
    pub fn load(path: &Path) -> Result<Scene> {
        if !path.is_dir() {
            return Err(IoError::Missing {
                path: path.into(),
                what: "run folder".into(),
            }
            .into());
        }
        let r = trand_pipeline::run_folder::load_run(path)?;
        let ply = path.join("surfels.ply");
        r.surfels.validate().map_err(|e| {
            PipelineError::Invalid(format!("{}: unusable surfels: {e}", ply.display()))
        })?;
        let cfg_path = path.join("config.toml");
        let config = std::fs::read_to_string(&cfg_path).map_err(|e| IoError::io(&cfg_path, e))?;
        let options = match r.state {
            State::T0 => {
                let o: ReconstructOptions = toml::from_str(&config).map_err(|e| {
                    PipelineError::Invalid(format!(
                        "{}: invalid configuration: {e}",
                        cfg_path.display()
                    ))
                })?;
                o.validate()?;
                if o.method.supervision() == Supervision::ObjectAware {
                    trand_pipeline::targets::check_channels(&r.channels, r.surfels.num_objects)
                        .map_err(|e| {
                            PipelineError::Invalid(format!(
                                "{}: field `object_channels`: {e}",
                                path.join("run.json").display()
                            ))
                        })?;
                }
                Some(o)
            }
            State::T1 => None,
        };
        let identity_used = match r.run_json.identity_used() {
            Some("overlap") => Identity::Overlap,
            _ => Identity::ObjectIds,
        };
        let details = &r.run_json.details;
        let scale = details
            .get("scene_scale")
            .and_then(scale_from_json)
            .or_else(|| scale_from_sequence(r.run_json.data.as_deref(), options.as_ref()));
        let removed = details
            .get("removed")
            .and_then(|v| serde_json::from_value(v.clone()).ok())
            .unwrap_or_default();
        let report = serde_json::to_value(&r.run_json).unwrap_or_default();
        Ok(Scene {
            surfels: r.surfels,
            channels: r.channels,
            settings: r.settings,
            clamp: r.clamp,
            state: r.state,
            options,
            scale,
            identity_used,
            removed,
            report,
            config,
        })
    }
}

/// The scale `trand update` computes for a run of the CLI: from the training ring of the sequence
/// `run.json` names, as the run's `views` selects it.
fn scale_from_sequence(
    data: Option<&str>,
    opts: Option<&ReconstructOptions>,
) -> Option<SceneScale> {
    let opts = opts?;
    let data = data?;
    let seq = trand_io::read_sequence_with(data, &LoadOptions::cameras_only()).ok()?;
    let views = match seq.train_selection {
        trand_io::TrainSelection::Listed => seq.train_t0.clone(),
        trand_io::TrainSelection::Ring => trand_io::select_train_views(
            &seq.train_t0,
            trand_io::ViewCount::from_count(opts.views as usize)?,
        ),
    };
    let cams: Vec<Camera> = views.iter().map(|v| v.camera).collect();
    Some(SceneScale::from_cameras(&cams, opts.downsample))
}

#[cfg(test)]
#[path = "scene_tests.rs"]
mod tests;
