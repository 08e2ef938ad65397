//! Analytic checks of the ray tracer: exact depth of the table and of a sphere, refraction through
//! a glass slab, total internal reflection. Run with `cargo test --release -p trand-synth`.

use glam::{DVec3, Quat, Vec2, Vec3};
use trand_core::camera::Camera;
use trand_synth::cameras::intrinsics;
use trand_synth::material::{Material, Texture};
use trand_synth::scene::{AreaLight, Background, Environment, Placed, RenderScene, Table};
use trand_synth::shapes::lathe;
use trand_synth::trace::{RenderSettings, ViewImages, render_view};

fn env() -> Environment {
    Environment {
        table: Table {
            half_size_m: 0.5,
            texture: Texture::Checker {
                a: [0.8; 3],
                b: [0.2; 3],
                size: 0.03,
            },
        },
        background: Background::Wall { color: [0.5; 3] },
        light: AreaLight {
            centre_m: [0.0, 0.0, 1.0],
            half_size_m: 0.3,
            radiance: 7.0,
        },
        ambient: 0.2,
    }
}

/// One sample per pixel: the depth is exact, the colour noise does not matter here.
fn render_one_sample(scene: &RenderScene, cam: &Camera, seed: u64) -> ViewImages {
    render_view(
        scene,
        cam,
        RenderSettings {
            samples_per_pixel: 1,
        },
        seed,
        &|| {},
    )
}

/// Analytic planar depth (mm) of the plane z = 0 along the ray through pixel `(x, y)`.
fn table_depth_mm(cam: &Camera, x: u32, y: u32) -> Option<f64> {
    let (c, d) = (cam.center(), cam.ray_direction(x as f64, y as f64));
    let t = -c.z / d.z;
    let p = c + t * d;
    (t > 0.0 && p.x.abs() <= 0.5 && p.y.abs() <= 0.5).then(|| 1000.0 * t * d.dot(cam.forward()))
}

#[test]
fn table_depth_is_the_analytic_planar_depth_at_every_pixel_centre() {
    let scene = RenderScene::new(&[], env());
    let cam = Camera::look_at(
        intrinsics(160, 120),
        DVec3::new(0.31, -0.22, 0.37),
        DVec3::new(0.0, 0.02, 0.0),
        DVec3::Z,
    );
    let img = render_one_sample(&scene, &cam, 1);
    let mut checked = 0;
    for y in 0..120 {
        for x in 0..160 {
            let got = img.depth_mm[(y * 160 + x) as usize];
            match table_depth_mm(&cam, x, y) {
                Some(want) => {
                    assert!(
                        (got as f64 - want).abs() <= 0.5 + 1e-3,
                        "pixel ({x}, {y}): {got} vs {want:.4}"
                    );
                    checked += 1;
                }
                None => assert_eq!(got, 0, "pixel ({x}, {y}) sees no table"),
            }
            assert_eq!(img.ids[(y * 160 + x) as usize], 0);
        }
    }
    assert!(checked > 10_000);
}

#[test]
fn sphere_depth_matches_the_ray_sphere_intersection() {
    // A finely tessellated sphere of radius 3 cm standing on the table.
    let r = 0.03f32;
    let mut profile = vec![Vec2::new(0.0, -r)];
    let steps = 96;
    for i in 1..=steps {
        let a = -std::f32::consts::FRAC_PI_2 + std::f32::consts::PI * i as f32 / steps as f32;
        profile.push(r * Vec2::new(a.cos(), a.sin()));
    }
    let mesh = lathe(&profile, 192);
    let centre = Vec3::new(0.01, -0.02, r);
    let placed = [Placed {
        obj_id: 7,
        mesh: &mesh,
        material: Material::Glazed {
            color: [0.7, 0.2, 0.2],
        },
        rotation: Quat::IDENTITY,
        translation: centre,
    }];
    let scene = RenderScene::new(&placed, env());
    let cam = Camera::look_at(
        intrinsics(160, 120),
        DVec3::new(0.2, 0.15, 0.25),
        centre.as_dvec3(),
        DVec3::Z,
    );
    let img = render_one_sample(&scene, &cam, 2);
    let (c, s) = (cam.center(), centre.as_dvec3());
    let mut checked = 0;
    for y in 0..120u32 {
        for x in 0..160u32 {
            let d = cam.ray_direction(x as f64, y as f64);
            // |c + t d − s|² = r²  →  t = −b − √(b² − q), b = d·(c − s), q = |c − s|² − r².
            let oc = c - s;
            let b = d.dot(oc);
            let disc = b * b - (oc.length_squared() - (r as f64).powi(2));
            let i = (y * 160 + x) as usize;
            if disc <= 0.0 {
                continue;
            }
            let t = -b - disc.sqrt();
            let normal = (c + t * d - s).normalize();
            if -normal.dot(d) < 0.3 {
                continue; // grazing: the polygonal silhouette is inside the true one
            }
            let want = 1000.0 * t * d.dot(cam.forward());
            assert_eq!(img.ids[i], 7, "pixel ({x}, {y}) hits the sphere");
            // The inscribed mesh deviates from the sphere by at most r(1 − cos(π/96)) ≈ 0.016 mm.
            assert!(
                (img.depth_mm[i] as f64 - want).abs() <= 0.5 + 0.05,
                "pixel ({x}, {y}): {} vs {want:.3}",
                img.depth_mm[i]
            );
            checked += 1;
        }
    }
    assert!(checked > 500, "{checked}");
}

/// A 1 cm thick glass disc of radius 20 cm, top face at z = 0.06.
fn slab_scene(ior: f32) -> (RenderScene, f32, f32) {
    let (thick, top) = (0.01f32, 0.06f32);
    let profile = [
        Vec2::new(0.0, 0.0),
        Vec2::new(0.2, 0.0),
        Vec2::new(0.2, thick),
        Vec2::new(0.0, thick),
    ];
    let mesh = lathe(&profile, 256);
    let placed = [Placed {
        obj_id: 1,
        mesh: &mesh,
        material: Material::Glass {
            ior,
            tint: [1.0; 3],
        },
        rotation: Quat::IDENTITY,
        translation: Vec3::new(0.0, 0.0, top - thick),
    }];
    (RenderScene::new(&placed, env()), thick, top)
}

#[test]
fn glass_slab_shifts_a_ray_sideways_by_the_analytic_amount_and_keeps_its_direction() {
    let ior = 1.5f32;
    let (scene, thick, top) = slab_scene(ior);
    for theta_deg in [10.0f32, 30.0, 55.0] {
        let th = theta_deg.to_radians();
        let d = Vec3::new(th.sin(), 0.0, -th.cos());
        let o = Vec3::new(0.0, 0.013, top) - 0.05 * d;
        let path = scene.refraction_path(o, d, 8);
        // in air → in glass → out (ends on the table)
        assert_eq!(path.len(), 3, "{path:?}");
        let out = path[2];
        assert!(
            (out.direction - d).length() < 1e-5,
            "exit direction {:?} vs {d:?}",
            out.direction
        );
        // Lateral shift s = h sin(θ₁ − θ₂) / cos θ₂ with sin θ₂ = sin θ₁ / n.
        let th2 = (th.sin() / ior).asin();
        let want = thick * (th - th2).sin() / th2.cos();
        let got = (out.origin - o).cross(d).length();
        assert!(
            (got - want).abs() < 2e-6,
            "θ = {theta_deg}°: shift {got} vs {want}"
        );
    }
}

#[test]
fn light_past_the_critical_angle_is_totally_internally_reflected_inside_the_slab() {
    let ior = 1.5f32;
    let (scene, thick, top) = slab_scene(ior);
    let critical = (1.0 / ior).asin();
    for (angle, trapped) in [(critical - 0.05, false), (critical + 0.05, true)] {
        // Start inside the glass, heading up towards the top face at `angle` from the normal.
        let o = Vec3::new(0.0, 0.0, top - 0.5 * thick);
        let d = Vec3::new(angle.sin(), 0.0, angle.cos());
        let path = scene.refraction_path(o, d, 6);
        assert_eq!(
            path[0].total_internal_reflection,
            trapped,
            "angle {:.2}° vs critical {:.2}°",
            angle.to_degrees(),
            critical.to_degrees()
        );
        if trapped {
            // Bounces between the faces stay inside the slab with the mirrored direction.
            assert!(
                path.iter().take(4).all(|s| s.total_internal_reflection),
                "{path:?}"
            );
            assert!((path[1].direction.z + d.z).abs() < 1e-5);
        }
    }
}
