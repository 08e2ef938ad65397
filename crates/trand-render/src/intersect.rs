//! The per-pixel ray–surfel intersection (2DGS eq. 8–11), shared by the forward and backward kernels.
//!
//! For pixel `(x, y)` the planes `k = x·T_w − T_u` and `l = y·T_w − T_v` intersect the splat plane along
//! the ray; `p = k × l ∝ (u, v, 1)` gives the splat coordinates, `ρ₃ = u² + v²`. The screen-space filter
//! `ρ₂ = 2·|c − (x, y)|²` takes over where the disk is thinner than a pixel: `ρ = min(ρ₃, ρ₂)`,
//! `G = exp(−ρ/2)`, `α = min(0.99, o·G)`. The camera depth of the hit is `z = T_w · (u, v, 1)`.

use trand_core::Real;

use crate::constants::{FILTER_INV_SQUARE, MAX_ALPHA, MIN_ALPHA};
use crate::lanes::{M, V, rsub, select};
use crate::preprocess::{Proj, RowCut};
use crate::vec3::cross;

/// A ray–surfel hit that passes the depth and alpha gates.
#[derive(Clone, Copy, Debug)]
pub struct Hit<R> {
    pub u: R,
    pub v: R,
    pub z: R,
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
    a: [R; 3],
    b: [R; 3],
}

/// The per-surfel part of [`Row`]: `T_w × l = T_v × T_w` does not depend on the row (`T_w × T_w = 0`)
/// and `T_u × l = y·(T_u × T_w) − T_u × T_v` is linear in it, so a kernel computes these three cross
/// products once per (tile, surfel) pair and each row costs six multiply-adds instead of two cross
/// products.
#[derive(Clone, Copy, Debug)]
pub struct RowBasis<R> {
    a: [R; 3],
    b1: [R; 3],
    b0: [R; 3],
}

impl<R: Real> RowBasis<R> {
    #[inline(always)]
    pub fn new(p: &Proj<R>) -> Self {
        Self {
            a: cross(&p.t_v, &p.t_w),
            b1: cross(&p.t_u, &p.t_w),
            b0: cross(&p.t_u, &p.t_v),
        }
    }
}

impl<R: Real> Row<R> {
    /// Row `y` of surfel `p` (see [`Row::at`] for the per-pair form the kernels use).
    #[inline(always)]
    pub fn new(p: &Proj<R>, y: R) -> Self {
        Self::at(&RowBasis::new(p), y)
    }

    /// Row `y` from the surfel's [`RowBasis`].
    #[inline(always)]
    pub fn at(basis: &RowBasis<R>, y: R) -> Self {
        Self {
            y,
            a: basis.a,
            b: [
                y * basis.b1[0] - basis.b0[0],
                y * basis.b1[1] - basis.b0[1],
                y * basis.b1[2] - basis.b0[2],
            ],
        }
    }
}

/// The columns `[lo, hi]` (inclusive, image coordinates) of pixel row `y` where surfel `p` can reach
/// `α ≥ 1/255` ([`crate::preprocess::RowCut`]); `None` when no column can. Outside it every pixel fails
/// the alpha gate, so the kernels skip those lanes: the rectangular evaluation box of an inclined
/// ellipse is mostly empty (on trained scenes two thirds of its pixels), and the cut changes no result.
/// The chord is evaluated in f32 in the ellipse's centred frame (error ~1e-4 px) and widened by
/// 0.05 px plus 0.2 % of its width, so rounding can never put a passing pixel outside it (tested
/// against the kernel itself on varied scenes). The margin was a whole pixel plus 1 % before: on the
/// benchmark scene that evaluated 11 % more eight-pixel groups for nothing.
#[inline(always)]
pub fn row_columns<R: Real>(p: &Proj<R>, y: R) -> Option<(i32, i32)> {
    let cut = &p.cut;
    let Some(ellipse) = cut.ellipse else {
        return Some((i32::MIN, i32::MAX));
    };
    let (reachable, lo, hi) = row_chord(cut, ellipse, y.to_f64() as f32);
    // Saturating casts: far outside the image either way.
    reachable.then_some((lo as i32, hi as i32))
}

/// [`row_columns`] for the sixteen image rows `ty0 .. ty0 + 16` of a tile at once (the forward kernel
/// asks for every row of every pair, ~60 scalar instructions a row; sixteen lanes of the same f32
/// operations cost about as much as two rows). Row `r` gets `(lo[r], hi[r])`, with `lo > hi` where
/// `row_columns` says `None`.
#[inline(always)]
pub fn tile_row_columns<R: Real>(p: &Proj<R>, ty0: i32) -> ([i32; 16], [i32; 16]) {
    let cut = &p.cut;
    let Some(ellipse) = cut.ellipse else {
        return ([i32::MIN; 16], [i32::MAX; 16]);
    };
    let (mut lo, mut hi) = ([0i32; 16], [0i32; 16]);
    for r in 0..16 {
        let (reachable, l, u) = row_chord(cut, ellipse, (ty0 + r as i32) as f32);
        lo[r] = if reachable { l as i32 } else { 1 };
        hi[r] = if reachable { u as i32 } else { 0 };
    }
    (lo, hi)
}

/// The chord of row `y` for [`row_columns`]: whether any column can pass the gate, and the widened
/// bounds (floored and ceiled; `±∞` when they came out NaN). Written without branches so that
/// [`tile_row_columns`] runs it on sixteen rows in vector lanes.
#[inline(always)]
#[allow(clippy::neg_cmp_op_on_partial_ord)] // `!(lo <= hi)` also catches NaN
fn row_chord(cut: &RowCut, [xc, m, y0, a, d]: [f32; 5], y: f32) -> (bool, f32, f32) {
    let rf = cut.filter_radius;
    let dy = y - y0;
    let r2 = a * dy * dy + d;
    let (h, xm) = (r2.sqrt(), xc - m * dy);
    let (elo, ehi) = (xm - h, xm + h);
    let (dlo, dhi) = (cut.center[0] - rf, cut.center[0] + rf);
    let e_ok = r2 >= 0.0;
    let d_ok = (y - cut.center[1]).abs() <= rf;
    let (lo, hi) = match (e_ok, d_ok) {
        (true, true) => (elo.min(dlo), ehi.max(dhi)),
        (true, false) => (elo, ehi),
        _ => (dlo, dhi),
    };
    let margin = 0.05 + 0.002 * (hi - lo);
    let (lo, hi) = ((lo - margin).floor(), (hi + margin).ceil());
    let (lo, hi) = if !(lo <= hi) {
        (f32::NEG_INFINITY, f32::INFINITY)
    } else {
        (lo, hi)
    };
    (e_ok || d_ok, lo, hi)
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
    Some(Hit {
        u,
        v,
        z,
        g,
        alpha,
        object_space,
        clamped,
    })
}

/// The hits of eight pixels of a row, [`intersect`] lane by lane. Lanes that miss (outside `lanes`,
/// parallel ray, behind the near plane, alpha below 1/255) have `valid` unset and are sanitised:
/// `u = v = 0`, `z = 1/p_z = 1`, `G = α = 0`, so any product with them is a finite zero.
#[derive(Clone, Copy, Debug)]
pub struct Hits<R: Real> {
    pub u: V<R>,
    pub v: V<R>,
    pub z: V<R>,
    /// `1/p_z`, which the backward pass needs again.
    pub inv_pz: V<R>,
    pub g: V<R>,
    pub alpha: V<R>,
    pub valid: M<R>,
    pub object_space: M<R>,
    pub clamped: M<R>,
}

/// [`intersect`] for the eight pixels at columns `xs` of `row`, restricted to `lanes`: the same
/// operations in the same order, so each lane equals the scalar result bit for bit.
#[inline(always)]
pub fn intersect_lanes<R: Real>(
    p: &Proj<R>,
    row: &Row<R>,
    xs: V<R>,
    near: R,
    lanes: M<R>,
) -> Hits<R> {
    hits(p, row, xs, lanes, Gates::Test { near })
}

/// [`intersect_lanes`] for lanes known to pass every gate: those the forward pass blended, which the
/// backward pass revisits. The same values, without the gates' comparisons.
#[inline(always)]
pub fn blended_lanes<R: Real>(p: &Proj<R>, row: &Row<R>, xs: V<R>, blended: M<R>) -> Hits<R> {
    hits(p, row, xs, blended, Gates::Passed)
}

/// Whether [`hits`] tests its lanes against the depth and alpha gates.
#[derive(Clone, Copy)]
enum Gates<R> {
    /// Valid lanes: `lanes` whose ray is not parallel, whose hit is beyond `near` and whose α ≥ 1/255.
    Test { near: R },
    /// Every lane of `lanes` is known to pass.
    Passed,
}

#[inline(always)]
fn hits<R: Real>(p: &Proj<R>, row: &Row<R>, xs: V<R>, lanes: M<R>, gates: Gates<R>) -> Hits<R> {
    let tw = &p.t_w;
    let px = xs * row.a[0] - row.b[0];
    let py = xs * row.a[1] - row.b[1];
    let pz = xs * row.a[2] - row.b[2];
    let nonzero = pz.ne(V::splat(R::ZERO));
    let inv = V::splat(R::ONE) / pz;
    let (u, v) = (px * inv, py * inv);
    let z = u * tw[0] + v * tw[1] + tw[2];
    let rho3 = u * u + v * v;
    let dx = rsub(p.center[0], xs);
    let dy = p.center[1] - row.y;
    let rho2 = (dx * dx + dy * dy) * R::from_f64(FILTER_INV_SQUARE);
    let object_space = rho3.le(rho2);
    let rho = select(object_space, rho3, rho2);
    let g = V(R::fast_exp8((rho * R::from_f64(-0.5)).0));
    let a = g * p.opacity;
    let max_a = V::splat(R::from_f64(MAX_ALPHA));
    let clamped = a.gt(max_a);
    let alpha = select(clamped, max_a, a);
    let valid = match gates {
        Gates::Test { near } => {
            lanes & nonzero & !z.lt(V::splat(near)) & !alpha.lt(V::splat(R::from_f64(MIN_ALPHA)))
        }
        Gates::Passed => lanes,
    };
    let (zero, one) = (V::splat(R::ZERO), V::splat(R::ONE));
    Hits {
        u: select(valid, u, zero),
        v: select(valid, v, zero),
        z: select(valid, z, one),
        inv_pz: select(valid, inv, one),
        g: select(valid, g, zero),
        alpha: select(valid, alpha, zero),
        valid,
        object_space,
        clamped: clamped & valid,
    }
}

/// NDC-mapped depth used by the distortion loss, `m(z) = f/(f−n)·(1 − n/z)`, and its derivative,
/// per lane.
#[inline(always)]
pub fn ndc_depth_lanes<R: Real>(z: V<R>) -> (V<R>, V<R>) {
    let n = R::from_f64(crate::constants::DEFAULT_NEAR);
    let f = R::from_f64(crate::constants::FAR);
    let a = f / (f - n);
    (
        rsub(R::ONE, V::splat(n) / z) * a,
        (V::splat(a * n) / (z * z)),
    )
}
