//! The per-particle part of a substep, four particles at a time (one per SIMD lane): the
//! deformation update `F ← (I + Δt C) F`, the polar rotation `R` of `F`, the fixed-corotated
//! Kirchhoff stress `τ = 2μ(F − R)Fᵀ + λJ(J − 1)I` with `J = det F`, and the MLS affine matrix
//! `A = −Δt V_p (4/dx²) τ + m_p C` that P2G scatters.
//!
//! # Polar rotation
//! The rotation extraction of Müller et al. 2016 ("A Robust Method to Extract the Rotational Part of
//! Deformations"): gradient ascent of `tr(RᵀF)` on the rotation quaternion,
//! `ω = Σᵢ rᵢ × fᵢ / (|Σᵢ rᵢ · fᵢ| + 10⁻⁹)` over the columns, `q ← exp(ω) q`, warm-started from the
//! particle's previous rotation, which converges in one or two iterations per substep. It always
//! returns a proper rotation (det +1), also for inverted `F`, where it maximises `tr(RᵀF)` like the
//! rotation-variant SVD `U Vᵀ` does.
//!
//! The lanes iterate together until every lane has converged; a converged lane's quaternion is
//! frozen (selected, not recomputed), so each particle's result is exactly that of iterating it
//! alone, whatever particles share its pack.
//!
//! # Precision
//! `f32`, like Taichi's default. The stopping tolerance ([`POLAR_TOLERANCE`]) dominates the error
//! of `R`; `f32` rounding of `F − R` (`F ≈ R` for small strain) is ~10⁻⁷, i.e. ~0.004 Pa of stress.
//! [`polar_rotation`] is the same iteration in `f64` on one matrix, for callers outside the solver
//! (rigid fits) and as the tests' reference.

use glam::{DMat3, DQuat};
use wide::f32x4;

use super::config::StepParams;
use super::store::{LaneMat3, Pack};

/// Polar rotation: stop when the incremental rotation angle is below this (radians). An error `δ` in
/// `R` changes τ by about `2μ·δ ≈ 3.6 Pa` at 1e-4, against the ~15 kPa a 10 cm glass of the paper's
/// density puts on its base (2e-4 relative), and the warm start means the error does not accumulate
/// (the fixture bodies still land within 5e-4 m of the Taichi engine's). Iterations per particle and
/// substep on the fixture: 4.6 at 1e-9, 1.8 at 1e-6; 1e-4 takes a further 20 % off the substep.
pub(super) const POLAR_TOLERANCE: f32 = 1e-4;
/// Polar rotation: iteration cap (only reached for degenerate `F`, e.g. a collapsed particle).
const POLAR_MAX_ITERATIONS: usize = 40;

/// A 3-vector per lane.
type LaneVec3 = [f32x4; 3];
/// A quaternion `(x, y, z, w)` per lane.
type LaneQuat = [f32x4; 4];

/// Updates `F` and `R` of the pack's particles from their `C`; returns their affine matrices `A`.
pub(super) fn update_pack(p: &mut Pack, sp: &StepParams) -> LaneMat3 {
    let dt = f32x4::splat(sp.dt);
    let step = add(&identity(), &scale(&p.c, dt));
    p.f = mul(&step, &p.f);
    let r;
    (p.rot, r) = polar_lanes(&p.f, p.rot);
    let j = det(&p.f);
    // τ = 2μ(F − R)Fᵀ + λJ(J−1)I, then A = stress_scale τ + m_p C.
    let mut tau = scale(
        &mul_transposed(&sub(&p.f, &r), &p.f),
        f32x4::splat(2.0 * sp.mu),
    );
    let pressure = f32x4::splat(sp.lambda) * j * (j - f32x4::ONE);
    for (k, col) in tau.iter_mut().enumerate() {
        col[k] += pressure;
    }
    add(
        &scale(&tau, f32x4::splat(sp.stress_scale)),
        &scale(&p.c, f32x4::splat(sp.p_mass)),
    )
}

/// Rotation part of `F = R S` per lane (module doc), from the warm start `q`; returns the
/// quaternion and its matrix.
fn polar_lanes(f: &LaneMat3, mut q: LaneQuat) -> (LaneQuat, LaneMat3) {
    let tol2 = f32x4::splat(POLAR_TOLERANCE * POLAR_TOLERANCE);
    let mut active = f32x4::ZERO.simd_eq(f32x4::ZERO); // every bit set: all lanes
    for _ in 0..POLAR_MAX_ITERATIONS {
        let r = quat_to_mat3(q);
        let num = add3(
            add3(cross(r[0], f[0]), cross(r[1], f[1])),
            cross(r[2], f[2]),
        );
        let den = (dot(r[0], f[0]) + dot(r[1], f[1]) + dot(r[2], f[2])).abs() + f32x4::splat(1e-9);
        let omega = num.map(|c| c / den);
        // `!(|ω|² < tol²)` keeps a NaN lane going, so test `≥`: NaN stops like convergence does.
        active &= dot(omega, omega).simd_ge(tol2);
        if !active.any() {
            return (q, r);
        }
        // exp(ω) to first order, (ω/2, 1) normalised: the same fixed point (ω = 0) without a
        // sincos, and a shorter, still ascending, step when ω is large.
        let next = normalize(half_turn_times(omega, q));
        q = std::array::from_fn(|k| active.select(next[k], q[k]));
    }
    (q, quat_to_mat3(q))
}

/// `(ω/2, 1) ⊗ q` (Hamilton product).
#[inline(always)]
fn half_turn_times(omega: LaneVec3, q: LaneQuat) -> LaneQuat {
    let h = omega.map(|c| f32x4::splat(0.5) * c);
    let [qx, qy, qz, qw] = q;
    let [hx, hy, hz] = h;
    [
        qx + qw * hx + (hy * qz - hz * qy),
        qy + qw * hy + (hz * qx - hx * qz),
        qz + qw * hz + (hx * qy - hy * qx),
        qw - (hx * qx + hy * qy + hz * qz),
    ]
}

#[inline(always)]
fn normalize(q: LaneQuat) -> LaneQuat {
    let inv = f32x4::ONE / (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    q.map(|c| c * inv)
}

/// Rotation matrix of a unit quaternion (glam's `Mat3::from_quat` per lane).
#[inline(always)]
fn quat_to_mat3([x, y, z, w]: LaneQuat) -> LaneMat3 {
    let (x2, y2, z2) = (x + x, y + y, z + z);
    let (xx, xy, xz) = (x * x2, x * y2, x * z2);
    let (yy, yz, zz) = (y * y2, y * z2, z * z2);
    let (wx, wy, wz) = (w * x2, w * y2, w * z2);
    let one = f32x4::ONE;
    [
        [one - (yy + zz), xy + wz, xz - wy],
        [xy - wz, one - (xx + zz), yz + wx],
        [xz + wy, yz - wx, one - (xx + yy)],
    ]
}

#[inline(always)]
fn cross(a: LaneVec3, b: LaneVec3) -> LaneVec3 {
    [
        a[1] * b[2] - b[1] * a[2],
        a[2] * b[0] - b[2] * a[0],
        a[0] * b[1] - b[0] * a[1],
    ]
}

#[inline(always)]
fn dot(a: LaneVec3, b: LaneVec3) -> f32x4 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline(always)]
fn add3(a: LaneVec3, b: LaneVec3) -> LaneVec3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

fn identity() -> LaneMat3 {
    let (o, i) = (f32x4::ZERO, f32x4::ONE);
    [[i, o, o], [o, i, o], [o, o, i]]
}

#[inline(always)]
fn add(a: &LaneMat3, b: &LaneMat3) -> LaneMat3 {
    std::array::from_fn(|c| add3(a[c], b[c]))
}

#[inline(always)]
fn sub(a: &LaneMat3, b: &LaneMat3) -> LaneMat3 {
    std::array::from_fn(|c| std::array::from_fn(|r| a[c][r] - b[c][r]))
}

#[inline(always)]
fn scale(a: &LaneMat3, s: f32x4) -> LaneMat3 {
    a.map(|col| col.map(|v| v * s))
}

/// `a b` (columns of the product are `a` applied to the columns of `b`).
#[inline(always)]
fn mul(a: &LaneMat3, b: &LaneMat3) -> LaneMat3 {
    std::array::from_fn(|c| {
        std::array::from_fn(|r| a[0][r] * b[c][0] + a[1][r] * b[c][1] + a[2][r] * b[c][2])
    })
}

/// `a bᵀ`: entry (r, c) is `Σₖ a[k][r] b[k][c]`.
#[inline(always)]
fn mul_transposed(a: &LaneMat3, b: &LaneMat3) -> LaneMat3 {
    std::array::from_fn(|c| {
        std::array::from_fn(|r| a[0][r] * b[0][c] + a[1][r] * b[1][c] + a[2][r] * b[2][c])
    })
}

/// `det a` (triple product of the columns).
#[inline(always)]
fn det(a: &LaneMat3) -> f32x4 {
    dot(a[0], cross(a[1], a[2]))
}

/// Rotation part `R` of `F = R S` (module doc), in `f64`, from `warm`: a unit quaternion (a
/// proper rotation, also for `det F ≤ 0`).
pub fn polar_rotation(f: DMat3, warm: DQuat) -> DQuat {
    let mut q = warm;
    for _ in 0..POLAR_MAX_ITERATIONS {
        let r = DMat3::from_quat(q);
        let num = r.x_axis.cross(f.x_axis) + r.y_axis.cross(f.y_axis) + r.z_axis.cross(f.z_axis);
        let den =
            (r.x_axis.dot(f.x_axis) + r.y_axis.dot(f.y_axis) + r.z_axis.dot(f.z_axis)).abs() + 1e-9;
        let omega = num / den;
        let angle = omega.length();
        if angle.is_nan() || angle < POLAR_TOLERANCE as f64 {
            return q;
        }
        let half = 0.5 * omega;
        q = (DQuat::from_xyzw(half.x, half.y, half.z, 1.0) * q).normalize();
    }
    q
}

#[cfg(test)]
mod tests {
    use glam::{DVec3, Mat3};

    use super::*;
    use crate::mpm::store::{LANES, lane_mat3, packs_at_rest};

    /// Polar rotation by Higham's Newton iteration `R ← ½(R + R⁻ᵀ)` (valid for det F > 0).
    fn newton_polar(f: DMat3) -> DMat3 {
        let mut r = f;
        for _ in 0..100 {
            r = 0.5 * (r + r.inverse().transpose());
        }
        r
    }

    /// Deterministic pseudo-random numbers in [-1, 1] (no rand dependency in unit tests).
    fn lcg(state: &mut u64) -> f64 {
        *state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((*state >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    }

    /// A rotation times a symmetric stretch, up to 3 rad and ±30 %.
    fn random_deformation(s: &mut u64) -> DMat3 {
        let axis = DVec3::new(lcg(s), lcg(s), lcg(s)).normalize();
        let rot = DMat3::from_axis_angle(axis, 3.0 * lcg(s));
        let a = DMat3::from_cols_array(&std::array::from_fn(|_| 0.3 * lcg(s)));
        rot * (DMat3::IDENTITY + 0.5 * (a + a.transpose()))
    }

    fn max_abs(m: DMat3) -> f64 {
        m.to_cols_array().iter().fold(0.0f64, |a, v| a.max(v.abs()))
    }

    fn lanes_of(ms: [DMat3; LANES]) -> LaneMat3 {
        std::array::from_fn(|c| std::array::from_fn(|r| f32x4::new(ms.map(|m| m.col(c)[r] as f32))))
    }

    fn quat_lanes(qs: [DQuat; LANES]) -> LaneQuat {
        std::array::from_fn(|k| f32x4::new(qs.map(|q| q.to_array()[k] as f32)))
    }

    #[test]
    fn polar_rotation_matches_newton_polar_decomposition() {
        let mut s = 7u64;
        for _ in 0..500 {
            let f = random_deformation(&mut s);
            if f.determinant() <= 0.05 {
                continue;
            }
            let r = DMat3::from_quat(polar_rotation(f, DQuat::IDENTITY));
            let e = max_abs(r - newton_polar(f));
            assert!(e < 2.0 * POLAR_TOLERANCE as f64, "error {e}");
        }
    }

    #[test]
    fn lane_polar_rotation_matches_newton_polar_decomposition_in_every_lane() {
        let mut s = 11u64;
        let mut done = 0;
        while done < 400 {
            let fs: [DMat3; LANES] = std::array::from_fn(|_| random_deformation(&mut s));
            if fs.iter().any(|f| f.determinant() <= 0.05) {
                continue;
            }
            let (q, r) = polar_lanes(&lanes_of(fs), quat_lanes([DQuat::IDENTITY; LANES]));
            for (l, f) in fs.iter().enumerate() {
                let rl = lane_mat3(&r, l).as_dmat3();
                let ql = glam::Quat::from_array(q.map(|c| c.as_array()[l])).as_dquat();
                let e = max_abs(rl - newton_polar(*f));
                assert!(e < 2.0 * POLAR_TOLERANCE as f64, "lane {l}: error {e}");
                assert!(
                    max_abs(rl - DMat3::from_quat(ql)) < 1e-6,
                    "R is not q's matrix"
                );
            }
            done += LANES;
        }
    }

    #[test]
    fn a_lanes_rotation_does_not_depend_on_the_other_lanes() {
        let mut s = 3u64;
        let f = random_deformation(&mut s);
        // Mates that converge at once (identity) or never (zero matrix: ω is NaN from the start;
        // a tiny matrix: many iterations).
        let tiny = 1e-6 * random_deformation(&mut s);
        let warm = quat_lanes([DQuat::IDENTITY; LANES]);
        let alone = polar_lanes(&lanes_of([f; LANES]), warm);
        for mates in [DMat3::IDENTITY, DMat3::ZERO, tiny] {
            let mixed = polar_lanes(&lanes_of([mates, f, mates, mates]), warm);
            let bits = |q: &LaneQuat, l: usize| q.map(|c| c.as_array()[l].to_bits());
            assert_eq!(bits(&alone.0, 0), bits(&mixed.0, 1), "mates {mates:?}");
        }
    }

    #[test]
    fn polar_rotation_of_inverted_f_is_a_proper_rotation() {
        let f = DMat3::from_diagonal(DVec3::new(1.0, 0.9, -0.2)) * DMat3::from_rotation_x(0.3);
        let score = |r: DMat3| {
            (r.transpose() * f)
                .to_cols_array()
                .iter()
                .step_by(4)
                .sum::<f64>()
        };
        let lane = lane_mat3(
            &polar_lanes(&lanes_of([f; LANES]), quat_lanes([DQuat::IDENTITY; LANES])).1,
            0,
        );
        for r in [
            DMat3::from_quat(polar_rotation(f, DQuat::IDENTITY)),
            lane.as_dmat3(),
        ] {
            assert!((r.determinant() - 1.0).abs() < 1e-5);
            // Maximises tr(RᵀF): no other rotation near it does better.
            for axis in [DVec3::X, DVec3::Y, DVec3::Z] {
                for a in [-0.05, 0.05] {
                    assert!(score(DMat3::from_axis_angle(axis, a) * r) <= score(r) + 1e-6);
                }
            }
        }
    }

    #[test]
    fn affine_matrix_is_the_fixed_corotated_stress_impulse_plus_apic_momentum() {
        let sp = crate::MpmConfig::default().step_params();
        let mut s = 5u64;
        let mut pack = packs_at_rest(&[[0.0; 3]; LANES])[0];
        let fs: [DMat3; LANES] = std::array::from_fn(|_| random_deformation(&mut s));
        let cs: [DMat3; LANES] = std::array::from_fn(|_| {
            DMat3::from_cols_array(&std::array::from_fn(|_| 20.0 * lcg(&mut s)))
        });
        (pack.f, pack.c) = (lanes_of(fs), lanes_of(cs));
        let a = update_pack(&mut pack, &sp);
        let (dt, mu, lambda) = (sp.dt as f64, sp.mu as f64, sp.lambda as f64);
        for l in 0..LANES {
            // f64 formulas on the lane's inputs and its rotation.
            let f = (DMat3::IDENTITY + dt * cs[l]) * fs[l];
            assert!(max_abs(pack.f(l).as_dmat3() - f) < 1e-5 * max_abs(f));
            let r = DMat3::from_quat(pack.rot(l).as_dquat());
            let j = f.determinant();
            let tau = 2.0 * mu * (f - r) * f.transpose()
                + DMat3::from_diagonal(DVec3::splat(lambda * j * (j - 1.0)));
            let want = sp.stress_scale as f64 * tau + sp.p_mass as f64 * cs[l];
            let got: Mat3 = lane_mat3(&a, l);
            let e = max_abs(got.as_dmat3() - want);
            assert!(
                e < 1e-5 * max_abs(want),
                "lane {l}: {e} of {}",
                max_abs(want)
            );
        }
    }
}
