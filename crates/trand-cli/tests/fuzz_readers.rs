//! Fuzz-style property tests of every reader (issue 21): arbitrary bytes and structured mutations of
//! valid files (numbers replaced by extreme ones, fields of the wrong type, truncations, flipped
//! bytes). Each reader must return `Ok` or an error, never panic or abort, and never ask the
//! allocator for more than a bound proportional to its input: a counting global allocator records
//! the largest single request made by the test's thread.
//!
//! Readers: surfel PLY, NPY, checkpoint, BOP `scene_camera.json`, the authors'
//! `transforms_sparse_*.json`, nerfstudio `transforms.json`, `run.json`'s `object_channels`, and the
//! TOML options of `trand reconstruct` and `trand update`.

#![allow(unsafe_code)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::path::Path;

use proptest::prelude::*;
use proptest::test_runner::{Config, TestRng, TestRunner};
use serde_json::{Value, json};
use trand_io::{Image, LoadOptions, ScratchDir, read_sequence_with};

/// The system allocator, recording the largest request of each thread.
struct Counting;

thread_local! {
    static LARGEST: Cell<usize> = const { Cell::new(0) };
}

// SAFETY: every call is forwarded unchanged to the system allocator; the thread-local cell is
// const-initialised, so recording a size allocates nothing.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = LARGEST.try_with(|c| c.set(c.get().max(layout.size())));
        // SAFETY: the caller's layout contract is passed on.
        unsafe { System.alloc(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` came from `System.alloc` with this layout.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let _ = LARGEST.try_with(|c| c.set(c.get().max(new_size)));
        // SAFETY: as for `alloc`; `ptr` came from this allocator.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOC: Counting = Counting;

/// Runs `f`, returning the largest single allocation it asked for.
fn largest_allocation(f: impl FnOnce()) -> usize {
    LARGEST.with(|c| c.set(0));
    f();
    LARGEST.with(Cell::get)
}

/// The allowance for reading `input` bytes: a fixed 8 MiB plus 64 bytes per input byte.
fn allowance(input: usize) -> usize {
    (8 << 20) + 64 * input
}

/// A runner with a fixed seed: every run tries the same cases, so a failure is reproducible.
fn runner(cases: u32) -> TestRunner {
    let config = Config {
        cases,
        failure_persistence: None,
        ..Config::default()
    };
    let rng = TestRng::deterministic_rng(config.rng_algorithm);
    TestRunner::new_with_rng(config, rng)
}

/// Numbers and values that break careless readers.
fn nasty() -> impl Strategy<Value = Value> {
    prop_oneof![
        Just(json!(0)),
        Just(json!(-1)),
        Just(json!(1e308)),
        Just(json!(-1e308)),
        Just(json!(5e-324)),
        Just(json!(4_294_967_296u64)),
        Just(json!(u64::MAX)),
        Just(json!(i64::MIN)),
        Just(json!(100_000)),
        Just(json!(65_536)),
        Just(json!(null)),
        Just(json!("x")),
        Just(json!([])),
        Just(json!({})),
        Just(json!([1e308, 0, 0])),
        any::<i32>().prop_map(|v| json!(v)),
        any::<f64>()
            .prop_filter("JSON numbers are finite", |v| v.is_finite())
            .prop_map(|v| json!(v)),
    ]
}

/// Every leaf of `v` (numbers, strings, booleans, null) and every array or object, as a path.
fn paths(v: &Value, at: &mut Vec<String>, out: &mut Vec<Vec<String>>) {
    out.push(at.clone());
    match v {
        Value::Object(m) => {
            for (k, c) in m {
                at.push(k.clone());
                paths(c, at, out);
                at.pop();
            }
        }
        Value::Array(a) => {
            for (i, c) in a.iter().enumerate() {
                at.push(i.to_string());
                paths(c, at, out);
                at.pop();
            }
        }
        _ => {}
    }
}

fn at_path<'a>(v: &'a mut Value, path: &[String]) -> &'a mut Value {
    path.iter().fold(v, |v, k| match v {
        Value::Object(m) => m.get_mut(k).expect("path exists"),
        Value::Array(a) => &mut a[k.parse::<usize>().expect("index")],
        _ => unreachable!("paths end at leaves"),
    })
}

/// `valid` with up to four of its values (leaves or whole subtrees) replaced by nasty ones.
fn mutate_json(valid: Value) -> impl Strategy<Value = Value> {
    let mut all = Vec::new();
    paths(&valid, &mut Vec::new(), &mut all);
    let n = all.len();
    prop::collection::vec((0..n, nasty()), 1..=4).prop_map(move |edits| {
        let mut v = valid.clone();
        for (i, new) in edits {
            // An earlier edit may have replaced an ancestor: skip paths that no longer exist.
            let p = &all[i];
            let exists = p
                .iter()
                .try_fold(&v, |v, k| match v {
                    Value::Object(m) => m.get(k),
                    Value::Array(a) => k.parse::<usize>().ok().and_then(|i| a.get(i)),
                    _ => None,
                })
                .is_some();
            if exists {
                *at_path(&mut v, p) = new;
            }
        }
        v
    })
}

/// Byte-level edits of `valid`: flipped bytes, a truncation, an inserted run of bytes.
fn mutate_bytes(valid: Vec<u8>) -> impl Strategy<Value = Vec<u8>> {
    let n = valid.len().max(1);
    (
        prop::collection::vec((0..n, any::<u8>()), 0..6),
        prop::option::of(0..n),
        prop::option::of((0..n, prop::collection::vec(any::<u8>(), 1..16))),
    )
        .prop_map(move |(flips, cut, insert)| {
            let mut b = valid.clone();
            for (i, x) in flips {
                if i < b.len() {
                    b[i] = x;
                }
            }
            if let Some((i, bytes)) = insert {
                let i = i.min(b.len());
                b.splice(i..i, bytes);
            }
            if let Some(c) = cut {
                b.truncate(c);
            }
            b
        })
}

/// Text edits of a header: numbers replaced by extreme ones.
fn mutate_numbers(valid: String) -> impl Strategy<Value = String> {
    let words: Vec<usize> = valid
        .match_indices(|c: char| c.is_ascii_digit())
        .map(|(i, _)| i)
        .collect();
    let n = words.len().max(1);
    let big = prop_oneof![
        Just("0".to_string()),
        Just("4611686018427387904".to_string()),
        Just("18446744073709551615".to_string()),
        Just("99999999999999999999999".to_string()),
        Just("1000000000000".to_string()),
        Just("-1".to_string()),
        Just("65".to_string()),
        Just("nan".to_string()),
    ];
    prop::collection::vec((0..n, big), 1..=3).prop_map(move |edits| {
        let mut s = valid.clone();
        for (i, new) in edits {
            let Some(&start) = words.get(i) else { continue };
            if start >= s.len() || !s.as_bytes()[start].is_ascii_digit() {
                continue;
            }
            let end = s[start..]
                .find(|c: char| !c.is_ascii_digit())
                .map_or(s.len(), |e| start + e);
            s.replace_range(start..end, &new);
        }
        s
    })
}

fn ply_sample() -> Vec<u8> {
    let mut s = trand_core::Surfels::new(1, 3).unwrap();
    for i in 0..3 {
        s.push(&trand_core::surfels::Surfel {
            mean: [i as f32, 0.5, -0.25],
            log_scale: [-3.0, -4.0],
            quat: [1.0, 0.0, 0.0, 0.0],
            opacity_logit: 0.5,
            sh_dc: [0.1; 3],
            mask_dc: [0.2; 3],
            obj_logits: vec![1.0, 0.0, -1.0],
        });
    }
    trand_io::ply::surfels_to_ply_bytes(&s)
}

/// Checks one reader call on `input`: no panic (proptest reports one), bounded allocation.
fn bounded(input: usize, f: impl FnOnce()) -> Result<(), TestCaseError> {
    let largest = largest_allocation(f);
    prop_assert!(
        largest <= allowance(input),
        "asked for {largest} bytes reading {input}"
    );
    Ok(())
}

#[test]
fn surfel_ply_reader_survives_arbitrary_and_mutated_files() {
    let read = |b: &[u8]| {
        bounded(b.len(), || {
            let _ = trand_io::ply::surfels_from_ply_bytes(b, Path::new("f.ply"));
        })
    };
    let valid = ply_sample();
    let header_end = valid
        .windows(11)
        .position(|w| w == b"end_header\n")
        .unwrap()
        + 11;
    let (header, body) = (
        String::from_utf8(valid[..header_end].to_vec()).unwrap(),
        valid[header_end..].to_vec(),
    );
    runner(1500)
        .run(&prop::collection::vec(any::<u8>(), 0..512), |b| {
            let mut with_magic = b"ply\nformat binary_little_endian 1.0\n".to_vec();
            with_magic.extend(&b);
            read(&b)?;
            read(&with_magic)
        })
        .unwrap();
    runner(1500)
        .run(&mutate_bytes(valid.clone()), |b| read(&b))
        .unwrap();
    runner(1500)
        .run(&mutate_numbers(header), |h| {
            let mut b = h.into_bytes();
            b.extend(&body);
            read(&b)
        })
        .unwrap();
    // A plain 2DGS layout (no obj_index properties: the channel count comes from the comment).
    let plain = "ply\nformat binary_little_endian 1.0\ncomment trand surfels sh_degree 0 num_objects 3\n\
                 element vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
                 property float f_dc_0\nproperty float f_dc_1\nproperty float f_dc_2\n\
                 property float opacity\nproperty float scale_0\nproperty float scale_1\n\
                 property float rot_0\nproperty float rot_1\nproperty float rot_2\nproperty float rot_3\n\
                 end_header\n";
    let mut b = plain.as_bytes().to_vec();
    b.extend([0u8; 3 * 13 * 4]);
    assert!(trand_io::ply::surfels_from_ply_bytes(&b, Path::new("p.ply")).is_ok());
    runner(1500)
        .run(&mutate_numbers(plain.to_string()), |h| {
            let mut b = h.into_bytes();
            b.extend([0u8; 3 * 13 * 4]);
            read(&b)
        })
        .unwrap();
}

#[test]
fn checkpoint_reader_survives_arbitrary_and_mutated_files() {
    use rand::SeedableRng;
    let s = trand_io::ply::surfels_from_ply_bytes(&ply_sample(), Path::new("s")).unwrap();
    let adam = trand_train::Adam::new(&s, trand_train::AdamParams::default());
    let stats = trand_train::DensifyStats::new(s.len());
    let rng = rand_pcg::Pcg64::seed_from_u64(1);
    let valid = trand_pipeline::checkpoint::Snapshot {
        iteration: 7,
        surfels: &s,
        adam: &adam,
        stats: &stats,
        rng: &rng,
        stack: &[1, 0],
        poses: &trand_train::PoseCorrections::new(2),
        curve: &[(1, 0.5)],
        initial_surfels: 3,
        fingerprint: "abc",
        options: "views = 6\n",
    }
    .encode();
    let read = |b: &[u8]| {
        bounded(b.len(), || {
            let _ = trand_pipeline::checkpoint::Checkpoint::decode(b, Path::new("c.bin"));
        })
    };
    runner(1000)
        .run(&prop::collection::vec(any::<u8>(), 0..256), |b| {
            let mut with_magic = b"TRAND-CHECKPOINT\n".to_vec();
            with_magic.extend(&b);
            read(&b)?;
            read(&with_magic)
        })
        .unwrap();
    runner(2000)
        .run(&mutate_bytes(valid.clone()), |b| read(&b))
        .unwrap();
    // Header fields replaced by extreme values, the sections kept.
    let hlen = u64::from_le_bytes(valid[17..25].try_into().unwrap()) as usize;
    let header: Value = serde_json::from_slice(&valid[25..25 + hlen]).unwrap();
    let sections = valid[25 + hlen..].to_vec();
    runner(1500)
        .run(&mutate_json(header), |h| {
            let h = serde_json::to_vec(&h).unwrap();
            let mut b = b"TRAND-CHECKPOINT\n".to_vec();
            b.extend((h.len() as u64).to_le_bytes());
            b.extend(&h);
            b.extend(&sections);
            read(&b)
        })
        .unwrap();
}

#[test]
fn npy_reader_survives_arbitrary_and_mutated_files() {
    let dir = ScratchDir::new("fuzz-npy").unwrap();
    let p = dir.path().join("d.npy");
    let img = Image::from_vec(3, 2, 1, vec![0.5f32; 6]).unwrap();
    trand_io::write_npy_f32(&p, &img).unwrap();
    let valid = std::fs::read(&p).unwrap();
    let read = |b: &[u8]| {
        std::fs::write(&p, b).unwrap();
        bounded(b.len(), || {
            let _ = trand_io::read_npy_f32(&p);
        })
    };
    runner(500)
        .run(&prop::collection::vec(any::<u8>(), 0..200), |b| read(&b))
        .unwrap();
    runner(1000)
        .run(&mutate_bytes(valid.clone()), |b| read(&b))
        .unwrap();
    let header_end = valid.iter().position(|&b| b == b'\n').unwrap() + 1;
    let header = String::from_utf8_lossy(&valid[10..header_end]).into_owned();
    let data = valid[header_end..].to_vec();
    runner(1000)
        .run(&mutate_numbers(header), |h| {
            let mut b = valid[..8].to_vec();
            b.extend((h.len() as u16).to_le_bytes());
            b.extend(h.as_bytes());
            b.extend(&data);
            read(&b)
        })
        .unwrap();
}

/// A dataset folder with `file` holding each mutation of `valid`; every read must end cleanly.
fn fuzz_sequence_json(dir: &Path, file: &str, valid: Value, cases: u32) {
    let path = dir.join(file);
    let read = |v: &Value| {
        let text = serde_json::to_vec(v).unwrap();
        std::fs::write(&path, &text).unwrap();
        bounded(text.len(), || {
            let _ = read_sequence_with(dir, &LoadOptions::default());
        })
    };
    read(&valid).unwrap();
    if let Err(e) = read_sequence_with(dir, &LoadOptions::default()) {
        panic!("the unmutated {file} must read: {e}");
    }
    runner(cases)
        .run(&mutate_json(valid), |v| read(&v))
        .unwrap();
    runner(cases / 4)
        .run(&prop::collection::vec(any::<u8>(), 0..128), |b| {
            std::fs::write(&path, &b).unwrap();
            bounded(b.len(), || {
                let _ = read_sequence_with(dir, &LoadOptions::default());
            })
        })
        .unwrap();
}

const W: u32 = 4;
const H: u32 = 3;

/// RGB, an 8-bit mask holding `mask_value` at one pixel (BOP masks are 0/255, id maps hold the id)
/// and depth, at the paths given relative to `root`.
fn small_images(root: &Path, rgb: &str, mask: Option<(&str, u8)>, depth: Option<&str>) {
    let c = Image::from_vec(
        W,
        H,
        3,
        (0..W * H * 3).map(|i| (i as u8).wrapping_mul(9)).collect(),
    )
    .unwrap();
    trand_io::write_rgb_png(&root.join(rgb), &c).unwrap();
    if let Some((m, value)) = mask {
        let mut img = Image::filled(W, H, 1, 0u8);
        img.set(1, 1, 0, value);
        trand_io::write_gray8_png(&root.join(m), &img).unwrap();
    }
    if let Some(d) = depth {
        let img = Image::from_vec(W, H, 1, vec![1000u16; (W * H) as usize]).unwrap();
        trand_io::write_gray16_png(&root.join(d), &img).unwrap();
    }
}

#[test]
fn bop_scene_camera_reader_survives_mutations() {
    let dir = ScratchDir::new("fuzz-bop").unwrap();
    let root = dir.path();
    small_images(
        root,
        "train_0/rgb/000000.png",
        Some(("train_0/mask_visib/000000_000002.png", 255)),
        Some("train_0/depth/000000.png"),
    );
    let valid = json!({"0": {"cam_K": [10.0, 0.0, 1.5, 0.0, 10.0, 1.0, 0.0, 0.0, 1.0],
        "cam_R_w2c": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        "cam_t_w2c": [0.0, 0.0, 1000.0], "depth_scale": 1.0, "width": W, "height": H}});
    fuzz_sequence_json(root, "train_0/scene_camera.json", valid, 600);
}

#[test]
fn authors_transforms_reader_survives_mutations() {
    let dir = ScratchDir::new("fuzz-tr").unwrap();
    let root = dir.path();
    small_images(
        root,
        "rgb/000004.png",
        Some(("class/000004.png", 2)),
        Some("depth/000004.png"),
    );
    let valid = json!({"num_obj": 1, "frames": [{"file_path": "rgb/000004.png",
        "class_path": "class/000004.png", "depth_path": "depth/000004.png",
        "transform_matrix": [[1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 1.0], [0.0, 0.0, 0.0, 1.0]],
        "cam": {"fl_x": 10.0, "fl_y": 11.0, "cx": 1.5, "cy": 1.0, "w": W, "h": H}, "obj_idx": [2]}]});
    fuzz_sequence_json(root, "transforms_sparse_train.json", valid, 600);
}

#[test]
fn nerfstudio_reader_survives_mutations() {
    let dir = ScratchDir::new("fuzz-ns").unwrap();
    let root = dir.path();
    small_images(
        root,
        "images/frame_00002.png",
        Some(("masks/frame_00002.png", 2)),
        None,
    );
    let valid = json!({"fl_x": 10.0, "fl_y": 10.0, "cx": 2.0, "cy": 1.5, "w": W, "h": H,
        "frames": [{"file_path": "images/frame_00002.png", "mask_path": "masks/frame_00002.png",
        "transform_matrix": [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 1.0], [0.0, 0.0, 0.0, 1.0]]}]});
    fuzz_sequence_json(root, "transforms.json", valid, 600);
}

#[test]
fn run_json_object_channels_are_parsed_and_checked_without_panicking() {
    let read = |v: &Value| {
        bounded(64, || {
            if let Ok(c) = serde_json::from_value::<Vec<(u16, usize)>>(v["object_channels"].clone())
            {
                let _ = trand_pipeline::targets::check_channels(&c, 15);
            }
        })
    };
    let valid = json!({"state": "t0", "object_channels": [[1, 1], [4, 2], [9, 3]]});
    runner(2000).run(&mutate_json(valid), |v| read(&v)).unwrap();
    runner(1000)
        .run(
            &prop::collection::vec((any::<u16>(), any::<usize>()), 0..20),
            |c| {
                let r = trand_pipeline::targets::check_channels(&c, 15);
                let sound =
                    !c.is_empty() && c.iter().all(|&(id, ch)| id > 0 && (1..15).contains(&ch));
                prop_assert!(r.is_err() || sound, "{c:?} accepted");
                Ok(())
            },
        )
        .unwrap();
}

#[test]
fn toml_options_are_parsed_and_validated_without_panicking() {
    use trand_pipeline::ReconstructOptions;
    use trand_pipeline::update::UpdateOptions;
    let valid_r = toml::to_string(&ReconstructOptions::default()).unwrap();
    let valid_u = toml::to_string(&UpdateOptions::default()).unwrap();
    let read = |s: &str| {
        bounded(s.len(), || {
            if let Ok(o) = toml::from_str::<ReconstructOptions>(s) {
                let _ = o.validate();
            }
            if let Ok(o) = toml::from_str::<UpdateOptions>(s) {
                let _ = o.validate();
            }
        })
    };
    runner(1000)
        .run(&mutate_numbers(valid_r), |s| read(&s))
        .unwrap();
    runner(1000)
        .run(&mutate_numbers(valid_u), |s| read(&s))
        .unwrap();
    runner(500)
        .run(&"[a-z_.=\\[\\] 0-9\n\"-]{0,200}", |s| read(&s))
        .unwrap();
}

#[test]
fn render_cameras_reader_survives_arbitrary_and_mutated_files() {
    let dir = ScratchDir::new("fuzz-cameras").unwrap();
    let path = dir.path().join("cameras.json");
    let valid = json!([{
        "name": "wrist",
        "K": [[600.0, 0.0, 319.5], [0.0, 600.0, 239.5], [0.0, 0.0, 1.0]],
        "world_to_camera": [
            [1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.5], [0.0, 0.0, 0.0, 1.0]
        ],
        "width": 640,
        "height": 480
    }]);
    std::fs::write(&path, valid.to_string()).unwrap();
    assert_eq!(trand_io::read_cameras_json(&path).unwrap().len(), 1);
    let read = |bytes: &[u8]| {
        std::fs::write(&path, bytes).unwrap();
        bounded(bytes.len(), || {
            let _ = trand_io::read_cameras_json(&path);
        })
    };
    runner(2000)
        .run(&mutate_json(valid.clone()), |v| {
            read(v.to_string().as_bytes())
        })
        .unwrap();
    runner(1000)
        .run(&mutate_bytes(valid.to_string().into_bytes()), |b| read(&b))
        .unwrap();
}
