//! Triangle meshes as binary little-endian PLY: vertices (`float x y z`), optional per-vertex colour
//! (`uchar red green blue`) and label (an object id: `uchar label` when every label fits a byte,
//! else `ushort label`), and faces (`list uchar int vertex_indices`). Readable by MeshLab, Open3D and
//! Blender.

use std::path::Path;

use crate::error::IoError;
use crate::write::write_atomic;

/// A triangle mesh with optional per-vertex colours and labels.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    pub vertices: Vec<[f32; 3]>,
    pub colors: Option<Vec<[u8; 3]>>,
    /// Object id per vertex.
    pub labels: Option<Vec<u16>>,
    pub faces: Vec<[u32; 3]>,
}

impl Mesh {
    /// Checks attribute lengths and face indices.
    pub fn validate(&self) -> Result<(), String> {
        let n = self.vertices.len();
        if let Some(c) = &self.colors
            && c.len() != n
        {
            return Err(format!("{} colours for {n} vertices", c.len()));
        }
        if let Some(l) = &self.labels
            && l.len() != n
        {
            return Err(format!("{} labels for {n} vertices", l.len()));
        }
        if let Some((i, f)) = self
            .faces
            .iter()
            .enumerate()
            .find(|(_, f)| f.iter().any(|&v| v as usize >= n))
        {
            return Err(format!("face {i} {f:?} indexes past {n} vertices"));
        }
        if n > i32::MAX as usize {
            return Err("too many vertices for int indices".into());
        }
        Ok(())
    }
}

/// Serialises a mesh to PLY bytes.
pub fn mesh_to_ply_bytes(m: &Mesh) -> Vec<u8> {
    let mut out = Vec::new();
    out.extend_from_slice(b"ply\nformat binary_little_endian 1.0\ncomment trand mesh\n");
    out.extend_from_slice(
        format!(
            "element vertex {}\nproperty float x\nproperty float y\nproperty float z\n",
            m.vertices.len()
        )
        .as_bytes(),
    );
    if m.colors.is_some() {
        out.extend_from_slice(b"property uchar red\nproperty uchar green\nproperty uchar blue\n");
    }
    let wide = m.labels.iter().flatten().any(|&l| l > u8::MAX as u16);
    if m.labels.is_some() {
        out.extend_from_slice(if wide {
            b"property ushort label\n"
        } else {
            b"property uchar label\n"
        });
    }
    out.extend_from_slice(
        format!(
            "element face {}\nproperty list uchar int vertex_indices\nend_header\n",
            m.faces.len()
        )
        .as_bytes(),
    );
    for (i, v) in m.vertices.iter().enumerate() {
        v.iter()
            .for_each(|x| out.extend_from_slice(&x.to_le_bytes()));
        if let Some(c) = &m.colors {
            out.extend_from_slice(&c[i]);
        }
        match &m.labels {
            Some(l) if wide => out.extend_from_slice(&l[i].to_le_bytes()),
            Some(l) => out.push(l[i] as u8),
            None => {}
        }
    }
    for f in &m.faces {
        out.push(3);
        f.iter()
            .for_each(|&v| out.extend_from_slice(&(v as i32).to_le_bytes()));
    }
    out
}

/// Writes a mesh PLY atomically.
pub fn write_mesh_ply(path: &Path, m: &Mesh) -> Result<(), IoError> {
    m.validate().map_err(|reason| IoError::Ply {
        path: path.into(),
        reason,
    })?;
    write_atomic(path, &mesh_to_ply_bytes(m))
}
