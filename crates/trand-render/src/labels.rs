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

use crate::constants::TILE;

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

/// The labels present in one tile and, for each, the bit masks of its pixels per tile row (bit `x` of
/// `rows[k][y]` for local pixel `(x, y)`; pixels outside the image belong to none). The kernels turn a
/// row's byte into a lane mask and *select* the weight, which is bit for bit the product with a 0/1
/// plane that this replaced, without the 1 KiB float plane per label and tile.
pub struct TileLabels {
    pub labels: Vec<u8>,
    pub rows: Vec<[u16; TILE as usize]>,
}

impl TileLabels {
    /// Gathers the tile `(x0, y0)..=(x1, y1)` of a row-major label image of width `width`, labels in
    /// order of first appearance (row-major). Per row: one 16-byte comparison per label already seen,
    /// and a new label only for pixels no seen label covers.
    pub fn gather(labels: &[u8], width: usize, (x0, y0, x1, y1): (i32, i32, i32, i32)) -> Self {
        let mut out = Self {
            labels: Vec::new(),
            rows: Vec::new(),
        };
        let full = ((1u32 << (x1 - x0 + 1)) - 1) as u16;
        for y in y0..=y1 {
            let start = y as usize * width + x0 as usize;
            let row = &labels[start..start + (x1 - x0 + 1) as usize];
            let ly = (y - y0) as usize;
            let mut covered = 0u16;
            for (k, &l) in out.labels.iter().enumerate() {
                let bits = equal_bits(row, l);
                out.rows[k][ly] = bits;
                covered |= bits;
            }
            while covered != full {
                let first = (!covered & full).trailing_zeros() as usize;
                let l = row[first];
                let bits = equal_bits(row, l);
                let mut rows = [0u16; TILE as usize];
                rows[ly] = bits;
                out.labels.push(l);
                out.rows.push(rows);
                covered |= bits;
            }
        }
        out
    }
}

/// Bit `x` set where `row[x] == l` (at most 16 pixels).
#[inline]
fn equal_bits(row: &[u8], l: u8) -> u16 {
    row.iter()
        .enumerate()
        .fold(0u16, |b, (x, &v)| b | (u16::from(v == l) << x))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gathered_rows_mark_exactly_the_pixels_of_each_label() {
        // A 40×20 label image with three labels in stripes and blocks; tiles at the image's edge too.
        let (w, h) = (40usize, 20usize);
        let img: Vec<u8> = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                if x < 5 {
                    7
                } else if (x + y) % 3 == 0 {
                    2
                } else {
                    0
                }
            })
            .collect();
        for (x0, y0) in [(0, 0), (16, 0), (32, 16)] {
            let (x1, y1) = ((x0 + 15).min(w as i32 - 1), (y0 + 15).min(h as i32 - 1));
            let t = TileLabels::gather(&img, w, (x0, y0, x1, y1));
            assert_eq!(t.labels.len(), t.rows.len());
            let mut seen = t.labels.clone();
            seen.sort_unstable();
            seen.dedup();
            assert_eq!(seen.len(), t.labels.len(), "a label listed twice");
            for ly in 0..16 {
                for lx in 0..16 {
                    let (x, y) = (x0 + lx, y0 + ly);
                    let inside = x <= x1 && y <= y1;
                    for (k, &l) in t.labels.iter().enumerate() {
                        let bit = t.rows[k][ly as usize] >> lx & 1 == 1;
                        let want = inside && img[y as usize * w + x as usize] == l;
                        assert_eq!(bit, want, "label {l} at ({x}, {y})");
                    }
                }
            }
        }
    }
}
