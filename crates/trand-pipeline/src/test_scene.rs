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
