//! The real capture `../shared/data/real/keypose_bottle0` run as a user runs it: `trand reconstruct`
//! with defaults, on its nerfstudio conversion (six views of a stereo rig, at most ~12° apart) and on
//! the raw files as the dataset ships them (the three masked left views train; the run's depth is
//! written at the three right cameras, which it never trained on).
//!
//! Bounds (the goal): depth MAE at most 1.5 cm against the approximate GT depth over its
//! object pixels (a pixel with no predicted depth counts its whole GT depth as error), and every
//! labelled keypoint's predicted depth within 1 cm of the expected surface depth there (the GT
//! depth at the keypoint's pixel). Measured with defaults: MAE 0.86 cm on this definition, keypoints
//! within 0.77 cm (converted); MAE 0.45 cm, keypoints within 0.84 cm (raw).

use std::path::{Path, PathBuf};
use std::process::Command;

use trand_io::{ScratchDir, read_npy_f32};

fn capture() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/real/keypose_bottle0")
}

/// `trand reconstruct --data DATA --out RUN` with defaults.
fn reconstruct(data: &Path, run: &Path) {
    let out = Command::new(env!("CARGO_BIN_EXE_trand"))
        .args(["reconstruct", "--data"])
        .arg(data)
        .arg("--out")
        .arg(run)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Checks the run's depth of each `(run frame, converted frame, raw source view)` against the
/// approximate GT of the converted frame and the source view's keypoints.
fn check(run: &Path, views: &[(u32, u32, &str)]) {
    let root = capture();
    let kp: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(root.join("keypoints.json")).unwrap())
            .unwrap();
    let (mut sum, mut n) = (0.0f64, 0usize);
    for &(frame, converted, src) in views {
        let pred = read_npy_f32(&run.join(format!("depth/{frame:06}.npy"))).unwrap();
        let gt =
            read_npy_f32(&root.join(format!("converted/gt_depth/{converted:06}.npy"))).unwrap();
        for (&p, &g) in pred.data.iter().zip(&gt.data) {
            if g > 0.0 {
                sum += (p - g).abs() as f64;
                n += 1;
            }
        }
        for k in kp[src]["keypoints_uvz"].as_array().unwrap() {
            let (u, v) = (k[0].as_f64().unwrap(), k[1].as_f64().unwrap());
            let (x, y) = (u.round() as u32, v.round() as u32);
            let (p, g) = (pred.get(x, y, 0), gt.get(x, y, 0));
            assert!(g > 0.0, "{src}: keypoint ({u}, {v}) off the GT object");
            assert!(
                (p - g).abs() <= 0.01,
                "{src}: keypoint ({u}, {v}) depth {p} m, expected surface {g} m"
            );
        }
    }
    let mae = sum / n as f64;
    assert!(mae <= 0.015, "MAE {mae} m over {n} GT object pixels");
}

#[test]
#[ignore = "needs ../shared/data/real/keypose_bottle0 and ~2 minutes on 2 cores"]
fn keypose_bottle_depth_is_within_the_goal_with_defaults() {
    let tmp = ScratchDir::new("real-keypose").unwrap();
    let run = tmp.path().join("run0");
    reconstruct(&capture().join("converted"), &run);
    // The conversion numbered 1L, 1R, 2L, 2R, 3L, 3R as frames 1, 3, ..., 11.
    let sources = [
        "000001_L", "000001_R", "000002_L", "000002_R", "000003_L", "000003_R",
    ];
    let views: Vec<(u32, u32, &str)> = sources
        .iter()
        .enumerate()
        .map(|(i, s)| (2 * i as u32 + 1, 2 * i as u32 + 1, *s))
        .collect();
    check(&run, &views);
}

#[test]
#[ignore = "needs ../shared/data/real/keypose_bottle0 and ~1 minute on 2 cores"]
fn keypose_raw_files_run_with_defaults_and_the_unseen_right_views_are_within_the_goal() {
    let tmp = ScratchDir::new("real-keypose-raw").unwrap();
    let run = tmp.path().join("run0");
    reconstruct(&capture().join("raw"), &run);
    // The reader numbers NNNNNN_R as frame 2·NNNNNN + 1; the conversion numbered them 3, 7, 11.
    check(
        &run,
        &[(3, 3, "000001_R"), (5, 7, "000002_R"), (7, 11, "000003_R")],
    );
}
