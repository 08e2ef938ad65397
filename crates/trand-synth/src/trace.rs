//! Whitted-style ray tracer with real dielectrics, plus the exact ground-truth pass.
//!
//! **Colour.** Each pixel averages `spp` jittered camera rays (box filter over the pixel). At a
//! glass surface the ray splits deterministically into a Fresnel-weighted reflection and a
//! refraction (`L = R·L_r + (1 − R)·L_t`, see [`crate::material`]); past the critical angle only
//! the reflection is followed. Light travelling inside glass is attenuated by Beer–Lambert
//! absorption over the segment length. Diffuse surfaces (table, glazed objects) get direct light:
//! the area light's exact irradiance (Lambert's polygon formula) times the visibility of one
//! stratified light point, times `albedo/π`; the shadow ray passes through glass (attenuated by a
//! per-interface loss and the glass tint, no caustics) and stops at opaque objects; plus a uniform
//! ambient term. Branches
//! whose weight falls under [`MIN_WEIGHT`] or deeper than [`MAX_DEPTH`] are cut.
//!
//! **Ground truth.** One ray through each pixel centre (integer pixel coordinates): depth is the
//! first surface hit's planar camera `z = t (d · f)` (glass surfaces included), the mask id is the
//! object it belongs to. No jitter, no filtering, so depth and masks are exact and agree.
//!
//! **Determinism.** Rows are rendered in parallel, but every pixel draws its random numbers from
//! its own PCG stream seeded by `(view seed, pixel index)` and writes only its own output, so the
//! bytes do not depend on the number of threads or the scheduling order.

use crate::material::{Interface, Material, absorption, dielectric, reflect, schlick};
use crate::scene::RenderScene;
use glam::{DVec3, Vec3};
use rand::{RngExt, SeedableRng};
use rayon::prelude::*;
use std::f32::consts::PI;
use trand_core::camera::Camera;

/// Maximum number of surface interactions along one path (glass stacks need about 8: two walls
/// of two stacked glasses, in and out).
pub const MAX_DEPTH: u32 = 12;
/// Branches contributing less than this fraction of the pixel are dropped (1 % is below one
/// 8-bit step for most of the tone range).
pub const MIN_WEIGHT: f32 = 0.01;
/// Offset of secondary ray origins along the ray, against self-intersection (metres; 1000×
/// smaller than the thinnest glass wall).
pub const RAY_EPS: f32 = 2e-6;
/// Light lost at one glass interface by a shadow ray (about twice the 4 % normal-incidence
/// Fresnel reflectance, averaged over angles).
pub const SHADOW_INTERFACE_LOSS: f32 = 0.08;
/// Clear-coat reflectance at normal incidence for glazed objects (that of n = 1.5).
pub const GLAZE_F0: f32 = 0.04;

/// What a ray hit first.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Surface {
    Table,
    /// Index into [`RenderScene::objects`].
    Object(u32),
}

/// A first hit with the geometry needed for shading.
#[derive(Clone, Copy, Debug)]
pub struct SurfaceHit {
    pub t: f32,
    pub point: Vec3,
    /// Geometric (flat) normal, outward.
    pub geo_normal: Vec3,
    /// Interpolated vertex normal, outward.
    pub shading_normal: Vec3,
    pub surface: Surface,
}

/// Per-view rendering settings.
#[derive(Clone, Copy, Debug)]
pub struct RenderSettings {
    pub samples_per_pixel: u32,
}

/// The images of one view.
pub struct ViewImages {
    pub width: u32,
    pub height: u32,
    /// sRGB, 8 bit, row-major RGB.
    pub rgb: Vec<u8>,
    /// Planar camera depth in millimetres (0 = no surface).
    pub depth_mm: Vec<u16>,
    /// Object id (`obj_id`) of the first surface, 0 for the table or the background.
    pub ids: Vec<u32>,
}

impl RenderScene {
    /// First surface along `o + t d`, `0 < t < t_max`.
    pub fn intersect(&self, o: Vec3, d: Vec3, t_max: f32) -> Option<SurfaceHit> {
        let mut best: Option<SurfaceHit> = None;
        let table = &self.env.table;
        if d.z < 0.0 && o.z > 0.0 {
            let t = -o.z / d.z;
            let p = o + t * d;
            if t < t_max && p.x.abs() <= table.half_size_m && p.y.abs() <= table.half_size_m {
                let point = Vec3::new(p.x, p.y, 0.0);
                best = Some(SurfaceHit {
                    t,
                    point,
                    geo_normal: Vec3::Z,
                    shading_normal: Vec3::Z,
                    surface: Surface::Table,
                });
            }
        }
        let limit = best.map_or(t_max, |b| b.t);
        if let Some(h) = self.bvh.closest(o, d, limit) {
            let tri = self.bvh.tri(h.tri);
            let sh = &self.shading[h.tri as usize];
            let mut geo = tri.e1.cross(tri.e2).normalize_or_zero();
            let w = 1.0 - h.u - h.v;
            let shading =
                (w * sh.normals[0] + h.u * sh.normals[1] + h.v * sh.normals[2]).normalize_or(geo);
            if geo.dot(shading) < 0.0 {
                geo = -geo;
            }
            best = Some(SurfaceHit {
                t: h.t,
                point: o + h.t * d,
                geo_normal: geo,
                shading_normal: shading,
                surface: Surface::Object(sh.object),
            });
        }
        best
    }

    /// Radiance arriving along `-d` at `o`; `weight` is this branch's share of the pixel.
    fn radiance(&self, o: Vec3, d: Vec3, depth: u32, weight: f32, rng: &mut Sampler) -> Vec3 {
        let env = &self.env;
        let hit = self.intersect(o, d, f32::INFINITY);
        let light_t = env.light.hit(o, d);
        match (hit, light_t) {
            (None, Some(_)) => return Vec3::splat(env.light.radiance),
            (Some(h), Some(tl)) if tl < h.t => return Vec3::splat(env.light.radiance),
            (None, None) => return env.background.radiance(d),
            _ => {}
        }
        let h = hit.expect("matched above");
        if depth >= MAX_DEPTH {
            return env.background.radiance(d);
        }
        match h.surface {
            Surface::Table => {
                let albedo = env.table.texture.eval(h.point.x, h.point.y);
                albedo * self.diffuse_irradiance(h.point, Vec3::Z, rng)
            }
            Surface::Object(k) => match self.objects[k as usize].material {
                Material::Glazed { color } => {
                    let n = face_forward(h.shading_normal, h.geo_normal, d);
                    let f = schlick(-d.dot(n), GLAZE_F0);
                    let base =
                        Vec3::from(color) * self.diffuse_irradiance(h.point + RAY_EPS * n, n, rng);
                    let mut l = (1.0 - f) * base;
                    if weight * f > MIN_WEIGHT {
                        let r = reflect_above(d, n, h.geo_normal);
                        l +=
                            f * self.radiance(h.point + RAY_EPS * r, r, depth + 1, weight * f, rng);
                    }
                    l
                }
                Material::Glass { ior, tint } => self.glass(&h, d, ior, tint, depth, weight, rng),
            },
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn glass(
        &self,
        h: &SurfaceHit,
        d: Vec3,
        ior: f32,
        tint: [f32; 3],
        depth: u32,
        weight: f32,
        rng: &mut Sampler,
    ) -> Vec3 {
        let entering = d.dot(h.geo_normal) < 0.0;
        let (n, geo, n1, n2) = if entering {
            (h.shading_normal, h.geo_normal, 1.0, ior)
        } else {
            (-h.shading_normal, -h.geo_normal, ior, 1.0)
        };
        // Shading normals can face away from the ray near silhouettes; fall back to the flat one.
        let n = if d.dot(n) < 0.0 { n } else { geo };
        let r = reflect_above(d, n, geo);
        let l = match dielectric(d, n, n1, n2) {
            Interface::TotalInternalReflection => {
                self.radiance(h.point + RAY_EPS * r, r, depth + 1, weight, rng)
            }
            Interface::Split {
                reflectance,
                refracted,
            } => {
                let t = if refracted.dot(geo) < 0.0 {
                    refracted
                } else {
                    d
                };
                let mut l = (1.0 - reflectance)
                    * self.radiance(
                        h.point + RAY_EPS * t,
                        t,
                        depth + 1,
                        weight * (1.0 - reflectance),
                        rng,
                    );
                if weight * reflectance > MIN_WEIGHT {
                    l += reflectance
                        * self.radiance(
                            h.point + RAY_EPS * r,
                            r,
                            depth + 1,
                            weight * reflectance,
                            rng,
                        );
                }
                l
            }
        };
        // Leaving the glass: the ray travelled `t` inside it.
        if entering {
            l
        } else {
            l * absorption(tint, h.t)
        }
    }

    /// Irradiance factor at a diffuse point, so that `albedo × this` is the outgoing radiance:
    /// the light's exact unoccluded irradiance (Lambert's polygon formula, see
    /// [`crate::scene::AreaLight::irradiance`]) times the visibility of one stratified point of
    /// the light (glass-aware shadow ray), over `π`, plus the ambient term. Unshadowed surfaces
    /// are therefore noise-free; only penumbrae are sampled.
    fn diffuse_irradiance(&self, p: Vec3, n: Vec3, rng: &mut Sampler) -> Vec3 {
        let light = &self.env.light;
        let ambient = Vec3::splat(self.env.ambient * (0.6 + 0.4 * n.z));
        let e = light.irradiance(p, n);
        if e <= 0.0 {
            return ambient;
        }
        let (a, b) = rng.light_uv();
        let to = light.point(a, b) - p;
        let dist = to.length();
        let vis = self.transmittance(p + RAY_EPS * n, to / dist, dist);
        ambient + vis * (e / PI)
    }

    /// Fraction of light reaching `o` from distance `len` along `w`: zero behind opaque objects,
    /// attenuated by interface loss and Beer–Lambert absorption through glass.
    fn transmittance(&self, o: Vec3, w: Vec3, len: f32) -> Vec3 {
        let mut t_done = 0.0;
        let mut trans = Vec3::ONE;
        for _ in 0..2 * MAX_DEPTH {
            let start = o + t_done * w;
            let Some(h) = self.intersect(start, w, len - t_done) else {
                return trans;
            };
            match h.surface {
                Surface::Table => return Vec3::ZERO,
                Surface::Object(k) => match self.objects[k as usize].material {
                    Material::Glazed { .. } => return Vec3::ZERO,
                    Material::Glass { tint, .. } => {
                        trans *= 1.0 - SHADOW_INTERFACE_LOSS;
                        if w.dot(h.geo_normal) > 0.0 {
                            trans *= absorption(tint, h.t);
                        }
                    }
                },
            }
            t_done += h.t + RAY_EPS;
            if trans.max_element() < MIN_WEIGHT {
                return Vec3::ZERO;
            }
        }
        trans
    }
}

/// One straight piece of a traced light path.
#[derive(Clone, Copy, Debug)]
pub struct PathSegment {
    pub origin: Vec3,
    pub direction: Vec3,
    /// Where the segment ended on a surface (`None`: it left the scene).
    pub end: Option<Vec3>,
    /// Whether the ended segment turned by total internal reflection there.
    pub total_internal_reflection: bool,
}

impl RenderScene {
    /// Follows only the transmitted branch through glass (reflected when totally internally
    /// reflected), using exactly the renderer's interface logic; stops at the first non-glass
    /// surface, when the ray leaves the scene, or after `max_segments`. For tests and debugging.
    pub fn refraction_path(
        &self,
        mut o: Vec3,
        mut d: Vec3,
        max_segments: usize,
    ) -> Vec<PathSegment> {
        let mut path = Vec::new();
        for _ in 0..max_segments {
            let Some(h) = self.intersect(o, d, f32::INFINITY) else {
                path.push(PathSegment {
                    origin: o,
                    direction: d,
                    end: None,
                    total_internal_reflection: false,
                });
                break;
            };
            let Surface::Object(k) = h.surface else {
                path.push(PathSegment {
                    origin: o,
                    direction: d,
                    end: Some(h.point),
                    total_internal_reflection: false,
                });
                break;
            };
            let Material::Glass { ior, .. } = self.objects[k as usize].material else {
                path.push(PathSegment {
                    origin: o,
                    direction: d,
                    end: Some(h.point),
                    total_internal_reflection: false,
                });
                break;
            };
            let entering = d.dot(h.geo_normal) < 0.0;
            let (n, geo, n1, n2) = if entering {
                (h.shading_normal, h.geo_normal, 1.0, ior)
            } else {
                (-h.shading_normal, -h.geo_normal, ior, 1.0)
            };
            let n = if d.dot(n) < 0.0 { n } else { geo };
            let (next, tir) = match dielectric(d, n, n1, n2) {
                Interface::TotalInternalReflection => (reflect_above(d, n, geo), true),
                Interface::Split { refracted, .. } => (
                    if refracted.dot(geo) < 0.0 {
                        refracted
                    } else {
                        d
                    },
                    false,
                ),
            };
            path.push(PathSegment {
                origin: o,
                direction: d,
                end: Some(h.point),
                total_internal_reflection: tir,
            });
            o = h.point + RAY_EPS * next;
            d = next;
        }
        path
    }
}

/// Per-pixel random numbers with stratification: with `n²` samples per pixel, sample `i` takes
/// pixel-footprint stratum `(i mod n, i div n)` and a different (shifted) light stratum, so both
/// the anti-aliasing and the soft shadows are stratified (less noise than independent samples).
pub struct Sampler {
    rng: rand_pcg::Pcg32,
    light_stratum: (f32, f32),
    inv_n: f32,
}

impl Sampler {
    fn new(seed: u64) -> Self {
        Self {
            rng: rand_pcg::Pcg32::seed_from_u64(seed),
            light_stratum: (0.0, 0.0),
            inv_n: 1.0,
        }
    }

    /// Starts sample `i` of `n²`; returns its jitter in the pixel, in `[−½, ½)²`.
    fn start_sample(&mut self, i: u32, n: u32) -> (f64, f64) {
        let (sx, sy) = (i % n, i / n);
        self.inv_n = 1.0 / n as f32;
        self.light_stratum = (((sx + sy) % n) as f32, sx as f32);
        let inv = 1.0 / n as f64;
        (
            (sx as f64 + self.rng.random::<f64>()) * inv - 0.5,
            (sy as f64 + self.rng.random::<f64>()) * inv - 0.5,
        )
    }

    /// A point of the unit square for the light sample, inside this sample's light stratum.
    fn light_uv(&mut self) -> (f32, f32) {
        let (u, v) = (self.rng.random::<f32>(), self.rng.random::<f32>());
        (
            (self.light_stratum.0 + u) * self.inv_n,
            (self.light_stratum.1 + v) * self.inv_n,
        )
    }
}

/// The shading normal flipped to the side the ray comes from.
fn face_forward(n: Vec3, geo: Vec3, d: Vec3) -> Vec3 {
    let g = if d.dot(geo) < 0.0 { geo } else { -geo };
    let n = if n.dot(g) < 0.0 { -n } else { n };
    if d.dot(n) < 0.0 { n } else { g }
}

/// Mirror reflection about `n`, forced to the incident side of the geometric normal `geo`.
fn reflect_above(d: Vec3, n: Vec3, geo: Vec3) -> Vec3 {
    let r = reflect(d, n);
    if r.dot(geo) > 0.0 { r } else { reflect(d, geo) }
}

/// Linear radiance to 8-bit sRGB (IEC 61966-2-1 transfer curve), clamped.
fn srgb8(v: f32) -> u8 {
    let v = v.clamp(0.0, 1.0);
    let s = if v <= 0.003_130_8 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    };
    (s * 255.0 + 0.5) as u8
}

/// Seed of one pixel's random stream: a SplitMix64 finaliser of the view seed and pixel index.
fn pixel_seed(view_seed: u64, pixel: u64) -> u64 {
    let mut z = view_seed ^ pixel.wrapping_mul(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Depth in millimetres as stored in the PNG: `round(z · 1000)`, saturated to the u16 range.
pub fn encode_depth_mm(z_m: f64) -> u16 {
    (z_m * 1000.0).round().clamp(1.0, 65535.0) as u16
}

/// Renders colour, depth and instance ids of one view. `on_row` is called once per finished row.
pub fn render_view(
    scene: &RenderScene,
    cam: &Camera,
    settings: RenderSettings,
    view_seed: u64,
    on_row: &(dyn Fn() + Sync),
) -> ViewImages {
    let k = cam.intrinsics;
    let (w, h) = (k.width as usize, k.height as usize);
    let origin = cam.center().as_vec3();
    let forward = cam.forward();
    let mut rgb = vec![0u8; w * h * 3];
    let mut depth_mm = vec![0u16; w * h];
    let mut ids = vec![0u32; w * h];
    let spp = settings.samples_per_pixel.max(1);
    let strata = (spp as f64).sqrt().round() as u32;
    rgb.par_chunks_mut(w * 3)
        .zip(depth_mm.par_chunks_mut(w))
        .zip(ids.par_chunks_mut(w))
        .enumerate()
        .for_each(|(y, ((rgb_row, depth_row), id_row))| {
            for x in 0..w {
                // Ground truth: one ray through the pixel centre.
                let dc: DVec3 = cam.ray_direction(x as f64, y as f64);
                if let Some(hit) = scene.intersect(origin, dc.as_vec3(), f32::INFINITY) {
                    depth_row[x] = encode_depth_mm(hit.t as f64 * dc.dot(forward));
                    id_row[x] = match hit.surface {
                        Surface::Table => 0,
                        Surface::Object(o) => scene.objects[o as usize].obj_id,
                    };
                }
                // Colour: jittered samples over the pixel footprint.
                let mut rng = Sampler::new(pixel_seed(view_seed, (y * w + x) as u64));
                let mut sum = Vec3::ZERO;
                for i in 0..spp {
                    // Stratified when spp is a square; otherwise plain random (one stratum).
                    let n = if strata * strata == spp { strata } else { 1 };
                    let (jx, jy) = rng.start_sample(i % (n * n), n);
                    let d = cam.ray_direction(x as f64 + jx, y as f64 + jy).as_vec3();
                    sum += scene.radiance(origin, d, 0, 1.0, &mut rng);
                }
                let c = sum / spp as f32;
                rgb_row[3 * x..3 * x + 3].copy_from_slice(&[srgb8(c.x), srgb8(c.y), srgb8(c.z)]);
            }
            on_row();
        });
    ViewImages {
        width: k.width,
        height: k.height,
        rgb,
        depth_mm,
        ids,
    }
}
