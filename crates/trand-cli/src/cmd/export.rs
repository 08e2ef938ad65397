//! `trand export`: a finished run's objects as PLY files other tools open (Open3D, MeshLab, splat
//! viewers).
//!
//! ```text
//! OUT/object_ID.ply       the object's surfels as points: x y z, nx ny nz (surfel normal),
//!                         red green blue (SH DC colour)
//! OUT/scene_points.ply    every object's points, with a `ushort object_id` property
//! OUT/object_ID_mesh.ply  the object's part of the fused mesh (vertices, faces, palette colour)
//! OUT/mesh.ply            the whole fused mesh, `uchar label` = object id per vertex
//! OUT/splats.ply          with --splats: every surfel as a 3DGS splat (thin third scale)
//! OUT/export.json         counts, the opacity threshold and the thickness ratio used
//! ```
//! Which surfels and how the mesh is made: `trand_pipeline::export`; the splat layout:
//! `trand_io::splats`. The output folder appears only when every file is written.

use std::path::PathBuf;

use anyhow::{Context, bail};
use trand_pipeline::export::{DEFAULT_MIN_OPACITY, export};

use super::render::load_run;

#[derive(clap::Args)]
#[command(
    after_help = "Writes OUT/object_ID.ply (points: x y z, nx ny nz, red green blue), \
OUT/scene_points.ply (all objects, ushort object_id), OUT/object_ID_mesh.ply and OUT/mesh.ply \
(TSDF-fused mesh, uchar label = object id), OUT/export.json (counts), and with --splats \
OUT/splats.ply (3DGS layout). A surfel belongs to an object when the probability of the object's \
channel is above 1/2."
)]
pub struct Args {
    /// A finished run folder (t=0 or t=1).
    #[arg(long)]
    pub run: PathBuf,
    /// Output folder (must not exist).
    #[arg(long)]
    pub out: PathBuf,
    /// Also write splats.ply, every surfel as a 3D Gaussian (3 scales) for splat viewers.
    #[arg(long)]
    pub splats: bool,
    /// Surfels below this opacity (0..1) are left out of the point clouds.
    #[arg(long, default_value_t = DEFAULT_MIN_OPACITY)]
    pub min_opacity: f64,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    if !(0.0..1.0).contains(&a.min_opacity) {
        bail!(
            "--min-opacity {}: must be at least 0 and below 1",
            a.min_opacity
        );
    }
    trand_io::output::check_new_output(&a.out)?;
    let t = std::time::Instant::now();
    let r = load_run(&a.run)?;
    let ply = a.run.join("surfels.ply");
    r.surfels
        .validate()
        .with_context(|| format!("{}: invalid surfels", ply.display()))?;
    let ex = export(
        &r.surfels,
        &r.channels,
        a.min_opacity,
        &r.settings,
        &mut |_, _, _| {},
    )?;
    let dir = trand_io::RunDir::create(&a.out)?;
    let p = |name: String| dir.path().join(name);
    let mut objects = Vec::new();
    for o in &ex.objects {
        trand_io::write_point_cloud_ply(&p(format!("object_{}.ply", o.id)), &o.points)?;
        trand_io::write_mesh_ply(&p(format!("object_{}_mesh.ply", o.id)), &o.mesh)?;
        objects.push(serde_json::json!({
            "id": o.id,
            "points": o.points.len(),
            "mesh_vertices": o.mesh.vertices.len(),
            "mesh_faces": o.mesh.faces.len(),
        }));
    }
    trand_io::write_point_cloud_ply(&p("scene_points.ply".into()), &ex.scene_points)?;
    trand_io::write_mesh_ply(&p("mesh.ply".into()), &ex.scene_mesh)?;
    if a.splats {
        trand_io::write_splats_ply(&p("splats.ply".into()), &r.surfels)?;
    }
    let summary = serde_json::json!({
        "run": a.run.canonicalize().unwrap_or(a.run.clone()),
        "state": r.state.as_str(),
        "min_opacity": a.min_opacity,
        "objects": objects,
        "scene_points": ex.scene_points.len(),
        "mesh_vertices": ex.scene_mesh.vertices.len(),
        "mesh_faces": ex.scene_mesh.faces.len(),
        "splats": a.splats.then_some(r.surfels.len()),
        "splat_thin_ratio": a.splats.then_some(trand_io::splats::THIN_RATIO),
    });
    let text = serde_json::to_string_pretty(&summary).context("serialising export.json")?;
    trand_io::write_atomic(&p("export.json".into()), text.as_bytes())?;
    dir.commit()?;
    println!(
        "exported {} object(s), {} points, mesh {} vertices / {} faces{} of {} ({} run) -> {} in {:.1} s",
        ex.objects.len(),
        ex.scene_points.len(),
        ex.scene_mesh.vertices.len(),
        ex.scene_mesh.faces.len(),
        if a.splats {
            format!(", {} splats", r.surfels.len())
        } else {
            String::new()
        },
        a.run.display(),
        r.state.as_str(),
        a.out.display(),
        t.elapsed().as_secs_f64()
    );
    Ok(())
}
