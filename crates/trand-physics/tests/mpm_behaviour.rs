//! Physical behaviour of the MPM solver on small scenes: free fall, resting contact, falling onto
//! the ground, and bit-identical results whatever the number of threads.

use trand_physics::{Ground, MpmConfig, MpmSolver, ParticleVolume, StopAtRest};

/// Particles on a regular lattice of spacing `h` filling the box `[lo, hi)`, offset by `h/2`.
fn block(lo: [f32; 3], hi: [f32; 3], h: f32) -> Vec<[f32; 3]> {
    let n: [usize; 3] = std::array::from_fn(|k| ((hi[k] - lo[k]) / h).round() as usize);
    let mut out = Vec::new();
    for k in 0..n[2] {
        for j in 0..n[1] {
            for i in 0..n[0] {
                out.push([
                    lo[0] + (i as f32 + 0.5) * h,
                    lo[1] + (j as f32 + 0.5) * h,
                    lo[2] + (k as f32 + 0.5) * h,
                ]);
            }
        }
    }
    out
}

/// A stiffer, real-density material (ρgh/E ≈ 6e-4 for a 6 cm block) so the block's own
/// oscillation is tiny and "at rest" is a meaningful check; everything else is the paper's setting.
fn stiff_config(spacing: f32) -> MpmConfig {
    MpmConfig {
        youngs_modulus: 5e5,
        density: 1000.0,
        particle_volume: ParticleVolume::Fixed(spacing * spacing * spacing),
        ..MpmConfig::default()
    }
}

fn mean(ps: &[[f32; 3]]) -> [f64; 3] {
    let mut s = [0.0f64; 3];
    for p in ps {
        for k in 0..3 {
            s[k] += p[k] as f64;
        }
    }
    s.map(|v| v / ps.len() as f64)
}

fn max_speed(vs: &[[f32; 3]]) -> f32 {
    vs.iter()
        .map(|v| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt())
        .fold(0.0, f32::max)
}

#[test]
fn free_fall_follows_the_ballistic_parabola() {
    let cfg = MpmConfig {
        ground: Ground::None,
        ..MpmConfig::default()
    };
    let h = cfg.dx / 2.0;
    let x0 = block([0.4, 0.4, 1.0], [0.5, 0.5, 1.06], h);
    let z0 = mean(&x0)[2];
    let mut solver = MpmSolver::new(cfg.clone(), &x0).unwrap();
    let frames = 50;
    solver.run(frames, |_, _| {}).unwrap();
    let n = (frames * cfg.substeps) as f64;
    let (dt, g) = (cfg.substep_dt() as f64, 4.9f64);
    let t = n * dt;
    let z = mean(&solver.positions())[2];
    // Symplectic Euler (v += g dt, then x += v dt) gives z0 − g dt² n(n+1)/2 = z0 − ½gt² − ½g t dt.
    let discrete = z0 - g * dt * dt * n * (n + 1.0) / 2.0;
    let analytic = z0 - 0.5 * g * t * t;
    assert!((z - discrete).abs() < 2e-5, "z {z} vs discrete {discrete}");
    assert!(
        (z - analytic).abs() < 0.5 * g * t * dt + 2e-5,
        "z {z} vs analytic {analytic}"
    );
    // A uniform translation does not deform the block.
    for f in solver.deformation_gradients() {
        assert!(
            (f - glam::Mat3::IDENTITY).abs_diff_eq(glam::Mat3::ZERO, 1e-4),
            "{f:?}"
        );
    }
    let v = solver.velocities();
    assert!(
        v.iter()
            .all(|v| (v[2] as f64 + g * t).abs() < 1e-3 && v[0].abs() < 1e-4 && v[1].abs() < 1e-4)
    );
}

#[test]
fn block_resting_on_the_floor_stays_put() {
    let h = 1.0 / 96.0;
    let cfg = stiff_config(h);
    let x0 = block([0.45, 0.45, 0.0], [0.51, 0.51, 0.06], h);
    let mut solver = MpmSolver::new(cfg, &x0).unwrap();
    solver.run(100, |_, _| {}).unwrap(); // 1000 substeps, 0.4 s
    let x = solver.positions();
    let (c0, c) = (mean(&x0), mean(&x));
    assert!(
        (c[0] - c0[0]).abs() < 1e-3 && (c[1] - c0[1]).abs() < 1e-3,
        "horizontal drift {c0:?} -> {c:?}"
    );
    assert!(
        (c[2] - c0[2]).abs() < 3e-3,
        "vertical drift {} -> {}",
        c0[2],
        c[2]
    );
    assert!(
        x.iter().all(|p| p[2] > -0.01 && p[2] < 0.07),
        "a particle left the block"
    );
    let v = max_speed(&solver.velocities());
    assert!(v < 0.02, "still moving at {v} m/s");
}

#[test]
fn block_whose_support_was_removed_falls_to_the_floor() {
    // The paper's (soft, heavy) material: the block lands and bounces elastically (there is no
    // damping in the model), so the check is on the trajectory: it reaches the floor, does not
    // pass through it, and stays well below where it started.
    let cfg = MpmConfig::default();
    let h = cfg.dx / 2.0;
    let x0 = block([0.45, 0.45, 0.10], [0.51, 0.51, 0.16], h);
    let mut solver = MpmSolver::new(cfg, &x0).unwrap();
    let mut lowest = f32::MAX;
    for frame in 0..100 {
        solver.step_frame().unwrap();
        let x = solver.positions();
        let zmin = x.iter().map(|p| p[2]).fold(f32::MAX, f32::min);
        lowest = lowest.min(zmin);
        if frame < 40 {
            // 0.16 s: still falling freely (contact starts after ~0.2 s).
            let c = mean(&x)[2];
            let t = 0.004 * (frame + 1) as f64;
            assert!(
                (c - (0.13 - 0.5 * 4.9 * t * t)).abs() < 2e-3,
                "frame {frame}: centroid {c}"
            );
        }
    }
    let x = solver.positions();
    assert!(lowest < 0.01, "never reached the floor (lowest {lowest})");
    assert!(lowest > -0.02, "went through the floor ({lowest})");
    assert!(
        mean(&x)[2] < 0.08,
        "centroid {} still near the start 0.13",
        mean(&x)[2]
    );
}

#[test]
fn results_are_bit_identical_for_one_and_many_threads() {
    let h = 1.0 / 144.0;
    // Two bodies, > 2 chunks of particles, one falling onto the other (contact, rotation).
    let mut x0 = block([0.40, 0.40, 0.0], [0.56, 0.56, 0.08], h);
    x0.extend(block([0.47, 0.44, 0.12], [0.55, 0.52, 0.16], h));
    assert!(x0.len() > 3 * trand_physics::mpm::CHUNK);
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let mut s = MpmSolver::new(MpmConfig::default(), &x0).unwrap();
            s.run(8, |_, _| {}).unwrap();
            (s.positions(), s.velocities(), s.rotations())
        })
    };
    let one = run(1);
    for threads in [2, 3, 4] {
        let many = run(threads);
        let bits = |v: &[[f32; 3]]| v.iter().flatten().map(|f| f.to_bits()).collect::<Vec<_>>();
        assert_eq!(
            bits(&one.0),
            bits(&many.0),
            "positions differ with {threads} threads"
        );
        assert_eq!(
            bits(&one.1),
            bits(&many.1),
            "velocities differ with {threads} threads"
        );
        let qbits = |q: &[glam::Quat]| {
            q.iter()
                .flat_map(|q| q.to_array())
                .map(f32::to_bits)
                .collect::<Vec<_>>()
        };
        assert_eq!(
            qbits(&one.2),
            qbits(&many.2),
            "rotations differ with {threads} threads"
        );
    }
}

#[test]
fn run_stops_once_every_particle_stayed_slower_than_the_threshold_for_its_frames() {
    // No gravity, no ground: nothing ever moves.
    let still = MpmConfig {
        gravity: [0.0; 3],
        ground: Ground::None,
        stop_at_rest: StopAtRest::Below {
            speed: 1e-6,
            frames: 3,
        },
        ..MpmConfig::default()
    };
    let x0 = block([0.4, 0.4, 0.1], [0.45, 0.45, 0.15], 1.0 / 96.0);
    let mut solver = MpmSolver::new(still.clone(), &x0).unwrap();
    assert_eq!(solver.run(10, |_, _| {}).unwrap(), 3);
    assert!(solver.at_rest() && solver.frames_done() == 3);
    let never = MpmConfig {
        stop_at_rest: StopAtRest::Never,
        ..still
    };
    let mut solver = MpmSolver::new(never, &x0).unwrap();
    assert_eq!(solver.run(10, |_, _| {}).unwrap(), 10);
    assert!(!solver.at_rest());
}

#[test]
fn a_body_that_lost_its_support_is_never_taken_for_at_rest() {
    // TRAN-D's criterion on a block starting to fall from rest: it is faster than the threshold
    // from the first frame on.
    let cfg = MpmConfig::default();
    let StopAtRest::Below { speed, .. } = cfg.stop_at_rest else {
        panic!("the default stops at rest");
    };
    let x0 = block([0.45, 0.45, 0.10], [0.51, 0.51, 0.16], cfg.dx / 2.0);
    let mut solver = MpmSolver::new(cfg, &x0).unwrap();
    for _ in 0..30 {
        solver.step_frame().unwrap();
        assert!(solver.max_speed() > speed && !solver.at_rest());
    }
}
