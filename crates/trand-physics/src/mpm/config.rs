//! The solver's settings ([`MpmConfig`], TRAN-D's scene update by default), its errors, and the
//! constants of one substep derived from them ([`StepParams`]).

use glam::Vec3;
use serde::{Deserialize, Serialize};

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

/// Whether [`crate::MpmSolver::run`] (and the scene update's frame loop) may stop before the frame
/// count because nothing moves any more.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum StopAtRest {
    /// Always simulate every frame.
    Never,
    /// Stop once the largest particle speed (m/s), sampled at the end of each frame, has stayed
    /// below `speed` for `frames` consecutive frames.
    Below { speed: f32, frames: u32 },
}

impl StopAtRest {
    /// Half the speed a body gains in one frame of free fall (`½ g Δt_frame` = 0.0098 m/s with
    /// g = 4.9 m/s² and 4 ms frames): a body that has lost its support exceeds it one frame after it
    /// starts to fall, and one thrown up is below it for less than one frame around its apex, so
    /// two consecutive frames below it cannot be ballistic motion. Three frames leave a margin.
    pub const TRAN_D: Self = Self::Below {
        speed: 0.0098,
        frames: 3,
    };
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
    /// Stopping before `frames` when every particle is at rest (the authors always run 100).
    pub stop_at_rest: StopAtRest,
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
            stop_at_rest: StopAtRest::TRAN_D,
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

    pub(super) fn validate(&self) -> Result<(), MpmError> {
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
        if matches!(self.stop_at_rest, StopAtRest::Below { speed, frames }
            if !(speed.is_finite() && speed >= 0.0) || frames == 0)
        {
            return bad("stop_at_rest needs a finite speed ≥ 0 and at least 1 frame");
        }
        Ok(())
    }

    /// The constants of one substep.
    pub(super) fn step_params(&self) -> StepParams {
        let dt = self.substep_dt();
        let p_vol = self.particle_volume_m3();
        let (mu, lambda) = self.lame();
        StepParams {
            dt,
            dx: self.dx,
            inv_dx: 1.0 / self.dx,
            p_mass: self.density * p_vol,
            stress_scale: -dt * p_vol * 4.0 / (self.dx * self.dx),
            mu,
            lambda,
            gravity: Vec3::from_array(self.gravity),
            ground: self.ground,
            max_grid_nodes: self.max_grid_nodes,
        }
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

/// Constants of one substep.
#[derive(Clone, Copy)]
pub(super) struct StepParams {
    pub dt: f32,
    pub dx: f32,
    pub inv_dx: f32,
    pub p_mass: f32,
    /// `−Δt V_p 4/dx²`, the factor turning τ into the grid momentum impulse.
    pub stress_scale: f32,
    pub mu: f32,
    pub lambda: f32,
    pub gravity: Vec3,
    pub ground: Ground,
    pub max_grid_nodes: usize,
}
