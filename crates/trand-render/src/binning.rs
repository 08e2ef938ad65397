//! Stage 2: tile binning.
//!
//! Visible surfels are sorted by the camera depth of their centre (ties by index, so the order is a
//! pure function of the input; a stable LSD radix sort on the depth's bits, which order like the values
//! for the positive depths of visible surfels), then scattered into per-tile lists in that order: every tile list comes
//! out depth-sorted without 64-bit keys. Buffers (CSR):
//!
//! * `tile_start[t] .. tile_start[t+1]` — the slice of `tile_list` for tile `t` (row-major tile id);
//!   `tile_list[p]` is an index into the visible-surfel array. `p` is a *pair* position.
//! * `pair_start[j] .. pair_start[j+1]` — the slice of `pair_pos` that lists, for visible surfel `j`,
//!   the pair positions of all its tiles in row-major tile order. The backward pass writes one gradient
//!   record per pair and sums each surfel's records in this fixed order: deterministic for any thread
//!   count, no atomics.

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
    // The keys and tile rectangles in one sequential pass: the scatter below visits the surfels in depth
    // order, and reading each rectangle from its ~200-byte `Proj` there was a cache miss per surfel
    // (half of the binning's time on a trained 55 k-surfel scene).
    let (keys, rects): (Vec<u64>, Vec<[u32; 4]>) = projs
        .iter()
        .map(|p| (p.depth.to_bits_u64(), p.tiles))
        .unzip();
    let order = radix_order(keys);

    let mut counts = vec![0u32; n_tiles + 1];
    let mut pair_start = Vec::with_capacity(projs.len() + 1);
    pair_start.push(0u32);
    let mut total = 0u32;
    for &[x0, y0, x1, y1] in &rects {
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
        let [x0, y0, x1, y1] = rects[j as usize];
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

/// The indices `0..keys.len()` sorted by key, ties in index order: a least-significant-digit radix sort,
/// one stable counting pass per byte, skipping bytes every key shares (the high half of an `f32`
/// depth's bits). For 30 000 surfels it takes a tenth of the comparison sort it replaced, whose every
/// comparison fetched two surfels' records.
fn radix_order(mut keys: Vec<u64>) -> Vec<u32> {
    let n = keys.len();
    let mut order: Vec<u32> = (0..n as u32).collect();
    let (mut keys2, mut order2) = (vec![0u64; n], vec![0u32; n]);
    for shift in (0..64).step_by(8) {
        let mut start = [0usize; 257];
        for &k in &keys {
            start[((k >> shift) & 0xff) as usize + 1] += 1;
        }
        if start.contains(&n) {
            continue;
        }
        for b in 0..256 {
            start[b + 1] += start[b];
        }
        for (&k, &j) in keys.iter().zip(&order) {
            let b = ((k >> shift) & 0xff) as usize;
            keys2[start[b]] = k;
            order2[start[b]] = j;
            start[b] += 1;
        }
        std::mem::swap(&mut keys, &mut keys2);
        std::mem::swap(&mut order, &mut order2);
    }
    order
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn radix_order_equals_a_comparison_sort_with_index_ties() {
        let mut state = 12345u64;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            state >> 33
        };
        // Few distinct values (many ties), f32 depths and full 64-bit keys.
        let sets: Vec<Vec<u64>> = vec![
            (0..5000).map(|_| next() % 7).collect(),
            (0..5000)
                .map(|_| u64::from((0.1 + (next() % 100_000) as f32 * 1e-4).to_bits()))
                .collect(),
            (0..5000).map(|_| next() << 31 ^ next()).collect(),
            vec![],
            vec![3],
        ];
        for keys in sets {
            let mut want: Vec<u32> = (0..keys.len() as u32).collect();
            want.sort_by_key(|&j| (keys[j as usize], j));
            assert_eq!(radix_order(keys), want);
        }
    }
}
