//! Relocalisation: after the simulation, the objects it moved are put at rest where the new image
//! says they are, in whatever pose they ended up (standing, upside down, lying, leaning on or resting
//! on another object).
//!
//! Why: the simulation decides *that* an object falls, but where and how it lands is chaotic, and the
//! paper's very soft material ends up in poses no glass can hold: tilted in mid-fall, a centimetre or
//! two above the table, sagged. One top-down silhouette does not pin a pose down either: a glass
//! tilted by 40° and one lying on its side can cover nearly the same pixels. What does is the
//! silhouette *together with* physics: a real glass is at rest, touching what holds it, with its centre
//! of mass over its contacts.
//!
//! # Which objects
//! The objects the simulation may move (in contact, transitively, with a removed one:
//! [`crate::contact`]) are always searched. Every other object keeps its t = 0 pose unless its
//! rendered silhouette misses its mask ([`Relocalise::below_iou`]), which means the contact analysis
//! was wrong, or it fits its mask much better shifted ([`Object::displaced`]: a falling object
//! knocked it aside). Objects are searched lowest first, each resting on the others as they then are.
//!
//! # Candidates ([`search`])
//! Orientations over the whole sphere of up directions × yaws, each placed under the mask, made
//! physically plausible by quasi-static settling on the table and the other objects ([`support`]),
//! and fitted to the mask; the simulated pose settled the same way; the best of each distinct resting
//! mode and the settled simulated one refined locally (position, yaw, tilt), every pose dropped onto
//! its support; the best of these polished on its rendered score among poses at rest (every move
//! settled, so a standing glass is not left tipped on its base edge). An object rests on its *body*
//! ([`mod@body`]): the surfels that reached into another object's space at t = 0 do not count.
//!
//! # The score
//! Each finalist and the simulated pose itself are rendered ([`silhouette`]) and scored
//!
//! `score = IoU − w_photo · photometric − w_rest · implausibility − w_prior · prior − w_turn · turn
//!          − w_energy · energy`
//!
//! * IoU of the rendered silhouette, its holes filled, with the instance mask (other objects' pixels
//!   not counted against it);
//! * photometric: mean absolute difference of the rendered colours and the new image's inside the mask
//!   (background outside it), over the mask and the silhouette: the refinement's colour loss before
//!   its first step, which tells apart poses with the same outline (upside down, the wrong end
//!   towards the camera);
//! * implausibility: how far the pose floats above or sinks into its support beyond contact, plus how
//!   far its centre of mass overhangs its contacts, in object sizes ([`support::Rest`]);
//! * prior: mean distance from the simulated pose in object sizes, capped: the simulation's outcome
//!   breaks the ties one view leaves (upright or upside down, which way it fell);
//! * turn: how far past lying on its side the pose has turned from the simulated one (0 up to 90°, 1
//!   upside down): a fall tips an object over far more often than it rolls it onto its top, and an
//!   open vessel upside down can cover its mask better than upright when its t = 0 shape lacks the
//!   foot its support hid;
//! * energy: height of the centre of mass above the lowest it can lie, in object sizes: a falling
//!   glass dissipates its energy and ends in a deep resting state far more often than balanced in a
//!   high one, so between poses the image cannot tell apart, the lower one is taken.
//!
//! The best finalist replaces the simulated pose only when its score beats the simulated pose's by
//! [`Relocalise::min_gain`]; the simulated pose is scored with the same terms, so one left floating or
//! tilted in mid-air loses to its own version at rest.

pub mod body;
pub mod pose;
pub mod search;
pub mod silhouette;
pub mod support;

use glam::DVec3;
use trand_core::{Camera, Surfels};
use trand_io::{InstanceMap, Rgb8Image};
use trand_render::{GeometryMaps, Maps, RenderSettings};

pub use pose::Pose;
pub use search::Origin;
pub use silhouette::WORKING_WIDTH;
pub use support::Rest;

use crate::Result;
use body::{Hull, body};
use pose::{Shape, rigid_fit};
use search::{Candidate, FINALISTS, Search};
use silhouette::{Scorer, Target};
use support::Support;

/// Settings of the relocalisation.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Relocalise {
    /// An object the simulation could not move is searched when its silhouette IoU is below this (or
    /// when [`Object::displaced`]).
    pub below_iou: f64,
    /// A found pose replaces the simulated one only when its score is higher by this much.
    pub min_gain: f64,
    /// Sampled up directions (Fibonacci sphere) and yaws per direction.
    pub up_directions: usize,
    pub yaws: usize,
    pub weights: Weights,
}

impl Default for Relocalise {
    fn default() -> Self {
        Self {
            below_iou: 0.5,
            min_gain: 0.02,
            up_directions: 48,
            yaws: 8,
            weights: Weights::default(),
        }
    }
}

/// Weights of the score's terms (the IoU's is 1).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Weights {
    /// The photometric error is a mean over colour channels in `[0, 1]`.
    pub photometric: f64,
    /// A pose floating, sunk in or overhanging by one object size costs as much as the whole IoU.
    pub rest: f64,
    /// Tie-breakers: a pose one object size further from the simulated one, or with its centre of
    /// mass one size higher, needs this much more IoU.
    pub prior: f64,
    pub energy: f64,
    /// A pose turned upside down from the simulated one needs this much more IoU (nothing up to
    /// lying on its side; [`search::FREE_TURN_DEG`]).
    pub turn: f64,
}

impl Default for Weights {
    fn default() -> Self {
        Self {
            photometric: 1.0,
            rest: 1.0,
            prior: 0.05,
            energy: 0.05,
            turn: 0.25,
        }
    }
}

/// Why an object was searched, or not.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Reason {
    /// The simulation could move it: always searched.
    Movable,
    /// The simulation could not move it, but its silhouette misses its mask.
    SilhouetteMiss,
    /// The simulation could not move it, but its silhouette fits its mask far better shifted: it was
    /// knocked aside ([`crate::new_camera::CameraCorrection::displaced`]).
    Displaced,
    /// The simulation could not move it and it is on its mask: kept without a search.
    Static,
}

/// The score of one pose and its terms.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Score {
    pub total: f64,
    pub iou: f64,
    pub photometric: Option<f64>,
    pub rest: Rest,
    pub implausibility: f64,
    pub prior: f64,
    pub turn: f64,
    pub energy: f64,
}

/// A pose as reported, and where it came from.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct PoseReport {
    pub origin: Origin,
    /// Rotation from the t = 0 pose (quaternion `x, y, z, w`) and the move of the surfels' centroid
    /// (m).
    pub rotation_xyzw: [f64; 4],
    pub translation_m: [f64; 3],
    /// Angle between the world vertical and the object's t = 0 vertical (degrees).
    pub tilt_deg: f64,
}

impl PoseReport {
    fn of(origin: Origin, pose: &Pose) -> PoseReport {
        let r = pose.rot;
        PoseReport {
            origin,
            rotation_xyzw: [r.x, r.y, r.z, r.w],
            translation_m: pose.t.to_array(),
            tilt_deg: pose.tilt_deg(),
        }
    }
}

/// What happened to one object.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Relocation {
    pub object_id: u16,
    pub reason: Reason,
    /// Rendered IoU of the simulated pose with the object's mask (working resolution), and of the
    /// pose kept.
    pub iou_before: f64,
    pub iou_after: f64,
    pub moved: bool,
    /// Scores of the simulated pose and of the pose kept, and the pose kept (`None` when not
    /// searched).
    pub score_before: Option<Score>,
    pub score_after: Option<Score>,
    pub chosen: Option<PoseReport>,
    /// The refined finalists, with their scores.
    pub finalists: Vec<Finalist>,
    /// Poses settled, splat silhouettes evaluated, poses rendered.
    pub candidates: usize,
    pub evaluations: usize,
    pub rendered: usize,
}

/// A refined finalist.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Finalist {
    pub pose: PoseReport,
    pub score: Score,
}

/// The new image.
#[derive(Clone, Copy, Debug)]
pub struct NewImage<'a> {
    pub camera: &'a Camera,
    pub instance: &'a InstanceMap,
    pub rgb: Option<&'a Rgb8Image>,
}

/// One object to relocalise: its id, its surfels' indices, and its id in the new instance map.
#[derive(Clone, Debug)]
pub struct Object {
    pub id: u16,
    pub surfels: Vec<u32>,
    pub new_id: u16,
    /// Searched even when the simulation could not move it and its silhouette is on its mask.
    pub displaced: bool,
}

/// Relocalises `objects` in `surfels`. `before` is the scene before the simulation (same surfel order:
/// the undeformed t = 0 shapes); `removed` the removed objects' surfels (at t = 0); `movable` the ids
/// the simulation could move; `ground` the table height.
#[allow(clippy::too_many_arguments)]
pub fn relocalise(
    surfels: &mut Surfels,
    before: &Surfels,
    removed: &[Surfels],
    objects: &[Object],
    movable: &[u16],
    image: &NewImage,
    ground: f64,
    settings: &RenderSettings,
    opts: &Relocalise,
) -> Result<Vec<Relocation>> {
    let target = Target::new(image.camera, image.instance, image.rgb, ground);
    let settings = RenderSettings {
        maps: Maps::Rgb,
        geometry: GeometryMaps::Skipped,
        sh_degree: Some(0),
        ..*settings
    };
    // Static objects first, then the movable ones from the lowest up.
    let height = |o: &Object| {
        o.surfels
            .iter()
            .map(|&i| surfels.means[i as usize][2] as f64)
            .sum::<f64>()
            / o.surfels.len().max(1) as f64
    };
    let mut order: Vec<(bool, f64, usize)> = objects
        .iter()
        .enumerate()
        .map(|(k, o)| (movable.contains(&o.id), height(o), k))
        .collect();
    order.sort_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)));

    let bases: Vec<Surfels> = objects.iter().map(|o| gather(before, &o.surfels)).collect();
    let mut bodies: Option<Vec<Vec<bool>>> = None;
    let mut report = Vec::new();
    for (is_movable, _, k) in order {
        let obj = &objects[k];
        let simulated = gather(surfels, &obj.surfels);
        if simulated.len() < 3 {
            continue;
        }
        let sim_centroid = mean(&simulated.means);
        let Some(mut sim_scorer) =
            Scorer::new(&target, settings, obj.new_id, &simulated, sim_centroid)
        else {
            continue;
        };
        let sim_render = sim_scorer.render(&Pose::IDENTITY)?;
        let reason = if is_movable {
            Reason::Movable
        } else if sim_render.iou < opts.below_iou {
            Reason::SilhouetteMiss
        } else if obj.displaced {
            Reason::Displaced
        } else {
            Reason::Static
        };
        let mut rel = Relocation {
            object_id: obj.id,
            reason,
            iou_before: sim_render.iou,
            iou_after: sim_render.iou,
            moved: false,
            score_before: None,
            score_after: None,
            chosen: None,
            finalists: Vec::new(),
            candidates: 0,
            evaluations: 0,
            rendered: 1,
        };
        if reason == Reason::Static {
            report.push(rel);
            continue;
        }
        let bodies = bodies.get_or_insert_with(|| body_masks(&bases, removed, ground));
        let Some(shape) = Shape::new(&bases[k], &bodies[k]) else {
            report.push(rel);
            continue;
        };
        // The support: the table and every other object where it now is.
        let mut others: Vec<DVec3> = Vec::new();
        for (j, o) in objects.iter().enumerate().filter(|(j, _)| *j != k) {
            if let Some(s) = Shape::new(&gather(surfels, &o.surfels), &bodies[j]) {
                others.extend(s.solid);
            }
        }
        let support = Support::new(ground, &others);
        let prior = rigid_fit(
            &points(&bases[k].means),
            &points(&simulated.means),
            shape.centroid,
        );
        let scorer = Scorer::new(&target, settings, obj.new_id, &bases[k], shape.centroid)
            .expect("the mask was checked non-empty");
        let mut search = Search {
            shape: &shape,
            support: &support,
            scorer,
            prior,
            weights: opts.weights,
            settled: 0,
            rendered: 0,
        };
        let before_score = search.terms(&prior, sim_render.iou, sim_render.photometric);
        let sorted = search.candidates(opts.up_directions, opts.yaws);
        let mut best: Option<(Candidate, Score)> = None;
        for c in search.finalists(&sorted, FINALISTS) {
            let c = search.refine(c);
            let s = search.score(&c.pose)?;
            rel.finalists.push(Finalist {
                pose: PoseReport::of(c.origin, &c.pose),
                score: s,
            });
            if best.is_none_or(|b| s.total > b.1.total) {
                best = Some((c, s));
            }
        }
        let best = match best {
            Some((c, _)) => Some(search.polish(c)?),
            None => None,
        };
        rel.score_before = Some(before_score);
        rel.score_after = Some(before_score);
        rel.chosen = Some(PoseReport::of(Origin::Simulated, &prior));
        if let Some((c, s)) = best
            && s.total >= before_score.total + opts.min_gain
        {
            let placed = search.scorer.place(&c.pose);
            for (j, &i) in obj.surfels.iter().enumerate() {
                surfels.means[i as usize] = placed.means[j];
                surfels.quats[i as usize] = placed.quats[j];
            }
            rel.moved = true;
            rel.iou_after = s.iou;
            rel.score_after = Some(s);
            rel.chosen = Some(PoseReport::of(c.origin, &c.pose));
        }
        rel.candidates = search.settled;
        rel.evaluations = search.scorer.evaluations;
        rel.rendered += search.rendered;
        report.push(rel);
    }
    Ok(report)
}

/// The surfels `idx` of `s`.
fn gather(s: &Surfels, idx: &[u32]) -> Surfels {
    s.gather(&idx.iter().map(|&i| i as usize).collect::<Vec<_>>())
}

fn points(means: &[[f32; 3]]) -> Vec<DVec3> {
    means
        .iter()
        .map(|m| DVec3::new(m[0] as f64, m[1] as f64, m[2] as f64))
        .collect()
}

fn mean(means: &[[f32; 3]]) -> DVec3 {
    points(means).iter().sum::<DVec3>() / means.len().max(1) as f64
}

/// Per object of `bases` (t = 0 surfels), which of its surfels belong to its body ([`mod@body`]), against
/// the hulls of the other objects and of the `removed` ones, over the table at `ground`.
fn body_masks(bases: &[Surfels], removed: &[Surfels], ground: f64) -> Vec<Vec<bool>> {
    let all: Vec<Option<Shape>> = bases
        .iter()
        .chain(removed)
        .map(|s| Shape::new(s, &vec![true; s.len()]))
        .collect();
    let hulls: Vec<Option<Hull>> = all
        .iter()
        .map(|s| s.as_ref().and_then(|s| Hull::of(&s.solid)))
        .collect();
    bases
        .iter()
        .enumerate()
        .map(|(k, base)| match &all[k] {
            None => vec![true; base.len()],
            Some(own) => {
                let others: Vec<Hull> = hulls
                    .iter()
                    .enumerate()
                    .filter(|(j, _)| *j != k)
                    .filter_map(|(_, h)| h.clone())
                    .collect();
                body(&points(&base.means), &own.solid, &others, ground)
            }
        })
        .collect()
}

#[cfg(test)]
mod tests;
