//! Real spherical harmonics up to degree 3, with the constants and basis order of the 3DGS/2DGS
//! rasterizers (so checkpoints interoperate with common splat viewers).
//!
//! Colour = `max(Σ_k c_k · Y_k(d) + ½, 0)` per channel, with `d` the unit direction from the camera
//! centre to the surfel mean. Coefficient 0 is the "DC" term (`f_dc_*` in PLY files).

use crate::Real;

pub const SH_C0: f64 = 0.28209479177387814;
pub const SH_C1: f64 = 0.4886025119029199;
pub const SH_C2: [f64; 5] = [
    1.0925484305920792,
    -1.0925484305920792,
    0.31539156525252005,
    -1.0925484305920792,
    0.5462742152960396,
];
pub const SH_C3: [f64; 7] = [
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
];

/// Largest supported degree.
pub const MAX_SH_DEGREE: u32 = 3;

/// Number of coefficients per channel for a degree: `(d+1)²`.
pub const fn num_coeffs(degree: u32) -> usize {
    ((degree + 1) * (degree + 1)) as usize
}

/// RGB value of a constant colour as a DC coefficient: `(rgb − ½)/C0`.
pub fn rgb_to_dc(rgb: f32) -> f32 {
    ((rgb as f64 - 0.5) / SH_C0) as f32
}

/// DC coefficient to RGB (degree-0 colour before clamping).
pub fn dc_to_rgb(dc: f32) -> f32 {
    (dc as f64 * SH_C0 + 0.5) as f32
}

/// Evaluates the basis `Y_k(d)` for `k < num_coeffs(degree)` into `out`. `d` must be unit length.
#[inline]
pub fn basis<R: Real>(degree: u32, d: [R; 3], out: &mut [R; 16]) {
    let c = R::from_f64;
    let [x, y, z] = d;
    out[0] = c(SH_C0);
    if degree == 0 {
        return;
    }
    out[1] = -c(SH_C1) * y;
    out[2] = c(SH_C1) * z;
    out[3] = -c(SH_C1) * x;
    if degree == 1 {
        return;
    }
    let (xx, yy, zz, xy, yz, xz) = (x * x, y * y, z * z, x * y, y * z, x * z);
    let two = c(2.0);
    out[4] = c(SH_C2[0]) * xy;
    out[5] = c(SH_C2[1]) * yz;
    out[6] = c(SH_C2[2]) * (two * zz - xx - yy);
    out[7] = c(SH_C2[3]) * xz;
    out[8] = c(SH_C2[4]) * (xx - yy);
    if degree == 2 {
        return;
    }
    let (three, four) = (c(3.0), c(4.0));
    out[9] = c(SH_C3[0]) * y * (three * xx - yy);
    out[10] = c(SH_C3[1]) * xy * z;
    out[11] = c(SH_C3[2]) * y * (four * zz - xx - yy);
    out[12] = c(SH_C3[3]) * z * (two * zz - three * xx - three * yy);
    out[13] = c(SH_C3[4]) * x * (four * zz - xx - yy);
    out[14] = c(SH_C3[5]) * z * (xx - yy);
    out[15] = c(SH_C3[6]) * x * (xx - three * yy);
}

/// Jacobian of the basis with respect to the (unit) direction: `jac[k] = ∂Y_k/∂d`.
#[inline]
pub fn basis_jacobian<R: Real>(degree: u32, d: [R; 3], jac: &mut [[R; 3]; 16]) {
    let c = R::from_f64;
    let z0 = R::ZERO;
    let [x, y, z] = d;
    jac[0] = [z0; 3];
    if degree == 0 {
        return;
    }
    jac[1] = [z0, -c(SH_C1), z0];
    jac[2] = [z0, z0, c(SH_C1)];
    jac[3] = [-c(SH_C1), z0, z0];
    if degree == 1 {
        return;
    }
    let two = c(2.0);
    jac[4] = [c(SH_C2[0]) * y, c(SH_C2[0]) * x, z0];
    jac[5] = [z0, c(SH_C2[1]) * z, c(SH_C2[1]) * y];
    jac[6] = [
        -two * c(SH_C2[2]) * x,
        -two * c(SH_C2[2]) * y,
        c(4.0) * c(SH_C2[2]) * z,
    ];
    jac[7] = [c(SH_C2[3]) * z, z0, c(SH_C2[3]) * x];
    jac[8] = [two * c(SH_C2[4]) * x, -two * c(SH_C2[4]) * y, z0];
    if degree == 2 {
        return;
    }
    let (xx, yy, zz) = (x * x, y * y, z * z);
    let (three, four, six, eight) = (c(3.0), c(4.0), c(6.0), c(8.0));
    jac[9] = [
        c(SH_C3[0]) * six * x * y,
        c(SH_C3[0]) * (three * xx - three * yy),
        z0,
    ];
    jac[10] = [
        c(SH_C3[1]) * y * z,
        c(SH_C3[1]) * x * z,
        c(SH_C3[1]) * x * y,
    ];
    jac[11] = [
        -two * c(SH_C3[2]) * x * y,
        c(SH_C3[2]) * (four * zz - xx - three * yy),
        eight * c(SH_C3[2]) * y * z,
    ];
    jac[12] = [
        -six * c(SH_C3[3]) * x * z,
        -six * c(SH_C3[3]) * y * z,
        c(SH_C3[3]) * (six * zz - three * xx - three * yy),
    ];
    jac[13] = [
        c(SH_C3[4]) * (four * zz - three * xx - yy),
        -two * c(SH_C3[4]) * x * y,
        eight * c(SH_C3[4]) * x * z,
    ];
    jac[14] = [
        two * c(SH_C3[5]) * x * z,
        -two * c(SH_C3[5]) * y * z,
        c(SH_C3[5]) * (xx - yy),
    ];
    jac[15] = [
        c(SH_C3[6]) * (three * xx - three * yy),
        -six * c(SH_C3[6]) * x * y,
        z0,
    ];
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn basis_jacobian_matches_finite_differences() {
        let d = [0.3f64, -0.5, 0.812];
        let mut jac = [[0.0; 3]; 16];
        basis_jacobian(3, d, &mut jac);
        for a in 0..3 {
            let (mut dp, mut dm) = (d, d);
            dp[a] += 1e-6;
            dm[a] -= 1e-6;
            let (mut bp, mut bm) = ([0.0; 16], [0.0; 16]);
            basis(3, dp, &mut bp);
            basis(3, dm, &mut bm);
            for k in 0..16 {
                let fd = (bp[k] - bm[k]) / 2e-6;
                assert!(
                    (fd - jac[k][a]).abs() < 1e-8,
                    "coeff {k} axis {a}: fd {fd} vs {}",
                    jac[k][a]
                );
            }
        }
    }

    #[test]
    fn dc_round_trip() {
        assert!((dc_to_rgb(rgb_to_dc(0.25)) - 0.25).abs() < 1e-6);
        assert_eq!(num_coeffs(3), 16);
    }
}
