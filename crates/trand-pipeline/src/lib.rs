//! TRAN-D's stages end to end, on top of the rasterizer (`trand-render`), the losses and optimiser
//! (`trand-train`) and the readers (`trand-io`):
//!
//! * [`associate`]: per-image instance ids made consistent across the t = 0 views by voting in a
//!   voxel hull.
//! * [`missed_masks`]: masks a segmenter missed, drawn in by the association again through corrected
//!   cameras (the table-aligned ones, or a first training pass's).
//! * [`targets`]: per training view, the three images the surfels are fitted to — RGB with the
//!   background blacked out, the colour-coded instance mask, and the K-channel one-hot object map.
//! * [`trainer`]: one optimisation loop (render → losses → backward → Adam → densify), used at t = 0
//!   and for the t = 1 refinement.
//! * [`mod@reconstruct`]: the t = 0 run from random initialisation, with the paper's ablations.
//! * [`mod@update`]: the t = 1 scene update — removal detection, deletion, TSDF mesh, MLS-MPM, single-image
//!   refinement.
//! * [`checkpoint`]: checkpoints that resume a reconstruction exactly.
//! * [`outputs`]: the run folder (surfels PLY, test-view depth, object maps, `run.json`).
//! * [`at_cameras`]: a finished run's depth, object ids, alpha and normals at any camera.
//! * [`run_folder`]: a finished run folder read back for rendering.
//! * [`export`]: a finished run's objects as point clouds and meshes.

pub mod associate;
pub mod at_cameras;
pub mod checkpoint;
pub mod contact;
pub mod detect;
pub mod export;
pub mod front_fill;
pub mod mask_agreement;
pub mod mask_edges;
pub mod missed_masks;
pub mod new_camera;
pub mod openings;
pub mod outputs;
pub mod reconstruct;
pub mod refill;
pub mod relocalise;
pub mod run_folder;
pub mod simulate;
pub mod support;
mod surfel_ops;
pub mod table_align;
pub mod table_height;
pub mod targets;
#[cfg(test)]
mod test_scene;
pub mod trainer;
pub mod update;
pub mod update_options;

pub use reconstruct::{InitMode, Method, ReconstructOptions, Reconstruction, reconstruct};
pub use targets::{Supervision, TrainView};
pub use trainer::{StepReport, Trainer};

/// Errors of the pipeline, each naming what failed.
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    #[error(transparent)]
    Io(#[from] trand_io::IoError),
    #[error("rendering failed: {0}")]
    Render(#[from] trand_render::RenderError),
    #[error("initialisation failed: {0}")]
    Init(#[from] trand_train::init::InitError),
    #[error(transparent)]
    Config(#[from] trand_train::config::ConfigError),
    #[error("view {view}: {what}")]
    View { view: String, what: String },
    #[error("{0}")]
    Invalid(String),
    #[error("interrupted at iteration {0}")]
    Interrupted(u32),
}

pub type Result<T, E = PipelineError> = std::result::Result<T, E>;
