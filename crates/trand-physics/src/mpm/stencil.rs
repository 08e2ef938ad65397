//! The 3×3×3 node stencil of a particle and the two transfers over it.
//!
//! # Pack-wide stencils
//! Base nodes `b = ⌊x/dx − ½⌋`, fractional offsets `f = x/dx − b` and quadratic B-spline weights
//! are computed for the four particles of a pack at once ([`PackStencil`]).
//!
//! # Windows
//! The transfers work on a [`Window`], a local copy of the 27 nodes around one base node: G2P
//! loads it from the grid, P2G accumulates into it and adds it to the grid in one go
//! ([`GatherWindow`], [`ScatterWindow`]). Particles are sorted so that those sharing a base node
//! are adjacent (TRAN-D's particles are dense: tens to hundreds per grid cell), and a window is
//! kept while the base node stays the same, so most particles touch no grid memory and compute no
//! grid index. Each node of a chunk grid is then the sum over runs of particles of the run's sum:
//! a fixed order, as the particle order is.
//!
//! # Separable sums
//! The weight of node `b + (i, j, k)` is a product `wxᵢ wyⱼ wzₖ`, and what P2G sends there,
//! `m v + A (o − f) dx`, is affine in the offset `o = (i, j, k)`. So is what G2P gathers. Both
//! transfers therefore factor axis by axis: G2P sums each x-row of three nodes (`Σᵢ wxᵢ nᵢ` and
//! `Σᵢ i wxᵢ nᵢ`), then the three rows of each z-plane, then the three planes, and returns
//! `Σ w n` and `Σ w n ⊗ o` (the caller forms `C = (4/dx)(Σ w v ⊗ o − (Σ w v) ⊗ f)`); P2G builds each
//! node's value from per-plane and per-row partial products. The sums are the same as node by node
//! up to float rounding, at about half the vector operations.

use glam::{IVec3, Mat4, Vec4};
use wide::f32x4;

use super::store::LANES;

/// `[k][j][i]`: the node `b + (i, j, k)` of a stencil with base node `b`.
pub(super) type Window = [[[Vec4; 3]; 3]; 3];

/// Coordinates are clamped to ±2³⁰ nodes before the integer conversion (a NaN goes to the lower
/// bound): exact within, and a particle beyond makes the grid-size check refuse the region
/// instead of overflowing.
const NODE_RANGE: f32 = (1u32 << 30) as f32;

/// Quadratic B-spline weights of the three nodes `b, b+1, b+2` for fractional offsets `f`.
#[inline(always)]
pub(super) fn bspline_weights(f: f32x4) -> [f32x4; 3] {
    let half = f32x4::splat(0.5);
    let (a, b, c) = (f32x4::splat(1.5) - f, f - f32x4::ONE, f - half);
    [half * a * a, f32x4::splat(0.75) - b * b, half * c * c]
}

/// Base nodes, fractional offsets and weights of a pack's lanes.
pub(super) struct PackStencil {
    /// `base[axis][lane]`.
    base: [[i32; LANES]; 3],
    /// `frac[axis]`.
    pub frac: [f32x4; 3],
    /// `w[axis][node]`.
    w: [[f32x4; 3]; 3],
}

impl PackStencil {
    #[inline(always)]
    pub fn new(x: &[f32x4; 3], inv_dx: f32) -> Self {
        let (lo, hi) = (f32x4::splat(-NODE_RANGE), f32x4::splat(NODE_RANGE));
        let mut base = [[0; LANES]; 3];
        let mut frac = [f32x4::ZERO; 3];
        for a in 0..3 {
            let xg = x[a] * f32x4::splat(inv_dx);
            let v = (xg - f32x4::splat(0.5)).fast_max(lo).fast_min(hi);
            let t = v.fast_trunc_int().round_float(); // towards zero
            let floor = t - (t.simd_gt(v) & f32x4::ONE);
            base[a] = floor.fast_trunc_int().to_array();
            frac[a] = xg - floor;
        }
        let w = [
            bspline_weights(frac[0]),
            bspline_weights(frac[1]),
            bspline_weights(frac[2]),
        ];
        Self { base, frac, w }
    }

    #[inline(always)]
    pub fn base(&self, l: usize) -> IVec3 {
        IVec3::new(self.base[0][l], self.base[1][l], self.base[2][l])
    }

    /// Weights of lane `l`, `[axis][node]`.
    #[inline(always)]
    pub fn weights(&self, l: usize) -> [[f32; 3]; 3] {
        // Indexing, not `array::map`, which is not inlined here.
        let axis = |a: usize| {
            let w = &self.w[a];
            [w[0].as_array()[l], w[1].as_array()[l], w[2].as_array()[l]]
        };
        [axis(0), axis(1), axis(2)]
    }
}

/// Base node of one position (lane 0 of the pack computation).
#[cfg(test)]
pub(super) fn base_node(x: glam::Vec3, inv_dx: f32) -> IVec3 {
    let lanes = [f32x4::splat(x.x), f32x4::splat(x.y), f32x4::splat(x.z)];
    PackStencil::new(&lanes, inv_dx).base(0)
}

/// Node indexing of a dense grid over the box `[lo, lo + dims)`, x fastest.
pub(super) struct Rows {
    lo: IVec3,
    dims: IVec3,
    /// Offsets of the nine rows `(j, k)` (index `3k + j`) of a stencil from its base node.
    offsets: [usize; 9],
}

impl Rows {
    pub fn new(lo: IVec3, dims: IVec3) -> Self {
        let (nx, layer) = (dims.x as usize, (dims.x * dims.y) as usize);
        Self {
            lo,
            dims,
            offsets: std::array::from_fn(|r| (r / 3) * layer + (r % 3) * nx),
        }
    }

    /// Index of node `b`.
    #[inline(always)]
    pub fn start(&self, b: IVec3) -> usize {
        let o = (b - self.lo).as_uvec3();
        ((o.z as usize * self.dims.y as usize) + o.y as usize) * self.dims.x as usize + o.x as usize
    }

    /// The three nodes of row `(j, k)` of the stencil at `start`.
    #[inline(always)]
    fn row<'a>(&self, nodes: &'a [Vec4], start: usize, j: usize, k: usize) -> &'a [Vec4; 3] {
        let at = start + self.offsets[3 * k + j];
        nodes[at..at + 3].try_into().unwrap()
    }

    #[inline(always)]
    fn row_mut<'a>(
        &self,
        nodes: &'a mut [Vec4],
        start: usize,
        j: usize,
        k: usize,
    ) -> &'a mut [Vec4; 3] {
        let at = start + self.offsets[3 * k + j];
        (&mut nodes[at..at + 3]).try_into().unwrap()
    }
}

/// No window held yet.
const NO_NODE: usize = usize::MAX;

/// G2P's copy of the nodes around the last base node it read.
pub(super) struct GatherWindow {
    start: usize,
    nodes: Window,
}

impl GatherWindow {
    pub fn new() -> Self {
        Self {
            start: NO_NODE,
            nodes: [[[Vec4::ZERO; 3]; 3]; 3],
        }
    }

    /// The nodes around grid index `start` (read from `grid` when they are not those held).
    #[inline(always)]
    pub fn at(&mut self, grid: &[Vec4], rows: &Rows, start: usize) -> &Window {
        if start != self.start {
            for (k, plane) in self.nodes.iter_mut().enumerate() {
                for (j, row) in plane.iter_mut().enumerate() {
                    *row = *rows.row(grid, start, j, k);
                }
            }
            self.start = start;
        }
        &self.nodes
    }
}

/// P2G's sums for the nodes around the base node of the current run of particles.
pub(super) struct ScatterWindow {
    start: usize,
    sums: Window,
}

impl ScatterWindow {
    pub fn new() -> Self {
        Self {
            start: NO_NODE,
            sums: [[[Vec4::ZERO; 3]; 3]; 3],
        }
    }

    /// The sums for the nodes around grid index `start`; those of the previous run go into `grid`
    /// first.
    #[inline(always)]
    pub fn at(&mut self, grid: &mut [Vec4], rows: &Rows, start: usize) -> &mut Window {
        if start != self.start {
            self.flush(grid, rows);
            self.start = start;
        }
        &mut self.sums
    }

    /// Adds the sums held into `grid` and empties the window.
    pub fn flush(&mut self, grid: &mut [Vec4], rows: &Rows) {
        if self.start == NO_NODE {
            return;
        }
        for (k, plane) in self.sums.iter_mut().enumerate() {
            for (j, row) in plane.iter_mut().enumerate() {
                for (n, s) in rows
                    .row_mut(grid, self.start, j, k)
                    .iter_mut()
                    .zip(row.iter_mut())
                {
                    *n += *s;
                    *s = Vec4::ZERO;
                }
            }
        }
        self.start = NO_NODE;
    }
}

/// `(Σᵢ wᵢ aᵢ, Σᵢ i wᵢ aᵢ)` over three nodes (rows, planes) at offsets 0, 1, 2.
#[inline(always)]
fn moments(w: [f32; 3], a: [Vec4; 3]) -> (Vec4, Vec4) {
    let (b1, b2) = (w[1] * a[1], w[2] * a[2]);
    (w[0] * a[0] + b1 + b2, b1 + b2 + b2)
}

#[inline(always)]
fn weighted_sum(w: [f32; 3], a: [Vec4; 3]) -> Vec4 {
    w[0] * a[0] + w[1] * a[1] + w[2] * a[2]
}

/// `[Σ w n, Σ w n i, Σ w n j, Σ w n k]` over the window's nodes `n` with weights `w[axis][node]`
/// (module doc: row by row, then plane by plane).
#[inline(always)]
pub(super) fn gather(win: &Window, w: [[f32; 3]; 3]) -> [Vec4; 4] {
    let plane = |k: usize| {
        let row = |j: usize| moments(w[0], win[k][j]);
        let [r0, r1, r2] = [row(0), row(1), row(2)];
        let (s, sj) = moments(w[1], [r0.0, r1.0, r2.0]);
        (s, weighted_sum(w[1], [r0.1, r1.1, r2.1]), sj)
    };
    let [p0, p1, p2] = [plane(0), plane(1), plane(2)];
    let (s, sk) = moments(w[2], [p0.0, p1.0, p2.0]);
    let si = weighted_sum(w[2], [p0.1, p1.1, p2.1]);
    let sj = weighted_sum(w[2], [p0.2, p1.2, p2.2]);
    [s, si, sj, sk]
}

/// Adds `wxᵢ wyⱼ wzₖ (m0 + i ax + j ay + k az)` to window node `(i, j, k)` (module doc: built
/// plane by plane, row by row).
#[inline(always)]
pub(super) fn scatter(win: &mut Window, w: [[f32; 3]; 3], m0: Vec4, [ax, ay, az]: [Vec4; 3]) {
    let mut plane = m0;
    for (k, rows) in win.iter_mut().enumerate() {
        let wz = w[2][k];
        let (yk, xk) = (wz * ay, wz * ax);
        let mut row = wz * plane;
        for (j, nodes) in rows.iter_mut().enumerate() {
            let wy = w[1][j];
            let (b, step) = (wy * row, wy * xk);
            let b1 = b + step;
            nodes[0] += w[0][0] * b;
            nodes[1] += w[0][1] * b1;
            nodes[2] += w[0][2] * (b1 + step);
            row += yk;
        }
        plane += az;
    }
}

/// Lanes of four per-lane vectors → per-lane `Vec4`s (`rows[c]` holds component `c` of every lane).
#[inline(always)]
pub(super) fn lanes_to_vec4s(rows: [f32x4; 4]) -> [Vec4; LANES] {
    let c = |r: f32x4| Vec4::from_array(r.to_array());
    let m = Mat4::from_cols(c(rows[0]), c(rows[1]), c(rows[2]), c(rows[3])).transpose();
    [m.x_axis, m.y_axis, m.z_axis, m.w_axis]
}

/// The inverse of [`lanes_to_vec4s`].
#[inline(always)]
pub(super) fn vec4s_to_lanes(v: [Vec4; LANES]) -> [f32x4; 4] {
    let m = Mat4::from_cols(v[0], v[1], v[2], v[3]).transpose();
    let c = |v: Vec4| f32x4::new(v.to_array());
    [c(m.x_axis), c(m.y_axis), c(m.z_axis), c(m.w_axis)]
}

/// All bits set in the first `live` lanes.
pub(super) fn live_mask(live: usize) -> f32x4 {
    f32x4::new([0.0, 1.0, 2.0, 3.0]).simd_lt(f32x4::splat(live as f32))
}

#[cfg(test)]
mod tests {
    use glam::{DVec3, DVec4, Vec3};

    use super::*;

    #[test]
    fn bspline_weights_sum_to_one_and_reproduce_position() {
        for f in [0.5f32, 0.7, 1.0, 1.3, 1.49] {
            let w = bspline_weights(f32x4::splat(f)).map(|w| w.as_array()[0]);
            let first_moment: f32 = w.iter().enumerate().map(|(i, w)| w * i as f32).sum();
            assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-6);
            assert!((first_moment - f).abs() < 1e-6);
        }
    }

    #[test]
    fn base_node_is_the_floor_of_x_over_dx_minus_a_half_also_below_zero() {
        let inv_dx = 48.0;
        for x in [
            0.0f32,
            0.0104,
            0.0105,
            0.3,
            -0.0001,
            -0.01,
            -0.0105,
            -0.3,
            -1.0 / 96.0,
            1.0 / 96.0,
        ] {
            // x/dx in f32 as the solver has it, then the floor exactly.
            let want = ((x * inv_dx) as f64 - 0.5).floor() as i32;
            assert_eq!(
                base_node(Vec3::splat(x), inv_dx),
                IVec3::splat(want),
                "x = {x}"
            );
        }
        // Far out and NaN: clamped, so the grid-size check refuses them rather than overflowing.
        let far = base_node(Vec3::new(1e30, -1e30, f32::NAN), inv_dx);
        assert_eq!(far, IVec3::new(1 << 30, -(1 << 30), -(1 << 30)));
    }

    /// Weights per axis and node of fractional offsets `f`, in f64.
    fn weights_f64(f: DVec3) -> [[f64; 3]; 3] {
        let w = |f: f64| {
            [
                0.5 * (1.5 - f).powi(2),
                0.75 - (f - 1.0).powi(2),
                0.5 * (f - 0.5).powi(2),
            ]
        };
        [w(f.x), w(f.y), w(f.z)]
    }

    fn offsets() -> impl Iterator<Item = (usize, usize, usize)> {
        (0..3).flat_map(|k| (0..3).flat_map(move |j| (0..3).map(move |i| (i, j, k))))
    }

    fn stencil_of(f: Vec3) -> [[f32; 3]; 3] {
        let st = PackStencil::new(&[f.x, f.y, f.z].map(f32x4::splat), 1.0);
        st.weights(0)
    }

    #[test]
    fn gather_sums_weighted_nodes_and_their_first_moments() {
        // Positions in grid units with base node 0: the fractional offsets themselves.
        let f = Vec3::new(0.63, 1.21, 1.47);
        let win: Window = std::array::from_fn(|k| {
            std::array::from_fn(|j| {
                std::array::from_fn(|i| {
                    let t = (i * 7 + j * 3 + k * 11) as f32;
                    Vec4::new(0.1 * t.sin(), 0.2 * (0.3 * t).cos(), -1.0 + 0.05 * t, 0.3)
                })
            })
        });
        let got = gather(&win, stencil_of(f));
        let w = weights_f64(f.as_dvec3());
        let mut want = [DVec4::ZERO; 4];
        for (i, j, k) in offsets() {
            let wn = w[0][i] * w[1][j] * w[2][k] * win[k][j][i].as_dvec4();
            want[0] += wn;
            want[1] += i as f64 * wn;
            want[2] += j as f64 * wn;
            want[3] += k as f64 * wn;
        }
        for (g, w) in got.iter().zip(want) {
            assert!((g.as_dvec4() - w).abs().max_element() < 1e-6, "{g} vs {w}");
        }
    }

    #[test]
    fn scatter_adds_each_node_its_weighted_affine_value() {
        let f = Vec3::new(0.52, 0.98, 1.33);
        let (m0, ax, ay, az) = (
            Vec4::new(0.3, -0.2, -1.1, 0.27),
            Vec4::new(0.05, 0.01, -0.02, 0.0),
            Vec4::new(-0.03, 0.04, 0.01, 0.0),
            Vec4::new(0.02, -0.05, 0.03, 0.0),
        );
        let mut win: Window = [[[Vec4::ONE; 3]; 3]; 3];
        scatter(&mut win, stencil_of(f), m0, [ax, ay, az]);
        let w = weights_f64(f.as_dvec3());
        for (i, j, k) in offsets() {
            let value = m0 + i as f32 * ax + j as f32 * ay + k as f32 * az;
            let want = DVec4::ONE + w[0][i] * w[1][j] * w[2][k] * value.as_dvec4();
            let got = win[k][j][i].as_dvec4();
            assert!((got - want).abs().max_element() < 1e-6, "({i}, {j}, {k})");
        }
    }

    #[test]
    fn windows_read_and_add_the_nodes_around_their_base_node() {
        let (lo, dims) = (IVec3::new(-2, 5, 1), IVec3::new(5, 4, 6));
        let rows = Rows::new(lo, dims);
        let n = (dims.x * dims.y * dims.z) as usize;
        let mut grid: Vec<Vec4> = (0..n).map(|i| Vec4::splat(i as f32)).collect();
        let b = IVec3::new(-1, 6, 3);
        let index = |o: IVec3| {
            let g = b + o - lo;
            ((g.z * dims.y + g.y) * dims.x + g.x) as usize
        };
        let mut read = GatherWindow::new();
        let win = *read.at(&grid, &rows, rows.start(b));
        for (i, j, k) in offsets() {
            let at = index(IVec3::new(i as i32, j as i32, k as i32));
            assert_eq!(win[k][j][i], Vec4::splat(at as f32));
        }
        // Two runs: the first run's sums reach the grid when the base node changes, the second's
        // on the flush; nodes outside the stencils are untouched.
        let before = grid.clone();
        let mut sums = ScatterWindow::new();
        sums.at(&mut grid, &rows, rows.start(b))[0][0][0] += Vec4::ONE;
        sums.at(&mut grid, &rows, rows.start(b))[2][1][2] += Vec4::ONE;
        assert_eq!(grid, before, "nothing added before the run ends");
        sums.at(&mut grid, &rows, rows.start(b + IVec3::X))[0][0][0] += Vec4::ONE;
        sums.flush(&mut grid, &rows);
        let mut want = before;
        for o in [IVec3::ZERO, IVec3::new(2, 1, 2), IVec3::X] {
            want[index(o)] += Vec4::ONE;
        }
        assert_eq!(grid, want);
    }
}
