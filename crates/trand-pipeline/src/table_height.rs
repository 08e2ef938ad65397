//! Where the table lies, from its texture or its shading: the height of the support plane in the
//! frame of the training cameras, found by a plane sweep.
//!
//! **Why.** Pose refinement (`trand_train::pose`) makes the training views agree with one another,
//! but a motion of the whole scene with every camera changes no image, so the scene keeps the
//! mean of the given poses' errors. Six views half a degree and 3 mm off each leave that mean at
//! 1–5 mm at the objects, depending on the draw, and the exact cameras the depth is wanted at see
//! the scene that far off: 4.6 mm sideways costs seq_108 3.9 points of depth within 2.5 cm, 3 mm
//! up cost it 2.6 before its height was read (BENCHMARKS.md §8). Sideways nothing in the images can
//! tell, but the height can: the table is the plane z = 0 of the world frame (trand's convention),
//! and the views agree best on its texture, or on its shading and shadows, at its true height.
//!
//! **Sweep.** For each height `h` of a grid, each view's table pixels (outside every object's mask,
//! widened by [`MASK_MARGIN_SHARE`] of the image width, within half the cameras' mean distance of the
//! cameras' focus on the table) are cast onto the plane `z = h`, projected into every other view and read there
//! (bilinear, grey); the score of `h` is the mean over ordered view pairs of the zero-mean
//! normalised cross-correlation of the two readings. The best grid height is refined by a parabola
//! through its neighbours. Refraction and caustics are masked with the objects; shadows lie on the
//! table and agree.
//!
//! **When the height is trusted.** Three kinds of curve are read, and one is refused:
//! - *Textured*: a sharp peak, the best score beating the worst by [`MIN_CONTRAST`] or more.
//! - *Broad*: a plain table correlates through its shading and soft shadows almost as well at any
//!   height (best minus worst 0.01–0.06), but the curve is one smooth hump whose top lies at the
//!   table: a single parabola fitted to the whole sweep explains [`MIN_HUMP`] or more of its
//!   variance, opens downwards and has its vertex inside the sweep. Over 96 refined runs on plain
//!   tables (seq_101, seq_109 and their perturbed copies, `trand synth` scenes) the best height of
//!   such a curve lay 0.5 mm from the refined cameras' vertical bias on average, within 1 mm in 91 %
//!   of them, 2.3 mm at worst. A plain table's height is trusted less than a texture's: a refined
//!   frame is moved by [`BROAD_SHARE`] of it.
//! - *Faint*: a peak whose contrast lies between the aliases' highest ([`MIN_FAINT_CONTRAST`]) and
//!   [`MIN_CONTRAST`], and not a broad hump: a texture seen less sharply (0.34–0.40 on scenes drawn
//!   by `trand synth`). The frame is moved by a share of its height that grows from 0 to 1 across
//!   that band ([`faint_share`]): with a cut at [`MIN_CONTRAST`] a run whose contrast fell from 0.403
//!   to 0.383 lost a 6.7 mm move and 3.9 points of depth (BENCHMARKS.md §8).
//! - *Refused*: a texture finer than the cameras' remaining disagreement (wood rings 6–9 mm apart)
//!   peaks at aliases several millimetres apart with contrast 0.06–0.31: the curve is a comb that a
//!   parabola fits badly (0.10–0.42 of its variance). A flat curve, as a narrow rig's, is refused too.
//!
//! The best grid point must lie strictly inside the sweep in either case.

use glam::DVec3;
use rayon::prelude::*;
use serde::Serialize;
use trand_core::Camera;

use crate::targets::TrainView;

mod hump;
#[cfg(test)]
pub(crate) mod painted;

pub use hump::hump;

/// Heights swept (m): the mean of independent per-view errors of a few millimetres stays well
/// inside; a wider range would let a periodic texture (stripes a few centimetres apart) alias.
pub const RANGE_M: f64 = 0.010;
/// Grid step of the sweep (m); the parabola refines within it.
pub const STEP_M: f64 = 0.0005;
/// Best minus worst score below which the table's height is not trusted. Plain tables correlate
/// through their shading alone (0.03–0.05 on seq_101 and seq_109). A texture finer than the refined
/// cameras' remaining disagreement (wood rings 6–9 mm apart, with perturbed inputs) rises by
/// 0.06–0.31 and can peak at an alias up to 9 mm off; the checkered, striped and marble tables rise
/// by 0.46–0.92 and their heights came within 0.1–0.8 mm of the truth (BENCHMARKS.md §8).
pub const MIN_CONTRAST: f64 = 0.4;
/// The highest contrast the aliasing wood rings reached (see [`MIN_CONTRAST`]): below it a peak is
/// not trusted at all.
pub const MIN_FAINT_CONTRAST: f64 = 0.31;
/// Share of the sweep's variance a single parabola must explain for a low-contrast curve to count as
/// a plain table's broad hump: 0.94–0.999 on plain tables, 0.10–0.42 on the aliasing wood rings.
pub const MIN_HUMP: f64 = 0.9;
/// The share of a broad reading's height a refined frame is moved by. The whole height
/// over-corrects on plain tables, as if the model followed a frame seen too low only in part: on the
/// public plain-table runs it lowered t=0 in 8 of 14, half of it raised 13 (BENCHMARKS.md §8,
/// "Plain tables"). Textured tables keep the whole move, which did as well as half there.
pub const BROAD_SHARE: f64 = 0.5;
/// Object masks are widened by this share of the image width (8 px at 640): a mask's edge, a
/// shadow's core and the refraction at a glass's rim stay out of the table's readings.
pub const MASK_MARGIN_SHARE: f64 = 1.0 / 80.0;
/// A height closer than this to z = 0 is left alone. The sweep comes within a few tenths of a
/// millimetre of the truth, but moves under a millimetre changed the depth scores by ±0.2 points
/// either way (with exact inputs seq_108's refined cameras see the table 0.57 mm low: moved, −0.2).
pub const MIN_TABLE_SHIFT_M: f64 = 0.001;
/// With the poses kept as given, a textured table this far off z = 0 is reported (`trand
/// reconstruct` warns), not moved.
pub const WARN_M: f64 = 0.005;
/// About this many table pixels are sampled per view (a regular grid).
const SAMPLES_PER_VIEW: f64 = 30_000.0;
/// View pairs with fewer common table samples than this are left out of the score.
const MIN_PAIR_SAMPLES: usize = 500;

/// The sweep's result, as `run.json` reports it.
#[derive(Clone, Copy, Debug, Serialize, PartialEq)]
pub struct TableFit {
    /// Height of the table plane in the cameras' frame (m).
    pub height_m: f64,
    /// Mean cross-correlation at the best grid height.
    pub peak: f64,
    /// Best minus worst score over the grid.
    pub contrast: f64,
    /// Whether the best grid height lies strictly inside the sweep.
    pub interior: bool,
    /// Share of the scores' variance explained by one downward parabola whose vertex lies inside the
    /// sweep (0 when the best parabola opens upwards or peaks outside): [`hump`].
    pub hump: f64,
}

impl TableFit {
    /// A clear peak inside the sweep: a textured table.
    pub fn textured(&self) -> bool {
        self.interior && self.contrast >= MIN_CONTRAST
    }

    /// One smooth hump with its top inside the sweep: a plain table's shading and shadows.
    pub fn broad(&self) -> bool {
        self.interior && self.hump >= MIN_HUMP
    }

    /// A peak inside the sweep above the aliases' contrast but under [`MIN_CONTRAST`].
    pub fn faint(&self) -> bool {
        self.interior && self.contrast > MIN_FAINT_CONTRAST && self.contrast < MIN_CONTRAST
    }

    /// How the height was read, `None` when it is not trusted (module docs).
    pub fn reading(&self) -> Option<Reading> {
        if self.textured() {
            Some(Reading::Textured)
        } else if self.broad() {
            Some(Reading::Broad)
        } else if self.faint() {
            Some(Reading::Faint)
        } else {
            None
        }
    }

    /// The share of the measured height a refined frame is moved by: all of it for a texture,
    /// [`BROAD_SHARE`] for a broad hump, [`faint_share`] for a faint peak, none when the height is
    /// not trusted.
    pub fn share(&self) -> f64 {
        match self.reading() {
            Some(Reading::Textured) => 1.0,
            Some(Reading::Broad) => BROAD_SHARE,
            Some(Reading::Faint) => faint_share(self.contrast),
            None => 0.0,
        }
    }
}

/// A faint peak's share: linear in the contrast from 0 at [`MIN_FAINT_CONTRAST`] to 1 at
/// [`MIN_CONTRAST`], so that a reading near either end moves the frame about as its neighbour does.
pub fn faint_share(contrast: f64) -> f64 {
    ((contrast - MIN_FAINT_CONTRAST) / (MIN_CONTRAST - MIN_FAINT_CONTRAST)).clamp(0.0, 1.0)
}

/// Which kind of sweep curve gave a trusted height (module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Reading {
    /// A sharp peak: the table's texture.
    Textured,
    /// One smooth hump: a plain table's shading and soft shadows.
    Broad,
    /// A peak under the textured contrast, above the aliases'.
    Faint,
}

/// What a run did about the table's height, as `run.json` reports it.
#[derive(Clone, Copy, Debug, Serialize, PartialEq)]
pub struct TableLevel {
    /// The sweep through the refined cameras (`None` when no two views saw the table).
    pub fit: Option<TableFit>,
    /// How the height was read when it was trusted (`textured`, `broad` or `faint`, module docs).
    pub reading: Option<Reading>,
    /// The move (m): the table's height in the frame training used times the reading's
    /// [`TableFit::share`] when the fit was trusted and at least [`MIN_TABLE_SHIFT_M`] off z = 0,
    /// else 0. The surfels moved by minus this along z, the cameras with them. The heights
    /// `run.json` reports of the training's decisions (`vessel_tops`) are those before the move.
    pub shifted_m: f64,
}

/// One view's sampled table pixels and what the others read them with.
struct Sampled<'a> {
    /// Unit ray and grey value per sample.
    rays: Vec<(DVec3, f32)>,
    grey: &'a [f32],
    blocked: Vec<bool>,
    size: (usize, usize),
    camera: Camera,
}

/// Sweeps the table's height as seen by `views` through `cameras` (one per view, in order).
/// `None` when fewer than two views see the table.
pub fn measure(views: &[TrainView], cameras: &[Camera]) -> Option<TableFit> {
    let focus = trand_core::camera::focus_point(cameras)?;
    let distance: f64 = cameras.iter().map(|c| c.center().distance(focus)).sum();
    let radius = 0.5 * distance / cameras.len() as f64;
    let sampled: Vec<Sampled> = views
        .iter()
        .zip(cameras)
        .map(|(v, c)| sample(v, *c))
        .collect();
    let steps = (RANGE_M / STEP_M).round() as i64;
    let heights: Vec<f64> = (-steps..=steps).map(|k| k as f64 * STEP_M).collect();
    let scores: Vec<Option<f64>> = heights
        .par_iter()
        .map(|&h| score(&sampled, h, focus, radius))
        .collect();
    let scores: Option<Vec<f64>> = scores.into_iter().collect();
    let scores = scores?;
    let (best, &peak) = scores
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.total_cmp(b.1))?;
    let worst = scores.iter().copied().fold(f64::INFINITY, f64::min);
    let interior = best > 0 && best + 1 < scores.len();
    let offset = if interior {
        let (a, b, c) = (scores[best - 1], peak, scores[best + 1]);
        let den = a - 2.0 * b + c;
        if den < 0.0 {
            (0.5 * (a - c) / den).clamp(-0.5, 0.5)
        } else {
            0.0
        }
    } else {
        0.0
    };
    Some(TableFit {
        height_m: heights[best] + offset * STEP_M,
        peak,
        contrast: peak - worst,
        interior,
        hump: hump(&heights, &scores),
    })
}

/// `view`'s table samples: a regular pixel grid, outside the widened object masks.
fn sample(view: &TrainView, camera: Camera) -> Sampled<'_> {
    let (w, h) = (view.width, view.height);
    let grey = &view.grey;
    let margin = (w as f64 * MASK_MARGIN_SHARE).ceil() as usize;
    let blocked = widen(&view.given_ids, (w, h), margin);
    let step = ((w * h) as f64 / SAMPLES_PER_VIEW).sqrt().max(1.0) as usize;
    let mut rays = Vec::new();
    for y in (margin..h.saturating_sub(margin)).step_by(step) {
        for x in (margin..w.saturating_sub(margin)).step_by(step) {
            let i = y * w + x;
            if !blocked[i] {
                rays.push((camera.ray_direction(x as f64, y as f64), grey[i]));
            }
        }
    }
    Sampled {
        rays,
        grey,
        blocked,
        size: (w, h),
        camera,
    }
}

/// Object pixels of `ids` grown by `r` pixels (a square window, two separable passes).
pub(crate) fn widen(ids: &[u16], (w, h): (usize, usize), r: usize) -> Vec<bool> {
    let mut rows = vec![false; w * h];
    for y in 0..h {
        for x in 0..w {
            if ids[y * w + x] != 0 {
                let row = &mut rows[y * w..(y + 1) * w];
                row[x.saturating_sub(r)..(x + r + 1).min(w)].fill(true);
            }
        }
    }
    let mut out = vec![false; w * h];
    for y in 0..h {
        for x in 0..w {
            if rows[y * w + x] {
                for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
                    out[yy * w + x] = true;
                }
            }
        }
    }
    out
}

/// Mean ZNCC over ordered view pairs of the table cast onto `z = height` (module docs), `None` when
/// no pair shares enough of it.
fn score(views: &[Sampled], height: f64, focus: DVec3, radius: f64) -> Option<f64> {
    let mut sum = 0.0;
    let mut pairs = 0;
    for (a, va) in views.iter().enumerate() {
        let centre = va.camera.center();
        let points: Vec<(DVec3, f32)> = va
            .rays
            .iter()
            .filter_map(|&(d, g)| {
                let lambda = (height - centre.z) / d.z;
                let p = centre + lambda * d;
                let near = (p.x - focus.x).hypot(p.y - focus.y) < radius;
                (lambda > 0.0 && near).then_some((p, g))
            })
            .collect();
        for (b, vb) in views.iter().enumerate() {
            if a == b {
                continue;
            }
            let mut acc = Zncc::default();
            for &(p, ga) in &points {
                if let Some(gb) = read(vb, p) {
                    acc.add(ga as f64, gb as f64);
                }
            }
            if acc.n >= MIN_PAIR_SAMPLES {
                sum += acc.value();
                pairs += 1;
            }
        }
    }
    (pairs > 0).then(|| sum / pairs as f64)
}

/// `view`'s grey value at `p`'s image (bilinear, pixel centres at integer coordinates), `None`
/// outside the image or on a widened object mask.
fn read(view: &Sampled, p: DVec3) -> Option<f32> {
    let (x, y, _) = view.camera.project(p)?;
    let (w, h) = view.size;
    if x < 0.0 || y < 0.0 || x >= (w - 1) as f64 || y >= (h - 1) as f64 {
        return None;
    }
    let (x0, y0) = (x as usize, y as usize);
    let near = (y.round() as usize) * w + x.round() as usize;
    if view.blocked[near] {
        return None;
    }
    let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
    let g = |xx: usize, yy: usize| view.grey[yy * w + xx];
    let top = g(x0, y0) * (1.0 - fx) + g(x0 + 1, y0) * fx;
    let bottom = g(x0, y0 + 1) * (1.0 - fx) + g(x0 + 1, y0 + 1) * fx;
    Some(top * (1.0 - fy) + bottom * fy)
}

/// Running sums of a zero-mean normalised cross-correlation.
#[derive(Default)]
struct Zncc {
    n: usize,
    a: f64,
    b: f64,
    aa: f64,
    bb: f64,
    ab: f64,
}

impl Zncc {
    fn add(&mut self, a: f64, b: f64) {
        self.n += 1;
        self.a += a;
        self.b += b;
        self.aa += a * a;
        self.bb += b * b;
        self.ab += a * b;
    }

    fn value(&self) -> f64 {
        let n = self.n as f64;
        let cov = self.ab - self.a * self.b / n;
        let va = self.aa - self.a * self.a / n;
        let vb = self.bb - self.b * self.b / n;
        if va <= 0.0 || vb <= 0.0 {
            return 0.0;
        }
        cov / (va * vb).sqrt()
    }
}

#[cfg(test)]
mod tests {
    use super::painted::{soft_shadows, speckle, views_of_table};
    use super::*;

    fn fit(height: f64, paint: fn(f64, f64) -> f32) -> TableFit {
        let views = views_of_table(height, paint);
        let cameras: Vec<Camera> = views.iter().map(|v| v.camera).collect();
        measure(&views, &cameras).expect("the views see the table")
    }

    #[test]
    fn a_textured_table_s_height_is_found_within_a_fifth_of_a_millimetre() {
        for height in [0.0, 0.0032, -0.0047] {
            let f = fit(height, speckle);
            assert!(f.textured(), "{f:?}");
            assert!((f.height_m - height).abs() < 2e-4, "{height}: {f:?}");
        }
    }

    fn peak(contrast: f64, hump: f64) -> TableFit {
        TableFit {
            height_m: -0.004,
            peak: 0.8,
            contrast,
            interior: true,
            hump,
        }
    }

    #[test]
    fn the_share_grows_with_a_faint_peak_s_contrast_without_a_step_at_either_end() {
        let share = |c: f64| peak(c, 0.0).share();
        assert_eq!(peak(MIN_FAINT_CONTRAST, 0.0).reading(), None);
        assert_eq!(peak(0.35, 0.0).reading(), Some(Reading::Faint));
        assert_eq!(peak(MIN_CONTRAST, 0.0).reading(), Some(Reading::Textured));
        assert!(share(MIN_FAINT_CONTRAST + 1e-9) < 1e-6);
        assert!((share(MIN_CONTRAST - 1e-9) - 1.0).abs() < 1e-6);
        let mid = 0.5 * (MIN_FAINT_CONTRAST + MIN_CONTRAST);
        assert!((share(mid) - 0.5).abs() < 1e-9);
        let grid: Vec<f64> = (0..=50)
            .map(|k| share(0.3 + 0.002 * f64::from(k)))
            .collect();
        assert!(grid.windows(2).all(|w| w[1] >= w[0]), "{grid:?}");
        // A broad hump keeps its own share; a curve that is neither is not trusted.
        assert_eq!(peak(0.34, MIN_HUMP).share(), BROAD_SHARE);
        assert_eq!(peak(0.2, 0.5).share(), 0.0);
        let edge = TableFit {
            interior: false,
            ..peak(0.38, 0.0)
        };
        assert_eq!(edge.share(), 0.0, "a peak at the sweep's end");
    }

    #[test]
    fn a_plain_table_lit_by_a_linear_gradient_alone_shows_no_height() {
        let f = fit(0.003, |x, y| (0.5 + 0.4 * x - 0.2 * y) as f32);
        assert_eq!(f.reading(), None, "{f:?}");
    }

    #[test]
    fn a_plain_table_s_soft_shadows_give_its_height_within_a_millimetre() {
        for height in [0.0035, -0.0042] {
            let f = fit(height, soft_shadows);
            assert_eq!(f.reading(), Some(Reading::Broad), "{f:?}");
            assert!((f.height_m - height).abs() < 1e-3, "{height}: {f:?}");
        }
    }

    #[test]
    fn widening_covers_the_square_around_each_object_pixel_and_nothing_else() {
        let (w, h) = (7, 5);
        let mut ids = vec![0u16; w * h];
        ids[2 * w + 3] = 4;
        let out = widen(&ids, (w, h), 1);
        for y in 0..h {
            for x in 0..w {
                let near = x.abs_diff(3) <= 1 && y.abs_diff(2) <= 1;
                assert_eq!(out[y * w + x], near, "({x}, {y})");
            }
        }
    }
}
