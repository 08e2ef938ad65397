//! Readers on tiny sequences written by the tests: the three formats agree, and every error case
//! names the file and the field.

use std::path::Path;

use serde_json::json;
use trand_io::{Image, IoError, LoadOptions, ScratchDir, read_sequence, read_sequence_with};

const W: u32 = 4;
const H: u32 = 3;

fn write_json(p: &Path, v: &serde_json::Value) {
    std::fs::create_dir_all(p.parent().unwrap()).unwrap();
    std::fs::write(p, serde_json::to_string_pretty(v).unwrap()).unwrap();
}

fn rgb(seed: u8) -> Image<u8> {
    Image::from_vec(
        W,
        H,
        3,
        (0..W * H * 3)
            .map(|i| (i as u8).wrapping_mul(7).wrapping_add(seed))
            .collect(),
    )
    .unwrap()
}

/// Object 2 at (1,1) and (2,1), object 5 at (3,2).
fn mask(id: u16) -> Image<u8> {
    let mut m = Image::filled(W, H, 1, 0u8);
    match id {
        2 => {
            m.set(1, 1, 0, 255);
            m.set(2, 1, 0, 255);
        }
        _ => m.set(3, 2, 0, 255),
    }
    m
}

fn depth_raw() -> Image<u16> {
    Image::from_vec(W, H, 1, (0..W * H).map(|i| 1000 + i as u16).collect()).unwrap()
}

fn cam_entry(t_z_mm: f64, depth_scale: f64) -> serde_json::Value {
    json!({"cam_K": [10.0, 0.0, 1.5, 0.0, 10.0, 1.0, 0.0, 0.0, 1.0],
           "cam_R_w2c": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
           "cam_t_w2c": [0.0, 0.0, t_z_mm], "depth_scale": depth_scale, "width": W, "height": H})
}

/// A BOP sequence with two train_0 frames and one test_0 frame.
fn bop_fixture(root: &Path) {
    for (folder, frames) in [("train_0", vec![0u32, 1]), ("test_0", vec![0])] {
        let d = root.join(folder);
        let mut cams = serde_json::Map::new();
        for &f in &frames {
            cams.insert(f.to_string(), cam_entry(1000.0 + f as f64, 1.0));
            trand_io::write_rgb_png(&d.join(format!("rgb/{f:06}.png")), &rgb(f as u8)).unwrap();
            trand_io::write_gray16_png(&d.join(format!("depth/{f:06}.png")), &depth_raw()).unwrap();
            for id in [2u16, 5] {
                trand_io::write_gray8_png(
                    &d.join(format!("mask_visib/{f:06}_{id:06}.png")),
                    &mask(id),
                )
                .unwrap();
            }
        }
        write_json(
            &d.join("scene_camera.json"),
            &serde_json::Value::Object(cams),
        );
    }
    write_json(&root.join("sequence.json"), &json!({"removed_obj_id": 5}));
}

fn expect_instance() -> Vec<u16> {
    let mut v = vec![0u16; (W * H) as usize];
    v[(W + 1) as usize] = 2;
    v[(W + 2) as usize] = 2;
    v[(2 * W + 3) as usize] = 5;
    v
}

#[test]
fn bop_fixture_reads_cameras_images_masks_and_depth() {
    let dir = ScratchDir::new("io-bop").unwrap();
    bop_fixture(dir.path());
    let seq = read_sequence(dir.path()).unwrap();
    assert_eq!(seq.train_t0.len(), 2);
    assert_eq!(seq.test_t0.len(), 1);
    assert!(seq.train_t1.is_empty() && seq.test_t1.is_empty());
    assert_eq!(seq.object_ids, vec![2, 5]);
    assert_eq!(seq.removed_ids, Some(vec![5]));
    let v = &seq.train_t0[1];
    assert_eq!(v.name, "train_0/000001");
    assert_eq!(v.camera.t_w2c, [0.0, 0.0, 1.001]);
    assert_eq!(v.rgb.as_ref().unwrap(), &rgb(1));
    assert_eq!(v.instance.as_ref().unwrap().data, expect_instance());
    assert_eq!(v.depth.as_ref().unwrap().get(1, 0, 0), 1.001);
}

#[test]
fn bop_index_named_masks_are_mapped_through_scene_gt() {
    let dir = ScratchDir::new("io-bopidx").unwrap();
    bop_fixture(dir.path());
    for folder in ["train_0", "test_0"] {
        let d = dir.path().join(folder);
        let frames: Vec<u32> = if folder == "train_0" {
            vec![0, 1]
        } else {
            vec![0]
        };
        let mut gt = serde_json::Map::new();
        for f in frames {
            for (idx, id) in [(0u16, 2u16), (1, 5)] {
                std::fs::rename(
                    d.join(format!("mask_visib/{f:06}_{id:06}.png")),
                    d.join(format!("mask_visib/{f:06}_{idx:06}.png.x")),
                )
                .unwrap();
            }
            for idx in 0..2 {
                std::fs::rename(
                    d.join(format!("mask_visib/{f:06}_{idx:06}.png.x")),
                    d.join(format!("mask_visib/{f:06}_{idx:06}.png")),
                )
                .unwrap();
            }
            gt.insert(f.to_string(), json!([{"obj_id": 2}, {"obj_id": 5}]));
        }
        write_json(&d.join("scene_gt.json"), &serde_json::Value::Object(gt));
    }
    let seq = read_sequence(dir.path()).unwrap();
    assert_eq!(seq.object_ids, vec![2, 5]);
    assert_eq!(
        seq.train_t0[0].instance.as_ref().unwrap().data,
        expect_instance()
    );
}

#[test]
fn missing_depth_file_is_named() {
    let dir = ScratchDir::new("io-missing").unwrap();
    bop_fixture(dir.path());
    let p = dir.path().join("test_0/depth/000000.png");
    std::fs::remove_file(&p).unwrap();
    match read_sequence(dir.path()) {
        Err(e @ IoError::Missing { .. }) => {
            assert!(e.to_string().contains("test_0/depth/000000.png"), "{e}")
        }
        other => panic!("expected Missing, got {other:?}"),
    }
    // Without depth the same sequence reads.
    read_sequence_with(
        dir.path(),
        &LoadOptions::for_eval().with_depth(trand_io::Load::No),
    )
    .unwrap();
}

#[test]
fn malformed_json_field_names_file_and_field() {
    let dir = ScratchDir::new("io-field").unwrap();
    bop_fixture(dir.path());
    let p = dir.path().join("train_0/scene_camera.json");
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
    v["1"]["cam_K"] = json!([1.0, 2.0]);
    write_json(&p, &v);
    let e = read_sequence(dir.path()).unwrap_err();
    let msg = e.to_string();
    assert!(
        matches!(e, IoError::Field { .. })
            && msg.contains("scene_camera.json")
            && msg.contains("`1.cam_K`"),
        "{msg}"
    );
}

#[test]
fn mask_with_wrong_size_is_rejected() {
    let dir = ScratchDir::new("io-size").unwrap();
    bop_fixture(dir.path());
    let p = dir.path().join("train_0/mask_visib/000001_000005.png");
    trand_io::write_gray8_png(&p, &Image::filled(W + 1, H, 1, 0u8)).unwrap();
    let e = read_sequence(dir.path()).unwrap_err();
    assert!(
        matches!(
            e,
            IoError::SizeMismatch {
                found_w: 5,
                expected_w: 4,
                ..
            }
        ),
        "{e}"
    );
    assert!(e.to_string().contains("000001_000005.png"), "{e}");
}

#[test]
fn disagreeing_depth_scale_is_rejected() {
    let dir = ScratchDir::new("io-scale").unwrap();
    bop_fixture(dir.path());
    let p = dir.path().join("test_0/scene_camera.json");
    write_json(&p, &json!({"0": cam_entry(1000.0, 0.1)}));
    let e = read_sequence_with(dir.path(), &LoadOptions::cameras_only()).unwrap_err();
    let msg = e.to_string();
    assert!(
        matches!(
            e,
            IoError::DepthScaleMismatch {
                found: 0.1,
                expected: 1.0,
                ..
            }
        ),
        "{msg}"
    );
    assert!(
        msg.contains("test_0/scene_camera.json") && msg.contains("0.depth_scale"),
        "{msg}"
    );
}

#[test]
fn object_ids_beyond_the_channel_budget_are_rejected() {
    let dir = ScratchDir::new("io-k").unwrap();
    bop_fixture(dir.path());
    let opts = LoadOptions {
        object_channels: Some(5),
        ..LoadOptions::default()
    };
    let e = read_sequence_with(dir.path(), &opts).unwrap_err();
    assert!(
        matches!(
            e,
            IoError::TooManyObjects {
                id: 5,
                channels: 5,
                ..
            }
        ),
        "{e}"
    );
    assert!(
        e.to_string().contains("mask_visib/000000_000005.png"),
        "{e}"
    );
    let opts = LoadOptions {
        object_channels: Some(6),
        ..LoadOptions::default()
    };
    read_sequence_with(dir.path(), &opts).unwrap();
}

#[test]
fn non_finite_pose_is_rejected() {
    let dir = ScratchDir::new("io-nan").unwrap();
    // A camera-to-world matrix whose inverse overflows to infinity.
    write_json(
        &dir.path().join("transforms_sparse_train.json"),
        &json!({"frames": [{"original_path": "rgb/000001.png",
            "transform_matrix": [[1e308, 0, 0, 1e308], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],
            "cam": {"fl_x": 10.0, "fl_y": 10.0, "cx": 1.5, "cy": 1.0, "w": W, "h": H}}]}),
    );
    let e = read_sequence_with(dir.path(), &LoadOptions::cameras_only()).unwrap_err();
    assert!(matches!(e, IoError::NonFinitePose { .. }), "{e}");
    assert!(e.to_string().contains("frames[0].transform_matrix"), "{e}");
}

#[test]
fn unknown_folder_is_reported() {
    let dir = ScratchDir::new("io-unknown").unwrap();
    assert!(matches!(
        read_sequence(dir.path()),
        Err(IoError::UnknownFormat { .. })
    ));
    assert!(matches!(
        read_sequence(dir.path().join("nope")),
        Err(IoError::Missing { .. })
    ));
}

/// Camera at world (0, 0, 1) looking at the origin: OpenCV rotation diag(1, −1, −1).
const C2W_CV: [[f64; 4]; 4] = [
    [1.0, 0.0, 0.0, 0.0],
    [0.0, -1.0, 0.0, 0.0],
    [0.0, 0.0, -1.0, 1.0],
    [0.0, 0.0, 0.0, 1.0],
];

#[test]
fn authors_transforms_match_the_bop_camera_and_load_class_maps() {
    let dir = ScratchDir::new("io-tr").unwrap();
    let root = dir.path();
    let mut class = Image::filled(W, H, 1, 0u8);
    class.set(0, 0, 0, 3);
    trand_io::write_rgb_png(&root.join("rgb/000004.png"), &rgb(4)).unwrap();
    trand_io::write_gray8_png(&root.join("class/000004.png"), &class).unwrap();
    trand_io::write_gray16_png(&root.join("depth/000004.png"), &depth_raw()).unwrap();
    let frame = |test: bool| {
        json!({"original_path": "/machine/of/authors/syn_test_01/rgb/000004.png", "file_path": "color_mask/000004.png",
               "class_path": "class/000004.png", "depth_path": "depth/000004.png", "transform_matrix": C2W_CV,
               "cam": {"fl_x": 10.0, "fl_y": 11.0, "cx": 1.5, "cy": 1.0, "w": W, "h": H}, "obj_idx": if test { json!([]) } else { json!([3]) }})
    };
    write_json(
        &root.join("transforms_sparse_train.json"),
        &json!({"num_obj": 1, "frames": [frame(false)]}),
    );
    write_json(
        &root.join("transforms_sparse_test_01.json"),
        &json!({"frames": [frame(true)]}),
    );
    let seq = read_sequence(root.join("transforms_sparse_train.json")).unwrap();
    assert_eq!(seq.train_t0.len(), 1);
    assert_eq!(seq.test_t1.len(), 1);
    assert_eq!(seq.object_ids, vec![3]);
    let v = &seq.train_t0[0];
    assert_eq!((v.name.as_str(), v.frame), ("train_0/000004", 4));
    assert_eq!(seq.test_t1[0].name, "test_1/000004");
    assert_eq!(
        v.camera.r_w2c,
        [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]
    );
    assert_eq!(v.camera.t_w2c, [0.0, 0.0, 1.0]);
    assert_eq!(
        (v.camera.intrinsics.fy, v.camera.intrinsics.cx),
        (11.0, 1.5)
    );
    // The absolute path of another machine was re-rooted onto this folder.
    assert_eq!(v.rgb.as_ref().unwrap(), &rgb(4));
    assert_eq!(v.instance.as_ref().unwrap().get(0, 0, 0), 3);
    assert_eq!(v.depth.as_ref().unwrap().get(0, 0, 0), 1.0);
}

#[test]
fn hand_eye_init_right_multiplies_the_pose() {
    let dir = ScratchDir::new("io-he").unwrap();
    // c2w = I · H with H the camera 1 m above the origin looking down.
    write_json(
        &dir.path().join("transforms_sparse_train.json"),
        &json!({"hand_eye_init": C2W_CV, "frames": [{"original_path": "rgb/000000.png",
            "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],
            "cam": {"camera_angle_x": 2.0 * (0.5f64).atan(), "w": W, "h": H}}]}),
    );
    let seq = read_sequence_with(dir.path(), &LoadOptions::cameras_only()).unwrap();
    let c = seq.train_t0[0].camera;
    assert!((c.center() - glam::DVec3::new(0.0, 0.0, 1.0)).length() < 1e-12);
    // camera_angle_x with tan(a/2) = 1/2 gives fx = W.
    assert!((c.intrinsics.fx - W as f64).abs() < 1e-9 && c.intrinsics.cx == 1.5);
}

#[test]
fn nerfstudio_flips_opengl_axes_and_shifts_pixel_centres() {
    let dir = ScratchDir::new("io-ns").unwrap();
    let root = dir.path();
    let mut inst = Image::filled(W, H, 1, 0u16);
    inst.set(2, 1, 0, 300);
    trand_io::write_gray16_png(&root.join("masks/frame_00002.png"), &inst).unwrap();
    trand_io::write_rgb_png(&root.join("images/frame_00002.png"), &rgb(2)).unwrap();
    let mut d = Image::filled(W, H, 1, 0.0f32);
    d.set(3, 2, 0, 0.75);
    trand_io::write_npy_f32(&root.join("depth/frame_00002.npy"), &d).unwrap();
    // OpenGL camera 1 m above the origin looking down (-z forward, +y up = world +y).
    let gl = [
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 1.0],
        [0.0, 0.0, 0.0, 1.0],
    ];
    let frame = |name: &str| {
        json!({"file_path": format!("images/{name}.png"), "transform_matrix": gl,
        "mask_path": format!("masks/{name}.png"), "depth_file_path": format!("depth/{name}.npy")})
    };
    write_json(
        &root.join("transforms.json"),
        &json!({"fl_x": 10.0, "fl_y": 10.0, "cx": 2.0, "cy": 1.5, "w": W, "h": H,
                "frames": [frame("frame_00002"), {"file_path": "images/frame_00007.png", "transform_matrix": gl}],
                "test_filenames": ["images/frame_00007.png"]}),
    );
    let opts = LoadOptions {
        object_channels: None,
        ..LoadOptions::default()
    };
    let e = read_sequence_with(
        root,
        &LoadOptions {
            rgb: trand_io::Load::No,
            ..LoadOptions::default()
        },
    )
    .unwrap_err();
    assert!(matches!(e, IoError::TooManyObjects { id: 300, .. }), "{e}");
    let seq = read_sequence_with(
        root,
        &LoadOptions {
            rgb: trand_io::Load::No,
            ..opts
        },
    )
    .unwrap();
    assert_eq!(seq.train_t0.len(), 1);
    assert_eq!(seq.test_t0.len(), 1);
    assert_eq!(seq.test_t0[0].name, "test_0/000007");
    let v = &seq.train_t0[0];
    assert_eq!(v.frame, 2);
    assert_eq!((v.camera.intrinsics.cx, v.camera.intrinsics.cy), (1.5, 1.0));
    let (x, y, z) = v.camera.project(glam::DVec3::ZERO).unwrap();
    assert_eq!((x, y, z), (1.5, 1.0, 1.0));
    // World +y is "up" in the OpenGL image, so it projects to a smaller row.
    let (_, y_up, _) = v.camera.project(glam::DVec3::new(0.0, 0.05, 0.0)).unwrap();
    assert!(y_up < 1.0);
    assert_eq!(seq.object_ids, vec![300]);
    assert_eq!(v.instance.as_ref().unwrap().get(2, 1, 0), 300);
    assert_eq!(v.depth.as_ref().unwrap().get(3, 2, 0), 0.75);
}
