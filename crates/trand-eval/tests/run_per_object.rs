//! `trand eval`'s per-object figures on a BOP sequence written by the test: the rows are keyed by the
//! object ids that name the `mask_visib` files, kinds come from `sequence.json`, `metrics.json` keeps
//! the pooled figures at the top level and gains `per_object`, and a sequence without
//! `sequence.json` still evaluates (no kinds).

use std::path::Path;

use serde_json::json;
use trand_eval::{UNKNOWN_KIND, evaluate, evaluate_run_detailed, prediction_path};
use trand_io::{Image, LoadOptions, ScratchDir, Split, State, read_sequence_with};

const W: u32 = 4;
const H: u32 = 2;
/// Object ids: not 1, 2, … so that an id taken from the mask's position would show.
const MUG: u16 = 4;
const BOWL: u16 = 9;

fn write_json(p: &Path, v: &serde_json::Value) {
    std::fs::create_dir_all(p.parent().unwrap()).unwrap();
    std::fs::write(p, serde_json::to_string_pretty(v).unwrap()).unwrap();
}

fn cameras(frames: &[u32]) -> serde_json::Value {
    let entry = json!({"cam_K": [10.0, 0.0, 1.5, 0.0, 10.0, 0.5, 0.0, 0.0, 1.0],
        "cam_R_w2c": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        "cam_t_w2c": [0.0, 0.0, 1000.0], "depth_scale": 1.0, "width": W, "height": H});
    frames
        .iter()
        .map(|f| (f.to_string(), entry.clone()))
        .collect()
}

/// Row-major 4×2 masks: the mug covers x = 0, 1 of row 0; the bowl x = 2 of row 0 and x = 3 of
/// row 1. GT depth 1 m, except 1.5 m under the bowl's second pixel. One training view (the reader
/// wants a `train_0`), two test views.
fn write_sequence(root: &Path) {
    let mut depth = Image::filled(W, H, 1, 1000u16);
    depth.set(3, 1, 0, 1500);
    let train = root.join("train_0");
    write_json(&train.join("scene_camera.json"), &cameras(&[0]));
    trand_io::write_gray16_png(&train.join("depth/000000.png"), &depth).unwrap();
    let test = root.join("test_0");
    write_json(&test.join("scene_camera.json"), &cameras(&[0, 1]));
    for f in [0u32, 1] {
        trand_io::write_gray16_png(&test.join(format!("depth/{f:06}.png")), &depth).unwrap();
        for (id, pixels) in [(MUG, vec![(0, 0), (1, 0)]), (BOWL, vec![(2, 0), (3, 1)])] {
            let mut m = Image::filled(W, H, 1, 0u8);
            for (x, y) in pixels {
                m.set(x, y, 0, 255);
            }
            let path = test.join(format!("mask_visib/{f:06}_{id:06}.png"));
            trand_io::write_gray8_png(&path, &m).unwrap();
        }
    }
    write_json(
        &root.join("sequence.json"),
        &json!({"objects": [
            {"id": MUG, "kind": "mug", "params_m": {"initial_mode": "upright"}},
            {"id": BOWL, "kind": "bowl", "params_m": {"initial_mode": "inverted"}},
            {"id": 12, "kind": "bottle", "params_m": {"initial_mode": "upright"}}]}),
    );
}

/// Predictions: GT everywhere, then the mug 1/64 m too near in frame 0 and the bowl's second pixel
/// uncovered in frame 1. Mug: |e| = 1/64, 1/64, 0, 0; bowl: |e| = 0, 0, 0, 1.5.
fn write_predictions(run: &Path) {
    std::fs::write(run.join("run.json"), r#"{"state": "t0"}"#).unwrap();
    for f in [0u32, 1] {
        let mut p = Image::filled(W, H, 1, 1.0f32);
        p.set(3, 1, 0, 1.5);
        if f == 0 {
            p.set(0, 0, 0, 1.0 - 1.0 / 64.0);
            p.set(1, 0, 0, 1.0 - 1.0 / 64.0);
        } else {
            p.set(3, 1, 0, 0.0);
        }
        trand_io::write_npy_f32(&prediction_path(run, f), &p).unwrap();
    }
}

fn read_metrics_json(run: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(run.join("metrics.json")).unwrap()).unwrap()
}

#[test]
fn per_object_rows_are_keyed_by_mask_ids_and_labelled_from_sequence_json() {
    let data = ScratchDir::new("eval-objects-data").unwrap();
    let run = ScratchDir::new("eval-objects-run").unwrap();
    write_sequence(data.path());
    write_predictions(run.path());
    let ev = evaluate_run_detailed(run.path(), data.path(), None).unwrap();
    assert_eq!(ev.state, State::T0);
    let ids: Vec<u16> = ev.objects.iter().map(|o| o.id).collect();
    assert_eq!(ids, [MUG, BOWL], "the bottle (id 12) is in no view");
    let (mug, bowl) = (&ev.objects[0], &ev.objects[1]);
    assert_eq!(mug.label, "mug (upright)");
    assert_eq!(bowl.label, "bowl (inverted)");
    assert_eq!((mug.metrics.pixels, mug.metrics.uncovered), (4, 0));
    assert_eq!(mug.metrics.mae_m, 2.0 / 64.0 / 4.0);
    assert_eq!(mug.metrics.acc, [0.5, 0.5, 1.0, 1.0, 1.0, 1.0]);
    assert_eq!((bowl.metrics.pixels, bowl.metrics.uncovered), (4, 1));
    assert_eq!(bowl.metrics.mae_m, 1.5 / 4.0);
    assert_eq!(bowl.metrics.acc, [0.75; 6]);

    // metrics.json: the pooled figures as before at the top level, the objects under per_object.
    let seq = read_sequence_with(data.path(), &LoadOptions::for_eval()).unwrap();
    let preds: Vec<_> = seq
        .views(Split::Test, State::T0)
        .iter()
        .map(|v| {
            let d = trand_io::read_npy_f32(&prediction_path(run.path(), v.frame)).unwrap();
            (v.name.clone(), d)
        })
        .collect();
    let pooled = evaluate(&preds, seq.views(Split::Test, State::T0)).unwrap();
    assert_eq!(ev.metrics, pooled);
    let j = read_metrics_json(run.path());
    assert_eq!(j["pixels"], 8);
    assert_eq!(j["mae_m"], pooled.mae_m);
    assert_eq!(j["per_view"].as_array().unwrap().len(), 2);
    let objs = j["per_object"].as_array().unwrap();
    assert_eq!(objs.len(), 2);
    assert_eq!(objs[1]["id"], BOWL);
    assert_eq!(objs[1]["kind"], "bowl");
    assert_eq!(objs[1]["orientation"], "inverted");
    assert_eq!(objs[1]["label"], "bowl (inverted)");
    assert_eq!(objs[1]["metrics"]["pixels"], 4);
    assert_eq!(objs[1]["counts"]["abs_sum"], 1.5);
}

#[test]
fn a_sequence_without_sequence_json_evaluates_with_unknown_kinds() {
    let data = ScratchDir::new("eval-objects-nokind").unwrap();
    let run = ScratchDir::new("eval-objects-nokind-run").unwrap();
    write_sequence(data.path());
    std::fs::remove_file(data.path().join("sequence.json")).unwrap();
    write_predictions(run.path());
    let ev = evaluate_run_detailed(run.path(), data.path(), None).unwrap();
    let rows: Vec<(u16, &str, Option<&str>)> = ev
        .objects
        .iter()
        .map(|o| (o.id, o.label.as_str(), o.kind.as_deref()))
        .collect();
    assert_eq!(
        rows,
        [(MUG, UNKNOWN_KIND, None), (BOWL, UNKNOWN_KIND, None)]
    );
    let j = read_metrics_json(run.path());
    assert!(j["per_object"][0]["kind"].is_null());
    assert_eq!(j["per_object"][0]["metrics"]["pixels"], 4);
}
