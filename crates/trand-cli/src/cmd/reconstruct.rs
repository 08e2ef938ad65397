//! `trand reconstruct`: the t = 0 object-aware 2DGS reconstruction of a sequence.
//!
//! Progress bar with loss and surfel count. A checkpoint (`OUT.checkpoint/checkpoint.bin`, the whole
//! loop state: see `trand_pipeline::checkpoint`) is written every `--checkpoint-every` iterations, on
//! Ctrl-C and after the last iteration; `--resume` continues from it exactly (same bits as an
//! uninterrupted run) and refuses a checkpoint of other training views or options. A failed
//! checkpoint write is reported at once.
//!
//! The output location and the options are checked before any work. Ctrl-C stops every phase: while
//! training it checkpoints and stops after the current iteration; while writing the run folder it
//! stops once the folder is complete; in any other phase at once (nothing is half-written then; a
//! second Ctrl-C always stops at once). The run folder appears only when the run is complete.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU8, Ordering};
use std::time::Instant;

use anyhow::{Context, bail};
use indicatif::{ProgressBar, ProgressStyle};
use trand_io::{LoadOptions, Sequence, read_sequence_with};
use trand_pipeline::associate::Identity;
use trand_pipeline::checkpoint::Checkpoint;
use trand_pipeline::front_fill::FrontFill;
use trand_pipeline::missed_masks::{MissedFill, MissedMasks};
use trand_pipeline::reconstruct::{OpeningPrior, Start, reconstruct_from};
use trand_pipeline::support::SupportPrior;
use trand_pipeline::table_align::TableAlign;

use super::{canonical, name_of};
use trand_pipeline::{InitMode, Method, PipelineError, ReconstructOptions};

#[derive(clap::Args)]
pub struct Args {
    /// Sequence folder (BOP layout, the authors' transforms_sparse_*.json, nerfstudio transforms.json,
    /// or a KeyPose capture).
    #[arg(long)]
    pub data: PathBuf,
    /// Output run folder (must not exist).
    #[arg(long)]
    pub out: PathBuf,
    /// Training views: 3, 6 (the paper) or 12 ring views.
    #[arg(long)]
    pub views: Option<u32>,
    /// trand, no-object-loss (ablation) or plain2dgs (alias plain-2dgs; baseline).
    #[arg(long, value_enum)]
    pub method: Option<Method>,
    /// TOML file with any of the options (see `config.toml` of a finished run for every key).
    #[arg(long)]
    pub config: Option<PathBuf>,
    #[arg(long)]
    pub iterations: Option<u32>,
    #[arg(long)]
    pub seed: Option<u64>,
    /// Train on images downsampled by this integer factor (evaluation stays at full resolution).
    #[arg(long)]
    pub downsample: Option<u32>,
    /// Initialisation: visual-hull (default) or slab (the authors' random slab).
    #[arg(long, value_enum)]
    pub init: Option<InitMode>,
    /// Open vessels: carve (default: keep surfels out of the openings of upright tumblers, mugs,
    /// bowls and wine glasses, so their inside is fitted instead of a lid) or off.
    #[arg(long, value_enum)]
    pub openings: Option<OpeningPrior>,
    /// Instance ids of the training masks: auto (default: used as they are unless they disagree with
    /// the geometry, then associated), ids (one id per object in every view, as a tracker gives) or
    /// overlap (per-image ids, e.g. SAM or Mask R-CNN: associated across views by voxel votes).
    #[arg(long, value_enum)]
    pub identity: Option<Identity>,
    /// Support prior: auto (default: on when the training views span less than 30 degrees), on or
    /// off. Keeps the initial surfels where the table under them is hidden behind an object in every
    /// view, which pins the depth a narrow baseline leaves open.
    #[arg(long, value_enum)]
    pub support: Option<SupportPrior>,
    /// Holes in a glass's front: hull-front (default: where a training view sees through an object
    /// to its back wall after training, a surfel is put at the visual hull's front) or off.
    #[arg(long, value_enum)]
    pub front_fill: Option<FrontFill>,
    /// Training cameras: texture (default: first aligned on the table's texture where it shows one,
    /// with the poses refined and the views spread; run.json `table_alignment`) or off.
    #[arg(long, value_enum)]
    pub table_align: Option<TableAlign>,
    /// Masks a segmenter missed, drawn in from the other views: corrected-cameras (default: where
    /// one was filled, drawn again through the table-aligned cameras or, on a plain table, those of
    /// a first pass trained until the pose corrections settle; run.json `missed_masks`) or
    /// given-cameras.
    #[arg(long, value_enum)]
    pub missed_masks: Option<MissedMasks>,
    /// Pixels drawn in for a missed mask: unknown (default: left out of the losses, kept in the
    /// visual-hull initialisation) or object (taught as the drawn object's).
    #[arg(long, value_enum)]
    pub missed_fill: Option<MissedFill>,
    /// Object channels K, background included (default 15).
    #[arg(long)]
    pub objects: Option<usize>,
    /// Continue from `OUT.checkpoint/`.
    #[arg(long)]
    pub resume: bool,
    #[arg(long, default_value_t = 100)]
    pub checkpoint_every: u32,
}

pub fn options(a: &Args) -> anyhow::Result<ReconstructOptions> {
    let mut o = match &a.config {
        Some(p) => {
            let s =
                std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
            toml::from_str::<ReconstructOptions>(&s)
                .with_context(|| format!("{}: invalid configuration", p.display()))?
        }
        None => ReconstructOptions::default(),
    };
    if let Some(v) = a.views {
        o.views = v;
    }
    if let Some(m) = a.method {
        o.method = m;
    }
    if let Some(n) = a.iterations {
        o.train.iterations = n;
    }
    if let Some(s) = a.seed {
        o.train.seed = s;
        o.init.seed = s;
    }
    if let Some(d) = a.downsample {
        if d == 0 {
            bail!("--downsample must be at least 1");
        }
        o.downsample = d;
    }
    if let Some(i) = a.init {
        o.init_mode = i;
    }
    if let Some(k) = a.objects {
        o.num_objects = k;
    }
    if let Some(p) = a.openings {
        o.openings = p;
    }
    if let Some(i) = a.identity {
        o.identity = i;
    }
    if let Some(f) = a.front_fill {
        o.front_fill = f;
    }
    if let Some(m) = a.missed_masks {
        o.missed_masks = m;
    }
    if let Some(f) = a.missed_fill {
        o.missed_fill = f;
    }
    if let Some(t) = a.table_align {
        o.table_align = t;
    }
    if let Some(p) = a.support {
        o.support = p;
    }
    o.validate().map_err(|e| match &a.config {
        Some(p) => anyhow::anyhow!("{}: {e}", p.display()),
        None => e.into(),
    })?;
    Ok(o)
}

fn checkpoint_dir(out: &Path) -> PathBuf {
    let mut s = out.as_os_str().to_owned();
    s.push(".checkpoint");
    PathBuf::from(s)
}

/// The checkpoint file inside `checkpoint_dir`.
const CHECKPOINT_FILE: &str = "checkpoint.bin";

/// What the process is doing, for the Ctrl-C handler.
#[derive(Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
enum Phase {
    /// Reading, preparing, rendering, evaluating: nothing half-written, so Ctrl-C exits at once.
    Stoppable = 0,
    /// Training: Ctrl-C checkpoints and stops after the current iteration.
    Training = 1,
    /// Writing the run folder: Ctrl-C stops once it is complete.
    Writing = 2,
}

/// Installs the Ctrl-C handler: sets `cancel`, and exits at once (status 130) when the phase is
/// [`Phase::Stoppable`] or on a second Ctrl-C.
fn install_ctrlc(cancel: Arc<AtomicBool>, phase: Arc<AtomicU8>) {
    let _ = ctrlc::set_handler(move || {
        let again = cancel.swap(true, Ordering::SeqCst);
        if again || phase.load(Ordering::SeqCst) == Phase::Stoppable as u8 {
            eprintln!("\ninterrupted");
            std::process::exit(130);
        }
    });
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let t_all = Instant::now();
    let opts = options(&a)?;
    trand_io::output::check_new_output(&a.out)?;
    let ckpt = checkpoint_dir(&a.out);
    let ckpt_file = ckpt.join(CHECKPOINT_FILE);
    let start = if a.resume {
        let c = Checkpoint::read(&ckpt_file)
            .with_context(|| format!("--resume: no usable checkpoint in {}", ckpt.display()))?;
        eprintln!(
            "resuming after iteration {} ({} surfels)",
            c.iteration,
            c.surfels.len()
        );
        Start::Resume(Box::new(c))
    } else {
        Start::Init
    };
    let cancel = Arc::new(AtomicBool::new(false));
    let phase = Arc::new(AtomicU8::new(Phase::Stoppable as u8));
    install_ctrlc(cancel.clone(), phase.clone());
    let seq = read_sequence(&a.data, opts.num_objects)?;

    let frames: Vec<u32> = match seq.train_selection {
        trand_io::TrainSelection::Listed => seq.train_t0.iter().map(|v| v.frame).collect(),
        trand_io::TrainSelection::Ring => trand_io::ViewCount::from_count(opts.views as usize)
            .map(|n| {
                trand_io::select_train_views(&seq.train_t0, n)
                    .iter()
                    .map(|v| v.frame)
                    .collect()
            })
            .unwrap_or_default(),
    };
    eprintln!(
        "training on {} view(s) at t=0: frames {frames:?}{}",
        frames.len(),
        match seq.train_selection {
            trand_io::TrainSelection::Listed => " (every training image the layout lists)",
            trand_io::TrainSelection::Ring => " (the ring views --views selects)",
        }
    );

    let total = opts.train.iterations as u64;
    let pb = ProgressBar::new(total);
    pb.set_style(
        ProgressStyle::with_template(
            "{elapsed_precise} [{bar:30}] {pos}/{len} it  {msg}  eta {eta}",
        )
        .expect("valid template")
        .progress_chars("=> "),
    );
    let every = a.checkpoint_every.max(1);
    let last_it = opts.train.start_iteration + opts.train.iterations;
    let mut last_ckpt: anyhow::Result<()> = Ok(());
    let mut on_step = |r: &trand_pipeline::StepReport,
                       snap: &trand_pipeline::checkpoint::Snapshot<'_>| {
        phase.store(Phase::Training as u8, Ordering::SeqCst);
        pb.set_position((r.iteration - opts.train.start_iteration) as u64);
        pb.set_message(format!("loss {:.4}  surfels {}", r.loss, r.num_surfels));
        if pb.is_hidden() && r.iteration.is_multiple_of(100) {
            eprintln!(
                "iteration {}: loss {:.4}, {} surfels, {:.1} s",
                r.iteration,
                r.loss,
                r.num_surfels,
                pb.elapsed().as_secs_f64()
            );
        }
        if r.iteration.is_multiple_of(every)
            || r.iteration == last_it
            || cancel.load(Ordering::SeqCst)
        {
            last_ckpt = std::fs::create_dir_all(&ckpt)
                .map_err(|e| trand_io::IoError::io(&ckpt, e))
                .and_then(|()| snap.write(&ckpt_file))
                .with_context(|| format!("writing the checkpoint of iteration {}", r.iteration));
            if let Err(e) = &last_ckpt {
                pb.println(format!("warning: {e:#}"));
            }
        }
    };
    let result = reconstruct_from(&seq, &opts, start, &mut on_step, &cancel);
    phase.store(Phase::Stoppable as u8, Ordering::SeqCst);
    let rec = match result {
        Ok(r) => r,
        Err(PipelineError::Interrupted(it)) => {
            pb.abandon();
            last_ckpt
                .with_context(|| format!("interrupted at iteration {it} without a checkpoint"))?;
            eprintln!(
                "interrupted at iteration {it}; checkpoint in {} (continue with --resume)",
                ckpt.display()
            );
            std::process::exit(130);
        }
        Err(e) => return Err(e).with_context(|| format!("reconstructing {}", a.data.display())),
    };
    pb.finish_and_clear();
    if let Err(e) = &last_ckpt {
        eprintln!("warning: the final checkpoint was not written ({e:#}); the run goes on");
    }
    if cancel.load(Ordering::SeqCst) {
        eprintln!(
            "interrupted after training; the trained state is in {} (--resume writes the run)",
            ckpt.display()
        );
        std::process::exit(130);
    }

    let t_render = Instant::now();
    let settings = trand_render::RenderSettings {
        background: opts.train.background,
        near: opts.train.near as f64,
        sh_degree: Some(opts.train.sh_degree),
        ..Default::default()
    };
    let side = |h: f64| if h > 0.0 { "above" } else { "below" };
    match (rec.table.shifted_m, rec.table.fit) {
        (m, Some(f)) if m != 0.0 => eprintln!(
            "note: the refined cameras see the table {:.1} mm {} z = 0 (its {}); the scene was moved {:.1} mm towards it",
            f.height_m.abs() * 1e3,
            side(f.height_m),
            match rec.table.reading {
                Some(trand_pipeline::table_height::Reading::Broad) => "shading",
                _ => "texture",
            },
            m.abs() * 1e3
        ),
        (_, Some(f))
            if f.textured() && f.height_m.abs() >= trand_pipeline::table_height::WARN_M =>
        {
            eprintln!(
                "warning: the table's texture puts it {:.1} mm {} z = 0; trand takes the table as the plane z = 0 of the world frame",
                f.height_m.abs() * 1e3,
                side(f.height_m)
            )
        }
        _ => {}
    }
    // Without test views, the depth is rendered at the training views (named by their frames).
    let trained: Vec<trand_io::View> = seq
        .train_t0
        .iter()
        .filter(|v| rec.train_views.contains(&v.name))
        .cloned()
        .collect();
    let (depth_views, depth_at) = if seq.test_t0.is_empty() {
        eprintln!(
            "note: {} has no t=0 test views; depth/ holds the training views' depth instead",
            a.data.display()
        );
        (&trained, "train")
    } else {
        (&seq.test_t0, "test")
    };
    let renders = trand_pipeline::outputs::render_views(&rec.surfels, depth_views, &settings)?;
    let render_s = t_render.elapsed().as_secs_f64();
    let mut run_json = trand_io::RunManifest {
        state: Some("t0".into()),
        method: Some(name_of(serde_json::json!(opts.method))),
        views: Some(opts.views),
        data: Some(canonical(&a.data)),
        sequence_fingerprint: Some(trand_pipeline::outputs::sequence_fingerprint(&seq)),
        depth_clamp_m: Some(Some(trand_pipeline::outputs::depth_clamp(depth_views))),
        object_channels: Some(rec.channels.clone()),
        timings: Some(
            [
                ("preprocess_s", rec.preprocess_s),
                ("optimise_s", rec.optimise_s),
                ("total_s", rec.preprocess_s + rec.optimise_s),
                ("test_render_s", render_s),
                ("wall_s", t_all.elapsed().as_secs_f64()),
            ]
            .map(|(k, v)| (k.to_string(), v))
            .into(),
        ),
        num_surfels: Some(rec.surfels.len()),
        loss_curve: Some(rec.curve.clone()),
        peak_rss_mb: trand_pipeline::outputs::peak_rss_mb(),
        threads: Some(rayon::current_num_threads()),
        trand_version: Some(env!("CARGO_PKG_VERSION").into()),
        ..Default::default()
    };
    run_json
        .detail("train_views", &rec.train_views)
        .detail("depth_views", depth_at)
        .detail("vessel_tops", &rec.vessel_tops)
        .detail(
            "mask_agreement",
            serde_json::json!({ "measured": rec.mask_agreement, "rule": opts.overhangs, "overhangs": rec.overhangs }),
        )
        .detail("identity", &rec.identity)
        .detail(
            "mask_edges",
            serde_json::json!({
                "rule": opts.train.image_loss.snap_masks,
                "grown_to_image_edges": rec.grown_to_image_edges,
            }),
        )
        .detail("table_height", rec.table)
        .detail(
            "table_alignment",
            serde_json::json!({ "mode": opts.table_align, "found": rec.table_alignment }),
        )
        .detail(
            "missed_masks",
            serde_json::json!({
                "mode": opts.missed_masks,
                "fill": opts.missed_fill,
                "redrawn": rec.missed_masks,
            }),
        )
        .detail(
            "front_fill",
            serde_json::json!({ "mode": opts.front_fill, "surfels_added": rec.front_fill_added }),
        )
        .detail(
            "support_prior",
            serde_json::json!({ "mode": opts.support, "applied": rec.support_applied }),
        )
        .detail(
            "pose_refinement",
            serde_json::json!({
                "mode": rec.pose_refinement,
                "openings_from": if rec.openings_retaken { "settled poses" } else { "given poses" },
                "views": rec.pose_report(),
            }),
        )
        .detail("initial_surfels", rec.initial_surfels)
        .detail("num_trained", rec.num_trained);
    let config = toml::to_string(&opts).context("serialising the configuration")?;
    phase.store(Phase::Writing as u8, Ordering::SeqCst);
    trand_pipeline::outputs::write_run(&a.out, &run_json, &config, &rec.surfels, &renders)?;
    phase.store(Phase::Stoppable as u8, Ordering::SeqCst);
    let _ = std::fs::remove_dir_all(&ckpt);
    if cancel.load(Ordering::SeqCst) {
        eprintln!("interrupted; the run {} is complete", a.out.display());
        std::process::exit(130);
    }
    println!(
        "reconstructed {} in {:.1} s (preprocess {:.1} s, optimise {:.1} s): {} object surfels -> {}",
        a.data.display(),
        rec.preprocess_s + rec.optimise_s,
        rec.preprocess_s,
        rec.optimise_s,
        rec.surfels.len(),
        a.out.display()
    );
    if seq
        .test_t0
        .iter()
        .all(|v| v.depth.is_some() && v.instance.is_some())
        && !seq.test_t0.is_empty()
    {
        let (_, m) = trand_eval::evaluate_run(&a.out, &a.data, Some(trand_io::State::T0))?;
        print!("{}", trand_eval::table(&[("t0", &m)]));
    }
    Ok(())
}

/// The sequence at `data` with `num_objects` object channels (the run's), errors naming the path.
pub(crate) fn read_sequence(data: &Path, num_objects: usize) -> anyhow::Result<Sequence> {
    read_sequence_with(
        data,
        &LoadOptions {
            object_channels: Some(num_objects),
            ..Default::default()
        },
    )
    .with_context(|| format!("reading {}", data.display()))
}
