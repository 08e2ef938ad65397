//! The indexed triangle mesh of the whole project: the synthetic models (`trand-synth`), the TSDF
//! surface of the scene update (`trand-physics`, `trand-pipeline`) and the mesh PLY files
//! (`trand-io`) are this one type.
//!
//! Layout: `vertices[i]` in metres; per-vertex attributes `normals[i]` (unit, pointing out of the
//! surface), `colors[i]` (8 bits per channel) and `labels[i]` (an object id), each either one per
//! vertex or absent; `faces[t]` = three vertex indices, counter-clockwise seen from outside.
//! Normals are a `Vec` that is empty when the mesh has none (every producer computes them, so an
//! `Option` would only add unwrapping); colours and labels are `Option`s because they are added
//! later, by labelling or colouring a finished surface. [`Mesh::validate`] checks the lengths and
//! indices.
//!
//! Vertex indices are `u32`, so a mesh holds at most 2³² vertices: index arithmetic here is checked
//! rather than truncated.
//!
//! The solid measures assume a closed, outward-facing surface: the enclosed volume by the
//! divergence theorem, `V = Σ_t a·(b × c) / 6` over the triangles `(a, b, c)` (each term is the
//! signed volume of the tetrahedron from the origin to the triangle), and the centre of mass of the
//! uniform solid, `Σ_t V_t (a + b + c) / 4 / Σ_t V_t`.

use glam::Vec3;

/// Why a mesh is inconsistent.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum MeshError {
    #[error("{got} {attribute} for {vertices} vertices")]
    AttributeLength {
        attribute: &'static str,
        got: usize,
        vertices: usize,
    },
    #[error("face {face} {indices:?} indexes past {vertices} vertices")]
    FaceIndex {
        face: usize,
        indices: [u32; 3],
        vertices: usize,
    },
    #[error("{vertices} vertices: more than u32 indices can address")]
    TooManyVertices { vertices: usize },
    #[error("cannot append a mesh whose {attribute} differ in presence")]
    AttributeMismatch { attribute: &'static str },
}

/// An indexed triangle mesh with optional per-vertex normals, colours and object labels.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    pub vertices: Vec<[f32; 3]>,
    /// Unit outward normal per vertex, or empty when the mesh has none.
    pub normals: Vec<[f32; 3]>,
    /// Colour per vertex.
    pub colors: Option<Vec<[u8; 3]>>,
    /// Object id per vertex, once labelled.
    pub labels: Option<Vec<u16>>,
    pub faces: Vec<[u32; 3]>,
}

/// The largest vertex count that `u32` face indices can address.
const MAX_VERTICES: usize = u32::MAX as usize + 1;

impl Mesh {
    /// Checks that every attribute has one entry per vertex (normals: or none), that every face
    /// indexes an existing vertex, and that the vertex count fits `u32` indices.
    pub fn validate(&self) -> Result<(), MeshError> {
        let n = self.vertices.len();
        if n > MAX_VERTICES {
            return Err(MeshError::TooManyVertices { vertices: n });
        }
        let lengths = [
            (
                "normals",
                (!self.normals.is_empty()).then_some(self.normals.len()),
            ),
            ("colours", self.colors.as_ref().map(Vec::len)),
            ("labels", self.labels.as_ref().map(Vec::len)),
        ];
        if let Some((attribute, got)) = lengths
            .into_iter()
            .find_map(|(a, len)| len.filter(|&l| l != n).map(|l| (a, l)))
        {
            return Err(MeshError::AttributeLength {
                attribute,
                got,
                vertices: n,
            });
        }
        if let Some((face, f)) = self
            .faces
            .iter()
            .enumerate()
            .find(|(_, f)| f.iter().any(|&v| v as usize >= n))
        {
            return Err(MeshError::FaceIndex {
                face,
                indices: *f,
                vertices: n,
            });
        }
        Ok(())
    }

    /// No faces.
    pub fn is_empty(&self) -> bool {
        self.faces.is_empty()
    }

    /// The vertices as `glam` vectors.
    pub fn points(&self) -> impl ExactSizeIterator<Item = Vec3> + '_ {
        self.vertices.iter().map(|&v| Vec3::from(v))
    }

    /// Appends `other`, its face indices shifted past this mesh's vertices. Both meshes must carry
    /// the same attributes (a mesh without vertices takes `other`'s), and the joined vertex count
    /// must fit `u32` indices.
    pub fn append(&mut self, other: &Mesh) -> Result<(), MeshError> {
        if self.vertices.is_empty() && self.faces.is_empty() {
            *self = other.clone();
            return Ok(());
        }
        let presence = |m: &Mesh| {
            [
                ("normals", !m.normals.is_empty()),
                ("colours", m.colors.is_some()),
                ("labels", m.labels.is_some()),
            ]
        };
        if let Some(((attribute, _), _)) = presence(self)
            .into_iter()
            .zip(presence(other))
            .find(|(a, b)| a.1 != b.1)
        {
            return Err(MeshError::AttributeMismatch { attribute });
        }
        let total = self.vertices.len() + other.vertices.len();
        let base = u32::try_from(self.vertices.len())
            .ok()
            .filter(|_| total <= MAX_VERTICES)
            .ok_or(MeshError::TooManyVertices { vertices: total })?;
        self.vertices.extend_from_slice(&other.vertices);
        self.normals.extend_from_slice(&other.normals);
        if let (Some(a), Some(b)) = (self.colors.as_mut(), &other.colors) {
            a.extend_from_slice(b);
        }
        if let (Some(a), Some(b)) = (self.labels.as_mut(), &other.labels) {
            a.extend_from_slice(b);
        }
        self.faces
            .extend(other.faces.iter().map(|t| t.map(|i| i + base)));
        Ok(())
    }

    /// Axis-aligned bounds `(min, max)` of the vertices (`(f32::MAX, f32::MIN)` for none).
    pub fn bounds(&self) -> (Vec3, Vec3) {
        self.points().fold(
            (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
            |(lo, hi), p| (lo.min(p), hi.max(p)),
        )
    }

    /// Moves the mesh so its bounding-box centre is the origin; returns the shift applied.
    pub fn center_on_bounds(&mut self) -> Vec3 {
        let (lo, hi) = self.bounds();
        let c = 0.5 * (lo + hi);
        for v in &mut self.vertices {
            *v = (Vec3::from(*v) - c).to_array();
        }
        -c
    }

    /// The corners of face `t`.
    fn corners(&self, t: &[u32; 3]) -> [Vec3; 3] {
        t.map(|i| Vec3::from(self.vertices[i as usize]))
    }

    /// Enclosed volume (closed meshes; see the module docs).
    pub fn volume(&self) -> f32 {
        self.faces
            .iter()
            .map(|t| {
                let [a, b, c] = self.corners(t);
                a.dot(b.cross(c)) / 6.0
            })
            .sum()
    }

    /// Centre of mass of the enclosed uniform solid (closed meshes; see the module docs).
    pub fn centroid(&self) -> Vec3 {
        let (moment, volume) = self.faces.iter().fold((Vec3::ZERO, 0.0), |(m, v), t| {
            let [a, b, c] = self.corners(t);
            let vt = a.dot(b.cross(c)) / 6.0;
            (m + vt * (a + b + c) / 4.0, v + vt)
        });
        moment / volume
    }

    /// Connected components of triangles (two triangles are connected when they share a vertex):
    /// `(component of each face, number of faces per component)`. Components are numbered by their
    /// first face, so the result is deterministic. Requires a valid mesh ([`Mesh::validate`]).
    pub fn triangle_components(&self) -> (Vec<usize>, Vec<usize>) {
        let mut parent: Vec<usize> = (0..self.vertices.len()).collect();
        fn find(parent: &mut [usize], mut i: usize) -> usize {
            while parent[i] != i {
                parent[i] = parent[parent[i]];
                i = parent[i];
            }
            i
        }
        for f in &self.faces {
            for k in 1..3 {
                let (a, b) = (
                    find(&mut parent, f[0] as usize),
                    find(&mut parent, f[k] as usize),
                );
                if a != b {
                    parent[a.max(b)] = a.min(b);
                }
            }
        }
        let mut id_of_root = vec![usize::MAX; self.vertices.len()];
        let mut sizes = Vec::new();
        let comp = self
            .faces
            .iter()
            .map(|f| {
                let r = find(&mut parent, f[0] as usize);
                if id_of_root[r] == usize::MAX {
                    id_of_root[r] = sizes.len();
                    sizes.push(0);
                }
                sizes[id_of_root[r]] += 1;
                id_of_root[r]
            })
            .collect();
        (comp, sizes)
    }

    /// Drops vertices no face uses (with their attributes), renumbering the faces and keeping the
    /// vertex order.
    pub fn remove_unreferenced_vertices(&mut self) {
        let mut used = vec![false; self.vertices.len()];
        for f in &self.faces {
            for &v in f {
                used[v as usize] = true;
            }
        }
        let mut new_index = vec![u32::MAX; self.vertices.len()];
        let mut n = 0u32;
        for (i, u) in used.iter().enumerate() {
            if *u {
                new_index[i] = n;
                n += 1;
            }
        }
        fn keep<T>(v: &mut Vec<T>, used: &[bool]) {
            let mut i = 0;
            v.retain(|_| {
                i += 1;
                used[i - 1]
            });
        }
        keep(&mut self.vertices, &used);
        keep(&mut self.normals, &used);
        if let Some(c) = self.colors.as_mut() {
            keep(c, &used);
        }
        if let Some(l) = self.labels.as_mut() {
            keep(l, &used);
        }
        for f in &mut self.faces {
            *f = f.map(|v| new_index[v as usize]);
        }
    }

    /// The faces whose three vertices carry `label` (none when the mesh is unlabelled).
    pub fn faces_with_label(&self, label: u16) -> Vec<[u32; 3]> {
        let Some(l) = &self.labels else {
            return Vec::new();
        };
        self.faces
            .iter()
            .filter(|f| f.iter().all(|&v| l[v as usize] == label))
            .copied()
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Separate fans, one per entry of `sizes`, of that many triangles.
    fn fans(sizes: &[usize]) -> Mesh {
        let mut m = Mesh::default();
        for (c, &tris) in sizes.iter().enumerate() {
            let centre = m.vertices.len() as u32;
            m.vertices.push([c as f32, 0.0, 0.0]);
            for t in 0..=tris {
                m.vertices.push([c as f32, t as f32, 1.0]);
            }
            for t in 0..tris as u32 {
                m.faces.push([centre, centre + 1 + t, centre + 2 + t]);
            }
        }
        m.normals = vec![[0.0, 0.0, 1.0]; m.vertices.len()];
        m
    }

    /// The unit cube `[0, 1]³` as 12 outward triangles.
    fn cube() -> Mesh {
        let v = |i: u32| [(i & 1) as f32, ((i >> 1) & 1) as f32, (i >> 2) as f32];
        let quads = [
            [0, 2, 3, 1],
            [4, 5, 7, 6],
            [0, 1, 5, 4],
            [2, 6, 7, 3],
            [0, 4, 6, 2],
            [1, 3, 7, 5],
        ];
        Mesh {
            vertices: (0..8).map(v).collect(),
            faces: quads
                .iter()
                .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
                .collect(),
            ..Mesh::default()
        }
    }

    #[test]
    fn unit_cube_has_volume_one_and_its_centre_as_centroid() {
        let mut m = cube();
        assert!((m.volume() - 1.0).abs() < 1e-6);
        assert!((m.centroid() - Vec3::splat(0.5)).length() < 1e-6);
        assert_eq!(m.bounds(), (Vec3::ZERO, Vec3::ONE));
        assert_eq!(m.center_on_bounds(), Vec3::splat(-0.5));
        assert_eq!(m.bounds(), (Vec3::splat(-0.5), Vec3::splat(0.5)));
        assert!(m.centroid().length() < 1e-6);
    }

    #[test]
    fn components_are_the_fans_numbered_by_first_face() {
        let m = fans(&[3, 1, 2]);
        let (comp, sizes) = m.triangle_components();
        assert_eq!(comp, [0, 0, 0, 1, 2, 2]);
        assert_eq!(sizes, [3, 1, 2]);
    }

    #[test]
    fn removing_unreferenced_vertices_keeps_each_attribute_with_its_vertex() {
        let mut m = fans(&[1, 1]);
        m.labels = Some((0..m.vertices.len() as u16).collect());
        m.colors = Some((0..m.vertices.len() as u8).map(|i| [i; 3]).collect());
        m.faces.remove(0);
        m.remove_unreferenced_vertices();
        // The second fan's vertices 3, 4, 5 remain, renumbered 0, 1, 2.
        assert_eq!(m.faces, [[0, 1, 2]]);
        assert_eq!(m.labels.as_deref(), Some(&[3, 4, 5][..]));
        assert_eq!(m.colors.as_deref(), Some(&[[3; 3], [4; 3], [5; 3]][..]));
        assert_eq!(
            m.vertices,
            [[1.0, 0.0, 0.0], [1.0, 0.0, 1.0], [1.0, 1.0, 1.0]]
        );
        assert_eq!(m.normals.len(), 3);
        m.validate().unwrap();
    }

    #[test]
    fn appended_faces_index_the_appended_vertices() {
        let (a, b) = (fans(&[2]), fans(&[1]));
        let mut m = a.clone();
        m.append(&b).unwrap();
        m.validate().unwrap();
        assert_eq!(m.vertices.len(), a.vertices.len() + b.vertices.len());
        assert_eq!(&m.faces[2..], &[[4, 5, 6]]);
        let mut empty = Mesh::default();
        empty.append(&b).unwrap();
        assert_eq!(empty, b);
        let labelled = Mesh {
            labels: Some(vec![1; 3]),
            ..b.clone()
        };
        assert_eq!(
            m.append(&labelled),
            Err(MeshError::AttributeMismatch {
                attribute: "labels"
            })
        );
    }

    #[test]
    fn validate_names_the_attribute_or_face_that_is_wrong() {
        let m = fans(&[1]);
        m.validate().unwrap();
        let short = Mesh {
            labels: Some(vec![1]),
            ..m.clone()
        };
        assert_eq!(
            short.validate().unwrap_err().to_string(),
            "1 labels for 3 vertices"
        );
        let no_normals = Mesh {
            normals: Vec::new(),
            ..m.clone()
        };
        no_normals.validate().unwrap();
        let past = Mesh {
            faces: vec![[0, 1, 3]],
            ..m
        };
        assert_eq!(
            past.validate(),
            Err(MeshError::FaceIndex {
                face: 0,
                indices: [0, 1, 3],
                vertices: 3
            })
        );
    }

    #[test]
    fn faces_with_label_need_all_three_vertices_labelled() {
        let mut m = fans(&[2]);
        m.labels = Some(vec![7, 7, 7, 9]);
        assert_eq!(m.faces_with_label(7), [[0, 1, 2]]);
        assert!(m.faces_with_label(9).is_empty());
        m.labels = None;
        assert!(m.faces_with_label(7).is_empty());
    }
}
