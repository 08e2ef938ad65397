//! End-to-end checks of reconstruction and scene update: on a tiny synthetic scene (generated here by
//! `trand-synth`, exact ground truth) and on the independent Blender sequences in `shared/data/blender`
//! (ignored unless asked for with `--include-ignored`).

mod common;
#[path = "../../../testdata/shared_data.rs"]
mod shared_data;

use std::sync::atomic::AtomicBool;

use trand_eval::{Metrics, evaluate};
use trand_io::{Sequence, View, ViewCount, read_sequence, select_train_views};
use trand_pipeline::outputs::render_views;
use trand_pipeline::relocalise::Reason;
use trand_pipeline::simulate::channel_members;
use trand_pipeline::update::{RefineScope, SceneScale, Stage, UpdateOptions, update};
use trand_pipeline::{ReconstructOptions, Supervision, reconstruct};
use trand_render::RenderSettings;

fn metrics(surfels: &trand_core::Surfels, views: &[View]) -> Metrics {
    let renders = render_views(surfels, views, &RenderSettings::default()).expect("render");
    let preds: Vec<(String, trand_io::DepthMap)> = views
        .iter()
        .zip(renders)
        .map(|(v, r)| (v.name.clone(), r.depth))
        .collect();
    evaluate(&preds, views).expect("evaluate")
}

fn scale(seq: &Sequence, downsample: u32) -> SceneScale {
    let cams: Vec<_> = select_train_views(&seq.train_t0, ViewCount::Six)
        .iter()
        .map(|v| v.camera)
        .collect();
    SceneScale::from_cameras(&cams, downsample)
}

/// Reconstructs with `iterations` at `downsample`, then updates with each of `updates`; returns the t0
/// metrics and, per update, the t1 metrics and the removed ids it found.
fn run_with(
    seq: &Sequence,
    iterations: u32,
    downsample: u32,
    updates: &[UpdateOptions],
) -> (Metrics, Vec<(Metrics, Vec<u16>)>) {
    let mut opts = ReconstructOptions {
        downsample,
        ..Default::default()
    };
    opts.train.iterations = iterations;
    let rec = reconstruct(seq, &opts, None, &mut |_, _| {}, &AtomicBool::new(false))
        .expect("reconstruct");
    let m0 = metrics(&rec.surfels, &seq.test_t0);
    let new_view = seq
        .train_t1
        .iter()
        .find(|v| v.frame == 0)
        .expect("train_1 frame 0");
    let t1 = updates
        .iter()
        .map(|u| {
            let up = update(
                rec.surfels.clone(),
                &rec.channels,
                new_view,
                scale(seq, downsample),
                Supervision::ObjectAware,
                u,
                &mut |_, _, _| {},
                &mut |_| {},
            )
            .expect("update");
            (metrics(&up.surfels, &seq.test_t1), up.removed)
        })
        .collect();
    (m0, t1)
}

/// [`run_with`] the default update.
fn run(seq: &Sequence, iterations: u32, downsample: u32) -> (Metrics, Metrics, Vec<u16>) {
    let (m0, mut t1) = run_with(seq, iterations, downsample, &[UpdateOptions::default()]);
    let (m1, removed) = t1.pop().expect("one update");
    (m0, m1, removed)
}

#[test]
fn tiny_synthetic_scene_is_reconstructed_and_updated_within_bounds() {
    let dir = trand_io::ScratchDir::new("e2e-tiny").expect("scratch dir");
    // Seed 1: removing the support drops the glass on it 5 cm without toppling.
    let seq = common::tiny(1, dir.path());
    let (m0, m1, removed) = run(&seq, 200, 1);
    println!(
        "tiny t0: MAE {:.4} <2.5cm {:.3}; t1: MAE {:.4} <2.5cm {:.3}",
        m0.mae_m, m0.acc[2], m1.mae_m, m1.acc[2]
    );
    assert!(m0.mae_m < 0.04, "t0 MAE {} m", m0.mae_m);
    assert!(m0.acc[2] > 0.6, "t0 share under 2.5 cm {}", m0.acc[2]);
    assert_eq!(Some(removed), seq.removed_ids, "detected removal");
    assert!(
        m1.mae_m < 0.04 && m1.acc[2] > 0.6,
        "t1 MAE {} m, share {}",
        m1.mae_m,
        m1.acc[2]
    );
}

/// Seed 5: the glass on the removed object tips over by ~90° and lands several centimetres from where
/// the simulation puts it. The silhouette relocalisation moves it onto its mask; without it, a third
/// of the object pixels are left uncovered.
#[test]
fn a_toppled_glass_is_recovered_at_t1_by_silhouette_relocalisation() {
    let dir = trand_io::ScratchDir::new("e2e-topple").expect("scratch dir");
    let seq = common::tiny(5, dir.path());
    let off = UpdateOptions {
        relocalise: Stage::Off,
        ..Default::default()
    };
    let (_, t1) = run_with(&seq, 200, 1, &[UpdateOptions::default(), off]);
    let ((on, removed), (off, _)) = (&t1[0], &t1[1]);
    println!(
        "seed 5 t1: MAE {:.4} <2.5cm {:.3}; without relocalisation {:.4} {:.3}",
        on.mae_m, on.acc[2], off.mae_m, off.acc[2]
    );
    assert_eq!(Some(removed.clone()), seq.removed_ids, "detected removal");
    assert!(
        on.mae_m < 0.08 && on.acc[2] > 0.6,
        "t1 MAE {} m, share {}",
        on.mae_m,
        on.acc[2]
    );
    assert!(
        off.mae_m > 2.0 * on.mae_m,
        "without relocalisation: MAE {} m",
        off.mae_m
    );
}

/// A short run (150 iterations at quarter resolution) on the independent Blender data already beats the
/// paper's TRansPose rows (t0: MAE 0.0380 m, 69.11 % under 2.5 cm; t1: 0.0864 m, 48.46 %) and finds the
/// removed object.
#[test]
#[ignore = "needs ../shared/data/blender (see README: Tests)"]
fn blender_sequences_beat_the_papers_rows_after_a_short_run() {
    for name in ["seq_101", "seq_105"] {
        let path = shared_data::shared_data(&format!("blender/{name}"));
        let seq = read_sequence(&path).expect("read Blender sequence");
        let (m0, m1, removed) = run(&seq, 150, 4);
        println!(
            "{name} t0: MAE {:.4} <2.5cm {:.3}; t1: MAE {:.4} <2.5cm {:.3}",
            m0.mae_m, m0.acc[2], m1.mae_m, m1.acc[2]
        );
        assert!(
            m0.mae_m < 0.038 && m0.acc[2] > 0.6911,
            "{name} t0: MAE {} share {}",
            m0.mae_m,
            m0.acc[2]
        );
        assert!(
            m1.mae_m < 0.0864 && m1.acc[2] > 0.4846,
            "{name} t1: MAE {} share {}",
            m1.mae_m,
            m1.acc[2]
        );
        assert_eq!(Some(removed), seq.removed_ids, "{name}: detected removal");
    }
}

#[test]
fn same_seed_gives_bit_identical_surfels_for_one_and_two_threads() {
    let dir = trand_io::ScratchDir::new("e2e-det").expect("scratch dir");
    let seq = common::tiny(2, dir.path());
    let mut opts = ReconstructOptions::default();
    // Past the first densification (20) and opacity reset (100), with the object loss active (> 100).
    opts.train.iterations = 110;
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool");
        pool.install(|| {
            reconstruct(&seq, &opts, None, &mut |_, _| {}, &AtomicBool::new(false))
                .expect("reconstruct")
        })
    };
    let (a, b) = (run(1), run(2));
    let bits = |s: &trand_core::Surfels| -> Vec<u32> {
        s.means
            .as_flattened()
            .iter()
            .chain(s.log_scales.as_flattened())
            .chain(&s.obj_logits)
            .map(|v| v.to_bits())
            .collect()
    };
    assert!(!a.surfels.is_empty());
    assert_eq!(a.surfels.len(), b.surfels.len());
    assert_eq!(bits(&a.surfels), bits(&b.surfels));
    assert_eq!(a.curve, b.curve);
}

#[test]
fn objects_nothing_moved_keep_their_t0_surfels_through_the_refinement() {
    let dir = trand_io::ScratchDir::new("e2e-frozen").expect("scratch dir");
    let seq = common::tiny(3, dir.path());
    let mut opts = ReconstructOptions::default();
    opts.train.iterations = 150;
    let rec = reconstruct(&seq, &opts, None, &mut |_, _| {}, &AtomicBool::new(false))
        .expect("reconstruct");
    let new_view = seq.train_t1.iter().find(|v| v.frame == 0).expect("frame 0");
    let means_of = |s: &trand_core::Surfels, channel: usize| -> Vec<[u32; 3]> {
        let mut m: Vec<[u32; 3]> = channel_members(s, channel)
            .into_iter()
            .map(|i| s.means[i as usize].map(f32::to_bits))
            .collect();
        m.sort_unstable();
        m
    };
    let run = |scope| {
        let u = UpdateOptions {
            refine_scope: scope,
            ..Default::default()
        };
        update(
            rec.surfels.clone(),
            &rec.channels,
            new_view,
            scale(&seq, 1),
            Supervision::ObjectAware,
            &u,
            &mut |_, _, _| {},
            &mut |_| {},
        )
        .expect("update")
    };
    let moved = run(RefineScope::Moved);
    assert!(!moved.curve.is_empty(), "the refinement ran");
    let unmoved: Vec<(u16, usize)> = rec
        .channels
        .iter()
        .copied()
        .filter(|(id, _)| {
            !moved.removed.contains(id)
                && !moved.movable.contains(id)
                && moved
                    .relocations
                    .iter()
                    .all(|r| r.object_id != *id || r.reason == Reason::Static)
        })
        .collect();
    assert!(
        !unmoved.is_empty(),
        "the tiny scene keeps an object nothing moved"
    );
    let all = run(RefineScope::All);
    for &(id, c) in &unmoved {
        let t0 = means_of(&rec.surfels, c);
        assert!(!t0.is_empty());
        assert_eq!(means_of(&moved.surfels, c), t0, "object {id} changed");
        assert_ne!(
            means_of(&all.surfels, c),
            t0,
            "object {id}: the paper's scope refines it"
        );
    }
}
