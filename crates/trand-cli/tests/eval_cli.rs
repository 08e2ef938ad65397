//! `trand eval` as a user runs it, on seq_101 with GT depth copied as the prediction (ignored unless
//! asked for: it needs `../shared/data/blender/seq_101`).

#[path = "../../../testdata/shared_data.rs"]
mod shared_data;

use std::process::Command;

use trand_io::{LoadOptions, ScratchDir, read_sequence_with};

#[test]
#[ignore = "needs ../shared/data/blender (see README: Tests)"]
fn eval_of_gt_copy_prints_perfect_row_and_writes_metrics_json() {
    let data = shared_data::shared_data("blender/seq_101");
    let run = ScratchDir::new("cli-eval").unwrap();
    std::fs::write(run.path().join("run.json"), r#"{"state": "t0"}"#).unwrap();
    let seq = read_sequence_with(&data, &LoadOptions::for_eval()).unwrap();
    for v in &seq.test_t0 {
        trand_io::write_npy_f32(
            &trand_eval::prediction_path(run.path(), v.frame),
            v.depth.as_ref().unwrap(),
        )
        .unwrap();
    }
    let out = Command::new(env!("CARGO_BIN_EXE_trand"))
        .args(["eval", "--run"])
        .arg(run.path())
        .arg("--data")
        .arg(&data)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.contains("| seq_101 t0 | 0.0000 | 0.0000 | 100.00% | 100.00% |"),
        "{stdout}"
    );
    // Per object, with the kinds of seq_101's sequence.json; the objects partition the pooled pixels.
    assert!(
        stdout.contains("| 1 | tumbler (inverted) |")
            && stdout.contains("| 4 | wine_glass (upright) |"),
        "{stdout}"
    );
    let j: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.path().join("metrics.json")).unwrap())
            .unwrap();
    let objects = j["per_object"].as_array().unwrap();
    assert_eq!(objects.len(), 4);
    let sum: u64 = objects
        .iter()
        .map(|o| o["metrics"]["pixels"].as_u64().unwrap())
        .sum();
    assert_eq!(Some(sum), j["pixels"].as_u64());
    assert!(objects.iter().all(|o| o["metrics"]["mae_m"] == 0.0));
    // A missing prediction fails with the file named.
    std::fs::remove_file(trand_eval::prediction_path(
        run.path(),
        seq.test_t0[0].frame,
    ))
    .unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_trand"))
        .args(["eval", "--run"])
        .arg(run.path())
        .arg("--data")
        .arg(&data)
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("missing prediction"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}
