//! `trand render` as a user runs it: on a tiny generated sequence, a t=0 and a t=1 run rendered at
//! their own test cameras give the depth the runs wrote, bit for bit; a bad camera file is refused with
//! its field named and nothing written.

mod common;

use std::path::Path;

use common::{ok, tiny_run, trand_in};
use trand_io::{
    LoadOptions, NamedCamera, ScratchDir, Split, State, read_npy_f32, read_sequence_with,
};

/// Renders `run` at the sequence's test cameras of `state` and compares with the run's own depth.
fn renders_its_own_test_depth(dir: &Path, run: &str, state: State) {
    let seq = read_sequence_with(dir.join("seq"), &LoadOptions::cameras_only()).unwrap();
    let views = seq.views(Split::Test, state);
    assert!(!views.is_empty());
    let cams: Vec<NamedCamera> = views
        .iter()
        .map(|v| NamedCamera {
            name: format!("test{:06}", v.frame),
            camera: v.camera,
        })
        .collect();
    let file = format!("{run}_cams.json");
    std::fs::write(dir.join(&file), trand_io::cameras_to_json(&cams)).unwrap();
    let out = format!("{run}_render");
    ok(trand_in(
        dir,
        &["render", "--run", run, "--cameras", &file, "--out", &out],
    ));
    for v in views {
        let own = read_npy_f32(&dir.join(format!("{run}/depth/{:06}.npy", v.frame))).unwrap();
        let at = read_npy_f32(&dir.join(format!("{out}/test{:06}_depth.npy", v.frame))).unwrap();
        assert!(own.data.iter().any(|&d| d > 0.0), "{run}: empty depth");
        let same = own
            .data
            .iter()
            .zip(&at.data)
            .all(|(a, b)| a.to_bits() == b.to_bits());
        assert!(
            same && own.same_size(&at),
            "{run} frame {}: depth differs",
            v.frame
        );
        for suffix in [
            "depth.png",
            "ids.png",
            "objects.png",
            "alpha.npy",
            "alpha.png",
            "normal.npy",
            "normal.png",
        ] {
            assert!(
                dir.join(format!("{out}/test{:06}_{suffix}", v.frame))
                    .is_file(),
                "{suffix}"
            );
        }
    }
}

#[test]
fn render_at_test_cameras_equals_the_runs_own_depth_at_t0_and_t1() {
    let tmp = ScratchDir::new("cli-render").unwrap();
    let dir = tmp.path();
    tiny_run(dir, 30);
    ok(trand_in(
        dir,
        &["update", "--run", "run0", "--data", "seq", "--out", "run1"],
    ));
    renders_its_own_test_depth(dir, "run0", State::T0);
    renders_its_own_test_depth(dir, "run1", State::T1);

    // Object ids are the sequence's ids, and normals unit length where something was rendered.
    let ids = trand_io::read_gray16(&dir.join("run0_render/test000000_ids.png")).unwrap();
    let seq = read_sequence_with(dir.join("seq"), &LoadOptions::cameras_only()).unwrap();
    assert!(ids.data.iter().any(|&i| i != 0));
    assert!(
        ids.data
            .iter()
            .all(|&i| i == 0 || seq.object_ids.is_empty() || i < 16)
    );

    // A bad camera file: the field is named, the exit is non-zero, nothing is written.
    let good: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("run0_cams.json")).unwrap())
            .unwrap();
    let mut zero = good.clone();
    zero[0]["width"] = 0.into();
    let mut nan = good.clone();
    nan[0]["K"][2][2] = 12345.678.into();
    let nan = serde_json::to_string(&nan)
        .unwrap()
        .replace("12345.678", "NaN");
    for (what, text, field) in [
        (
            "zero size",
            serde_json::to_string(&zero).unwrap(),
            "[0].width",
        ),
        ("NaN", nan, "[0].K[2][2]"),
    ] {
        std::fs::write(dir.join("bad.json"), &text).unwrap();
        let out = trand_in(
            dir,
            &[
                "render",
                "--run",
                "run0",
                "--cameras",
                "bad.json",
                "--out",
                "bad_out",
            ],
        );
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{what}: accepted");
        assert!(
            err.contains("bad.json") && err.contains(field),
            "{what}: {err}"
        );
        assert!(!dir.join("bad_out").exists(), "{what}: output left behind");
    }
}
