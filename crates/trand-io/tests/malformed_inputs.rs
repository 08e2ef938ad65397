//! Regression tests of issue 21: crafted files that used to panic, abort on a huge allocation or be
//! accepted silently now give an error naming the file and the field.

use std::path::Path;

use serde_json::json;
use trand_io::{Image, ScratchDir, read_sequence};

const W: u32 = 4;
const H: u32 = 3;

fn write_json(p: &Path, v: &serde_json::Value) {
    std::fs::create_dir_all(p.parent().unwrap()).unwrap();
    std::fs::write(p, serde_json::to_string_pretty(v).unwrap()).unwrap();
}

fn good_camera() -> serde_json::Value {
    json!({"cam_K": [10.0, 0.0, 1.5, 0.0, 10.0, 1.0, 0.0, 0.0, 1.0],
           "cam_R_w2c": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
           "cam_t_w2c": [0.0, 0.0, 1000.0], "depth_scale": 1.0, "width": W, "height": H})
}

/// A one-frame BOP sequence whose frame 0 camera is `camera`, with an RGB image and one mask.
fn bop(root: &Path, camera: serde_json::Value) {
    let d = root.join("train_0");
    write_json(&d.join("scene_camera.json"), &json!({ "0": camera }));
    let rgb = Image::from_vec(W, H, 3, vec![100u8; (W * H * 3) as usize]).unwrap();
    trand_io::write_rgb_png(&d.join("rgb/000000.png"), &rgb).unwrap();
    let mut m = Image::filled(W, H, 1, 0u8);
    m.set(1, 1, 0, 255);
    trand_io::write_gray8_png(&d.join("mask_visib/000000_000002.png"), &m).unwrap();
    let depth = Image::from_vec(W, H, 1, vec![1000u16; (W * H) as usize]).unwrap();
    trand_io::write_gray16_png(&d.join("depth/000000.png"), &depth).unwrap();
}

/// Reads a BOP sequence whose camera has `key` set to `value`; the error's text.
fn camera_error(key: &str, value: serde_json::Value) -> String {
    let dir = ScratchDir::new("io-mal-cam").unwrap();
    let mut cam = good_camera();
    cam[key] = value;
    bop(dir.path(), cam);
    match read_sequence(dir.path()) {
        Ok(_) => panic!("`{key}` accepted"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn reflection_with_determinant_minus_one_is_refused() {
    // A half turn about x (determinant +1) is a rotation.
    let dir = ScratchDir::new("io-mal-rot").unwrap();
    let mut cam = good_camera();
    cam["cam_R_w2c"] = json!([1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0]);
    bop(dir.path(), cam);
    read_sequence(dir.path()).unwrap();
    let e = camera_error(
        "cam_R_w2c",
        json!([1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -1.0]),
    );
    assert!(
        e.contains("scene_camera.json") && e.contains("cam_R_w2c") && e.contains("reflection"),
        "{e}"
    );
}

#[test]
fn focal_1e308_is_refused_naming_cam_k() {
    let e = camera_error(
        "cam_K",
        json!([1e308, 0.0, 1.5, 0.0, 10.0, 1.0, 0.0, 0.0, 1.0]),
    );
    assert!(
        e.contains("scene_camera.json") && e.contains("`0.cam_K`") && e.contains("focal"),
        "{e}"
    );
    assert!(!e.contains("cam_R_w2c"), "blames the pose: {e}");
}

#[test]
fn translation_1e308_is_refused_naming_the_file() {
    let e = camera_error("cam_t_w2c", json!([0.0, 1e308, 1000.0]));
    assert!(
        e.contains("scene_camera.json") && e.contains("cam_t_w2c") && e.contains("translation"),
        "{e}"
    );
}

#[test]
fn image_width_100000_is_refused_before_allocating_naming_width_height() {
    for (w, h) in [(100_000u64, 100_000u64), (4_000_000_000, 4)] {
        let dir = ScratchDir::new("io-mal-size").unwrap();
        let mut cam = good_camera();
        cam["width"] = json!(w);
        cam["height"] = json!(h);
        bop(dir.path(), cam);
        let e = read_sequence(dir.path()).unwrap_err().to_string();
        assert!(
            e.contains("scene_camera.json") && e.contains("width/height"),
            "{w}x{h}: {e}"
        );
        assert!(!e.contains("cam_R_w2c"), "blames the pose: {e}");
    }
}

#[test]
fn unparsable_mask_file_names_are_reported_not_skipped() {
    for name in [
        "000000_070000.png",
        "000000_000003.PNG",
        "frame0_2.png",
        "000000.png",
    ] {
        let dir = ScratchDir::new("io-mal-mask").unwrap();
        bop(dir.path(), good_camera());
        let mdir = dir.path().join("train_0/mask_visib");
        std::fs::copy(mdir.join("000000_000002.png"), mdir.join(name)).unwrap();
        let e = read_sequence(dir.path()).expect_err(name).to_string();
        assert!(e.contains(name) && e.contains("file name"), "{name}: {e}");
    }
    // Hidden files (editor leftovers) are not masks.
    let dir = ScratchDir::new("io-mal-mask-hidden").unwrap();
    bop(dir.path(), good_camera());
    std::fs::write(dir.path().join("train_0/mask_visib/.DS_Store"), b"x").unwrap();
    assert_eq!(read_sequence(dir.path()).unwrap().object_ids, vec![2]);
}

fn ply_header(count: &str, comment: &str, props: &[&str]) -> Vec<u8> {
    let mut h = format!("ply\nformat binary_little_endian 1.0\n{comment}element vertex {count}\n");
    for p in props {
        h.push_str(&format!("property float {p}\n"));
    }
    h.push_str("end_header\n");
    h.into_bytes()
}

const MINIMAL: [&str; 14] = [
    "x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "rot_0", "rot_1",
    "rot_2", "rot_3", "nx",
];

#[test]
fn ply_vertex_count_2_pow_62_is_refused_without_allocating() {
    for count in ["4611686018427387904", "18446744073709551615", "1000000"] {
        let mut b = ply_header(count, "", &MINIMAL);
        b.extend_from_slice(&[0u8; 56 * 3]);
        let e = trand_io::ply::surfels_from_ply_bytes(&b, Path::new("s.ply"))
            .expect_err(count)
            .to_string();
        assert!(
            e.contains("s.ply") && e.contains("truncated"),
            "{count}: {e}"
        );
    }
}

#[test]
fn ply_comment_num_objects_1e12_without_obj_index_is_refused() {
    let comment = "comment trand surfels sh_degree 0 num_objects 1000000000000\n";
    let mut b = ply_header("2", comment, &MINIMAL);
    b.extend_from_slice(&[0u8; 56 * 2]);
    let e = trand_io::ply::surfels_from_ply_bytes(&b, Path::new("s.ply"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("s.ply") && e.contains("num_objects"), "{e}");
}

/// NPY v1.0 bytes with the header dictionary `dict` and `data` after it.
pub fn npy_bytes(dict: &str, data: &[u8]) -> Vec<u8> {
    let mut header = dict.to_string();
    while !(10 + header.len() + 1).is_multiple_of(64) {
        header.push(' ');
    }
    header.push('\n');
    let mut b = b"\x93NUMPY\x01\x00".to_vec();
    b.extend_from_slice(&(header.len() as u16).to_le_bytes());
    b.extend_from_slice(header.as_bytes());
    b.extend_from_slice(data);
    b
}

#[test]
fn npy_shape_beyond_the_file_is_refused_without_allocating() {
    let dir = ScratchDir::new("io-mal-npy").unwrap();
    let p = dir.path().join("d.npy");
    let ok = "{'descr': '<f4', 'fortran_order': False, 'shape': (2, 2), }";
    std::fs::write(&p, npy_bytes(ok, &[0u8; 16])).unwrap();
    assert_eq!(trand_io::read_npy_f32(&p).unwrap().data, vec![0.0; 4]);
    // The last two overflow the element count in 64 bits, or do not parse as integers.
    for shape in [
        "(99999999999, 9)",
        "(4294967296, 4294967296)",
        "(3, 2)",
        "(18446744073709551615, 3, )",
        "(461-1, 4611686018427387904, )",
    ] {
        let dict = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': {shape}, }}");
        std::fs::write(&p, npy_bytes(&dict, &[0u8; 16])).unwrap();
        let e = trand_io::read_npy_f32(&p).expect_err(shape).to_string();
        assert!(e.contains("d.npy"), "{shape}: {e}");
    }
}

#[test]
fn npy_version_2_header_length_beyond_the_file_is_refused_without_allocating() {
    let dir = ScratchDir::new("io-mal-npy2").unwrap();
    let p = dir.path().join("d.npy");
    let ok = "{'descr': '<f4', 'fortran_order': False, 'shape': (2, 2), }";
    let mut b = npy_bytes(ok, &[0u8; 16]);
    // Version 2 reads a 4-byte header length: here the first bytes of the header text, ~660 MB.
    b[6] = 2;
    std::fs::write(&p, &b).unwrap();
    let e = trand_io::read_npy_f32(&p).unwrap_err().to_string();
    assert!(e.contains("d.npy") && e.contains("header"), "{e}");
}

/// The id of a process that has exited.
fn dead_pid() -> u32 {
    let mut child = std::process::Command::new("true").spawn().unwrap();
    let pid = child.id();
    child.wait().unwrap();
    pid
}

#[test]
fn temp_folders_of_killed_runs_are_cleaned_by_the_next_run() {
    let dir = ScratchDir::new("io-stale").unwrap();
    let stale = dir.path().join(format!("run0.tmp-{}", dead_pid()));
    std::fs::create_dir(&stale).unwrap();
    trand_io::output::write_marker(&stale, trand_io::output::OutputKind::Run).unwrap();
    std::fs::write(stale.join("surfels.ply"), b"half").unwrap();
    // Not trand's (no marker): left alone even though its "process" is gone.
    let foreign = dir.path().join(format!("run0.tmp-{}", dead_pid()));
    std::fs::create_dir(&foreign).unwrap();
    let r = trand_io::RunDir::create(&dir.path().join("run0")).unwrap();
    assert!(
        !stale.exists(),
        "the killed run's temp folder is still there"
    );
    assert!(foreign.exists(), "an unmarked folder was removed");
    assert!(r.path().join(trand_io::output::MARKER).is_file());
    r.commit().unwrap();
    assert!(
        dir.path()
            .join("run0")
            .join(trand_io::output::MARKER)
            .is_file()
    );
}
