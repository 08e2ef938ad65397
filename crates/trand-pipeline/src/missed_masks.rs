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
//! **Resume.** The first pass is deterministic (same seed, same result for any thread count), so a
//! resumed run trains it again and draws the same masks.

use std::sync::atomic::{AtomicBool, Ordering};

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
