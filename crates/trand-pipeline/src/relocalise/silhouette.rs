//! What the new image says about a pose of one object: its silhouette against the object's instance
//! mask, and its rendered colours against the image's colours.
//!
//! Everything is taken at a working resolution of at most [`WORKING_WIDTH`] pixels across. The
//! silhouette IoU does not count silhouette pixels on *other* objects' masks as false positives (the
//! object may be behind them). Surfels below the table are left out: the table hides them, and an
//! object's reconstruction often reaches below its base (where it stood on another object at t = 0),
//! which would otherwise widen the silhouette of the right pose and not of an upside-down one. Two
//! silhouettes:
//! * **splat**: each surfel with opacity above ½ a disc of [`SPLAT_SIGMAS`] standard deviations around
//!   its projected centre, cheap enough for the thousands of poses a search tries. On the objects of
//!   the four Blender sequences' t = 1 views these discs agree with the rendered silhouette at IoU
//!   0.65–0.88 (the rendered one is the fuller); every surfel above 5 % opacity (a trained glass has
//!   20–30 times as many) agreed less;
//! * **rendered**: the object's surfels alone, `α > ½`, its holes filled ([`filled`]), the measure
//!   decisions are taken on. The same render gives the photometric error: the mean absolute
//!   difference between the rendered colour (over the background colour) and the image with every
//!   pixel outside the object's mask set to the background — the refinement's colour target — over
//!   the pixels of the mask or the silhouette (`α > ½`, unfilled), other objects' pixels left out. A
//!   pose that covers the mask with the wrong colours (upside down, the wrong end towards the camera)
//!   pays for them; one that covers only the part of the mask its colours happen to match pays for
//!   the rest.

use glam::DVec3;
use trand_core::{Camera, Surfels};
use trand_io::{InstanceMap, Rgb8Image};
use trand_render::{RenderSettings, render};

use super::pose::Pose;
use crate::Result;

/// Widest silhouette image the search renders (pixels): half of a 640 px view, 1.5–2 mm per pixel at
/// the benchmark distance (0.5 m). Trained surfels are about a native pixel across; rendered at a
/// quarter of the resolution they no longer cover their object (`α > ½` leaves holes), an object at
/// its true pose keeps only ~0.7 of its mask's IoU, and poses a centimetre apart score alike, which the
/// single-view refinement afterwards does not undo. At half resolution the silhouette holds; the full
/// one doubles the search's time for no gain on average (BENCHMARKS.md §10).
pub const WORKING_WIDTH: u32 = 320;
/// Splat disc radius in standard deviations of a surfel's larger axis, at most [`SPLAT_MAX_RADIUS_PX`]
/// pixels.
pub const SPLAT_SIGMAS: f64 = 2.0;
pub const SPLAT_MAX_RADIUS_PX: f64 = 3.0;
/// Opacity logit of the surfels below the table in a silhouette render: none.
const HIDDEN_OPACITY_LOGIT: f32 = -30.0;
/// Splat surfels: opacity above ½, or the [`SPLAT_MIN_SURFELS`] most opaque when fewer pass.
pub const SPLAT_MIN_SURFELS: usize = 200;

/// The new image at the working resolution.
pub struct Target {
    pub camera: Camera,
    /// Table height: nothing below it is seen.
    pub ground: f64,
    /// Instance id per pixel (block majority).
    pub ids: Vec<u16>,
    /// RGB in `[0, 1]` per pixel (block mean of the stored values); empty without an image.
    pub rgb: Vec<[f32; 3]>,
}

impl Target {
    /// `inst` and `rgb` (same size as the camera's image) reduced by the smallest integer factor
    /// that brings the width to at most [`WORKING_WIDTH`].
    pub fn new(
        camera: &Camera,
        inst: &InstanceMap,
        rgb: Option<&Rgb8Image>,
        ground: f64,
    ) -> Target {
        let f = inst.width.div_ceil(WORKING_WIDTH).max(1);
        let camera = Camera {
            intrinsics: camera.intrinsics.scaled(1.0 / f as f64),
            ..*camera
        };
        let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
        let ids = downsample_ids(inst, f, w, h);
        let rgb = rgb
            .filter(|r| r.same_size(inst) && r.channels == 3)
            .map(|r| downsample_rgb(r, f, w, h))
            .unwrap_or_default();
        Target {
            camera,
            ground,
            ids,
            rgb,
        }
    }

    pub fn width(&self) -> usize {
        self.camera.intrinsics.width as usize
    }
}

/// Scores of a rendered silhouette.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Rendered {
    pub iou: f64,
    /// Mean absolute colour difference over the pixels of mask ∪ silhouette (module doc; `None`: no
    /// image).
    pub photometric: Option<f64>,
}

/// The scorer of one object's poses.
pub struct Scorer<'a> {
    target: &'a Target,
    settings: RenderSettings,
    /// This object's mask and the other objects' pixels.
    mask: Vec<bool>,
    others: Vec<bool>,
    mask_size: usize,
    /// Mask bounding box `[x0, y0, x1, y1]` (inclusive).
    mask_box: [usize; 4],
    pub mask_centroid: (f64, f64),
    base: &'a Surfels,
    centroid: DVec3,
    /// Centres and footprint radii (world units) of the splat surfels.
    points: Vec<DVec3>,
    radius: Vec<f64>,
    hit: Vec<bool>,
    pub evaluations: usize,
}

/// A splat silhouette's IoU and centroid (pixels; `None` when empty).
pub struct Splat {
    pub iou: f64,
    pub centroid: Option<(f64, f64)>,
}

impl<'a> Scorer<'a> {
    /// The scorer of `base` (the object's undeformed surfels, `centroid` their mean) against the
    /// pixels of `new_id`. `None` when the mask has no pixel.
    pub fn new(
        target: &'a Target,
        settings: RenderSettings,
        new_id: u16,
        base: &'a Surfels,
        centroid: DVec3,
    ) -> Option<Self> {
        let w = target.width();
        let mask: Vec<bool> = target.ids.iter().map(|&i| i == new_id).collect();
        let others: Vec<bool> = target.ids.iter().map(|&i| i != 0 && i != new_id).collect();
        let (mut bx, mut n, mut sx, mut sy) = ([usize::MAX, usize::MAX, 0, 0], 0usize, 0.0, 0.0);
        for (p, _) in mask.iter().enumerate().filter(|(_, m)| **m) {
            let (x, y) = (p % w, p / w);
            bx = [bx[0].min(x), bx[1].min(y), bx[2].max(x), bx[3].max(y)];
            n += 1;
            sx += x as f64;
            sy += y as f64;
        }
        if n == 0 {
            return None;
        }
        let v = |a: [f32; 3]| DVec3::new(a[0] as f64, a[1] as f64, a[2] as f64);
        let mut logits = base.opacity_logits.clone();
        logits.sort_by(|a, b| b.total_cmp(a));
        let threshold = logits
            .get(SPLAT_MIN_SURFELS.saturating_sub(1))
            .map_or(f32::NEG_INFINITY, |&l| l.min(0.0));
        let (points, radius): (Vec<DVec3>, Vec<f64>) = base
            .means
            .iter()
            .zip(&base.log_scales)
            .zip(&base.opacity_logits)
            .filter(|(_, o)| **o >= threshold)
            .map(|((m, s), _)| (v(*m), SPLAT_SIGMAS * s[0].max(s[1]).exp() as f64))
            .unzip();
        Some(Self {
            target,
            settings,
            hit: vec![false; mask.len()],
            mask,
            others,
            mask_size: n,
            mask_box: bx,
            mask_centroid: (sx / n as f64, sy / n as f64),
            base,
            centroid,
            points,
            radius,
            evaluations: 0,
        })
    }

    /// The camera of the working resolution.
    pub fn target_camera(&self) -> Camera {
        self.target.camera
    }

    /// The object's surfels under `pose`.
    pub fn place(&self, pose: &Pose) -> Surfels {
        pose.place(self.base, self.centroid)
    }

    /// IoU with the mask over the pixels of box `b`, the silhouette given per pixel.
    fn iou(&self, b: [usize; 4], silhouette: impl Fn(usize) -> bool) -> f64 {
        let w = self.target.width();
        let (mut inter, mut extra) = (0usize, 0usize);
        for y in b[1]..=b[3] {
            for p in y * w + b[0]..=y * w + b[2] {
                if silhouette(p) {
                    if self.mask[p] {
                        inter += 1;
                    } else if !self.others[p] {
                        extra += 1;
                    }
                }
            }
        }
        inter as f64 / (self.mask_size + extra).max(1) as f64
    }

    /// The rendered silhouette's IoU and photometric error.
    pub fn render(&mut self, pose: &Pose) -> Result<Rendered> {
        let mut placed = self.place(pose);
        for (m, o) in placed.means.iter().zip(placed.opacity_logits.iter_mut()) {
            if (m[2] as f64) < self.target.ground {
                *o = HIDDEN_OPACITY_LOGIT;
            }
        }
        let out = render::<f32, _>(&placed, &self.target.camera, &self.settings)?;
        let k = self.target.camera.intrinsics;
        let all = [0, 0, k.width as usize - 1, k.height as usize - 1];
        let solid = filled(
            out.alpha.iter().map(|&a| a > 0.5).collect(),
            k.width as usize,
        );
        let iou = self.iou(all, |p| solid[p]);
        let (mut sum, mut n) = (0.0f64, 0usize);
        if !self.target.rgb.is_empty() {
            let bg = self.settings.background;
            for (p, &a) in out.alpha.iter().enumerate() {
                if (a > 0.5 || self.mask[p]) && !self.others[p] {
                    let want = if self.mask[p] { self.target.rgb[p] } else { bg };
                    for (got, want) in out.rgb[p * 3..p * 3 + 3].iter().zip(want) {
                        sum += (got - want).abs() as f64;
                    }
                    n += 1;
                }
            }
        }
        Ok(Rendered {
            iou,
            photometric: (n > 0).then(|| sum / (3 * n) as f64),
        })
    }

    /// The splat silhouette's IoU and centroid.
    pub fn splat(&mut self, pose: &Pose) -> Splat {
        self.evaluations += 1;
        let k = self.target.camera.intrinsics;
        let (w, h) = (k.width as i64, k.height as i64);
        let mut hit = std::mem::take(&mut self.hit);
        let mut b = self.mask_box;
        let (mut sx, mut sy, mut n) = (0.0, 0.0, 0usize);
        for (p, &r) in self.points.iter().zip(&self.radius) {
            let world = pose.apply(self.centroid, *p);
            if world.z < self.target.ground {
                continue;
            }
            let Some((x, y, z)) = self.target.camera.project(world) else {
                continue;
            };
            let rp = (k.fx * r / z).clamp(0.5, SPLAT_MAX_RADIUS_PX);
            let (x0, x1) = (
                ((x - rp).ceil() as i64).max(0),
                ((x + rp).floor() as i64).min(w - 1),
            );
            let (y0, y1) = (
                ((y - rp).ceil() as i64).max(0),
                ((y + rp).floor() as i64).min(h - 1),
            );
            if x0 > x1 || y0 > y1 {
                continue;
            }
            b = [
                b[0].min(x0 as usize),
                b[1].min(y0 as usize),
                b[2].max(x1 as usize),
                b[3].max(y1 as usize),
            ];
            for py in y0..=y1 {
                for px in x0..=x1 {
                    if (px as f64 - x).powi(2) + (py as f64 - y).powi(2) <= rp * rp {
                        let i = (py * w + px) as usize;
                        if !hit[i] {
                            hit[i] = true;
                            sx += px as f64;
                            sy += py as f64;
                            n += 1;
                        }
                    }
                }
            }
        }
        let iou = self.iou(b, |p| hit[p]);
        for y in b[1]..=b[3] {
            hit[y * w as usize + b[0]..=y * w as usize + b[2]].fill(false);
        }
        self.hit = hit;
        Splat {
            iou,
            centroid: (n > 0).then(|| (sx / n as f64, sy / n as f64)),
        }
    }
}

/// `silhouette` (row-major, `width` wide) with its holes filled: every pixel the image's border
/// cannot reach through pixels outside it (4-connected). An open vessel seen from above shows its
/// inside, and its mask covers it; a model of it whose floor is missing or was lowered under the
/// table (an object rests on its body, and surfels under the table are not drawn) renders a ring,
/// which then fits the mask worse than the vessel lying on its side.
pub fn filled(mut silhouette: Vec<bool>, width: usize) -> Vec<bool> {
    let height = silhouette.len() / width.max(1);
    let mut outside = vec![false; silhouette.len()];
    let mut stack: Vec<usize> = (0..width)
        .flat_map(|x| [x, (height - 1) * width + x])
        .chain((0..height).flat_map(|y| [y * width, y * width + width - 1]))
        .collect();
    while let Some(p) = stack.pop() {
        if silhouette[p] || outside[p] {
            continue;
        }
        outside[p] = true;
        let (x, y) = (p % width, p / width);
        if x > 0 {
            stack.push(p - 1);
        }
        if x + 1 < width {
            stack.push(p + 1);
        }
        if y > 0 {
            stack.push(p - width);
        }
        if y + 1 < height {
            stack.push(p + width);
        }
    }
    for (s, o) in silhouette.iter_mut().zip(&outside) {
        *s = !o;
    }
    silhouette
}

/// Downsamples an instance map by an integer factor: each block takes its most frequent id.
pub fn downsample_ids(inst: &InstanceMap, f: u32, width: u32, height: u32) -> Vec<u16> {
    let mut out = vec![0u16; (width * height) as usize];
    let mut counts: Vec<(u16, u32)> = Vec::new();
    for y in 0..height {
        for x in 0..width {
            counts.clear();
            for yy in y * f..((y + 1) * f).min(inst.height) {
                for xx in x * f..((x + 1) * f).min(inst.width) {
                    let id = inst.data[(yy * inst.width + xx) as usize];
                    match counts.iter_mut().find(|c| c.0 == id) {
                        Some(c) => c.1 += 1,
                        None => counts.push((id, 1)),
                    }
                }
            }
            out[(y * width + x) as usize] = counts
                .iter()
                .max_by_key(|c| (c.1, std::cmp::Reverse(c.0)))
                .map_or(0, |c| c.0);
        }
    }
    out
}

/// Downsamples an 8-bit RGB image by an integer factor: the mean of each block, in `[0, 1]`.
fn downsample_rgb(img: &Rgb8Image, f: u32, width: u32, height: u32) -> Vec<[f32; 3]> {
    let mut out = vec![[0.0f32; 3]; (width * height) as usize];
    for y in 0..height {
        for x in 0..width {
            let (mut acc, mut n) = ([0.0f32; 3], 0.0f32);
            for yy in y * f..((y + 1) * f).min(img.height) {
                for xx in x * f..((x + 1) * f).min(img.width) {
                    let p = ((yy * img.width + xx) * 3) as usize;
                    for (a, &v) in acc.iter_mut().zip(&img.data[p..p + 3]) {
                        *a += v as f32 / 255.0;
                    }
                    n += 1.0;
                }
            }
            out[(y * width + x) as usize] = acc.map(|a| a / n.max(1.0));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_scene::{camera, cylinder};

    #[test]
    fn a_ring_is_filled_and_a_notch_open_to_the_border_is_not() {
        // 5 × 5: a ring around the centre pixel, and a notch from the border into the ring's row 4.
        let ring: Vec<bool> = (0..25)
            .map(|p| {
                let (x, y) = (p % 5, p / 5);
                (1..=3).contains(&x) && (1..=3).contains(&y) && (x, y) != (2, 2)
            })
            .collect();
        let got = filled(ring.clone(), 5);
        assert!(got[12], "the centre is a hole");
        assert_eq!(got.iter().filter(|&&s| s).count(), 9);
        let mut notched = ring;
        notched[11] = false; // (1, 2): the hole now reaches the border through (0, 2)
        assert!(!filled(notched, 5)[12]);
    }

    #[test]
    fn an_open_vessel_seen_from_above_covers_its_mask() {
        // Walls only, as a vessel whose floor sank under the table: from above, a ring.
        let s = cylinder(0.0, 0.0, 1);
        let k = trand_core::Intrinsics::centered(300.0, 160, 120);
        let cam = Camera::look_at(k, DVec3::new(0.0, 0.0, 0.5), DVec3::ZERO, DVec3::Y);
        // Its mask: the disc inside the rim's image (the inside is seen through the opening).
        let r_px =
            300.0 * crate::test_scene::RADIUS as f64 / (0.5 - crate::test_scene::HEIGHT as f64);
        let ids: Vec<u16> = (0..k.width * k.height)
            .map(|p| {
                let (x, y) = ((p % k.width) as f64 - k.cx, (p / k.width) as f64 - k.cy);
                u16::from(x.hypot(y) <= r_px) * 7
            })
            .collect();
        let inst = InstanceMap::from_vec(k.width, k.height, 1, ids).unwrap();
        let target = Target::new(&cam, &inst, None, 0.0);
        let c = DVec3::new(0.0, 0.0, 0.05);
        let mut sc = Scorer::new(&target, RenderSettings::default(), 7, &s, c).unwrap();
        let iou = sc.render(&Pose::IDENTITY).unwrap().iou;
        assert!(iou > 0.9, "IoU {iou}");
    }

    #[test]
    fn a_block_majority_decides_a_downsampled_id() {
        let inst = InstanceMap::from_vec(4, 2, 1, vec![1, 1, 0, 2, 1, 0, 2, 2]).unwrap();
        assert_eq!(downsample_ids(&inst, 2, 2, 1), vec![1, 2]);
    }

    /// A glass of surfels the size training leaves them (a native pixel across, as dense), seen by a
    /// 640 × 480 camera from half a metre.
    fn fine_glass() -> (Surfels, Camera) {
        use glam::{Quat, Vec3};
        use trand_core::surfels::Surfel;
        let (r, h, step) = (0.03f32, 0.08f32, 0.001f32);
        let mut s = Surfels::new(0, 2).unwrap();
        let around = (std::f32::consts::TAU * r / step) as usize;
        for i in 0..around {
            let a = i as f32 * std::f32::consts::TAU / around as f32;
            let n = Vec3::new(a.cos(), a.sin(), 0.0);
            let q = Quat::from_rotation_arc(Vec3::Z, n);
            for j in 0..(h / step) as usize {
                s.push(&Surfel {
                    mean: [r * n.x, r * n.y, (j as f32 + 0.5) * step],
                    log_scale: [(0.5 * step).ln(); 2],
                    quat: [q.w, q.x, q.y, q.z],
                    opacity_logit: 2.0,
                    sh_dc: [0.5; 3],
                    mask_dc: [0.5; 3],
                    obj_logits: vec![0.0, 4.0],
                });
            }
        }
        let cam = Camera::look_at(
            trand_core::Intrinsics::centered(600.0, 640, 480),
            DVec3::new(0.0, -0.35, 0.36),
            DVec3::new(0.0, 0.0, 0.04),
            DVec3::Z,
        );
        (s, cam)
    }

    #[test]
    fn surfels_trained_at_native_resolution_keep_their_silhouette_at_the_working_one() {
        let (s, cam) = fine_glass();
        let out = render::<f32, _>(&s, &cam, &RenderSettings::default()).unwrap();
        let ids: Vec<u16> = out.alpha.iter().map(|&a| u16::from(a > 0.5) * 7).collect();
        let k = cam.intrinsics;
        let inst = InstanceMap::from_vec(k.width, k.height, 1, ids).unwrap();
        let target = Target::new(&cam, &inst, None, 0.0);
        let c = DVec3::new(0.0, 0.0, 0.04);
        let mut sc = Scorer::new(&target, RenderSettings::default(), 7, &s, c).unwrap();
        let right = sc.render(&Pose::IDENTITY).unwrap().iou;
        assert!(right > 0.85, "IoU {right} at the true pose");
        // 6 mm aside (three to four working pixels) must score clearly lower.
        let aside = sc
            .render(&Pose::IDENTITY.shifted(DVec3::new(0.006, 0.0, 0.0)))
            .unwrap()
            .iou;
        assert!(
            aside < right - 0.05,
            "IoU {aside} 6 mm aside, {right} at the pose"
        );
    }

    #[test]
    fn the_splat_silhouette_agrees_with_the_rendered_one() {
        let s = cylinder(0.02, 0.01, 0);
        let cam = camera();
        let out = render::<f32, _>(&s, &cam, &RenderSettings::default()).unwrap();
        let ids: Vec<u16> = out
            .alpha
            .iter()
            .map(|&a| if a > 0.5 { 7 } else { 0 })
            .collect();
        let k = cam.intrinsics;
        let inst = InstanceMap::from_vec(k.width, k.height, 1, ids).unwrap();
        let target = Target::new(&cam, &inst, None, 0.0);
        let c = s
            .means
            .iter()
            .map(|m| DVec3::new(m[0] as f64, m[1] as f64, m[2] as f64))
            .sum::<DVec3>()
            / s.len() as f64;
        let mut sc = Scorer::new(&target, RenderSettings::default(), 7, &s, c).unwrap();
        let splat = sc.splat(&Pose::IDENTITY);
        assert!(splat.iou > 0.85, "splat IoU {}", splat.iou);
        let (mx, my) = sc.mask_centroid;
        let (sx, sy) = splat.centroid.unwrap();
        assert!(
            (mx - sx).hypot(my - sy) < 1.0,
            "centroids {mx},{my} vs {sx},{sy}"
        );
        // Moved 3 cm, the silhouette no longer fits.
        let away = Pose::IDENTITY.shifted(DVec3::new(0.03, 0.0, 0.0));
        assert!(sc.splat(&away).iou < 0.5);
        assert!(sc.render(&Pose::IDENTITY).unwrap().iou > 0.99);
    }
}
