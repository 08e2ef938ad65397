//! Differentiable 2D Gaussian surfel rasterizer on the CPU (2DGS, Huang et al. 2024), with the extra
//! maps TRAN-D trains on: a colour-coded mask image and a K-channel object-probability map.
//!
//! Hand-written because no crate does differentiable surfel splatting on the CPU. The stages mirror the
//! GPU rasterizers so a wgpu backend can be a port, not a redesign:
//!
//! 1. [`preprocess`]: per surfel — ray-splat transform `T`, 3σ box, tiles, normal, colours.
//! 2. [`binning`]: depth sort and per-tile lists (CSR), plus each surfel's pair list.
//! 3. [`forward`]: per tile, front-to-back blending of every output map.
//! 4. [`backward`]: per tile, back-to-front gradients into one record per (tile, surfel) pair.
//! 5. reduction of the records per surfel in a fixed order (bit-identical for any thread count).
//! 6. [`preprocess::preprocess_backward_one`]: chain rule to the raw parameters (quaternion
//!    normalisation, SH view direction, exp/sigmoid/softmax activations), and each surfel's share of
//!    the camera-pose gradient ([`Gradients::camera`], summed in surfel order).
//!
//! The tile kernels (3, 4) run on eight-pixel lanes ([`lanes`]) and are compiled three times, for
//! AVX-512, AVX2 and the baseline target, chosen at run time ([`simd`]); all give identical bits.
//!
//! Everything is generic over [`trand_core::Real`]: `f32` in production, `f64` in the finite-difference
//! tests, from one source. Entry points: [`render`] and [`Rendered::backward`], or both behind the
//! [`Rasterizer`] trait ([`Cpu`]), the seam a GPU backend implements.

pub mod backward;
pub mod bench_scene;
pub mod binning;
pub mod camera;
pub mod constants;
pub mod forward;
pub mod intersect;
pub mod intrinsics;
pub mod labels;
pub mod lanes;
pub mod layout;
pub mod params;
pub mod preprocess;
pub mod rasterizer;
mod render;
pub mod simd;
mod vec3;

pub use labels::{ObjectSumGrads, ObjectSums};
pub use layout::GeometryMaps;
pub use params::{ParamsOf, SurfelParams};
pub use rasterizer::{Cpu, Rasterizer};
pub use render::{
    Gradients, MAX_OBJECTS, Maps, OutputGrads, RenderError, RenderSettings, Rendered, render,
    render_object_sums,
};
