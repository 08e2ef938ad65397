//! How well the training masks agree with one another: the share of mask-edge pixels whose ray
//! meets nothing the other views call an object.
//!
//! With exact masks and poses the visual hull of the other views contains the object, so the ray
//! through any object pixel of one view, even at the mask's edge, passes through it. A segmenter's
//! boundary a few pixels too wide, or a camera a fraction of a degree off, leaves edge pixels whose
//! rays pass beside that hull; a mask too tight does the same to the other views' edges. The share
//! of such edge pixels tells inputs a segmenter gave from exact ones without any ground truth;
//! `run.json` reports it, and with `overhangs = "when-masks-disagree"` it decides the overhang rule
//! (see [`crate::openings::overhang`]).
//!
//! Each view's edge pixels (object pixels, as given, with a background 4-neighbour) are tested: the
//! ray through the pixel's centre is marched through the hull's box in steps of [`STEP_M`], a step
//! inside when every other view that sees the point shows an object there and at least two do (a
//! few hundredths of a second for six 640 × 480 views).

use glam::DVec3;
use rayon::prelude::*;
use serde::Serialize;
use trand_train::init::SlabBox;

use crate::targets::TrainView;

/// March step along an edge pixel's ray (m). The chord of a ray half a pixel inside a silhouette
/// through a 2 cm wide object is several millimetres, so a millimetre step does not miss it.
const STEP_M: f64 = 0.001;
/// Share of edge rays missing the other views' hull above which the masks disagree. Exact masks of
/// the four public Blender sequences and twelve synthetic scenes miss on 0.7–2.5 % (a mask's pixel
/// grid is half a pixel off the silhouette); with one object's mask missing from one view, 2–5 %;
/// with boundaries 1–3 px off or poses half a degree off, a quarter or more (BENCHMARKS.md §8).
pub const DISAGREE_SHARE: f64 = 0.10;

/// The masks' agreement, as `run.json` reports it.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct MaskAgreement {
    /// Edge pixels tested, over all views.
    pub edge_pixels: usize,
    /// Share of them whose ray misses the other views' hull, per view and over all views.
    pub missed_per_view: Vec<f64>,
    pub missed: f64,
}

impl MaskAgreement {
    /// Whether the masks disagree by more than exact masks do ([`DISAGREE_SHARE`]).
    pub fn disagree(&self) -> bool {
        self.missed > DISAGREE_SHARE
    }
}

/// The agreement of `views`' masks (as given) inside box `b`, which must hold every object whole
/// (the rays of the edges of an object the box cuts off miss it: take
/// [`crate::reconstruct::openings_box`]).
pub fn measure(views: &[TrainView], b: &SlabBox) -> MaskAgreement {
    let per_view: Vec<(usize, usize)> = (0..views.len())
        .map(|i| {
            let edges = edge_pixels(&views[i]);
            let missed = edges
                .par_iter()
                .filter(|&&p| !ray_meets_others(views, i, p, b))
                .count();
            (edges.len(), missed)
        })
        .collect();
    let total: usize = per_view.iter().map(|v| v.0).sum();
    let missed: usize = per_view.iter().map(|v| v.1).sum();
    MaskAgreement {
        edge_pixels: total,
        missed_per_view: per_view
            .iter()
            .map(|&(n, m)| m as f64 / n.max(1) as f64)
            .collect(),
        missed: missed as f64 / total.max(1) as f64,
    }
}

/// The object pixels with a background 4-neighbour (or on the image border).
fn edge_pixels(v: &TrainView) -> Vec<usize> {
    let (w, h) = (v.width, v.height);
    let bg = |x: usize, y: usize| v.given_ids[y * w + x] == 0;
    (0..w * h)
        .filter(|&i| {
            let (x, y) = (i % w, i / w);
            !bg(x, y)
                && (x == 0
                    || y == 0
                    || x + 1 == w
                    || y + 1 == h
                    || bg(x - 1, y)
                    || bg(x + 1, y)
                    || bg(x, y - 1)
                    || bg(x, y + 1))
        })
        .collect()
}

/// Whether the ray through pixel `p` of view `i` passes through the hull of the other views in `b`.
fn ray_meets_others(views: &[TrainView], i: usize, p: usize, b: &SlabBox) -> bool {
    let v = &views[i];
    let (x, y) = ((p % v.width) as f64, (p / v.width) as f64);
    let o = v.camera.center();
    let d = v.camera.ray_direction(x, y);
    let Some((t0, t1)) = box_span(o, d, b) else {
        return false;
    };
    let mut t = t0;
    while t <= t1 {
        if inside_others(views, i, o + d * t) {
            return true;
        }
        t += STEP_M;
    }
    false
}

/// Whether every view but `i` that sees `q` shows an object there, and at least two do.
fn inside_others(views: &[TrainView], i: usize, q: DVec3) -> bool {
    let others = views
        .iter()
        .enumerate()
        .filter(|&(j, _)| j != i)
        .map(|(_, w)| w);
    crate::targets::in_hull_of(others, q, |w| &w.given_ids)
}

/// The parameter interval where the ray `o + t d` (t > 0) lies in box `b` (slab test).
fn box_span(o: DVec3, d: DVec3, b: &SlabBox) -> Option<(f64, f64)> {
    let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
    for a in 0..3 {
        let (lo, hi) = (b.min[a], b.max[a]);
        if d[a].abs() < 1e-12 {
            if o[a] < lo || o[a] > hi {
                return None;
            }
            continue;
        }
        let (ta, tb) = ((lo - o[a]) / d[a], (hi - o[a]) / d[a]);
        t0 = t0.max(ta.min(tb));
        t1 = t1.min(ta.max(tb));
    }
    (t0 <= t1).then_some((t0, t1))
}
