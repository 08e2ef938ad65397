//! Evaluating a run folder against a sequence (`trand eval`).
//!
//! Run-folder contract:
//! * `RUN/run.json` (optional): a JSON object with at least `"state": "t0" | "t1"`.
//! * `RUN/depth/{frame:06}.npy`: float32 `(H, W)` predicted depth in metres (0 = no prediction), one per
//!   test view of the state (`test_0` for t0, `test_1` for t1).
//!
//! File names come from [`trand_io::run_layout`]. Writes `RUN/metrics.json` (atomically): the [`Metrics`] plus the state and the data path.

use std::path::{Path, PathBuf};

use serde::Serialize;
use trand_io::{
    IoError, Load, LoadOptions, RunManifest, Split, State, read_npy_f32, read_sequence_with,
    run_layout,
};

use crate::metrics::{EvalError, Metrics, evaluate};
use crate::objects::{ObjectInfoError, PerObject, per_object, read_object_info};

#[derive(Debug, thiserror::Error)]
pub enum RunEvalError {
    #[error(transparent)]
    Io(#[from] IoError),
    #[error(transparent)]
    Eval(#[from] EvalError),
    #[error(transparent)]
    Objects(#[from] ObjectInfoError),
    #[error("missing prediction {path} for test view {view}")]
    MissingPrediction { path: PathBuf, view: String },
    #[error("{path}: predicted depth is {pred_w}x{pred_h}, test view {view} is {gt_w}x{gt_h}")]
    SizeMismatch {
        path: PathBuf,
        view: String,
        pred_w: u32,
        pred_h: u32,
        gt_w: u32,
        gt_h: u32,
    },
    #[error("{path}: field `state`: {reason}")]
    RunState { path: PathBuf, reason: String },
    #[error("{data}: no test views for state {state} ({folder}/)")]
    NoTestViews {
        data: PathBuf,
        state: &'static str,
        folder: &'static str,
    },
}

/// The state recorded in `RUN/run.json`, if any.
pub fn run_state(run: &Path) -> Result<Option<State>, RunEvalError> {
    let Some(manifest) = RunManifest::read(run)? else {
        return Ok(None);
    };
    manifest.state().map_err(|reason| RunEvalError::RunState {
        path: run.join(run_layout::RUN_JSON),
        reason,
    })
}

/// Path of the predicted depth of a frame (see [`trand_io::run_layout`]).
pub fn prediction_path(run: &Path, frame: u32) -> PathBuf {
    run_layout::depth_path(run, frame)
}

#[derive(Serialize)]
struct Report<'a> {
    state: State,
    data: String,
    #[serde(flatten)]
    metrics: &'a Metrics,
    per_object: &'a [PerObject],
}

/// Everything `trand eval` computes for a run.
#[derive(Clone, Debug)]
pub struct RunEvaluation {
    pub state: State,
    /// Pooled over every GT object pixel.
    pub metrics: Metrics,
    /// Per GT object (ascending id).
    pub objects: Vec<PerObject>,
}

/// [`evaluate_run_detailed`]'s state and pooled metrics.
pub fn evaluate_run(
    run: &Path,
    data: &Path,
    state: Option<State>,
) -> Result<(State, Metrics), RunEvalError> {
    evaluate_run_detailed(run, data, state).map(|e| (e.state, e.metrics))
}

/// Evaluates `run` against the sequence at `data`, pooled and per GT object. The state is `state` if
/// given, else `run.json`'s, else t0; an explicit state that contradicts `run.json` is an error.
/// Writes `RUN/metrics.json` (the pooled figures at the top level, the objects under `per_object`).
pub fn evaluate_run_detailed(
    run: &Path,
    data: &Path,
    state: Option<State>,
) -> Result<RunEvaluation, RunEvalError> {
    let recorded = run_state(run)?;
    let state = match (state, recorded) {
        (Some(s), Some(r)) if s != r => {
            return Err(RunEvalError::RunState {
                path: run.join(run_layout::RUN_JSON),
                reason: format!("run is {} but {} was asked for", r.as_str(), s.as_str()),
            });
        }
        (Some(s), _) | (None, Some(s)) => s,
        (None, None) => State::T0,
    };
    let opts = LoadOptions {
        rgb: Load::No,
        masks: Load::Yes,
        depth: Load::Yes,
        object_channels: None,
    };
    let seq = read_sequence_with(data, &opts)?;
    let gt = seq.views(Split::Test, state);
    if gt.is_empty() {
        return Err(RunEvalError::NoTestViews {
            data: data.into(),
            state: state.as_str(),
            folder: Split::Test.folder(state),
        });
    }
    let mut preds = Vec::with_capacity(gt.len());
    for v in gt {
        let path = prediction_path(run, v.frame);
        if !path.is_file() {
            return Err(RunEvalError::MissingPrediction {
                path,
                view: v.name.clone(),
            });
        }
        let d = read_npy_f32(&path)?;
        let k = v.camera.intrinsics;
        if (d.width, d.height) != (k.width, k.height) {
            return Err(RunEvalError::SizeMismatch {
                path,
                view: v.name.clone(),
                pred_w: d.width,
                pred_h: d.height,
                gt_w: k.width,
                gt_h: k.height,
            });
        }
        preds.push((v.name.clone(), d));
    }
    let metrics = evaluate(&preds, gt)?;
    let info = read_object_info(data)?;
    let objects = per_object(&preds, gt, &info)?;
    let report = Report {
        state,
        data: data.display().to_string(),
        metrics: &metrics,
        per_object: &objects,
    };
    let json = serde_json::to_vec_pretty(&report).expect("metrics serialise");
    trand_io::write_atomic(&run.join(run_layout::METRICS_JSON), &json)?;
    Ok(RunEvaluation {
        state,
        metrics,
        objects,
    })
}
