//! The per-pixel ray–surfel intersection (2DGS eq. 8–11), shared by the forward and backward kernels.
//!
//! For pixel `(x, y)` the planes `k = x·T_w − T_u` and `l = y·T_w − T_v` intersect the splat plane along
//! the ray; `p = k × l ∝ (u, v, 1)` gives the splat coordinates, `ρ₃ = u² + v²`. The screen-space filter
//! `ρ₂ = 2·|c − (x, y)|²` takes over where the disk is thinner than a pixel: `ρ = min(ρ₃, ρ₂)`,
//! `G = exp(−ρ/2)`, `α = min(0.99, o·G)`. The camera depth of the hit is `z = T_w · (u, v, 1)`.

use trand_core::Real;

use crate::constants::{FILTER_INV_SQUARE, MAX_ALPHA, MIN_ALPHA};
use crate::preprocess::Proj;

/// A ray–surfel hit that passes the depth and alpha gates.
#[derive(Clone, Copy, Debug)]
pub struct Hit<R> {
    pub u: R,
    pub v: R,
    pub z: R,
    pub pz: R,
    pub g: R,
    pub alpha: R,
    /// `ρ₃ ≤ ρ₂`: the object-space kernel is active (else the screen-space filter).
    pub object_space: bool,
    /// `o·G` reached the 0.99 clamp (zero gradient to `o` and `G`).
    pub clamped: bool,
}

/// Per (surfel, pixel row) constants: along a row `l = y·T_w − T_v` is fixed, so
/// `p = k × l = x·(T_w × l) − (T_u × l)` costs three multiply-adds per pixel.
#[derive(Clone, Copy, Debug)]
pub struct Row<R> {
    pub y: R,
    pub l: [R; 3],
    a: [R; 3],
    b: [R; 3],
}

impl<R: Real> Row<R> {
    #[inline(always)]
    pub fn new(p: &Proj<R>, y: R) -> Self {
        let (tu, tv, tw) = (&p.t_u, &p.t_v, &p.t_w);
        let l = [y * tw[0] - tv[0], y * tw[1] - tv[1], y * tw[2] - tv[2]];
        let cross = |u: &[R; 3]| [u[1] * l[2] - u[2] * l[1], u[2] * l[0] - u[0] * l[2], u[0] * l[1] - u[1] * l[0]];
        Self { y, l, a: cross(tw), b: cross(tu) }
    }
}

/// The hit of pixel `(x, row.y)` with surfel `p`, if it passes the depth and alpha gates.
#[inline(always)]
pub fn intersect<R: Real>(p: &Proj<R>, row: &Row<R>, x: R, near: R) -> Option<Hit<R>> {
    let tw = &p.t_w;
    let px = x * row.a[0] - row.b[0];
    let py = x * row.a[1] - row.b[1];
    let pz = x * row.a[2] - row.b[2];
    if pz == R::ZERO {
        return None;
    }
    let inv = R::ONE / pz;
    let (u, v) = (px * inv, py * inv);
    let z = u * tw[0] + v * tw[1] + tw[2];
    if z < near {
        return None;
    }
    let rho3 = u * u + v * v;
    let (dx, dy) = (p.center[0] - x, p.center[1] - row.y);
    let rho2 = R::from_f64(FILTER_INV_SQUARE) * (dx * dx + dy * dy);
    let object_space = rho3 <= rho2;
    let rho = if object_space { rho3 } else { rho2 };
    let g = (R::from_f64(-0.5) * rho).fast_exp();
    let a = p.opacity * g;
    let max_a = R::from_f64(MAX_ALPHA);
    let clamped = a > max_a;
    let alpha = if clamped { max_a } else { a };
    if alpha < R::from_f64(MIN_ALPHA) {
        return None;
    }
    Some(Hit { u, v, z, pz, g, alpha, object_space, clamped })
}

/// NDC-mapped depth used by the distortion loss, `m(z) = f/(f−n)·(1 − n/z)`, and its derivative.
#[inline(always)]
pub fn ndc_depth<R: Real>(z: R) -> (R, R) {
    let n = R::from_f64(crate::constants::DEFAULT_NEAR);
    let f = R::from_f64(crate::constants::FAR);
    let a = f / (f - n);
    (a * (R::ONE - n / z), a * n / (z * z))
}
