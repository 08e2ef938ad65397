//! The two 3-vector products the preprocess and the kernels share, on `[R; 3]` in the rasterizer's
//! precision (one definition, so every caller rounds the same way).

use trand_core::Real;

/// `u × v`.
#[inline(always)]
pub(crate) fn cross<R: Real>(u: &[R; 3], v: &[R; 3]) -> [R; 3] {
    [
        u[1] * v[2] - u[2] * v[1],
        u[2] * v[0] - u[0] * v[2],
        u[0] * v[1] - u[1] * v[0],
    ]
}

/// `a · b`.
#[inline]
pub(crate) fn dot<R: Real>(a: [R; 3], b: [R; 3]) -> R {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
