//! Triangle meshes as binary little-endian PLY: vertices (`float x y z`), optional per-vertex colour
//! (`uchar red green blue`) and label (an object id: `uchar label` when every label fits a byte,
//! else `ushort label`), and faces (`list uchar int vertex_indices`). Readable by MeshLab, Open3D and
//! Blender. The mesh is [`trand_core::Mesh`]; its normals, when it has any, are not written.

use std::path::Path;

use trand_core::Mesh;

use crate::error::IoError;
use crate::write::write_atomic;

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

/// Writes a mesh PLY atomically, after checking it ([`Mesh::validate`]) and that its vertex indices
/// fit the file's `int`.
pub fn write_mesh_ply(path: &Path, m: &Mesh) -> Result<(), IoError> {
    let bad = |reason: String| IoError::Ply {
        path: path.into(),
        reason,
    };
    m.validate().map_err(|e| bad(e.to_string()))?;
    if m.vertices.len() > i32::MAX as usize {
        return Err(bad("too many vertices for int indices".into()));
    }
    write_atomic(path, &mesh_to_ply_bytes(m))
}
