//! The real capture `../shared/data/real/keypose_bottle0` run as a user runs it: `trand reconstruct`
//! with defaults on its nerfstudio conversion (six views of a stereo rig, at most ~12° apart).
//!
//! Bounds (the goal): depth MAE at most 1.5 cm against the approximate GT depth over its
//! object pixels (a pixel with no predicted depth counts its whole GT depth as error), and every
//! labelled keypoint's predicted depth within 1 cm of the expected surface depth there (the GT
//! depth at the keypoint's pixel). Measured with defaults: MAE 0.86 cm on this definition, keypoints
//! within 0.77 cm.

use std::path::PathBuf;
use std::process::Command;

use trand_io::{ScratchDir, read_npy_f32};

/// The converted frames of the raw views, in the order the conversion numbered them 1, 3, ..., 11.
const SOURCES: [&str; 6] = [
    "000001_L", "000001_R", "000002_L", "000002_R", "000003_L", "000003_R",
];

#[test]
#[ignore = "needs ../shared/data/real/keypose_bottle0 and ~2 minutes on 2 cores"]
fn keypose_bottle_depth_is_within_the_goal_with_defaults() {
    let root =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/real/keypose_bottle0");
    let tmp = ScratchDir::new("real-keypose").unwrap();
    let run = tmp.path().join("run0");
    let out = Command::new(env!("CARGO_BIN_EXE_trand"))
        .args(["reconstruct", "--data"])
        .arg(root.join("converted"))
        .arg("--out")
        .arg(&run)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let kp: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(root.join("keypoints.json")).unwrap())
            .unwrap();
    let (mut sum, mut n) = (0.0f64, 0usize);
    for (i, src) in SOURCES.iter().enumerate() {
        let frame = 2 * i + 1;
        let pred = read_npy_f32(&run.join(format!("depth/{frame:06}.npy"))).unwrap();
        let gt = read_npy_f32(&root.join(format!("converted/gt_depth/{frame:06}.npy"))).unwrap();
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
