//! Step 1 of the scene update: which t = 0 objects are in the new image, and which were removed.
//!
//! Two rules ([`Identity`]). When the new mask's instance ids are t = 0 object ids (the contract the
//! t = 0 views already meet: one id per object across all views, which the authors get by propagating
//! SAM2 masks from frame to frame), a t = 0 object missing from the new mask was removed: the authors'
//! rule with their off-by-count bug fixed (notes §5.1). For per-image ids, notes §10 row 3: the t = 0
//! object map is rendered from the new view and the new mask's instances are assigned to the rendered
//! objects with the Hungarian method on the cost `1 − IoU + w·(centroid distance / image diagonal)`;
//! objects left without an instance were removed. Overlap alone cannot tell which object went when one
//! stood on another and fell off it after the removal (the fallen object overlaps the removed one's
//! old place better than its own), which is why ids win when the mask has them. Without ids, physics
//! breaks the tie (`assign_by_overlap`): every choice of removed objects is tried, and under each the
//! objects it could move (in contact with a removed one, [`crate::contact::may_move`], and not standing
//! on the table by themselves) cost at most [`MOVED_COST`], since their t = 0 place says nothing of
//! where they are now; an object nothing moved must be found where it stood. With `Auto`, ids that
//! merely lie among the t = 0 ids are not trusted when two or more instances contradict the rendered
//! objects (see [`contradicted`]); the CLI also takes overlap when the t = 0 run had to associate its
//! training masks, since the same segmenter made the new mask.

use trand_core::Surfels;
use trand_core::matching::{hungarian, iou};
use trand_io::View;
use trand_render::{Maps, RenderSettings, render};

use crate::{PipelineError, Result};

pub use crate::associate::Identity;

/// One t = 0 object and what it matched in the new image.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Match {
    pub object_id: u16,
    pub channel: usize,
    /// Instance id in the new mask, if matched.
    pub new_id: Option<u16>,
    pub iou: f64,
    /// Matched by overlap as an object the removal could have moved, so its t = 0 place was not
    /// required of it (see the module docs).
    pub may_have_moved: bool,
}

/// Step 1: finds each t = 0 object among the new instances (by id or by overlap, see [`Identity`]);
/// returns the matches and the rule used (`Auto` resolved). The IoU of every match is reported.
pub fn detect(
    surfels: &Surfels,
    channels: &[(u16, usize)],
    view: &View,
    settings: &RenderSettings,
    centroid_weight: f64,
    identity: Identity,
    movable_if: &dyn Fn(&[u16]) -> Vec<u16>,
) -> Result<(Vec<Match>, Identity)> {
    let inst = view.instance.as_ref().ok_or_else(|| PipelineError::View {
        view: view.name.clone(),
        what: "no instance mask".into(),
    })?;
    let out = render::<f32, _>(
        surfels,
        &view.camera,
        &RenderSettings {
            maps: Maps::RgbObjects,
            ..*settings
        },
    )?;
    if (out.width, out.height) != (inst.width, inst.height) {
        return Err(PipelineError::View {
            view: view.name.clone(),
            what: format!(
                "mask is {}x{} but the camera renders {}x{}",
                inst.width, inst.height, out.width, out.height
            ),
        });
    }
    let k = out.num_objects;
    let n = out.alpha.len();
    let rendered: Vec<Vec<bool>> = channels
        .iter()
        .map(|&(_, c)| {
            (0..n)
                .map(|p| {
                    out.objects[p * k + c] > 0.5 * out.alpha[p].max(1e-6) && out.alpha[p] > 0.3
                })
                .collect()
        })
        .collect();
    let new_ids: Vec<u16> = inst.ids().into_iter().filter(|&i| i != 0).collect();
    let new_masks: Vec<Vec<bool>> = new_ids.iter().map(|&i| inst.mask(i)).collect();
    let ious: Vec<Vec<f64>> = rendered
        .iter()
        .map(|r| new_masks.iter().map(|m| iou(r, m)).collect())
        .collect();
    let stranger = new_ids
        .iter()
        .copied()
        .find(|i| !channels.iter().any(|c| c.0 == *i));
    let identity = match (identity, stranger) {
        (Identity::Auto, None) if contradicted(channels, &new_ids, &ious) < MAX_CONTRADICTIONS => {
            Identity::ObjectIds
        }
        (Identity::Auto, _) => Identity::Overlap,
        (Identity::ObjectIds, Some(id)) => {
            return Err(PipelineError::View {
                view: view.name.clone(),
                what: format!(
                    "instance id {id} of the new mask is not a t=0 object (objects: {:?}); with per-image ids use --identity overlap",
                    channels.iter().map(|c| c.0).collect::<Vec<_>>()
                ),
            });
        }
        (other, _) => other,
    };
    if identity == Identity::ObjectIds {
        let assign: Vec<Option<usize>> = channels
            .iter()
            .map(|&(object_id, _)| new_ids.iter().position(|&i| i == object_id))
            .collect();
        return Ok((matches(channels, &new_ids, &ious, &assign, &[]), identity));
    }
    let w = inst.width as usize;
    let diag = ((inst.width as f64).powi(2) + (inst.height as f64).powi(2)).sqrt();
    let rc: Vec<_> = rendered.iter().map(|m| mask_centroid(m, w)).collect();
    let nc: Vec<_> = new_masks.iter().map(|m| mask_centroid(m, w)).collect();
    let cost: Vec<Vec<f64>> = ious
        .iter()
        .zip(&rc)
        .map(|(row, a)| {
            row.iter()
                .zip(&nc)
                .map(|(v, b)| match (a, b) {
                    (Some(a), Some(b)) => {
                        1.0 - v + centroid_weight * ((a.0 - b.0).hypot(a.1 - b.1) / diag)
                    }
                    // Not visible from the new view: the worst possible match.
                    _ => 2.0 + centroid_weight,
                })
                .collect()
        })
        .collect();
    let (assign, moved) = if new_ids.is_empty() {
        (vec![None; channels.len()], Vec::new())
    } else {
        assign_by_overlap(channels, &cost, movable_if)
    };
    Ok((
        matches(channels, &new_ids, &ious, &assign, &moved),
        identity,
    ))
}

/// Largest cost of matching an object the removal may have moved: a standing object that stayed
/// overlaps its t = 0 silhouette by more than half, so a worse match is likelier a moved object's.
pub const MOVED_COST: f64 = 0.5;

/// Rows of `cost` (objects of `channels`) assigned to its columns (new instances). With fewer
/// instances than objects, every set of `objects − instances` removed objects is tried; under each,
/// the rows `movable_if(removed)` names cost at most [`MOVED_COST`], the others are matched by the
/// Hungarian method at their cost, and the set with the least total wins (the first, in
/// lexicographic order, of equal ones). With no movable objects, or more than [`MAX_REMOVAL_SETS`]
/// sets, this is the plain Hungarian assignment of the whole matrix. Returns the assignment and the ids the winning set could move.
fn assign_by_overlap(
    channels: &[(u16, usize)],
    cost: &[Vec<f64>],
    movable_if: &dyn Fn(&[u16]) -> Vec<u16>,
) -> (Vec<Option<usize>>, Vec<u16>) {
    let (n, m) = (cost.len(), cost[0].len());
    if m >= n || choose(n, n - m) > MAX_REMOVAL_SETS {
        return (hungarian(cost), Vec::new());
    }
    let mut best: Option<(f64, Vec<Option<usize>>, Vec<u16>)> = None;
    for removed in subsets(n, n - m) {
        let ids: Vec<u16> = removed.iter().map(|&r| channels[r].0).collect();
        let movable = movable_if(&ids);
        let rows: Vec<usize> = (0..n).filter(|r| !removed.contains(r)).collect();
        let sub: Vec<Vec<f64>> = rows
            .iter()
            .map(|&r| {
                let capped = movable.contains(&channels[r].0);
                cost[r]
                    .iter()
                    .map(|&c| if capped { c.min(MOVED_COST) } else { c })
                    .collect()
            })
            .collect();
        let a = hungarian(&sub);
        let total: f64 = a
            .iter()
            .zip(&sub)
            .map(|(c, row)| c.map_or(0.0, |c| row[c]))
            .sum();
        if best.as_ref().is_none_or(|b| total < b.0 - 1e-12) {
            let mut full = vec![None; n];
            for (k, &r) in rows.iter().enumerate() {
                full[r] = a[k];
            }
            best = Some((total, full, movable));
        }
    }
    best.map_or_else(|| (hungarian(cost), Vec::new()), |b| (b.1, b.2))
}

/// Most sets of removed objects [`assign_by_overlap`] tries (each costs a contact closure); beyond, as
/// when half of fifteen objects went at once, overlap alone decides.
const MAX_REMOVAL_SETS: u64 = 500;

/// The binomial coefficient `n` choose `k`.
fn choose(n: usize, k: usize) -> u64 {
    (0..k as u64).fold(1, |c, i| c * (n as u64 - i) / (i + 1))
}

/// The `k`-element subsets of `0..n`, in lexicographic order.
fn subsets(n: usize, k: usize) -> Vec<Vec<usize>> {
    let mut out = Vec::new();
    let mut cur: Vec<usize> = (0..k).collect();
    if k > n {
        return out;
    }
    loop {
        out.push(cur.clone());
        let Some(i) = (0..k).rev().find(|&i| cur[i] < n - k + i) else {
            return out;
        };
        cur[i] += 1;
        for j in i + 1..k {
            cur[j] = cur[j - 1] + 1;
        }
    }
}

/// IoU below which an instance does not show the t = 0 object its id names.
const ID_MISS_IOU: f64 = 0.1;
/// IoU above which an instance clearly shows another t = 0 object.
const OTHER_HIT_IOU: f64 = 0.5;
/// With `Auto`, this many contradicted ids make the mask's ids per-image ids. One contradiction is an
/// object that fell where another stood (which ids tell and overlap cannot); two or more are ids
/// that merely lie among the t = 0 objects' ids.
const MAX_CONTRADICTIONS: usize = 2;

/// Instances of the new mask whose id names a t = 0 object they do not overlap
/// (IoU < [`ID_MISS_IOU`]) while they clearly show another one (IoU ≥ [`OTHER_HIT_IOU`]).
fn contradicted(channels: &[(u16, usize)], new_ids: &[u16], ious: &[Vec<f64>]) -> usize {
    new_ids
        .iter()
        .enumerate()
        .filter(|&(c, id)| {
            let Some(own) = channels.iter().position(|ch| ch.0 == *id) else {
                return false;
            };
            ious[own][c] < ID_MISS_IOU
                && (0..channels.len()).any(|r| r != own && ious[r][c] >= OTHER_HIT_IOU)
        })
        .count()
}

/// The matches of each t = 0 object (row of `ious`) given the new instance (column) assigned to it
/// and the ids matched as objects the removal could have moved.
fn matches(
    channels: &[(u16, usize)],
    new_ids: &[u16],
    ious: &[Vec<f64>],
    assign: &[Option<usize>],
    moved: &[u16],
) -> Vec<Match> {
    channels
        .iter()
        .enumerate()
        .map(|(r, &(object_id, channel))| match assign[r] {
            Some(c) => Match {
                object_id,
                channel,
                new_id: Some(new_ids[c]),
                iou: ious[r][c],
                may_have_moved: moved.contains(&object_id),
            },
            None => Match {
                object_id,
                channel,
                new_id: None,
                iou: ious[r].iter().copied().fold(0.0, f64::max),
                may_have_moved: false,
            },
        })
        .collect()
}

/// Mean pixel `(x, y)` of a row-major mask of width `w`; `None` when it is empty.
pub(crate) fn mask_centroid(mask: &[bool], w: usize) -> Option<(f64, f64)> {
    let (mut sx, mut sy, mut n) = (0.0, 0.0, 0usize);
    for (p, _) in mask.iter().enumerate().filter(|(_, b)| **b) {
        sx += (p % w) as f64;
        sy += (p / w) as f64;
        n += 1;
    }
    (n > 0).then(|| (sx / n as f64, sy / n as f64))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_scene::{camera, cylinder};

    /// Object 1 (channel 0) stood at A, object 2 (channel 1) at B. In the new image object 1 is gone and
    /// object 2 lies where object 1 stood (it stood on it and fell), its mask carrying id 2.
    /// [`fell_into_the_removed_ones_place`] with the new mask's instance 2 relabelled 5, an id that is
    /// no t=0 object.
    fn fell_with_unknown_instance_id_5() -> (Surfels, View) {
        let (s, mut view) = fell_into_the_removed_ones_place();
        for v in &mut view.instance.as_mut().unwrap().data {
            if *v == 2 {
                *v = 5;
            }
        }
        (s, view)
    }

    /// The new view's instance mask: `id` where `object` covers a pixel (alpha > ½), else 0.
    fn instance_mask(object: &Surfels, id: u16) -> trand_io::InstanceMap {
        let out = render::<f32, _>(object, &camera(), &RenderSettings::default()).unwrap();
        let data: Vec<u16> = out
            .alpha
            .iter()
            .map(|&a| if a > 0.5 { id } else { 0 })
            .collect();
        trand_io::InstanceMap::from_vec(out.width, out.height, 1, data).unwrap()
    }

    fn fell_into_the_removed_ones_place() -> (Surfels, View) {
        let mut s = cylinder(0.0, 0.0, 0);
        s.append(&cylinder(0.12, 0.04, 1));
        let inst = instance_mask(&cylinder(0.0, 0.0, 0), 2);
        let view = View {
            name: "new".into(),
            frame: 0,
            camera: camera(),
            rgb: None,
            instance: Some(inst),
            depth: None,
        };
        (s, view)
    }

    #[test]
    fn object_ids_tell_which_object_went_where_overlap_cannot() {
        let (s, view) = fell_into_the_removed_ones_place();
        let channels = [(1, 0), (2, 1)];
        let settings = RenderSettings::default();
        let (by_id, rule) = detect(
            &s,
            &channels,
            &view,
            &settings,
            0.5,
            Identity::Auto,
            &|_| Vec::new(),
        )
        .unwrap();
        assert_eq!(rule, Identity::ObjectIds);
        assert_eq!(
            (by_id[0].new_id, by_id[1].new_id),
            (None, Some(2)),
            "{by_id:?}"
        );
        // Overlap alone takes the fallen object for the one that stood there.
        let (by_overlap, rule) = detect(
            &s,
            &channels,
            &view,
            &settings,
            0.5,
            Identity::Overlap,
            &|_| Vec::new(),
        )
        .unwrap();
        assert_eq!(rule, Identity::Overlap);
        assert_eq!(
            (by_overlap[0].new_id, by_overlap[1].new_id),
            (Some(2), None),
            "{by_overlap:?}"
        );
    }

    /// Both objects stay where they stood, but the new mask numbers them the other way round: ids
    /// that lie among the t = 0 objects' ids and contradict the rendered objects twice.
    #[test]
    fn auto_does_not_trust_swapped_ids_that_happen_to_be_object_ids() {
        let a = cylinder(0.0, 0.0, 0);
        let b = cylinder(0.12, 0.04, 1);
        let mut s = a.clone();
        s.append(&b);
        let settings = RenderSettings::default();
        let alpha = |s: &Surfels| render::<f32, _>(s, &camera(), &settings).unwrap().alpha;
        let (ra, rb) = (alpha(&a), alpha(&b));
        let data: Vec<u16> = ra
            .iter()
            .zip(&rb)
            .map(|(&x, &y)| {
                if x > 0.5 {
                    2
                } else if y > 0.5 {
                    1
                } else {
                    0
                }
            })
            .collect();
        let view = View {
            name: "new".into(),
            frame: 0,
            camera: camera(),
            rgb: None,
            instance: Some(trand_io::InstanceMap::from_vec(200, 150, 1, data).unwrap()),
            depth: None,
        };
        let (m, rule) = detect(
            &s,
            &[(1, 0), (2, 1)],
            &view,
            &settings,
            0.5,
            Identity::Auto,
            &|_| Vec::new(),
        )
        .unwrap();
        assert_eq!(rule, Identity::Overlap);
        assert_eq!((m[0].new_id, m[1].new_id), (Some(2), Some(1)), "{m:?}");
    }

    #[test]
    fn forcing_object_ids_on_a_mask_with_unknown_ids_is_an_error_naming_the_id() {
        let (s, view) = fell_with_unknown_instance_id_5();
        let err = detect(
            &s,
            &[(1, 0), (2, 1)],
            &view,
            &RenderSettings::default(),
            0.5,
            Identity::ObjectIds,
            &|_| Vec::new(),
        )
        .unwrap_err();
        let msg = err.to_string();
        assert!(
            msg.contains("instance id 5") && msg.contains("--identity overlap"),
            "{msg}"
        );
    }

    #[test]
    fn ids_that_are_not_t0_objects_are_matched_by_overlap() {
        let (s, view) = fell_with_unknown_instance_id_5();
        let (m, rule) = detect(
            &s,
            &[(1, 0), (2, 1)],
            &view,
            &RenderSettings::default(),
            0.5,
            Identity::Auto,
            &|_| Vec::new(),
        )
        .unwrap();
        assert_eq!(rule, Identity::Overlap);
        assert_eq!((m[0].new_id, m[1].new_id), (Some(5), None), "{m:?}");
    }

    /// Object 1 stood at A, object 2 leaned on it from B. In the new image (per-image id 7) one object
    /// lies half over A's place: object 2, fallen once object 1 was taken.
    fn fell_half_over_the_removed_ones_place() -> (Surfels, View) {
        let (s, mut view) = fell_into_the_removed_ones_place();
        view.instance = Some(instance_mask(&cylinder(0.035, 0.0, 0), 7));
        (s, view)
    }

    #[test]
    fn without_ids_an_object_nothing_could_move_is_not_taken_for_one_that_fell() {
        let (s, view) = fell_half_over_the_removed_ones_place();
        let objects = [(1, 0), (2, 1)];
        let settings = RenderSettings::default();
        // Object 1 stands alone; taking it away moves object 2, taking object 2 away moves nothing.
        let physics = |removed: &[u16]| if removed == [1] { vec![2] } else { vec![] };
        let (m, _) = detect(
            &s,
            &objects,
            &view,
            &settings,
            0.5,
            Identity::Overlap,
            &physics,
        )
        .unwrap();
        assert!(
            m[0].iou < 1.0 - MOVED_COST,
            "object 1 overlaps the instance by {}",
            m[0].iou
        );
        assert_eq!((m[0].new_id, m[1].new_id), (None, Some(7)), "{m:?}");
        assert!(m[1].may_have_moved && !m[0].may_have_moved, "{m:?}");
        // Without the physics, overlap alone keeps object 1 and removes object 2.
        let (m, _) = detect(
            &s,
            &objects,
            &view,
            &settings,
            0.5,
            Identity::Overlap,
            &|_| vec![],
        )
        .unwrap();
        assert_eq!((m[0].new_id, m[1].new_id), (Some(7), None), "{m:?}");
    }

    #[test]
    fn subsets_are_every_k_of_n_once_in_order() {
        assert_eq!(
            subsets(4, 2),
            vec![[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]]
        );
        assert_eq!(subsets(3, 3), vec![vec![0, 1, 2]]);
        assert_eq!((choose(4, 2), choose(15, 7), choose(6, 0)), (6, 6435, 1));
    }
}
