//! Tables painted and seen from six views, for the tests of the sweep and of the frame's move.

use super::*;
use trand_core::Intrinsics;

/// Value noise on an 8 mm grid (bilinear between hashed corners): a texture with no period.
pub(crate) fn speckle(x: f64, y: f64) -> f32 {
    let corner = |i: i64, j: i64| {
        let mut k = (i.wrapping_mul(73_856_093) ^ j.wrapping_mul(19_349_663)) as u64;
        k ^= k >> 13;
        k = k.wrapping_mul(0x5bd1_e995);
        k ^= k >> 15;
        (k % 1000) as f64 / 1000.0
    };
    let (u, v) = (x / 0.008, y / 0.008);
    let (i, j) = (u.floor() as i64, v.floor() as i64);
    let (fu, fv) = (u - u.floor(), v - v.floor());
    let top = corner(i, j) * (1.0 - fu) + corner(i + 1, j) * fu;
    let bottom = corner(i, j + 1) * (1.0 - fu) + corner(i + 1, j + 1) * fu;
    (0.2 + 0.6 * (top * (1.0 - fv) + bottom * fv)) as f32
}

/// Six views around a table at `height` painted with `paint`, and a 3 cm object standing on it.
pub(crate) fn views_of_table(height: f64, paint: fn(f64, f64) -> f32) -> Vec<TrainView> {
    let (w, h) = (320, 240);
    (0..6)
        .map(|k| {
            let a = k as f64 * std::f64::consts::TAU / 6.0;
            let eye = DVec3::new(0.6 * a.cos(), 0.6 * a.sin(), 0.45);
            let camera = Camera::look_at(
                Intrinsics::centered(400.0, w as u32, h as u32),
                eye,
                DVec3::ZERO,
                DVec3::Z,
            );
            let mut grey = vec![0.3; w * h];
            let mut ids = vec![0u16; w * h];
            for y in 0..h {
                for x in 0..w {
                    let d = camera.ray_direction(x as f64, y as f64);
                    let p = eye + (height - eye.z) / d.z * d;
                    if d.z < 0.0 {
                        grey[y * w + x] = paint(p.x, p.y);
                        ids[y * w + x] = u16::from(p.truncate().length() < 0.03);
                    }
                }
            }
            let mut v = TrainView::from_ids(format!("{k}"), camera, (w, h), ids);
            v.grey = grey;
            v
        })
        .collect()
}

/// Soft shadows a few centimetres wide on an otherwise even table: a plain table's shading.
pub(crate) fn soft_shadows(x: f64, y: f64) -> f32 {
    let blob =
        |cx: f64, cy: f64, s: f64| (-((x - cx).powi(2) + (y - cy).powi(2)) / (2.0 * s * s)).exp();
    (0.7 - 0.25 * blob(0.05, 0.02, 0.03)
        - 0.2 * blob(-0.06, 0.05, 0.04)
        - 0.15 * blob(0.0, -0.07, 0.05)
        + 0.1 * x) as f32
}
