//! One sweep over a chunk of particles between two grids: G2P from the grid just updated, then the
//! material update and P2G of the next substep into the chunk's own grid.
//!
//! G2P of substep `s` and the material update that opens substep `s + 1` read and write the same
//! particle fields, and P2G of a chunk needs nothing but the chunk, so one task per chunk does all
//! three ([`ParticlePass`]: the first substep of a frame starts with the material update, the last
//! ends with G2P alone). Each particle sees the same operations in the same order wherever the
//! passes are cut.
//!
//! The parts of the transfers that do not touch the grid (the advection, `C` from the gathered
//! sums, `m v − A f dx`, the affine columns) run on whole packs; the per-particle `Vec4`s of the
//! node loops come out of one 4×4 transpose per quantity.

use glam::{IVec3, Vec4};
use wide::f32x4;

use super::config::StepParams;
use super::grid::{GridView, grid_nodes};
use super::material;
use super::stencil::{
    self, GatherWindow, PackStencil, Rows, ScatterWindow, lanes_to_vec4s, live_mask, vec4s_to_lanes,
};
use super::store::{LANES, LaneMat3, Pack};

/// What one sweep over a chunk's particles does.
#[derive(Clone, Copy)]
pub(super) enum ParticlePass<'a> {
    /// The material update and P2G of the first substep of a frame (nothing to gather yet).
    Scatter,
    /// G2P from the updated grid, then the material update and P2G of the next substep.
    GatherThenScatter(GridView<'a>),
    /// G2P only: the last substep of a frame.
    Gather(GridView<'a>),
}

/// A chunk's private scatter target: a dense grid over the chunk's stencils.
#[derive(Default)]
pub(super) struct ChunkGrid {
    pub lo: IVec3,
    pub dims: IVec3,
    /// Nodes this chunk's stencils would span when that exceeds the limit (nothing scattered).
    pub too_large: Option<usize>,
    nodes: Vec<Vec4>,
    /// The packs' affine matrices from the material update.
    affine: Vec<LaneMat3>,
}

impl ChunkGrid {
    pub fn view(&self) -> GridView<'_> {
        GridView {
            nodes: &self.nodes,
            lo: self.lo,
            dims: self.dims,
        }
    }

    /// Sizes the grid for stencils with base nodes in `[lo, hi]` (refused, with nothing
    /// allocated, when that exceeds `max_nodes`: a particle flung far away, or a NaN).
    fn set_box(&mut self, lo: IVec3, hi: IVec3, max_nodes: usize) {
        // Counted in i64: the extent of a refused box may not fit an i32.
        let nodes = grid_nodes(lo, hi, 3);
        self.nodes.clear();
        self.too_large = (nodes > max_nodes).then_some(nodes);
        if self.too_large.is_none() {
            (self.lo, self.dims) = (lo, hi - lo + IVec3::splat(3));
            self.nodes.resize(nodes, Vec4::ZERO);
        }
    }
}

/// What G2P found in a chunk.
#[derive(Clone, Copy, Default)]
pub(super) struct ChunkMotion {
    /// Input index of the first particle whose new position is not finite.
    pub diverged: Option<u32>,
    /// Largest squared particle speed (m²/s²).
    pub max_speed2: f32,
}

impl ChunkMotion {
    /// Both chunks' findings (the first divergence in chunk order).
    pub fn merge(self, later: Self) -> Self {
        Self {
            diverged: self.diverged.or(later.diverged),
            max_speed2: self.max_speed2.max(later.max_speed2),
        }
    }
}

/// One sweep over a chunk (module doc); returns what G2P found.
pub(super) fn particle_pass(
    packs: &mut [Pack],
    cg: &mut ChunkGrid,
    pass: ParticlePass,
    sp: &StepParams,
) -> ChunkMotion {
    let mut motion = ChunkMotion::default();
    if let ParticlePass::GatherThenScatter(grid) | ParticlePass::Gather(grid) = pass {
        let rows = Rows::new(grid.lo, grid.dims);
        let mut window = GatherWindow::new();
        let mut speed2 = f32x4::ZERO;
        for p in packs.iter_mut() {
            speed2 = speed2.fast_max(g2p_pack(p, grid.nodes, &rows, &mut window, sp));
            if motion.diverged.is_none() {
                motion.diverged = first_non_finite(p);
            }
        }
        motion.max_speed2 = speed2.to_array().into_iter().fold(0.0, f32::max);
    }
    if !matches!(pass, ParticlePass::Gather(_)) {
        update_and_scatter(packs, cg, sp);
    }
    motion
}

/// The material update of the chunk's packs, its grid's box, and P2G into it.
fn update_and_scatter(packs: &mut [Pack], cg: &mut ChunkGrid, sp: &StepParams) {
    let (mut lo, mut hi) = (IVec3::MAX, IVec3::MIN);
    cg.affine.clear();
    for p in packs.iter_mut() {
        cg.affine.push(material::update_pack(p, sp));
        let st = PackStencil::new(&p.x, sp.inv_dx);
        for l in 0..p.live {
            (lo, hi) = (lo.min(st.base(l)), hi.max(st.base(l)));
        }
    }
    cg.set_box(lo, hi, sp.max_grid_nodes);
    if cg.too_large.is_some() {
        return;
    }
    let rows = Rows::new(cg.lo, cg.dims);
    let mut window = ScatterWindow::new();
    for (p, a) in packs.iter().zip(&cg.affine) {
        scatter_pack(p, a, &mut cg.nodes, &rows, &mut window, sp);
    }
    window.flush(&mut cg.nodes, &rows);
}

/// Input index of the first live particle of `p` whose position is not finite.
fn first_non_finite(p: &Pack) -> Option<u32> {
    let inf = f32x4::splat(f32::INFINITY);
    let finite =
        p.x.iter()
            .fold(live_mask(p.live), |m, c| m & c.abs().simd_lt(inf));
    let bad = live_mask(p.live) & !finite;
    (0..p.live)
        .find(|&l| bad.as_array()[l].to_bits() != 0)
        .map(|l| p.id[l])
}

/// G2P of one pack: `v_p = Σ w v_I`, `C_p = (4/dx) Σ w v_I ⊗ (o − f)`, `x_p += Δt v_p`; returns the
/// squared speeds.
fn g2p_pack(
    p: &mut Pack,
    grid: &[Vec4],
    rows: &Rows,
    window: &mut GatherWindow,
    sp: &StepParams,
) -> f32x4 {
    let st = PackStencil::new(&p.x, sp.inv_dx);
    // Per lane: Σ w v_I and the three columns of Σ w v_I ⊗ o (free lanes: zero, so they stay at rest).
    let mut sums = [[Vec4::ZERO; LANES]; 4];
    for l in 0..p.live {
        let s = stencil::gather(window.at(grid, rows, rows.start(st.base(l))), st.weights(l));
        for (q, sq) in sums.iter_mut().zip(s) {
            q[l] = sq;
        }
    }
    let [v, si, sj, sk] = [
        vec4s_to_lanes(sums[0]),
        vec4s_to_lanes(sums[1]),
        vec4s_to_lanes(sums[2]),
        vec4s_to_lanes(sums[3]),
    ];
    let scale = f32x4::splat(4.0 * sp.inv_dx);
    for (a, (c, s)) in p.c.iter_mut().zip([si, sj, sk]).enumerate() {
        // Column a of C: (4/dx)(Σ w v oₐ − fₐ Σ w v).
        for r in 0..3 {
            c[r] = scale * (s[r] - st.frac[a] * v[r]);
        }
    }
    let dt = f32x4::splat(sp.dt);
    p.v = [v[0], v[1], v[2]];
    for (x, v) in p.x.iter_mut().zip(p.v) {
        *x += dt * v;
    }
    v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
}

/// P2G of one pack with affine matrices `a`: node `b + o` receives `w (m_p v + A (o − f) dx, m_p)`.
fn scatter_pack(
    p: &Pack,
    a: &LaneMat3,
    grid: &mut [Vec4],
    rows: &Rows,
    window: &mut ScatterWindow,
    sp: &StepParams,
) {
    let st = PackStencil::new(&p.x, sp.inv_dx);
    let (dx, mass) = (f32x4::splat(sp.dx), f32x4::splat(sp.p_mass));
    // At the base node: m v − A f dx, with the mass as fourth component; per unit offset along
    // each axis: the column of A dx, which carries no mass.
    let fdx = [st.frac[0] * dx, st.frac[1] * dx, st.frac[2] * dx];
    let m0 = |r: usize| mass * p.v[r] - (a[0][r] * fdx[0] + a[1][r] * fdx[1] + a[2][r] * fdx[2]);
    let m0 = lanes_to_vec4s([m0(0), m0(1), m0(2), mass]);
    let column = |c: usize| lanes_to_vec4s([a[c][0] * dx, a[c][1] * dx, a[c][2] * dx, f32x4::ZERO]);
    let [ax, ay, az] = [column(0), column(1), column(2)];
    for l in 0..p.live {
        let win = window.at(grid, rows, rows.start(st.base(l)));
        stencil::scatter(win, st.weights(l), m0[l], [ax[l], ay[l], az[l]]);
    }
}

#[cfg(test)]
mod tests {
    use glam::{DMat3, DVec3, DVec4, Mat3, Vec3};

    use super::*;
    use crate::mpm::store::{lane_mat3, packs_at_rest};

    fn params() -> StepParams {
        crate::MpmConfig::default().step_params()
    }

    /// Base node, and weight and `o − f` per node, of `x`, node by node in f64.
    fn stencil_f64(x: Vec3, inv_dx: f32) -> (IVec3, Vec<(IVec3, f64, DVec3)>) {
        let xg = (x * inv_dx).as_dvec3();
        let base = (xg - 0.5).floor();
        let f = xg - base;
        let w = |f: f64| {
            [
                0.5 * (1.5 - f).powi(2),
                0.75 - (f - 1.0).powi(2),
                0.5 * (f - 0.5).powi(2),
            ]
        };
        let (wx, wy, wz) = (w(f.x), w(f.y), w(f.z));
        let mut out = Vec::new();
        for k in 0..3 {
            for j in 0..3 {
                for i in 0..3 {
                    let o = IVec3::new(i, j, k);
                    let wo = wx[i as usize] * wy[j as usize] * wz[k as usize];
                    out.push((o, wo, o.as_dvec3() - f));
                }
            }
        }
        (base.as_ivec3(), out)
    }

    /// Three live particles (one lane free): two sharing a base node, one below zero.
    fn three_particles() -> Vec<[f32; 3]> {
        vec![
            [0.4531, 0.4677, 0.0812],
            [0.4568, 0.4612, 0.0846],
            [0.4499, 0.4501, -0.0106],
        ]
    }

    #[test]
    fn p2g_sends_each_node_its_weighted_momentum_and_mass() {
        let sp = params();
        let xs = three_particles();
        let mut pack = packs_at_rest(&xs)[0];
        let vs = [
            Vec3::new(0.3, -0.2, -1.1),
            Vec3::new(-0.5, 0.1, 0.4),
            Vec3::new(0.0, 0.7, -0.2),
        ];
        for (a, v) in pack.v.iter_mut().enumerate() {
            *v = f32x4::new(std::array::from_fn(|l| vs.get(l).map_or(0.0, |v| v[a])));
        }
        let am: [Mat3; 3] = std::array::from_fn(|l| {
            Mat3::from_cols_array(&std::array::from_fn(|e| {
                ((e * 7 + l * 3) % 11) as f32 * 0.05 - 0.25
            }))
        });
        let a: LaneMat3 = std::array::from_fn(|c| {
            std::array::from_fn(|r| f32x4::new(std::array::from_fn(|l| am[l.min(2)].col(c)[r])))
        });
        let bases: Vec<IVec3> = xs
            .iter()
            .map(|x| stencil_f64(Vec3::from_array(*x), sp.inv_dx).0)
            .collect();
        let mut cg = ChunkGrid::default();
        let lo = bases.iter().copied().reduce(IVec3::min).unwrap();
        cg.set_box(
            lo,
            bases.iter().copied().reduce(IVec3::max).unwrap(),
            usize::MAX,
        );
        let rows = Rows::new(cg.lo, cg.dims);
        let mut window = ScatterWindow::new();
        scatter_pack(&pack, &a, &mut cg.nodes, &rows, &mut window, &sp);
        window.flush(&mut cg.nodes, &rows);
        let (m, dx) = (sp.p_mass as f64, sp.dx as f64);
        let mut expected = vec![DVec4::ZERO; cg.nodes.len()];
        for (l, x) in xs.iter().enumerate() {
            let (base, stencil) = stencil_f64(Vec3::from_array(*x), sp.inv_dx);
            for (o, w, d) in stencil {
                let n = base + o - cg.lo;
                let idx = ((n.z * cg.dims.y + n.y) * cg.dims.x + n.x) as usize;
                let mv = m * vs[l].as_dvec3() + am[l].as_dmat3() * (d * dx);
                expected[idx] += w * mv.extend(m);
            }
        }
        for (got, want) in cg.nodes.iter().zip(&expected) {
            assert!(
                (got.as_dvec4() - *want).abs().max_element() < 1e-6,
                "{got} vs {want}"
            );
        }
        let total: f64 = cg.nodes.iter().map(|n| n.w as f64).sum();
        assert!(
            (total - 3.0 * m).abs() < 1e-6 * m,
            "mass {total} of {}",
            3.0 * m
        );
    }

    #[test]
    fn g2p_gathers_the_weighted_velocity_its_apic_gradient_and_advects() {
        let sp = params();
        let (lo, dims) = (IVec3::new(19, 19, -3), IVec3::new(7, 6, 10));
        // An arbitrary smooth node field (v, m).
        let grid: Vec<Vec4> = (0..dims.x * dims.y * dims.z)
            .map(|i| {
                let (x, y, z) = (i % dims.x, (i / dims.x) % dims.y, i / (dims.x * dims.y));
                let t = (x * 7 + y * 3 + z * 11) as f32;
                Vec4::new(0.1 * t.sin(), 0.2 * (0.3 * t).cos(), -1.0 + 0.05 * t, 0.3)
            })
            .collect();
        let xs = three_particles();
        let mut pack = packs_at_rest(&xs)[0];
        let rows = Rows::new(lo, dims);
        let speed2 = g2p_pack(&mut pack, &grid, &rows, &mut GatherWindow::new(), &sp);
        for (l, x) in xs.iter().enumerate() {
            let (base, stencil) = stencil_f64(Vec3::from_array(*x), sp.inv_dx);
            let (mut v, mut c) = (DVec3::ZERO, DMat3::ZERO);
            for (o, w, d) in stencil {
                let n = base + o - lo;
                let vi = grid[((n.z * dims.y + n.y) * dims.x + n.x) as usize]
                    .truncate()
                    .as_dvec3();
                v += w * vi;
                c += DMat3::from_cols(vi * (w * d.x), vi * (w * d.y), vi * (w * d.z));
            }
            c *= 4.0 * sp.inv_dx as f64;
            assert!(
                (pack.v(l).as_dvec3() - v).abs().max_element() < 1e-6,
                "lane {l}: v"
            );
            let e = (lane_mat3(&pack.c, l).as_dmat3() - c)
                .to_cols_array()
                .iter()
                .fold(0.0f64, |m, e| m.max(e.abs()));
            assert!(e < 2e-4, "lane {l}: C error {e}");
            let x1 = Vec3::from_array(*x).as_dvec3() + sp.dt as f64 * v;
            assert!(
                (pack.x(l).as_dvec3() - x1).abs().max_element() < 1e-7,
                "lane {l}: x"
            );
            assert!((speed2.as_array()[l] as f64 - v.length_squared()).abs() < 1e-5);
        }
        // The free lane stays at rest where it was.
        assert_eq!(
            (pack.v(3), pack.x(3)),
            (Vec3::ZERO, Vec3::from_array(xs[0]))
        );
        assert_eq!(speed2.as_array()[3], 0.0);
    }

    #[test]
    fn a_non_finite_position_is_reported_by_its_particle_id() {
        let mut pack = packs_at_rest(&three_particles())[0];
        assert_eq!(first_non_finite(&pack), None);
        pack.x[1].as_mut_array()[2] = f32::NAN;
        pack.x[0].as_mut_array()[1] = f32::INFINITY;
        assert_eq!(first_non_finite(&pack), Some(1));
        // Free lanes do not count.
        pack.live = 1;
        assert_eq!(first_non_finite(&pack), None);
    }
}
