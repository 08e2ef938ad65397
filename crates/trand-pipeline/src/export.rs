//! A finished run's objects as point clouds and meshes (`trand export`).
//!
//! * Points: the surfels of each object, by the membership rule of the update
//!   ([`crate::simulate::channel_members`]: the probability of the object's channel, from the run's
//!   `object_channels`, is above ½), keeping those with opacity `σ(o)` at least
//!   [`DEFAULT_MIN_OPACITY`]. A point is the surfel centre, its normal (the third column of `R(q)`) and
//!   its view-independent colour (the SH DC term, `0.5 + C0·dc`, clamped to [0, 1]).
//! * Mesh: the TSDF fusion and marching cubes of the t = 1 update ([`crate::simulate::fuse_mesh`]) with
//!   the update's virtual views, applied to every surfel of the run, so the surface is the one the run
//!   renders. The TSDF voxel is the authors' `2·radius/256` with `radius` the distance of the virtual
//!   cameras from the scene centre (TRAN-D's scene radius of the cameras that are fused), so the mesh
//!   depends on the surfels alone, not on the sequence's cameras. Vertices take the id of the nearest
//!   exported point; an object's mesh is the faces whose three vertices carry its id.

use trand_core::Surfels;
use trand_core::math::{quat_to_rotmat, sigmoid};
use trand_core::sh::dc_to_rgb;
use trand_io::PointCloud;
use trand_render::RenderSettings;

use crate::Result;
use crate::simulate::{channel_members, fuse_mesh, io_mesh, virtual_view_ring};
use crate::update::UpdateOptions;

/// Surfels below this opacity are not exported as points: at 5 % a surfel barely changes any pixel it
/// covers, and such near-transparent surfels are scattered off the surfaces (training prunes at 0.5 %).
pub const DEFAULT_MIN_OPACITY: f64 = 0.05;

/// One object's exported geometry.
pub struct ObjectExport {
    pub id: u16,
    pub points: PointCloud,
    pub mesh: trand_io::Mesh,
}

/// Everything `trand export` writes besides the splats.
pub struct Export {
    pub objects: Vec<ObjectExport>,
    /// Every object's points, with their object ids.
    pub scene_points: PointCloud,
    /// The whole fused mesh, vertices labelled by object id.
    pub scene_mesh: trand_io::Mesh,
}

/// The view-independent colour of a surfel as 8 bits per channel.
fn dc_colour(dc: [f32; 3]) -> [u8; 3] {
    dc.map(|c| (dc_to_rgb(c).clamp(0.0, 1.0) * 255.0).round() as u8)
}

/// The surfel normal: the third column of its rotation (zero for a zero quaternion).
fn normal(q: [f32; 4]) -> [f32; 3] {
    quat_to_rotmat(q)
        .map(|(m, _)| [m[0][2], m[1][2], m[2][2]])
        .unwrap_or([0.0; 3])
}

/// The exported points of the channel `c`: its members with opacity at least `min_opacity`.
pub fn object_points(s: &Surfels, c: usize, min_opacity: f64) -> PointCloud {
    let idx: Vec<usize> = channel_members(s, c)
        .into_iter()
        .map(|i| i as usize)
        .filter(|&i| f64::from(sigmoid(s.opacity_logits[i])) >= min_opacity)
        .collect();
    PointCloud {
        positions: idx.iter().map(|&i| s.means[i]).collect(),
        normals: idx.iter().map(|&i| normal(s.quats[i])).collect(),
        colors: idx.iter().map(|&i| dc_colour(s.sh_dc[i])).collect(),
        object_ids: None,
    }
}

/// The faces of `mesh` whose three vertices are labelled `id`, with the unused vertices dropped.
fn object_mesh(mesh: &trand_physics::Mesh, id: u16) -> trand_physics::Mesh {
    let Some(labels) = &mesh.labels else {
        return trand_physics::Mesh::default();
    };
    let mut m = mesh.clone();
    m.faces
        .retain(|f| f.iter().all(|&v| labels[v as usize] == id));
    m.remove_unreferenced_vertices();
    m
}

/// Points and meshes of every object in `channels` (the run's `(object id, channel)` pairs).
pub fn export(
    surfels: &Surfels,
    channels: &[(u16, usize)],
    min_opacity: f64,
    settings: &RenderSettings,
    progress: &mut dyn FnMut(&str, u32, u32),
) -> Result<Export> {
    let opts = UpdateOptions::default();
    let mut objects: Vec<ObjectExport> = channels
        .iter()
        .filter(|&&(id, c)| id != 0 && c < surfels.num_objects)
        .map(|&(id, c)| ObjectExport {
            id,
            points: object_points(surfels, c, min_opacity),
            mesh: trand_io::Mesh::default(),
        })
        .collect();
    let mut scene_points = PointCloud {
        object_ids: Some(Vec::new()),
        ..Default::default()
    };
    for o in &objects {
        scene_points
            .positions
            .extend_from_slice(&o.points.positions);
        scene_points.normals.extend_from_slice(&o.points.normals);
        scene_points.colors.extend_from_slice(&o.points.colors);
        if let Some(ids) = scene_points.object_ids.as_mut() {
            ids.extend(std::iter::repeat_n(o.id, o.points.len()));
        }
    }
    let mut mesh = trand_physics::Mesh::default();
    if !surfels.is_empty() {
        let radius = virtual_view_ring(surfels).1 as f32;
        let ids = scene_points.object_ids.as_deref().unwrap_or_default();
        mesh = fuse_mesh(
            surfels,
            radius,
            (&scene_points.positions, ids),
            &opts,
            settings,
            progress,
        )?;
    }
    for o in &mut objects {
        o.mesh = io_mesh(&object_mesh(&mesh, o.id));
    }
    Ok(Export {
        objects,
        scene_points,
        scene_mesh: io_mesh(&mesh),
    })
}
