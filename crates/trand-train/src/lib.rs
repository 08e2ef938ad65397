//! Training of trand's surfels, independent of the rasterizer:
//!
//! * [`losses`]: photometric (L1 + D-SSIM), Dice on the object map, TRAN-D's object-aware 3D loss and
//!   2DGS's normal-consistency and distortion losses, each with an analytic gradient.
//! * [`optim`]: Adam over [`trand_core::Surfels`] with per-group learning-rate schedules.
//! * [`config`]: [`TrainConfig`], TRAN-D's hyper-parameters (t = 0 default, [`TrainConfig::t1`]), TOML.
//! * [`densify`]: clone / split / prune and opacity reset, keeping Adam's moments aligned.
//! * [`init`]: TRAN-D's random slab initialisation.

pub mod config;
pub mod densify;
pub mod init;
pub mod losses;
pub mod optim;

pub use config::TrainConfig;
pub use densify::{DensifyReport, DensifyStats, densify_and_prune, reset_opacity};
pub use optim::{Adam, AdamParams, GroupLr, LrSchedule};

#[cfg(test)]
mod testutil;
