//! Core types of trand, shared by every other crate.
//!
//! * [`camera`]: the pinhole camera and *the* pixel-centre convention of the whole project.
//! * [`surfels`]: the struct-of-arrays parameter store of 2D Gaussian surfels (raw, pre-activation values).
//! * [`sh`]: real spherical harmonics up to degree 3 (constants and basis of the 3DGS/2DGS family).
//! * [`real`]: a tiny scalar trait so numeric kernels run in `f32` for speed and in `f64` for
//!   finite-difference tests, from one source.
//! * [`math`]: activations and quaternion helpers.
//! * [`matching`]: mask IoU and the Hungarian assignment.
//! * [`mesh`]: the indexed triangle mesh every crate shares (models, the fused surface, PLY).

pub mod camera;
pub mod matching;
pub mod math;
pub mod mesh;
pub mod real;
pub mod sh;
pub mod surfels;

pub use camera::{Camera, CameraError, Intrinsics};
pub use mesh::{Mesh, MeshError};
pub use real::Real;
pub use surfels::{DEFAULT_NUM_OBJECTS, MAX_NUM_OBJECTS, Surfels, SurfelsError};
