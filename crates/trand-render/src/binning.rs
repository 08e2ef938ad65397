//! Stage 2: tile binning.
//!
//! Visible surfels are sorted by the camera depth of their centre (ties by index, so the order is a
//! pure function of the input), then scattered into per-tile lists in that order: every tile list comes
//! out depth-sorted without 64-bit keys. Buffers (CSR):
//!
//! * `tile_start[t] .. tile_start[t+1]` — the slice of `tile_list` for tile `t` (row-major tile id);
//!   `tile_list[p]` is an index into the visible-surfel array. `p` is a *pair* position.
//! * `pair_start[j] .. pair_start[j+1]` — the slice of `pair_pos` that lists, for visible surfel `j`,
//!   the pair positions of all its tiles in row-major tile order. The backward pass writes one gradient
//!   record per pair and sums each surfel's records in this fixed order: deterministic for any thread
//!   count, no atomics.

use rayon::slice::ParallelSliceMut;
use trand_core::Real;

use crate::preprocess::Proj;

#[derive(Clone, Debug, Default)]
pub struct Bins {
    pub tiles_x: u32,
    pub tiles_y: u32,
    pub tile_start: Vec<u32>,
    pub tile_list: Vec<u32>,
    pub pair_start: Vec<u32>,
    pub pair_pos: Vec<u32>,
}

impl Bins {
    pub fn num_tiles(&self) -> usize {
        (self.tiles_x * self.tiles_y) as usize
    }

    pub fn num_pairs(&self) -> usize {
        self.tile_list.len()
    }

    /// The depth-sorted visible-surfel indices of tile `t`.
    pub fn tile(&self, t: usize) -> &[u32] {
        &self.tile_list[self.tile_start[t] as usize..self.tile_start[t + 1] as usize]
    }
}

/// Bins the visible surfels into `tiles_x × tiles_y` tiles.
pub fn bin<R: Real>(projs: &[Proj<R>], tiles_x: u32, tiles_y: u32) -> Bins {
    let n_tiles = (tiles_x * tiles_y) as usize;
    let mut order: Vec<u32> = (0..projs.len() as u32).collect();
    // Keys are unique (index tie-break), so the parallel sort's result is the one order.
    order.par_sort_unstable_by_key(|&j| (projs[j as usize].depth.to_bits_u64(), j));

    let mut counts = vec![0u32; n_tiles + 1];
    let mut pair_start = Vec::with_capacity(projs.len() + 1);
    pair_start.push(0u32);
    let mut total = 0u32;
    for p in projs {
        let [x0, y0, x1, y1] = p.tiles;
        for ty in y0..y1 {
            for tx in x0..x1 {
                counts[(ty * tiles_x + tx) as usize] += 1;
            }
        }
        total += (x1 - x0) * (y1 - y0);
        pair_start.push(total);
    }
    let mut tile_start = vec![0u32; n_tiles + 1];
    for t in 0..n_tiles {
        tile_start[t + 1] = tile_start[t] + counts[t];
    }
    let mut cursor = tile_start[..n_tiles].to_vec();
    let mut tile_list = vec![0u32; total as usize];
    let mut pair_pos = vec![0u32; total as usize];
    for &j in &order {
        let p = &projs[j as usize];
        let [x0, y0, x1, y1] = p.tiles;
        let mut k = pair_start[j as usize] as usize;
        for ty in y0..y1 {
            for tx in x0..x1 {
                let t = (ty * tiles_x + tx) as usize;
                let pos = cursor[t];
                cursor[t] += 1;
                tile_list[pos as usize] = j;
                pair_pos[k] = pos;
                k += 1;
            }
        }
    }
    Bins {
        tiles_x,
        tiles_y,
        tile_start,
        tile_list,
        pair_start,
        pair_pos,
    }
}
