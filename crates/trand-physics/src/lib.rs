//! Physics of trand's scene update (TRAN-D §5): after an object is removed, the remaining objects
//! are meshed from rendered depth, turned into particles and simulated with MLS-MPM so that the
//! Gaussians of objects that lost their support fall into place.
//!
//! * [`mpm`]: the MLS-MPM solver (fixed-corotated elasticity, sticky ground), parallel and
//!   deterministic.
//! * [`tsdf`]: TSDF fusion of depth maps and surface extraction.
//! * [`mesh`]: connected-component cleanup and vertex labelling of the fused [`trand_core::Mesh`].
//! * [`particles`]: MPM particles from surfel centres, mesh vertices and an optional interior fill.
//! * [`virtual_views`]: the ring of virtual cameras (plus one from below) used for depth fusion.
//!
//! The crate renders nothing: the caller renders depth maps and hands them over.

pub mod mesh;
pub mod mpm;
pub mod particles;
pub mod tsdf;
pub mod virtual_views;

pub use mesh::{LabelError, label_by_nearest, remove_small_components};
pub use mpm::{Ground, MpmConfig, MpmError, MpmSolver, ParticleVolume, StopAtRest};
pub use particles::{
    InteriorFill, ObjectSurfels, ParticleError, ParticleSet, ParticleSource, build_particles,
};
pub use tsdf::{TsdfError, TsdfSettings, TsdfVolume};
pub use virtual_views::{below_view, ring_views, scene_radius};
