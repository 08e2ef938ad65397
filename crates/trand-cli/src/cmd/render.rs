//! `trand render`: a finished run's depth, object ids, alpha and normals at the user's cameras.
//!
//! ```text
//! OUT/NAME_depth.npy    float32 (H, W) median depth, metres, 0 = nothing
//! OUT/NAME_depth.png    uint16 millimetres
//! OUT/NAME_ids.png      uint16 object id (the sequence's ids; 0 = background)
//! OUT/NAME_objects.png  the same colour-coded, as the run's objects/ images
//! OUT/NAME_alpha.npy    float32 (H, W) accumulated opacity; NAME_alpha.png as 8 bits
//! OUT/NAME_normal.npy   float32 (H, W, 3) unit normals in the camera frame (OpenCV); NAME_normal.png
//!                       as (n + 1)/2 colours
//! ```
//! The run's own render settings are used (near plane, SH degree, background from `config.toml`, the
//! far clamp from `run.json`), so a test camera of the run's sequence gives exactly the depth the run
//! wrote for it. The camera file is checked whole before anything is rendered, and the output folder
//! appears only when every file is written.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use trand_io::{Image, LoadOptions, RunManifest, State, read_sequence_with};
use trand_pipeline::at_cameras::{CameraMaps, render_at};
use trand_pipeline::targets::palette;

#[derive(clap::Args)]
pub struct Args {
    /// A finished run folder (t=0 or t=1).
    #[arg(long)]
    pub run: PathBuf,
    /// JSON list of cameras: {"name", "K" (3x3 row-major), "world_to_camera" (4x4 row-major, metres,
    /// OpenCV axes), "width", "height"}.
    #[arg(long)]
    pub cameras: PathBuf,
    /// Output folder (must not exist).
    #[arg(long)]
    pub out: PathBuf,
}

/// What a run folder says about how it renders.
pub(crate) struct RunRender {
    pub surfels: trand_core::Surfels,
    pub settings: trand_render::RenderSettings,
    pub clamp: f32,
    pub channels: Vec<(u16, usize)>,
    pub state: State,
}

fn toml_f64(cfg: &toml::Value, path: &Path, key: &str) -> anyhow::Result<f64> {
    let v = cfg
        .get("train")
        .and_then(|t| t.get(key))
        .with_context(|| format!("{}: field `train.{key}` missing", path.display()))?;
    v.as_float()
        .or_else(|| v.as_integer().map(|i| i as f64))
        .with_context(|| format!("{}: field `train.{key}` is not a number", path.display()))
}

/// The far clamp the run used: `run.json`'s `depth_clamp_m` (null = none), or for runs written before
/// it was recorded, recomputed from the test cameras of the sequence the run names.
fn clamp_of(run_json: &RunManifest, state: State, json_path: &Path) -> anyhow::Result<f32> {
    if let Some(clamp) = run_json.depth_clamp_m {
        return Ok(clamp.unwrap_or(f32::INFINITY));
    }
    let data = run_json.data.as_deref().with_context(|| {
        format!(
            "{}: neither `depth_clamp_m` nor `data` (the sequence) is recorded",
            json_path.display()
        )
    })?;
    let seq = read_sequence_with(data, &LoadOptions::cameras_only()).with_context(|| {
        format!(
            "{}: field `data`: reading the run's sequence",
            json_path.display()
        )
    })?;
    let views = seq.views(trand_io::Split::Test, state);
    Ok(trand_pipeline::outputs::depth_clamp(views))
}

/// Reads a run folder's surfels, render settings, far clamp and object channels.
pub(crate) fn load_run(run: &Path) -> anyhow::Result<RunRender> {
    let json_path = run.join(trand_io::run_layout::RUN_JSON);
    let run_json = RunManifest::read(run)?.with_context(|| {
        format!(
            "{}: not a run folder (no {})",
            run.display(),
            json_path.display()
        )
    })?;
    let state: State = run_json
        .state()
        .ok()
        .flatten()
        .with_context(|| format!("{}: field `state` must be t0 or t1", json_path.display()))?;
    let channels = run_json.object_channels.clone().with_context(|| {
        format!(
            "{}: field `object_channels` is missing",
            json_path.display()
        )
    })?;
    let cfg_path = run.join("config.toml");
    let cfg: toml::Value = toml::from_str(
        &std::fs::read_to_string(&cfg_path)
            .with_context(|| format!("reading {}", cfg_path.display()))?,
    )
    .with_context(|| format!("{}: invalid TOML", cfg_path.display()))?;
    let background = cfg
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
        .with_context(|| {
            format!(
                "{}: field `train.background` must be 3 numbers",
                cfg_path.display()
            )
        })?;
    let settings = trand_render::RenderSettings {
        background,
        near: toml_f64(&cfg, &cfg_path, "near")? as f32 as f64,
        sh_degree: Some(toml_f64(&cfg, &cfg_path, "sh_degree")? as u32),
        ..Default::default()
    };
    let surfels = trand_io::read_surfels_ply(&run.join("surfels.ply"))?;
    Ok(RunRender {
        clamp: clamp_of(&run_json, state, &json_path)?,
        surfels,
        settings,
        channels,
        state,
    })
}

fn write_maps(
    dir: &Path,
    name: &str,
    m: &CameraMaps,
    channels: &[(u16, usize)],
) -> anyhow::Result<()> {
    let p = |suffix: &str| dir.join(format!("{name}_{suffix}"));
    trand_io::write_npy_f32(&p("depth.npy"), &m.depth)?;
    trand_io::write_depth_png_mm(&p("depth.png"), &m.depth)?;
    trand_io::write_gray16_png(&p("ids.png"), &m.ids)?;
    let colours: Vec<u8> = m
        .ids
        .data
        .iter()
        .flat_map(|&id| {
            let channel = channels.iter().find(|c| c.0 == id && id != 0);
            let c = channel.map_or([0.0; 3], |&(_, c)| palette(c));
            c.map(|x| (x * 255.0).round() as u8)
        })
        .collect();
    let colours = Image::from_vec(m.ids.width, m.ids.height, 3, colours).expect("sizes agree");
    trand_io::write_rgb_png(&p("objects.png"), &colours)?;
    trand_io::write_npy_f32(&p("alpha.npy"), &m.alpha)?;
    trand_io::write_probability_png(&p("alpha.png"), &m.alpha)?;
    trand_io::write_npy_f32(&p("normal.npy"), &m.normal)?;
    let shown = Image {
        data: m
            .normal
            .data
            .iter()
            .map(|&v| if v == 0.0 { 0.0 } else { 0.5 * (v + 1.0) })
            .collect(),
        ..m.normal.clone()
    };
    trand_io::write_rgb_f32_png(&p("normal.png"), &shown)?;
    Ok(())
}

pub fn run(a: Args) -> anyhow::Result<()> {
    if a.out.exists() {
        bail!("{}: output folder already exists", a.out.display());
    }
    let cams = trand_io::read_cameras_json(&a.cameras)?;
    let r = load_run(&a.run)?;
    let dir = trand_io::RunDir::create(&a.out)?;
    for c in &cams {
        let maps = render_at(&r.surfels, &c.camera, &r.settings, r.clamp, &r.channels)
            .with_context(|| format!("{}: rendering camera `{}`", a.cameras.display(), c.name))?;
        write_maps(dir.path(), &c.name, &maps, &r.channels)?;
    }
    dir.commit()?;
    println!(
        "rendered {} camera(s) of {} ({} run) -> {}",
        cams.len(),
        a.run.display(),
        r.state.as_str(),
        a.out.display()
    );
    Ok(())
}
