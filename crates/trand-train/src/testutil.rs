//! Helpers shared by the unit tests: seeded random inputs and a central-difference gradient check.

use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64;

/// `n` values uniform in `[lo, hi)` from a seeded generator.
pub fn rand_vec(seed: u64, n: usize, lo: f64, hi: f64) -> Vec<f64> {
    let mut rng = Pcg64::seed_from_u64(seed);
    (0..n)
        .map(|_| lo + (hi - lo) * rng.random::<f64>())
        .collect()
}

/// Checks `grad` against central differences of `f` at `x` for every coordinate:
/// `|fd − grad| ≤ abs_tol + 1e-5·|fd|`.
pub fn assert_grad_matches_fd(
    x: &[f64],
    grad: &[f64],
    f: impl Fn(&[f64]) -> f64,
    h: f64,
    abs_tol: f64,
) {
    assert_eq!(x.len(), grad.len());
    let mut xp = x.to_vec();
    for i in 0..x.len() {
        xp[i] = x[i] + h;
        let fp = f(&xp);
        xp[i] = x[i] - h;
        let fm = f(&xp);
        xp[i] = x[i];
        let fd = (fp - fm) / (2.0 * h);
        assert!(
            (fd - grad[i]).abs() <= abs_tol + 1e-5 * fd.abs(),
            "coordinate {i}: finite difference {fd:e}, analytic {:e}",
            grad[i]
        );
    }
}
