//! Refill: surfels put back where an opening carved an object the opening prior then closed.
//!
//! The opening prior is decided from the given poses before the first iteration and carves every
//! open vessel's opening from then on. Once the pose corrections settle it is decided again
//! (`reconstruct::retake_openings`); an object the given poses opened can then be closed, above all
//! a spheroid whose dome the given poses' hull flattened into a bowl's crown. Its hull has been empty
//! where the opening was for hundreds of iterations by then, and densification regrows it only by
//! cloning and splitting the surfels around the hole, slowly: a test view looks through the dome at
//! the object's far side (seq_108's spheroid with boundary errors: 84 % of its pixels within 2.5 cm,
//! 98 % when it is never carved; BENCHMARKS.md §8).
//!
//! The refill samples the object's visual hull as the initial surfels did, at their density, and
//! keeps the samples that the closed opening carved and no opening of the retaken decision carves.
//! The model around them has trained for as long as the hole was there, so the new surfels start as
//! if they had trained with it rather than from the initial state: labelled with the object channel
//! the training masks show there (the majority over the views that see the sample, as the object map
//! would have taught it), with that channel's mask colour, and half opaque, so that the image losses
//! keep them rather than prune them before the object losses pull them onto the surface. Samples
//! no view labels as an object keep the initial state.

use std::collections::HashSet;

use rand_pcg::Pcg64;
use trand_core::sh::rgb_to_dc;
use trand_core::{Surfels, math::logit};
use trand_train::init::{InitConfig, surfels_from_points};

use crate::Result;
use crate::openings::{Opening, Top, VesselTop};
use crate::targets::{TrainView, palette};

/// A refilled surfel's opacity.
pub const OPACITY: f32 = 0.5;
/// A refilled surfel's logit of its object channel (the others 0), as the front fill's surfels.
pub const OBJECT_LOGIT: f32 = 8.0;

/// The openings of the `given` decision (in the order of its open `given_tops`, as
/// [`crate::openings::classify`] gives them) whose object the retaken decision (`tops`) closes; each
/// of those tops is marked [`VesselTop::refilled`].
pub fn closed_openings<'o, O>(
    given: &'o [O],
    given_tops: &[VesselTop],
    tops: &mut [VesselTop],
) -> Vec<&'o O> {
    let open = |t: &VesselTop| matches!(t.top, Top::Open { .. });
    let closed_ids: HashSet<u16> = tops
        .iter()
        .filter(|t| !open(t))
        .map(|t| t.object_id)
        .collect();
    let closed: Vec<(u16, &O)> = given_tops
        .iter()
        .filter(|t| open(t))
        .zip(given)
        .filter(|(g, _)| closed_ids.contains(&g.object_id))
        .map(|(g, o)| (g.object_id, o))
        .collect();
    for t in tops.iter_mut() {
        t.refilled = closed.iter().any(|&(id, _)| id == t.object_id);
    }
    closed.into_iter().map(|(_, o)| o).collect()
}

/// The surfels that refill what the `closed` openings carved from `hull` (visual-hull samples at the
/// initial surfels' density) and the retaken `openings` do not carve, labelled by the masks of
/// `views` (module docs). Empty when nothing was carved there.
pub fn surfels(
    hull: Vec<[f32; 3]>,
    closed: &[&Opening],
    openings: &[Opening],
    views: &[TrainView],
    cfg: &InitConfig,
    (sh_degree, num_objects): (u32, usize),
    rng: &mut Pcg64,
) -> Result<Surfels> {
    let pts: Vec<[f32; 3]> = hull
        .into_iter()
        .filter(|&p| closed.iter().any(|o| o.carves(p)) && !openings.iter().any(|o| o.carves(p)))
        .collect();
    let mut s = surfels_from_points(pts, cfg, sh_degree, num_objects, rng)?;
    s.opacity_logits.fill(logit(OPACITY));
    for i in 0..s.len() {
        let p = glam::Vec3::from_array(s.means[i]).as_dvec3();
        if let Some(c) = majority_channel(views, p, num_objects) {
            let row = &mut s.obj_logits[i * num_objects..(i + 1) * num_objects];
            row.fill(0.0);
            row[c] = OBJECT_LOGIT;
            s.mask_dc[i] = palette(c).map(rgb_to_dc);
        }
    }
    Ok(s)
}

/// The object channel most of the views that see `p` label it with (ties to the lower channel);
/// `None` when none labels it as an object.
fn majority_channel(views: &[TrainView], p: glam::DVec3, num_objects: usize) -> Option<usize> {
    let mut count = vec![0usize; num_objects];
    for v in views {
        if let Some(o) = v.pixel_of(p)
            && let Some(n) = count.get_mut(v.labels[o] as usize)
        {
            *n += 1;
        }
    }
    let c = (1..num_objects).max_by_key(|&c| (count[c], std::cmp::Reverse(c)))?;
    (count[c] > 0).then_some(c)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::openings::{Closed, Shape};
    use glam::DVec3;
    use trand_core::{Camera, Intrinsics};

    fn vessel(id: u16, open: bool) -> VesselTop {
        let top = if open {
            Top::Open {
                shape: Shape::Bowl,
                rim_z: 0.05,
                rim_radius: 0.04,
            }
        } else {
            Top::Closed {
                because: Closed::RoundTop,
            }
        };
        VesselTop::new(id, 1000, top)
    }

    #[test]
    fn only_the_openings_of_objects_the_retake_closes_are_refilled() {
        let given_tops = [
            vessel(1, true),
            vessel(2, false),
            vessel(3, true),
            vessel(4, true),
        ];
        // The given openings, in the order of the open tops: objects 1, 3 and 4.
        let given = ["one", "three", "four"];
        let mut tops = [
            vessel(1, true),
            vessel(2, false),
            vessel(3, false),
            vessel(4, true),
        ];
        let closed = closed_openings(&given, &given_tops, &mut tops);
        assert_eq!(closed, [&"three"]);
        let marked: Vec<bool> = tops.iter().map(|t| t.refilled).collect();
        assert_eq!(marked, [false, false, true, false]);
    }

    #[test]
    fn nothing_is_refilled_when_the_retake_closes_nothing() {
        let given_tops = [vessel(1, true), vessel(2, false)];
        let mut tops = [vessel(1, true), vessel(2, false)];
        assert!(closed_openings(&["one"], &given_tops, &mut tops).is_empty());
        assert!(tops.iter().all(|t| !t.refilled));
    }

    /// A 32×24 view of the origin from `eye`, every pixel labelled `c`.
    fn view(eye: DVec3, c: u8) -> TrainView {
        let (w, h) = (32, 24);
        let camera = Camera::look_at(
            Intrinsics::centered(30.0, w as u32, h as u32),
            eye,
            DVec3::ZERO,
            DVec3::Z,
        );
        let mut v = TrainView::from_ids("v".into(), camera, (w, h), vec![u16::from(c); w * h]);
        v.labels = vec![c; w * h];
        v
    }

    #[test]
    fn a_sample_takes_the_channel_most_views_see_it_in_and_background_alone_gives_none() {
        let eyes = [DVec3::new(1.0, 0.0, 0.5), DVec3::new(0.0, 1.0, 0.5)];
        let views = [view(eyes[0], 2), view(eyes[1], 2), view(eyes[0], 1)];
        assert_eq!(majority_channel(&views, DVec3::ZERO, 3), Some(2));
        // A tie goes to the lower channel.
        assert_eq!(majority_channel(&views[1..], DVec3::ZERO, 3), Some(1));
        let background = [view(eyes[0], 0), view(eyes[1], 0)];
        assert_eq!(majority_channel(&background, DVec3::ZERO, 3), None);
        // Outside every view.
        assert_eq!(majority_channel(&views, DVec3::new(0.0, 5.0, 2.0), 3), None);
    }
}
