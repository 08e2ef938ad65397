//! MPM particles of the remaining objects (TRAN-D §5.4).
//!
//! For each object, in the caller's order: its surfel centres, then the fused-mesh vertices
//! labelled with it, then (optionally, [`InteriorFill::RayParity`]) points filling its inside.
//! All objects go into one particle set (one MPM solver, so they interact through the grid).
//! [`ParticleSet::sources`] records where every particle came from, so after the simulation the
//! caller moves each surfel to its own particle's position (a surfel *is* its particle, as in the
//! authors' code) and may rotate it by the particle's polar rotation.
//!
//! Interior fill (absent from the authors' release, present in their pre-release code): the
//! object's labelled triangles are rasterised onto vertical rays through a regular grid of
//! columns (spacing `s`); the sorted crossings of a column pair up as (enter, leave), and grid
//! points `z = z₀ + (k + ½)s` between a pair are inside. A column with an odd number of
//! crossings (the mesh is open there) contributes nothing.

use rayon::prelude::*;

use trand_core::Mesh;

/// How to fill the objects' insides.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum InteriorFill {
    /// Surface particles only (the authors' release).
    #[default]
    None,
    /// Grid points at `spacing` metres inside the closed labelled mesh, by vertical ray parity
    /// (TRAN-D's MPM grid is 1/48 m; `dx/2 = 1/96` gives ~8 particles per cell).
    RayParity { spacing: f32 },
}

/// The surfels of one remaining object.
#[derive(Clone, Copy, Debug)]
pub struct ObjectSurfels<'a> {
    /// Object id (the mesh vertex label of this object).
    pub id: u16,
    /// Surfel centres.
    pub centres: &'a [[f32; 3]],
    /// Index of each surfel in the caller's surfel store (same length as `centres`).
    pub surfel_indices: &'a [u32],
}

/// Where a particle comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ParticleSource {
    /// The centre of surfel `surfel` (an index into the caller's surfel store).
    Surfel { object: u16, surfel: u32 },
    /// Vertex `vertex` of the fused mesh.
    MeshVertex { object: u16, vertex: u32 },
    /// An interior fill point.
    Interior { object: u16 },
}

impl ParticleSource {
    pub fn object(&self) -> u16 {
        match *self {
            Self::Surfel { object, .. }
            | Self::MeshVertex { object, .. }
            | Self::Interior { object } => object,
        }
    }
}

/// Particles and their origin, index-aligned.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ParticleSet {
    pub positions: Vec<[f32; 3]>,
    pub sources: Vec<ParticleSource>,
}

impl ParticleSet {
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// `(surfel index, particle index)` for every surfel particle.
    pub fn surfel_particles(&self) -> impl Iterator<Item = (u32, usize)> + '_ {
        self.sources
            .iter()
            .enumerate()
            .filter_map(|(i, s)| match *s {
                ParticleSource::Surfel { surfel, .. } => Some((surfel, i)),
                _ => None,
            })
    }
}

/// Why particles cannot be built.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ParticleError {
    #[error("object {id}: {centres} surfel centres but {indices} surfel indices")]
    SurfelCountMismatch {
        id: u16,
        centres: usize,
        indices: usize,
    },
    #[error("object {id}: surfel {surfel} has a non-finite centre")]
    NonFiniteSurfel { id: u16, surfel: u32 },
    #[error("the mesh has vertices but no labels (call label_by_nearest first)")]
    UnlabelledMesh,
    #[error("interior fill spacing {0} must be finite and positive")]
    BadSpacing(f32),
}

/// Builds the particle set (see the module docs for the order and the fill).
pub fn build_particles(
    objects: &[ObjectSurfels],
    mesh: &Mesh,
    fill: InteriorFill,
) -> Result<ParticleSet, ParticleError> {
    if !mesh.vertices.is_empty() && mesh.labels.is_none() {
        return Err(ParticleError::UnlabelledMesh);
    }
    match fill {
        InteriorFill::RayParity { spacing } if !(spacing.is_finite() && spacing > 0.0) => {
            return Err(ParticleError::BadSpacing(spacing));
        }
        _ => {}
    }
    for o in objects {
        if o.centres.len() != o.surfel_indices.len() {
            return Err(ParticleError::SurfelCountMismatch {
                id: o.id,
                centres: o.centres.len(),
                indices: o.surfel_indices.len(),
            });
        }
        if let Some(k) = o
            .centres
            .iter()
            .position(|c| c.iter().any(|v| !v.is_finite()))
        {
            return Err(ParticleError::NonFiniteSurfel {
                id: o.id,
                surfel: o.surfel_indices[k],
            });
        }
    }
    let per_object: Vec<ParticleSet> = objects
        .par_iter()
        .map(|o| object_particles(o, mesh, fill))
        .collect();
    let mut out = ParticleSet::default();
    for p in per_object {
        out.positions.extend(p.positions);
        out.sources.extend(p.sources);
    }
    Ok(out)
}

fn object_particles(o: &ObjectSurfels, mesh: &Mesh, fill: InteriorFill) -> ParticleSet {
    let mut set = ParticleSet::default();
    for (c, &s) in o.centres.iter().zip(o.surfel_indices) {
        set.positions.push(*c);
        set.sources.push(ParticleSource::Surfel {
            object: o.id,
            surfel: s,
        });
    }
    if let Some(labels) = &mesh.labels {
        for (v, (p, &l)) in mesh.vertices.iter().zip(labels).enumerate() {
            if l == o.id {
                set.positions.push(*p);
                set.sources.push(ParticleSource::MeshVertex {
                    object: o.id,
                    vertex: v as u32,
                });
            }
        }
    }
    if let InteriorFill::RayParity { spacing } = fill {
        let tris: Vec<[[f32; 3]; 3]> = mesh
            .faces_with_label(o.id)
            .iter()
            .map(|f| f.map(|v| mesh.vertices[v as usize]))
            .collect();
        for p in fill_by_ray_parity(&tris, spacing) {
            set.positions.push(p);
            set.sources.push(ParticleSource::Interior { object: o.id });
        }
    }
    set
}

/// Grid points at `spacing` inside the closed triangle soup `tris` (vertical ray parity).
pub fn fill_by_ray_parity(tris: &[[[f32; 3]; 3]], spacing: f32) -> Vec<[f32; 3]> {
    if tris.is_empty() {
        return Vec::new();
    }
    let (mut lo, mut hi) = ([f32::MAX; 3], [f32::MIN; 3]);
    for v in tris.iter().flatten() {
        for k in 0..3 {
            (lo[k], hi[k]) = (lo[k].min(v[k]), hi[k].max(v[k]));
        }
    }
    let s = spacing as f64;
    let n = |k: usize| (((hi[k] - lo[k]) as f64 / s).ceil() as usize).max(1);
    let (nx, ny, nz) = (n(0), n(1), n(2));
    // Column (i, j) at lo + (i + ½ + ε_k)s: the tiny offsets, irrational and different per axis,
    // keep columns off mesh edges and vertices, which lie on the TSDF voxel lattice and on its
    // diagonals (a column through an edge would hit both or neither of its triangles and break
    // the parity).
    const EPS: [f64; 2] = [
        1e-3 * std::f64::consts::SQRT_2,
        1e-3 * 1.732_050_807_568_877_2,
    ];
    let col = |i: usize, k: usize| lo[k] as f64 + (i as f64 + 0.5 + EPS[k]) * s;
    let mut crossings: Vec<Vec<f64>> = vec![Vec::new(); nx * ny];
    for t in tris {
        let [a, b, c] = t.map(|v| v.map(f64::from));
        let area = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
        if area.abs() < 1e-18 {
            continue; // vertical (edge-on) triangle: a ray never crosses its interior
        }
        let range = |k: usize| {
            let (mn, mx) = (a[k].min(b[k]).min(c[k]), a[k].max(b[k]).max(c[k]));
            let first = ((mn - lo[k] as f64) / s - 0.5 - EPS[k]).ceil().max(0.0) as usize;
            let last =
                (((mx - lo[k] as f64) / s - 0.5 - EPS[k]).floor() as i64).min(n(k) as i64 - 1);
            (first, last)
        };
        let ((i0, i1), (j0, j1)) = (range(0), range(1));
        for j in j0 as i64..=j1 {
            for i in i0 as i64..=i1 {
                let (x, y) = (col(i as usize, 0), col(j as usize, 1));
                // Barycentric coordinates of (x, y) in the projected triangle.
                let wb = ((x - a[0]) * (c[1] - a[1]) - (y - a[1]) * (c[0] - a[0])) / area;
                let wc = ((b[0] - a[0]) * (y - a[1]) - (b[1] - a[1]) * (x - a[0])) / area;
                let wa = 1.0 - wb - wc;
                if wa >= 0.0 && wb >= 0.0 && wc >= 0.0 {
                    crossings[j as usize * nx + i as usize].push(wa * a[2] + wb * b[2] + wc * c[2]);
                }
            }
        }
    }
    let mut out = Vec::new();
    for (idx, zs) in crossings.iter_mut().enumerate() {
        if zs.is_empty() || zs.len() % 2 == 1 {
            continue;
        }
        zs.sort_by(f64::total_cmp);
        let (x, y) = (col(idx % nx, 0), col(idx / nx, 1));
        for pair in zs.chunks_exact(2) {
            for k in 0..nz {
                let z = lo[2] as f64 + (k as f64 + 0.5) * s;
                if z > pair[0] && z < pair[1] {
                    out.push([x as f32, y as f32, z as f32]);
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Closed axis-aligned box `[lo, hi]` as 12 outward triangles.
    fn box_mesh(lo: [f32; 3], hi: [f32; 3], label: u16) -> Mesh {
        let v = |i: usize| {
            [
                if i & 1 == 0 { lo[0] } else { hi[0] },
                if i & 2 == 0 { lo[1] } else { hi[1] },
                if i & 4 == 0 { lo[2] } else { hi[2] },
            ]
        };
        let quads = [
            [0, 2, 3, 1],
            [4, 5, 7, 6],
            [0, 1, 5, 4],
            [2, 6, 7, 3],
            [0, 4, 6, 2],
            [1, 3, 7, 5],
        ];
        let faces = quads
            .iter()
            .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
            .collect();
        Mesh {
            vertices: (0..8).map(v).collect(),
            normals: vec![[0.0; 3]; 8],
            faces,
            labels: Some(vec![label; 8]),
            ..Mesh::default()
        }
    }

    #[test]
    fn closed_box_is_filled_on_the_grid_and_only_inside() {
        let m = box_mesh([0.0, 0.0, 0.0], [0.1, 0.2, 0.05], 3);
        let tris: Vec<_> = m
            .faces
            .iter()
            .map(|f| f.map(|v| m.vertices[v as usize]))
            .collect();
        let pts = fill_by_ray_parity(&tris, 0.01);
        assert_eq!(pts.len(), 10 * 20 * 5);
        assert!(pts.iter().all(|p| p[0] > 0.0
            && p[0] < 0.1
            && p[1] > 0.0
            && p[1] < 0.2
            && p[2] > 0.0
            && p[2] < 0.05));
    }

    #[test]
    fn open_mesh_columns_are_not_filled() {
        let mut m = box_mesh([0.0; 3], [0.1; 3], 3);
        m.faces.truncate(2); // keep only the bottom: every column crosses once
        let tris: Vec<_> = m
            .faces
            .iter()
            .map(|f| f.map(|v| m.vertices[v as usize]))
            .collect();
        assert!(fill_by_ray_parity(&tris, 0.01).is_empty());
    }

    #[test]
    fn particles_come_in_object_order_with_their_sources() {
        let mut mesh = box_mesh([0.0; 3], [0.1; 3], 2);
        mesh.labels.as_mut().unwrap()[7] = 5;
        let (c1, i1) = ([[0.05f32, 0.05, 0.05]], [42u32]);
        let (c2, i2) = ([[1.0f32, 1.0, 1.0], [1.1, 1.0, 1.0]], [7u32, 8]);
        let objects = [
            ObjectSurfels {
                id: 5,
                centres: &c2,
                surfel_indices: &i2,
            },
            ObjectSurfels {
                id: 2,
                centres: &c1,
                surfel_indices: &i1,
            },
        ];
        let set = build_particles(&objects, &mesh, InteriorFill::None).unwrap();
        use ParticleSource::*;
        assert_eq!(
            set.sources,
            vec![
                Surfel {
                    object: 5,
                    surfel: 7
                },
                Surfel {
                    object: 5,
                    surfel: 8
                },
                MeshVertex {
                    object: 5,
                    vertex: 7
                },
                Surfel {
                    object: 2,
                    surfel: 42
                },
            ]
            .into_iter()
            .chain((0..7).map(|v| MeshVertex {
                object: 2,
                vertex: v
            }))
            .collect::<Vec<_>>()
        );
        assert_eq!(set.positions[3], c1[0]);
        assert_eq!(
            set.surfel_particles().collect::<Vec<_>>(),
            vec![(7, 0), (8, 1), (42, 3)]
        );
        // Filled: after the surfel and the 8 vertices come the 10³ interior points.
        let closed = box_mesh([0.0; 3], [0.1; 3], 2);
        let filled = build_particles(
            &objects[1..],
            &closed,
            InteriorFill::RayParity { spacing: 0.01 },
        )
        .unwrap();
        assert_eq!(filled.len(), 1 + 8 + 1000);
        assert!(
            filled.sources[9..]
                .iter()
                .all(|s| *s == Interior { object: 2 })
        );
        // Object 2 without the top corner owns no top face any more: open, so no fill.
        let open = build_particles(
            &objects[1..],
            &mesh,
            InteriorFill::RayParity { spacing: 0.01 },
        )
        .unwrap();
        assert!(!open.sources.iter().any(|s| matches!(s, Interior { .. })));
        let unlabelled = Mesh {
            labels: None,
            ..mesh.clone()
        };
        assert_eq!(
            build_particles(&objects, &unlabelled, InteriorFill::None),
            Err(ParticleError::UnlabelledMesh)
        );
    }
}
