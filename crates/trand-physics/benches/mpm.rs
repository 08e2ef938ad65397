//! Times the MPM scene update on the fixture particles (`tests/data/mpm-reference`, or the
//! directory in `TRAND_MPM_FIXTURE`): 100 frames × 10 substeps, TRAN-D's settings, after one
//! warm-up frame on a copy. Plain `harness = false` main so that one run is one measurement.
//!
//! `cargo bench -p trand-physics --bench mpm` (threads: `RAYON_NUM_THREADS`). Prints wall time
//! and the process CPU time.

use std::time::Instant;

use trand_physics::{MpmConfig, MpmSolver};

fn main() {
    let dir = std::env::var("TRAND_MPM_FIXTURE").unwrap_or_else(|_| {
        concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/mpm-reference").into()
    });
    let path = format!("{dir}/particles_in.npy");
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("cannot read {path}: {e}"));
    let flat: Vec<f32> = npyz::NpyFile::new(&bytes[..]).unwrap().into_vec().unwrap();
    let positions: Vec<[f32; 3]> = flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    let frames = std::env::var("TRAND_MPM_FRAMES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(100u32);

    let mut warm = MpmSolver::new(MpmConfig::default(), &positions).unwrap();
    warm.step_frame().unwrap();

    let mut solver = MpmSolver::new(MpmConfig::default(), &positions).unwrap();
    let (t, cpu0) = (Instant::now(), process_cpu_seconds());
    solver.run(frames, |_, _| {}).unwrap();
    let secs = t.elapsed().as_secs_f64();
    let cpu = process_cpu_seconds().zip(cpu0).map(|(b, a)| b - a);
    println!(
        "trand-physics MPM: {} particles, {frames} frames x {} substeps: {secs:.3} s ({:.2} ms/substep, {} rayon threads)",
        positions.len(),
        solver.config().substeps,
        1e3 * secs / (frames * solver.config().substeps) as f64,
        rayon::current_num_threads()
    );
    if let Some(cpu) = cpu {
        // On a shared machine the CPU time is the steadier number: it excludes time spent waiting
        // for a core.
        println!("  process CPU time (all threads): {cpu:.3} s");
    }
}

/// User + system CPU time of this process (all threads) from `/proc/self/stat`; `None` off Linux.
/// Assumes the usual 100 clock ticks per second.
fn process_cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the parenthesised command name; utime and stime are fields 14 and 15.
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}
