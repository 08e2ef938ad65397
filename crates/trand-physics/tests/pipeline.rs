//! The scene-update chain on an analytic object: depth maps of a ball from the virtual views →
//! TSDF mesh → vertices labelled by the nearest "surfel" → particles with interior fill → MPM.

use glam::{DVec3, Vec3};
use trand_core::Intrinsics;
use trand_physics::{
    InteriorFill, MpmConfig, MpmSolver, ObjectSurfels, ParticleSource, TsdfVolume, build_particles,
    label_by_nearest, ring_views,
};

#[test]
fn ball_from_depth_maps_becomes_filled_particles_that_rest_on_the_floor() {
    let (c, r) = (DVec3::new(0.3, 0.2, 0.0501), 0.05);
    let voxel = 0.004f32;
    let k = Intrinsics::centered(160.0, 100, 100);
    let mut vol = TsdfVolume::new([0.2, 0.1, -0.02], [0.4, 0.3, 0.12], voxel).unwrap();
    for cam in ring_views(c, 0.5, &[-0.4, 0.4, 1.1], 8, k) {
        let (o, fwd) = (cam.center(), cam.forward());
        let mut depth = vec![0.0f32; k.num_pixels()];
        for j in 0..k.height {
            for i in 0..k.width {
                let d = cam.ray_direction(i as f64, j as f64);
                let oc = o - c;
                let (b, q) = (oc.dot(d), oc.length_squared() - r * r);
                if b * b - q >= 0.0 {
                    depth[(j * k.width + i) as usize] =
                        ((-b - (b * b - q).sqrt()) * d.dot(fwd)) as f32;
                }
            }
        }
        vol.integrate(&cam, &depth, 5.0 * voxel, 1.0).unwrap();
    }
    let mut mesh = vol.extract_mesh();
    // "Surfels": points on the ball's surface, object id 4.
    let surfels: Vec<[f32; 3]> = (0..200)
        .map(|i| {
            let (t, p) = (
                i as f64 * 2.399963,
                (1.0 - 2.0 * (i as f64 + 0.5) / 200.0).acos(),
            );
            (c + r * DVec3::new(p.sin() * t.cos(), p.sin() * t.sin(), p.cos()))
                .as_vec3()
                .to_array()
        })
        .collect();
    let indices: Vec<u32> = (1000..1200).collect();
    label_by_nearest(&mut mesh, &surfels, &vec![4; surfels.len()]).unwrap();
    let spacing = 1.0 / 96.0;
    let objects = [ObjectSurfels {
        id: 4,
        centres: &surfels,
        surfel_indices: &indices,
    }];
    let set = build_particles(&objects, &mesh, InteriorFill::RayParity { spacing }).unwrap();
    let interior: Vec<[f32; 3]> = set
        .positions
        .iter()
        .zip(&set.sources)
        .filter(|(_, s)| matches!(s, ParticleSource::Interior { .. }))
        .map(|(p, _)| *p)
        .collect();
    let expected = 4.0 / 3.0 * std::f64::consts::PI * r.powi(3) / (spacing as f64).powi(3);
    assert!(
        (interior.len() as f64 - expected).abs() < 0.15 * expected,
        "{} interior points, ~{expected:.0} expected",
        interior.len()
    );
    assert!(
        interior
            .iter()
            .all(|p| (Vec3::from_array(*p) - c.as_vec3()).length() < r as f32 + voxel)
    );
    assert_eq!(set.len(), 200 + mesh.vertices.len() + interior.len());

    let mut mpm = MpmSolver::new(MpmConfig::default(), &set.positions).unwrap();
    mpm.run(25, |_, _| {}).unwrap();
    let out = mpm.positions();
    let zmin = out.iter().map(|p| p[2]).fold(f32::MAX, f32::min);
    assert!(zmin > -0.03, "sank through the floor: {zmin}");
    // Surfels follow their particles.
    for (surfel, i) in set.surfel_particles() {
        assert!((1000..1200).contains(&surfel) && out[i][2].is_finite());
    }
}
