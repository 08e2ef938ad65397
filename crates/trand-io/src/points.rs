//! Coloured, oriented point clouds as binary little-endian PLY, the layout Open3D and MeshLab read as
//! a point cloud with normals and colours:
//!
//! ```text
//! element vertex N
//! property float x, y, z          position, metres
//! property float nx, ny, nz       unit normal
//! property uchar red, green, blue colour
//! property ushort object_id       only when the cloud carries object ids
//! ```

use std::path::Path;

use crate::error::IoError;
use crate::write::write_atomic;

/// Points with a normal and a colour each, and optionally an object id each.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PointCloud {
    pub positions: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
    pub colors: Vec<[u8; 3]>,
    pub object_ids: Option<Vec<u16>>,
}

impl PointCloud {
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// Checks that every attribute has one entry per point.
    pub fn validate(&self) -> Result<(), String> {
        let n = self.positions.len();
        let ids = self.object_ids.as_ref().map_or(n, Vec::len);
        for (what, len) in [
            ("normals", self.normals.len()),
            ("colours", self.colors.len()),
            ("object ids", ids),
        ] {
            if len != n {
                return Err(format!("{len} {what} for {n} points"));
            }
        }
        Ok(())
    }
}

/// Serialises a point cloud to PLY bytes (the cloud must be consistent, [`PointCloud::validate`]).
pub fn point_cloud_to_ply_bytes(p: &PointCloud) -> Vec<u8> {
    let n = p.len();
    let mut header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment trand points\nelement vertex {n}\n\
         property float x\nproperty float y\nproperty float z\n\
         property float nx\nproperty float ny\nproperty float nz\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\n"
    );
    if p.object_ids.is_some() {
        header.push_str("property ushort object_id\n");
    }
    header.push_str("end_header\n");
    let mut out = Vec::with_capacity(header.len() + n * 29);
    out.extend_from_slice(header.as_bytes());
    for i in 0..n {
        for v in p.positions[i].iter().chain(&p.normals[i]) {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out.extend_from_slice(&p.colors[i]);
        if let Some(ids) = &p.object_ids {
            out.extend_from_slice(&ids[i].to_le_bytes());
        }
    }
    out
}

/// Writes a point cloud PLY atomically.
pub fn write_point_cloud_ply(path: &Path, p: &PointCloud) -> Result<(), IoError> {
    p.validate().map_err(|reason| IoError::Ply {
        path: path.into(),
        reason,
    })?;
    write_atomic(path, &point_cloud_to_ply_bytes(p))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn point_records_follow_the_header() {
        let p = PointCloud {
            positions: vec![[1.0, 2.0, 3.0], [-1.0, 0.5, 0.25]],
            normals: vec![[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]],
            colors: vec![[10, 20, 30], [255, 0, 7]],
            object_ids: Some(vec![3, 300]),
        };
        let b = point_cloud_to_ply_bytes(&p);
        let text = String::from_utf8_lossy(&b);
        assert!(
            text.contains("element vertex 2\n") && text.contains("property ushort object_id\n")
        );
        let body = &b[text.find("end_header\n").unwrap() + 11..];
        assert_eq!(body.len(), 2 * (24 + 3 + 2));
        let rec = &body[29..];
        assert_eq!(f32::from_le_bytes(rec[4..8].try_into().unwrap()), 0.5);
        assert_eq!(&rec[24..27], &[255, 0, 7]);
        assert_eq!(u16::from_le_bytes([rec[27], rec[28]]), 300);
    }

    #[test]
    fn inconsistent_clouds_are_refused_with_the_file_named() {
        let p = PointCloud {
            positions: vec![[0.0; 3]],
            ..Default::default()
        };
        let e = write_point_cloud_ply(Path::new("/nonexistent/x.ply"), &p).unwrap_err();
        assert!(e.to_string().contains("x.ply") && e.to_string().contains("normals"));
    }
}
