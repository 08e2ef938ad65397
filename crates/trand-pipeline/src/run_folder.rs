//! A finished run folder read back for rendering: its surfels, object channels and the render settings
//! it was made with (`trand render`, the Python package's `trand.load`).
//!
//! The settings come from the run's own files — near plane, SH degree and background from
//! `config.toml`, the far clamp from `run.json` — so that a camera of the run's sequence renders to the
//! depth the run wrote for it. Runs written before `depth_clamp_m` was recorded get the clamp of the
//! test cameras of the sequence `run.json` names.

use std::path::Path;

use trand_io::{IoError, LoadOptions, RunManifest, State, read_sequence_with};
use trand_render::RenderSettings;

use crate::{PipelineError, Result};

/// What a run folder says about how it renders.
pub struct RunRender {
    pub surfels: trand_core::Surfels,
    pub settings: RenderSettings,
    /// Far clamp of the depth (metres; infinity = none).
    pub clamp: f32,
    /// `(object id, channel)`.
    pub channels: Vec<(u16, usize)>,
    pub state: State,
    /// The whole `run.json`.
    pub run_json: RunManifest,
    /// The whole `config.toml`.
    pub config: toml::Value,
}

fn invalid(path: &Path, what: impl std::fmt::Display) -> PipelineError {
    PipelineError::Invalid(format!("{}: {what}", path.display()))
}

fn train_number(cfg: &toml::Value, path: &Path, key: &str) -> Result<f64> {
    let v = cfg
        .get("train")
        .and_then(|t| t.get(key))
        .ok_or_else(|| invalid(path, format!("field `train.{key}` missing")))?;
    v.as_float()
        .or_else(|| v.as_integer().map(|i| i as f64))
        .ok_or_else(|| invalid(path, format!("field `train.{key}` is not a number")))
}

/// The far clamp the run used: `run.json`'s `depth_clamp_m` (null = none), or for runs written before
/// it was recorded, recomputed from the test cameras of the sequence the run names.
fn clamp_of(run_json: &RunManifest, state: State, json_path: &Path) -> Result<f32> {
    if let Some(clamp) = run_json.depth_clamp_m {
        return Ok(clamp.unwrap_or(f32::INFINITY));
    }
    let data = run_json.data.as_deref().ok_or_else(|| {
        invalid(
            json_path,
            "neither `depth_clamp_m` nor `data` (the sequence) is recorded",
        )
    })?;
    let seq = read_sequence_with(data, &LoadOptions::cameras_only()).map_err(|e| {
        invalid(
            json_path,
            format!("field `data`: reading the run's sequence: {e}"),
        )
    })?;
    let views = seq.views(trand_io::Split::Test, state);
    Ok(crate::outputs::depth_clamp(views))
}

/// Reads a run folder's surfels, render settings, far clamp and object channels.
pub fn load_run(run: &Path) -> Result<RunRender> {
    let json_path = run.join(trand_io::run_layout::RUN_JSON);
    let run_json = RunManifest::read(run)?.ok_or_else(|| {
        invalid(
            run,
            format!("not a run folder (no {})", json_path.display()),
        )
    })?;
    let state: State = run_json
        .state()
        .ok()
        .flatten()
        .ok_or_else(|| invalid(&json_path, "field `state` must be t0 or t1"))?;
    let channels = run_json
        .object_channels
        .clone()
        .ok_or_else(|| invalid(&json_path, "field `object_channels` is missing"))?;
    let cfg_path = run.join("config.toml");
    let text = std::fs::read_to_string(&cfg_path).map_err(|e| IoError::io(&cfg_path, e))?;
    let config: toml::Value =
        toml::from_str(&text).map_err(|e| invalid(&cfg_path, format!("invalid TOML: {e}")))?;
    let background = config
        .get("train")
        .and_then(|t| t.get("background"))
        .and_then(|b| b.as_array())
        .filter(|b| b.len() == 3)
        .and_then(|b| {
            let c: Vec<f32> = b
                .iter()
                .filter_map(|x| x.as_float())
                .map(|x| x as f32)
                .collect();
            <[f32; 3]>::try_from(c).ok()
        })
        .ok_or_else(|| invalid(&cfg_path, "field `train.background` must be 3 numbers"))?;
    let settings = RenderSettings {
        background,
        near: train_number(&config, &cfg_path, "near")? as f32 as f64,
        sh_degree: Some(train_number(&config, &cfg_path, "sh_degree")? as u32),
        ..Default::default()
    };
    let surfels = trand_io::read_surfels_ply(&run.join("surfels.ply"))?;
    Ok(RunRender {
        clamp: clamp_of(&run_json, state, &json_path)?,
        surfels,
        settings,
        channels,
        state,
        run_json,
        config,
    })
}
