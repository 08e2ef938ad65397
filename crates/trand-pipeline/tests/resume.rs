//! Interrupt-and-resume is exact: a reconstruction stopped at any iteration and resumed from its
//! checkpoint gives the same bits as the uninterrupted run, and a checkpoint of another sequence or
//! other options is refused (regression tests of issue 21).

mod common;

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};

use common::tiny;
use trand_io::Sequence;
use trand_pipeline::checkpoint::Checkpoint;
use trand_pipeline::reconstruct::{Reconstruction, Start, reconstruct_from};
use trand_pipeline::{PipelineError, ReconstructOptions};
use trand_train::PoseRefinement;
use trand_train::config::{ResolutionLevel, ResolutionSchedule};

fn options() -> ReconstructOptions {
    let mut o = ReconstructOptions::default();
    // Past densifications (every 20 from 20), the opacity reset (100) and into the object loss (> 100);
    // from the coarse level (80×60) to the training resolution (160×120) after iteration 60.
    o.train.iterations = 125;
    o.train.resolution = ResolutionSchedule::CoarseToFine(vec![ResolutionLevel {
        min_side: 60,
        ..ResolutionLevel::new(2, 0.48)
    }]);
    // Pose corrections stepped from 10 and settled at the densification of 80 (the openings are
    // decided again then): the resumed runs below cross both.
    o.train.pose = PoseRefinement::Refine {
        from_iteration: 10,
        settled_at: 80,
        lr_rotation: 2e-4,
        lr_translation: 2e-4,
        final_ratio: 0.1,
    };
    o
}

/// Runs from `start` and stops after iteration `stop` (if given), returning its checkpoint bytes.
fn run_until(
    seq: &Sequence,
    opts: &ReconstructOptions,
    start: Start,
    stop: Option<u32>,
) -> Result<Reconstruction, (PipelineError, Vec<u8>)> {
    let cancel = AtomicBool::new(false);
    let mut saved = Vec::new();
    let r = reconstruct_from(
        seq,
        opts,
        start,
        &mut |rep, snap| {
            if Some(rep.iteration) == stop {
                saved = snap.encode();
                cancel.store(true, Ordering::SeqCst);
            }
        },
        &cancel,
    );
    r.map_err(|e| (e, saved))
}

fn bits(r: &Reconstruction) -> Vec<u32> {
    let s = &r.surfels;
    s.means
        .as_flattened()
        .iter()
        .chain(s.log_scales.as_flattened())
        .chain(s.quats.as_flattened())
        .chain(&s.opacity_logits)
        .chain(s.sh_dc.as_flattened())
        .chain(s.mask_dc.as_flattened())
        .chain(&s.obj_logits)
        .map(|v| v.to_bits())
        .collect()
}

fn resume(bytes: &[u8]) -> Start {
    Start::Resume(Box::new(
        Checkpoint::decode(bytes, Path::new("checkpoint.bin")).expect("decode"),
    ))
}

#[test]
fn resumed_run_equals_the_uninterrupted_run_bit_for_bit() {
    let dir = trand_io::ScratchDir::new("resume-exact").expect("scratch");
    let seq = tiny(3, dir.path());
    let opts = options();
    let whole = run_until(&seq, &opts, Start::Init, None)
        .map_err(|e| e.0)
        .expect("uninterrupted");
    // Stopped mid-epoch between two densifications, resumed, stopped again just after the opacity
    // reset, resumed to the end.
    let (e, first) = run_until(&seq, &opts, Start::Init, Some(57)).expect_err("stops");
    assert!(matches!(e, PipelineError::Interrupted(57)), "{e}");
    let (e, second) = run_until(&seq, &opts, resume(&first), Some(103)).expect_err("stops");
    assert!(matches!(e, PipelineError::Interrupted(103)), "{e}");
    let resumed = run_until(&seq, &opts, resume(&second), None)
        .map_err(|e| e.0)
        .expect("resumed");
    assert!(!whole.surfels.is_empty());
    assert_eq!(resumed.surfels.len(), whole.surfels.len());
    assert_eq!(bits(&resumed), bits(&whole));
    assert_eq!(resumed.curve, whole.curve);
    assert_eq!(resumed.num_trained, whole.num_trained);
    assert_eq!(resumed.initial_surfels, whole.initial_surfels);
    assert_eq!(resumed.poses, whole.poses);
    assert!(whole.poses.settled.is_some());
    assert!(whole.poses.xi.iter().flatten().any(|&v| v != 0.0));
}

#[test]
fn a_checkpoint_of_another_sequence_or_other_options_is_refused() {
    let dir = trand_io::ScratchDir::new("resume-refused").expect("scratch");
    let (seq, other) = (tiny(3, dir.path()), tiny(4, dir.path()));
    let opts = options();
    let (_, ckpt) = run_until(&seq, &opts, Start::Init, Some(5)).expect_err("stops");
    let message = |r: Result<Reconstruction, (PipelineError, Vec<u8>)>| match r {
        Ok(_) => panic!("a mismatched checkpoint was accepted"),
        Err((e, _)) => e.to_string(),
    };
    let m = message(run_until(&other, &opts, resume(&ckpt), None));
    assert!(m.contains("other training views"), "{m}");
    let mut fewer = opts.clone();
    fewer.train.iterations = 4;
    let m = message(run_until(&seq, &fewer, resume(&ckpt), None));
    assert!(
        m.contains("other options") && m.contains("iterations"),
        "{m}"
    );
    let mut seed = opts.clone();
    seed.train.seed = 9;
    let m = message(run_until(&seq, &seed, resume(&ckpt), None));
    assert!(m.contains("other options"), "{m}");
}
