//! Missed masks drawn again through better cameras.
//!
//! **Why.** Where a segmenter missed an object in one view, the association
//! ([`crate::associate`], step 5) draws it in from the other views: their hull, splatted into the
//! view. Through exact cameras that drawing is close to the object (seq_101's wine glass, missed in
//! one of its copies' training views: IoU 0.85 with the true mask); through cameras half a degree
//! and 3 mm off, the hull is carved by masks that disagree and splatted through a camera that is
//! off itself, and the drawing slides beside the object (IoU 0.67, 15–20 px to one side). Training
//! then fits the object where that view says, which no pose correction undoes.
//!
//! **Method.** Where the association filled a missed mask, the cameras are first corrected:
//! * on a table whose texture aligned them ([`crate::table_align`], kept): those cameras;
//! * otherwise, with the poses refined and the support prior off (a narrow baseline keeps its poses
//!   as given): a first pass trains the run until its corrections settle
//!   (`PoseRefinement::settled`, iteration 400 of 850 by default, most of it at the coarse levels) and
//!   takes its corrected cameras.
//!
//! The training masks are then associated again through those cameras, and the run trains on them
//! from its own cameras (given, or table-aligned), as it would have. The corrected cameras serve the
//! drawing only: training from them instead compounds the refinement's weakly observed modes (seq_109
//! with all three input errors, seed 0: 94.2 → 86.2 % within 2.5 cm, BENCHMARKS.md §10).
//!
//! **Drawn, but unknown.** The drawing is the other views' hull: wider than the object (about a
//! third more pixels for seq_101's wine glass) and, through cameras that are off, beside it. Taught
//! as the object, it fattens and shifts the object in that view; taught as background, it carves it
//! away. By default ([`MissedFill::Unknown`]) the losses therefore leave the drawn pixels out
//! ([`leave_unknown`]): they count as background for the Dice term, where a channel with no
//! labelled pixel in a view pushes with `1/(P+1)²` (negligible at the rendered areas), and join the
//! view's band, whose photometric gradients are cleared. The view then teaches nothing about the
//! missed object, which the other views fit; the visual-hull initialisation keeps the drawing, so
//! the object is not carved out of it. Measured against teaching the drawing as the object, with all
//! three input errors, 27 copies of the public sequences: seq_101 seed 2 95.14 → 96.54 % within
//! 2.5 cm, the oracle (the true mask in place of the drawing) 96.50 (BENCHMARKS.md §8). Keeping the
//! drawing's core (farther than 6 px from its edge) as the object was worse on seq_105 and seq_108.
//!
//! **Resume.** The first pass is deterministic (same seed, same result for any thread count), so a
//! resumed run trains it again and draws the same masks.

use std::sync::atomic::{AtomicBool, Ordering};

use crate::targets::TrainView;
use crate::trainer::Trainer;
use crate::{PipelineError, Result};

/// Whether missed masks are drawn again through corrected cameras.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum MissedMasks {
    /// Drawn once, through the given cameras.
    GivenCameras,
    /// Drawn again through the table-aligned cameras, or those of a first pass (module docs).
    CorrectedCameras,
}

/// How the losses supervise the pixels drawn in for a missed mask (module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum MissedFill {
    /// Left out of the losses ([`leave_unknown`]); the visual-hull initialisation keeps them.
    Unknown,
    /// The drawn object's, as any labelled pixel.
    Object,
}

/// Which cameras the missed masks were drawn again through.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Redrawn {
    /// The cameras aligned on the table's texture.
    TableAligned,
    /// The cameras of a first training pass.
    FirstPass,
}

/// What was drawn again, as `run.json` reports it.
#[derive(Clone, Debug, serde::Serialize, PartialEq)]
pub struct RedrawReport {
    pub through: Redrawn,
    /// Per view of the first pass: its correction `(ω, δ)` (world frame, radians and metres) from the
    /// cameras the run trains from; empty for [`Redrawn::TableAligned`].
    pub corrections: Vec<[f64; 6]>,
    /// `(view, object id, pixels)` filled in, through the given cameras and then through the corrected
    /// ones.
    pub filled_given: Vec<(String, u16, usize)>,
    pub filled_corrected: Vec<(String, u16, usize)>,
}

/// Which cameras, if any, the filled masks are drawn again through: the table-aligned ones where the
/// alignment was `aligned` (kept), else a first pass where the poses are `refined` and the support
/// prior was not `support_applied`.
pub fn redraw_through(
    rule: MissedMasks,
    aligned: bool,
    refined: bool,
    support_applied: bool,
) -> Option<Redrawn> {
    match rule {
        MissedMasks::GivenCameras => None,
        MissedMasks::CorrectedCameras if aligned => Some(Redrawn::TableAligned),
        MissedMasks::CorrectedCameras if refined && !support_applied => Some(Redrawn::FirstPass),
        MissedMasks::CorrectedCameras => None,
    }
}

/// [`MissedFill::Unknown`]: in each view named in `drawn` (view name, object id, pixels:
/// [`crate::associate::Association::drawn`]), the pixels of the objects drawn there leave the losses: labelled background (the Dice counts moved with them) and
/// added to the view's band. The ids, which the visual-hull initialisation reads, keep them.
pub fn leave_unknown(views: &mut [TrainView], drawn: &[(String, u16, usize)]) {
    for v in views.iter_mut() {
        let ids: Vec<u16> = drawn
            .iter()
            .filter(|(name, ..)| *name == v.name)
            .map(|&(_, id, _)| id)
            .collect();
        if ids.is_empty() || v.labels.is_empty() {
            continue;
        }
        if v.band.is_empty() {
            v.band = vec![false; v.labels.len()];
        }
        for (o, id) in v.ids.iter().enumerate() {
            if ids.contains(id) {
                v.label_counts[v.labels[o] as usize] -= 1.0;
                v.label_counts[0] += 1.0;
                v.labels[o] = 0;
                v.band[o] = true;
            }
        }
    }
}

/// Trains `trainer` for iterations `1..=until`, calling `after_densify` after each densification
/// (the run's carving), and returns each view's correction then. `cancel` stops it with
/// [`PipelineError::Interrupted`] at iteration 0: nothing of the pass is kept.
pub fn train_until(
    mut trainer: Trainer<'_>,
    until: u32,
    after_densify: &mut dyn FnMut(&mut Trainer<'_>),
    cancel: &AtomicBool,
) -> Result<Vec<[f64; 6]>> {
    for it in 1..=until {
        if trainer.step(it, false)?.densified {
            after_densify(&mut trainer);
        }
        if cancel.load(Ordering::SeqCst) {
            return Err(PipelineError::Interrupted(0));
        }
    }
    Ok(trainer.poses.xi)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 3×2 view whose ids are `ids`, labelled channel = id (the camera does not matter).
    fn view(name: &str, ids: Vec<u16>) -> TrainView {
        let mut v = TrainView::from_ids(name.into(), crate::test_scene::camera(), (3, 2), ids);
        v.labels = v.ids.iter().map(|&i| i as u8).collect();
        v.label_counts = vec![0.0; 3];
        for &l in &v.labels {
            v.label_counts[l as usize] += 1.0;
        }
        v
    }

    #[test]
    fn drawn_pixels_leave_the_losses_of_their_view_only_and_stay_in_the_ids() {
        let ids = vec![0, 1, 2, 2, 2, 0];
        let mut views = vec![view("a", ids.clone()), view("b", ids.clone())];
        leave_unknown(&mut views, &[("a".into(), 2, 3)]);
        let a = &views[0];
        assert_eq!(a.labels, [0, 1, 0, 0, 0, 0]);
        assert_eq!(a.label_counts, [5.0, 1.0, 0.0]);
        assert_eq!(a.band, [false, false, true, true, true, false]);
        assert_eq!(a.ids, ids, "the visual hull still sees the drawing");
        let b = &views[1];
        assert_eq!(
            b.labels,
            [0, 1, 2, 2, 2, 0],
            "another view keeps its labels"
        );
        assert!(b.band.is_empty());
    }

    #[test]
    fn masks_are_drawn_again_through_the_table_or_a_first_pass_and_never_with_fixed_poses() {
        let c = MissedMasks::CorrectedCameras;
        assert_eq!(
            redraw_through(c, true, true, false),
            Some(Redrawn::TableAligned)
        );
        assert_eq!(
            redraw_through(c, false, true, false),
            Some(Redrawn::FirstPass)
        );
        assert_eq!(redraw_through(c, false, false, false), None, "poses fixed");
        assert_eq!(
            redraw_through(c, false, true, true),
            None,
            "narrow baseline"
        );
        let given = MissedMasks::GivenCameras;
        assert_eq!(redraw_through(given, true, true, false), None);
        assert_eq!(redraw_through(given, false, true, false), None);
    }
}
