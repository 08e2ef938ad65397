//! `trand update`: the t = 1 scene update of a t = 0 run from one new image (see
//! `trand_pipeline::update` for the stages).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, bail};
use indicatif::{ProgressBar, ProgressStyle};
use trand_io::{State, View, ViewCount, select_train_views};
use trand_pipeline::relocalise::Reason;
use trand_pipeline::update::{
    Identity, MeshDepth, RefineScope, Stage, SurfelMotion, UpdateOptions, update,
};
use trand_pipeline::{Method, ReconstructOptions};

use super::{canonical, name_of};

#[derive(clap::Args)]
pub struct Args {
    /// The t = 0 run folder (from `trand reconstruct`).
    #[arg(long)]
    pub run: PathBuf,
    /// The sequence the run was made from; its train_1 frame 0 is the new image unless --image is given.
    #[arg(long)]
    pub data: PathBuf,
    /// Output run folder for t = 1 (must not exist).
    #[arg(long)]
    pub out: PathBuf,
    /// New RGB image (PNG), with --mask; its camera is train_1 frame 0's (or train_0 frame 0's).
    #[arg(long, requires = "mask")]
    pub image: Option<PathBuf>,
    /// Instance-id mask of the new image (8- or 16-bit PNG, 0 = background).
    #[arg(long, requires = "image")]
    pub mask: Option<PathBuf>,
    /// Physics simulation: on (default) or off (the "without simulation" ablation).
    #[arg(long, value_enum)]
    pub physics: Option<Stage>,
    /// Single-image refinement: on (default) or off ("physics only").
    #[arg(long, value_enum)]
    pub refine: Option<Stage>,
    /// Relocalisation after the simulation: on (default) searches the resting poses of the objects the
    /// simulation could move (and of any whose silhouette misses its mask, or fits it far better
    /// shifted alone: knocked aside) against the new image's mask and colours; off keeps the
    /// simulated pose.
    #[arg(long, value_enum)]
    pub relocalise: Option<Stage>,
    /// The new photo's camera: on (default) turns it to fit the objects the removal cannot have
    /// moved (a robot's pose error of a fraction of a degree shifts them all alike); off keeps it.
    /// Either way, with the relocalisation on, an object that fits its mask far better shifted alone
    /// is searched (knocked aside).
    #[arg(long, value_enum)]
    pub correct_camera: Option<Stage>,
    /// Which objects the refinement may change: moved (default; the others keep their t=0 surfels)
    /// or all (the paper).
    #[arg(long, value_enum)]
    pub refine_scope: Option<RefineScope>,
    /// Object ids to treat as removed (skips detection).
    #[arg(long, num_args = 1..)]
    pub removed: Option<Vec<u16>>,
    /// How objects are found in the new mask: auto (default: by id when every id of the new mask is a
    /// t = 0 object id), ids (the mask's ids are the t = 0 object ids) or overlap (per-image ids,
    /// matched by overlap with the rendered t = 0 objects).
    #[arg(long, value_enum)]
    pub identity: Option<Identity>,
    /// Depth that feeds the TSDF: expected (default, the authors' code) or median.
    #[arg(long, value_enum)]
    pub mesh_depth: Option<MeshDepth>,
    /// How surfels follow the simulation: translate (each with its particle, the paper),
    /// translate-rotate (alias rotate: also turn by the particle's polar rotation) or
    /// rigid-per-object (alias rigid, the default: each object by the best rigid fit of its particles).
    #[arg(long, value_enum)]
    pub motion: Option<SurfelMotion>,
    /// TOML file with any of the update options.
    #[arg(long)]
    pub config: Option<PathBuf>,
}

fn new_view(a: &Args, seq: &trand_io::Sequence) -> anyhow::Result<View> {
    let base = seq
        .train_t1
        .iter()
        .chain(&seq.train_t0)
        .find(|v| v.frame == 0)
        .with_context(|| {
            format!(
                "{}: no train_1 (or train_0) frame 0 to take the new camera from",
                a.data.display()
            )
        })?;
    let mut v = base.clone();
    if let (Some(img), Some(mask)) = (&a.image, &a.mask) {
        let rgb = trand_io::read_rgb8(img)?;
        let k = &v.camera.intrinsics;
        if (rgb.width, rgb.height) != (k.width, k.height) {
            bail!(
                "{}: image is {}x{} but the camera is {}x{}",
                img.display(),
                rgb.width,
                rgb.height,
                k.width,
                k.height
            );
        }
        let inst = trand_io::read_gray16(mask).or_else(|_| {
            trand_io::read_gray8(mask).map(|m| {
                trand_io::Image::from_vec(
                    m.width,
                    m.height,
                    1,
                    m.data.iter().map(|&x| x as u16).collect(),
                )
                .expect("same size")
            })
        })?;
        if !rgb.same_size(&inst) {
            bail!(
                "{}: mask is {}x{} but the image is {}x{}",
                mask.display(),
                inst.width,
                inst.height,
                rgb.width,
                rgb.height
            );
        }
        v.name = img.display().to_string();
        v.rgb = Some(rgb);
        v.instance = Some(inst);
    }
    let inst = v
        .instance
        .as_ref()
        .with_context(|| format!("{}: the new image has no instance mask", v.name))?;
    if inst.data.iter().all(|&i| i == 0) {
        bail!(
            "{}: the new image's mask is empty (no object pixels)",
            v.name
        );
    }
    if v.rgb.is_none() {
        bail!("{}: the new image has no RGB", v.name);
    }
    Ok(v)
}

/// A t = 0 run folder, checked: its manifest, configuration, object channels and surfels.
struct T0Run {
    manifest: trand_io::RunManifest,
    options: ReconstructOptions,
    channels: Vec<(u16, usize)>,
    surfels: trand_core::Surfels,
}

fn load_t0_run(run: &Path) -> anyhow::Result<T0Run> {
    let run_json_path = run.join(trand_io::run_layout::RUN_JSON);
    let run_json = trand_io::RunManifest::read(run)?
        .with_context(|| format!("{}: not a run folder (no run.json)", run.display()))?;
    if run_json.state().ok().flatten() != Some(State::T0) {
        bail!(
            "{}: field `state` is {} but update needs a t0 run",
            run_json_path.display(),
            serde_json::json!(run_json.state)
        );
    }
    let cfg_path = run.join("config.toml");
    let ropts: ReconstructOptions = toml::from_str(
        &std::fs::read_to_string(&cfg_path)
            .with_context(|| format!("reading {}", cfg_path.display()))?,
    )
    .with_context(|| format!("{}: invalid configuration", cfg_path.display()))?;
    ropts
        .validate()
        .with_context(|| format!("{}: invalid configuration", cfg_path.display()))?;
    let channels = run_json.object_channels.clone().with_context(|| {
        format!(
            "{}: field `object_channels` is missing",
            run_json_path.display()
        )
    })?;
    let ply_path = run.join("surfels.ply");
    let surfels = trand_io::read_surfels_ply(&ply_path)?;
    surfels
        .validate()
        .with_context(|| format!("{}: unusable surfels", ply_path.display()))?;
    if ropts.method.supervision() == trand_pipeline::Supervision::ObjectAware {
        if surfels.num_objects != ropts.num_objects {
            bail!(
                "{}: {} object channels, but {} says num_objects = {}",
                ply_path.display(),
                surfels.num_objects,
                cfg_path.display(),
                ropts.num_objects
            );
        }
        trand_pipeline::targets::check_channels(&channels, surfels.num_objects).map_err(|r| {
            anyhow::anyhow!("{}: field `object_channels`: {r}", run_json_path.display())
        })?;
    }

    Ok(T0Run {
        manifest: run_json,
        options: ropts,
        channels,
        surfels,
    })
}

/// The update options: the `--config` file's (or the defaults), then the flags; the identity rule
/// follows the t = 0 run's when left on auto. Also whether the t = 0 masks needed association.
fn update_options(
    a: &Args,
    run_json: &trand_io::RunManifest,
    ropts: &ReconstructOptions,
) -> anyhow::Result<(UpdateOptions, bool)> {
    let mut opts = match &a.config {
        Some(p) => toml::from_str::<UpdateOptions>(
            &std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?,
        )
        .with_context(|| format!("{}: invalid configuration", p.display()))?,
        None => UpdateOptions::default(),
    };
    if let Some(p) = &a.config {
        opts.validate()
            .with_context(|| format!("{}: invalid configuration", p.display()))?;
    }
    opts.physics = a.physics.unwrap_or(opts.physics);
    opts.refine = a.refine.unwrap_or(opts.refine);
    opts.relocalise = a.relocalise.unwrap_or(opts.relocalise);
    opts.correct_camera = a.correct_camera.unwrap_or(opts.correct_camera);
    opts.refine_scope = a.refine_scope.unwrap_or(opts.refine_scope);
    opts.identity = a.identity.unwrap_or(opts.identity);
    // A segmenter whose t = 0 ids needed association numbers the new image on its own as well.
    let t0_associated = run_json.identity_used() == Some("overlap");
    if opts.identity == Identity::Auto && t0_associated {
        opts.identity = Identity::Overlap;
    }
    if a.removed.is_some() {
        opts.removed = a.removed.clone();
    }
    opts.mesh_depth = a.mesh_depth.unwrap_or(opts.mesh_depth);
    opts.motion = a.motion.unwrap_or(opts.motion);
    opts.train.background = ropts.train.background;
    opts.train.sh_degree = ropts.train.sh_degree;
    opts.train.near = ropts.train.near;
    Ok((opts, t0_associated))
}

/// What the t = 1 manifest records besides the update's result.
struct T1Record<'a> {
    seq: &'a trand_io::Sequence,
    fingerprint: String,
    view: &'a View,
    channels: Vec<(u16, usize)>,
    t0_associated: bool,
    render_s: f64,
    wall_s: f64,
}

/// `run.json` of the t = 1 run.
fn t1_manifest(
    a: &Args,
    ropts: &ReconstructOptions,
    opts: &UpdateOptions,
    up: &trand_pipeline::update::Update,
    t1: T1Record<'_>,
) -> trand_io::RunManifest {
    let total =
        up.detection_s + up.meshing_s + up.simulation_s + up.relocalisation_s + up.refinement_s;
    let mut out_json = trand_io::RunManifest {
        state: Some("t1".into()),
        method: Some(name_of(serde_json::json!(ropts.method))),
        views: Some(ropts.views),
        data: Some(canonical(&a.data)),
        sequence_fingerprint: Some(t1.fingerprint),
        depth_clamp_m: Some(Some(trand_pipeline::outputs::depth_clamp(&t1.seq.test_t1))),
        object_channels: Some(t1.channels),
        timings: Some(
            [
                ("detection_s", up.detection_s),
                ("meshing_s", up.meshing_s),
                ("simulation_s", up.simulation_s),
                ("relocalisation_s", up.relocalisation_s),
                ("refinement_s", up.refinement_s),
                ("total_s", total),
                ("test_render_s", t1.render_s),
                ("wall_s", t1.wall_s),
            ]
            .map(|(k, v)| (k.to_string(), v))
            .into(),
        ),
        num_surfels: Some(up.surfels.len()),
        loss_curve: Some(up.curve.clone()),
        peak_rss_mb: trand_pipeline::outputs::peak_rss_mb(),
        threads: Some(rayon::current_num_threads()),
        trand_version: Some(env!("CARGO_PKG_VERSION").into()),
        ..Default::default()
    };
    out_json
        .detail("t0_run", canonical(&a.run))
        .detail("new_image", &t1.view.name)
        .detail("matching", &up.matches)
        .detail("removed", &up.removed)
        .detail(
            "removed_by",
            if opts.removed.is_some() {
                "user"
            } else {
                "detection"
            },
        )
        .detail("identity", up.identity)
        .detail("identity_from_t0", t1.t0_associated)
        .detail("relocalise", opts.relocalise)
        .detail("correct_camera", opts.correct_camera)
        .detail("refine_scope", opts.refine_scope)
        .detail("relocations", &up.relocations)
        .detail("camera_correction", &up.camera_correction)
        .detail("movable", &up.movable)
        .detail("deleted_surfels", up.deleted_surfels)
        .detail("num_particles", up.num_particles)
        .detail("simulated_frames", up.simulated_frames)
        .detail("max_surfel_displacement_m", up.max_displacement_m)
        .detail("physics", opts.physics)
        .detail("motion", opts.motion)
        .detail("refine", opts.refine);
    out_json
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let t_all = Instant::now();
    trand_io::output::check_new_output(&a.out)?;
    let T0Run {
        manifest: run_json,
        options: ropts,
        channels,
        surfels,
    } = load_t0_run(&a.run)?;

    let seq = super::reconstruct::read_sequence(&a.data, ropts.num_objects)?;
    let fp = trand_pipeline::outputs::sequence_fingerprint(&seq);
    if run_json.sequence_fingerprint.is_none() {
        // A run made from in-memory arrays (the Python package's `Scene.save`) names no sequence.
        eprintln!(
            "note: {} records no sequence; taking {} to be the one it was reconstructed from",
            a.run.display(),
            a.data.display()
        );
    } else if run_json.sequence_fingerprint.as_deref() != Some(fp.as_str()) {
        bail!(
            "{} was reconstructed from another sequence than {} (field `sequence_fingerprint` {} ≠ {fp})",
            a.run.display(),
            a.data.display(),
            serde_json::json!(run_json.sequence_fingerprint)
        );
    }
    let view = new_view(&a, &seq)?;

    let (opts, t0_associated) = update_options(&a, &run_json, &ropts)?;

    // The t = 0 scene extent, for densification at t = 1 (notes §10 row 7).
    let vc = match ropts.views {
        3 => ViewCount::Three,
        12 => ViewCount::Twelve,
        _ => ViewCount::Six,
    };
    let cams: Vec<_> = select_train_views(&seq.train_t0, vc)
        .iter()
        .map(|v| v.camera)
        .collect();
    let scale = trand_pipeline::update::SceneScale::from_cameras(&cams, ropts.downsample);

    let pb = ProgressBar::new(100);
    pb.set_style(
        ProgressStyle::with_template("{prefix:>10} [{bar:30}] {pos}/{len} {msg}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    let mut progress = |stage: &str, i: u32, n: u32| {
        pb.set_prefix(stage.to_string());
        pb.set_length(n as u64);
        pb.set_position(i as u64);
    };
    let mut on_step = |r: &trand_pipeline::StepReport| {
        pb.set_prefix("refinement");
        pb.set_length(opts.train.iterations as u64);
        pb.set_position((r.iteration - opts.train.start_iteration) as u64);
        pb.set_message(format!("loss {:.4}", r.loss));
    };
    let sup = ropts.method.supervision();
    let up = update(
        surfels,
        &channels,
        &view,
        scale,
        sup,
        &opts,
        &mut progress,
        &mut on_step,
    )
    .with_context(|| format!("updating {}", a.run.display()))?;
    pb.finish_and_clear();

    let t_render = Instant::now();
    let settings = trand_render::RenderSettings {
        background: ropts.train.background,
        near: ropts.train.near as f64,
        sh_degree: Some(opts.train.sh_degree),
        ..Default::default()
    };
    let renders = trand_pipeline::outputs::render_views(&up.surfels, &seq.test_t1, &settings)?;
    let total =
        up.detection_s + up.meshing_s + up.simulation_s + up.relocalisation_s + up.refinement_s;
    let t1 = T1Record {
        seq: &seq,
        fingerprint: fp,
        view: &view,
        channels,
        t0_associated,
        render_s: t_render.elapsed().as_secs_f64(),
        wall_s: t_all.elapsed().as_secs_f64(),
    };
    let out_json = t1_manifest(&a, &ropts, &opts, &up, t1);
    let mut cfg = toml::to_string(&opts).context("serialising the configuration")?;
    if ropts.method == Method::Plain2dgs {
        cfg.insert_str(0, "# plain-2dgs run: no object channels, so no detection and no physics; refinement only\n");
    }
    let mesh = up.mesh.clone();
    trand_pipeline::outputs::write_run_with(
        &a.out,
        &out_json,
        &cfg,
        &up.surfels,
        &renders,
        &|dir| {
            if let Some(m) = mesh.as_ref().filter(|m| !m.vertices.is_empty()) {
                trand_io::write_mesh_ply(&dir.join("mesh.ply"), m)?;
            }
            Ok(())
        },
    )?;
    for m in &up.matches {
        match m.new_id {
            Some(n) => println!(
                "object {} -> new instance {n} (IoU {:.2}{})",
                m.object_id,
                m.iou,
                if m.may_have_moved {
                    "; may have moved: it touched a removed object"
                } else {
                    ""
                }
            ),
            None => println!(
                "object {} -> not found (best IoU {:.2}): removed",
                m.object_id, m.iou
            ),
        }
    }
    if let Some(c) = up.camera_correction.as_ref().filter(|c| c.applied) {
        println!(
            "new camera turned {:.2}° to fit {} unmoved object(s): shifted ({:.1}, {:.1}) px, IoU {:.2} -> {:.2}",
            c.turn_deg, c.objects, c.shift_px[0], c.shift_px[1], c.iou_given, c.iou_shifted
        );
    }
    for r in &up
        .relocations
        .iter()
        .filter(|r| r.moved)
        .collect::<Vec<_>>()
    {
        let (before, after) = (
            r.score_before.map_or(f64::NAN, |s| s.total),
            r.score_after.map_or(f64::NAN, |s| s.total),
        );
        let why = match r.reason {
            Reason::Movable => "it touched a removed object",
            Reason::SilhouetteMiss => "its silhouette missed its mask",
            Reason::Displaced => "knocked aside: its silhouette fit its mask better shifted",
            Reason::Static => "static",
        };
        println!(
            "object {} relocalised ({why}): score {before:.2} -> {after:.2}, IoU {:.2} -> {:.2}, tilted {:.0}° from its t=0 vertical",
            r.object_id,
            r.iou_before,
            r.iou_after,
            r.chosen.map_or(0.0, |c| c.tilt_deg)
        );
    }
    if up.removed.is_empty() {
        println!(
            "no object was found missing: nothing deleted, physics ran on the unchanged scene"
        );
    }
    println!(
        "updated in {total:.1} s (detection {:.1}, meshing {:.1}, simulation {:.1}, relocalisation {:.1}, refinement {:.1}): {} surfels, {} particles -> {}",
        up.detection_s,
        up.meshing_s,
        up.simulation_s,
        up.relocalisation_s,
        up.refinement_s,
        up.surfels.len(),
        up.num_particles,
        a.out.display()
    );
    if !seq.test_t1.is_empty()
        && seq
            .test_t1
            .iter()
            .all(|v| v.depth.is_some() && v.instance.is_some())
    {
        let (_, m) = trand_eval::evaluate_run(&a.out, &a.data, Some(trand_io::State::T1))?;
        print!("{}", trand_eval::table(&[("t1", &m)]));
    }
    Ok(())
}
