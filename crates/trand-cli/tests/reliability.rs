//! Regression tests of issue 21 through the `trand` binary: no data loss, no panic on crafted input,
//! each error names the file and field, output locations checked before any work.

mod common;

use std::ffi::OsStr;
use std::os::unix::ffi::OsStrExt;
use std::path::Path;
use std::process::Output;

use common::{fails_with, text, trand_in};
use trand_io::ScratchDir;

/// Runs `trand` in the temporary folder.
fn trand<S: AsRef<OsStr>>(args: &[S]) -> Output {
    trand_in(&std::env::temp_dir(), args)
}

#[test]
fn synth_out_dot_force_deletes_nothing() {
    let dir = ScratchDir::new("cli-dot-force").unwrap();
    std::fs::write(dir.path().join("thesis.tex"), b"precious").unwrap();
    std::fs::create_dir(dir.path().join("data")).unwrap();
    for out in [".", "./", "data/..", ".."] {
        let o = trand_in(
            &dir.path().join("data"),
            &[
                "synth", "--seed", "1", "--preset", "tiny", "--out", out, "--force", "--quiet",
            ],
        );
        fails_with(&o, &["current folder"]);
    }
    let o = trand_in(
        dir.path(),
        &[
            "synth", "--seed", "1", "--preset", "tiny", "--out", ".", "--force", "--quiet",
        ],
    );
    fails_with(&o, &["current folder"]);
    assert_eq!(
        std::fs::read(dir.path().join("thesis.tex")).unwrap(),
        b"precious"
    );
    assert!(dir.path().join("data").is_dir());
}

#[test]
fn synth_force_replaces_only_a_folder_trand_wrote() {
    let dir = ScratchDir::new("cli-force-foreign").unwrap();
    let out = dir.path().join("home");
    std::fs::create_dir(&out).unwrap();
    std::fs::write(out.join("notes.txt"), b"mine").unwrap();
    let o = trand(&[
        OsStr::new("synth"),
        "--seed".as_ref(),
        "1".as_ref(),
        "--preset".as_ref(),
        "tiny".as_ref(),
        "--out".as_ref(),
        out.as_os_str(),
        "--force".as_ref(),
        "--quiet".as_ref(),
    ]);
    fails_with(&o, &["home", ".trand-output", "never replaced"]);
    assert_eq!(std::fs::read(out.join("notes.txt")).unwrap(), b"mine");
    let leftovers: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
    assert_eq!(leftovers.len(), 1, "temporary folders left: {leftovers:?}");
}

#[test]
fn dangling_or_unwritable_out_fails_before_work_naming_out() {
    let dir = ScratchDir::new("cli-out-check").unwrap();
    let dangling = dir.path().join("dangling");
    std::os::unix::fs::symlink(dir.path().join("nowhere"), &dangling).unwrap();
    let missing_parent = dir.path().join("no/such/parent/run");
    // The data path does not exist either: the output is checked first, before any reading.
    for out in [&dangling, &missing_parent] {
        let o = trand(&[
            OsStr::new("reconstruct"),
            "--data".as_ref(),
            "/nonexistent/seq".as_ref(),
            "--out".as_ref(),
            out.as_os_str(),
        ]);
        fails_with(&o, &[&out.display().to_string()]);
        assert!(!text(&o).contains(".tmp-"), "{}", text(&o));
        assert!(
            !text(&o).contains("/nonexistent/seq"),
            "read data first: {}",
            text(&o)
        );
    }
    // A parent that is a file: found before the run folder is read.
    let file = dir.path().join("a_file");
    std::fs::write(&file, b"x").unwrap();
    let out = file.join("run");
    let o = trand(&[
        OsStr::new("update"),
        "--run".as_ref(),
        "/nonexistent/run".as_ref(),
        "--data".as_ref(),
        "/nonexistent/seq".as_ref(),
        "--out".as_ref(),
        out.as_os_str(),
    ]);
    fails_with(&o, &[&out.display().to_string()]);
    assert!(
        !text(&o).contains("/nonexistent/run"),
        "read the run first: {}",
        text(&o)
    );
}

#[test]
fn objects_100000_and_num_volume_1e11_are_refused_cleanly() {
    let dir = ScratchDir::new("cli-objects").unwrap();
    let out = dir.path().join("run");
    let o = trand(&[
        OsStr::new("reconstruct"),
        "--data".as_ref(),
        "/nonexistent/seq".as_ref(),
        "--out".as_ref(),
        out.as_os_str(),
        "--objects".as_ref(),
        "100000".as_ref(),
    ]);
    fails_with(&o, &["num_objects", "100000", "64"]);
    let cfg = dir.path().join("big.toml");
    std::fs::write(&cfg, "[init]\nnum_volume = 100000000000\n").unwrap();
    let o = trand(&[
        OsStr::new("reconstruct"),
        "--data".as_ref(),
        "/nonexistent/seq".as_ref(),
        "--out".as_ref(),
        out.as_os_str(),
        "--config".as_ref(),
        cfg.as_os_str(),
    ]);
    fails_with(&o, &["big.toml", "init.num_volume"]);
}

#[test]
fn toml_downsample_0_beta1_1_5_and_eps_0_are_refused_naming_the_file() {
    let dir = ScratchDir::new("cli-toml").unwrap();
    for (body, key) in [
        ("downsample = 0\n", "downsample"),
        (
            "[train.adam]\nbeta1 = 1.5\nbeta2 = 0.999\neps = 1e-15\n",
            "beta1",
        ),
        (
            "[train.adam]\nbeta1 = 0.9\nbeta2 = 0.999\neps = 0.0\n",
            "eps",
        ),
    ] {
        let cfg = dir.path().join("c.toml");
        std::fs::write(&cfg, body).unwrap();
        let o = trand(&[
            OsStr::new("reconstruct"),
            "--data".as_ref(),
            "/nonexistent/seq".as_ref(),
            "--out".as_ref(),
            dir.path().join("run").as_os_str(),
            "--config".as_ref(),
            cfg.as_os_str(),
        ]);
        fails_with(&o, &["c.toml", key]);
    }
}

/// A t = 0 run folder with `channels` in run.json and surfels whose first mean is `x`.
fn fake_run(root: &Path, channels: serde_json::Value, x: f32) {
    std::fs::create_dir_all(root).unwrap();
    let mut s = trand_core::Surfels::new(0, 15).unwrap();
    s.push(&trand_core::surfels::Surfel {
        mean: [x, 0.0, 0.05],
        log_scale: [-5.0, -5.0],
        quat: [1.0, 0.0, 0.0, 0.0],
        opacity_logit: 1.0,
        sh_dc: [0.0; 3],
        mask_dc: [0.0; 3],
        obj_logits: vec![0.0; 15],
    });
    trand_io::write_surfels_ply(&root.join("surfels.ply"), &s).unwrap();
    std::fs::write(root.join("config.toml"), "").unwrap();
    let j = serde_json::json!({"state": "t0", "object_channels": channels});
    std::fs::write(root.join("run.json"), j.to_string()).unwrap();
}

#[test]
fn update_refuses_bad_object_channels_and_nan_surfels_naming_the_file() {
    let dir = ScratchDir::new("cli-channels").unwrap();
    let cases = [
        (serde_json::json!([[1, 15]]), 0.0, "object_channels"),
        (serde_json::json!([[1, 0]]), 0.0, "object_channels"),
        (serde_json::json!([[1, 1], [1, 2]]), 0.0, "object_channels"),
        (serde_json::json!([[0, 1]]), 0.0, "object_channels"),
        (serde_json::json!([]), 0.0, "object_channels"),
        (serde_json::json!([[1, 1]]), f32::NAN, "surfels.ply"),
    ];
    for (i, (channels, x, field)) in cases.into_iter().enumerate() {
        let run = dir.path().join(format!("run{i}"));
        fake_run(&run, channels, x);
        let o = trand(&[
            OsStr::new("update"),
            "--run".as_ref(),
            run.as_os_str(),
            "--data".as_ref(),
            "/nonexistent/seq".as_ref(),
            "--out".as_ref(),
            dir.path().join(format!("out{i}")).as_os_str(),
        ]);
        fails_with(&o, &[field]);
        if field == "object_channels" {
            fails_with(&o, &["run.json"]);
        }
    }
}

#[test]
fn non_utf8_paths_run_to_the_end_without_panicking() {
    let dir = ScratchDir::new("cli-non-utf8").unwrap();
    let name = |s: &[u8]| dir.path().join(OsStr::from_bytes(s));
    let seq = name(b"seq-\xff");
    let o = trand(&[
        OsStr::new("synth"),
        "--seed".as_ref(),
        "5".as_ref(),
        "--preset".as_ref(),
        "tiny".as_ref(),
        "--out".as_ref(),
        seq.as_os_str(),
        "--quiet".as_ref(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let out0 = name(b"run0-\xfe");
    let o = trand(&[
        OsStr::new("reconstruct"),
        "--data".as_ref(),
        seq.as_os_str(),
        "--out".as_ref(),
        out0.as_os_str(),
        "--iterations".as_ref(),
        "3".as_ref(),
        "--downsample".as_ref(),
        "2".as_ref(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(out0.join("run.json").is_file());
    let out1 = name(b"run1-\xfd");
    let o = trand(&[
        OsStr::new("update"),
        "--run".as_ref(),
        out0.as_os_str(),
        "--data".as_ref(),
        seq.as_os_str(),
        "--out".as_ref(),
        out1.as_os_str(),
        "--physics".as_ref(),
        "off".as_ref(),
        "--refine".as_ref(),
        "off".as_ref(),
        "--relocalise".as_ref(),
        "off".as_ref(),
        "--removed".as_ref(),
        "1".as_ref(),
    ]);
    assert!(!text(&o).contains("panicked"), "{}", text(&o));
    assert!(o.status.success(), "{}", text(&o));
    assert!(out1.join("run.json").is_file());
}

#[test]
fn training_masks_without_object_pixels_are_refused_naming_the_sequence() {
    let dir = ScratchDir::new("cli-empty-masks").unwrap();
    let seq = dir.path().join("seq");
    common::sequence(&seq);
    let masks = seq.join("train_0/mask_visib");
    for e in std::fs::read_dir(&masks).unwrap() {
        let p = e.unwrap().path();
        let m = trand_io::image::read_gray8(&p).unwrap();
        let empty = trand_io::image::Image::filled(m.width, m.height, 1, 0u8);
        trand_io::write_gray8_png(&p, &empty).unwrap();
    }
    let out = dir.path().join("run");
    let o = trand(&[
        OsStr::new("reconstruct"),
        "--data".as_ref(),
        seq.as_os_str(),
        "--out".as_ref(),
        out.as_os_str(),
    ]);
    fails_with(&o, &["seq", "no object pixels in any t=0 training mask"]);
    assert!(!out.exists(), "nothing is written");
}
