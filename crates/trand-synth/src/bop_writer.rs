//! Writes views, annotations and models in the BOP `train_pbr`-like layout of the reference data.
//!
//! Per split folder (`train_0`, `test_0`, `train_1`, `test_1`): `rgb/{frame:06d}.png` (8-bit RGB),
//! `depth/{frame:06d}.png` (16-bit, mm), `mask_visib/{frame:06d}_{obj_id:06d}.png` (0/255, one
//! per object present in the state), `scene_camera.json`, `scene_gt.json`, `scene_gt_info.json`
//! (maps from the frame number as a string, in frame order). Poses in mm; rotations row-major.

use crate::error::SynthError;
use crate::physics::Pose;
use crate::trace::ViewImages;
use glam::{DMat3, DQuat, DVec3};
use serde::Serialize;
use serde::ser::SerializeMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use trand_core::Mesh;
use trand_core::camera::Camera;

/// `scene_camera.json` entry.
#[derive(Clone, Debug, Serialize)]
pub struct CameraEntry {
    #[serde(rename = "cam_K")]
    pub cam_k: [f64; 9],
    #[serde(rename = "cam_R_w2c")]
    pub cam_r_w2c: [f64; 9],
    pub cam_t_w2c: [f64; 3],
    pub depth_scale: f64,
    pub width: u32,
    pub height: u32,
}

/// `scene_gt.json` entry (one per object present).
#[derive(Clone, Debug, Serialize)]
pub struct GtEntry {
    pub obj_id: u32,
    #[serde(rename = "cam_R_m2c")]
    pub cam_r_m2c: [f64; 9],
    pub cam_t_m2c: [f64; 3],
}

/// `scene_gt_info.json` entry.
#[derive(Clone, Debug, Serialize)]
pub struct GtInfoEntry {
    pub obj_id: u32,
    pub px_count_visib: u64,
    /// `[x, y, w, h]`, or `[-1, -1, -1, -1]` when not visible.
    pub bbox_visib: [i64; 4],
}

/// A map from frame number to value, serialised in frame order with string keys.
pub struct FrameMap<T>(pub Vec<(u32, T)>);

impl<T: Serialize> Serialize for FrameMap<T> {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut m = s.serialize_map(Some(self.0.len()))?;
        for (k, v) in &self.0 {
            m.serialize_entry(&k.to_string(), v)?;
        }
        m.end()
    }
}

/// Rounds to `digits` decimals (keeps the JSON readable, like the reference's 6 decimals);
/// `-0.0` becomes `0.0`.
pub fn round(v: f64, digits: i32) -> f64 {
    let s = 10f64.powi(digits);
    (v * s).round() / s + 0.0
}

fn row_major(m: DMat3) -> [f64; 9] {
    let r = m.transpose().to_cols_array();
    r.map(|v| round(v, 9))
}

/// Camera entry from a camera (translation converted to mm).
pub fn camera_entry(cam: &Camera) -> CameraEntry {
    let k = cam.intrinsics;
    CameraEntry {
        cam_k: [k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0],
        cam_r_w2c: row_major(cam.rotation()),
        cam_t_w2c: (cam.translation() * 1000.0).to_array().map(|v| round(v, 6)),
        depth_scale: 1.0,
        width: k.width,
        height: k.height,
    }
}

/// Model-to-world rotation as f64.
pub fn pose_rotation(p: &Pose) -> DMat3 {
    DMat3::from_quat(
        DQuat::from_xyzw(
            p.rotation.x as f64,
            p.rotation.y as f64,
            p.rotation.z as f64,
            p.rotation.w as f64,
        )
        .normalize(),
    )
}

/// `scene_gt` entry: `R_m2c = R_w2c R_m2w`, `t_m2c = R_w2c t_m2w + t_w2c` (mm).
pub fn gt_entry(cam: &Camera, obj_id: u32, pose: &Pose) -> GtEntry {
    let r = cam.rotation() * pose_rotation(pose);
    let t = cam.rotation() * pose.translation.as_dvec3() + cam.translation();
    GtEntry {
        obj_id,
        cam_r_m2c: row_major(r),
        cam_t_m2c: (t * 1000.0).to_array().map(|v| round(v, 6)),
    }
}

/// Visible pixel count and bounding box of `obj_id` in an id image.
pub fn gt_info_entry(img: &ViewImages, obj_id: u32) -> GtInfoEntry {
    let w = img.width as usize;
    let (mut n, mut x0, mut y0, mut x1, mut y1) = (0u64, usize::MAX, usize::MAX, 0, 0);
    for (i, _) in img.ids.iter().enumerate().filter(|(_, id)| **id == obj_id) {
        let (x, y) = (i % w, i / w);
        n += 1;
        x0 = x0.min(x);
        y0 = y0.min(y);
        x1 = x1.max(x);
        y1 = y1.max(y);
    }
    let bbox_visib = if n == 0 {
        [-1; 4]
    } else {
        [
            x0 as i64,
            y0 as i64,
            (x1 - x0 + 1) as i64,
            (y1 - y0 + 1) as i64,
        ]
    };
    GtInfoEntry {
        obj_id,
        px_count_visib: n,
        bbox_visib,
    }
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> SynthError + '_ {
    move |source| SynthError::Io {
        path: path.to_path_buf(),
        source,
    }
}

fn png_err(path: &Path) -> impl FnOnce(image::ImageError) -> SynthError + '_ {
    move |source| SynthError::Png {
        path: path.to_path_buf(),
        source,
    }
}

/// Creates `rgb/`, `depth/`, `mask_visib/` under a split folder.
pub fn create_split_dirs(split: &Path) -> Result<(), SynthError> {
    for sub in ["rgb", "depth", "mask_visib"] {
        let p = split.join(sub);
        std::fs::create_dir_all(&p).map_err(io_err(&p))?;
    }
    Ok(())
}

/// Writes one view's RGB, depth and one mask per object id in `present`.
pub fn write_view(
    split: &Path,
    frame: u32,
    img: &ViewImages,
    present: &[u32],
) -> Result<(), SynthError> {
    let (w, h) = (img.width, img.height);
    let p = split.join(format!("rgb/{frame:06}.png"));
    image::save_buffer(&p, &img.rgb, w, h, image::ExtendedColorType::Rgb8).map_err(png_err(&p))?;
    let p = split.join(format!("depth/{frame:06}.png"));
    let depth =
        image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_raw(w, h, img.depth_mm.clone())
            .expect("depth buffer has w*h pixels");
    depth.save(&p).map_err(png_err(&p))?;
    for &id in present {
        let p = split.join(format!("mask_visib/{frame:06}_{id:06}.png"));
        let mask: Vec<u8> = img
            .ids
            .iter()
            .map(|&v| if v == id { 255 } else { 0 })
            .collect();
        image::save_buffer(&p, &mask, w, h, image::ExtendedColorType::L8).map_err(png_err(&p))?;
    }
    Ok(())
}

/// Writes any serialisable value as pretty JSON with a one-space indent (as the reference data).
pub fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<(), SynthError> {
    let f = std::fs::File::create(path).map_err(io_err(path))?;
    let mut w = std::io::BufWriter::new(f);
    let mut ser = serde_json::Serializer::with_formatter(
        &mut w,
        serde_json::ser::PrettyFormatter::with_indent(b" "),
    );
    value
        .serialize(&mut ser)
        .map_err(|source| SynthError::Json {
            path: path.to_path_buf(),
            source,
        })?;
    w.write_all(b"\n").map_err(io_err(path))?;
    w.flush().map_err(io_err(path))
}

/// Writes an ASCII PLY in millimetres with vertex normals (the reference's model format).
pub fn write_ply(path: &Path, mesh: &Mesh) -> Result<(), SynthError> {
    let f = std::fs::File::create(path).map_err(io_err(path))?;
    let mut w = std::io::BufWriter::new(f);
    let mut body = String::new();
    body.push_str(&format!(
        "ply\nformat ascii 1.0\ncomment units: millimetres, model frame\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\nproperty float nz\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n",
        mesh.vertices.len(),
        mesh.faces.len()
    ));
    for (p, n) in mesh.points().zip(&mesh.normals) {
        let p = p * 1000.0;
        body.push_str(&format!(
            "{:.4} {:.4} {:.4} {:.5} {:.5} {:.5}\n",
            p.x, p.y, p.z, n[0], n[1], n[2]
        ));
    }
    for t in &mesh.faces {
        body.push_str(&format!("3 {} {} {}\n", t[0], t[1], t[2]));
    }
    w.write_all(body.as_bytes()).map_err(io_err(path))?;
    w.flush().map_err(io_err(path))
}

/// `models_info.json` entry: diameter (largest vertex distance) and bounding box, in mm.
#[derive(Clone, Debug, Serialize)]
pub struct ModelInfo {
    pub diameter: f64,
    pub min_x: f64,
    pub min_y: f64,
    pub min_z: f64,
    pub size_x: f64,
    pub size_y: f64,
    pub size_z: f64,
}

pub fn model_info(mesh: &Mesh) -> ModelInfo {
    let (lo, hi) = mesh.bounds();
    // Exact diameter (largest vertex–vertex distance) by the O(n²) scan: a few thousand
    // vertices, a few milliseconds per model.
    let pts: Vec<DVec3> = mesh.points().map(|p| p.as_dvec3()).collect();
    let mut diam = 0.0f64;
    for (i, a) in pts.iter().enumerate() {
        for b in &pts[i + 1..] {
            diam = diam.max(a.distance(*b));
        }
    }
    let (lo, size) = (lo.as_dvec3() * 1000.0, (hi - lo).as_dvec3() * 1000.0);
    ModelInfo {
        diameter: round(diam * 1000.0, 4),
        min_x: round(lo.x, 4),
        min_y: round(lo.y, 4),
        min_z: round(lo.z, 4),
        size_x: round(size.x, 4),
        size_y: round(size.y, 4),
        size_z: round(size.z, 4),
    }
}

/// A split folder path inside the output folder.
pub fn split_dir(root: &Path, name: &str) -> PathBuf {
    root.join(name)
}
