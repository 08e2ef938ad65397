//! The containers family (`Preset::ContainersTiny`, the 640×480 family's scenes at 160×120),
//! checked from the written files alone: what the scenes contain, that a leaning object really
//! touches its support with its foot on the table and falls and turns at t = 1, that lying
//! tumblers rest on their side, that nothing else moves at t = 1, and that the bytes do not
//! depend on the thread count. Run with `cargo test --release -p trand-synth`.

use glam::{DMat3, DVec3};
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use trand_synth::contact::closest_point_on_triangle;
use trand_synth::{Preset, SynthConfig, generate};

/// Lowest point of an object resting on the table (mm): rapier's resting contacts sink hulls
/// by up to ~0.8 mm, and the hulls contain the glass.
const ON_TABLE_MM: std::ops::Range<f64> = -1.0..1.0;

/// Seeds generated once and shared by the tests (enough to hold leans, stacks and lying
/// tumblers; the tests check that they do).
const SEEDS: std::ops::Range<u64> = 0..6;

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!(
        "trand-synth-containers-{}-{name}",
        std::process::id()
    ));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The shared sequences: `(seed, folder, sequence.json)`, kept under cargo's scratch folder
/// for integration tests.
fn scenes() -> &'static [(u64, PathBuf, Value)] {
    static SCENES: OnceLock<Vec<(u64, PathBuf, Value)>> = OnceLock::new();
    SCENES.get_or_init(|| {
        let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("trand-synth-containers");
        let _ = std::fs::remove_dir_all(&dir);
        SEEDS
            .map(|seed| {
                let out = dir.join(format!("seq_{seed}"));
                generate(&SynthConfig::new(Preset::ContainersTiny, seed, &out)).unwrap();
                let seq = json(&out.join("sequence.json"));
                (seed, out, seq)
            })
            .collect()
    })
}

fn json(p: &Path) -> Value {
    serde_json::from_str(
        &std::fs::read_to_string(p).unwrap_or_else(|e| panic!("{}: {e}", p.display())),
    )
    .unwrap()
}

fn numbers(v: &Value) -> Vec<f64> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect()
}

/// World pose (rotation, translation in mm) from a `pose_t0`/`pose_t1` entry.
fn pose(v: &Value) -> (DMat3, DVec3) {
    let r = numbers(&v["R_m2w"]);
    let t = numbers(&v["t_m2w_mm"]);
    (
        DMat3::from_cols_array(&[r[0], r[3], r[6], r[1], r[4], r[7], r[2], r[5], r[8]]),
        DVec3::new(t[0], t[1], t[2]),
    )
}

/// Vertices (mm) and triangles of an ASCII PLY written by the generator.
fn ply(p: &Path) -> (Vec<DVec3>, Vec<[usize; 3]>) {
    let text = std::fs::read_to_string(p).unwrap();
    let count = |key: &str| -> usize {
        text.lines()
            .find_map(|l| l.strip_prefix(key))
            .unwrap()
            .trim()
            .parse()
            .unwrap()
    };
    let (nv, nf) = (count("element vertex "), count("element face "));
    let mut lines = text.split("end_header\n").nth(1).unwrap().lines();
    let vertices = (&mut lines)
        .take(nv)
        .map(|l| {
            let v: Vec<f64> = l
                .split_whitespace()
                .take(3)
                .map(|x| x.parse().unwrap())
                .collect();
            DVec3::new(v[0], v[1], v[2])
        })
        .collect();
    let faces = lines
        .take(nf)
        .map(|l| {
            let f: Vec<usize> = l
                .split_whitespace()
                .skip(1)
                .map(|x| x.parse().unwrap())
                .collect();
            [f[0], f[1], f[2]]
        })
        .collect();
    (vertices, faces)
}

fn object(seq: &Value, id: u64) -> &Value {
    seq["objects"]
        .as_array()
        .unwrap()
        .iter()
        .find(|o| o["id"].as_u64() == Some(id))
        .unwrap()
}

/// An object's mesh vertices (mm, world) in a state (`pose_t0` or `pose_t1`), and its triangles.
fn placed(dir: &Path, seq: &Value, id: u64, state: &str) -> (Vec<DVec3>, Vec<[usize; 3]>) {
    let (r, t) = pose(&object(seq, id)[state]);
    let (v, f) = ply(&dir.join(format!("models/obj_{id:06}.ply")));
    (v.into_iter().map(|p| r * p + t).collect(), f)
}

/// Smallest distance (mm) from the vertices of `a` to the triangles of `b`, both ways.
fn mesh_gap_mm(a: &(Vec<DVec3>, Vec<[usize; 3]>), b: &(Vec<DVec3>, Vec<[usize; 3]>)) -> f64 {
    let one_way = |from: &[DVec3], to: &(Vec<DVec3>, Vec<[usize; 3]>)| {
        let mut best = f64::MAX;
        for p in from {
            for t in &to.1 {
                let [x, y, z] = t.map(|i| to.0[i].as_vec3());
                let q = closest_point_on_triangle(p.as_vec3(), x, y, z);
                best = best.min(q.as_dvec3().distance(*p));
            }
        }
        best
    };
    one_way(&a.0, b).min(one_way(&b.0, a))
}

/// Angle (degrees) between a model's axis in the world and the vertical.
fn tilt_deg(r: &DMat3) -> f64 {
    r.z_axis.z.abs().min(1.0).acos().to_degrees()
}

fn is_open_container(kind: &str) -> bool {
    matches!(kind, "bowl" | "mug" | "wine_glass")
}

#[test]
fn a_containers_scene_has_two_upright_open_containers_and_records_every_initial_mode() {
    for (seed, _, seq) in scenes() {
        let objects = seq["objects"].as_array().unwrap();
        assert!(
            (3..=6).contains(&objects.len()),
            "seed {seed}: {} objects",
            objects.len()
        );
        assert_eq!(seq["resolution"]["width"], 160);
        let mut open = 0;
        for o in objects {
            let kind = o["kind"].as_str().unwrap();
            let mode = o["params_m"]["initial_mode"].as_str().unwrap();
            assert!(
                ["upright", "inverted", "lying", "tilted"].contains(&mode),
                "seed {seed}: mode {mode}"
            );
            assert_eq!(o["initial_mode"].as_str(), Some(mode));
            if mode == "upright" && is_open_container(kind) {
                open += 1;
            }
        }
        assert!(open >= 2, "seed {seed}: {open} upright open containers");
        let relation = &seq["relation_t0"];
        assert!(
            ["stack", "lean"].contains(&relation["type"].as_str().unwrap()),
            "seed {seed}: {relation}"
        );
        assert_eq!(relation["verified"], true, "seed {seed}: {relation}");
        assert_eq!(seq["removed_obj_id"], relation["support_obj_id"]);
    }
    let kinds: Vec<&str> = scenes()
        .iter()
        .map(|(_, _, s)| s["relation_t0"]["type"].as_str().unwrap())
        .collect();
    assert!(
        kinds.contains(&"lean") && kinds.contains(&"stack"),
        "seeds {SEEDS:?} should hold both events: {kinds:?}"
    );
}

#[test]
fn a_leaning_object_touches_its_support_with_its_foot_on_the_table_tilted_over_15_degrees() {
    let mut leans = 0;
    for (seed, dir, seq) in scenes() {
        let relation = &seq["relation_t0"];
        if relation["type"] != "lean" {
            continue;
        }
        leans += 1;
        let (s, l) = (
            relation["support_obj_id"].as_u64().unwrap(),
            relation["supported_obj_id"].as_u64().unwrap(),
        );
        assert_eq!(object(seq, l)["params_m"]["initial_mode"], "tilted");
        let leaner = placed(dir, seq, l, "pose_t0");
        let support = placed(dir, seq, s, "pose_t0");
        let gap = mesh_gap_mm(&leaner, &support);
        assert!(
            gap < 1.0,
            "seed {seed}: the leaning glass floats {gap:.2} mm away"
        );
        let foot = leaner.0.iter().map(|p| p.z).fold(f64::MAX, f64::min);
        assert!(
            ON_TABLE_MM.contains(&foot),
            "seed {seed}: lowest point at {foot:.2} mm"
        );
        let (r, _) = pose(&object(seq, l)["pose_t0"]);
        assert!(tilt_deg(&r) > 15.0, "seed {seed}: tilt {:.1}", tilt_deg(&r));
        let (rs, _) = pose(&object(seq, s)["pose_t0"]);
        assert!(tilt_deg(&rs) < 5.0, "seed {seed}: the support tilts");
    }
    assert!(leans > 0, "no lean among seeds {SEEDS:?}");
}

#[test]
fn the_supported_object_falls_at_t1_and_a_leaning_one_turns() {
    for (seed, dir, seq) in scenes() {
        let relation = &seq["relation_t0"];
        let l = relation["supported_obj_id"].as_u64().unwrap();
        let moved = &seq["displacement_t0_to_t1"][l.to_string()];
        let (drop, turn) = (
            moved["translation_mm"].as_f64().unwrap(),
            moved["rotation_deg"].as_f64().unwrap(),
        );
        assert!(drop > 10.0, "seed {seed}: moved only {drop:.1} mm");
        let at1 = placed(dir, seq, l, "pose_t1");
        let lowest = at1.0.iter().map(|p| p.z).fold(f64::MAX, f64::min);
        assert!(
            ON_TABLE_MM.contains(&lowest),
            "seed {seed}: at t=1 its lowest point is at {lowest:.2} mm"
        );
        if relation["type"] == "lean" {
            assert!(turn > 15.0, "seed {seed}: turned only {turn:.1} degrees");
            let (r0, _) = pose(&object(seq, l)["pose_t0"]);
            let (r1, _) = pose(&object(seq, l)["pose_t1"]);
            assert!(
                tilt_deg(&r1) > tilt_deg(&r0) + 10.0,
                "seed {seed}: tilt {:.1} -> {:.1}",
                tilt_deg(&r0),
                tilt_deg(&r1)
            );
        }
    }
}

#[test]
fn lying_tumblers_rest_on_their_side() {
    let mut lying = 0;
    for (seed, dir, seq) in scenes() {
        for o in seq["objects"].as_array().unwrap() {
            if o["params_m"]["initial_mode"] != "lying" {
                continue;
            }
            lying += 1;
            let id = o["id"].as_u64().unwrap();
            assert_eq!(o["kind"], "tumbler");
            let (r, _) = pose(&o["pose_t0"]);
            // The axis is horizontal up to the taper of the wall (a few degrees).
            assert!(
                tilt_deg(&r) > 80.0,
                "seed {seed} obj {id}: tilt {:.1}",
                tilt_deg(&r)
            );
            let (v, _) = placed(dir, seq, id, "pose_t0");
            let lowest = v.iter().map(|p| p.z).fold(f64::MAX, f64::min);
            assert!(
                ON_TABLE_MM.contains(&lowest),
                "seed {seed} obj {id}: lowest point at {lowest:.2} mm"
            );
        }
    }
    assert!(lying > 0, "no lying tumbler among seeds {SEEDS:?}");
}

#[test]
fn at_t1_only_the_objects_a_falling_one_touches_move() {
    for (seed, _, seq) in scenes() {
        let simulated: Vec<String> = seq["physics"]["t1_simulated_obj_ids"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.to_string())
            .collect();
        assert!(simulated.contains(&seq["relation_t0"]["supported_obj_id"].to_string()));
        for (id, d) in seq["displacement_t0_to_t1"].as_object().unwrap() {
            if !simulated.contains(id) {
                assert_eq!(d["static_snapped"], true, "seed {seed} obj {id}: {d}");
                assert_eq!(d["translation_mm"], 0.0, "seed {seed} obj {id}");
            }
        }
    }
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
fn a_containers_scene_is_identical_for_one_and_two_threads() {
    let dir = scratch("determinism");
    let run = |threads: usize, name: &str| {
        let out = dir.join(name);
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| generate(&SynthConfig::new(Preset::ContainersTiny, 4, &out)))
            .unwrap();
        all_files(&out)
    };
    let (a, b) = (run(1, "a"), run(2, "b"));
    assert_eq!(a.len(), b.len());
    for ((pa, da), (pb, db)) in a.iter().zip(&b) {
        assert_eq!(pa, pb);
        assert!(da == db, "{} differs between runs", pa.display());
    }
    let _ = std::fs::remove_dir_all(&dir);
}
