//! Activations and quaternion maths shared by the rasterizer and the optimiser.
//!
//! Quaternions are stored `(w, x, y, z)` and are *not* kept normalised: every use goes through
//! [`quat_to_rotmat`], which normalises first. The gradient of that normalisation is
//! [`normalize_vjp`].

use crate::Real;

/// Logistic sigmoid `1 / (1 + e^{-x})`, stable for large |x|.
#[inline]
pub fn sigmoid<R: Real>(x: R) -> R {
    if x >= R::ZERO {
        R::ONE / (R::ONE + (-x).exp())
    } else {
        let e = x.exp();
        e / (R::ONE + e)
    }
}

/// Inverse sigmoid `ln(p / (1 - p))`.
#[inline]
pub fn logit(p: f32) -> f32 {
    let p = p.clamp(1e-7, 1.0 - 1e-7);
    (p / (1.0 - p)).ln()
}

/// Numerically stable softmax of `logits` written to `out`.
pub fn softmax<R: Real>(logits: &[R], out: &mut [R]) {
    debug_assert_eq!(logits.len(), out.len());
    let mut m = logits.first().copied().unwrap_or(R::ZERO);
    for &l in logits {
        m = m.max(l);
    }
    let mut s = R::ZERO;
    for (o, &l) in out.iter_mut().zip(logits) {
        *o = (l - m).exp();
        s += *o;
    }
    let inv = R::ONE / s;
    for o in out.iter_mut() {
        *o *= inv;
    }
}

/// Softmax of eight rows at once, up to the division: `x[c][l]` (logit `c` of row `l`, channel-major
/// lanes) becomes `exp(x[c][l] − max_c x[c][l])` by [`Real::fast_exp8`] (its arguments are ≤ 0, the
/// range it is made for), and the per-row sums of those numerators, added in channel order, come back.
/// Row `l`'s probabilities are `x[c][l] / sum[l]`: each row gets the same operations in the same order
/// as a scalar softmax, whatever its neighbours in the block. The rasterizer's object probabilities and
/// the object-aware loss's membership both use it, so a surfel is a member exactly when its rendered
/// probability says so.
#[inline]
pub fn softmax_numerators8<R: Real>(x: &mut [[R; 8]]) -> [R; 8] {
    let Some((first, rest)) = x.split_first() else {
        return [R::ZERO; 8];
    };
    let mut m = *first;
    for xc in rest {
        for l in 0..8 {
            if xc[l] > m[l] {
                m[l] = xc[l];
            }
        }
    }
    let mut s = [R::ZERO; 8];
    for xc in x.iter_mut() {
        *xc = R::fast_exp8(std::array::from_fn(|l| xc[l] - m[l]));
        for l in 0..8 {
            s[l] += xc[l];
        }
    }
    s
}

/// VJP of softmax: given `p = softmax(l)` and `g = dL/dp`, returns `dL/dl_k = p_k (g_k - Σ_j p_j g_j)`.
pub fn softmax_vjp<R: Real>(p: &[R], g: &[R], out: &mut [R]) {
    let mut dot = R::ZERO;
    for (&pk, &gk) in p.iter().zip(g) {
        dot += pk * gk;
    }
    for ((o, &pk), &gk) in out.iter_mut().zip(p).zip(g) {
        *o = pk * (gk - dot);
    }
}

/// Rotation matrix (row-major `m[r][c]`) of the unit quaternion `q / |q|`, `q = (w, x, y, z)`.
///
/// Returns `None` for a zero or non-finite quaternion, so callers can cull the surfel instead of
/// rendering NaN.
#[inline]
// `!(a > b)` on purpose: NaN fails the test and is culled.
#[allow(clippy::neg_cmp_op_on_partial_ord)]
pub fn quat_to_rotmat<R: Real>(q: [R; 4]) -> Option<([[R; 3]; 3], [R; 4])> {
    let n2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3];
    if !(n2 > R::from_f64(1e-24)) || !n2.is_finite() {
        return None;
    }
    let inv = R::ONE / n2.sqrt();
    let (w, x, y, z) = (q[0] * inv, q[1] * inv, q[2] * inv, q[3] * inv);
    let two = R::from_f64(2.0);
    let m = [
        [
            R::ONE - two * (y * y + z * z),
            two * (x * y - w * z),
            two * (x * z + w * y),
        ],
        [
            two * (x * y + w * z),
            R::ONE - two * (x * x + z * z),
            two * (y * z - w * x),
        ],
        [
            two * (x * z - w * y),
            two * (y * z + w * x),
            R::ONE - two * (x * x + y * y),
        ],
    ];
    Some((m, [w, x, y, z]))
}

/// VJP of [`quat_to_rotmat`] with respect to the *normalised* quaternion `qn`, given `g = dL/dR`
/// (row-major). Differentiates the polynomial entries of `R(qn)`.
#[inline]
pub fn rotmat_vjp<R: Real>(qn: [R; 4], g: [[R; 3]; 3]) -> [R; 4] {
    let (w, x, y, z) = (qn[0], qn[1], qn[2], qn[3]);
    let two = R::from_f64(2.0);
    let gw = two * (x * (g[2][1] - g[1][2]) + y * (g[0][2] - g[2][0]) + z * (g[1][0] - g[0][1]));
    let gx = two
        * (-two * x * (g[1][1] + g[2][2])
            + y * (g[1][0] + g[0][1])
            + z * (g[2][0] + g[0][2])
            + w * (g[2][1] - g[1][2]));
    let gy = two
        * (x * (g[1][0] + g[0][1]) - two * y * (g[0][0] + g[2][2])
            + z * (g[2][1] + g[1][2])
            + w * (g[0][2] - g[2][0]));
    let gz = two
        * (x * (g[2][0] + g[0][2]) + y * (g[2][1] + g[1][2]) - two * z * (g[0][0] + g[1][1])
            + w * (g[1][0] - g[0][1]));
    [gw, gx, gy, gz]
}

/// VJP of `q ↦ q / |q|`: `g_raw = (g - (g·q̂) q̂) / |q|`.
#[inline]
pub fn normalize_vjp<R: Real>(q_raw: [R; 4], g: [R; 4]) -> [R; 4] {
    let n = (q_raw[0] * q_raw[0] + q_raw[1] * q_raw[1] + q_raw[2] * q_raw[2] + q_raw[3] * q_raw[3])
        .sqrt();
    let inv = R::ONE / n;
    let qn = [
        q_raw[0] * inv,
        q_raw[1] * inv,
        q_raw[2] * inv,
        q_raw[3] * inv,
    ];
    let d = g[0] * qn[0] + g[1] * qn[1] + g[2] * qn[2] + g[3] * qn[3];
    [
        (g[0] - d * qn[0]) * inv,
        (g[1] - d * qn[1]) * inv,
        (g[2] - d * qn[2]) * inv,
        (g[3] - d * qn[3]) * inv,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotmat_is_orthonormal_for_unnormalised_quaternion() {
        let (m, _) = quat_to_rotmat([0.3f64, -1.2, 0.7, 2.0]).expect("non-zero quaternion");
        for i in 0..3 {
            for j in 0..3 {
                let d: f64 = (0..3).map(|k| m[i][k] * m[j][k]).sum();
                let e = if i == j { 1.0 } else { 0.0 };
                assert!((d - e).abs() < 1e-12, "row {i}·row {j} = {d}");
            }
        }
    }

    #[test]
    fn zero_quaternion_is_rejected() {
        assert!(quat_to_rotmat([0.0f32; 4]).is_none());
        assert!(quat_to_rotmat([f32::NAN, 0.0, 0.0, 1.0]).is_none());
    }

    #[test]
    fn quaternion_chain_matches_finite_differences() {
        // L = Σ G ⊙ R(q/|q|) for a fixed random G; compare the analytic chain with central differences.
        let q = [0.4f64, -0.3, 0.9, 0.2];
        let g = [[0.3, -1.1, 0.5], [0.7, 0.2, -0.4], [-0.6, 0.8, 1.3]];
        let loss = |q: [f64; 4]| {
            let (m, _) = quat_to_rotmat(q).unwrap();
            (0..3)
                .flat_map(|i| (0..3).map(move |j| (i, j)))
                .map(|(i, j)| g[i][j] * m[i][j])
                .sum::<f64>()
        };
        let (_, qn) = quat_to_rotmat(q).unwrap();
        let an = normalize_vjp(q, rotmat_vjp(qn, g));
        for k in 0..4 {
            let h = 1e-6;
            let (mut qp, mut qm) = (q, q);
            qp[k] += h;
            qm[k] -= h;
            let fd = (loss(qp) - loss(qm)) / (2.0 * h);
            assert!(
                (fd - an[k]).abs() < 1e-8,
                "component {k}: fd {fd} analytic {}",
                an[k]
            );
        }
    }

    #[test]
    fn softmax_vjp_matches_finite_differences() {
        let l = [0.3f64, -1.0, 2.0, 0.1];
        let g = [1.0, -0.5, 0.25, 2.0];
        let loss = |l: &[f64]| {
            let mut p = [0.0; 4];
            softmax(l, &mut p);
            p.iter().zip(&g).map(|(a, b)| a * b).sum::<f64>()
        };
        let mut p = [0.0; 4];
        softmax(&l, &mut p);
        let mut an = [0.0; 4];
        softmax_vjp(&p, &g, &mut an);
        for k in 0..4 {
            let (mut lp, mut lm) = (l, l);
            lp[k] += 1e-6;
            lm[k] -= 1e-6;
            let fd = (loss(&lp) - loss(&lm)) / 2e-6;
            assert!((fd - an[k]).abs() < 1e-8);
        }
    }
}
