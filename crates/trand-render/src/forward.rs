//! Stage 3: per-tile forward rasterization (front-to-back alpha blending, 2DGS §4 and the auxiliary
//! maps of the reference rasterizer).
//!
//! Surfel-outer, pixel-inner: each surfel of the tile's depth-sorted list visits only the pixels of its
//! evaluation box (see [`crate::preprocess`]). A 16-bit mask per tile row marks the pixels still
//! blending, so saturated pixels cost nothing and the tile stops once every mask is empty. The
//! accumulators live in fixed `[R; 256]` arrays on the stack (channel-planar, index `ly·16 + lx`).
//! Per pixel, with `T` the transmittance in front of surfel `i` and `w_i = α_i T`:
//!
//! | output | value |
//! |---|---|
//! | colour, mask colour | `Σ w_i c_i + T_final · bg` |
//! | object map (K ch.) | `Σ w_i p_i` (no background term) |
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
use crate::intersect::{intersect, ndc_depth, Row};
use crate::layout::Layout;
use crate::preprocess::Proj;

/// One channel plane of a tile.
pub type Plane<R> = [R; TILE_PIXELS];

/// Pixel range of tile `t` clipped to the image: `(x0, y0, x1, y1)` inclusive.
#[inline]
pub fn tile_pixels(t: usize, tiles_x: u32, width: u32, height: u32) -> (i32, i32, i32, i32) {
    let tx = (t as u32 % tiles_x) * TILE;
    let ty = (t as u32 / tiles_x) * TILE;
    (tx as i32, ty as i32, ((tx + TILE).min(width) - 1) as i32, ((ty + TILE).min(height) - 1) as i32)
}

/// Bit mask of local columns `x0..=x1` (relative to the tile).
#[inline(always)]
pub fn span_mask(x0: i32, x1: i32) -> u16 {
    let n = (x1 - x0 + 1) as u32;
    (((1u32 << n) - 1) << x0) as u16
}

/// The rows' masks of pixels inside the image.
pub fn inside_masks(tx0: i32, ty0: i32, tx1: i32, ty1: i32) -> [u16; TILE as usize] {
    let mut m = [0u16; TILE as usize];
    for y in ty0..=ty1 {
        m[(y - ty0) as usize] = span_mask(0, tx1 - tx0);
    }
    m
}

/// Rasterizes tile `t` into its float block `buf` (zero-initialised) and integer block `ibuf`.
#[allow(clippy::too_many_arguments)]
pub fn raster_tile<R: Real>(
    t: usize,
    bins: &Bins,
    projs: &[Proj<R>],
    probs: &[R],
    lay: &Layout,
    cam: &CamR<R>,
    background: [R; 3],
    buf: &mut [R],
    ibuf: &mut [u32],
) {
    let (tx0, ty0, tx1, ty1) = tile_pixels(t, bins.tiles_x, cam.width, cam.height);
    let k_obj = lay.num_objects;
    let (has_mask, has_obj) = (lay.has_mask, lay.has_objects);
    let z = R::ZERO;
    let mut tr: Plane<R> = [R::ONE; TILE_PIXELS];
    let mut rgb: [Plane<R>; 3] = [[z; TILE_PIXELS]; 3];
    let mut msk: [Plane<R>; 3] = [[z; TILE_PIXELS]; 3];
    let mut nrm: [Plane<R>; 3] = [[z; TILE_PIXELS]; 3];
    let mut dep: Plane<R> = [z; TILE_PIXELS];
    let mut med: Plane<R> = [z; TILE_PIXELS];
    let mut dist: Plane<R> = [z; TILE_PIXELS];
    let mut m1: Plane<R> = [z; TILE_PIXELS];
    let mut m2: Plane<R> = [z; TILE_PIXELS];
    let mut obj: Vec<Plane<R>> = if has_obj { vec![[z; TILE_PIXELS]; k_obj] } else { Vec::new() };
    let (last, medpos) = ibuf.split_at_mut(TILE_PIXELS);
    let last: &mut [u32; TILE_PIXELS] = last.try_into().expect("256 pixels");
    let medpos: &mut [u32; TILE_PIXELS] = medpos.try_into().expect("256 pixels");
    medpos.fill(u32::MAX);

    let mut active = inside_masks(tx0, ty0, tx1, ty1);
    let half = R::from_f64(MEDIAN_TRANSMITTANCE);
    let min_t = R::from_f64(MIN_TRANSMITTANCE);
    let two = R::from_f64(2.0);

    for (pos, &j) in bins.tile(t).iter().enumerate() {
        let p = &projs[j as usize];
        let (x0, y0) = (p.bbox[0].max(tx0) - tx0, p.bbox[1].max(ty0) - ty0);
        let (x1, y1) = (p.bbox[2].min(tx1) - tx0, p.bbox[3].min(ty1) - ty0);
        let span = span_mask(x0, x1);
        let pr = &probs[j as usize * k_obj..(j as usize + 1) * k_obj];
        for ly in y0..=y1 {
            let mut bits = active[ly as usize] & span;
            if bits == 0 {
                continue;
            }
            let row = Row::new(p, R::from_f64((ty0 + ly) as f64));
            while bits != 0 {
                let lx = bits.trailing_zeros() as i32;
                bits &= bits - 1;
                let idx = ((ly * TILE as i32 + lx) as usize) & (TILE_PIXELS - 1);
                let Some(h) = intersect(p, &row, R::from_f64((tx0 + lx) as f64), cam.near) else { continue };
                let t_before = tr[idx];
                let t_after = t_before * (R::ONE - h.alpha);
                if t_after < min_t {
                    active[ly as usize] &= !(1u16 << lx);
                    continue;
                }
                let w = h.alpha * t_before;
                for c in 0..3 {
                    rgb[c][idx] += w * p.rgb[c];
                    nrm[c][idx] += w * p.normal[c];
                }
                if has_mask {
                    for c in 0..3 {
                        msk[c][idx] += w * p.mask[c];
                    }
                }
                if has_obj {
                    for (plane, &pc) in obj.iter_mut().zip(pr) {
                        plane[idx] += w * pc;
                    }
                }
                dep[idx] += w * h.z;
                if t_before > half {
                    med[idx] = h.z;
                    medpos[idx] = pos as u32;
                }
                let (m, _) = ndc_depth(h.z);
                let a = R::ONE - t_before;
                dist[idx] += w * (m * m * a + m2[idx] - two * m * m1[idx]);
                m1[idx] += w * m;
                m2[idx] += w * m * m;
                tr[idx] = t_after;
                last[idx] = pos as u32 + 1;
            }
        }
        if active.iter().all(|&m| m == 0) {
            break;
        }
    }

    let mut put = |ch: usize, plane: &Plane<R>| buf[ch * TILE_PIXELS..(ch + 1) * TILE_PIXELS].copy_from_slice(plane);
    for c in 0..3 {
        for idx in 0..TILE_PIXELS {
            rgb[c][idx] += tr[idx] * background[c];
            msk[c][idx] += tr[idx] * background[c];
        }
        put(lay.rgb + c, &rgb[c]);
        put(lay.normal + c, &nrm[c]);
        if has_mask {
            put(lay.mask + c, &msk[c]);
        }
    }
    for (c, plane) in obj.iter().enumerate() {
        put(lay.obj + c, plane);
    }
    let alpha: Plane<R> = std::array::from_fn(|i| R::ONE - tr[i]);
    put(lay.alpha, &alpha);
    put(lay.depth, &dep);
    put(lay.median, &med);
    put(lay.dist, &dist);
    put(lay.t_final, &tr);
    put(lay.m1, &m1);
    put(lay.m2, &m2);
}
