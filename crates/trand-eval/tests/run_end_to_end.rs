//! `evaluate_run` on the real seq_101 test views: GT copied as the prediction, a constant offset,
//! nothing predicted, and the error cases. Ignored unless asked for (`--include-ignored`): they need
//! `../shared/data/blender/seq_101`.

#[path = "../../../testdata/shared_data.rs"]
mod shared_data;

use std::path::{Path, PathBuf};

use trand_eval::{RunEvalError, THRESHOLDS_M, evaluate_run, prediction_path};
use trand_io::{Image, LoadOptions, ScratchDir, Split, State, read_sequence_with};

fn seq_dir() -> PathBuf {
    shared_data::shared_data("blender/seq_101")
}

/// Writes GT depth (+ `offset` metres, or zeros) as predictions for the test views of `state`.
/// Returns (evaluated pixel count, mean GT depth over them).
fn write_predictions(data: &Path, run: &Path, state: State, f: impl Fn(f32) -> f32) -> (u64, f64) {
    let seq = read_sequence_with(data, &LoadOptions::for_eval()).unwrap();
    let (mut n, mut sum) = (0u64, 0.0f64);
    for v in seq.views(Split::Test, state) {
        let d = v.depth.as_ref().unwrap();
        let inst = v.instance.as_ref().unwrap();
        for (&g, &i) in d.data.iter().zip(&inst.data) {
            if i != 0 && g > 0.0 {
                n += 1;
                sum += g as f64;
            }
        }
        let pred = Image {
            data: d.data.iter().map(|&g| f(g)).collect(),
            ..d.clone()
        };
        trand_io::write_npy_f32(&prediction_path(run, v.frame), &pred).unwrap();
    }
    (n, sum / n as f64)
}

#[test]
#[ignore = "needs ../shared/data/blender (see README: Tests)"]
fn gt_depth_as_prediction_scores_perfectly() {
    let data = seq_dir();
    let run = ScratchDir::new("eval-gt").unwrap();
    let (n, _) = write_predictions(&data, run.path(), State::T0, |g| g);
    let (state, m) = evaluate_run(run.path(), &data, None).unwrap();
    assert_eq!(state, State::T0);
    assert_eq!(m.pixels, n);
    assert!(n > 10_000, "{n} object pixels");
    assert_eq!((m.mae_m, m.rmse_m, m.uncovered), (0.0, 0.0, 0));
    assert_eq!(m.acc, [1.0; 6]);
    assert_eq!(m.per_view.len(), 10);
    let j: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.path().join("metrics.json")).unwrap())
            .unwrap();
    assert_eq!(j["state"], "t0");
    assert_eq!(j["pixels"], n);
    assert_eq!(j["mae_m"], 0.0);
}

#[test]
#[ignore = "needs ../shared/data/blender (see README: Tests)"]
fn constant_offset_gives_that_mae_and_splits_the_thresholds() {
    let data = seq_dir();
    let run = ScratchDir::new("eval-off").unwrap();
    std::fs::write(
        run.path().join("run.json"),
        r#"{"state": "t1", "iterations": 1100}"#,
    )
    .unwrap();
    let offset = 0.02f32;
    write_predictions(&data, run.path(), State::T1, |g| g + offset);
    let (state, m) = evaluate_run(run.path(), &data, None).unwrap();
    assert_eq!(state, State::T1);
    assert!(
        (m.mae_m - 0.02).abs() < 1e-6 && (m.rmse_m - 0.02).abs() < 1e-6,
        "{} {}",
        m.mae_m,
        m.rmse_m
    );
    // 2 cm: outside 0.5 and 1 cm, inside 2.5 cm and above.
    assert_eq!(m.acc, [0.0, 0.0, 1.0, 1.0, 1.0, 1.0]);
    assert_eq!(m.thresholds_m, THRESHOLDS_M);
    assert!(m.per_view.iter().all(|v| v.view.starts_with("test_1/")));
}

#[test]
#[ignore = "needs ../shared/data/blender (see README: Tests)"]
fn empty_prediction_costs_the_mean_gt_depth() {
    let data = seq_dir();
    let run = ScratchDir::new("eval-zero").unwrap();
    let (n, mean_gt) = write_predictions(&data, run.path(), State::T0, |_| 0.0);
    let (_, m) = evaluate_run(run.path(), &data, Some(State::T0)).unwrap();
    assert_eq!((m.pixels, m.uncovered), (n, n));
    assert!((m.mae_m - mean_gt).abs() < 1e-9);
    assert_eq!(m.acc, [0.0; 6]);
}

#[test]
#[ignore = "needs ../shared/data/blender (see README: Tests)"]
fn missing_or_wrongly_sized_prediction_names_the_file() {
    let data = seq_dir();
    let run = ScratchDir::new("eval-err").unwrap();
    write_predictions(&data, run.path(), State::T0, |g| g);
    let p = prediction_path(run.path(), 3);
    trand_io::write_npy_f32(&p, &Image::filled(320, 240, 1, 1.0f32)).unwrap();
    let e = evaluate_run(run.path(), &data, None).unwrap_err();
    assert!(
        matches!(
            e,
            RunEvalError::SizeMismatch {
                pred_w: 320,
                gt_w: 640,
                ..
            }
        ),
        "{e}"
    );
    assert!(e.to_string().contains("depth/000003.npy"), "{e}");
    std::fs::remove_file(&p).unwrap();
    let e = evaluate_run(run.path(), &data, None).unwrap_err();
    assert!(
        matches!(e, RunEvalError::MissingPrediction { .. })
            && e.to_string().contains("000003.npy")
            && e.to_string().contains("test_0/000003"),
        "{e}"
    );
    assert!(!run.path().join("metrics.json").exists());
}

#[test]
#[ignore = "needs ../shared/data/blender (see README: Tests)"]
fn state_conflicting_with_run_json_is_an_error() {
    let data = seq_dir();
    let run = ScratchDir::new("eval-state").unwrap();
    std::fs::write(run.path().join("run.json"), r#"{"state": "t0"}"#).unwrap();
    let e = evaluate_run(run.path(), &data, Some(State::T1)).unwrap_err();
    assert!(
        matches!(e, RunEvalError::RunState { .. }) && e.to_string().contains("run.json"),
        "{e}"
    );
    std::fs::write(run.path().join("run.json"), r#"{"state": "t7"}"#).unwrap();
    assert!(matches!(
        evaluate_run(run.path(), &data, None),
        Err(RunEvalError::RunState { .. })
    ));
}
