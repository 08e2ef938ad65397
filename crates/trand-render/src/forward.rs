//! Stage 3: per-tile forward rasterization (front-to-back alpha blending, 2DGS §4 and the auxiliary
//! maps of the reference rasterizer).
//!
//! Surfel-outer, pixel-inner: each surfel of the tile's depth-sorted list visits only the pixels of its
//! evaluation box (see [`crate::preprocess`]), skipping pixels already saturated; the tile stops once
//! every pixel is. Per pixel, with `T` the transmittance in front of surfel `i` and `w_i = α_i T`:
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
use crate::intersect::{intersect, ndc_depth};
use crate::layout::Layout;
use crate::preprocess::Proj;

/// Pixel range of tile `t` clipped to the image: `(x0, y0, x1, y1)` inclusive.
#[inline]
pub fn tile_pixels(t: usize, tiles_x: u32, width: u32, height: u32) -> (i32, i32, i32, i32) {
    let tx = (t as u32 % tiles_x) * TILE;
    let ty = (t as u32 / tiles_x) * TILE;
    (tx as i32, ty as i32, ((tx + TILE).min(width) - 1) as i32, ((ty + TILE).min(height) - 1) as i32)
}

/// Rasterizes tile `t` into its float block `buf` and integer block `ibuf`.
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
    let mut tr = [R::ONE; TILE_PIXELS];
    let mut done = [true; TILE_PIXELS];
    let mut active = 0usize;
    for y in ty0..=ty1 {
        for x in tx0..=tx1 {
            done[((y - ty0) * TILE as i32 + (x - tx0)) as usize] = false;
            active += 1;
        }
    }
    let (last, medpos) = ibuf.split_at_mut(TILE_PIXELS);
    last.fill(0);
    medpos.fill(u32::MAX);
    buf.fill(R::ZERO);
    let half = R::from_f64(MEDIAN_TRANSMITTANCE);
    let min_t = R::from_f64(MIN_TRANSMITTANCE);

    for (pos, &j) in bins.tile(t).iter().enumerate() {
        if active == 0 {
            break;
        }
        let p = &projs[j as usize];
        let (x0, y0) = (p.bbox[0].max(tx0), p.bbox[1].max(ty0));
        let (x1, y1) = (p.bbox[2].min(tx1), p.bbox[3].min(ty1));
        let pr = &probs[j as usize * k_obj..(j as usize + 1) * k_obj];
        for y in y0..=y1 {
            let yr = R::from_f64(y as f64);
            let row = ((y - ty0) * TILE as i32) as usize;
            for x in x0..=x1 {
                let idx = row + (x - tx0) as usize;
                if done[idx] {
                    continue;
                }
                let Some(h) = intersect(p, R::from_f64(x as f64), yr, cam.near) else { continue };
                let t_before = tr[idx];
                let t_after = t_before * (R::ONE - h.alpha);
                if t_after < min_t {
                    done[idx] = true;
                    active -= 1;
                    continue;
                }
                let w = h.alpha * t_before;
                for c in 0..3 {
                    buf[(lay.rgb + c) * TILE_PIXELS + idx] += w * p.rgb[c];
                    buf[(lay.normal + c) * TILE_PIXELS + idx] += w * p.normal[c];
                }
                if lay.has_mask {
                    for c in 0..3 {
                        buf[(lay.mask + c) * TILE_PIXELS + idx] += w * p.mask[c];
                    }
                }
                if lay.has_objects {
                    for (c, &pc) in pr.iter().enumerate() {
                        buf[(lay.obj + c) * TILE_PIXELS + idx] += w * pc;
                    }
                }
                buf[lay.depth * TILE_PIXELS + idx] += w * h.z;
                if t_before > half {
                    buf[lay.median * TILE_PIXELS + idx] = h.z;
                    medpos[idx] = pos as u32;
                }
                let (m, _) = ndc_depth(h.z);
                let a = R::ONE - t_before;
                let m1 = buf[lay.m1 * TILE_PIXELS + idx];
                let m2 = buf[lay.m2 * TILE_PIXELS + idx];
                buf[lay.dist * TILE_PIXELS + idx] += w * (m * m * a + m2 - R::from_f64(2.0) * m * m1);
                buf[lay.m1 * TILE_PIXELS + idx] = m1 + w * m;
                buf[lay.m2 * TILE_PIXELS + idx] = m2 + w * m * m;
                tr[idx] = t_after;
                last[idx] = pos as u32 + 1;
            }
        }
    }

    for idx in 0..TILE_PIXELS {
        let t_final = tr[idx];
        buf[lay.t_final * TILE_PIXELS + idx] = t_final;
        buf[lay.alpha * TILE_PIXELS + idx] = R::ONE - t_final;
        for c in 0..3 {
            buf[(lay.rgb + c) * TILE_PIXELS + idx] += t_final * background[c];
            if lay.has_mask {
                buf[(lay.mask + c) * TILE_PIXELS + idx] += t_final * background[c];
            }
        }
    }
}
