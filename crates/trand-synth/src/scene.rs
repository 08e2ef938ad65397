//! What the ray tracer sees: posed object meshes in one BVH, the table, the light and the
//! background.
//!
//! The table is the analytic square `|x|, |y| ≤ half_size`, `z = 0` (exact depth, no
//! tessellation). Objects are instanced into world space once per state (t = 0, t = 1) and every
//! triangle remembers its object and its three vertex normals for smooth shading. The single area
//! light is a downward-facing square; the background is radiance only (it has no depth).

use crate::bvh::{Bvh, Tri};
use crate::material::{Material, Texture};
use glam::{Quat, Vec3};
use serde::Serialize;
use trand_core::Mesh;

/// The square table top at `z = 0`.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Table {
    pub half_size_m: f32,
    pub texture: Texture,
}

/// Radiance of rays that leave the scene.
#[derive(Clone, Copy, Debug, Serialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum Background {
    /// A vertical gradient from `horizon` to `zenith`.
    Sky { horizon: [f32; 3], zenith: [f32; 3] },
    /// A uniformly lit wall colour all around.
    Wall { color: [f32; 3] },
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lambert_polygon_irradiance_matches_numerical_integration() {
        let light = AreaLight {
            centre_m: [0.1, -0.2, 1.0],
            half_size_m: 0.3,
            radiance: 2.0,
        };
        for (p, n) in [
            (Vec3::ZERO, Vec3::Z),
            (
                Vec3::new(0.3, 0.1, 0.05),
                Vec3::new(0.3, 0.0, 1.0).normalize(),
            ),
        ] {
            // Midpoint rule over the light: E = ∫ L cosθ_s cosθ_l / r² dA.
            let k = 400;
            let mut e = 0.0f64;
            for i in 0..k {
                for j in 0..k {
                    let q = light.point((i as f32 + 0.5) / k as f32, (j as f32 + 0.5) / k as f32);
                    let w = q - p;
                    let r2 = w.length_squared() as f64;
                    let w = w.normalize();
                    e += (light.radiance as f64) * (n.dot(w) as f64).max(0.0) * (w.z as f64) / r2;
                }
            }
            e *= light.area() as f64 / (k * k) as f64;
            let got = light.irradiance(p, n) as f64;
            assert!((got - e).abs() / e < 1e-3, "{got} vs {e}");
        }
    }
}

impl Background {
    pub fn radiance(&self, d: Vec3) -> Vec3 {
        match *self {
            Background::Sky { horizon, zenith } => {
                Vec3::from(horizon).lerp(zenith.into(), d.z.clamp(0.0, 1.0).sqrt())
            }
            Background::Wall { color } => color.into(),
        }
    }
}

/// A square emitter facing straight down (−z), radiance `radiance` in all its directions.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct AreaLight {
    pub centre_m: [f32; 3],
    pub half_size_m: f32,
    pub radiance: f32,
}

impl AreaLight {
    pub fn area(&self) -> f32 {
        4.0 * self.half_size_m * self.half_size_m
    }

    /// Point on the light for the unit-square sample `(a, b)`.
    pub fn point(&self, a: f32, b: f32) -> Vec3 {
        Vec3::from(self.centre_m) + self.half_size_m * Vec3::new(2.0 * a - 1.0, 2.0 * b - 1.0, 0.0)
    }

    /// Corners, counter-clockwise seen from above (the order Lambert's formula below expects).
    pub fn corners(&self) -> [Vec3; 4] {
        [
            self.point(0.0, 0.0),
            self.point(1.0, 0.0),
            self.point(1.0, 1.0),
            self.point(0.0, 1.0),
        ]
    }

    /// Unoccluded irradiance at `p` with normal `n` from the whole light, by Lambert's formula
    /// for a polygonal luminaire of uniform radiance `L`:
    /// `E = (L/2) Σᵢ Θᵢ (n · Γᵢ)`, with `uᵢ` the unit directions from `p` to the corners,
    /// `Θᵢ = acos(uᵢ · uᵢ₊₁)` and `Γᵢ = normalize(uᵢ × uᵢ₊₁)`. Exact while the light is above the
    /// surface's horizon (always for the table); clamped at 0 otherwise.
    pub fn irradiance(&self, p: Vec3, n: Vec3) -> f32 {
        let u = self.corners().map(|c| (c - p).normalize());
        let mut sum = 0.0;
        for i in 0..4 {
            let (a, b) = (u[i], u[(i + 1) % 4]);
            let theta = a.dot(b).clamp(-1.0, 1.0).acos();
            sum += theta * n.dot(a.cross(b).normalize_or_zero());
        }
        (0.5 * self.radiance * sum).max(0.0)
    }

    /// Distance at which the ray meets the emitting (lower) face, if it does.
    pub fn hit(&self, o: Vec3, d: Vec3) -> Option<f32> {
        let c = Vec3::from(self.centre_m);
        if d.z <= 0.0 {
            return None;
        }
        let t = (c.z - o.z) / d.z;
        let p = o + t * d;
        (t > 0.0 && (p.x - c.x).abs() <= self.half_size_m && (p.y - c.y).abs() <= self.half_size_m)
            .then_some(t)
    }
}

/// Lighting and surroundings shared by both states.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Environment {
    pub table: Table,
    pub background: Background,
    pub light: AreaLight,
    /// Uniform ambient irradiance factor applied to diffuse surfaces (stands in for the
    /// inter-reflections a one-bounce tracer omits).
    pub ambient: f32,
}

/// One object placed in the world for rendering.
pub struct Placed<'a> {
    pub obj_id: u32,
    pub mesh: &'a Mesh,
    pub material: Material,
    pub rotation: Quat,
    pub translation: Vec3,
}

/// Per-triangle shading data, parallel to the BVH's triangle list.
#[derive(Clone, Copy, Debug)]
pub struct TriShading {
    /// Index into [`RenderScene::objects`].
    pub object: u32,
    pub normals: [Vec3; 3],
}

/// An object as the renderer knows it.
#[derive(Clone, Copy, Debug)]
pub struct RenderObject {
    pub obj_id: u32,
    pub material: Material,
}

/// Everything needed to render one state.
pub struct RenderScene {
    pub bvh: Bvh,
    pub shading: Vec<TriShading>,
    pub objects: Vec<RenderObject>,
    pub env: Environment,
}

impl RenderScene {
    pub fn new(placed: &[Placed<'_>], env: Environment) -> Self {
        let mut tris = Vec::new();
        let mut shading = Vec::new();
        let mut objects = Vec::new();
        for (k, p) in placed.iter().enumerate() {
            let world = |v: Vec3| p.rotation * v + p.translation;
            for t in &p.mesh.faces {
                let [a, b, c] = t.map(|i| world(Vec3::from(p.mesh.vertices[i as usize])));
                tris.push(Tri::new(a, b, c));
                shading.push(TriShading {
                    object: k as u32,
                    normals: t.map(|i| p.rotation * Vec3::from(p.mesh.normals[i as usize])),
                });
            }
            objects.push(RenderObject {
                obj_id: p.obj_id,
                material: p.material,
            });
        }
        Self {
            bvh: Bvh::build(tris),
            shading,
            objects,
            env,
        }
    }
}
