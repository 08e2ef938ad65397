//! What the pipeline's integration tests share: the tiny synthetic scene of a seed, and the pose
//! errors and short refined run the pose tests put it through.

use std::path::Path;

use glam::DVec3;
use trand_io::{Sequence, read_sequence};
use trand_pipeline::ReconstructOptions;
use trand_train::config::ResolutionSchedule;
use trand_train::{PoseCorrections, PoseRefinement};

/// `trand synth --preset tiny --seed SEED`, written under `dir` and read back.
pub fn tiny(seed: u64, dir: &Path) -> Sequence {
    let out = dir.join(format!("seq{seed}"));
    trand_synth::generate(&trand_synth::SynthConfig::new(
        trand_synth::Preset::Tiny,
        seed,
        &out,
    ))
    .expect("synth");
    read_sequence(&out).expect("read synthetic sequence")
}

/// Each of `n` views' world moved by its own `ξ_p` (3° about its own axis, 1 cm along its own
/// direction): the correction that undoes it is `−ξ_p` to first order, up to the mean (the gauge).
#[allow(dead_code)] // Not every test binary that shares this module moves its cameras.
pub fn wrong_poses(n: usize) -> PoseCorrections {
    let mut wrong = PoseCorrections::new(n);
    for (i, x) in wrong.xi.iter_mut().enumerate() {
        let a = i as f64 * 2.1;
        let axis = DVec3::new(a.cos(), a.sin(), 0.5 * (3.0 * a).cos()).normalize();
        let dir = DVec3::new((a + 1.0).sin(), (2.0 * a).cos(), 0.3).normalize();
        let (w, d) = (axis * 3f64.to_radians(), dir * 0.01);
        *x = [w.x, w.y, w.z, d.x, d.y, d.z];
    }
    wrong
}

/// 300 iterations at the training resolution, the poses refined from iteration 20 and settled at 150:
/// a run of the tiny scene short enough for a test.
#[allow(dead_code)] // Not every test binary that shares this module refines poses.
pub fn short_refined_run() -> ReconstructOptions {
    let mut opts = ReconstructOptions::default();
    opts.train.iterations = 300;
    opts.train.resolution = ResolutionSchedule::Full;
    opts.train.pose = PoseRefinement::Refine {
        from_iteration: 20,
        settled_at: 150,
        lr_rotation: 5e-4,
        lr_translation: 5e-4,
        final_ratio: 0.1,
    };
    opts
}
