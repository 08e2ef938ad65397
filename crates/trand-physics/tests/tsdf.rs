//! TSDF fusion of analytic depth maps: a sphere seen from a ring of views (plus one from below),
//! a plane seen from above, and nothing at all.

use glam::{DVec3, Vec3};
use trand_core::{Camera, Intrinsics};
use trand_physics::{TsdfVolume, ring_views};

/// Camera-frame depth (z) of the first hit of each pixel's ray with `hit(origin, dir) -> t`.
fn render_depth(cam: &Camera, hit: impl Fn(DVec3, DVec3) -> Option<f64>) -> Vec<f32> {
    let k = cam.intrinsics;
    let (o, fwd) = (cam.center(), cam.forward());
    let mut depth = vec![0.0f32; k.num_pixels()];
    for j in 0..k.height {
        for i in 0..k.width {
            let d = cam.ray_direction(i as f64, j as f64);
            if let Some(t) = hit(o, d) {
                depth[(j * k.width + i) as usize] = (t * d.dot(fwd)) as f32;
            }
        }
    }
    depth
}

fn sphere_hit(c: DVec3, r: f64) -> impl Fn(DVec3, DVec3) -> Option<f64> {
    move |o, d| {
        let oc = o - c;
        let b = oc.dot(d);
        let disc = b * b - (oc.length_squared() - r * r);
        (disc >= 0.0).then(|| -b - disc.sqrt()).filter(|t| *t > 0.0)
    }
}

#[test]
fn fused_sphere_mesh_lies_on_the_sphere() {
    let (c, r, voxel) = (DVec3::new(0.0, 0.0, 0.1), 0.08, 0.005f32);
    let k = Intrinsics::centered(150.0, 120, 120);
    let cams = ring_views(c, 0.5, &[-0.5, 0.3, 1.0], 8, k);
    let mut vol = TsdfVolume::new([-0.15, -0.15, -0.05], [0.15, 0.15, 0.25], voxel).unwrap();
    for cam in &cams {
        vol.integrate(cam, &render_depth(cam, sphere_hit(c, r)), 5.0 * voxel, 1.0)
            .unwrap();
    }
    let mesh = vol.extract_mesh();
    assert!(
        mesh.vertices.len() > 2000,
        "only {} vertices",
        mesh.vertices.len()
    );
    assert_eq!(
        mesh.triangle_components().1.len(),
        1,
        "the sphere is one piece"
    );
    let cf = c.as_vec3();
    let mut worst = 0.0f32;
    for (v, n) in mesh.vertices.iter().zip(&mesh.normals) {
        let p = Vec3::from_array(*v) - cf;
        worst = worst.max((p.length() - r as f32).abs());
        assert!(
            Vec3::from_array(*n).dot(p.normalize()) > 0.8,
            "normal {n:?} at {v:?} does not point out"
        );
    }
    assert!(
        worst < voxel,
        "a vertex is {worst} m off the sphere (voxel {voxel})"
    );
    // Faces are counter-clockwise seen from outside.
    let outward = mesh
        .faces
        .iter()
        .filter(|f| {
            let [a, b, cc] = f.map(|i| Vec3::from_array(mesh.vertices[i as usize]));
            (b - a).cross(cc - a).dot(a - cf) > 0.0
        })
        .count();
    assert!(
        outward as f64 > 0.99 * mesh.faces.len() as f64,
        "{outward} of {} faces wound outward",
        mesh.faces.len()
    );
}

#[test]
fn fused_plane_mesh_is_flat() {
    let voxel = 0.004f32;
    let k = Intrinsics::centered(200.0, 100, 100);
    let cams = ring_views(DVec3::ZERO, 0.4, &[0.9, 1.3], 6, k);
    let plane = |o: DVec3, d: DVec3| (d.z.abs() > 1e-9).then(|| -o.z / d.z).filter(|t| *t > 0.0);
    let mut vol = TsdfVolume::new([-0.08, -0.08, -0.04], [0.08, 0.08, 0.04], voxel).unwrap();
    for cam in cams.iter().filter(|c| c.center().z > 0.0) {
        vol.integrate(cam, &render_depth(cam, plane), 5.0 * voxel, 2.0)
            .unwrap();
    }
    let mesh = vol.extract_mesh();
    assert!(mesh.faces.len() > 1000, "{} faces", mesh.faces.len());
    let worst = mesh
        .vertices
        .iter()
        .map(|v| v[2].abs())
        .fold(0.0f32, f32::max);
    assert!(worst < 0.5 * voxel, "a vertex is {worst} m off the plane");
    assert!(mesh.normals.iter().all(|n| n[2] > 0.95), "normals point up");
}

#[test]
fn empty_depth_gives_an_empty_mesh() {
    let k = Intrinsics::centered(100.0, 64, 48);
    let cams = ring_views(DVec3::ZERO, 0.5, &[0.5], 4, k);
    let mut vol = TsdfVolume::new([-0.1; 3], [0.1; 3], 0.01).unwrap();
    for cam in &cams {
        vol.integrate(cam, &vec![0.0; k.num_pixels()], 0.05, 1.0)
            .unwrap();
    }
    let mesh = vol.extract_mesh();
    assert!(mesh.is_empty() && mesh.vertices.is_empty());
    assert!(vol.weights().iter().all(|w| *w == 0.0));
}

#[test]
fn integrate_rejects_a_depth_map_of_the_wrong_size() {
    let k = Intrinsics::centered(100.0, 64, 48);
    let cam = ring_views(DVec3::ZERO, 0.5, &[0.5], 1, k)[0];
    let mut vol = TsdfVolume::new([-0.1; 3], [0.1; 3], 0.01).unwrap();
    assert!(vol.integrate(&cam, &[0.0; 10], 0.05, 1.0).is_err());
    assert!(TsdfVolume::new([0.0; 3], [0.0; 3], 0.01).is_err());
}

#[test]
fn fusion_is_identical_for_one_and_many_threads_and_ignores_invalid_depth() {
    let (c, r) = (DVec3::new(0.0, 0.0, 0.05), 0.04);
    let k = Intrinsics::centered(120.0, 80, 80);
    let cams = ring_views(c, 0.4, &[0.5], 5, k);
    let fuse = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| {
                let mut vol =
                    TsdfVolume::new([-0.06, -0.06, -0.01], [0.06, 0.06, 0.11], 0.004).unwrap();
                for cam in &cams {
                    let mut depth = render_depth(cam, sphere_hit(c, r));
                    // Garbage pixels (NaN, negative, infinite) count as "no depth".
                    depth[0] = f32::NAN;
                    depth[1] = -1.0;
                    depth[2] = f32::INFINITY;
                    vol.integrate(cam, &depth, 0.02, 1.0).unwrap();
                }
                vol
            })
    };
    let (one, many) = (fuse(1), fuse(3));
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(one.tsdf()), bits(many.tsdf()));
    assert_eq!(bits(one.weights()), bits(many.weights()));
    assert!(one.tsdf().iter().all(|v| v.is_finite()));
    assert_eq!(one.extract_mesh(), many.extract_mesh());
}
