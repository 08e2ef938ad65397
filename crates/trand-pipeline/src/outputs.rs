//! The run folder: what `trand reconstruct` and `trand update` leave behind, and what `trand eval`,
//! `trand bench` and the report read.
//!
//! ```text
//! RUN/
//!   run.json            state, method, timings, surfel counts, loss curve, object channels, …
//!   config.toml         the effective configuration
//!   surfels.ply         the kept surfels (2DGS/3DGS property names plus trand's object fields)
//!   depth/{frame}.npy   float32 median depth of every test view (metres, 0 = nothing rendered)
//!   depth/{frame}.png   the same in uint16 millimetres
//!   objects/{frame}.png colour-coded argmax of the rendered object map (black = background)
//! ```
//! The folder is written under a temporary name and renamed at the end: an interrupted run leaves no
//! half-written folder.

use std::path::Path;

use trand_core::Surfels;
use trand_io::{
    DepthMap, Image, RunDir, RunManifest, View, write_depth_png_mm, write_npy_f32, write_rgb_png,
    write_surfels_ply,
};
use trand_render::RenderSettings;

use crate::Result;
use crate::at_cameras;
use crate::targets::palette;

/// Rendered outputs of one test view.
pub struct TestRender {
    pub frame: u32,
    pub depth: DepthMap,
    pub objects: Image<u8>,
}

/// Depth beyond `2 × radius` is clamped (official-code notes §6), with `radius` the smallest distance
/// from a test camera to the point the test cameras look at.
pub fn depth_clamp(views: &[View]) -> f32 {
    let cams: Vec<_> = views.iter().map(|v| v.camera).collect();
    match trand_train::init::focus_point(&cams) {
        Ok(f) => {
            (2.0 * cams
                .iter()
                .map(|c| (c.center() - f).length())
                .fold(f64::INFINITY, f64::min)) as f32
        }
        Err(_) => f32::INFINITY,
    }
}

/// Renders the median depth and the object map of every view (full resolution), the depth clamped at
/// [`depth_clamp`] of the views.
pub fn render_views(
    surfels: &Surfels,
    views: &[View],
    settings: &RenderSettings,
) -> Result<Vec<TestRender>> {
    let clamp = depth_clamp(views);
    views
        .iter()
        .map(|v| {
            let out = at_cameras::render_with_objects(surfels, &v.camera, settings)?;
            let obj: Vec<u8> = at_cameras::argmax_channels(&out)
                .into_iter()
                .flat_map(|c| {
                    c.map_or([0.0; 3], palette)
                        .map(|x| (x * 255.0).round() as u8)
                })
                .collect();
            Ok(TestRender {
                frame: v.frame,
                depth: at_cameras::median_depth(&out, clamp),
                objects: Image::from_vec(out.width, out.height, 3, obj).expect("sizes agree"),
            })
        })
        .collect()
}

/// Writes a complete run folder at `target` (which must not exist).
pub fn write_run(
    target: &Path,
    run_json: &RunManifest,
    config_toml: &str,
    surfels: &Surfels,
    renders: &[TestRender],
) -> Result<()> {
    write_run_with(target, run_json, config_toml, surfels, renders, &|_| Ok(()))
}

/// [`write_run`] plus extra files written by `extra` into the (temporary) folder before the commit.
pub fn write_run_with(
    target: &Path,
    run_json: &RunManifest,
    config_toml: &str,
    surfels: &Surfels,
    renders: &[TestRender],
    extra: &dyn Fn(&Path) -> std::result::Result<(), trand_io::IoError>,
) -> Result<()> {
    let dir = RunDir::create(target)?;
    let p = dir.path();
    let io = |path: &Path, e: std::io::Error| trand_io::IoError::io(path, e);
    std::fs::create_dir_all(p.join("depth")).map_err(|e| io(&p.join("depth"), e))?;
    std::fs::create_dir_all(p.join("objects")).map_err(|e| io(&p.join("objects"), e))?;
    write_surfels_ply(&p.join("surfels.ply"), surfels)?;
    for r in renders {
        write_npy_f32(&p.join(format!("depth/{:06}.npy", r.frame)), &r.depth)?;
        write_depth_png_mm(&p.join(format!("depth/{:06}.png", r.frame)), &r.depth)?;
        write_rgb_png(&p.join(format!("objects/{:06}.png", r.frame)), &r.objects)?;
    }
    trand_io::write_atomic(&p.join("config.toml"), config_toml.as_bytes())?;
    trand_io::write_atomic(&p.join(trand_io::run_layout::RUN_JSON), &run_json.to_json())?;
    extra(p)?;
    dir.commit()?;
    Ok(())
}

/// Peak resident memory of this process in MiB (Linux `VmHWM`), if known.
pub fn peak_rss_mb() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

/// A short fingerprint of a sequence (its t = 0 training poses and object ids), stored in `run.json` so
/// that `trand update` can refuse a run folder made from another sequence.
pub fn sequence_fingerprint(seq: &trand_io::Sequence) -> String {
    // FNV-1a over the poses rounded to 0.1 mm / 1e-6, stable across platforms.
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |v: i64| {
        for b in v.to_le_bytes() {
            h ^= b as u64;
            h = h.wrapping_mul(0x0100_0000_01b3);
        }
    };
    for v in &seq.train_t0 {
        for r in v.camera.r_w2c.iter().flatten() {
            eat((r * 1e6).round() as i64);
        }
        for t in &v.camera.t_w2c {
            eat((t * 1e4).round() as i64);
        }
    }
    for &id in &seq.object_ids {
        eat(id as i64);
    }
    format!("{h:016x}")
}
