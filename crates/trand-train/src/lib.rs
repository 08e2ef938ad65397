//! Training of trand's surfels, independent of the rasterizer:
//!
//! * [`losses`]: photometric (L1 + D-SSIM), Dice on the object map, TRAN-D's object-aware 3D loss and
//!   2DGS's normal-consistency and distortion losses, each with an analytic gradient.
//! * [`optim`]: Adam over [`trand_core::Surfels`] with per-group learning-rate schedules.
//! * [`config`]: [`TrainConfig`], TRAN-D's hyper-parameters (t = 0 default, [`TrainConfig::t1`]), TOML.
//! * [`densify`]: clone / split / prune and opacity reset, keeping Adam's moments aligned.
//! * [`init`]: TRAN-D's random slab initialisation.
//! * [`pose`]: per-view pose refinement (a rigid correction of each training camera).
//!
//! # Wiring one iteration (TRAN-D / 2DGS order, reference notes §2.2, §2.5)
//!
//! For `it` in [`TrainConfig::iteration_range`]:
//! 1. `lr = cfg.learning_rates(it, camera_extent)`;
//! 2. render the view; losses: `rgb·photometric(rgb) + mask·photometric(mask colour) + dice·dice(obj map)`
//!    (weights in [`config::ImageLossConfig`]), plus [`losses::object::object_aware_loss`] on the means
//!    when `cfg.object_loss.active.is_active(it)`, plus normal/distortion when their λ > 0 and
//!    `cfg.geometry_loss.active.is_active(it)`; backward through the rasterizer into a gradient `Surfels`;
//! 3. `stats.add(radii, densification_grads)` (while `it < densify.until_iteration`);
//! 4. if `cfg.densify.densify_now(it)`: [`densify_and_prune`] with `cfg.densify.size_threshold(it)`;
//!    then if `cfg.densify.reset_opacity_now(it)`: [`reset_opacity`];
//! 5. `adam.step(...)`, unless it is the last iteration or densification replaced the surfels this
//!    iteration (the gradient rows no longer match; the reference's step updates nothing then). After an
//!    opacity reset without densification, step every group but the opacity ([`Adam::step_groups`]).

pub mod config;
pub mod densify;
pub mod init;
pub mod losses;
pub mod optim;
pub mod pose;

pub use config::TrainConfig;
pub use densify::{DensifyReport, DensifyStats, densify_and_prune, reset_opacity};
pub use optim::{Adam, AdamParams, GroupLr, LrSchedule};
pub use pose::{PoseCorrections, PoseRefinement};

#[cfg(test)]
mod testutil;
