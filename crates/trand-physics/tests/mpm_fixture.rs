//! The solver against the authors' Taichi engine on the same particles
//! (`tests/data/mpm-reference`, a copy of the project fixture; see its README: body A, a soft cylinder resting on the ground, rows
//! 0..19999; body B, a box 5 cm above it, rows 20000..34999; 100 frames of TRAN-D's settings).

use trand_physics::{MpmConfig, MpmSolver};

const FIXTURE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/mpm-reference");
const BODY_A: std::ops::Range<usize> = 0..20000;
const BODY_B: std::ops::Range<usize> = 20000..35000;

fn load(name: &str) -> Vec<[f32; 3]> {
    let bytes = std::fs::read(format!("{FIXTURE}/{name}")).expect("fixture");
    let flat: Vec<f32> = npyz::NpyFile::new(&bytes[..]).unwrap().into_vec().unwrap();
    flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
}

fn mean_displacement(a: &[[f32; 3]], b: &[[f32; 3]]) -> [f64; 3] {
    let mut s = [0.0f64; 3];
    for (p, q) in a.iter().zip(b) {
        for k in 0..3 {
            s[k] += (q[k] - p[k]) as f64;
        }
    }
    s.map(|v| v / a.len() as f64)
}

fn z_range(a: &[[f32; 3]]) -> (f32, f32) {
    a.iter().fold((f32::MAX, f32::MIN), |(lo, hi), p| {
        (lo.min(p[2]), hi.max(p[2]))
    })
}

#[test]
fn fixture_bodies_land_where_the_taichi_engine_puts_them() {
    let input = load("particles_in.npy");
    let reference = load("particles_out_100_frames.npy");
    let mut solver = MpmSolver::new(MpmConfig::default(), &input).unwrap();
    solver.run(100, |_, _| {}).unwrap();
    let out = solver.positions();
    for (name, rows) in [("A", BODY_A), ("B", BODY_B)] {
        let ours = mean_displacement(&input[rows.clone()], &out[rows.clone()]);
        let theirs = mean_displacement(&input[rows.clone()], &reference[rows.clone()]);
        let (zr, zt) = (
            z_range(&out[rows.clone()]),
            z_range(&reference[rows.clone()]),
        );
        eprintln!(
            "body {name}: mean displacement ours {ours:?} taichi {theirs:?}; z range ours {zr:?} taichi {zt:?}"
        );
        // Measured agreement is ~1e-7 m (float order differs); the bounds leave room for other
        // platforms' rounding while catching any real change of the physics.
        for k in 0..3 {
            assert!(
                (ours[k] - theirs[k]).abs() < 5e-4,
                "body {name} axis {k}: {} vs {}",
                ours[k],
                theirs[k]
            );
        }
        assert!(
            (zr.0 - zt.0).abs() < 2e-3 && (zr.1 - zt.1).abs() < 2e-3,
            "body {name} z range {zr:?} vs {zt:?}"
        );
    }
}
