//! Stage 4 and 5: per-tile backward rasterization and the per-surfel gradient reduction.
//!
//! Each tile walks its list back to front from the last surfel any of its pixels blended. Per pixel it
//! keeps the transmittance, recovered as `T_i = T_{i+1}/(1 − α_i)` from the saved `T_final`, and the
//! suffix sum `S = Σ_{k>i} v_k α_k Π_{i<j<k}(1 − α_j)` of `v_k = Σ_q q_k·g_q + z_k g_D + g_A + g_{w,k}`,
//! updated after use as `S ← α_i v_i + (1 − α_i) S`. Because a pixel's upstream gradients `g_q` are the
//! same for every surfel along its ray, this one scalar replaces the per-channel suffix sums `S_q` of
//! the CUDA reference (`Σ_q (q_i − S_q)·g_q = v_i − S`): the backward state is two numbers per pixel
//! whatever the number of object channels. Then (2DGS backward, `g_·` the upstream pixel gradients):
//!
//! * `∂L/∂q_i = α_i T_i g_q` for colours, mask colours, object probabilities and normals;
//! * `∂L/∂α_i = T_i (v_i − S) − T_final (bg·g_C + bg·g_M)/(1 − α_i)`,
//!   with the distortion weight gradient `g_{w,i} = (M₂ + m_i² A − 2 m_i M₁) g_dist`;
//! * `∂L/∂z_i = α_i T_i g_D + [i = median] g_med + 2 α_i T_i (m_i A − M₁) g_dist · ∂m/∂z`;
//! * `α = o·G` → `∂L/∂o = G ∂L/∂α`, `∂L/∂G = o ∂L/∂α` (zero when `o·G` hit the 0.99 clamp: the exact
//!   derivative, where the CUDA reference ignores the clamp), `G = e^{−ρ/2}`;
//! * object-space branch: `ρ = u² + v²`; filter branch: `ρ = 2|c − x|²`, whose gradient goes to the
//!   filter centre `c`. In both branches the depth `z = T_w·(u, v, 1)` depends on `T` through `(u, v)`:
//!   trand keeps that term (the reference drops it in the filter branch), so the gradient is exact.
//! * `(u, v) = (p_x, p_y)/p_z`, `p = k × l`, `k = x T_w − T_u`, `l = y T_w − T_v` → ∂L/∂T.
//!
//! Against a label map ([`crate::labels`]) the object term of `v_i` is `Σ_c π_c ∂L/∂P_c` (one constant
//! per surfel) plus `π_ℓ ∂L/∂I_ℓ` for the pixel's label `ℓ`, and `∂L/∂π_c = W ∂L/∂P_c + W_c ∂L/∂I_c`
//! from the pair's weight sums, so no per-channel plane is needed.
//!
//! Every (tile, surfel) pair writes one gradient record at its pair position; stage 5 sums each
//! surfel's records in the fixed order of [`crate::binning::Bins::pair_pos`]. No atomics, so results are
//! bit-identical for any number of threads.

use trand_core::Real;

use crate::binning::Bins;
use crate::camera::CamR;
use crate::constants::{FILTER_INV_SQUARE, TILE, TILE_PIXELS};
use crate::forward::{PADDED_PIXELS, PaddedPlane, RowGroups, group_columns, tile_pixels};
use crate::intersect::{Row, RowBasis, blended_lanes, ndc_depth_lanes};
use crate::intrinsics::{PREFETCH_AHEAD, prefetch, prefetch_slice};
use crate::labels::TileLabels;
use crate::lanes::{LANES, M, V, rsub, select};
use crate::layout::Layout;
use crate::preprocess::{Proj, ProjGrad};
use crate::vec3::cross;

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
    /// `(∂L/∂P, ∂L/∂I, β)` of the object sums, with the forward's labels; `β_j = Σ_c π_{j,c} ∂L/∂P_c`
    /// per visible surfel (computed once per surfel rather than once per pair).
    pub object_sums: Option<(&'a [R], &'a [R], &'a [R])>,
}

/// Backward pass of tile `t` (`rows`: the forward's per-entry row masks, see
/// [`crate::forward::raster_tile`]): writes one record per pair of the tile into `pairs`
/// (`(tile_start[t+1] − tile_start[t]) × stride` values, zero-initialised). Called through
/// [`crate::simd::backward_tile`], which compiles it for the CPU's widest lanes.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
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
    rows: &[u16],
    labels: Option<&[u8]>,
    grads: &GradMaps<'_, R>,
    pairs: &mut [R],
) {
    let (tx0, ty0, tx1, ty1) = tile_pixels(t, bins.tiles_x, cam.width, cam.height);
    let k_obj = lay.num_objects;
    let stride = rec::stride(k_obj);
    let (last, medpos_in) = ibuf.split_at(TILE_PIXELS);
    let max_last = last.iter().copied().max().unwrap_or(0) as usize;
    if max_last == 0 {
        return;
    }
    let plane = |ch: usize| -> &[R] { &buf[ch * TILE_PIXELS..(ch + 1) * TILE_PIXELS] };
    let w_img = cam.width as usize;
    let has_mask = lay.has_mask && grads.mask.is_some();
    let has_obj = lay.has_objects && grads.objects.is_some();
    let has_dist = grads.distortion.is_some();
    // Terms whose upstream gradient is absent are skipped (they would add exact zeros): a training step
    // without geometric losses needs neither the normal nor any depth term.
    let (has_nrm, has_depth, has_alpha, has_med) = (
        grads.normal.is_some(),
        grads.depth.is_some(),
        grads.alpha.is_some(),
        grads.median.is_some(),
    );
    let has_z = has_depth || has_med || has_dist;
    let z = R::ZERO;

    // Upstream gradients and the forward's per-pixel state, in padded channel planes (an eight-pixel
    // group may run up to seven pixels past the tile, see [`crate::forward::PADDED_PIXELS`]).
    let padded = |src: &[R]| -> PaddedPlane<R> {
        let mut p = [z; PADDED_PIXELS];
        p[..TILE_PIXELS].copy_from_slice(src);
        p
    };
    let mut g_rgb: [PaddedPlane<R>; 3] = [[z; PADDED_PIXELS]; 3];
    let mut g_msk: [PaddedPlane<R>; 3] = [[z; PADDED_PIXELS]; 3];
    let mut g_nrm: [PaddedPlane<R>; 3] = [[z; PADDED_PIXELS]; 3];
    let mut g_obj: Vec<PaddedPlane<R>> = if has_obj {
        vec![[z; PADDED_PIXELS]; k_obj]
    } else {
        Vec::new()
    };
    let (mut g_a, mut g_d, mut g_med, mut g_dist, mut g_bg) = (
        [z; PADDED_PIXELS],
        [z; PADDED_PIXELS],
        [z; PADDED_PIXELS],
        [z; PADDED_PIXELS],
        [z; PADDED_PIXELS],
    );
    let t_final = padded(plane(lay.t_final));
    let mut medpos = [u32::MAX; PADDED_PIXELS];
    if has_med {
        medpos[..TILE_PIXELS].copy_from_slice(medpos_in);
    }
    for y in ty0..=ty1 {
        for x in tx0..=tx1 {
            let idx = ((y - ty0) * TILE as i32 + (x - tx0)) as usize;
            let pix = y as usize * w_img + x as usize;
            let mut bg_term = z;
            if let Some(g) = grads.rgb {
                for c in 0..3 {
                    g_rgb[c][idx] = g[pix * 3 + c];
                    bg_term += background[c] * g[pix * 3 + c];
                }
            }
            if has_mask {
                let g = grads.mask.expect("checked");
                for c in 0..3 {
                    g_msk[c][idx] = g[pix * 3 + c];
                    bg_term += background[c] * g[pix * 3 + c];
                }
            }
            if has_obj {
                let g = grads.objects.expect("checked");
                for (c, pl) in g_obj.iter_mut().enumerate() {
                    pl[idx] = g[pix * k_obj + c];
                }
            }
            if let Some(g) = grads.normal {
                for c in 0..3 {
                    g_nrm[c][idx] = g[pix * 3 + c];
                }
            }
            let scalar = |m: Option<&[R]>| m.map_or(z, |g| g[pix]);
            g_a[idx] = scalar(grads.alpha);
            g_d[idx] = scalar(grads.depth);
            g_med[idx] = scalar(grads.median);
            g_dist[idx] = scalar(grads.distortion);
            g_bg[idx] = bg_term * t_final[idx];
        }
    }
    // The distortion moments exist only with the geometric planes (a distortion gradient needs them).
    let (m1f, m2f) = if lay.has_geometry() && has_dist {
        (padded(plane(lay.m1)), padded(plane(lay.m2)))
    } else {
        ([z; PADDED_PIXELS], [z; PADDED_PIXELS])
    };

    // Running state: transmittance and the combined suffix sum.
    let mut tr: PaddedPlane<R> = t_final;
    let mut suffix: PaddedPlane<R> = [z; PADDED_PIXELS];

    let list = bins.tile(t);
    let two = R::from_f64(2.0);
    let filt2 = R::from_f64(2.0 * FILTER_INV_SQUARE);
    let zv = V::splat(z);
    // Per-lane partial sums of the pair's record; summed over the lanes when the pair is done.
    let mut acc = [zv; rec::OBJ];
    let mut acc_obj = [zv; crate::MAX_OBJECTS];
    let xs = group_columns::<R>(tx0);
    // The tile origin, for the tile-local coordinates of the ∂L/∂T moments; `Σ dz·(u, v, 1)` per pair.
    let (ox, oy) = (R::from_f64(tx0 as f64), R::from_f64(ty0 as f64));
    let mut acc_dz = [zv; 3];

    // Object sums: per pair Σw, Σw per label, and the pair's constants β = Σ_c π_c ∂L/∂P_c and
    // π_ℓ ∂L/∂I_ℓ per label present.
    let sum_grads = grads.object_sums.filter(|_| lay.sums.is_some());
    let tl = match (sum_grads, labels) {
        (Some(_), Some(l)) => Some(TileLabels::gather(l, w_img, (tx0, ty0, tx1, ty1))),
        _ => None,
    };
    let n_lab = tl.as_ref().map_or(0, |t| t.labels.len());
    let (mut acc_w, mut acc_l) = (zv, [zv; crate::MAX_OBJECTS]);
    let (mut beta, mut coef) = (z, [z; crate::MAX_OBJECTS]);

    for pos in (0..max_last).rev() {
        if pos >= PREFETCH_AHEAD {
            let ahead = list[pos - PREFETCH_AHEAD] as usize;
            prefetch(&projs[ahead]);
            prefetch_slice(&probs[ahead * k_obj..(ahead + 1) * k_obj]);
        }
        let j = list[pos] as usize;
        let p = &projs[j];
        let pr = &probs[j * k_obj..(j + 1) * k_obj];
        let (y0, y1) = (p.bbox[1].max(ty0) - ty0, p.bbox[3].min(ty1) - ty0);
        let pos_v = pos as u32;
        let basis = RowBasis::new(p);
        let mut touched = false;
        let row_bits = &rows[pos * TILE as usize..(pos + 1) * TILE as usize];
        for ly in y0..=y1 {
            // The pixels of this row the forward blended this surfel on.
            let bits = row_bits[ly as usize];
            if bits == 0 {
                continue;
            }
            let yr = R::from_f64((ty0 + ly) as f64);
            let row = Row::at(&basis, yr);
            for (c0, hb) in RowGroups::new(bits) {
                let xr = xs[c0];
                let base = ly as usize * TILE as usize + c0;
                let px = base..base + LANES;
                let h = blended_lanes(p, &row, xr, M::from_bits(hb));
                if !touched {
                    acc = [zv; rec::OBJ];
                    acc_dz = [zv; 3];
                    acc_obj[..k_obj].fill(zv);
                    if let (Some((_, gi, betas)), Some(tl)) = (sum_grads, &tl) {
                        (acc_w, beta) = (zv, betas[j]);
                        acc_l[..n_lab].fill(zv);
                        for (c, &l) in coef.iter_mut().zip(&tl.labels) {
                            *c = pr[l as usize] * gi[l as usize];
                        }
                    }
                    touched = true;
                }
                let a = h.alpha;
                let one_m = rsub(R::ONE, a);
                let tr_v = V::load(&tr[px.clone()]);
                let inv_one_m = V::splat(R::ONE) / one_m;
                let t_i = tr_v * inv_one_m;
                let w = a * t_i;

                // v_i = Σ_q q_i·g_q + z_i g_D + g_A (+ g_w): blended quantities and their ∂/∂q_i.
                let g_dv = V::load(&g_d[px.clone()]);
                let mut v = if has_depth { h.z * g_dv } else { zv };
                if has_alpha {
                    v += V::load(&g_a[px.clone()]);
                }
                for c in 0..3 {
                    let g = V::load(&g_rgb[c][px.clone()]);
                    acc[rec::RGB + c] += w * g;
                    v += g * p.rgb[c];
                }
                if has_nrm {
                    for c in 0..3 {
                        let g = V::load(&g_nrm[c][px.clone()]);
                        acc[rec::NORMAL + c] += w * g;
                        v += g * p.normal[c];
                    }
                }
                if has_mask {
                    for c in 0..3 {
                        let g = V::load(&g_msk[c][px.clone()]);
                        acc[rec::MASK + c] += w * g;
                        v += g * p.mask[c];
                    }
                }
                if has_obj {
                    for ((ao, &pc), gp) in acc_obj.iter_mut().zip(pr).zip(&g_obj) {
                        let g = V::load(&gp[px.clone()]);
                        *ao += w * g;
                        v += g * pc;
                    }
                }
                if let Some(tl) = &tl {
                    let mut vo = V::splat(beta);
                    for ((a, rows), &c) in acc_l[..n_lab].iter_mut().zip(&tl.rows).zip(&coef) {
                        let on = M::from_bits((rows[ly as usize] >> c0) as u8);
                        vo += select(on, V::splat(c), zv);
                        *a += select(on, w, zv);
                    }
                    v += vo;
                    acc_w += w;
                }
                let mut dz = if has_depth { w * g_dv } else { zv };
                if has_med {
                    let at_median = M::from_fn(|l| medpos[base + l] == pos_v);
                    dz += select(at_median & h.valid, V::load(&g_med[px.clone()]), zv);
                }
                if has_dist {
                    let (m, dm) = ndc_depth_lanes(h.z);
                    let a_f = rsub(R::ONE, V::load(&t_final[px.clone()]));
                    let (m1v, g_distv) = (V::load(&m1f[px.clone()]), V::load(&g_dist[px.clone()]));
                    let g_w = (V::load(&m2f[px.clone()]) + m * m * a_f - m * two * m1v) * g_distv;
                    v += g_w;
                    dz += w * two * (m * a_f - m1v) * g_distv * dm;
                }
                let s_v = V::load(&suffix[px.clone()]);
                let bracket = v - s_v;
                select(h.valid, a * v + one_m * s_v, s_v).store(&mut suffix[px.clone()]);
                let d_alpha = select(
                    h.valid,
                    t_i * bracket - V::load(&g_bg[px.clone()]) * inv_one_m,
                    zv,
                );
                select(h.valid, t_i, tr_v).store(&mut tr[px.clone()]);

                // α = min(0.99, o·G), G = exp(−ρ/2).
                acc[rec::OPACITY] += select(h.clamped, zv, h.g * d_alpha);
                let d_g = select(h.clamped, zv, d_alpha * p.opacity);
                let d_rho = h.g * d_g * R::from_f64(-0.5);
                let (gu, gv) = if has_z {
                    let (dzu, dzv) = (dz * p.t_w[0], dz * p.t_w[1]);
                    (
                        select(h.object_space, h.u * two * d_rho + dzu, dzu),
                        select(h.object_space, h.v * two * d_rho + dzv, dzv),
                    )
                } else {
                    (
                        select(h.object_space, h.u * two * d_rho, zv),
                        select(h.object_space, h.v * two * d_rho, zv),
                    )
                };
                let filter = h.valid & !h.object_space;
                acc[rec::CENTER] += select(filter, rsub(p.center[0], xr) * filt2 * d_rho, zv);
                acc[rec::CENTER + 1] += select(filter, d_rho * (filt2 * (p.center[1] - yr)), zv);
                // ∂L/∂p = (gu, gv, −(gu u + gv v))/p_z. Its contributions to ∂L/∂T are cross products
                // with k = x T_w − T_u and l = y T_w − T_v, both linear in the pixel: only the moments
                // Σ gp, Σ x gp, Σ y gp (tile-local x, y) are accumulated per pixel, and the cross
                // products are taken once per pair ([`t_from_moments`]).
                let inv = h.inv_pz;
                let gp = [gu * inv, gv * inv, rsub(R::ZERO, gu * h.u + gv * h.v) * inv];
                let (xl, yl) = (xr - ox, yr - oy);
                let uv1 = [h.u, h.v, V::splat(R::ONE)];
                for c in 0..3 {
                    acc[rec::T + c] += gp[c];
                    acc[rec::T + 3 + c] += gp[c] * xl;
                    acc[rec::T + 6 + c] += gp[c] * yl;
                    if has_z {
                        acc_dz[c] += dz * uv1[c];
                    }
                }
            }
        }
        if touched {
            let out = &mut pairs[pos * stride..(pos + 1) * stride];
            for (o, a) in out[..rec::OBJ].iter_mut().zip(&acc) {
                *o = a.sum();
            }
            let dz = if has_z {
                acc_dz.map(|a| a.sum())
            } else {
                [z; 3]
            };
            let t = t_from_moments(p, tx0, ty0, &out[rec::T..rec::T + 9], dz);
            out[rec::T..rec::T + 9].copy_from_slice(&t);
            if has_obj {
                for (o, a) in out[rec::OBJ..].iter_mut().zip(&acc_obj[..k_obj]) {
                    *o = a.sum();
                }
            }
            if let (Some((gp, gi, _)), Some(tl)) = (sum_grads, &tl) {
                let w_sum = acc_w.sum();
                for (o, &g) in out[rec::OBJ..].iter_mut().zip(gp) {
                    *o = g * w_sum;
                }
                for (&l, a) in tl.labels.iter().zip(&acc_l) {
                    out[rec::OBJ + l as usize] += gi[l as usize] * a.sum();
                }
            }
        }
    }
}

/// `∂L/∂T` of one pair from its moments `m = (Σ gp, Σ x gp, Σ y gp)` (tile-local `x`, `y`) and
/// `dz = (Σ dz·u, Σ dz·v, Σ dz)`. With `T_u' = T_u − x₀ T_w`, `T_v' = T_v − y₀ T_w` (tile origin
/// `(x₀, y₀)`), `k = x T_w − T_u'` and `l = y T_w − T_v'` in tile-local coordinates; per pixel
/// `∂L/∂T_u = −l × gp`, `∂L/∂T_v = −gp × k`, `∂L/∂T_w = x (l × gp) + y (gp × k) + dz (u, v, 1)` (image
/// `x`, `y`). Summed over the pixels by bilinearity: `Σ l × gp = T_w × Σy gp − T_v' × Σ gp`,
/// `Σ gp × k = Σx gp × T_w − Σ gp × T_u'`, and in local coordinates
/// `Σ x (l × gp) + Σ y (gp × k) = −T_v' × Σx gp − Σy gp × T_u'` (the `xy T_w` terms cancel); the tile
/// origin adds `x₀ Σ l × gp + y₀ Σ gp × k`. Per pixel that is nine multiply-adds instead of two cross
/// products and their weighting (42 lane operations → 15).
#[inline(always)]
fn t_from_moments<R: Real>(p: &Proj<R>, tx0: i32, ty0: i32, m: &[R], dz: [R; 3]) -> [R; 9] {
    let (x0, y0) = (R::from_f64(tx0 as f64), R::from_f64(ty0 as f64));
    let tw = p.t_w;
    let tu: [R; 3] = std::array::from_fn(|c| p.t_u[c] - x0 * tw[c]);
    let tv: [R; 3] = std::array::from_fn(|c| p.t_v[c] - y0 * tw[c]);
    let (s, sx, sy) = ([m[0], m[1], m[2]], [m[3], m[4], m[5]], [m[6], m[7], m[8]]);
    let (a, b) = (cross(&tw, &sy), cross(&tv, &s));
    let l_gp: [R; 3] = std::array::from_fn(|c| a[c] - b[c]);
    let (a, b) = (cross(&sx, &tw), cross(&s, &tu));
    let gp_k: [R; 3] = std::array::from_fn(|c| a[c] - b[c]);
    let (a, b) = (cross(&tv, &sx), cross(&sy, &tu));
    let mut out = [R::ZERO; 9];
    for c in 0..3 {
        out[c] = R::ZERO - l_gp[c];
        out[3 + c] = R::ZERO - gp_k[c];
        out[6 + c] = x0 * l_gp[c] + y0 * gp_k[c] - a[c] - b[c] + dz[c];
    }
    out
}

/// Stage 5: sums the pair records of visible surfel `j` in its fixed pair order.
pub fn reduce_surfel<R: Real>(
    j: usize,
    bins: &Bins,
    pairs: &[R],
    k_obj: usize,
    dprobs: &mut [R],
) -> ProjGrad<R> {
    let stride = rec::stride(k_obj);
    let mut g = ProjGrad::<R>::default();
    dprobs.fill(R::ZERO);
    // The records lie in tile order, scattered for one surfel (three on average): fetch those of the
    // surfel two ahead, which the caller reduces next but one.
    if j + 3 < bins.pair_start.len() {
        let ahead =
            &bins.pair_pos[bins.pair_start[j + 2] as usize..bins.pair_start[j + 3] as usize];
        for &pos in ahead {
            prefetch_slice(&pairs[pos as usize * stride..(pos as usize + 1) * stride]);
        }
    }
    let list = &bins.pair_pos[bins.pair_start[j] as usize..bins.pair_start[j + 1] as usize];
    for &pos in list {
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
