//! Times the MPM scene update on the fixture particles (`tests/data/mpm-reference`, or the
//! directory in `TRAND_MPM_FIXTURE`): 100 frames × 10 substeps, TRAN-D's settings, after one
//! warm-up frame on a copy. Plain `harness = false` main so that one run is one measurement.
//!
//! `cargo bench -p trand-physics --bench mpm` (threads: `RAYON_NUM_THREADS`).

use std::time::Instant;

use trand_physics::{MpmConfig, MpmSolver};

fn main() {
    let dir = std::env::var("TRAND_MPM_FIXTURE").unwrap_or_else(|_| concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/mpm-reference").into());
    let path = format!("{dir}/particles_in.npy");
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("cannot read {path}: {e}"));
    let flat: Vec<f32> = npyz::NpyFile::new(&bytes[..]).unwrap().into_vec().unwrap();
    let positions: Vec<[f32; 3]> = flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    let frames = std::env::var("TRAND_MPM_FRAMES").ok().and_then(|s| s.parse().ok()).unwrap_or(100u32);

    let mut warm = MpmSolver::new(MpmConfig::default(), &positions).unwrap();
    warm.step_frame().unwrap();

    let mut solver = MpmSolver::new(MpmConfig::default(), &positions).unwrap();
    let t = Instant::now();
    solver.run(frames, |_, _| {}).unwrap();
    let secs = t.elapsed().as_secs_f64();
    println!(
        "trand-physics MPM: {} particles, {frames} frames x {} substeps: {secs:.3} s ({:.2} ms/substep, {} rayon threads)",
        positions.len(),
        solver.config().substeps,
        1e3 * secs / (frames * solver.config().substeps) as f64,
        rayon::current_num_threads()
    );
}
