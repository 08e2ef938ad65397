//! End-to-end checks of `generate` with the tiny preset: masks agree with depth, the table depth is
//! exact, runs are bit-identical for any thread count, the layout matches the reference data (ignored
//! unless asked for: it needs `../shared/data/blender/seq_101`), and bad settings fail cleanly. Run with
//! `cargo test --release -p trand-synth`.

#[path = "../../../testdata/shared_data.rs"]
mod shared_data;

use glam::{DMat3, DVec3};
use serde_json::Value;
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use trand_synth::{ExistingOutput, ObjectCount, Preset, SynthConfig, SynthError, generate};

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("trand-synth-test-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn tiny(seed: u64, out: &Path) -> SynthConfig {
    SynthConfig::new(Preset::Tiny, seed, out)
}

fn json(p: &Path) -> Value {
    serde_json::from_str(
        &std::fs::read_to_string(p).unwrap_or_else(|e| panic!("{}: {e}", p.display())),
    )
    .unwrap()
}

/// Vertices (mm) of an ASCII PLY written by the generator.
fn ply_vertices(p: &Path) -> Vec<DVec3> {
    let text = std::fs::read_to_string(p).unwrap();
    let n: usize = text
        .lines()
        .find_map(|l| l.strip_prefix("element vertex "))
        .unwrap()
        .trim()
        .parse()
        .unwrap();
    let body = text.split("end_header\n").nth(1).unwrap();
    body.lines()
        .take(n)
        .map(|l| {
            let v: Vec<f64> = l
                .split_whitespace()
                .take(3)
                .map(|x| x.parse().unwrap())
                .collect();
            DVec3::new(v[0], v[1], v[2])
        })
        .collect()
}

fn numbers(v: &Value) -> Vec<f64> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect()
}

fn mat(v: &Value) -> DMat3 {
    let a = numbers(v);
    DMat3::from_cols_array(&[a[0], a[3], a[6], a[1], a[4], a[7], a[2], a[5], a[8]])
}

fn vec3(v: &Value) -> DVec3 {
    let a = numbers(v);
    DVec3::new(a[0], a[1], a[2])
}

#[test]
fn every_mask_pixel_has_its_objects_depth_and_the_rest_is_exact_table_depth() {
    let dir = scratch("masks");
    let out = dir.join("seq");
    generate(&tiny(11, &out)).unwrap();
    let models: Vec<(u64, Vec<DVec3>)> = (1..=3)
        .map(|id| {
            (
                id,
                ply_vertices(&out.join(format!("models/obj_{id:06}.ply"))),
            )
        })
        .collect();
    let mut mask_px = 0;
    for split in ["train_0", "test_0", "train_1", "test_1"] {
        let cams = json(&out.join(split).join("scene_camera.json"));
        let gts = json(&out.join(split).join("scene_gt.json"));
        for (frame, cam) in cams.as_object().unwrap() {
            let f: u32 = frame.parse().unwrap();
            let (w, h) = (
                cam["width"].as_u64().unwrap() as u32,
                cam["height"].as_u64().unwrap() as u32,
            );
            let k: Vec<f64> = cam["cam_K"]
                .as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_f64().unwrap())
                .collect();
            let (r, t) = (mat(&cam["cam_R_w2c"]), vec3(&cam["cam_t_w2c"]));
            let depth = image::open(out.join(split).join(format!("depth/{f:06}.png")))
                .unwrap()
                .into_luma16();
            let mut covered = vec![false; (w * h) as usize];
            for gt in gts[frame].as_array().unwrap() {
                let id = gt["obj_id"].as_u64().unwrap();
                let (rm, tm) = (mat(&gt["cam_R_m2c"]), vec3(&gt["cam_t_m2c"]));
                let verts = &models.iter().find(|m| m.0 == id).unwrap().1;
                let zs: Vec<f64> = verts.iter().map(|v| (rm * *v + tm).z).collect();
                let (zmin, zmax) = (
                    zs.iter().cloned().fold(f64::MAX, f64::min),
                    zs.iter().cloned().fold(f64::MIN, f64::max),
                );
                let mask = image::open(
                    out.join(split)
                        .join(format!("mask_visib/{f:06}_{id:06}.png")),
                )
                .unwrap()
                .into_luma8();
                for (i, m) in mask.pixels().enumerate() {
                    match m.0[0] {
                        0 => {}
                        255 => {
                            assert!(!covered[i], "{split}/{f}: pixel {i} in two masks");
                            covered[i] = true;
                            let d = depth.as_raw()[i] as f64;
                            assert!(
                                d >= zmin - 1.0 && d <= zmax + 1.0,
                                "{split}/{f} obj {id}: depth {d} outside [{zmin:.1}, {zmax:.1}]"
                            );
                            mask_px += 1;
                        }
                        v => panic!("mask value {v} is neither 0 nor 255"),
                    }
                }
            }
            // Pixels in no mask see the table (exact planar depth) or nothing (0).
            let c = -(r.transpose() * t) / 1000.0;
            for (i, d) in depth.as_raw().iter().enumerate() {
                if covered[i] {
                    continue;
                }
                let (x, y) = ((i as u32 % w) as f64, (i as u32 / w) as f64);
                let ray = r.transpose() * DVec3::new((x - k[2]) / k[0], (y - k[5]) / k[4], 1.0);
                let s = -c.z / ray.z;
                let p = c + s * ray;
                let want = if s > 0.0 && p.x.abs() <= 0.5 && p.y.abs() <= 0.5 {
                    1000.0 * s
                } else {
                    0.0
                };
                assert!(
                    (*d as f64 - want).abs() <= 0.5 + 2e-3,
                    "{split}/{f} pixel ({x}, {y}): {d} vs table {want:.3}"
                );
            }
        }
    }
    assert!(
        mask_px > 1000,
        "objects should be visible ({mask_px} mask pixels)"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

fn all_files(root: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.push((
                    p.strip_prefix(root).unwrap().to_path_buf(),
                    std::fs::read(&p).unwrap(),
                ));
            }
        }
    }
    out.sort();
    out
}

#[test]
fn the_same_seed_gives_identical_bytes_for_one_and_two_threads() {
    let dir = scratch("determinism");
    let run = |threads: usize, name: &str| {
        let out = dir.join(name);
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| generate(&tiny(42, &out))).unwrap();
        all_files(&out)
    };
    let a = run(1, "a");
    let b = run(2, "b");
    assert_eq!(a.len(), b.len());
    for ((pa, da), (pb, db)) in a.iter().zip(&b) {
        assert_eq!(pa, pb);
        assert!(da == db, "{} differs between runs", pa.display());
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// The keys of a JSON object.
fn keys(v: &Value) -> BTreeSet<String> {
    v.as_object()
        .unwrap_or_else(|| panic!("not an object: {v}"))
        .keys()
        .cloned()
        .collect()
}

#[test]
#[ignore = "needs ../shared/data/blender (see README: Tests)"]
fn output_layout_matches_the_reference_blender_sequence() {
    let reference = shared_data::shared_data("blender/seq_101");
    let dir = scratch("layout");
    let out = dir.join("seq");
    let mut cfg = tiny(101, &out);
    cfg.objects = ObjectCount::Exactly(4);
    generate(&cfg).unwrap();
    let names = |p: &Path| -> BTreeSet<String> {
        std::fs::read_dir(p)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|n| n != "render_stats.json" && n != trand_io::output::MARKER)
            .collect()
    };
    assert_eq!(names(&out), names(&reference), "top-level entries");
    assert_eq!(
        names(&out.join("models")),
        names(&reference.join("models")),
        "model files (4 objects each)"
    );
    let info = |p: &Path| json(&p.join("models/models_info.json"));
    assert_eq!(keys(&info(&out)["1"]), keys(&info(&reference)["1"]));
    for split in ["train_0", "test_0", "train_1", "test_1"] {
        let (ours, theirs) = (out.join(split), reference.join(split));
        assert_eq!(names(&ours), names(&theirs), "{split} entries");
        for file in ["scene_camera.json", "scene_gt.json", "scene_gt_info.json"] {
            let (a, b) = (json(&ours.join(file)), json(&theirs.join(file)));
            let (ea, eb) = (&a["0"], &b["0"]);
            if ea.is_array() {
                assert_eq!(keys(&ea[0]), keys(&eb[0]), "{split}/{file} entry keys");
                for k in keys(&eb[0]) {
                    assert_eq!(
                        std::mem::discriminant(&ea[0][&k]),
                        std::mem::discriminant(&eb[0][&k]),
                        "{split}/{file}: type of {k}"
                    );
                }
            } else {
                assert_eq!(keys(ea), keys(eb), "{split}/{file} keys");
                for k in keys(eb) {
                    assert_eq!(
                        std::mem::discriminant(&ea[&k]),
                        std::mem::discriminant(&eb[&k]),
                        "{split}/{file}: type of {k}"
                    );
                }
            }
        }
        // Same image kinds: 8-bit RGB colour, 16-bit depth, 8-bit masks named by obj_id.
        let first = |sub: &str| {
            std::fs::read_dir(ours.join(sub))
                .unwrap()
                .map(|e| e.unwrap().path())
                .min()
                .unwrap()
        };
        assert_eq!(
            image::open(first("rgb")).unwrap().color(),
            image::ColorType::Rgb8
        );
        assert_eq!(
            image::open(first("depth")).unwrap().color(),
            image::ColorType::L16
        );
        assert_eq!(
            image::open(first("mask_visib")).unwrap().color(),
            image::ColorType::L8
        );
        let n_frames = json(&ours.join("scene_camera.json"))
            .as_object()
            .unwrap()
            .len();
        assert_eq!(
            std::fs::read_dir(ours.join("rgb")).unwrap().count(),
            n_frames
        );
    }
    assert_eq!(
        json(&out.join("train_0/scene_camera.json"))
            .as_object()
            .unwrap()
            .len(),
        13
    );
    assert_eq!(
        json(&out.join("train_1/scene_camera.json"))
            .as_object()
            .unwrap()
            .len(),
        1
    );
    // sequence.json: the fields consumers read.
    let (a, b) = (
        json(&out.join("sequence.json")),
        json(&reference.join("sequence.json")),
    );
    for k in [
        "seed",
        "resolution",
        "intrinsics",
        "objects",
        "relation_t0",
        "removed_obj_id",
        "removed_obj_kind",
        "displacement_t0_to_t1",
        "workspace_center_m",
        "cameras",
    ] {
        assert!(a.get(k).is_some(), "sequence.json lacks {k}");
    }
    for k in [
        "id",
        "kind",
        "transparent",
        "model",
        "material",
        "mass_kg",
        "params_m",
        "pose_t0",
        "pose_t1",
        "removed_at_t1",
    ] {
        assert!(
            a["objects"][0].get(k).is_some() && b["objects"][0].get(k).is_some(),
            "objects[0].{k}"
        );
    }
    let moved = a["displacement_t0_to_t1"]
        .as_object()
        .unwrap()
        .values()
        .next()
        .unwrap();
    for k in ["translation_mm", "rotation_deg"] {
        assert!(moved[k].is_f64(), "displacement.{k}");
    }
    assert_eq!(
        keys(&a["cameras"]["train_ring"]),
        keys(&b["cameras"]["train_ring"])
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_settings_and_occupied_outputs_fail_with_a_named_reason_and_leave_nothing() {
    let dir = scratch("errors");
    let out = dir.join("seq");
    for (field, edit) in [
        (
            "width",
            Box::new(|c: &mut SynthConfig| c.width = 0) as Box<dyn Fn(&mut SynthConfig)>,
        ),
        ("height", Box::new(|c: &mut SynthConfig| c.height = 0)),
        (
            "objects",
            Box::new(|c: &mut SynthConfig| c.objects = ObjectCount::Exactly(0)),
        ),
        (
            "objects",
            Box::new(|c: &mut SynthConfig| c.objects = ObjectCount::Exactly(7)),
        ),
    ] {
        let mut c = tiny(1, &out);
        edit(&mut c);
        match generate(&c) {
            Err(SynthError::InvalidConfig { field: f, .. }) => assert_eq!(f, field),
            other => panic!("expected an error for {field}, got {other:?}"),
        }
    }
    // A folder below a regular file cannot be created.
    let file = dir.join("a_file");
    std::fs::write(&file, b"x").unwrap();
    assert!(matches!(
        generate(&tiny(1, &file.join("seq"))),
        Err(SynthError::OutputUnwritable { .. })
    ));
    // Non-empty output: refused without Replace; with it, replaced only if trand wrote it.
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("keep.txt"), b"mine").unwrap();
    assert!(matches!(
        generate(&tiny(1, &out)),
        Err(SynthError::OutputNotEmpty { .. })
    ));
    assert!(out.join("keep.txt").exists());
    let mut c = tiny(1, &out);
    c.existing = ExistingOutput::Replace;
    assert!(matches!(generate(&c), Err(SynthError::Output(_))));
    assert!(
        out.join("keep.txt").exists(),
        "a folder trand did not write was touched"
    );
    std::fs::remove_dir_all(&out).unwrap();
    generate(&tiny(1, &out)).unwrap();
    assert!(out.join(trand_io::output::MARKER).is_file());
    std::fs::write(out.join("extra.txt"), b"from an earlier run").unwrap();
    generate(&c).unwrap();
    assert!(!out.join("extra.txt").exists() && out.join("sequence.json").exists());
    // No temporary folders are left next to the target.
    let leftovers: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains("synth-tmp") || n.contains("synth-old"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
    let _ = std::fs::remove_dir_all(&dir);
}
