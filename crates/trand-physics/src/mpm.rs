//! MLS-MPM (Hu et al. 2018, "A Moving Least Squares Material Point Method") with fixed-corotated
//! elasticity and a sticky ground: the engine of TRAN-D's scene update (the authors run the
//! taichi_elements `mpm_solver.py`; the settings are its defaults for that step, see [`MpmConfig`]).
//!
//! # One substep
//! With `dx` the grid spacing, nodes at integer multiples of `dx` in world coordinates, and for each
//! particle `p` the base node `b = ⌊x/dx − ½⌋` and fractional offset `f = x/dx − b ∈ [½, 3/2)³`:
//! 1. **Material** (`material`): `F ← (I + Δt C) F`; the polar rotation `R` of `F` and `J = det F`
//!    give the fixed-corotated Kirchhoff stress `τ = 2μ(F − R)Fᵀ + λJ(J − 1)I` and the MLS affine
//!    matrix `A = −Δt V_p (4/dx²) τ + m_p C` (APIC momentum plus the stress impulse, eq. 18 of the
//!    paper).
//! 2. **P2G** (`stencil::scatter`): with the quadratic B-spline weights
//!    `w_i = ½(3/2 − f)², ¾ − (f − 1)², ½(f − ½)²` (per axis, product over axes) every one of the
//!    3×3×3 nodes `b + o` receives `m_I += w m_p` and `(mv)_I += w (m_p v_p + A (o − f) dx)`.
//! 3. **Grid** (`grid::update_layer`): `v_I = (mv)_I / m_I + Δt g`; nodes below the ground
//!    (`z_I < z_ground`) are sticky: `v_I = 0`.
//! 4. **G2P** (`stencil::gather`): `v_p = Σ w v_I`, `C_p = (4/dx) Σ w v_I ⊗ (o − f)`,
//!    `x_p += Δt v_p`.
//!
//! Steps 4, 1 and 2 of consecutive substeps of a frame run as one sweep over each chunk of particles
//! (`transfer`); a frame is: sort, steps 1–2, then per substep 3 and 4 (+ 1–2 but for the last).
//!
//! # Layout
//! Particles are stored in packs of four with every field one SIMD vector across the pack
//! (`store`): the material update runs on four particles per instruction, the transfers one lane at
//! a time through a local window of the 27 nodes that stays put while consecutive particles share a
//! base node (`stencil`). The grid is dense over the bounding box of the particles' stencils,
//! recomputed every substep, so world coordinates are used directly, like the authors' unbounded
//! sparse grid, and memory follows the scene, not a fixed domain (a block-sparse grid would save
//! little: TRAN-D's particles are dense, tens to hundreds per cell, so the grid is small beside
//! them; BENCHMARKS.md §6). Node layout is `[z][y][x]` (x fastest), one `Vec4`
//! `(mv_x, mv_y, mv_z, m)` (after the grid update `(v_x, v_y, v_z, m)`) per node, so that a node
//! update is one SIMD multiply-add.
//!
//! # Determinism
//! Particles are re-sorted at the start of every frame by the 4×4×4-node block of their base node,
//! then by the node (a stable sort) and processed in chunks of [`CHUNK`] particles: the chunk size
//! is a constant, not derived from the thread count. Each chunk scatters into its own small dense
//! grid covering its own stencils; the global grid is then assembled per z-layer by adding the
//! chunk grids **in chunk order**. No float atomics and no reduction whose order depends on
//! scheduling: results are bit-identical for any number of rayon threads.
//!
//! # Precision
//! Particle state is `f32` (like Taichi's default), and so is the material update, the polar
//! rotation included (`material` bounds the error).
//!
//! # Stopping at rest
//! [`StopAtRest`] ends [`MpmSolver::run`] early once the largest particle speed has stayed below a
//! threshold for some frames ([`StopAtRest::TRAN_D`] explains the default). With TRAN-D's material
//! it does not fire in practice: the material is soft for its density (`ρgh/E ≈ 0.35` for a 12 cm
//! object), so every body, resting ones included, sags under its own weight and oscillates without
//! damping; it ends the runs of stiffer materials and of scenes where nothing moves.

mod config;
mod grid;
mod material;
mod stencil;
mod store;
mod transfer;

use glam::{IVec3, Mat3, Quat, Vec4};
use rayon::prelude::*;

use config::StepParams;
pub use config::{Ground, MpmConfig, MpmError, ParticleVolume, StopAtRest};
use grid::GridView;
pub use material::polar_rotation;
use store::{LANES, Pack};
use transfer::{ChunkGrid, ChunkMotion, ParticlePass};

/// Particles per work chunk. A fixed constant (never the thread count) so that the summation order
/// on the grid, hence every bit of the result, does not depend on how many threads run. 2048 is
/// large enough to amortise one small chunk grid per chunk and small enough to give a few chunks
/// per core for a 35 k-particle scene.
pub const CHUNK: usize = 2048;
const CHUNK_PACKS: usize = CHUNK / LANES;

/// Cells per block edge for the particle sort (particles of one block are contiguous in memory, so
/// a chunk's grid stays small).
const SORT_BLOCK_SHIFT: i32 = 2;

/// MLS-MPM solver over one set of particles (all objects share the grid, so they collide).
pub struct MpmSolver {
    config: MpmConfig,
    packs: Vec<Pack>,
    num_particles: usize,
    chunks: Vec<ChunkGrid>,
    grid: Vec<Vec4>,
    frames_done: u32,
    /// Largest particle speed at the end of the last substep (m/s).
    max_speed: f32,
    /// Consecutive frames, up to the last one, that ended with every particle slower than
    /// [`StopAtRest::Below`]'s speed.
    frames_at_rest: u32,
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
        Ok(Self {
            config,
            packs: store::packs_at_rest(positions),
            num_particles: positions.len(),
            chunks: Vec::new(),
            grid: Vec::new(),
            frames_done: 0,
            max_speed: 0.0,
            frames_at_rest: 0,
        })
    }

    pub fn config(&self) -> &MpmConfig {
        &self.config
    }

    pub fn num_particles(&self) -> usize {
        self.num_particles
    }

    /// Frames simulated so far.
    pub fn frames_done(&self) -> u32 {
        self.frames_done
    }

    /// The largest particle speed (m/s) after the last substep (0 before the first).
    pub fn max_speed(&self) -> f32 {
        self.max_speed
    }

    /// Whether the configured [`StopAtRest`] criterion holds after the last frame: every particle
    /// has been slower than its speed at the end of its number of consecutive frames.
    pub fn at_rest(&self) -> bool {
        match self.config.stop_at_rest {
            StopAtRest::Never => false,
            StopAtRest::Below { frames, .. } => self.frames_at_rest >= frames,
        }
    }

    /// Positions in the input order.
    pub fn positions(&self) -> Vec<[f32; 3]> {
        self.gather(|p, l| p.x(l).to_array())
    }

    /// Velocities in the input order.
    pub fn velocities(&self) -> Vec<[f32; 3]> {
        self.gather(|p, l| p.v(l).to_array())
    }

    /// Polar rotation of each particle's deformation gradient (`F = R S`), in the input order: the
    /// local rotation a surfel carried by the particle has undergone.
    pub fn rotations(&self) -> Vec<Quat> {
        self.gather(Pack::rot)
    }

    /// Deformation gradients in the input order.
    pub fn deformation_gradients(&self) -> Vec<Mat3> {
        self.gather(Pack::f)
    }

    fn gather<T: Copy + Default>(&self, f: impl Fn(&Pack, usize) -> T) -> Vec<T> {
        let mut out = vec![T::default(); self.num_particles];
        for p in &self.packs {
            for l in 0..p.live {
                out[p.id[l] as usize] = f(p, l);
            }
        }
        out
    }

    /// Simulates up to `frames` frames, calling `progress(done, frames)` after each, and stopping
    /// early when the configured [`StopAtRest`] criterion holds ([`Self::at_rest`]). Returns the
    /// number of frames simulated.
    pub fn run(
        &mut self,
        frames: u32,
        mut progress: impl FnMut(u32, u32),
    ) -> Result<u32, MpmError> {
        for i in 0..frames {
            self.step_frame()?;
            progress(i + 1, frames);
            if self.at_rest() {
                return Ok(i + 1);
            }
        }
        Ok(frames)
    }

    /// One frame: re-sort the particles, then `substeps` substeps (G2P of each fused with the
    /// material update and P2G of the next).
    pub fn step_frame(&mut self) -> Result<(), MpmError> {
        self.sort_particles();
        let sp = self.config.step_params();
        self.particle_pass(ParticlePass::Scatter, &sp);
        for s in 1..=self.config.substeps {
            let next = if s < self.config.substeps {
                Substeps::More
            } else {
                Substeps::Done
            };
            self.finish_substep(&sp, next)?;
        }
        self.frames_done += 1;
        self.frames_at_rest = match self.config.stop_at_rest {
            StopAtRest::Below { speed, .. } if self.max_speed < speed => self.frames_at_rest + 1,
            _ => 0,
        };
        Ok(())
    }

    /// One MLS-MPM substep on its own (P2G, grid, G2P), exactly as within [`Self::step_frame`].
    pub fn substep(&mut self) -> Result<(), MpmError> {
        let sp = self.config.step_params();
        self.particle_pass(ParticlePass::Scatter, &sp);
        self.finish_substep(&sp, Substeps::Done)
    }

    /// Sort by 4×4×4-node block (z, y, x), then by node within the block, of the particles' base
    /// nodes: each chunk stays spatially compact, and particles sharing a stencil are adjacent.
    fn sort_particles(&mut self) {
        let inv_dx = 1.0 / self.config.dx;
        store::sort_packs(&mut self.packs, |p: &Pack| {
            let st = stencil::PackStencil::new(&p.x, inv_dx);
            std::array::from_fn(|l| sort_key(st.base(l)))
        });
    }

    /// Runs `pass` over every chunk (in parallel) and returns what G2P found (in chunk order).
    fn particle_pass(&mut self, pass: ParticlePass, sp: &StepParams) -> ChunkMotion {
        let n_chunks = self.packs.len().div_ceil(CHUNK_PACKS);
        self.chunks.resize_with(n_chunks, ChunkGrid::default);
        self.packs
            .par_chunks_mut(CHUNK_PACKS)
            .zip(self.chunks.par_iter_mut())
            .map(|(ps, cg)| transfer::particle_pass(ps, cg, pass, sp))
            .reduce(ChunkMotion::default, ChunkMotion::merge)
    }

    /// The rest of a substep whose P2G is done: the grid, and G2P (with the material update and
    /// P2G of the next substep when `next` says there is one).
    fn finish_substep(&mut self, sp: &StepParams, next: Substeps) -> Result<(), MpmError> {
        if self.packs.is_empty() {
            return Ok(());
        }
        if let Some(nodes) = self.chunks.iter().find_map(|c| c.too_large) {
            return Err(MpmError::GridTooLarge {
                nodes,
                max: self.config.max_grid_nodes,
            });
        }
        let (lo, dims) = self.assemble_grid(sp)?;
        let grid = std::mem::take(&mut self.grid);
        let view = GridView {
            nodes: &grid,
            lo,
            dims,
        };
        let pass = match next {
            Substeps::More => ParticlePass::GatherThenScatter(view),
            Substeps::Done => ParticlePass::Gather(view),
        };
        let motion = self.particle_pass(pass, sp);
        self.grid = grid;
        self.max_speed = motion.max_speed2.sqrt();
        match motion.diverged {
            Some(id) => Err(MpmError::Diverged { index: id as usize }),
            None => Ok(()),
        }
    }

    /// The global grid = the union of the chunk grids, summed in chunk order, then updated; one
    /// z-layer per task. Returns its box.
    fn assemble_grid(&mut self, sp: &StepParams) -> Result<(IVec3, IVec3), MpmError> {
        let lo = self.chunks.iter().map(|c| c.lo).reduce(IVec3::min).unwrap();
        let hi = self
            .chunks
            .iter()
            .map(|c| c.lo + c.dims)
            .reduce(IVec3::max)
            .unwrap();
        let nodes = grid::grid_nodes(lo, hi, 0);
        if nodes > self.config.max_grid_nodes {
            return Err(MpmError::GridTooLarge {
                nodes,
                max: self.config.max_grid_nodes,
            });
        }
        let dims = hi - lo;
        self.grid.resize(nodes, Vec4::ZERO);
        let layer = (dims.x * dims.y) as usize;
        let chunks = &self.chunks;
        self.grid
            .par_chunks_mut(layer)
            .enumerate()
            .for_each(|(z, nodes)| {
                let gz = lo.z + z as i32;
                nodes.fill(Vec4::ZERO);
                for cg in chunks {
                    grid::add_layer(nodes, lo, dims, gz, cg.view());
                }
                grid::update_layer(nodes, gz, sp);
            });
        Ok((lo, dims))
    }
}

/// Whether a substep is followed by another in the same frame.
#[derive(Clone, Copy)]
enum Substeps {
    More,
    Done,
}

/// Sort key of a base node: its 4×4×4 block (z, y, x; 18 bits each, clamped, so the order is
/// exact within ±2¹⁷ blocks, i.e. ±11 km at TRAN-D's dx), then the node within the block.
fn sort_key(b: IVec3) -> u64 {
    let block = |c: i32| ((c >> SORT_BLOCK_SHIFT) + (1 << 17)).clamp(0, (1 << 18) - 1) as u64;
    let cell = |c: i32| (c & ((1 << SORT_BLOCK_SHIFT) - 1)) as u64;
    (block(b.z) << 42)
        | (block(b.y) << 24)
        | (block(b.x) << 6)
        | (cell(b.z) << 4)
        | (cell(b.y) << 2)
        | cell(b.x)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two blocks on a lattice of spacing `h`, one above the other: more than two chunks, a free
    /// lane in the last pack, contact.
    fn two_blocks(h: f32) -> Vec<[f32; 3]> {
        let mut out = Vec::new();
        for (lo, n) in [
            ([0.40f32, 0.40, 0.0], [20, 20, 10]),
            ([0.45, 0.44, 0.1], [9, 9, 5]),
        ] {
            for k in 0..n[2] {
                for j in 0..n[1] {
                    for i in 0..n[0] {
                        let o = [i, j, k].map(|c| (c as f32 + 0.5) * h);
                        out.push([lo[0] + o[0], lo[1] + o[1], lo[2] + o[2]]);
                    }
                }
            }
        }
        out.push([0.5, 0.5, 0.2]);
        out
    }

    #[test]
    fn a_frame_is_its_substeps_one_by_one_bit_for_bit() {
        let x = two_blocks(1.0 / 144.0);
        assert!(x.len() > 2 * CHUNK && !x.len().is_multiple_of(LANES));
        let mut fused = MpmSolver::new(MpmConfig::default(), &x).unwrap();
        let mut apart = MpmSolver::new(MpmConfig::default(), &x).unwrap();
        for _ in 0..3 {
            fused.step_frame().unwrap();
            apart.sort_particles();
            for _ in 0..apart.config.substeps {
                apart.substep().unwrap();
            }
        }
        let bits = |s: &MpmSolver| {
            let mut b: Vec<u32> = s
                .positions()
                .iter()
                .flatten()
                .map(|v| v.to_bits())
                .collect();
            b.extend(
                s.deformation_gradients()
                    .iter()
                    .flat_map(|f| f.to_cols_array())
                    .map(f32::to_bits),
            );
            b.extend(
                s.rotations()
                    .iter()
                    .flat_map(|q| q.to_array())
                    .map(f32::to_bits),
            );
            b
        };
        assert!(bits(&fused) == bits(&apart));
    }

    #[test]
    fn sort_key_orders_by_block_then_by_node_within_the_block() {
        let nodes = [
            IVec3::new(0, 0, 0),
            IVec3::new(3, 3, 3),
            IVec3::new(4, 0, 0),
            IVec3::new(-1, 0, 0),
            IVec3::new(0, 4, 0),
            IVec3::new(0, 0, 4),
            IVec3::new(0, 0, -1),
            IVec3::new(1, 0, 0),
        ];
        let mut by_key = nodes;
        by_key.sort_by_key(|&b| sort_key(b));
        let mut by_rule = nodes;
        by_rule.sort_by_key(|&b| {
            let (blk, cell) = (b >> SORT_BLOCK_SHIFT, b & 3);
            (blk.z, blk.y, blk.x, cell.z, cell.y, cell.x)
        });
        assert_eq!(by_key, by_rule);
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
        // Far beyond the i32 node range on both sides, too.
        for far in [
            [[0.0, 0.0, 0.0], [1e9, -1e9, 3e9]],
            [[-1e12, 0.0, 0.0], [1e12, 0.0, 0.0]],
        ] {
            let mut solver = MpmSolver::new(MpmConfig::default(), &far).unwrap();
            assert!(matches!(
                solver.step_frame(),
                Err(MpmError::GridTooLarge { .. })
            ));
        }
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
