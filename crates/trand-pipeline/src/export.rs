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
//!   exported point; an object's mesh is the faces whose three vertices carry its id. Faces more than a
//!   voxel outside the surfels' bounding box are dropped: they are the truncation band's extension of
//!   walls under the objects, where no virtual view sees a surface.

use trand_core::math::{quat_to_rotmat, sigmoid};
use trand_core::sh::dc_to_rgb;
use trand_core::{Mesh, Surfels};
use trand_io::PointCloud;
use trand_physics::TsdfSettings;
use trand_render::RenderSettings;

use crate::Result;
use crate::simulate::{channel_members, coloured_by_object, fuse_mesh, virtual_view_ring};
use crate::update::UpdateOptions;

/// Surfels below this opacity are not exported as points: at 5 % a surfel barely changes any pixel it
/// covers, and such near-transparent surfels are scattered off the surfaces (training prunes at 0.5 %).
pub const DEFAULT_MIN_OPACITY: f64 = 0.05;

/// One object's exported geometry.
pub struct ObjectExport {
    pub id: u16,
    pub points: PointCloud,
    pub mesh: Mesh,
}

/// Everything `trand export` writes besides the splats.
pub struct Export {
    pub objects: Vec<ObjectExport>,
    /// Every object's points, with their object ids.
    pub scene_points: PointCloud,
    /// The whole fused mesh, vertices labelled by object id.
    pub scene_mesh: Mesh,
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

/// The faces of `mesh` whose three vertices lie in the box `[lo − pad, hi + pad]` of the surfel
/// centres: the fusion's truncation band extends walls a few voxels past the last surface it saw
/// (below an object standing on the table, where no view looks), and that extension is not part of
/// the scene.
fn crop_to_surfels(mesh: &mut Mesh, s: &Surfels, pad: f32) {
    let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    for m in &s.means {
        for a in 0..3 {
            lo[a] = lo[a].min(m[a] - pad);
            hi[a] = hi[a].max(m[a] + pad);
        }
    }
    let inside = |v: &[f32; 3]| (0..3).all(|a| v[a] >= lo[a] && v[a] <= hi[a]);
    let vertices = &mesh.vertices;
    mesh.faces
        .retain(|f| f.iter().all(|&v| inside(&vertices[v as usize])));
    mesh.remove_unreferenced_vertices();
}

/// The faces of `mesh` whose three vertices are labelled `id`, with the unused vertices dropped.
fn object_mesh(mesh: &Mesh, id: u16) -> Mesh {
    if mesh.labels.is_none() {
        return Mesh::default();
    }
    let mut m = Mesh {
        faces: mesh.faces_with_label(id),
        ..mesh.clone()
    };
    m.remove_unreferenced_vertices();
    m
}

/// Points and meshes of every object in `channels` (the run's `(object id, channel)` pairs) that has
/// any: an object removed at t = 1 is left out.
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
            mesh: Mesh::default(),
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
    let mut mesh = Mesh::default();
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
        crop_to_surfels(&mut mesh, surfels, TsdfSettings::tran_d(radius).voxel);
    }
    for o in &mut objects {
        o.mesh = coloured_by_object(object_mesh(&mesh, o.id));
    }
    // An object without surfels (one removed at t = 1) has nothing to export.
    objects.retain(|o| !o.points.is_empty() || !o.mesh.faces.is_empty());
    Ok(Export {
        objects,
        scene_points,
        scene_mesh: coloured_by_object(mesh),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_scene::block;
    use trand_core::sh::SH_C0;

    /// Two boxes (ids 7 and 9 in channels 0 and 1); every 5th surfel faint, every 7th undecided
    /// between the two channels.
    fn scene() -> (Surfels, Vec<(u16, usize)>) {
        let mut s = block(-0.09, -0.03, -0.03, 0.03, 0.06, 0);
        s.append(&block(0.03, -0.03, 0.09, 0.03, 0.06, 1));
        for i in 0..s.len() {
            if i % 5 == 0 {
                s.opacity_logits[i] = -5.0;
            }
            if i % 7 == 0 {
                s.obj_logits[2 * i..2 * i + 2].copy_from_slice(&[1.0, 1.0]);
            }
        }
        (s, vec![(7, 0), (9, 1)])
    }

    #[test]
    fn exported_points_are_the_object_surfels() {
        let (s, channels) = scene();
        for &(_, c) in &channels {
            let p = object_points(&s, c, DEFAULT_MIN_OPACITY);
            let want: Vec<usize> = (0..s.len())
                .filter(|&i| {
                    let l = &s.obj_logits[2 * i..2 * i + 2];
                    let prob = 1.0 / (1.0 + (l[1 - c] - l[c]).exp());
                    prob > 0.5 && 1.0 / (1.0 + (-s.opacity_logits[i]).exp()) >= 0.05
                })
                .collect();
            assert!(!want.is_empty());
            assert_eq!(
                p.positions,
                want.iter().map(|&i| s.means[i]).collect::<Vec<_>>()
            );
            for (k, &i) in want.iter().enumerate() {
                let q = glam::Quat::from_array([
                    s.quats[i][1],
                    s.quats[i][2],
                    s.quats[i][3],
                    s.quats[i][0],
                ]);
                let n = q * glam::Vec3::Z;
                assert!((glam::Vec3::from(p.normals[k]) - n).length() < 1e-5);
                let rgb = s.sh_dc[i].map(|d| ((0.5 + SH_C0 as f32 * d) * 255.0).round() as u8);
                assert_eq!(p.colors[k], rgb);
            }
        }
    }

    #[test]
    fn mesh_faces_index_existing_vertices_and_each_object_mesh_lies_on_its_surfels() {
        let (s, channels) = scene();
        let settings = RenderSettings::default();
        let ex = export(
            &s,
            &channels,
            DEFAULT_MIN_OPACITY,
            &settings,
            &mut |_, _, _| {},
        )
        .unwrap();
        assert_eq!(ex.objects.len(), 2);
        let ids = ex.scene_points.object_ids.as_ref().unwrap();
        let mut total = 0;
        for o in &ex.objects {
            assert!(!o.mesh.faces.is_empty(), "object {}: empty mesh", o.id);
            o.mesh.validate().unwrap();
            assert!(o.mesh.labels.as_ref().unwrap().iter().all(|&l| l == o.id));
            // Every mesh vertex lies within the fusion's truncation band of the object's surfels, and
            // half of them within 1.5 voxels (the open-bottomed boxes are also seen from below, so
            // their walls get an inner copy inside the band).
            let own: Vec<glam::Vec3> = s
                .means
                .iter()
                .map(|&m| glam::Vec3::from(m))
                .filter(|m| (m.x < 0.0) == (o.id == 7))
                .collect();
            let ts = TsdfSettings::tran_d(virtual_view_ring(&s).1 as f32);
            let mut d: Vec<f32> = o
                .mesh
                .vertices
                .iter()
                .map(|&v| {
                    own.iter()
                        .map(|&p| (glam::Vec3::from(v) - p).length())
                        .fold(f32::INFINITY, f32::min)
                })
                .collect();
            d.sort_by(f32::total_cmp);
            let (median, max) = (d[d.len() / 2], d[d.len() - 1]);
            assert!(
                max < ts.trunc && median < 1.5 * ts.voxel,
                "object {}: median {median}, max {max}, voxel {}",
                o.id,
                ts.voxel
            );
            assert_eq!(ids.iter().filter(|&&i| i == o.id).count(), o.points.len());
            total += o.points.len();
        }
        assert_eq!(ex.scene_points.len(), total);
        ex.scene_mesh.validate().unwrap();
        let faces: usize = ex.objects.iter().map(|o| o.mesh.faces.len()).sum();
        assert!(faces <= ex.scene_mesh.faces.len() && faces > ex.scene_mesh.faces.len() * 9 / 10);
    }

    #[test]
    fn channels_without_an_object_id_are_not_exported() {
        let (s, _) = scene();
        let ex = export(
            &s,
            &[(0, 0), (4, 1), (5, 9)],
            0.5,
            &RenderSettings::default(),
            &mut |_, _, _| {},
        )
        .unwrap();
        let ids: Vec<u16> = ex.objects.iter().map(|o| o.id).collect();
        assert_eq!(ids, [4]);
    }
}
