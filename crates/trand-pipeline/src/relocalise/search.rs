//! The pose search of one object: candidates at rest anywhere under its mask, in any orientation,
//! refined locally (see the parent module for how they are judged).
//!
//! * **Sampled**: every orientation of [`super::Relocalise::up_directions`] shape directions turned
//!   upwards × [`super::Relocalise::yaws`] turns about the vertical, the centre of mass placed on the
//!   ray through the mask's centroid at the height it has resting on the table, settled on the support
//!   ([`Support::settle`]: it may topple, or come to rest on or against another object), then shifted so
//!   that its splat silhouette's centroid meets the mask's and dropped again.
//! * **Simulated at rest**: the simulated pose, settled and shifted the same way.
//! * **Refinement** of the best candidate of each resting mode ([`DISTINCT_DEG`], at most
//!   [`FINALISTS`]) and of the simulated one at rest: a pattern search over `(x, y, yaw, tilt about x,
//!   tilt about y)` (± one step per coordinate, keep any improvement, halve the steps when nothing
//!   improves), every move dropped onto the support, on the cheap objective; then settled and searched
//!   once more over `(x, y, yaw)`.
//! * **Polish** of the best finalist: the same pattern search with smaller steps ([`POLISH_STEPS`]) on
//!   the rendered score, every move *settled* rather than dropped. The pose kept must be one the object
//!   can hold: a glass standing on its base, tipped a few degrees about its edge, still touches the
//!   support within [`super::support::CONTACT_M`] over most of its base and so costs nothing in
//!   implausibility, and where its t = 0 shape is a little off (a base its support hid) such a tip can
//!   fit the mask better; settling stands it back up (or lets it lean or fall where it would), so the
//!   rendered score only ever compares resting poses.
//!
//! The cheap objective is the score with the splat silhouette's IoU and without the photometric term
//! (which needs a render): `IoU_splat − w_rest · implausibility − w_prior · prior − w_turn · turn
//! − w_energy · energy`.
//! The splat and the render disagree by a few pixels, which is what the polish corrects.

use glam::{DQuat, DVec3};

use super::pose::{Pose, Shape, orientation, sphere};
use super::silhouette::Scorer;
use super::support::Support;
use super::{Score, Weights};
use crate::Result;

/// Refinement steps: 2 cm on the table, 15° of yaw, 10° of tilt; halved per level.
pub const STEPS: (f64, f64, f64) = (0.02, 15.0, 10.0);
pub const LEVELS: u32 = 4;
/// Polish steps (4 mm, 4°, 3°) and levels.
pub const POLISH_STEPS: (f64, f64, f64) = (0.004, 4.0, 3.0);
pub const POLISH_LEVELS: u32 = 2;
/// Rounds of moves per pattern-search level at most (refinement, polish).
const MAX_ROUNDS: (usize, usize) = (40, 3);
/// Distinct resting modes searched locally at most (besides the simulated pose at rest).
pub const FINALISTS: usize = 4;
/// Finalists differ in which direction of the shape points up by at least this much (degrees): the
/// best of each resting mode (upright, upside down, lying on one side or another) goes on, whatever
/// its yaw and position, which the refinement settles.
pub const DISTINCT_DEG: f64 = 25.0;
/// The prior saturates at this many object sizes from the simulated pose.
pub const PRIOR_CAP: f64 = 2.0;
/// Turning further than this from the simulated pose's vertical costs the turn term (degrees): a
/// fall tips an object over (up to lying, 90°) far more often than it rolls it onto its top.
pub const FREE_TURN_DEG: f64 = 90.0;

/// The turn term: how far past [`FREE_TURN_DEG`] the object's t = 0 vertical has turned from where
/// it points in `simulated`, as a fraction of the remaining 90° (0 up to lying, 1 upside down).
pub fn turn_past_lying(pose: &Pose, simulated: &Pose) -> f64 {
    let up = |p: &Pose| p.rot * glam::DVec3::Z;
    let deg = up(pose)
        .dot(up(simulated))
        .clamp(-1.0, 1.0)
        .acos()
        .to_degrees();
    ((deg - FREE_TURN_DEG) / (180.0 - FREE_TURN_DEG)).max(0.0)
}

/// Where a candidate came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Origin {
    /// The simulated pose as it is.
    Simulated,
    /// The simulated pose settled on the support and fitted to the mask.
    SimulatedAtRest,
    /// A sampled orientation settled under the mask.
    Sampled,
}

#[derive(Clone, Copy, Debug)]
pub struct Candidate {
    pub origin: Origin,
    pub pose: Pose,
    /// Cheap objective.
    pub objective: f64,
}

/// How a pattern search puts each moved pose back on the support.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Placement {
    /// Lowered onto whatever is below it ([`Support::drop`]).
    Drop,
    /// Brought to rest ([`Support::settle`]): a tilt the object cannot hold is undone.
    Settle,
}

/// Which coordinates a pattern search moves.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Dofs {
    /// `x, y, yaw`: an object at rest on the table stays at rest.
    Table,
    /// Also the tilt about the world x and y axes.
    Tilt,
}

/// One object's search.
pub struct Search<'a, 'b> {
    pub shape: &'a Shape,
    pub support: &'a Support,
    pub scorer: Scorer<'b>,
    /// The simulated pose.
    pub prior: Pose,
    pub weights: Weights,
    /// Poses settled (candidates tried) and rendered.
    pub settled: usize,
    pub rendered: usize,
}

impl Search<'_, '_> {
    /// The prior term: distance from the simulated pose in object sizes, capped.
    fn prior_term(&self, pose: &Pose) -> f64 {
        (self.shape.distance(pose, &self.prior) / self.shape.size).min(PRIOR_CAP)
    }

    fn turn_term(&self, pose: &Pose) -> f64 {
        turn_past_lying(pose, &self.prior)
    }

    /// The score of `pose` given its rendered IoU and photometric error.
    pub fn terms(&self, pose: &Pose, iou: f64, photometric: Option<f64>) -> Score {
        let rest = self.support.rest(self.shape, pose);
        let implausibility = rest.implausibility(self.shape.size);
        let prior = self.prior_term(pose);
        let turn = self.turn_term(pose);
        let energy = self.shape.energy(pose, self.support.ground());
        let w = &self.weights;
        Score {
            total: iou
                - w.photometric * photometric.unwrap_or(1.0)
                - w.rest * implausibility
                - w.prior * prior
                - w.turn * turn
                - w.energy * energy,
            iou,
            photometric,
            rest,
            implausibility,
            prior,
            turn,
            energy,
        }
    }

    /// The rendered score of `pose`.
    pub fn score(&mut self, pose: &Pose) -> Result<Score> {
        self.rendered += 1;
        let r = self.scorer.render(pose)?;
        Ok(self.terms(pose, r.iou, r.photometric))
    }

    /// The cheap objective of `pose`.
    fn objective(&mut self, pose: &Pose) -> f64 {
        let iou = self.scorer.splat(pose).iou;
        let rest = self.support.rest(self.shape, pose);
        iou - self.weights.rest * rest.implausibility(self.shape.size)
            - self.weights.prior * self.prior_term(pose)
            - self.weights.turn * self.turn_term(pose)
            - self.weights.energy * self.shape.energy(pose, self.support.ground())
    }

    /// `pose` dropped, shifted twice so that its splat silhouette's centroid meets the mask's, dropped.
    fn fit_to_mask(&mut self, pose: &Pose) -> Pose {
        let mut pose = self.support.drop(self.shape, pose);
        let cam = self.scorer.target_camera();
        for _ in 0..2 {
            let Some((sx, sy)) = self.scorer.splat(&pose).centroid else {
                break;
            };
            let (mx, my) = self.scorer.mask_centroid;
            let com = self.shape.com_at(&pose);
            let Some((u, v, _)) = cam.project(com) else {
                break;
            };
            let Some(to) = ray_at_height(&cam, u + mx - sx, v + my - sy, com.z) else {
                break;
            };
            pose = self.support.drop(
                self.shape,
                &pose.shifted(DVec3::new(to.x - com.x, to.y - com.y, 0.0)),
            );
        }
        pose
    }

    /// The sampled candidates and the simulated pose at rest, best first.
    pub fn candidates(&mut self, up_directions: usize, yaws: usize) -> Vec<Candidate> {
        let shape = self.shape;
        let ground = self.support.ground();
        let cam = self.scorer.target_camera();
        let (mx, my) = self.scorer.mask_centroid;
        let mut out = Vec::new();
        for up in sphere(up_directions) {
            for k in 0..yaws {
                let rot = orientation(up, k as f64 * std::f64::consts::TAU / yaws as f64);
                // The centre of mass at its height resting on the table, on the mask centroid's ray.
                let lowest = shape
                    .solid
                    .iter()
                    .map(|&p| (rot * (p - shape.centroid)).z)
                    .fold(f64::INFINITY, f64::min);
                let com_rel = rot * (shape.com - shape.centroid);
                let Some(at) = ray_at_height(&cam, mx, my, ground + com_rel.z - lowest) else {
                    continue;
                };
                let pose = Pose {
                    rot,
                    t: at - com_rel - shape.centroid,
                };
                let pose = self.support.settle(shape, &pose);
                self.settled += 1;
                let pose = self.fit_to_mask(&pose);
                let objective = self.objective(&pose);
                out.push(Candidate {
                    origin: Origin::Sampled,
                    pose,
                    objective,
                });
            }
        }
        let at_rest = self.support.settle(shape, &self.prior);
        self.settled += 1;
        let pose = self.fit_to_mask(&at_rest);
        let objective = self.objective(&pose);
        out.push(Candidate {
            origin: Origin::SimulatedAtRest,
            pose,
            objective,
        });
        out.sort_by(|a, b| b.objective.total_cmp(&a.objective));
        out
    }

    /// The best `n` of `sorted` in pairwise distinct resting modes ([`DISTINCT_DEG`]), plus the
    /// simulated one at rest.
    pub fn finalists(&self, sorted: &[Candidate], n: usize) -> Vec<Candidate> {
        let up = |c: &Candidate| c.pose.rot.inverse() * DVec3::Z;
        let cos = DISTINCT_DEG.to_radians().cos();
        let mut keep: Vec<Candidate> = Vec::new();
        for c in sorted {
            if keep.len() < n && keep.iter().all(|k| up(k).dot(up(c)) < cos) {
                keep.push(*c);
            }
        }
        if let Some(s) = sorted.iter().find(|c| c.origin == Origin::SimulatedAtRest)
            && !keep.iter().any(|k| k.origin == Origin::SimulatedAtRest)
        {
            keep.push(*s);
        }
        keep
    }

    /// Local refinement of a candidate on the cheap objective (module doc).
    pub fn refine(&mut self, c: Candidate) -> Candidate {
        let cheap = |s: &mut Self, p: &Pose| Ok(s.objective(p));
        let (pose, _) = self
            .pattern(
                c.pose,
                STEPS,
                LEVELS,
                MAX_ROUNDS.0,
                (Dofs::Tilt, Placement::Drop),
                cheap,
            )
            .expect("the cheap objective does not fail");
        let settled = self.support.settle(self.shape, &pose);
        self.settled += 1;
        let (pose, objective) = self
            .pattern(
                settled,
                STEPS,
                2,
                MAX_ROUNDS.0,
                (Dofs::Table, Placement::Drop),
                cheap,
            )
            .expect("the cheap objective does not fail");
        Candidate {
            origin: c.origin,
            pose,
            objective,
        }
    }

    /// The polish of a candidate on the rendered score; returns it with its score.
    pub fn polish(&mut self, c: Candidate) -> Result<(Candidate, Score)> {
        let rendered = |s: &mut Self, p: &Pose| s.score(p).map(|x| x.total);
        let start = self.support.settle(self.shape, &c.pose);
        let (pose, _) = self.pattern(
            start,
            POLISH_STEPS,
            POLISH_LEVELS,
            MAX_ROUNDS.1,
            (Dofs::Tilt, Placement::Settle),
            rendered,
        )?;
        let score = self.score(&pose)?;
        Ok((Candidate { pose, ..c }, score))
    }

    /// Pattern search from `start`, `levels` step sizes from `steps` (metres, degrees, degrees) down,
    /// maximising `f`.
    fn pattern(
        &mut self,
        start: Pose,
        steps: (f64, f64, f64),
        levels: u32,
        rounds: usize,
        (dofs, placement): (Dofs, Placement),
        mut f: impl FnMut(&mut Self, &Pose) -> Result<f64>,
    ) -> Result<(Pose, f64)> {
        let mut best_f = f(self, &start)?;
        let mut best = start;
        let (mut step, mut yaw, mut tilt) = (steps.0, steps.1.to_radians(), steps.2.to_radians());
        let moves = match dofs {
            Dofs::Table => 6,
            Dofs::Tilt => 10,
        };
        for _ in 0..levels {
            for _ in 0..rounds {
                let mut improved = false;
                for mv in 0..moves {
                    let sign = if mv % 2 == 0 { 1.0 } else { -1.0 };
                    let com = self.shape.com_at(&best);
                    let c = self.shape.centroid;
                    let p = match mv / 2 {
                        0 => best.shifted(DVec3::new(sign * step, 0.0, 0.0)),
                        1 => best.shifted(DVec3::new(0.0, sign * step, 0.0)),
                        2 => best.turned(c, DQuat::from_rotation_z(sign * yaw), com),
                        3 => best.turned(c, DQuat::from_rotation_x(sign * tilt), com),
                        _ => best.turned(c, DQuat::from_rotation_y(sign * tilt), com),
                    };
                    let p = match placement {
                        Placement::Drop => self.support.drop(self.shape, &p),
                        Placement::Settle => self.support.settle(self.shape, &p),
                    };
                    let v = f(self, &p)?;
                    if v > best_f {
                        (best, best_f, improved) = (p, v, true);
                    }
                }
                if !improved {
                    break;
                }
            }
            step *= 0.5;
            yaw *= 0.5;
            tilt *= 0.5;
        }
        Ok((best, best_f))
    }
}

/// Where the ray through pixel `(u, v)` reaches the height `z` (`None`: parallel or behind).
pub fn ray_at_height(cam: &trand_core::Camera, u: f64, v: f64, z: f64) -> Option<DVec3> {
    let (eye, dir) = (cam.center(), cam.ray_direction(u, v));
    if dir.z.abs() < 1e-6 {
        return None;
    }
    let s = (z - eye.z) / dir.z;
    (s > 0.0).then(|| eye + s * dir)
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{DQuat, DVec3};

    fn turned(axis: DVec3, deg: f64) -> Pose {
        Pose {
            rot: DQuat::from_axis_angle(axis, deg.to_radians()),
            t: DVec3::new(0.01, -0.02, 0.03),
        }
    }

    #[test]
    fn turning_up_to_lying_is_free_and_upside_down_costs_one() {
        let upright = Pose::IDENTITY;
        for (deg, want) in [
            (0.0, 0.0),
            (60.0, 0.0),
            (90.0, 0.0),
            (135.0, 0.5),
            (180.0, 1.0),
        ] {
            let t = turn_past_lying(&turned(DVec3::X, deg), &upright);
            assert!((t - want).abs() < 1e-9, "{deg}°: {t}, want {want}");
        }
        // A yaw about the vertical is no turn at all.
        assert!(turn_past_lying(&turned(DVec3::Z, 170.0), &upright).abs() < 1e-12);
    }

    #[test]
    fn the_turn_is_measured_from_the_simulated_pose_not_the_world() {
        // Simulated lying on its side: lying on the other side is a half turn past lying, upright is free.
        let lying = turned(DVec3::Y, 90.0);
        assert!(turn_past_lying(&Pose::IDENTITY, &lying).abs() < 1e-9);
        let other_side = turned(DVec3::Y, -90.0);
        assert!((turn_past_lying(&other_side, &lying) - 1.0).abs() < 1e-9);
    }
}
