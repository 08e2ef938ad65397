//! Evaluation of trand's outputs with the TRAN-D paper's protocol.
//!
//! * [`metrics`]: MAE, RMSE and threshold accuracies of predicted depth on GT object pixels, pooled per
//!   sequence ([`evaluate`]), averaged over sequences ([`mean_over_sequences`]), as a Markdown [`table`].
//! * [`run`]: the `trand eval` contract (a run folder of `.npy` depths → `metrics.json`).
//! * [`objects`]: the same metrics per GT object and pooled per object kind (`bowl (upright)`, …),
//!   with [`kind_label`], the one rule for that label.
//! * [`iou`] and [`hungarian`]: re-exported from `trand_core::matching`, where the pipeline uses them
//!   too.

pub mod metrics;
pub mod objects;
pub mod run;

pub use metrics::{
    Counts, EvalError, Metrics, PAPER_COLUMNS, PIXEL_SET_NOTE, THRESHOLDS_M, ViewCounts, evaluate,
    mean_over_sequences, paper_cells, table,
};
pub use objects::{
    KindRow, ObjectInfo, PerObject, UNKNOWN_KIND, kind_label, kind_table, object_table, per_object,
    pool_by_kind, read_object_info,
};
pub use run::{
    RunEvalError, RunEvaluation, evaluate_run, evaluate_run_detailed, prediction_path, run_state,
};
pub use trand_core::matching::{hungarian, iou};
