//! MLS-MPM (Hu et al. 2018, "A Moving Least Squares Material Point Method") with fixed-corotated
//! elasticity and a sticky ground: the engine of TRAN-D's scene update (the authors run the
//! taichi_elements `mpm_solver.py`; the settings are its defaults for that step, see [`MpmConfig`]).
//!
//! # One substep (the whole algorithm is [`MpmSolver::substep`] and the three functions it calls)
//! With `dx` the grid spacing, nodes at integer multiples of `dx` in world coordinates, and for each
//! particle `p` the base node `b = ⌊x/dx − ½⌋` and fractional offset `f = x/dx − b ∈ [½, 3/2)³`:
//! 1. **P2G** (`p2g_chunk`): `F ← (I + Δt C) F`; the polar rotation `R` of `F` and `J = det F`
//!    give the fixed-corotated Kirchhoff stress `τ = 2μ(F − R)Fᵀ + λJ(J − 1)I`; with the
//!    quadratic B-spline weights `w_i = ½(3/2 − f)², ¾ − (f − 1)², ½(f − ½)²` (per axis, product
//!    over axes) every one of the 3×3×3 nodes `b + o` receives
//!    `m_I += w m_p` and `(mv)_I += w (m_p v_p + A (o − f) dx)`, with the MLS affine matrix
//!    `A = −Δt V_p (4/dx²) τ + m_p C` (APIC momentum plus the stress impulse, eq. 18 of the paper).
//! 2. **Grid** (`grid_update_layer`): `v_I = (mv)_I / m_I + Δt g`; nodes below the ground
//!    (`z_I < z_ground`) are sticky: `v_I = 0`.
//! 3. **G2P** (`g2p_chunk`): `v_p = Σ w v_I`, `C_p = (4/dx) Σ w v_I ⊗ (o − f)`, `x_p += Δt v_p`.
//!
//! # Grid and buffers
//! The grid is dense over the bounding box of the particles' stencils, recomputed every substep
//! (`grid_lo` = smallest base node, extent = box + 3 nodes), so world coordinates are used
//! directly, like the authors' unbounded sparse grid, and memory follows the scene, not a
//! fixed domain. Node layout is `[z][y][x]` (x fastest), one `Vec4` `(mv_x, mv_y, mv_z, m)`
//! (after the grid update `(v_x, v_y, v_z, m)`) per node, so that a node update is one SIMD
//! multiply-add.
//!
//! # Determinism
//! Particles are kept sorted by 4×4×4-cell block (re-sorted at the start of every frame with a
//! stable sort) and processed in chunks of [`CHUNK`] particles: the chunk size is a constant, not
//! derived from the thread count. Each chunk scatters into its own small dense grid covering its
//! own stencils; the global grid is then assembled per z-layer by adding the chunk grids **in
//! chunk order**. No float atomics and no reduction whose order depends on scheduling: results are
//! bit-identical for any number of rayon threads.
//!
//! # Precision
//! Particle state is `f32` (like Taichi's default). The polar rotation is computed in `f64` by the
//! rotation extraction of Müller et al. 2016 ("A Robust Method to Extract the Rotational Part of
//! Deformations"), warm-started from the particle's previous rotation, which converges in one or
//! two iterations per substep; it always returns a proper rotation (det +1), also for inverted
//! `F`, where it maximises `tr(RᵀF)` like the rotation-variant SVD `U Vᵀ` does.

use glam::{DMat3, DQuat, DVec3, IVec3, Mat3, Quat, Vec3, Vec4};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Particles per work chunk. A fixed constant (never the thread count) so that the summation order
/// on the grid, hence every bit of the result, does not depend on how many threads run. 2048 is
/// large enough to amortise one small chunk grid per chunk and small enough to give a few chunks
/// per core for a 35 k-particle scene.
pub const CHUNK: usize = 2048;

/// Cells per block edge for the particle sort (particles of one block are contiguous in memory, so
/// a chunk's grid stays small).
const SORT_BLOCK_SHIFT: i32 = 2;

/// Polar rotation: stop when the incremental rotation angle is below this (radians). An error `δ` in
/// `R` changes τ by about `2μ·δ ≈ 3.6 Pa` at 1e-4, against the ~15 kPa a 10 cm glass of the paper's
/// density puts on its base (2e-4 relative), and the warm start means the error does not accumulate
/// (the fixture bodies still land within 5e-4 m of the Taichi engine's). Iterations per particle and
/// substep on the fixture: 4.6 at 1e-9, 1.8 at 1e-6; 1e-4 takes a further 20 % off the substep.
const POLAR_TOLERANCE: f64 = 1e-4;
/// Polar rotation: iteration cap (only reached for degenerate `F`, e.g. a collapsed particle).
const POLAR_MAX_ITERATIONS: usize = 40;

/// Volume assigned to each particle (mass = density × volume).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum ParticleVolume {
    /// `dx³` per particle, whatever the particle density: the authors' engine (`p_vol = dx³`).
    GridCell,
    /// A fixed volume in m³ per particle.
    Fixed(f32),
}

/// Boundary condition at the bottom of the scene.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum Ground {
    /// No ground: free space.
    None,
    /// Sticky plane `z = height`: grid nodes with `z < height` get velocity 0
    /// (taichi_elements `add_surface_collider(..., surface_sticky)`).
    Sticky { height: f32 },
}

/// Every parameter of the simulation; `Default` is TRAN-D's scene-update setting.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct MpmConfig {
    /// Grid spacing in metres (authors: `res = 48`, `size = 1` → 1/48 m).
    pub dx: f32,
    /// Young's modulus in Pa (authors: `1e6 · E_scale 0.05`).
    pub youngs_modulus: f32,
    /// Poisson's ratio.
    pub poisson_ratio: f32,
    /// Density in kg/m³ (authors changed taichi_elements' 1000 to 30000).
    pub density: f32,
    pub particle_volume: ParticleVolume,
    /// Gravity in m/s² (world z up).
    pub gravity: [f32; 3],
    pub ground: Ground,
    /// Seconds per frame (authors: `mpm.step(4e-3)`).
    pub frame_dt: f32,
    /// Substeps per frame (authors: `int(4e-3 / (2e-2·dx)) + 1 = 10`).
    pub substeps: u32,
    /// Number of frames the scene update runs (authors: 100, i.e. 0.4 s).
    pub frames: u32,
    /// Refuse more particles than this (authors' `max_num_particles = 2**21`).
    pub max_particles: usize,
    /// Refuse a grid with more nodes than this: only reached when particles fly apart (explosion)
    /// or the input spans a huge region. 2²⁶ nodes = 1 GiB of grid.
    pub max_grid_nodes: usize,
}

impl Default for MpmConfig {
    fn default() -> Self {
        Self {
            dx: 1.0 / 48.0,
            youngs_modulus: 5e4,
            poisson_ratio: 0.4,
            density: 30000.0,
            particle_volume: ParticleVolume::GridCell,
            gravity: [0.0, 0.0, -4.9],
            ground: Ground::Sticky { height: 0.0 },
            frame_dt: 4e-3,
            substeps: 10,
            frames: 100,
            max_particles: 1 << 21,
            max_grid_nodes: 1 << 26,
        }
    }
}

impl MpmConfig {
    /// Lamé parameters `(μ, λ) = (E / 2(1+ν), Eν / (1+ν)(1−2ν))`.
    pub fn lame(&self) -> (f32, f32) {
        let (e, nu) = (self.youngs_modulus, self.poisson_ratio);
        (
            e / (2.0 * (1.0 + nu)),
            e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu)),
        )
    }

    /// Volume of one particle in m³.
    pub fn particle_volume_m3(&self) -> f32 {
        match self.particle_volume {
            ParticleVolume::GridCell => self.dx * self.dx * self.dx,
            ParticleVolume::Fixed(v) => v,
        }
    }

    /// Substep length `frame_dt / substeps`.
    pub fn substep_dt(&self) -> f32 {
        self.frame_dt / self.substeps as f32
    }

    fn validate(&self) -> Result<(), MpmError> {
        let bad = |what: &str| Err(MpmError::InvalidConfig(what.to_string()));
        if !(self.dx.is_finite() && self.dx > 0.0) {
            return bad("dx must be finite and positive");
        }
        if !(self.youngs_modulus.is_finite() && self.youngs_modulus >= 0.0) {
            return bad("Young's modulus must be finite and non-negative");
        }
        if !(self.poisson_ratio > -1.0 && self.poisson_ratio < 0.5) {
            return bad("Poisson's ratio must lie in (-1, 0.5)");
        }
        if !(self.density.is_finite() && self.density > 0.0) {
            return bad("density must be finite and positive");
        }
        let vol = self.particle_volume_m3();
        if !(vol.is_finite() && vol > 0.0) {
            return bad("particle volume must be finite and positive");
        }
        if !(self.frame_dt.is_finite() && self.frame_dt > 0.0 && self.substeps > 0) {
            return bad("frame_dt must be positive and substeps at least 1");
        }
        if self.gravity.iter().any(|g| !g.is_finite()) {
            return bad("gravity must be finite");
        }
        if matches!(self.ground, Ground::Sticky { height } if !height.is_finite()) {
            return bad("ground height must be finite");
        }
        Ok(())
    }
}

/// Why the solver cannot be built or cannot go on.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum MpmError {
    #[error("{count} particles exceed the configured maximum of {max}")]
    TooManyParticles { count: usize, max: usize },
    #[error("particle {index} has a non-finite position {position:?}")]
    NonFinitePosition { index: usize, position: [f32; 3] },
    #[error("invalid MPM config: {0}")]
    InvalidConfig(String),
    #[error(
        "the grid around the particles needs {nodes} nodes (max {max}): the particles span too large a region (exploded?)"
    )]
    GridTooLarge { nodes: usize, max: usize },
    #[error(
        "particle {index} left the finite numbers (the simulation diverged; try smaller substeps)"
    )]
    Diverged { index: usize },
}

/// One material point (array-of-structs: every field is used by both transfers).
#[derive(Clone, Copy, Debug)]
struct Particle {
    x: Vec3,
    v: Vec3,
    /// APIC affine velocity matrix (≈ ∇v).
    c: Mat3,
    /// Deformation gradient.
    f: Mat3,
    /// Polar rotation of `f` (also the warm start of the next extraction).
    rot: DQuat,
    /// Index in the caller's input order.
    id: u32,
}

/// A chunk's private scatter target: a dense grid over the chunk's stencils, and the per-particle
/// affine matrices computed in the first pass over the chunk.
#[derive(Default)]
struct ChunkGrid {
    lo: IVec3,
    dims: IVec3,
    /// Nodes this chunk's stencils would span when that exceeds the limit (nothing scattered).
    too_large: Option<usize>,
    nodes: Vec<Vec4>,
    affine: Vec<Mat3>,
}

/// Constants of one substep.
#[derive(Clone, Copy)]
struct StepParams {
    dt: f32,
    dx: f32,
    inv_dx: f32,
    p_mass: f32,
    /// `−Δt V_p 4/dx²`, the factor turning τ into the grid momentum impulse.
    stress_scale: f64,
    mu: f64,
    lambda: f64,
    gravity: Vec3,
    ground: Ground,
    max_grid_nodes: usize,
}

/// MLS-MPM solver over one set of particles (all objects share the grid, so they collide).
pub struct MpmSolver {
    config: MpmConfig,
    particles: Vec<Particle>,
    chunks: Vec<ChunkGrid>,
    grid: Vec<Vec4>,
    grid_lo: IVec3,
    grid_dims: IVec3,
    frames_done: u32,
}

impl MpmSolver {
    /// Particles at rest (`v = 0`, `C = 0`, `F = I`, `R = I`).
    pub fn new(config: MpmConfig, positions: &[[f32; 3]]) -> Result<Self, MpmError> {
        config.validate()?;
        if positions.len() > config.max_particles || positions.len() > u32::MAX as usize {
            return Err(MpmError::TooManyParticles {
                count: positions.len(),
                max: config.max_particles,
            });
        }
        if let Some(index) = positions
            .iter()
            .position(|p| p.iter().any(|c| !c.is_finite()))
        {
            return Err(MpmError::NonFinitePosition {
                index,
                position: positions[index],
            });
        }
        let particles = positions
            .iter()
            .enumerate()
            .map(|(i, p)| Particle {
                x: Vec3::from_array(*p),
                v: Vec3::ZERO,
                c: Mat3::ZERO,
                f: Mat3::IDENTITY,
                rot: DQuat::IDENTITY,
                id: i as u32,
            })
            .collect();
        Ok(Self {
            config,
            particles,
            chunks: Vec::new(),
            grid: Vec::new(),
            grid_lo: IVec3::ZERO,
            grid_dims: IVec3::ZERO,
            frames_done: 0,
        })
    }

    pub fn config(&self) -> &MpmConfig {
        &self.config
    }

    pub fn num_particles(&self) -> usize {
        self.particles.len()
    }

    /// Frames simulated so far.
    pub fn frames_done(&self) -> u32 {
        self.frames_done
    }

    /// Positions in the input order.
    pub fn positions(&self) -> Vec<[f32; 3]> {
        self.gather(|p| p.x.to_array())
    }

    /// Velocities in the input order.
    pub fn velocities(&self) -> Vec<[f32; 3]> {
        self.gather(|p| p.v.to_array())
    }

    /// Polar rotation of each particle's deformation gradient (`F = R S`), in the input order: the
    /// local rotation a surfel carried by the particle has undergone.
    pub fn rotations(&self) -> Vec<Quat> {
        self.gather(|p| p.rot.as_quat())
    }

    /// Deformation gradients in the input order.
    pub fn deformation_gradients(&self) -> Vec<Mat3> {
        self.gather(|p| p.f)
    }

    fn gather<T: Copy + Default + Send>(&self, f: impl Fn(&Particle) -> T + Sync) -> Vec<T> {
        let mut out = vec![T::default(); self.particles.len()];
        for p in &self.particles {
            out[p.id as usize] = f(p);
        }
        out
    }

    /// Simulates `frames` frames, calling `progress(done, frames)` after each.
    pub fn run(&mut self, frames: u32, mut progress: impl FnMut(u32, u32)) -> Result<(), MpmError> {
        for i in 0..frames {
            self.step_frame()?;
            progress(i + 1, frames);
        }
        Ok(())
    }

    /// One frame: re-sort the particles by block, then `substeps` substeps.
    pub fn step_frame(&mut self) -> Result<(), MpmError> {
        self.sort_particles();
        for _ in 0..self.config.substeps {
            self.substep()?;
        }
        self.frames_done += 1;
        Ok(())
    }

    /// Stable sort by 4×4×4-cell block (z, y, x): keeps each chunk spatially compact.
    fn sort_particles(&mut self) {
        let inv_dx = 1.0 / self.config.dx;
        self.particles.par_sort_by_key(|p| {
            let b = floor_i32(p.x * inv_dx) >> SORT_BLOCK_SHIFT;
            (b.z, b.y, b.x)
        });
    }

    fn params(&self) -> StepParams {
        let c = &self.config;
        let dt = c.substep_dt();
        let p_vol = c.particle_volume_m3();
        let (mu, lambda) = c.lame();
        StepParams {
            dt,
            dx: c.dx,
            inv_dx: 1.0 / c.dx,
            p_mass: c.density * p_vol,
            stress_scale: -(dt as f64) * p_vol as f64 * 4.0 / (c.dx as f64 * c.dx as f64),
            mu: mu as f64,
            lambda: lambda as f64,
            gravity: Vec3::from_array(c.gravity),
            ground: c.ground,
            max_grid_nodes: c.max_grid_nodes,
        }
    }

    /// One MLS-MPM substep: P2G per chunk, assemble the grid, grid update, G2P.
    pub fn substep(&mut self) -> Result<(), MpmError> {
        if self.particles.is_empty() {
            return Ok(());
        }
        let sp = self.params();
        let n_chunks = self.particles.len().div_ceil(CHUNK);
        self.chunks.resize_with(n_chunks, ChunkGrid::default);

        // 1. P2G into per-chunk grids.
        self.particles
            .par_chunks_mut(CHUNK)
            .zip(self.chunks.par_iter_mut())
            .for_each(|(ps, cg)| p2g_chunk(ps, cg, &sp));
        if let Some(nodes) = self.chunks.iter().find_map(|c| c.too_large) {
            return Err(MpmError::GridTooLarge {
                nodes,
                max: self.config.max_grid_nodes,
            });
        }

        // Global grid = union of the chunk grids.
        let lo = self.chunks.iter().map(|c| c.lo).reduce(IVec3::min).unwrap();
        let hi = self
            .chunks
            .iter()
            .map(|c| c.lo + c.dims)
            .reduce(IVec3::max)
            .unwrap();
        let nodes = grid_nodes(lo, hi, 0);
        if nodes > self.config.max_grid_nodes {
            return Err(MpmError::GridTooLarge {
                nodes,
                max: self.config.max_grid_nodes,
            });
        }
        let dims = hi - lo;
        self.grid.resize(nodes, Vec4::ZERO);
        (self.grid_lo, self.grid_dims) = (lo, dims);
        let layer = (dims.x * dims.y) as usize;
        let chunks = &self.chunks;

        // 2. Assemble (chunk order fixed) and update the grid, one z-layer per task.
        self.grid
            .par_chunks_mut(layer)
            .enumerate()
            .for_each(|(z, nodes)| {
                let gz = lo.z + z as i32;
                nodes.fill(Vec4::ZERO);
                for cg in chunks {
                    add_chunk_layer(nodes, lo, dims, gz, cg);
                }
                grid_update_layer(nodes, gz, &sp);
            });

        // 3. G2P.
        let (grid, grid_lo) = (&self.grid, self.grid_lo);
        let diverged: Option<u32> = self
            .particles
            .par_chunks_mut(CHUNK)
            .map(|ps| g2p_chunk(ps, grid, grid_lo, dims, &sp))
            .reduce(|| None, Option::or);
        match diverged {
            Some(id) => Err(MpmError::Diverged { index: id as usize }),
            None => Ok(()),
        }
    }
}

/// Quadratic B-spline weights of the three nodes `b, b+1, b+2` for fractional offsets `f`.
#[inline(always)]
fn bspline_weights(f: Vec3) -> [Vec3; 3] {
    let a = Vec3::splat(1.5) - f;
    let b = f - Vec3::ONE;
    let c = f - Vec3::splat(0.5);
    [0.5 * a * a, Vec3::splat(0.75) - b * b, 0.5 * c * c]
}

/// Base node `⌊x/dx − ½⌋` and fractional offset `x/dx − base`.
#[inline(always)]
fn stencil(x: Vec3, inv_dx: f32) -> (IVec3, Vec3) {
    let xg = x * inv_dx;
    let base = floor_i32(xg - Vec3::splat(0.5));
    (base, xg - base.as_vec3())
}

/// `⌊v⌋` per component without a libm call (`floorf` is not inlined on the baseline x86-64 target,
/// and it was 7 % of the substep). Exact for |v| < 2³¹; beyond, the conversion saturates and so does
/// the subtraction (the grid-size check then refuses the region).
#[inline(always)]
fn floor_i32(v: Vec3) -> IVec3 {
    let t = v.as_ivec3(); // truncation towards zero
    t.saturating_sub(IVec3::select(t.as_vec3().cmpgt(v), IVec3::ONE, IVec3::ZERO))
}

/// P2G for one chunk: deformation update, stress, then scatter into the chunk's own grid.
#[allow(clippy::needless_range_loop)] // i, j, k are node offsets as well as weight indices
fn p2g_chunk(ps: &mut [Particle], cg: &mut ChunkGrid, sp: &StepParams) {
    let (mut lo, mut hi) = (IVec3::MAX, IVec3::MIN);
    cg.affine.clear();
    for p in ps.iter_mut() {
        let (base, _) = stencil(p.x, sp.inv_dx);
        (lo, hi) = (lo.min(base), hi.max(base));
        p.f = (Mat3::IDENTITY + sp.dt * p.c) * p.f;
        let f = p.f.as_dmat3();
        let r;
        (p.rot, r) = polar_rotation_and_matrix(f, p.rot);
        let j = f.determinant();
        // Fixed-corotated Kirchhoff stress τ = 2μ(F − R)Fᵀ + λJ(J−1)I.
        let tau = 2.0 * sp.mu * (f - r) * f.transpose()
            + DMat3::from_diagonal(DVec3::splat(sp.lambda * j * (j - 1.0)));
        cg.affine
            .push((tau * sp.stress_scale).as_mat3() + sp.p_mass * p.c);
    }
    // Checked in i64 before anything is allocated: a particle flung far away (or a NaN, which
    // floors to 0 next to huge coordinates) must give an error, not an abort.
    let nodes = grid_nodes(lo, hi, 3);
    if nodes > sp.max_grid_nodes {
        cg.too_large = Some(nodes);
        return;
    }
    cg.too_large = None;
    cg.lo = lo;
    cg.dims = hi - lo + IVec3::splat(3);
    let (nx, ny) = (cg.dims.x as usize, cg.dims.y as usize);
    cg.nodes.clear();
    cg.nodes.resize(nx * ny * cg.dims.z as usize, Vec4::ZERO);
    for (p, a) in ps.iter().zip(&cg.affine) {
        let (base, fx) = stencil(p.x, sp.inv_dx);
        let w = bspline_weights(fx);
        // Momentum sent to node b + o: m v + A (o − f) dx, built incrementally along each axis.
        // (momentum, mass) as one Vec4; the affine columns carry no mass (w = 0).
        let m0 = (sp.p_mass * p.v - *a * (fx * sp.dx)).extend(sp.p_mass);
        let (ax, ay, az) = (
            (a.x_axis * sp.dx).extend(0.0),
            (a.y_axis * sp.dx).extend(0.0),
            (a.z_axis * sp.dx).extend(0.0),
        );
        let o = (base - lo).as_uvec3();
        for k in 0..3 {
            let mk = m0 + az * k as f32;
            for j in 0..3 {
                let mjk = mk + ay * j as f32;
                let wjk = w[j].y * w[k].z;
                let row = ((o.z as usize + k) * ny + o.y as usize + j) * nx + o.x as usize;
                let nodes: &mut [Vec4; 3] = (&mut cg.nodes[row..row + 3]).try_into().unwrap();
                for i in 0..3 {
                    nodes[i] += (w[i].x * wjk) * (mjk + ax * i as f32);
                }
            }
        }
    }
}

/// Nodes of the box `[lo, hi + pad)`, computed in `i64` (no overflow for any `i32` corners).
fn grid_nodes(lo: IVec3, hi: IVec3, pad: i64) -> usize {
    let d = (hi.as_i64vec3() - lo.as_i64vec3() + pad).max(glam::I64Vec3::ZERO);
    d.x.saturating_mul(d.y).saturating_mul(d.z) as usize
}

/// Adds the part of one chunk grid that lies in global layer `gz`.
fn add_chunk_layer(layer: &mut [Vec4], lo: IVec3, dims: IVec3, gz: i32, cg: &ChunkGrid) {
    let lz = gz - cg.lo.z;
    if lz < 0 || lz >= cg.dims.z {
        return;
    }
    let (cnx, cny) = (cg.dims.x as usize, cg.dims.y as usize);
    let off = cg.lo - lo;
    for y in 0..cny {
        let src = &cg.nodes[(lz as usize * cny + y) * cnx..][..cnx];
        let dst_start = (off.y as usize + y) * dims.x as usize + off.x as usize;
        for (d, s) in layer[dst_start..dst_start + cnx].iter_mut().zip(src) {
            *d += *s;
        }
    }
}

/// Grid update of one z-layer: momentum → velocity, gravity, sticky ground.
fn grid_update_layer(layer: &mut [Vec4], gz: i32, sp: &StepParams) {
    let below_ground = match sp.ground {
        Ground::Sticky { height } => (gz as f32) * sp.dx < height,
        Ground::None => false,
    };
    let dv = (sp.dt * sp.gravity).extend(0.0);
    for n in layer.iter_mut() {
        if n.w > 0.0 {
            let v = if below_ground {
                Vec4::ZERO
            } else {
                *n / n.w + dv
            };
            *n = v.truncate().extend(n.w);
        }
    }
}

/// G2P for one chunk: gather velocity and APIC matrix, advect. Returns the input index of the
/// first particle whose new position is not finite, if any.
#[allow(clippy::needless_range_loop)] // i, j, k are node offsets as well as weight indices
fn g2p_chunk(
    ps: &mut [Particle],
    grid: &[Vec4],
    lo: IVec3,
    dims: IVec3,
    sp: &StepParams,
) -> Option<u32> {
    let mut diverged = None;
    let (nx, ny) = (dims.x as usize, dims.y as usize);
    for p in ps.iter_mut() {
        let (base, fx) = stencil(p.x, sp.inv_dx);
        let w = bspline_weights(fx);
        let o = (base - lo).as_uvec3();
        // Vec4 accumulators (w carries the node mass along, unused) for SIMD.
        let (mut v, mut cx, mut cy, mut cz) = (Vec4::ZERO, Vec4::ZERO, Vec4::ZERO, Vec4::ZERO);
        for k in 0..3 {
            let dz = k as f32 - fx.z;
            for j in 0..3 {
                let dy = j as f32 - fx.y;
                let wjk = w[j].y * w[k].z;
                let row = ((o.z as usize + k) * ny + o.y as usize + j) * nx + o.x as usize;
                let nodes: &[Vec4; 3] = grid[row..row + 3].try_into().unwrap();
                for i in 0..3 {
                    let wv = (w[i].x * wjk) * nodes[i];
                    v += wv;
                    cx += wv * (i as f32 - fx.x);
                    cy += wv * dy;
                    cz += wv * dz;
                }
            }
        }
        p.v = v.truncate();
        p.c = (4.0 * sp.inv_dx) * Mat3::from_cols(cx.truncate(), cy.truncate(), cz.truncate());
        p.x += sp.dt * p.v;
        if diverged.is_none() && !p.x.is_finite() {
            diverged = Some(p.id);
        }
    }
    diverged
}

/// Rotation part `R` of `F = R S` (Müller et al. 2016): gradient ascent of `tr(RᵀF)` on the
/// rotation quaternion, `ω = Σᵢ rᵢ × fᵢ / (|Σᵢ rᵢ · fᵢ| + 10⁻⁹)` over the columns, `q ← exp(ω) q`,
/// starting from `warm`. Returns a unit quaternion (a proper rotation, also for `det F ≤ 0`).
pub fn polar_rotation(f: DMat3, warm: DQuat) -> DQuat {
    polar_rotation_and_matrix(f, warm).0
}

/// [`polar_rotation`] and its matrix (the last iteration's, so it is not computed twice).
fn polar_rotation_and_matrix(f: DMat3, warm: DQuat) -> (DQuat, DMat3) {
    let mut q = warm;
    for _ in 0..POLAR_MAX_ITERATIONS {
        let r = DMat3::from_quat(q);
        let num = r.x_axis.cross(f.x_axis) + r.y_axis.cross(f.y_axis) + r.z_axis.cross(f.z_axis);
        let den =
            (r.x_axis.dot(f.x_axis) + r.y_axis.dot(f.y_axis) + r.z_axis.dot(f.z_axis)).abs() + 1e-9;
        let omega = num / den;
        let angle = omega.length();
        if angle.is_nan() || angle < POLAR_TOLERANCE {
            return (q, r);
        }
        // exp(ω) to first order, (ω/2, 1) normalised: the same fixed point (ω = 0) without a sincos,
        // and a shorter, still ascending, step when ω is large.
        let half = 0.5 * omega;
        q = (DQuat::from_xyzw(half.x, half.y, half.z, 1.0) * q).normalize();
    }
    (q, DMat3::from_quat(q))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Polar rotation by Higham's Newton iteration `R ← ½(R + R⁻ᵀ)` (valid for det F > 0).
    fn newton_polar(f: DMat3) -> DMat3 {
        let mut r = f;
        for _ in 0..100 {
            r = 0.5 * (r + r.inverse().transpose());
        }
        r
    }

    /// Deterministic pseudo-random numbers in [-1, 1] (no rand dependency in unit tests).
    fn lcg(state: &mut u64) -> f64 {
        *state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((*state >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    }

    #[test]
    fn polar_rotation_matches_newton_polar_decomposition() {
        let mut s = 7u64;
        for _ in 0..500 {
            let axis = DVec3::new(lcg(&mut s), lcg(&mut s), lcg(&mut s)).normalize();
            let rot = DMat3::from_axis_angle(axis, 3.0 * lcg(&mut s));
            let sym = {
                let a = DMat3::from_cols_array(&std::array::from_fn(|_| 0.3 * lcg(&mut s)));
                DMat3::IDENTITY + 0.5 * (a + a.transpose())
            };
            let f = rot * sym;
            if f.determinant() <= 0.05 {
                continue;
            }
            let r = DMat3::from_quat(polar_rotation(f, DQuat::IDENTITY));
            let e = (r - newton_polar(f))
                .to_cols_array()
                .iter()
                .fold(0.0f64, |m, v| m.max(v.abs()));
            assert!(e < 2.0 * POLAR_TOLERANCE, "error {e}");
        }
    }

    #[test]
    fn polar_rotation_of_inverted_f_is_a_proper_rotation() {
        let f = DMat3::from_diagonal(DVec3::new(1.0, 0.9, -0.2)) * DMat3::from_rotation_x(0.3);
        let r = DMat3::from_quat(polar_rotation(f, DQuat::IDENTITY));
        assert!((r.determinant() - 1.0).abs() < 1e-9);
        // Maximises tr(RᵀF): no other rotation near it does better.
        let score = |r: DMat3| {
            (r.transpose() * f)
                .to_cols_array()
                .iter()
                .step_by(4)
                .sum::<f64>()
        };
        for axis in [DVec3::X, DVec3::Y, DVec3::Z] {
            for a in [-0.05, 0.05] {
                assert!(score(DMat3::from_axis_angle(axis, a) * r) <= score(r) + 1e-12);
            }
        }
    }

    #[test]
    fn bspline_weights_sum_to_one_and_reproduce_position() {
        for f in [0.5f32, 0.7, 1.0, 1.3, 1.49] {
            let w = bspline_weights(Vec3::splat(f));
            let sum: f32 = w.iter().map(|w| w.x).sum();
            let first_moment: f32 = w.iter().enumerate().map(|(i, w)| w.x * i as f32).sum();
            assert!((sum - 1.0).abs() < 1e-6 && (first_moment - f).abs() < 1e-6);
        }
    }

    #[test]
    fn default_config_is_the_papers() {
        let c = MpmConfig::default();
        let (mu, la) = c.lame();
        assert!((mu - 17857.14).abs() < 0.1 && (la - 71428.57).abs() < 0.1);
        assert!((c.density * c.particle_volume_m3() - 0.27127).abs() < 1e-4);
        assert!((c.substep_dt() - 4e-4).abs() < 1e-10);
    }

    #[test]
    fn particles_spanning_too_large_a_region_give_an_error_not_an_abort() {
        let far = [[0.0, 0.0, 0.0], [1e9, -1e9, 3e9]];
        let mut solver = MpmSolver::new(MpmConfig::default(), &far).unwrap();
        assert!(matches!(
            solver.step_frame(),
            Err(MpmError::GridTooLarge { .. })
        ));
    }

    #[test]
    fn nan_position_is_rejected_with_its_index() {
        let e = MpmSolver::new(MpmConfig::default(), &[[0.0; 3], [0.0, f32::NAN, 0.0]])
            .err()
            .unwrap();
        assert!(matches!(e, MpmError::NonFinitePosition { index: 1, .. }));
        let cfg = MpmConfig {
            max_particles: 1,
            ..Default::default()
        };
        let e = MpmSolver::new(cfg, &[[0.0; 3], [0.0; 3]]).err().unwrap();
        assert_eq!(e, MpmError::TooManyParticles { count: 2, max: 1 });
    }
}
