//! Small hand-built scenes for the unit tests of the update stages.

use glam::{DVec3, Quat, Vec3};
use trand_core::surfels::Surfel;
use trand_core::{Camera, Intrinsics, Surfels};

pub const RADIUS: f32 = 0.03;
pub const HEIGHT: f32 = 0.10;
/// Object channels of the test scenes.
pub const CHANNELS: usize = 2;

/// An open glass cylinder of surfels (radius [`RADIUS`], height [`HEIGHT`]) standing on the table at
/// `(x, y)`, every surfel confidently in object channel `channel`.
pub fn cylinder(x: f32, y: f32, channel: usize) -> Surfels {
    let mut s = Surfels::new(0, CHANNELS).unwrap();
    let mut logits = vec![0.0; CHANNELS];
    logits[channel] = 4.0;
    for i in 0..48 {
        let a = i as f32 * std::f32::consts::TAU / 48.0;
        let n = Vec3::new(a.cos(), a.sin(), 0.0);
        let q = Quat::from_rotation_arc(Vec3::Z, n);
        for j in 0..25 {
            s.push(&Surfel {
                mean: [
                    x + RADIUS * n.x,
                    y + RADIUS * n.y,
                    (j as f32 + 0.5) * HEIGHT / 25.0,
                ],
                log_scale: [(0.003f32).ln(); 2],
                quat: [q.w, q.x, q.y, q.z],
                opacity_logit: 4.0,
                sh_dc: [0.5; 3],
                mask_dc: [0.5; 3],
                obj_logits: logits.clone(),
            });
        }
    }
    s
}

/// A 200×150 camera looking down at the table from 0.57 m.
pub fn camera() -> Camera {
    Camera::look_at(
        Intrinsics::centered(180.0, 200, 150),
        DVec3::new(0.0, -0.35, 0.45),
        DVec3::new(0.04, 0.02, 0.0),
        DVec3::Z,
    )
}

/// A closed box of surfels standing on the table over `[x0, x1] × [y0, y1]`, `height` tall (4 mm
/// spacing on its top and sides), every surfel confidently in object channel `channel`.
pub fn block(x0: f32, y0: f32, x1: f32, y1: f32, height: f32, channel: usize) -> Surfels {
    let mut s = Surfels::new(0, CHANNELS).unwrap();
    let mut logits = vec![0.0; CHANNELS];
    logits[channel] = 4.0;
    let step = 0.004;
    let n = |a: f32, b: f32| ((b - a) / step).round().max(1.0) as usize;
    let mut push = |p: Vec3, normal: Vec3| {
        let q = Quat::from_rotation_arc(Vec3::Z, normal);
        s.push(&Surfel {
            mean: p.to_array(),
            log_scale: [(0.003f32).ln(); 2],
            quat: [q.w, q.x, q.y, q.z],
            opacity_logit: 4.0,
            sh_dc: [0.2, 0.6, 0.2],
            mask_dc: [0.5; 3],
            obj_logits: logits.clone(),
        });
    };
    let lerp = |a: f32, b: f32, i: usize, k: usize| a + (b - a) * i as f32 / k as f32;
    let (nx, ny, nz) = (n(x0, x1), n(y0, y1), n(0.0, height));
    for i in 0..=nx {
        for j in 0..=ny {
            push(
                Vec3::new(lerp(x0, x1, i, nx), lerp(y0, y1, j, ny), height),
                Vec3::Z,
            );
        }
    }
    for k in 0..nz {
        let z = lerp(0.0, height, k, nz);
        for i in 0..=nx {
            let x = lerp(x0, x1, i, nx);
            push(Vec3::new(x, y0, z), -Vec3::Y);
            push(Vec3::new(x, y1, z), Vec3::Y);
        }
        for j in 0..=ny {
            let y = lerp(y0, y1, j, ny);
            push(Vec3::new(x0, y, z), -Vec3::X);
            push(Vec3::new(x1, y, z), Vec3::X);
        }
    }
    s
}
