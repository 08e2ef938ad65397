//! Clean-up and object labels of the fused surface ([`trand_core::Mesh`]): the small floating
//! clusters TRAN-D removes, and each vertex's object id from the nearest labelled point.

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rayon::prelude::*;
use trand_core::Mesh;

/// Triangle clusters to keep by size rank (TRAN-D `post_process_mesh(cluster_to_keep=50)`).
pub const CLUSTERS_TO_KEEP: usize = 50;
/// Never keep a cluster smaller than this many triangles (same function).
pub const MIN_CLUSTER_TRIANGLES: usize = 50;

/// Why labelling failed.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum LabelError {
    #[error("{points} labelled points but {labels} labels")]
    LabelCountMismatch { points: usize, labels: usize },
    #[error("no labelled points to label the vertices with")]
    NoLabelledPoints,
    #[error("cannot build the kd-tree of the labelled points: {0}")]
    KdTree(String),
}

/// Removes small floating clusters (TRAN-D §5.3): keeps the triangle components
/// ([`Mesh::triangle_components`]) with at least `max(size of the 50th largest component (0 if
/// fewer), 50)` triangles, then drops degenerate faces and unreferenced vertices.
pub fn remove_small_components(mesh: &mut Mesh) {
    let (comp, sizes) = mesh.triangle_components();
    let mut sorted = sizes.clone();
    sorted.sort_unstable_by(|a, b| b.cmp(a));
    let rank_size = sorted.get(CLUSTERS_TO_KEEP - 1).copied().unwrap_or(0);
    let min_size = rank_size.max(MIN_CLUSTER_TRIANGLES);
    let faces = std::mem::take(&mut mesh.faces);
    mesh.faces = faces
        .into_iter()
        .zip(comp)
        .filter(|(f, c)| sizes[*c] >= min_size && f[0] != f[1] && f[1] != f[2] && f[0] != f[2])
        .map(|(f, _)| f)
        .collect();
    mesh.remove_unreferenced_vertices();
}

/// Labels every vertex of `mesh` with the label of its nearest labelled point (exact kd-tree
/// search, kiddo). TRAN-D compares TSDF-averaged colours for exact equality, which silently drops
/// boundary vertices; the nearest object surfel labels every vertex.
pub fn label_by_nearest(
    mesh: &mut Mesh,
    points: &[[f32; 3]],
    labels: &[u16],
) -> Result<(), LabelError> {
    if points.len() != labels.len() {
        return Err(LabelError::LabelCountMismatch {
            points: points.len(),
            labels: labels.len(),
        });
    }
    if points.is_empty() {
        return Err(LabelError::NoLabelledPoints);
    }
    let tree = ImmutableKdTree::<f32, 3>::new_from_slice(points)
        .map_err(|e| LabelError::KdTree(format!("{e:?}")))?;
    let out = mesh
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
    mesh.labels = Some(out);
    Ok(())
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
        remove_small_components(&mut m);
        assert_eq!(m.faces.len(), 60 + 50 + 200);
        assert_eq!(m.vertices.len(), 62 + 52 + 202); // a fan of t triangles has t + 2 vertices
        m.validate().unwrap();
    }

    #[test]
    fn only_the_fifty_largest_components_survive() {
        let sizes: Vec<usize> = (0..60).map(|i| 100 + i).collect();
        let mut m = clusters(&sizes);
        remove_small_components(&mut m);
        // The 50th largest has 110 triangles: the ten smaller clusters (100..109) go.
        assert_eq!(m.faces.len(), (110..160).sum::<usize>());
    }

    #[test]
    fn vertices_take_the_label_of_the_nearest_point() {
        let mut m = clusters(&[3]);
        label_by_nearest(&mut m, &[[0.0, 0.0, 0.0], [0.0, 3.0, 1.0]], &[7, 9]).unwrap();
        assert_eq!(m.labels.as_deref(), Some(&[7, 7, 7, 9, 9][..]));
        assert_eq!(m.faces_with_label(7).len(), 1);
        assert_eq!(
            label_by_nearest(&mut m, &[], &[]),
            Err(LabelError::NoLabelledPoints)
        );
    }
}
