//! Stage 3: per-tile forward rasterization (front-to-back alpha blending, 2DGS §4 and the auxiliary
//! maps of the reference rasterizer).
//!
//! Surfel-outer, pixel-inner: each surfel of the tile's depth-sorted list visits only the pixels of its
//! evaluation box (see [`crate::preprocess`]), and on each row only the columns where its alpha can
//! reach 1/255 ([`crate::intersect::tile_row_columns`]). A 16-bit mask per tile row marks the pixels still
//! blending, so saturated pixels cost nothing and the tile stops once every mask is empty. A row is
//! processed in groups of eight pixels ([`crate::lanes`]), each starting at the row's lowest pixel not
//! yet covered ([`RowGroups`]): one vector instruction per operation for eight pixels, with masks where
//! the scalar code branched. The accumulators live in fixed arrays on the stack (channel-planar, index
//! `ly·16 + lx`, padded by eight for a group starting late in the last row).
//! Per pixel, with `T` the transmittance in front of surfel `i` and `w_i = α_i T`:
//!
//! | output | value |
//! |---|---|
//! | colour, mask colour | `Σ w_i c_i + T_final · bg` |
//! | object map (K ch.) | `Σ w_i p_i` (no background term), or its two sums per channel against a label map ([`crate::labels`]) |
//! | alpha | `1 − T_final` |
//! | depth (unnormalised) | `D = Σ w_i z_i` |
//! | median depth | `z_i` of the last blended `i` with `T > ½` (0 if none) |
//! | normal (camera) | `Σ w_i n_i` |
//! | distortion | `Σ_i Σ_{j<i} w_i w_j (m_i − m_j)²`, `m` the NDC depth, accumulated as `w_i(m_i² A + M₂ − 2 m_i M₁)` |
//!
//! A pixel stops *before* the surfel that would take `T` below 1e-4 (that surfel is not blended).

use trand_core::Real;

use crate::binning::Bins;
use crate::camera::CamR;
use crate::constants::{MEDIAN_TRANSMITTANCE, MIN_TRANSMITTANCE, TILE, TILE_PIXELS};
use crate::intersect::{Row, RowBasis, intersect_lanes, ndc_depth_lanes, tile_row_columns};
use crate::intrinsics::{PREFETCH_AHEAD, prefetch, prefetch_slice};
use crate::labels::TileLabels;
use crate::lanes::{LANES, M, V, rsub, select};
use crate::layout::Layout;
use crate::preprocess::Proj;

/// A tile's channel plane with [`LANES`] values of padding: an eight-pixel group may start at any column, so one
/// starting late in the last row reads and writes up to seven pixels past the tile (masked lanes, whose
/// values are stored back unchanged).
pub const PADDED_PIXELS: usize = TILE_PIXELS + LANES;

/// One channel plane of a tile (index `ly·16 + lx`), padded ([`PADDED_PIXELS`]).
pub type PaddedPlane<R> = [R; PADDED_PIXELS];

/// Pixel range of tile `t` clipped to the image: `(x0, y0, x1, y1)` inclusive.
#[inline]
pub fn tile_pixels(t: usize, tiles_x: u32, width: u32, height: u32) -> (i32, i32, i32, i32) {
    let tx = (t as u32 % tiles_x) * TILE;
    let ty = (t as u32 / tiles_x) * TILE;
    (
        tx as i32,
        ty as i32,
        ((tx + TILE).min(width) - 1) as i32,
        ((ty + TILE).min(height) - 1) as i32,
    )
}

/// Bit mask of local columns `x0..=x1` (relative to the tile).
#[inline(always)]
pub fn span_mask(x0: i32, x1: i32) -> u16 {
    let n = (x1 - x0 + 1) as u32;
    (((1u32 << n) - 1) << x0) as u16
}

/// Image columns of the eight-pixel group starting at each local column `c` of the tile starting at
/// image column `tx0`: `tx0 + c + l` in lane `l`.
#[inline(always)]
pub fn group_columns<R: Real>(tx0: i32) -> [V<R>; TILE as usize] {
    std::array::from_fn(|c| {
        V(std::array::from_fn(|l| {
            R::from_f64((tx0 + (c + l) as i32) as f64)
        }))
    })
}

/// The eight-pixel groups that cover the pixels of a row mask: each starts at the lowest pixel not yet
/// covered and takes the eight columns from there. Yields `(start column, lane bits)`.
///
/// Groups at fixed halves of the row (columns 0–7 and 8–15) took two groups for any span crossing the
/// middle; starting at the first pixel needs `⌈span/8⌉`, 10 % fewer groups on a trained scene (1.44 M
/// → 1.30 M per training step of seq_105 at 320×240), each of which costs the same vector work
/// whatever its number of live lanes.
#[derive(Clone, Copy)]
pub struct RowGroups(u32);

impl RowGroups {
    #[inline(always)]
    pub fn new(bits: u16) -> Self {
        Self(u32::from(bits))
    }
}

impl Iterator for RowGroups {
    type Item = (usize, u8);
    #[inline(always)]
    fn next(&mut self) -> Option<(usize, u8)> {
        if self.0 == 0 {
            return None;
        }
        let c0 = self.0.trailing_zeros();
        let lanes = (self.0 >> c0) as u8;
        self.0 &= !(0xff << c0);
        Some((c0 as usize, lanes))
    }
}

/// The rows' masks of pixels inside the image.
pub fn inside_masks(tx0: i32, ty0: i32, tx1: i32, ty1: i32) -> [u16; TILE as usize] {
    let mut m = [0u16; TILE as usize];
    for y in ty0..=ty1 {
        m[(y - ty0) as usize] = span_mask(0, tx1 - tx0);
    }
    m
}

/// Rasterizes tile `t` into its float block `buf` (zero-initialised) and integer block `ibuf`;
/// `labels` (row-major, one channel index per pixel) when the layout has object sums. `rows` (16 per
/// list entry, zero-initialised) receives, for each surfel and tile row, the pixels it blended: exactly
/// the pixels the backward pass visits for it, which reads them instead of solving the row cut and the
/// alpha gates again.
/// Called through [`crate::simd::raster_tile`], which compiles it for the CPU's widest lanes.
#[allow(clippy::too_many_arguments, clippy::needless_range_loop)] // c indexes planes and colour alike
#[inline(always)]
pub fn raster_tile<R: Real>(
    t: usize,
    bins: &Bins,
    projs: &[Proj<R>],
    probs: &[R],
    lay: &Layout,
    cam: &CamR<R>,
    background: [R; 3],
    labels: Option<&[u8]>,
    buf: &mut [R],
    ibuf: &mut [u32],
    rows: &mut [u16],
) {
    let geometry = lay.has_geometry();
    let (tx0, ty0, tx1, ty1) = tile_pixels(t, bins.tiles_x, cam.width, cam.height);
    let k_obj = lay.num_objects;
    let (has_mask, has_obj) = (lay.has_mask, lay.has_objects);
    let z = R::ZERO;
    let mut tr: PaddedPlane<R> = [R::ONE; PADDED_PIXELS];
    let mut rgb: [PaddedPlane<R>; 3] = [[z; PADDED_PIXELS]; 3];
    let mut msk: [PaddedPlane<R>; 3] = [[z; PADDED_PIXELS]; 3];
    let mut nrm: [PaddedPlane<R>; 3] = [[z; PADDED_PIXELS]; 3];
    let mut dep: PaddedPlane<R> = [z; PADDED_PIXELS];
    let mut med: PaddedPlane<R> = [z; PADDED_PIXELS];
    let mut dist: PaddedPlane<R> = [z; PADDED_PIXELS];
    let mut m1: PaddedPlane<R> = [z; PADDED_PIXELS];
    let mut m2: PaddedPlane<R> = [z; PADDED_PIXELS];
    let mut obj: Vec<PaddedPlane<R>> = if has_obj {
        vec![[z; PADDED_PIXELS]; k_obj]
    } else {
        Vec::new()
    };
    let mut last = [0u32; PADDED_PIXELS];
    let mut medpos = [u32::MAX; PADDED_PIXELS];

    let mut active = inside_masks(tx0, ty0, tx1, ty1);
    let half_t = R::from_f64(MEDIAN_TRANSMITTANCE);
    let min_t = R::from_f64(MIN_TRANSMITTANCE);
    let two = R::from_f64(2.0);

    let xs = group_columns::<R>(tx0);

    // Object sums against labels: per pair Σw and Σw per label present, folded into `sums` (P, I).
    let tl = match (lay.sums, labels) {
        (Some(_), Some(l)) => Some(TileLabels::gather(
            l,
            cam.width as usize,
            (tx0, ty0, tx1, ty1),
        )),
        _ => None,
    };
    let n_lab = tl.as_ref().map_or(0, |t| t.labels.len());
    let mut sums = [z; 2 * crate::MAX_OBJECTS];
    let (mut acc_w, mut acc_l) = (V::splat(z), [V::splat(z); crate::MAX_OBJECTS]);

    let list = bins.tile(t);
    for (pos, &j) in list.iter().enumerate() {
        if let Some(&ahead) = list.get(pos + PREFETCH_AHEAD) {
            prefetch(&projs[ahead as usize]);
            prefetch_slice(&probs[ahead as usize * k_obj..(ahead as usize + 1) * k_obj]);
        }
        let p = &projs[j as usize];
        let (x0, y0) = (p.bbox[0].max(tx0) - tx0, p.bbox[1].max(ty0) - ty0);
        let (x1, y1) = (p.bbox[2].min(tx1) - tx0, p.bbox[3].min(ty1) - ty0);
        let span = span_mask(x0, x1);
        let pr = &probs[j as usize * k_obj..(j as usize + 1) * k_obj];
        let pos_v = pos as u32;
        let basis = RowBasis::new(p);
        let (cut_lo, cut_hi) = tile_row_columns(p, ty0);
        let mut touched = false;
        for ly in y0..=y1 {
            let bits = active[ly as usize] & span;
            if bits == 0 {
                continue;
            }
            // The row's columns where α ≥ 1/255 is possible, within the box.
            let c0 = cut_lo[ly as usize].max(tx0 + x0) - tx0;
            let c1 = cut_hi[ly as usize].min(tx0 + x1) - tx0;
            if c0 > c1 {
                continue;
            }
            let bits = bits & span_mask(c0, c1);
            if bits == 0 {
                continue;
            }
            let yr = R::from_f64((ty0 + ly) as f64);
            let row = Row::at(&basis, yr);
            let mut blended = 0u16;
            for (c0, hb) in RowGroups::new(bits) {
                let xh = xs[c0];
                let base = ly as usize * TILE as usize + c0;
                let px = base..base + LANES;
                let h = intersect_lanes(p, &row, xh, cam.near, M::from_bits(hb));
                if !h.valid.any() {
                    continue;
                }
                if !touched && n_lab > 0 {
                    acc_w = V::splat(z);
                    acc_l[..n_lab].fill(V::splat(z));
                }
                touched = true;
                let t_before = V::load(&tr[px.clone()]);
                let t_after = t_before * rsub(R::ONE, h.alpha);
                // Stop before the surfel that would take T below 1e-4 (it is not blended).
                let stop = h.valid & t_after.lt(V::splat(min_t));
                active[ly as usize] &= !((u32::from(stop.bits()) << c0) as u16);
                let blend = h.valid & !stop;
                blended |= (u32::from(blend.bits()) << c0) as u16;
                let w = select(blend, h.alpha * t_before, V::splat(z));
                for c in 0..3 {
                    (w * p.rgb[c]).add_to(&mut rgb[c][px.clone()]);
                }
                if has_mask {
                    for c in 0..3 {
                        (w * p.mask[c]).add_to(&mut msk[c][px.clone()]);
                    }
                }
                if has_obj {
                    for (plane, &pc) in obj.iter_mut().zip(pr) {
                        (w * pc).add_to(&mut plane[px.clone()]);
                    }
                }
                if let Some(tl) = &tl {
                    acc_w += w;
                    for (a, rows) in acc_l[..n_lab].iter_mut().zip(&tl.rows) {
                        let on = M::from_bits((rows[ly as usize] >> c0) as u8);
                        *a += select(on, w, V::splat(z));
                    }
                }
                if geometry {
                    for c in 0..3 {
                        (w * p.normal[c]).add_to(&mut nrm[c][px.clone()]);
                    }
                    (w * h.z).add_to(&mut dep[px.clone()]);
                    let at_median = blend & t_before.gt(V::splat(half_t));
                    select(at_median, h.z, V::load(&med[px.clone()])).store(&mut med[px.clone()]);
                    let (m, _) = ndc_depth_lanes(h.z);
                    let (m1v, m2v) = (V::load(&m1[px.clone()]), V::load(&m2[px.clone()]));
                    let a = rsub(R::ONE, t_before);
                    (w * (m * m * a + m2v - m * two * m1v)).add_to(&mut dist[px.clone()]);
                    (m1v + w * m).store(&mut m1[px.clone()]);
                    (m2v + w * m * m).store(&mut m2[px.clone()]);
                    for l in 0..LANES {
                        if at_median.lane(l) {
                            medpos[base + l] = pos_v;
                        }
                    }
                }
                select(blend, t_after, t_before).store(&mut tr[px.clone()]);
                // last = pos + 1 where blended: list positions only grow, so a branch-free max.
                for l in 0..LANES {
                    let hit = u32::from(blend.lane(l));
                    last[base + l] = last[base + l].max((pos_v + 1) * hit);
                }
            }
            rows[pos * TILE as usize + ly as usize] = blended;
        }
        if let (true, Some(tl)) = (touched, &tl) {
            let w_sum = acc_w.sum();
            for (s, &pc) in sums[..k_obj].iter_mut().zip(pr) {
                *s += pc * w_sum;
            }
            for (&l, a) in tl.labels.iter().zip(&acc_l) {
                sums[k_obj + l as usize] += pr[l as usize] * a.sum();
            }
        }
        if active.iter().all(|&m| m == 0) {
            break;
        }
    }

    let mut put = |ch: usize, plane: &PaddedPlane<R>| {
        buf[ch * TILE_PIXELS..(ch + 1) * TILE_PIXELS].copy_from_slice(&plane[..TILE_PIXELS])
    };
    for c in 0..3 {
        for idx in 0..TILE_PIXELS {
            rgb[c][idx] += tr[idx] * background[c];
            msk[c][idx] += tr[idx] * background[c];
        }
        put(lay.rgb + c, &rgb[c]);
        if geometry {
            put(lay.normal + c, &nrm[c]);
        }
        if has_mask {
            put(lay.mask + c, &msk[c]);
        }
    }
    for (c, plane) in obj.iter().enumerate() {
        put(lay.obj + c, plane);
    }
    let alpha: PaddedPlane<R> = std::array::from_fn(|i| R::ONE - tr[i]);
    put(lay.alpha, &alpha);
    put(lay.t_final, &tr);
    if geometry {
        put(lay.depth, &dep);
        put(lay.median, &med);
        put(lay.dist, &dist);
        put(lay.m1, &m1);
        put(lay.m2, &m2);
    }
    let (last_out, medpos_out) = ibuf.split_at_mut(TILE_PIXELS);
    last_out.copy_from_slice(&last[..TILE_PIXELS]);
    medpos_out[..TILE_PIXELS].copy_from_slice(&medpos[..TILE_PIXELS]);
    if let Some(sp) = lay.sums {
        buf[sp * TILE_PIXELS..sp * TILE_PIXELS + 2 * k_obj].copy_from_slice(&sums[..2 * k_obj]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn row_groups_cover_every_pixel_once_and_never_take_more_groups_than_halves() {
        for bits in 0..=u16::MAX {
            let mut covered = 0u32;
            let mut groups = 0;
            let mut next_free = 0;
            for (c0, lanes) in RowGroups::new(bits) {
                assert!(c0 >= next_free, "mask {bits:#06x}: groups overlap");
                assert_eq!(lanes & 1, 1, "mask {bits:#06x}: a group starts on a pixel");
                covered |= u32::from(lanes) << c0;
                next_free = c0 + LANES;
                groups += 1;
            }
            assert_eq!(covered, u32::from(bits), "mask {bits:#06x}");
            // Never more groups than the fixed halves (columns 0–7, 8–15) took, and at most
            // ⌈span/8⌉: each group starts eight or more columns after the previous one.
            let halves = usize::from(bits & 0xff != 0) + usize::from(bits >> 8 != 0);
            assert!(groups <= halves, "mask {bits:#06x}");
            if bits != 0 {
                let span = 16 - bits.leading_zeros() - bits.trailing_zeros();
                assert!(
                    groups <= span.div_ceil(LANES as u32) as usize,
                    "mask {bits:#06x}"
                );
            }
        }
    }
}
