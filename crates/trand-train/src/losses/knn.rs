//! Exact k-nearest-neighbour queries on one object's members, for the object-aware 3D loss.
//!
//! The loss asks, every iteration and for every object, the K ≤ 32 members nearest to each of its
//! G ≤ 64 FPS centres. The members change every iteration, so the structure is rebuilt every time for
//! about a hundred queries: it must be cheap to build, not only to query. On a trained five-object
//! seq_105 scene (7–14 k members per object; `objloss_timing`, 2 threads) the whole loss took 5.45 ms
//! with kiddo's kd-tree (sorting along the axes, O(n log n) to build), 5.7–6.9 ms with an eight-lane
//! brute-force scan (O(n) per query), and 4.6 ms with this grid.
//!
//! [`PointGrid`] is a uniform grid built by one counting sort (O(n)), cells of about
//! [`POINTS_PER_CELL`] points if the members filled their bounding box; glass objects are surfaces,
//! so an occupied cell holds more. A query visits the cells in growing cubic shells around its own cell
//! and stops when the K-th best distance is below the nearest a point of an unvisited shell can be.
//!
//! Results are exactly [`k_nearest`]'s (the plain scan, the reference): squared Euclidean distance in
//! `f64`, nearest first, ties to the lower index, points with a non-finite coordinate never chosen.
//! Candidates arrive in cell order rather than index order, so the kept list is ordered by the pair
//! (distance, index), which is what the scan's "an equal distance does not displace an earlier index"
//! amounts to.

use trand_core::Real;

/// Target points per cell, were the members spread through their bounding box. Smaller cells mean
/// fewer distance evaluations per query but more (mostly empty) cells to visit and build. The value was
/// not tuned.
pub const POINTS_PER_CELL: f64 = 8.0;

/// Most cells along one axis (bounds the grid's memory for elongated or degenerate boxes).
const MAX_CELLS_PER_AXIS: usize = 128;

/// Squared distance: the one expression of every distance here and in the object-aware loss, so the
/// grid's distances are bit for bit [`k_nearest`]'s.
#[inline(always)]
pub(crate) fn dist2<R: Real>(a: &[R; 3], b: &[R; 3]) -> R {
    let (dx, dy, dz) = (a[0] - b[0], a[1] - b[1], a[2] - b[2]);
    dx * dx + dy * dy + dz * dz
}

/// The `k` of `points` nearest to `query` (squared Euclidean, ties to the lower index), nearest first.
/// Points at a non-finite distance are never chosen, so fewer than `k` may come back. A scan of every
/// point: the reference [`PointGrid::k_nearest`] is tested against.
pub fn k_nearest<R: Real>(points: &[[R; 3]], query: &[R; 3], k: usize) -> Vec<usize> {
    if k == 0 {
        return Vec::new();
    }
    // A sorted list of the k best (distance, index) pairs; most candidates are rejected by one comparison
    // with the current k-th. A later equal distance does not displace an earlier index.
    let mut best: Vec<(R, usize)> = Vec::with_capacity(k + 1);
    for (j, p) in points.iter().enumerate() {
        let d = dist2(p, query);
        if (best.len() == k && d >= best[k - 1].0) || !d.is_finite() {
            continue;
        }
        let at = best.partition_point(|&(bd, _)| bd <= d);
        best.insert(at, (d, j));
        best.truncate(k);
    }
    best.into_iter().map(|(_, j)| j).collect()
}

/// A uniform grid over the finite points, in compressed form: the points sorted by cell (stably, so
/// ascending index within a cell), `start[c]..start[c + 1]` the range of cell `c` (x fastest).
pub struct PointGrid {
    origin: [f64; 3],
    /// Cell edge length (> 0).
    cell: f64,
    dims: [usize; 3],
    start: Vec<u32>,
    /// Coordinates and original index of the points in cell order.
    pos: Vec<[f64; 3]>,
    index: Vec<u32>,
}

impl PointGrid {
    /// Builds the grid of `points` (those with a non-finite coordinate are left out).
    pub fn new<R: Real>(points: &[[R; 3]]) -> Self {
        let finite: Vec<(u32, [f64; 3])> = points
            .iter()
            .enumerate()
            .filter(|(_, p)| p.iter().all(|v| v.is_finite()))
            .map(|(i, p)| (i as u32, p.map(R::to_f64)))
            .collect();
        let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        for (_, p) in &finite {
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        if finite.is_empty() {
            (lo, hi) = ([0.0; 3], [0.0; 3]);
        }
        let ext = [hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]];
        let longest = ext[0].max(ext[1]).max(ext[2]);
        let cells_wanted = (finite.len() as f64 / POINTS_PER_CELL).max(1.0);
        // Volume-based edge, never so small that an axis exceeds its cell cap; a box with no extent
        // (one point, or all equal) gets one cell.
        let by_volume = (ext[0] * ext[1] * ext[2] / cells_wanted).cbrt();
        let cell = by_volume
            .max(longest / MAX_CELLS_PER_AXIS as f64)
            .max(longest * 1e-9);
        let cell = if cell > 0.0 && cell.is_finite() {
            cell
        } else {
            1.0
        };
        let dims = ext.map(|e| ((e / cell) as usize + 1).min(MAX_CELLS_PER_AXIS));
        let mut grid = Self {
            origin: lo,
            cell,
            dims,
            start: Vec::new(),
            pos: Vec::with_capacity(finite.len()),
            index: Vec::with_capacity(finite.len()),
        };
        let n_cells = dims[0] * dims[1] * dims[2];
        let cell_of: Vec<u32> = finite
            .iter()
            .map(|(_, p)| grid.cell_index(grid.coords(p)) as u32)
            .collect();
        // Counting sort by cell.
        let mut start = vec![0u32; n_cells + 1];
        for &c in &cell_of {
            start[c as usize + 1] += 1;
        }
        for c in 0..n_cells {
            start[c + 1] += start[c];
        }
        let mut fill = start.clone();
        grid.pos.resize(finite.len(), [0.0; 3]);
        grid.index.resize(finite.len(), 0);
        for ((i, p), &c) in finite.iter().zip(&cell_of) {
            let at = fill[c as usize] as usize;
            fill[c as usize] += 1;
            grid.pos[at] = *p;
            grid.index[at] = *i;
        }
        grid.start = start;
        grid
    }

    /// Integer cell coordinates of `p`, clamped into the grid.
    #[inline]
    fn coords(&self, p: &[f64; 3]) -> [usize; 3] {
        std::array::from_fn(|a| {
            let f = ((p[a] - self.origin[a]) / self.cell).floor();
            if f > 0.0 {
                (f as usize).min(self.dims[a] - 1)
            } else {
                0
            }
        })
    }

    #[inline]
    fn cell_index(&self, c: [usize; 3]) -> usize {
        (c[2] * self.dims[1] + c[1]) * self.dims[0] + c[0]
    }

    /// The `k` points nearest to `query` (which must be finite), as [`k_nearest`] would return them.
    pub fn k_nearest(&self, query: &[f64; 3], k: usize) -> Vec<usize> {
        if k == 0 {
            return Vec::new();
        }
        let mut best: Vec<(f64, u32)> = Vec::with_capacity(k + 1);
        let q = self.coords(query);
        let max_ring = (0..3)
            .map(|a| q[a].max(self.dims[a] - 1 - q[a]))
            .max()
            .unwrap_or(0);
        for r in 0..=max_ring {
            self.visit_shell(q, r, |first, last| {
                for (p, &j) in self.pos[first..last].iter().zip(&self.index[first..last]) {
                    let d = dist2(p, query);
                    // Keep the k smallest (distance, index) pairs.
                    if best.len() == k {
                        let (kd, kj) = best[k - 1];
                        if d > kd || (d == kd && j > kj) {
                            continue;
                        }
                    }
                    let at = best.partition_point(|&(bd, bj)| bd < d || (bd == d && bj < j));
                    best.insert(at, (d, j));
                    best.truncate(k);
                }
            });
            // A point outside shells 0..=r differs from the query's cell by r + 1 cells along some axis,
            // so lies at least r cell edges away (less a rounding margin: the cell of a point on a cell
            // wall may be either). Strictly below: an equal distance at a lower index could still come.
            if best.len() == k {
                let reach = r as f64 * self.cell * (1.0 - 1e-9);
                if best[k - 1].0 < reach * reach {
                    break;
                }
            }
        }
        best.into_iter().map(|(_, j)| j as usize).collect()
    }

    /// Calls `f(first, last)` with the point range of every non-empty cell at Chebyshev distance exactly
    /// `r` from cell `q` (the cells of the cube's surface, clipped to the grid).
    fn visit_shell(&self, q: [usize; 3], r: usize, mut f: impl FnMut(usize, usize)) {
        let range = |a: usize| q[a].saturating_sub(r)..=(q[a] + r).min(self.dims[a] - 1);
        let ri = r as isize;
        for z in range(2) {
            let on_z = (z as isize - q[2] as isize).abs() == ri;
            for y in range(1) {
                let on_yz = on_z || (y as isize - q[1] as isize).abs() == ri;
                let row = (z * self.dims[1] + y) * self.dims[0];
                let mut visit = |x: usize| {
                    let (a, b) = (
                        self.start[row + x] as usize,
                        self.start[row + x + 1] as usize,
                    );
                    if a < b {
                        f(a, b);
                    }
                };
                if on_yz {
                    for x in range(0) {
                        visit(x);
                    }
                } else {
                    // Inside the cube along y and z: only the two x faces.
                    if q[0] >= r {
                        visit(q[0] - r);
                    }
                    if r > 0 && q[0] + r < self.dims[0] {
                        visit(q[0] + r);
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_pcg::Pcg64;

    /// A thin cylindrical shell (a glass's wall) with some duplicate points (distance ties).
    fn glass(seed: u64, n: usize) -> Vec<[f64; 3]> {
        let mut rng = Pcg64::seed_from_u64(seed);
        let mut p: Vec<[f64; 3]> = (0..n)
            .map(|_| {
                let t = rng.random::<f64>() * std::f64::consts::TAU;
                let r = 0.03 + 0.0005 * rng.random::<f64>();
                [r * t.cos(), r * t.sin(), 0.1 * rng.random::<f64>()]
            })
            .collect();
        for i in (0..n.saturating_sub(1)).step_by(41) {
            p[i + 1] = p[i];
        }
        p
    }

    #[test]
    fn grid_knn_equals_the_scan_on_a_glass_wall_with_ties() {
        let p = glass(5, 3001);
        let g = PointGrid::new(&p);
        for q in (0..3001).step_by(29).chain([41, 42, 3000]) {
            for k in [1usize, 2, 16, 32] {
                assert_eq!(
                    g.k_nearest(&p[q], k),
                    k_nearest(&p, &p[q], k),
                    "query {q}, k {k}"
                );
            }
        }
    }

    #[test]
    fn grid_knn_equals_the_scan_for_queries_away_from_the_points_and_equal_distances() {
        // A lattice: many exact distance ties, which the lower index must win in any visiting order.
        let p: Vec<[f64; 3]> = (0..600)
            .map(|i| {
                [
                    (i % 10) as f64 * 0.5,
                    ((i / 10) % 10) as f64 * 0.5,
                    (i / 100) as f64 * 0.5,
                ]
            })
            .collect();
        let g = PointGrid::new(&p);
        for q in [
            [0.0, 0.0, 0.0],
            [2.25, 2.25, 1.0],
            [-3.0, 9.0, 0.7],
            [4.5, 4.5, 2.5],
        ] {
            for k in [1usize, 7, 16, 32, 600] {
                assert_eq!(
                    g.k_nearest(&q, k),
                    k_nearest(&p, &q, k),
                    "query {q:?}, k {k}"
                );
            }
        }
    }

    #[test]
    fn grid_leaves_out_non_finite_points_and_handles_degenerate_boxes() {
        let mut p = glass(6, 200);
        p[3] = [f64::NAN, 0.0, 0.0];
        p[4] = [0.0, f64::INFINITY, 0.0];
        let g = PointGrid::new(&p);
        for k in [16usize, 198, 200] {
            assert_eq!(g.k_nearest(&p[0], k), k_nearest(&p, &p[0], k), "k {k}");
        }
        assert_eq!(g.k_nearest(&p[0], 200).len(), 198);
        // All points equal: one cell, ties by index.
        let same = vec![[1.0, 2.0, 3.0]; 40];
        assert_eq!(
            PointGrid::new(&same).k_nearest(&same[0], 5),
            vec![0, 1, 2, 3, 4]
        );
        // A flat (planar) object and an empty one.
        let flat: Vec<[f64; 3]> = glass(7, 300).iter().map(|p| [p[0], p[1], 0.0]).collect();
        let g = PointGrid::new(&flat);
        assert_eq!(g.k_nearest(&flat[9], 32), k_nearest(&flat, &flat[9], 32));
        assert!(
            PointGrid::new::<f64>(&[])
                .k_nearest(&[0.0; 3], 3)
                .is_empty()
        );
    }
}
