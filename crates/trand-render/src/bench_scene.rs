//! A tabletop benchmark scene: surfels spread over the surfaces of glass-sized cylinders on a table,
//! seen from 0.5 m, as after TRAN-D's t=0 optimisation (object surfels only). Used by the benchmarks
//! and by `trand bench-render`.

use trand_core::{Camera, Intrinsics, Surfels, math::logit, sh::rgb_to_dc, surfels::Surfel};

/// Deterministic xorshift generator (no dependency needed for a benchmark scene).
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> f32 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 40) as f32 / (1u64 << 24) as f32
    }
}

/// `n` surfels on four cylinders (radius 3–4 cm, height 8–14 cm) around the origin, tangent to the
/// surface, scale from the mean spacing, opacity 0.5–0.95, 15 object channels.
pub fn tabletop_scene(n: usize, seed: u64) -> Surfels {
    let cyl = [
        (-0.06f32, -0.04f32, 0.03f32, 0.10f32),
        (0.05, -0.05, 0.035, 0.08),
        (0.0, 0.06, 0.04, 0.14),
        (0.09, 0.05, 0.03, 0.09),
    ];
    let area: f32 = cyl
        .iter()
        .map(|c| 2.0 * std::f32::consts::PI * c.2 * c.3)
        .sum();
    let spacing = (area / n as f32).sqrt();
    let mut rng = Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1);
    let mut s = Surfels::new(0, 15).expect("valid");
    for i in 0..n {
        let (cx, cy, r, h) = cyl[i % 4];
        let th = rng.next() * std::f32::consts::TAU;
        let z = rng.next() * h;
        let mean = [cx + r * th.cos(), cy + r * th.sin(), z];
        // Tangent frame: normal radial, so the disk lies on the cylinder.
        let q =
            glam::Quat::from_rotation_arc(glam::Vec3::Z, glam::Vec3::new(th.cos(), th.sin(), 0.0));
        let mut obj = vec![-2.0f32; 15];
        obj[1 + i % 4] = 3.0;
        s.push(&Surfel {
            mean,
            log_scale: [
                (spacing * (0.8 + 0.4 * rng.next())).ln(),
                (spacing * (0.8 + 0.4 * rng.next())).ln(),
            ],
            quat: [q.w, q.x, q.y, q.z],
            opacity_logit: logit(0.5 + 0.45 * rng.next()),
            sh_dc: [
                rgb_to_dc(0.3 + 0.6 * rng.next()),
                rgb_to_dc(0.5),
                rgb_to_dc(0.7),
            ],
            mask_dc: [rgb_to_dc(0.8), rgb_to_dc(0.2), rgb_to_dc(0.1)],
            obj_logits: obj,
        });
    }
    s
}

/// 640×480 camera (f = 600) 0.5 m from the scene centre, 38° elevation.
pub fn tabletop_camera() -> Camera {
    let el = 38f64.to_radians();
    let eye = glam::DVec3::new(
        0.5 * el.cos() * 0.6,
        -0.5 * el.cos() * 0.8,
        0.5 * el.sin() + 0.05,
    );
    Camera::look_at(
        Intrinsics::centered(600.0, 640, 480),
        eye,
        glam::DVec3::new(0.0, 0.0, 0.05),
        glam::DVec3::Z,
    )
}
