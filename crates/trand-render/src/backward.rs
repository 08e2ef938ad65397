//! Stage 4 and 5: per-tile backward rasterization and the per-surfel gradient reduction.
//!
//! Each tile walks its list back to front from the last surfel any of its pixels blended. Per pixel it
//! keeps the transmittance, recovered as `T_i = T_{i+1}/(1 − α_i)` from the saved `T_final`, and suffix
//! sums `S_q = Σ_{k>i} q_k α_k Π_{i<j<k}(1 − α_j)` for every blended quantity `q`, updated after use as
//! `S_q ← α_i q_i + (1 − α_i) S_q`. Then (2DGS backward, with `g_·` the upstream pixel gradients):
//!
//! * `∂L/∂q_i = α_i T_i g_q` for colours, mask colours, object probabilities and normals;
//! * `∂L/∂α_i = T_i [Σ_q (q_i − S_q)·g_q + (1 − S_1) g_A + (g_{w,i} − S_w)] − T_final (bg·g_C + bg·g_M)/(1 − α_i)`,
//!   with the distortion weight gradient `g_{w,i} = (M₂ + m_i² A − 2 m_i M₁) g_dist`;
//! * `∂L/∂z_i = α_i T_i g_D + [i = median] g_med + 2 α_i T_i (m_i A − M₁) g_dist · ∂m/∂z`;
//! * `α = o·G` → `∂L/∂o = G ∂L/∂α`, `∂L/∂G = o ∂L/∂α` (zero when `o·G` hit the 0.99 clamp: the exact
//!   derivative, where the CUDA reference ignores the clamp), `G = e^{−ρ/2}`;
//! * object-space branch: `ρ = u² + v²`; filter branch: `ρ = 2|c − x|²`, whose gradient goes to the
//!   filter centre `c`. In both branches the depth `z = T_w·(u, v, 1)` depends on `T` through `(u, v)`:
//!   trand keeps that term (the reference drops it in the filter branch), so the gradient is exact.
//! * `(u, v) = (p_x, p_y)/p_z`, `p = k × l`, `k = x T_w − T_u`, `l = y T_w − T_v` → ∂L/∂T.
//!
//! Every (tile, surfel) pair writes one gradient record at its pair position; stage 5 sums each
//! surfel's records in the fixed order of [`crate::binning::Bins::pair_pos`]. No atomics, so results are
//! bit-identical for any number of threads.

use trand_core::Real;

use crate::binning::Bins;
use crate::camera::{cross, CamR};
use crate::constants::{FILTER_INV_SQUARE, TILE, TILE_PIXELS};
use crate::forward::tile_pixels;
use crate::intersect::{intersect, ndc_depth};
use crate::layout::Layout;
use crate::preprocess::{Proj, ProjGrad};

/// Offsets inside a pair gradient record.
pub mod rec {
    pub const T: usize = 0;
    pub const CENTER: usize = 9;
    pub const RGB: usize = 11;
    pub const MASK: usize = 14;
    pub const NORMAL: usize = 17;
    pub const OPACITY: usize = 20;
    pub const OBJ: usize = 21;
    /// Record length for `k` object channels.
    pub const fn stride(k: usize) -> usize {
        OBJ + k
    }
}

/// Row-major upstream gradients of the rendered maps (`None` = zero).
#[derive(Clone, Copy, Default)]
pub struct GradMaps<'a, R> {
    pub rgb: Option<&'a [R]>,
    pub mask: Option<&'a [R]>,
    pub objects: Option<&'a [R]>,
    pub alpha: Option<&'a [R]>,
    pub depth: Option<&'a [R]>,
    pub median: Option<&'a [R]>,
    pub normal: Option<&'a [R]>,
    pub distortion: Option<&'a [R]>,
}

/// Backward pass of tile `t`: writes one record per pair of the tile into `pairs`
/// (`(tile_start[t+1] − tile_start[t]) × stride` values, zero-initialised).
#[allow(clippy::too_many_arguments)]
pub fn backward_tile<R: Real>(
    t: usize,
    bins: &Bins,
    projs: &[Proj<R>],
    probs: &[R],
    lay: &Layout,
    cam: &CamR<R>,
    background: [R; 3],
    buf: &[R],
    ibuf: &[u32],
    grads: &GradMaps<'_, R>,
    pairs: &mut [R],
) {
    let (tx0, ty0, tx1, ty1) = tile_pixels(t, bins.tiles_x, cam.width, cam.height);
    let k_obj = lay.num_objects;
    let stride = rec::stride(k_obj);
    let (last, medpos) = ibuf.split_at(TILE_PIXELS);
    let max_last = last.iter().copied().max().unwrap_or(0) as usize;
    if max_last == 0 {
        return;
    }
    let w_img = cam.width as usize;
    let has_mask = lay.has_mask && grads.mask.is_some();
    let has_obj = lay.has_objects && grads.objects.is_some();

    // Gather the upstream gradients into channel-planar tile arrays.
    let nq = 3 + 3 + k_obj;
    let mut g_col = vec![R::ZERO; nq * TILE_PIXELS]; // rgb 0..3, mask 3..6, obj 6..
    let mut g_sc = vec![R::ZERO; 8 * TILE_PIXELS]; // alpha, depth, median, nx, ny, nz, dist, bg term
    for y in ty0..=ty1 {
        for x in tx0..=tx1 {
            let idx = ((y - ty0) * TILE as i32 + (x - tx0)) as usize;
            let pix = y as usize * w_img + x as usize;
            let mut bg_term = R::ZERO;
            if let Some(g) = grads.rgb {
                for c in 0..3 {
                    g_col[c * TILE_PIXELS + idx] = g[pix * 3 + c];
                    bg_term += background[c] * g[pix * 3 + c];
                }
            }
            if has_mask {
                let g = grads.mask.expect("checked");
                for c in 0..3 {
                    g_col[(3 + c) * TILE_PIXELS + idx] = g[pix * 3 + c];
                    bg_term += background[c] * g[pix * 3 + c];
                }
            }
            if has_obj {
                let g = grads.objects.expect("checked");
                for c in 0..k_obj {
                    g_col[(6 + c) * TILE_PIXELS + idx] = g[pix * k_obj + c];
                }
            }
            let scalar = |m: Option<&[R]>| m.map_or(R::ZERO, |g| g[pix]);
            g_sc[idx] = scalar(grads.alpha);
            g_sc[TILE_PIXELS + idx] = scalar(grads.depth);
            g_sc[2 * TILE_PIXELS + idx] = scalar(grads.median);
            if let Some(g) = grads.normal {
                for c in 0..3 {
                    g_sc[(3 + c) * TILE_PIXELS + idx] = g[pix * 3 + c];
                }
            }
            g_sc[6 * TILE_PIXELS + idx] = scalar(grads.distortion);
            g_sc[7 * TILE_PIXELS + idx] = bg_term * buf[lay.t_final * TILE_PIXELS + idx];
        }
    }
    let has_dist = grads.distortion.is_some();

    // Per-pixel running state: T and suffix sums (colours, mask, objects, z, 1, normal, w).
    let mut tr: Vec<R> = buf[lay.t_final * TILE_PIXELS..(lay.t_final + 1) * TILE_PIXELS].to_vec();
    let mut s_col = vec![R::ZERO; nq * TILE_PIXELS];
    let mut s_sc = vec![R::ZERO; 6 * TILE_PIXELS]; // z, one, nx, ny, nz, w
    let list = bins.tile(t);
    let two = R::from_f64(2.0);
    let filt2 = R::from_f64(2.0 * FILTER_INV_SQUARE);

    for pos in (0..max_last).rev() {
        let j = list[pos] as usize;
        let p = &projs[j];
        let pr = &probs[j * k_obj..(j + 1) * k_obj];
        let (x0, y0) = (p.bbox[0].max(tx0), p.bbox[1].max(ty0));
        let (x1, y1) = (p.bbox[2].min(tx1), p.bbox[3].min(ty1));
        let rec_out = &mut pairs[pos * stride..(pos + 1) * stride];
        let mut touched = false;
        for y in y0..=y1 {
            let yr = R::from_f64(y as f64);
            let row = ((y - ty0) * TILE as i32) as usize;
            for x in x0..=x1 {
                let idx = row + (x - tx0) as usize;
                if pos as u32 >= last[idx] {
                    continue;
                }
                let xr = R::from_f64(x as f64);
                let Some(h) = intersect(p, xr, yr, cam.near) else { continue };
                touched = true;
                let a = h.alpha;
                let one_m = R::ONE - a;
                let t_i = tr[idx] / one_m;
                let w = a * t_i;
                let px = |c: usize| c * TILE_PIXELS + idx;

                // Blended colour-like quantities.
                let mut bracket = R::ZERO;
                for c in 0..3 {
                    let g = g_col[px(c)];
                    rec_out[rec::RGB + c] += w * g;
                    bracket += (p.rgb[c] - s_col[px(c)]) * g;
                    s_col[px(c)] = a * p.rgb[c] + one_m * s_col[px(c)];
                }
                if has_mask {
                    for c in 0..3 {
                        let g = g_col[px(3 + c)];
                        rec_out[rec::MASK + c] += w * g;
                        bracket += (p.mask[c] - s_col[px(3 + c)]) * g;
                        s_col[px(3 + c)] = a * p.mask[c] + one_m * s_col[px(3 + c)];
                    }
                }
                if has_obj {
                    for (c, &pc) in pr.iter().enumerate() {
                        let g = g_col[px(6 + c)];
                        rec_out[rec::OBJ + c] += w * g;
                        bracket += (pc - s_col[px(6 + c)]) * g;
                        s_col[px(6 + c)] = a * pc + one_m * s_col[px(6 + c)];
                    }
                }
                // Depth, alpha, normal.
                let g_d = g_sc[px(1)];
                bracket += (h.z - s_sc[px(0)]) * g_d;
                s_sc[px(0)] = a * h.z + one_m * s_sc[px(0)];
                let mut dz = w * g_d;
                bracket += (R::ONE - s_sc[px(1)]) * g_sc[px(0)];
                s_sc[px(1)] = a + one_m * s_sc[px(1)];
                for c in 0..3 {
                    let g = g_sc[px(3 + c)];
                    rec_out[rec::NORMAL + c] += w * g;
                    bracket += (p.normal[c] - s_sc[px(2 + c)]) * g;
                    s_sc[px(2 + c)] = a * p.normal[c] + one_m * s_sc[px(2 + c)];
                }
                // Median depth.
                if pos as u32 == medpos[idx] {
                    dz += g_sc[px(2)];
                }
                // Distortion.
                if has_dist {
                    let g_dist = g_sc[px(6)];
                    let (m, dm) = ndc_depth(h.z);
                    let a_f = R::ONE - buf[lay.t_final * TILE_PIXELS + idx];
                    let m1 = buf[lay.m1 * TILE_PIXELS + idx];
                    let m2 = buf[lay.m2 * TILE_PIXELS + idx];
                    let g_w = (m2 + m * m * a_f - two * m * m1) * g_dist;
                    bracket += g_w - s_sc[px(5)];
                    s_sc[px(5)] = a * g_w + one_m * s_sc[px(5)];
                    dz += two * w * (m * a_f - m1) * g_dist * dm;
                }
                let d_alpha = t_i * bracket - g_sc[px(7)] / one_m;
                tr[idx] = t_i;

                // α = min(0.99, o·G), G = exp(−ρ/2).
                let d_g = if h.clamped {
                    R::ZERO
                } else {
                    rec_out[rec::OPACITY] += h.g * d_alpha;
                    p.opacity * d_alpha
                };
                let d_rho = R::from_f64(-0.5) * h.g * d_g;
                let (gu, gv) = if h.object_space {
                    (two * h.u * d_rho + dz * p.t_w[0], two * h.v * d_rho + dz * p.t_w[1])
                } else {
                    rec_out[rec::CENTER] += filt2 * (p.center[0] - xr) * d_rho;
                    rec_out[rec::CENTER + 1] += filt2 * (p.center[1] - yr) * d_rho;
                    (dz * p.t_w[0], dz * p.t_w[1])
                };
                let inv = R::ONE / h.pz;
                let gp = [gu * inv, gv * inv, -(gu * h.u + gv * h.v) * inv];
                let gk = cross(h.l, gp);
                let gl = cross(gp, h.k);
                let uv1 = [h.u, h.v, R::ONE];
                for c in 0..3 {
                    rec_out[rec::T + c] -= gk[c];
                    rec_out[rec::T + 3 + c] -= gl[c];
                    rec_out[rec::T + 6 + c] += xr * gk[c] + yr * gl[c] + dz * uv1[c];
                }
            }
        }
        let _ = touched;
    }
}

/// Stage 5: sums the pair records of visible surfel `j` in its fixed pair order.
pub fn reduce_surfel<R: Real>(j: usize, bins: &Bins, pairs: &[R], k_obj: usize, dprobs: &mut [R]) -> ProjGrad<R> {
    let stride = rec::stride(k_obj);
    let mut g = ProjGrad::<R>::default();
    dprobs.fill(R::ZERO);
    for &pos in &bins.pair_pos[bins.pair_start[j] as usize..bins.pair_start[j + 1] as usize] {
        let r = &pairs[pos as usize * stride..(pos as usize + 1) * stride];
        for c in 0..9 {
            g.t[c] += r[rec::T + c];
        }
        for c in 0..2 {
            g.center[c] += r[rec::CENTER + c];
        }
        for c in 0..3 {
            g.rgb[c] += r[rec::RGB + c];
            g.mask[c] += r[rec::MASK + c];
            g.normal[c] += r[rec::NORMAL + c];
        }
        g.opacity += r[rec::OPACITY];
        for (d, &v) in dprobs.iter_mut().zip(&r[rec::OBJ..]) {
            *d += v;
        }
    }
    g
}
