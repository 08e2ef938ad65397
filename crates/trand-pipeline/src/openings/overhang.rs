//! Surfels whose disc overhangs an opening's lip: the shelf a segmenter's boundary errors grow.
//!
//! The carving ([`Opening::carves`]) tests a surfel's centre. With masks a few pixels off, the rim
//! of an open vessel gathers flat surfels whose centres sit in the kept wall but whose discs reach
//! millimetres over the opening (likely because a view whose mask is too wide at the far rim asks
//! for object a few pixels above it, and a flat disc on the rim that reaches out that far reaches
//! as far in). Seen over the near rim from another view it is a shelf in front of the inside
//! (seq_101's tumbler with boundary errors: six times as many surfels in the top 4 mm under its
//! rim, too-near pixels inside its outline 1.4 → 5.2 %). So a surfel in the lip band whose disc
//! reaches, at [`OVERHANG_SIGMA`] σ horizontally towards the axis, into the carving is carved too
//! ([`Overhangs::Carved`]).
//!
//! [`OverhangRule`] says when. The rule was first switched on only where the masks disagree
//! ([`crate::mask_agreement`]): a thin rim is made of the same kind of surfels, and with exact masks
//! the stemmed glasses lost by it. With the front fill, the thin lip and the table's height, carving
//! with exact masks gains too, and so does carving with cameras aligned on the table, whose masks
//! then agree (BENCHMARKS.md §8): it is on for every run by default.

use glam::{DVec2, DVec3};
use serde::{Deserialize, Serialize};

use super::{LIP_BAND_M, Opening};

/// How many σ of a surfel's disc count as its reach: a 2DGS disc at 2σ still has e^-2 of its
/// opacity.
pub const OVERHANG_SIGMA: f64 = 2.0;

/// When the overhang test of [`Opening::overhangs`] carves ([`ReconstructOptions`]'s `overhangs`).
///
/// [`ReconstructOptions`]: crate::reconstruct::ReconstructOptions
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum OverhangRule {
    /// Always.
    Carve,
    /// Only where the training masks disagree with one another ([`crate::mask_agreement`]).
    WhenMasksDisagree,
    /// Never: only surfel centres are tested.
    Keep,
}

impl OverhangRule {
    /// What the rule decides for training masks that `disagree` with one another or not.
    pub fn decide(self, disagree: bool) -> Overhangs {
        match self {
            OverhangRule::Carve => Overhangs::Carved,
            OverhangRule::WhenMasksDisagree if disagree => Overhangs::Carved,
            OverhangRule::WhenMasksDisagree | OverhangRule::Keep => Overhangs::Kept,
        }
    }
}

/// Whether surfels whose disc overhangs an opening's lip are carved with it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Overhangs {
    /// Only surfel centres are tested (masks that agree with one another).
    Kept,
    /// Surfels in the lip band whose disc reaches into the carving are carved too.
    Carved,
}

impl Opening {
    /// Whether the disc of a surfel at `mean` (`log_scale`, unit-or-not `quat` (w, x, y, z)) lies
    /// within [`LIP_BAND_M`] under the rim and reaches, at [`OVERHANG_SIGMA`] σ in its own plane
    /// along the horizontal direction to the carving's centre line, into the carved region (taken
    /// at the surfel's height). For the tangent axes `t₁, t₂` with scales `s₁, s₂` and the inward
    /// unit `u`, the reach is `k·√((s₁ t₁·u)² + (s₂ t₂·u)²)`: the support function of the disc's
    /// ellipse at `k σ`, projected on `u`.
    pub fn overhangs(&self, mean: [f32; 3], log_scale: [f32; 2], quat: [f32; 4]) -> bool {
        let p = DVec3::new(mean[0] as f64, mean[1] as f64, mean[2] as f64);
        if p.z > self.rim_z || p.z < self.floor_z || p.z < self.rim_z - LIP_BAND_M {
            return false;
        }
        let Some(k) = self.profile.slice_of(p.z) else {
            return false;
        };
        let to_axis = self.carving.centre(k.min(self.carving.radius.len() - 1)) - p.truncate();
        let Some(u) = to_axis.try_normalize() else {
            return false;
        };
        let Some((m, _)) = trand_core::math::quat_to_rotmat(quat) else {
            return false;
        };
        let along = |c: usize| DVec2::new(m[0][c] as f64, m[1][c] as f64).dot(u);
        let (s1, s2) = ((log_scale[0] as f64).exp(), (log_scale[1] as f64).exp());
        let reach = OVERHANG_SIGMA * ((s1 * along(0)).powi(2) + (s2 * along(1)).powi(2)).sqrt();
        let q = p.truncate() + u * reach.min(to_axis.length());
        self.carves([q.x as f32, q.y as f32, mean[2]])
    }
}
