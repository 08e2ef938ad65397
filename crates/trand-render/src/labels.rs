//! Object channels reduced against a label map: the two sums per channel that TRAN-D's Dice loss
//! needs, without rendering the K-channel object map.
//!
//! With `p_c(x) = Σ_i w_i(x) π_{i,c}` the object map (`w_i` the blending weight of surfel `i` at pixel
//! `x`, `π_i` its softmax) and `ℓ(x)` a per-pixel label (the target channel), the Dice loss reads the
//! map only through
//!
//! `P_c = Σ_x p_c(x) = Σ_i π_{i,c} W_i`  and  `I_c = Σ_{x: ℓ(x)=c} p_c(x) = Σ_i π_{i,c} W_{i,c}`,
//!
//! with `W_i = Σ_x w_i(x)` and `W_{i,c} = Σ_{x: ℓ(x)=c} w_i(x)`. Per (tile, surfel) pair the kernels
//! accumulate `W` and one `W_{·,ℓ}` per label present in the tile (a tile rarely holds more than two),
//! instead of K products per pixel. Upstream gradients come as `∂L/∂P_c` and `∂L/∂I_c`, i.e. the
//! per-pixel gradient `g_c(x) = ∂L/∂P_c + ∂L/∂I_c·[ℓ(x) = c]`; the backward needs, per pixel, only
//! `Σ_c π_{i,c} g_c(x) = Σ_c π_{i,c} ∂L/∂P_c + π_{i,ℓ(x)} ∂L/∂I_{ℓ(x)}`, and per pair
//! `∂L/∂π_{i,c} = W ∂L/∂P_c + W_c ∂L/∂I_c`. The result equals the dense map's to rounding (tested).
//!
//! Per-tile sums go to one extra plane of the tile block ([`crate::layout::Layout::sums`]): `P` in
//! entries `0..K`, `I` in `K..2K`; the render adds the tiles' planes in tile order.

use trand_core::Real;

use crate::constants::{TILE, TILE_PIXELS};
use crate::forward::Plane;

/// The two per-channel sums of the object map (see the module doc).
#[derive(Clone, Debug, PartialEq)]
pub struct ObjectSums<R> {
    /// `P_c = Σ_x p_c(x)`.
    pub total: Vec<R>,
    /// `I_c = Σ_{x: ℓ(x) = c} p_c(x)`.
    pub on_label: Vec<R>,
}

/// Gradients of a loss with respect to [`ObjectSums`].
#[derive(Clone, Debug, PartialEq)]
pub struct ObjectSumGrads<R> {
    /// `∂L/∂P_c`.
    pub total: Vec<R>,
    /// `∂L/∂I_c`.
    pub on_label: Vec<R>,
}

/// The labels present in one tile and a 0/1 plane for each (pixels outside the image belong to none).
pub struct TileLabels<R> {
    pub labels: Vec<u8>,
    pub masks: Vec<Plane<R>>,
}

impl<R: Real> TileLabels<R> {
    /// Gathers the tile `(x0, y0)..=(x1, y1)` of a row-major label image of width `width`.
    pub fn gather(labels: &[u8], width: usize, (x0, y0, x1, y1): (i32, i32, i32, i32)) -> Self {
        let mut out = Self {
            labels: Vec::new(),
            masks: Vec::new(),
        };
        for y in y0..=y1 {
            for x in x0..=x1 {
                let l = labels[y as usize * width + x as usize];
                let k = match out.labels.iter().position(|&m| m == l) {
                    Some(k) => k,
                    None => {
                        out.labels.push(l);
                        out.masks.push([R::ZERO; TILE_PIXELS]);
                        out.labels.len() - 1
                    }
                };
                out.masks[k][((y - y0) * TILE as i32 + (x - x0)) as usize] = R::ONE;
            }
        }
        out
    }
}
