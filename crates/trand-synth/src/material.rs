//! Materials, table textures and the optics of a smooth dielectric interface.
//!
//! * Snell's law `n₁ sin θ₁ = n₂ sin θ₂`, in vector form for a unit incident direction `d` and a
//!   unit normal `n` facing the incident side (`cos θ₁ = −d·n`, `η = n₁/n₂`):
//!   `t = η d + (η cos θ₁ − cos θ₂) n`, with `cos θ₂ = √(1 − η²(1 − cos² θ₁))`.
//!   When the radicand is negative the light is totally internally reflected.
//! * Fresnel reflectance of unpolarised light (exact dielectric form):
//!   `R = ½(R_s + R_p)`, `R_s = ((n₁cosθ₁ − n₂cosθ₂)/(n₁cosθ₁ + n₂cosθ₂))²`,
//!   `R_p = ((n₁cosθ₂ − n₂cosθ₁)/(n₁cosθ₂ + n₂cosθ₁))²`.
//! * Absorption inside glass follows Beer–Lambert: transmittance `T(ℓ) = tint^(ℓ / 1 cm)`, where
//!   `tint` is the per-channel transmittance through one centimetre of glass.

use glam::{Vec2, Vec3};
use serde::Serialize;

/// Thickness over which a glass's `tint` is the transmittance (so tints read like real glass).
pub const TINT_REFERENCE_LENGTH_M: f32 = 0.01;

/// Surface optics of an object.
#[derive(Clone, Copy, Debug, Serialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum Material {
    /// Smooth dielectric with Fresnel reflection, refraction and Beer–Lambert absorption.
    Glass { ior: f32, tint: [f32; 3] },
    /// Lambertian base under a thin clear coat (Fresnel-weighted mirror reflection, `F0 = 0.04`).
    Glazed { color: [f32; 3] },
}

impl Material {
    pub fn is_transparent(&self) -> bool {
        matches!(self, Material::Glass { .. })
    }
}

/// What the ray does at a dielectric interface.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Interface {
    /// Both a reflected and a refracted ray; `reflectance` is the Fresnel `R`.
    Split { reflectance: f32, refracted: Vec3 },
    /// Past the critical angle: everything is reflected.
    TotalInternalReflection,
}

/// Mirror direction `r = d − 2 (d·n) n`.
#[inline]
pub fn reflect(d: Vec3, n: Vec3) -> Vec3 {
    d - 2.0 * d.dot(n) * n
}

/// Snell refraction and Fresnel reflectance for unit `d` arriving from the side `n` faces,
/// going from index `n1` into `n2` (see the module docs for the equations).
pub fn dielectric(d: Vec3, n: Vec3, n1: f32, n2: f32) -> Interface {
    let cos1 = (-d.dot(n)).clamp(0.0, 1.0);
    let eta = n1 / n2;
    let sin2_sq = eta * eta * (1.0 - cos1 * cos1);
    if sin2_sq >= 1.0 {
        return Interface::TotalInternalReflection;
    }
    let cos2 = (1.0 - sin2_sq).sqrt();
    let rs = ((n1 * cos1 - n2 * cos2) / (n1 * cos1 + n2 * cos2)).powi(2);
    let rp = ((n1 * cos2 - n2 * cos1) / (n1 * cos2 + n2 * cos1)).powi(2);
    let refracted = (eta * d + (eta * cos1 - cos2) * n).normalize();
    Interface::Split {
        reflectance: 0.5 * (rs + rp),
        refracted,
    }
}

/// Schlick's approximation `F = F0 + (1 − F0)(1 − cos θ)⁵`, used for the glazed clear coat.
#[inline]
pub fn schlick(cos: f32, f0: f32) -> f32 {
    f0 + (1.0 - f0) * (1.0 - cos.clamp(0.0, 1.0)).powi(5)
}

/// Beer–Lambert transmittance of a path of `length` metres through glass of the given tint.
#[inline]
pub fn absorption(tint: [f32; 3], length: f32) -> Vec3 {
    let k = length / TINT_REFERENCE_LENGTH_M;
    Vec3::new(tint[0].powf(k), tint[1].powf(k), tint[2].powf(k))
}

/// Procedural table-top textures, evaluated at world `(x, y)` in metres.
#[derive(Clone, Copy, Debug, Serialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum Texture {
    Plain {
        color: [f32; 3],
    },
    /// Squares of side `size` metres in two colours.
    Checker {
        a: [f32; 3],
        b: [f32; 3],
        size: f32,
    },
    /// Veins `|sin(x·f + turbulence)|` between a base and a vein colour.
    Marble {
        base: [f32; 3],
        vein: [f32; 3],
        frequency: f32,
    },
    /// Growth rings around a far-away centre, perturbed by noise, between two wood tones.
    Wood {
        light: [f32; 3],
        dark: [f32; 3],
        ring_spacing: f32,
    },
}

impl Texture {
    pub fn eval(&self, x: f32, y: f32) -> Vec3 {
        match *self {
            Texture::Plain { color } => color.into(),
            Texture::Checker { a, b, size } => {
                let parity = ((x / size).floor() as i64 + (y / size).floor() as i64).rem_euclid(2);
                if parity == 0 { a.into() } else { b.into() }
            }
            Texture::Marble {
                base,
                vein,
                frequency,
            } => {
                let p = Vec2::new(x, y) * 20.0;
                let s = (x * frequency + 6.0 * turbulence(p)).sin().abs().powf(0.35);
                Vec3::from(vein).lerp(base.into(), s)
            }
            Texture::Wood {
                light,
                dark,
                ring_spacing,
            } => {
                let p = Vec2::new(x, y);
                let r = (p - Vec2::new(-1.3, 0.21)).length() + 0.004 * turbulence(p * 40.0);
                let ring = (r / ring_spacing).fract();
                let grain = 0.08 * value_noise(Vec2::new(x * 300.0, y * 8.0));
                Vec3::from(light).lerp(dark.into(), (ring * ring + grain).clamp(0.0, 1.0))
            }
        }
    }
}

/// Lattice hash → `[0, 1)`; deterministic, no tables.
fn hash2(i: i32, j: i32) -> f32 {
    let mut h = (i as u32).wrapping_mul(0x8da6_b343) ^ (j as u32).wrapping_mul(0xd816_3841);
    h ^= h >> 13;
    h = h.wrapping_mul(0x85eb_ca6b);
    h ^= h >> 16;
    (h & 0x00ff_ffff) as f32 / 16_777_216.0
}

/// Bilinear value noise with smoothstep weights, range `[0, 1)`.
fn value_noise(p: Vec2) -> f32 {
    let (i, j) = (p.x.floor() as i32, p.y.floor() as i32);
    let f = p - p.floor();
    let w = f * f * (Vec2::splat(3.0) - 2.0 * f);
    let a = hash2(i, j) + (hash2(i + 1, j) - hash2(i, j)) * w.x;
    let b = hash2(i, j + 1) + (hash2(i + 1, j + 1) - hash2(i, j + 1)) * w.x;
    a + (b - a) * w.y
}

/// Four octaves of value noise (a "turbulence" sum), range about `[0, 1)`.
fn turbulence(p: Vec2) -> f32 {
    (0..4)
        .map(|o| value_noise(p * (1u32 << o) as f32) / (2u32 << o) as f32)
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fresnel_at_normal_incidence_is_the_textbook_four_percent() {
        let Interface::Split {
            reflectance,
            refracted,
        } = dielectric(-Vec3::Z, Vec3::Z, 1.0, 1.5)
        else {
            panic!()
        };
        assert!((reflectance - 0.04).abs() < 1e-6);
        assert!((refracted - (-Vec3::Z)).length() < 1e-6);
    }

    #[test]
    fn refraction_obeys_snells_law() {
        let th: f32 = 0.7;
        let d = Vec3::new(th.sin(), 0.0, -th.cos());
        let Interface::Split { refracted, .. } = dielectric(d, Vec3::Z, 1.0, 1.5) else {
            panic!()
        };
        let sin2 = refracted.x;
        assert!((th.sin() - 1.5 * sin2).abs() < 1e-6);
    }

    #[test]
    fn total_internal_reflection_past_the_critical_angle() {
        let crit = (1.0f32 / 1.5).asin();
        for (angle, tir) in [(crit - 0.01, false), (crit + 0.01, true), (1.5, true)] {
            // Inside glass going up into air; the normal faces the incident (glass) side.
            let d = Vec3::new(angle.sin(), 0.0, angle.cos());
            let got = dielectric(d, -Vec3::Z, 1.5, 1.0);
            assert_eq!(
                got == Interface::TotalInternalReflection,
                tir,
                "angle {angle} vs critical {crit}"
            );
        }
        // Just below the critical angle nearly everything is already reflected (R → 1).
        let d = Vec3::new((crit - 1e-3).sin(), 0.0, (crit - 1e-3).cos());
        let Interface::Split { reflectance, .. } = dielectric(d, -Vec3::Z, 1.5, 1.0) else {
            panic!()
        };
        assert!(reflectance > 0.7, "R = {reflectance}");
    }
}
