//! Evaluation of trand's outputs with the TRAN-D paper's protocol.
//!
//! * [`metrics`]: MAE, RMSE and threshold accuracies of predicted depth on GT object pixels, pooled per
//!   sequence ([`evaluate`]), averaged over sequences ([`mean_over_sequences`]), as a Markdown [`table`].
//! * [`run`]: the `trand eval` contract (a run folder of `.npy` depths → `metrics.json`).
//! * [`matching`]: mask [`iou`] and rectangular [`hungarian`] assignment, for matching objects across
//!   the scene change.

pub mod matching;
pub mod metrics;
pub mod run;

pub use matching::{hungarian, iou};
pub use metrics::{
    Counts, EvalError, Metrics, PIXEL_SET_NOTE, THRESHOLDS_M, ViewCounts, evaluate,
    mean_over_sequences, table,
};
pub use run::{RunEvalError, evaluate_run, prediction_path, run_state};
