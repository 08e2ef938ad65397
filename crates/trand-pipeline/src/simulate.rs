//! Steps 3–5 of the scene update: the remaining surfels' depth from virtual views fused into a TSDF
//! and meshed, particles from surfel centres and mesh vertices, MLS-MPM, and the surfels moved with
//! their particles ([`SurfelMotion`]).

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use glam::{DVec3, Quat};
use trand_core::{Camera, Intrinsics, Mesh, Surfels};
use trand_physics::{
    MpmSolver, ObjectSurfels, TsdfSettings, TsdfVolume, below_view, build_particles,
    label_by_nearest, ring_views,
};
use trand_render::{RenderSettings, render};

use crate::surfel_ops::{channel_probs, turn};
use crate::targets;
pub use crate::update_options::{MeshDepth, SurfelMotion};
use crate::update_options::{SceneScale, UpdateOptions};
use crate::{PipelineError, Result};

/// The centre of the surfels' bounding box and the distance of the virtual cameras from it: far
/// enough that the whole footprint fits a 60°-wide view.
pub fn virtual_view_ring(s: &Surfels) -> (DVec3, f64) {
    let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    for m in &s.means {
        let p = DVec3::new(m[0] as f64, m[1] as f64, m[2] as f64);
        lo = lo.min(p);
        hi = hi.max(p);
    }
    let size = (hi - lo).max_element().max(0.05);
    ((lo + hi) * 0.5, (size * 1.2).max(0.3))
}

/// The virtual cameras of step 3 around the surfels' footprint ([`virtual_view_ring`]).
pub fn virtual_cameras(s: &Surfels, opts: &UpdateOptions) -> Vec<Camera> {
    let (centre, radius) = virtual_view_ring(s);
    let k = Intrinsics::centered(opts.virtual_focal, opts.virtual_width, opts.virtual_height);
    let els: Vec<f64> = opts
        .ring_elevations_deg
        .iter()
        .map(|d| d.to_radians())
        .collect();
    let mut cams = ring_views(centre, radius, &els, opts.ring_azimuths, k);
    cams.push(below_view(DVec3::new(centre.x, centre.y, 0.0), radius, k));
    cams
}

/// The surfels of object channel `c`: those whose probability of `c` is above ½ (the membership
/// rule of the update, the contact test and `trand export`).
pub fn channel_members(s: &Surfels, c: usize) -> Vec<u32> {
    let p = channel_probs(s, c);
    (0..s.len() as u32)
        .filter(|&i| p[i as usize] > 0.5)
        .collect()
}

/// Step 3: the depth of `surfels` rendered from [`virtual_cameras`], fused into a TSDF of
/// [`TsdfSettings::tran_d`]`(radius)` over the surfels' bounds (never reaching more than a margin
/// below the table, z = 0), meshed by marching cubes with small clusters removed, and each vertex
/// labelled with the id of the nearest of `labelled` points (left unlabelled when there are none).
pub fn fuse_mesh(
    surfels: &Surfels,
    radius: f32,
    labelled: (&[[f32; 3]], &[u16]),
    opts: &UpdateOptions,
    settings: &RenderSettings,
    progress: &mut dyn FnMut(&str, u32, u32),
) -> Result<Mesh> {
    let cams = virtual_cameras(surfels, opts);
    let ts = TsdfSettings::tran_d(radius);
    let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    for m in &surfels.means {
        for a in 0..3 {
            lo[a] = lo[a].min(m[a]);
            hi[a] = hi[a].max(m[a]);
        }
    }
    let margin = 8.0 * ts.voxel + 0.01;
    let lo = [
        lo[0] - margin,
        lo[1] - margin,
        (lo[2] - margin).max(-margin),
    ];
    let hi = [hi[0] + margin, hi[1] + margin, hi[2] + margin];
    let mut tsdf = TsdfVolume::new(lo, hi, ts.voxel)
        .map_err(|e| PipelineError::Invalid(format!("TSDF: {e}")))?;
    let n_cams = cams.len() as u32;
    for (i, cam) in cams.iter().enumerate() {
        let out = render::<f32, _>(surfels, cam, settings)?;
        let depth: Vec<f32> = match opts.mesh_depth {
            MeshDepth::Expected => out
                .expected_depth()
                .iter()
                .zip(&out.alpha)
                .map(|(&d, &a)| if a > 0.5 { d } else { 0.0 })
                .collect(),
            MeshDepth::Median => out.median.clone(),
        };
        tsdf.integrate(cam, &depth, ts.trunc, ts.max_depth)
            .map_err(|e| PipelineError::Invalid(format!("TSDF: {e}")))?;
        progress("meshing", i as u32 + 1, n_cams);
    }
    let mut mesh = tsdf.extract_mesh();
    let (pts, labels) = labelled;
    if !mesh.vertices.is_empty() && !pts.is_empty() {
        label_by_nearest(&mut mesh, pts, labels)
            .map_err(|e| PipelineError::Invalid(format!("mesh labels: {e}")))?;
    }
    Ok(mesh)
}

/// The mesh as written to PLY: vertex colours from the palette of each vertex's object id (none
/// when the mesh is unlabelled).
pub fn coloured_by_object(mut mesh: Mesh) -> Mesh {
    mesh.colors = mesh.labels.as_ref().map(|l| {
        l.iter()
            .map(|&id| targets::palette(usize::from(id)).map(|c| (c * 255.0) as u8))
            .collect()
    });
    mesh
}

/// What [`simulate`] made besides the moved surfels.
#[derive(Clone, Debug)]
pub struct Simulation {
    /// The TSDF mesh, vertices labelled and coloured by object ([`coloured_by_object`]).
    pub mesh: Mesh,
    pub num_particles: usize,
    /// Frames simulated: `opts.mpm.frames`, or fewer when every particle came to rest before
    /// ([`trand_physics::StopAtRest`]); 0 without particles or without a movable object.
    pub frames: u32,
    /// The largest distance a surfel centre moved (metres).
    pub max_displacement_m: f32,
    pub meshing_s: f64,
    pub simulation_s: f64,
}

/// Steps 3–5: mesh, particles, MPM (up to `opts.mpm.frames` frames, ending early at rest as
/// `opts.mpm.stop_at_rest` says, none when no object is `movable`); moves `surfels` in place.
/// Stops with [`PipelineError::Interrupted`] after the meshing or the simulated frame during which
/// `cancel` was set.
#[allow(clippy::too_many_arguments)]
pub fn simulate(
    surfels: &mut Surfels,
    objects: &[(u16, usize)],
    movable: &[u16],
    scale: SceneScale,
    opts: &UpdateOptions,
    settings: &RenderSettings,
    progress: &mut dyn FnMut(&str, u32, u32),
    cancel: &AtomicBool,
) -> Result<Simulation> {
    let stop = || {
        if cancel.load(Ordering::SeqCst) {
            Err(PipelineError::Interrupted(0))
        } else {
            Ok(())
        }
    };
    let t0 = Instant::now();
    // Vertices are labelled by the nearest object surfel.
    let mut pts = Vec::new();
    let mut labels = Vec::new();
    let mut members: Vec<(u16, Vec<[f32; 3]>, Vec<u32>)> = Vec::new();
    for &(id, c) in objects {
        let idx = channel_members(surfels, c);
        let centres: Vec<[f32; 3]> = idx.iter().map(|&i| surfels.means[i as usize]).collect();
        pts.extend_from_slice(&centres);
        labels.extend(std::iter::repeat_n(id, centres.len()));
        members.push((id, centres, idx));
    }
    let mesh = fuse_mesh(
        surfels,
        scale.radius.max(0.05),
        (&pts, &labels),
        opts,
        settings,
        progress,
    )?;
    let meshing_s = t0.elapsed().as_secs_f64();
    stop()?;

    let t1 = Instant::now();
    let objs: Vec<ObjectSurfels> = members
        .iter()
        .map(|(id, c, idx)| ObjectSurfels {
            id: *id,
            centres: c,
            surfel_indices: idx,
        })
        .collect();
    let unlabelled = Mesh::default();
    let mesh_for_particles = if mesh.labels.is_some() {
        &mesh
    } else {
        &unlabelled
    };
    let set = build_particles(&objs, mesh_for_particles, opts.fill)
        .map_err(|e| PipelineError::Invalid(format!("particles: {e}")))?;
    let mut max_disp = 0.0f32;
    let mut frames = 0;
    // Objects that are not `movable` are put back where they were after the simulation, so with
    // none movable the simulation cannot change anything: it is skipped (0 frames).
    if !set.positions.is_empty() && !movable.is_empty() {
        let mut solver = MpmSolver::new(opts.mpm.clone(), &set.positions)
            .map_err(|e| PipelineError::Invalid(format!("MPM: {e}")))?;
        while frames < opts.mpm.frames && !solver.at_rest() {
            solver
                .step_frame()
                .map_err(|e| PipelineError::Invalid(format!("MPM: {e}")))?;
            frames += 1;
            progress("simulation", frames, opts.mpm.frames);
            stop()?;
        }
        let pos = solver.positions();
        let rots = match opts.motion {
            SurfelMotion::TranslateRotate => Some(solver.rotations()),
            _ => None,
        };
        let before: Vec<[f32; 3]> = surfels.means.clone();
        let before_quats = surfels.quats.clone();
        for (surfel, particle) in set.surfel_particles() {
            let s = surfel as usize;
            surfels.means[s] = pos[particle];
            if let Some(r) = &rots {
                surfels.quats[s] = turn(r[particle], surfels.quats[s]);
            }
        }
        for (id, _, idx) in &members {
            if !movable.contains(id) {
                // Nothing it touches has changed (crate::contact): it keeps its pose.
                for &i in idx {
                    surfels.means[i as usize] = before[i as usize];
                    surfels.quats[i as usize] = before_quats[i as usize];
                }
            } else if opts.motion == SurfelMotion::RigidPerObject {
                rigid_fit(surfels, &before, idx);
            }
        }
        for (b, a) in before.iter().zip(&surfels.means) {
            let d = ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt();
            max_disp = max_disp.max(d);
        }
    }
    let simulation_s = t1.elapsed().as_secs_f64();
    Ok(Simulation {
        mesh: coloured_by_object(mesh),
        num_particles: set.positions.len(),
        frames,
        max_displacement_m: max_disp,
        meshing_s,
        simulation_s,
    })
}

/// Moves the surfels `idx` (simulated positions in `surfels.means`, previous ones in `before`) by
/// the rigid motion that fits them best in the least-squares sense (Kabsch): `R` is the polar
/// rotation of `Σ (q − q̄)(p − p̄)ᵀ`, `t = q̄ − R p̄`; the surfels' orientations turn by `R` too.
/// An object the fit sank below the table is lifted back onto it: the paper's soft material sags
/// under gravity (by up to a third of an object's height), which lowers the fitted centroid.
fn rigid_fit(surfels: &mut Surfels, before: &[[f32; 3]], idx: &[u32]) {
    if idx.len() < 3 {
        return;
    }
    let v = |a: [f32; 3]| DVec3::new(a[0] as f64, a[1] as f64, a[2] as f64);
    let n = idx.len() as f64;
    let pbar = idx.iter().map(|&i| v(before[i as usize])).sum::<DVec3>() / n;
    let qbar = idx
        .iter()
        .map(|&i| v(surfels.means[i as usize]))
        .sum::<DVec3>()
        / n;
    let mut m = glam::DMat3::ZERO;
    for &i in idx {
        let (p, q) = (
            v(before[i as usize]) - pbar,
            v(surfels.means[i as usize]) - qbar,
        );
        m += glam::DMat3::from_cols(p * q.x, p * q.y, p * q.z).transpose();
    }
    let r = trand_physics::mpm::polar_rotation(m, glam::DQuat::IDENTITY);
    let rf = Quat::from_xyzw(r.x as f32, r.y as f32, r.z as f32, r.w as f32);
    for &i in idx {
        let i = i as usize;
        let p = r * (v(before[i]) - pbar) + qbar;
        surfels.means[i] = [p.x as f32, p.y as f32, p.z as f32];
        surfels.quats[i] = turn(rf, surfels.quats[i]);
    }
    let lowest = idx
        .iter()
        .map(|&i| surfels.means[i as usize][2])
        .fold(f32::INFINITY, f32::min);
    if lowest < 0.0 {
        for &i in idx {
            surfels.means[i as usize][2] -= lowest;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use trand_core::surfels::Surfel;

    fn column(n: u32) -> (Surfels, Vec<[f32; 3]>) {
        let mut s = Surfels::new(0, 2).unwrap();
        let before: Vec<[f32; 3]> = (0..n).map(|i| [0.0, 0.0, 0.002 * i as f32]).collect();
        for p in &before {
            s.push(&Surfel {
                mean: *p,
                log_scale: [-5.0; 2],
                quat: [1.0, 0.0, 0.0, 0.0],
                opacity_logit: 0.0,
                sh_dc: [0.0; 3],
                mask_dc: [0.0; 3],
                obj_logits: vec![],
            });
        }
        (s, before)
    }

    #[test]
    fn rigid_fit_lifts_an_object_the_fit_sank_below_the_table_back_onto_it() {
        let (mut s, before) = column(20);
        // Sagged: squashed to half its height and moved 1 cm sideways; the fit lowers the centroid.
        for (m, b) in s.means.iter_mut().zip(&before) {
            *m = [0.01, 0.0, 0.5 * b[2] - 0.01];
        }
        let idx: Vec<u32> = (0..20).collect();
        rigid_fit(&mut s, &before, &idx);
        let lowest = s.means.iter().map(|m| m[2]).fold(f32::INFINITY, f32::min);
        assert!(lowest.abs() < 1e-6, "lowest point at {lowest}");
        for (m, b) in s.means.iter().zip(&before) {
            assert!(
                (m[0] - 0.01).abs() < 1e-4 && (m[2] - b[2]).abs() < 1e-4,
                "{m:?} vs {b:?}"
            );
        }
    }

    #[test]
    fn rigid_fit_recovers_a_known_rotation_and_translation_from_noisy_positions() {
        let mut s = Surfels::new(0, 2).unwrap();
        let mut before = Vec::new();
        for i in 0..50 {
            let t = i as f32 * 0.37;
            let p = [0.05 * t.cos(), 0.04 * (1.3 * t).sin(), 0.002 * i as f32];
            before.push(p);
            s.push(&Surfel {
                mean: p,
                log_scale: [-5.0; 2],
                quat: [1.0, 0.0, 0.0, 0.0],
                opacity_logit: 0.0,
                sh_dc: [0.0; 3],
                mask_dc: [0.0; 3],
                obj_logits: vec![],
            });
        }
        let r = Quat::from_axis_angle(glam::Vec3::new(1.0, 0.5, 0.2).normalize(), 0.6);
        let t = glam::Vec3::new(0.02, -0.01, 0.05);
        // Simulated positions: the rigid motion plus a ±0.5 mm wobble (the soft material's sag).
        for (i, m) in s.means.iter_mut().enumerate() {
            let q = r * glam::Vec3::from_array(before[i]) + t;
            let wobble = 0.0005 * ((i as f32 * 1.7).sin());
            *m = [q.x + wobble, q.y - wobble, q.z + wobble];
        }
        let idx: Vec<u32> = (0..50).collect();
        rigid_fit(&mut s, &before, &idx);
        for (i, m) in s.means.iter().enumerate() {
            let q = r * glam::Vec3::from_array(before[i]) + t;
            let e = (glam::Vec3::from_array(*m) - q).length();
            assert!(e < 1.5e-3, "surfel {i}: {e} m from the rigid motion");
        }
        let q = s.quats[0];
        let got = Quat::from_xyzw(q[1], q[2], q[3], q[0]);
        assert!(
            got.angle_between(r) < 0.02,
            "orientation off by {} rad",
            got.angle_between(r)
        );
    }
}
