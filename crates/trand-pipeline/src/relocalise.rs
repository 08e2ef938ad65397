//! Silhouette relocalisation: after the simulation, an object whose rendered silhouette in the new
//! image misses its instance mask is moved rigidly to where the mask says it is.
//!
//! Why: the simulation decides *that* an object falls, but where a toppling glass ends up (which way it
//! tips, how far it rolls) is chaotic; on the synthetic benchmark a third of the objects that fell
//! landed 5–10 cm from the simulated pose, their t = 1 depth then covered almost none of their pixels,
//! and 100 refinement iterations cannot move surfels that far. The new image's instance mask shows
//! where the object is; this step searches the rigid poses an object resting on the table can take.
//!
//! # The search (per object with a matched mask)
//! Silhouettes are taken from the new camera at a working resolution of at most
//! [`WORKING_WIDTH`] pixels across, the object's surfels alone (rendered: `α > ½`). The score is the IoU with the
//! mask, where silhouette pixels on *other* objects' masks are not counted as false positives (the
//! object may be behind them).
//! 1. Score the simulated pose. At or above [`Relocalise::below_iou`] nothing is done.
//! 2. Candidates: the simulated pose; and the t = 0 (undeformed) shape upright, upside down, and
//!    tipped over by 90° towards each of [`TIP_DIRECTIONS`] directions, each lowered onto the table
//!    (its lowest surfels, the [`REST_PERCENTILE`] of their heights, at the ground height). Each is
//!    placed so that its centroid lies on the ray through the mask's centroid, at the centroid's
//!    height above the table.
//! 3. Pattern search over `(x, y, yaw)` on the table: try ± one step on each coordinate, keep any
//!    improvement, halve the steps when nothing improves ([`STEPS`], [`LEVELS`] levels). The search
//!    scores a *splat* silhouette (each surfel a disc around its projected centre), two orders of
//!    magnitude cheaper than a render: every candidate gets the coarsest level, the best
//!    [`FINALISTS`] and the simulated pose all levels.
//! 4. The finalists and the searched simulated pose are rendered; the best replaces the simulated
//!    pose when its IoU beats the simulated pose's by [`Relocalise::min_gain`].

use glam::{DQuat, DVec3, Quat};
use trand_core::{Camera, Surfels};
use trand_io::InstanceMap;
use trand_render::{GeometryMaps, Maps, RenderSettings, render};

use crate::Result;
use crate::detect::mask_centroid;
use crate::simulate::turn;

/// Widest silhouette image the search renders (pixels): 160 px across a 640 px view is 3–4 mm per
/// pixel at the benchmark distance (0.5 m), finer than what the refinement afterwards corrects.
pub const WORKING_WIDTH: u32 = 200;
/// Directions in which a tipped-over object can lie (every 30°).
pub const TIP_DIRECTIONS: usize = 12;
/// Heights below this percentile of an object's surfels are taken as stray (floaters) when setting
/// it down on the table.
pub const REST_PERCENTILE: f64 = 0.02;
/// Initial pattern-search steps: 2 cm on the table, 15° of yaw; four levels, down to 2.5 mm and ~2°.
pub const STEPS: (f64, f64) = (0.02, 15.0);
const LEVELS: u32 = 4;
/// The best this many candidates after the coarse level are searched to the finest level.
const FINALISTS: usize = 3;
/// Splat silhouette: a surfel's disc radius is this many of its larger standard deviations (the 2DGS
/// cut-off is 3σ at α = 1/255; ~2σ is where a typical surfel's α falls below the ½ of the rendered
/// silhouette), at most [`SPLAT_MAX_RADIUS_PX`] pixels; surfels with opacity below sigmoid(−3) ≈ 5 %
/// do not count.
const SPLAT_SIGMAS: f64 = 2.0;
const SPLAT_MAX_RADIUS_PX: f64 = 3.0;
const SPLAT_MIN_OPACITY_LOGIT: f32 = -3.0;

/// Settings of the relocalisation.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Relocalise {
    /// Objects whose simulated silhouette reaches this IoU with their mask are left alone.
    pub below_iou: f64,
    /// A found pose is used only when it beats the simulated pose's IoU by this much.
    pub min_gain: f64,
}

impl Default for Relocalise {
    fn default() -> Self {
        Self {
            below_iou: 0.5,
            min_gain: 0.1,
        }
    }
}

/// What happened to one object.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Relocation {
    pub object_id: u16,
    /// IoU of the simulated pose with the object's mask (working resolution).
    pub iou_before: f64,
    /// IoU of the pose kept.
    pub iou_after: f64,
    /// Whether the object was moved.
    pub moved: bool,
    /// Splat silhouettes evaluated by the search.
    pub evaluations: usize,
}

/// A rigid pose of one object: `p ↦ R (p − c) + c + t` with `c` the base shape's centroid.
#[derive(Clone, Copy, Debug)]
struct Pose {
    rot: DQuat,
    t: DVec3,
}

/// The silhouette scorer for one object in the new view.
struct Scorer<'a> {
    camera: Camera,
    settings: RenderSettings,
    /// Object mask and pixels of other objects, at the working resolution.
    mask: Vec<bool>,
    others: Vec<bool>,
    mask_size: usize,
    base: &'a Surfels,
    centroid: DVec3,
    /// Footprint radius (world units) of each base surfel that counts for the splat silhouette
    /// (`None`: too transparent to count).
    radius: Vec<Option<f64>>,
    /// Scratch silhouette of [`Self::splat_score`].
    hit: Vec<bool>,
    evaluations: usize,
}

impl<'a> Scorer<'a> {
    #[allow(clippy::too_many_arguments)]
    fn new(
        camera: Camera,
        settings: RenderSettings,
        mask: Vec<bool>,
        others: Vec<bool>,
        base: &'a Surfels,
    ) -> Self {
        let v = |a: [f32; 3]| DVec3::new(a[0] as f64, a[1] as f64, a[2] as f64);
        let centroid = base.means.iter().map(|&m| v(m)).sum::<DVec3>() / base.len().max(1) as f64;
        let radius = base
            .log_scales
            .iter()
            .zip(&base.opacity_logits)
            .map(|(s, &o)| {
                (o > SPLAT_MIN_OPACITY_LOGIT).then(|| SPLAT_SIGMAS * s[0].max(s[1]).exp() as f64)
            })
            .collect();
        let mask_size = mask.iter().filter(|&&b| b).count();
        let hit = vec![false; mask.len()];
        Self {
            camera,
            settings,
            mask,
            others,
            mask_size,
            base,
            centroid,
            radius,
            hit,
            evaluations: 0,
        }
    }

    fn place(&self, pose: &Pose) -> Surfels {
        let mut s = self.base.clone();
        let rf = Quat::from_xyzw(
            pose.rot.x as f32,
            pose.rot.y as f32,
            pose.rot.z as f32,
            pose.rot.w as f32,
        );
        for m in &mut s.means {
            let p = self.transform(pose, *m);
            *m = [p.x as f32, p.y as f32, p.z as f32];
        }
        for q in &mut s.quats {
            *q = turn(rf, *q);
        }
        s
    }

    fn transform(&self, pose: &Pose, m: [f32; 3]) -> DVec3 {
        pose.rot * (DVec3::new(m[0] as f64, m[1] as f64, m[2] as f64) - self.centroid)
            + self.centroid
            + pose.t
    }

    /// IoU of a silhouette with the mask, pixels of other objects ignored as false positives.
    fn iou(&self, silhouette: impl Iterator<Item = bool>) -> f64 {
        let (mut inter, mut extra) = (0usize, 0usize);
        for (p, s) in silhouette.enumerate() {
            if s {
                if self.mask[p] {
                    inter += 1;
                } else if !self.others[p] {
                    extra += 1;
                }
            }
        }
        inter as f64 / (self.mask_size + extra).max(1) as f64
    }

    /// IoU of the rendered silhouette (`α > ½`): the measure decisions are taken on.
    fn render_score(&mut self, pose: &Pose) -> Result<f64> {
        let out = render::<f32, _>(&self.place(pose), &self.camera, &self.settings)?;
        Ok(self.iou(out.alpha.iter().map(|&a| a > 0.5)))
    }

    /// IoU of the splat silhouette: each surfel a disc of its footprint radius around its projected
    /// centre. Two orders of magnitude cheaper than a render, which is what makes the search affordable.
    fn splat_score(&mut self, pose: &Pose) -> f64 {
        self.evaluations += 1;
        let k = self.camera.intrinsics;
        let (w, h) = (k.width as i64, k.height as i64);
        let mut hit = std::mem::take(&mut self.hit);
        hit.fill(false);
        for (m, r) in self.base.means.iter().zip(&self.radius) {
            let Some(r) = r else { continue };
            let Some((x, y, z)) = self.camera.project(self.transform(pose, *m)) else {
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
            for py in y0..=y1 {
                for px in x0..=x1 {
                    if (px as f64 - x).powi(2) + (py as f64 - y).powi(2) <= rp * rp {
                        hit[(py * w + px) as usize] = true;
                    }
                }
            }
        }
        let iou = self.iou(hit.iter().copied());
        self.hit = hit;
        iou
    }

    /// Pattern search over `(x, y, yaw)` from `start` on the splat score; `levels` step sizes from
    /// [`STEPS`] down. Returns the best pose and its splat IoU.
    fn search(&mut self, start: Pose, levels: u32) -> (Pose, f64) {
        let (mut best, mut best_iou) = (start, self.splat_score(&start));
        let (mut step, mut yaw) = (STEPS.0, STEPS.1.to_radians());
        for _ in 0..levels {
            loop {
                let mut improved = false;
                for mv in 0..6 {
                    let sign = if mv % 2 == 0 { 1.0 } else { -1.0 };
                    let mut p = best;
                    match mv / 2 {
                        0 => p.t.x += sign * step,
                        1 => p.t.y += sign * step,
                        _ => p.rot = DQuat::from_rotation_z(sign * yaw) * p.rot,
                    }
                    let iou = self.splat_score(&p);
                    if iou > best_iou {
                        (best, best_iou, improved) = (p, iou, true);
                    }
                }
                if !improved {
                    break;
                }
            }
            step *= 0.5;
            yaw *= 0.5;
        }
        (best, best_iou)
    }
}

/// Downsamples an instance map by an integer factor: each block takes its most frequent id.
fn downsample_ids(inst: &InstanceMap, f: u32, width: u32, height: u32) -> Vec<u16> {
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

/// The `q`-quantile of `v` (sorted copy).
fn quantile(v: &[f64], q: f64) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    s[((s.len() - 1) as f64 * q).round() as usize]
}

/// Relocalises the objects of `surfels` (their members given by `objects`: object id, the surfel
/// indices, and the new instance id of the object in `inst`). `before` is the scene before the
/// simulation (same surfel order: the undeformed t = 0 shapes); `ground` is the table height.
#[allow(clippy::too_many_arguments)]
pub fn relocalise(
    surfels: &mut Surfels,
    before: &Surfels,
    objects: &[(u16, Vec<u32>, u16)],
    camera: &Camera,
    inst: &InstanceMap,
    ground: f64,
    settings: &RenderSettings,
    opts: &Relocalise,
) -> Result<Vec<Relocation>> {
    let f = inst.width.div_ceil(WORKING_WIDTH).max(1);
    let camera = Camera {
        intrinsics: camera.intrinsics.scaled(1.0 / f as f64),
        ..*camera
    };
    let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
    let ids = downsample_ids(inst, f, w, h);
    let settings = RenderSettings {
        maps: Maps::Rgb,
        geometry: GeometryMaps::Skipped,
        sh_degree: Some(0),
        ..*settings
    };
    let identity = Pose {
        rot: DQuat::IDENTITY,
        t: DVec3::ZERO,
    };
    let mut report = Vec::new();
    for (object_id, idx, new_id) in objects {
        let mask: Vec<bool> = ids.iter().map(|i| i == new_id).collect();
        let others: Vec<bool> = ids.iter().map(|i| *i != 0 && i != new_id).collect();
        if idx.len() < 3 || !mask.contains(&true) {
            continue;
        }
        let idx_us: Vec<usize> = idx.iter().map(|&i| i as usize).collect();

        // 1. The simulated pose, and the best pose near it.
        let simulated = surfels.gather(&idx_us);
        let mut sim = Scorer::new(camera, settings, mask.clone(), others.clone(), &simulated);
        let iou_before = sim.render_score(&identity)?;
        if iou_before >= opts.below_iou {
            report.push(Relocation {
                object_id: *object_id,
                iou_before,
                iou_after: iou_before,
                moved: false,
                evaluations: 0,
            });
            continue;
        }
        let (sim_pose, _) = sim.search(identity, LEVELS);

        // 2. Undeformed candidates resting on the table, each placed on the mask centroid's ray.
        let rest = before.gather(&idx_us);
        let mut tip = Scorer::new(camera, settings, mask.clone(), others, &rest);
        let c0 = tip.centroid;
        let (mx, my) = mask_centroid(&mask, w as usize).expect("mask checked non-empty");
        let (eye, dir) = (camera.center(), camera.ray_direction(mx, my));
        let mut rotations = vec![
            DQuat::IDENTITY,
            DQuat::from_rotation_x(std::f64::consts::PI),
        ];
        for k in 0..TIP_DIRECTIONS {
            let a = k as f64 * std::f64::consts::TAU / TIP_DIRECTIONS as f64;
            rotations.push(DQuat::from_axis_angle(
                DVec3::new(a.cos(), a.sin(), 0.0),
                std::f64::consts::FRAC_PI_2,
            ));
        }
        let v = |a: [f32; 3]| DVec3::new(a[0] as f64, a[1] as f64, a[2] as f64);
        let mut coarse: Vec<(Pose, f64)> = rotations
            .into_iter()
            .map(|rot| {
                // Lower onto the table: the rotated shape's low heights at the ground.
                let heights: Vec<f64> = rest.means.iter().map(|&m| (rot * (v(m) - c0)).z).collect();
                let cz = ground - quantile(&heights, REST_PERCENTILE);
                let mut t = DVec3::new(0.0, 0.0, cz - c0.z);
                let s = (cz - eye.z) / dir.z;
                if dir.z.abs() > 1e-6 && s > 0.0 {
                    let hit = eye + s * dir;
                    (t.x, t.y) = (hit.x - c0.x, hit.y - c0.y);
                }
                tip.search(Pose { rot, t }, 1)
            })
            .collect();
        // 3. The finalists to the finest level, judged on their rendered silhouettes.
        coarse.sort_by(|a, b| b.1.total_cmp(&a.1));
        let mut rest_best: Option<(Pose, f64)> = None;
        for c in coarse.iter().take(FINALISTS) {
            let (pose, _) = tip.search(c.0, LEVELS);
            let iou = tip.render_score(&pose)?;
            if rest_best.is_none_or(|b| iou > b.1) {
                rest_best = Some((pose, iou));
            }
        }
        let (rest_pose, rest_iou) = rest_best.expect("at least one candidate");

        // 4. Decide on rendered silhouettes.
        let sim_iou = sim.render_score(&sim_pose)?;
        let evaluations = sim.evaluations + tip.evaluations;
        let chosen = if rest_iou >= sim_iou {
            (&tip, rest_pose, rest_iou)
        } else {
            (&sim, sim_pose, sim_iou)
        };
        let moved = chosen.2 >= iou_before + opts.min_gain;
        if moved {
            let placed = chosen.0.place(&chosen.1);
            for (k, &i) in idx_us.iter().enumerate() {
                surfels.means[i] = placed.means[k];
                surfels.quats[i] = placed.quats[k];
            }
        }
        let iou_after = if moved { chosen.2 } else { iou_before };
        report.push(Relocation {
            object_id: *object_id,
            iou_before,
            iou_after,
            moved,
            evaluations,
        });
    }
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_scene::{HEIGHT, RADIUS, camera, cylinder};
    use glam::Vec3;

    /// The instance map (id 7) of `s` seen from `camera()`, with another object's pixels (id 9) in a corner.
    fn mask_of(s: &Surfels) -> InstanceMap {
        let out = render::<f32, _>(s, &camera(), &RenderSettings::default()).unwrap();
        let mut data: Vec<u16> = out
            .alpha
            .iter()
            .map(|&a| if a > 0.5 { 7 } else { 0 })
            .collect();
        data[..10].fill(9);
        InstanceMap::from_vec(200, 150, 1, data).unwrap()
    }

    fn centroid(s: &Surfels) -> Vec3 {
        s.means.iter().map(|&m| Vec3::from_array(m)).sum::<Vec3>() / s.len() as f32
    }

    fn run(s: &mut Surfels, inst: &InstanceMap) -> Relocation {
        let before = s.clone();
        let idx: Vec<u32> = (0..s.len() as u32).collect();
        let mut r = relocalise(
            s,
            &before,
            &[(1, idx, 7)],
            &camera(),
            inst,
            0.0,
            &RenderSettings::default(),
            &Relocalise::default(),
        )
        .unwrap();
        r.pop().unwrap()
    }

    #[test]
    fn a_glass_that_tipped_over_and_rolled_is_moved_onto_its_mask() {
        // Truth: tipped over towards 40° (between two of the 12 tried directions) and 9 cm away.
        let truth_pose = Pose {
            rot: DQuat::from_axis_angle(
                DVec3::new(40f64.to_radians().cos(), 40f64.to_radians().sin(), 0.0),
                std::f64::consts::FRAC_PI_2,
            ),
            t: DVec3::new(0.07, 0.05, RADIUS as f64 - HEIGHT as f64 / 2.0),
        };
        let upright = cylinder(0.0, 0.0, 0);
        let sc = Scorer::new(
            camera(),
            RenderSettings::default(),
            vec![],
            vec![],
            &upright,
        );
        let truth = sc.place(&truth_pose);
        let mut s = upright.clone();
        let r = run(&mut s, &mask_of(&truth));
        assert!(r.moved && r.iou_before < 0.1, "{r:?}");
        assert!(r.iou_after > 0.8, "{r:?}");
        let err = (centroid(&s) - centroid(&truth)).length();
        assert!(err < 0.01, "centroid {err} m from the truth");
        let lowest = s.means.iter().map(|m| m[2]).fold(f32::INFINITY, f32::min);
        assert!(
            lowest.abs() < 0.006,
            "lowest surfel at z = {lowest} (table at 0)"
        );
    }

    #[test]
    fn a_glass_on_its_mask_is_left_where_it_is() {
        let mut s = cylinder(0.02, 0.01, 0);
        let inst = mask_of(&s);
        let before = s.means.clone();
        let r = run(&mut s, &inst);
        assert!(
            !r.moved && r.iou_before > 0.9 && r.evaluations == 0,
            "{r:?}"
        );
        assert_eq!(before, s.means);
    }

    #[test]
    fn a_block_majority_decides_a_downsampled_id() {
        let inst = InstanceMap::from_vec(4, 2, 1, vec![1, 1, 0, 2, 1, 0, 2, 2]).unwrap();
        assert_eq!(downsample_ids(&inst, 2, 2, 1), vec![1, 2]);
    }
}
