//! Readers on the real Blender sequences in `../shared/data/blender/` (relative to the workspace root).
//! Ignored unless asked for (`--include-ignored`); run without the data, each fails naming the folder.

#[path = "../../../testdata/shared_data.rs"]
mod shared_data;

use std::path::PathBuf;

use trand_io::{
    Load, LoadOptions, Split, State, ViewCount, read_gray16, read_sequence, read_sequence_with,
    select_train_views,
};

fn seq_dir(name: &str) -> PathBuf {
    shared_data::shared_data(&format!("blender/{name}"))
}

fn json(p: PathBuf) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
}

#[test]
#[ignore = "needs ../shared/data/blender (see README: Tests)"]
fn seq_101_has_the_documented_views_objects_and_removed_object() {
    let dir = seq_dir("seq_101");
    let seq = read_sequence_with(&dir, &LoadOptions::cameras_only()).unwrap();
    assert_eq!(seq.train_t0.len(), 13);
    assert_eq!(seq.train_t1.len(), 1);
    assert_eq!(seq.test_t0.len(), 10);
    assert_eq!(seq.test_t1.len(), 10);
    assert_eq!(seq.object_ids, vec![1, 2, 3, 4]);
    assert_eq!(seq.removed_ids, Some(vec![1]));
    assert_eq!(seq.train_t0[3].name, "train_0/000003");
    assert_eq!(seq.test_t1[0].name, "test_1/000000");
    let k = seq.train_t0[0].camera.intrinsics;
    assert_eq!(
        (k.width, k.height, k.cx, k.cy, k.fx),
        (640, 480, 319.5, 239.5, 600.0)
    );
    assert!(
        seq.all_views()
            .all(|v| v.rgb.is_none() && v.depth.is_none() && v.instance.is_none())
    );
}

#[test]
#[ignore = "needs ../shared/data/blender (see README: Tests)"]
fn birds_eye_camera_projects_workspace_centre_to_image_centre() {
    let dir = seq_dir("seq_101");
    let seq = read_sequence_with(&dir, &LoadOptions::cameras_only()).unwrap();
    let c = json(dir.join("sequence.json"))["workspace_center_m"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect::<Vec<_>>();
    let bev = &seq.train_t0[0].camera;
    let (x, y, z) = bev.project(glam::DVec3::new(c[0], c[1], 0.0)).unwrap();
    assert!(
        (x - 319.5).abs() < 1.0 && (y - 239.5).abs() < 1.0,
        "table centre at ({x}, {y})"
    );
    // Straight down from about 0.78 m above the table.
    assert!((z - 0.805).abs() < 0.01, "z = {z}");
    assert!(bev.forward().z < -0.999);
    // t=1's only view has the bird's-eye pose.
    assert_eq!(seq.train_t1[0].camera, *bev);
}

#[test]
#[ignore = "needs ../shared/data/blender (see README: Tests)"]
fn ring_views_sit_at_the_documented_distance_and_six_views_are_odd_frames() {
    let dir = seq_dir("seq_101");
    let seq = read_sequence_with(&dir, &LoadOptions::cameras_only()).unwrap();
    let s = json(dir.join("sequence.json"));
    let d = s["cameras"]["train_ring"]["ring_distance_m"]
        .as_f64()
        .unwrap();
    let c = s["workspace_center_m"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect::<Vec<_>>();
    let centre = glam::DVec3::new(c[0], c[1], c[2]);
    let six = select_train_views(&seq.train_t0, ViewCount::Six);
    assert_eq!(
        six.iter().map(|v| v.frame).collect::<Vec<_>>(),
        vec![1, 3, 5, 7, 9, 11]
    );
    for v in &six {
        let r = (v.camera.center() - centre).length();
        assert!((r - d).abs() < 0.01, "{}: distance {r} vs {d}", v.name);
    }
    // Three views: 120 degrees apart around the vertical axis.
    let three = select_train_views(&seq.train_t0, ViewCount::Three);
    let az: Vec<f64> = three
        .iter()
        .map(|v| {
            let p = v.camera.center() - centre;
            p.y.atan2(p.x).to_degrees()
        })
        .collect();
    for i in 0..3 {
        let diff = (az[(i + 1) % 3] - az[i]).rem_euclid(360.0);
        assert!(
            (diff - 120.0).abs() < 1.0 && diff > 0.0 || (diff - 240.0).abs() < 1.0,
            "azimuths {az:?}"
        );
    }
}

#[test]
#[ignore = "needs ../shared/data/blender (see README: Tests)"]
fn depth_is_png_over_1000_and_table_pixels_unproject_to_the_table_plane() {
    let dir = seq_dir("seq_101");
    let seq = read_sequence(&dir).unwrap();
    let v = &seq.train_t0[0];
    let depth = v.depth.as_ref().unwrap();
    let raw = read_gray16(&dir.join("train_0/depth/000000.png")).unwrap();
    for (d, r) in depth.data.iter().zip(&raw.data) {
        assert!((*d as f64 - *r as f64 / 1000.0).abs() < 1e-6);
    }
    let inst = v.instance.as_ref().unwrap();
    let rgb = v.rgb.as_ref().unwrap();
    assert_eq!((rgb.width, rgb.height, rgb.channels), (640, 480, 3));
    let mut checked = 0;
    for y in (0..480).step_by(7) {
        for x in (0..640).step_by(7) {
            let z = depth.get(x, y, 0) as f64;
            if z <= 0.0 || inst.get(x, y, 0) != 0 {
                continue;
            }
            let ray = v.camera.ray_direction(x as f64, y as f64);
            let cos = ray.dot(v.camera.forward());
            let p = v.camera.center() + ray * (z / cos);
            // Background pixels of the bird's-eye view are table (z = 0), within the mm quantisation.
            assert!(
                p.z.abs() < 1.5e-3,
                "pixel ({x}, {y}) unprojects to z = {}",
                p.z
            );
            checked += 1;
        }
    }
    assert!(checked > 1000);
}

#[test]
#[ignore = "needs ../shared/data/blender (see README: Tests)"]
fn instance_maps_match_mask_pixel_counts_and_lose_the_removed_object() {
    let dir = seq_dir("seq_101");
    let opts = LoadOptions {
        rgb: Load::No,
        depth: Load::No,
        ..LoadOptions::default()
    };
    let seq = read_sequence_with(&dir, &opts).unwrap();
    let info = json(dir.join("test_0/scene_gt_info.json"));
    let gt = json(dir.join("test_0/scene_gt.json"));
    for v in seq.views(Split::Test, State::T0) {
        let inst = v.instance.as_ref().unwrap();
        let key = v.frame.to_string();
        for (ann, obj) in info[&key]
            .as_array()
            .unwrap()
            .iter()
            .zip(gt[&key].as_array().unwrap())
        {
            let id = obj["obj_id"].as_u64().unwrap() as u16;
            let n = inst.data.iter().filter(|&&p| p == id).count() as u64;
            assert_eq!(
                n,
                ann["px_count_visib"].as_u64().unwrap(),
                "{} object {id}",
                v.name
            );
        }
    }
    let t1 = &seq.train_t1[0];
    let ids = t1.instance.as_ref().unwrap().ids();
    assert!(
        !ids.contains(&1) && !ids.is_empty() && ids.iter().all(|i| [2, 3, 4].contains(i)),
        "{ids:?}"
    );
}

#[test]
#[ignore = "needs ../shared/data/blender (see README: Tests)"]
fn seq_105_reads_with_its_five_objects() {
    let dir = seq_dir("seq_105");
    let seq = read_sequence_with(&dir, &LoadOptions::for_eval()).unwrap();
    assert_eq!(seq.object_ids, vec![1, 2, 3, 4, 5]);
    assert!(seq.removed_ids.as_ref().is_some_and(|r| r.len() == 1));
    assert!(
        seq.test_t0
            .iter()
            .all(|v| v.depth.is_some() && v.instance.is_some() && v.rgb.is_none())
    );
}
