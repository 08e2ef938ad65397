//! Test helpers: running the real `trand` ([`trand_in`], [`ok`], [`fails_with`], [`tiny_run`]), a tiny
//! BOP sequence with ready-made predictions, and a stand-in `trand` script that fakes `synth`,
//! `reconstruct` and `update` (copying those predictions) while `eval` is the real one.

#![allow(dead_code)]

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::Output;

use serde_json::json;
use trand_io::{Image, State};

pub const W: u32 = 8;
pub const H: u32 = 6;

fn write_json(p: &Path, v: &serde_json::Value) {
    std::fs::create_dir_all(p.parent().unwrap()).unwrap();
    std::fs::write(p, serde_json::to_string_pretty(v).unwrap()).unwrap();
}

/// Object 1: left half; object 2: bottom-right corner (absent at t1, removed).
fn instance(state: State) -> Image<u16> {
    let mut m = Image::filled(W, H, 1, 0u16);
    for y in 0..H {
        for x in 0..W {
            if x < W / 2 && y > 0 {
                m.set(x, y, 0, 1);
            } else if x >= W - 2 && y >= H - 2 && state == State::T0 {
                m.set(x, y, 0, 2);
            }
        }
    }
    m
}

fn depth(frame: u32) -> Image<f32> {
    Image::from_vec(
        W,
        H,
        1,
        (0..W * H)
            .map(|i| 0.4 + 0.01 * i as f32 + 0.05 * frame as f32)
            .collect(),
    )
    .unwrap()
}

/// A BOP sequence at `root`: train_0 frames 0, 1, 3; train_1 frame 0; test_0 and test_1 frames 0, 1.
/// `root/fake_pred/{t0,t1}/{frame:06}.npy` hold predictions: GT + 1 cm at t0, GT + 3 cm at t1 (frame 0),
/// exact GT for frame 1. `sequence.json` names object 1 an upright bowl and object 2 an inverted mug.
pub fn sequence(root: &Path) {
    let splits = [
        ("train_0", State::T0, vec![0u32, 1, 3]),
        ("train_1", State::T1, vec![0]),
        ("test_0", State::T0, vec![0, 1]),
        ("test_1", State::T1, vec![0, 1]),
    ];
    for (folder, state, frames) in splits {
        let d = root.join(folder);
        let mut cams = serde_json::Map::new();
        for &f in &frames {
            cams.insert(
                f.to_string(),
                json!({"cam_K": [10.0, 0.0, 3.5, 0.0, 10.0, 2.5, 0.0, 0.0, 1.0],
                       "cam_R_w2c": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
                       "cam_t_w2c": [0.0, 0.0, 500.0 + f as f64], "depth_scale": 1.0, "width": W, "height": H}),
            );
            let rgb = Image::from_vec(
                W,
                H,
                3,
                (0..W * H * 3).map(|i| (i * 5 + f * 40) as u8).collect(),
            )
            .unwrap();
            trand_io::write_rgb_png(&d.join(format!("rgb/{f:06}.png")), &rgb).unwrap();
            let gt = depth(f);
            trand_io::write_depth_png_mm(&d.join(format!("depth/{f:06}.png")), &gt).unwrap();
            let inst = instance(state);
            for id in inst.ids() {
                let m = Image::from_vec(
                    W,
                    H,
                    1,
                    inst.data
                        .iter()
                        .map(|&v| if v == id { 255 } else { 0 })
                        .collect(),
                )
                .unwrap();
                trand_io::write_gray8_png(&d.join(format!("mask_visib/{f:06}_{id:06}.png")), &m)
                    .unwrap();
            }
            if folder.starts_with("test") {
                // GT as stored (millimetre rounding), plus the offset.
                let stored =
                    trand_io::read_depth_png(&d.join(format!("depth/{f:06}.png")), 1.0).unwrap();
                let off = match (state, f) {
                    (_, 1) => 0.0,
                    (State::T0, _) => 0.01,
                    (State::T1, _) => 0.03,
                };
                let pred = Image {
                    data: stored.data.iter().map(|&g| g + off).collect(),
                    ..stored
                };
                let p = root.join(format!("fake_pred/{}/{f:06}.npy", state.as_str()));
                trand_io::write_npy_f32(&p, &pred).unwrap();
            }
        }
        write_json(
            &d.join("scene_camera.json"),
            &serde_json::Value::Object(cams),
        );
    }
    write_json(
        &root.join("sequence.json"),
        &json!({"removed_obj_id": 2, "objects": [
            {"id": 1, "kind": "bowl", "params_m": {"initial_mode": "upright"}},
            {"id": 2, "kind": "mug", "params_m": {"initial_mode": "inverted"}}]}),
    );
}

/// The stand-in `trand`: appends its subcommand to `$FAKE_LOG`; `synth` copies `$FAKE_SEQ`;
/// `reconstruct` / `update` write `run.json`, copy the fake predictions and an objects PNG; a
/// `reconstruct --method $FAKE_FAIL` fails; `eval` runs `$REAL_TRAND eval`.
pub const FAKE_TRAND: &str = r#"#!/bin/sh
set -e
sub=$1; shift
echo "$sub" >> "$FAKE_LOG"
[ "$sub" = eval ] && exec "$REAL_TRAND" eval "$@"
out=; data=; method=trand; views=6; state=t0
while [ $# -gt 0 ]; do
  case $1 in
    --out) out=$2; shift 2;;
    --data) data=$2; shift 2;;
    --method) method=$2; shift 2;;
    --views) views=$2; shift 2;;
    *) shift;;
  esac
done
case $sub in
  synth) rm -rf "$out"; cp -r "$FAKE_SEQ" "$out";;
  reconstruct|update)
    if [ "$sub" = reconstruct ] && [ "$method" = "$FAKE_FAIL" ]; then echo "fake failure of $method" >&2; exit 3; fi
    [ "$sub" = update ] && state=t1
    mkdir -p "$out/depth" "$out/objects"
    cp "$data/fake_pred/$state/"*.npy "$out/depth/"
    for f in "$out/depth/"*.npy; do b=$(basename "$f" .npy); cp "$data/test_0/rgb/000000.png" "$out/objects/$b.png"; done
    if [ $state = t0 ]; then
      echo "{\"state\": \"t0\", \"method\": \"$method\", \"views\": $views, \"timings\": {\"preprocess_s\": 1.5, \"optimise_s\": $views, \"total_s\": 8}, \"num_surfels\": 1000, \"loss_curve\": [[0, 1.0], [100, 0.5], [200, 0.3]], \"peak_rss_mb\": 50}" > "$out/run.json"
    else
      echo "{\"state\": \"t1\", \"timings\": {\"detection_s\": 0.5, \"meshing_s\": 1, \"simulation_s\": 2, \"refinement_s\": 3, \"total_s\": 6.5}, \"num_surfels\": 900}" > "$out/run.json"
    fi
    echo "fake $sub done";;
  *) echo "fake trand: unknown subcommand $sub" >&2; exit 2;;
esac
"#;

/// A scratch folder with a sequence `seq_a`, a second `seq_b`, and the fake script.
pub struct Fixture {
    pub dir: trand_io::ScratchDir,
}

impl Fixture {
    pub fn new(tag: &str) -> Self {
        let dir = trand_io::ScratchDir::new(tag).unwrap();
        sequence(&dir.path().join("seq_a"));
        sequence(&dir.path().join("seq_b"));
        let script = dir.path().join("fake-trand.sh");
        std::fs::write(&script, FAKE_TRAND).unwrap();
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&script, std::fs::Permissions::from_mode(0o755)).unwrap();
        Self { dir }
    }

    pub fn path(&self) -> &Path {
        self.dir.path()
    }

    pub fn seq(&self, name: &str) -> PathBuf {
        self.path().join(name)
    }

    /// Subcommands the fake script ran so far, one per line.
    pub fn calls(&self) -> Vec<String> {
        std::fs::read_to_string(self.path().join("calls.log"))
            .unwrap_or_default()
            .lines()
            .map(String::from)
            .collect()
    }

    /// Runs the real `trand` with `args`, its steps going to the fake script.
    pub fn trand(&self, args: &[&str], fail_method: &str) -> Output {
        std::process::Command::new(env!("CARGO_BIN_EXE_trand"))
            .args(args)
            .env("TRAND_BIN", self.path().join("fake-trand.sh"))
            .env("REAL_TRAND", env!("CARGO_BIN_EXE_trand"))
            .env("FAKE_LOG", self.path().join("calls.log"))
            .env("FAKE_SEQ", self.seq("seq_a"))
            .env("FAKE_FAIL", fail_method)
            .output()
            .unwrap()
    }
}

pub fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

/// Runs the real `trand` with `args` in the folder `cwd`.
pub fn trand_in<S: AsRef<OsStr>>(cwd: &Path, args: &[S]) -> Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_trand"))
        .args(args)
        .current_dir(cwd)
        .output()
        .unwrap()
}

/// The output of a run that must have succeeded (the assertion shows it otherwise).
pub fn ok(out: Output) -> String {
    let t = text(&out);
    assert!(out.status.success(), "{t}");
    t
}

/// Asserts that a run failed (non-zero, not a panic) with every one of `needles` in its output.
pub fn fails_with(o: &Output, needles: &[&str]) {
    let t = text(o);
    assert!(!o.status.success(), "succeeded: {t}");
    assert!(!t.contains("panicked"), "panicked: {t}");
    for n in needles {
        assert!(t.contains(n), "`{n}` not in: {t}");
    }
}

/// In `dir`: a tiny generated sequence `seq` (`trand synth --preset tiny --seed 3`) and its t = 0 run
/// `run0` after `iterations` training iterations.
pub fn tiny_run(dir: &Path, iterations: u32) {
    ok(trand_in(
        dir,
        &["synth", "--preset", "tiny", "--seed", "3", "--out", "seq"],
    ));
    ok(trand_in(
        dir,
        &[
            "reconstruct",
            "--data",
            "seq",
            "--out",
            "run0",
            "--iterations",
            &iterations.to_string(),
        ],
    ));
}
