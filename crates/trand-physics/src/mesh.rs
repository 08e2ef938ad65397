//! Indexed triangle mesh, connected-component cleanup and per-vertex object labels.
//!
//! Layout: `vertices[i]`, `normals[i]` (unit, pointing out of the surface) and optional
//! `labels[i]` (object id) per vertex; `faces[t]` = three vertex indices, counter-clockwise seen
//! from outside.

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rayon::prelude::*;

/// Triangle clusters to keep by size rank (TRAN-D `post_process_mesh(cluster_to_keep=50)`).
pub const CLUSTERS_TO_KEEP: usize = 50;
/// Never keep a cluster smaller than this many triangles (same function).
pub const MIN_CLUSTER_TRIANGLES: usize = 50;

#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    pub vertices: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
    pub faces: Vec<[u32; 3]>,
    /// Object id per vertex, once labelled.
    pub labels: Option<Vec<u16>>,
}

/// Why labelling failed.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum MeshError {
    #[error("{points} labelled points but {labels} labels")]
    LabelCountMismatch { points: usize, labels: usize },
    #[error("no labelled points to label the vertices with")]
    NoLabelledPoints,
    #[error("cannot build the kd-tree of the labelled points: {0}")]
    KdTree(String),
}

impl Mesh {
    pub fn is_empty(&self) -> bool {
        self.faces.is_empty()
    }

    /// Connected components of triangles (two triangles are connected when they share a
    /// vertex): `(component of each face, number of faces per component)`. Components are
    /// numbered by their first face, so the result is deterministic.
    pub fn triangle_components(&self) -> (Vec<u32>, Vec<usize>) {
        let mut parent: Vec<u32> = (0..self.vertices.len() as u32).collect();
        fn find(parent: &mut [u32], mut i: u32) -> u32 {
            while parent[i as usize] != i {
                parent[i as usize] = parent[parent[i as usize] as usize];
                i = parent[i as usize];
            }
            i
        }
        for f in &self.faces {
            for k in 1..3 {
                let (a, b) = (find(&mut parent, f[0]), find(&mut parent, f[k]));
                if a != b {
                    parent[a.max(b) as usize] = a.min(b);
                }
            }
        }
        let mut id_of_root = vec![u32::MAX; self.vertices.len()];
        let mut sizes = Vec::new();
        let comp = self
            .faces
            .iter()
            .map(|f| {
                let r = find(&mut parent, f[0]) as usize;
                if id_of_root[r] == u32::MAX {
                    id_of_root[r] = sizes.len() as u32;
                    sizes.push(0);
                }
                sizes[id_of_root[r] as usize] += 1;
                id_of_root[r]
            })
            .collect();
        (comp, sizes)
    }

    /// Removes small floating clusters (TRAN-D §5.3): keeps the triangle components with at
    /// least `max(size of the 50th largest component (0 if fewer), 50)` triangles, then drops
    /// degenerate faces and unreferenced vertices.
    pub fn remove_small_components(&mut self) {
        let (comp, sizes) = self.triangle_components();
        let mut sorted = sizes.clone();
        sorted.sort_unstable_by(|a, b| b.cmp(a));
        let rank_size = sorted.get(CLUSTERS_TO_KEEP - 1).copied().unwrap_or(0);
        let min_size = rank_size.max(MIN_CLUSTER_TRIANGLES);
        let faces = std::mem::take(&mut self.faces);
        self.faces = faces
            .into_iter()
            .zip(comp)
            .filter(|(f, c)| {
                sizes[*c as usize] >= min_size && f[0] != f[1] && f[1] != f[2] && f[0] != f[2]
            })
            .map(|(f, _)| f)
            .collect();
        self.remove_unreferenced_vertices();
    }

    /// Drops vertices no face uses (renumbering the faces, keeping vertex order).
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
        if let Some(l) = self.labels.as_mut() {
            keep(l, &used);
        }
        for f in &mut self.faces {
            *f = f.map(|v| new_index[v as usize]);
        }
    }

    /// Labels every vertex with the label of its nearest labelled point (exact kd-tree search,
    /// kiddo). TRAN-D compares TSDF-averaged colours for exact equality, which silently drops
    /// boundary vertices; the nearest object surfel labels every vertex.
    pub fn label_by_nearest(
        &mut self,
        points: &[[f32; 3]],
        labels: &[u16],
    ) -> Result<(), MeshError> {
        if points.len() != labels.len() {
            return Err(MeshError::LabelCountMismatch {
                points: points.len(),
                labels: labels.len(),
            });
        }
        if points.is_empty() {
            return Err(MeshError::NoLabelledPoints);
        }
        let tree = ImmutableKdTree::<f32, 3>::new_from_slice(points)
            .map_err(|e| MeshError::KdTree(format!("{e:?}")))?;
        let out = self
            .vertices
            .par_iter()
            .map(|v| {
                labels[tree
                    .query(v)
                    .nearest_one::<SquaredEuclidean<f32>>()
                    .execute()
                    .item as usize]
            })
            .collect();
        self.labels = Some(out);
        Ok(())
    }

    /// The faces whose three vertices carry `label` (requires labels).
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

    /// `n` separate fans of `tris` triangles each.
    fn clusters(sizes: &[usize]) -> Mesh {
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

    #[test]
    fn components_below_fifty_triangles_are_removed() {
        let mut m = clusters(&[60, 10, 49, 50, 200]);
        m.remove_small_components();
        assert_eq!(m.faces.len(), 60 + 50 + 200);
        assert_eq!(m.vertices.len(), 62 + 52 + 202); // a fan of t triangles has t + 2 vertices
        assert!(
            m.faces
                .iter()
                .flatten()
                .all(|&v| (v as usize) < m.vertices.len())
        );
    }

    #[test]
    fn only_the_fifty_largest_components_survive() {
        let sizes: Vec<usize> = (0..60).map(|i| 100 + i).collect();
        let mut m = clusters(&sizes);
        m.remove_small_components();
        // The 50th largest has 110 triangles: the ten smaller clusters (100..109) go.
        assert_eq!(m.faces.len(), (110..160).sum::<usize>());
    }

    #[test]
    fn vertices_take_the_label_of_the_nearest_point() {
        let mut m = clusters(&[3]);
        m.label_by_nearest(&[[0.0, 0.0, 0.0], [0.0, 3.0, 1.0]], &[7, 9])
            .unwrap();
        assert_eq!(m.labels.as_deref(), Some(&[7, 7, 7, 9, 9][..]));
        assert_eq!(m.faces_with_label(7).len(), 1);
        assert_eq!(
            m.label_by_nearest(&[], &[]),
            Err(MeshError::NoLabelledPoints)
        );
    }
}
