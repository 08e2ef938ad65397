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
//! **When the height is trusted.** Two kinds of curve are read, and one is refused:
//! - *Textured*: a sharp peak, the best score beating the worst by [`MIN_CONTRAST`] or more.
//! - *Broad*: a plain table correlates through its shading and soft shadows almost as well at any
//!   height (best minus worst 0.01–0.06), but the curve is one smooth hump whose top lies at the
//!   table: a single parabola fitted to the whole sweep explains [`MIN_HUMP`] or more of its
//!   variance, opens downwards and has its vertex inside the sweep. Over 96 refined runs on plain
//!   tables (seq_101, seq_109 and their perturbed copies, `trand synth` scenes) the best height of
//!   such a curve lay 0.5 mm from the refined cameras' vertical bias on average, within 1 mm in 91 %
//!   of them, 2.3 mm at worst. A plain table's height is trusted less than a texture's: a refined
//!   frame is moved by [`BROAD_SHARE`] of it.
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
/// Share of the sweep's variance a single parabola must explain for a low-contrast curve to count as
/// a plain table's broad hump: 0.94–0.999 on plain tables, 0.10–0.42 on the aliasing wood rings.
pub const MIN_HUMP: f64 = 0.9;
/// The share of a broad reading's height a refined frame is moved by. On plain tables the whole
/// height over-corrects, although it lies 0.5 mm from the refined cameras' vertical bias on
/// average: the model follows that bias only in part. On seq_109 and 13 perturbed copies of seq_101
/// and seq_109 the whole move changed t=0 depth within 2.5 cm by +0.05 points on average and
/// lowered 8 of the 14; half of it gained 0.61 and lowered one, by 0.24 (BENCHMARKS.md §8). Where a
/// plain table was seen above z = 0 (three synthetic copies) the whole move did better in two, by
/// 0.3–0.5: too few to split the rule by sign. On textured tables half the move (rendered at the
/// test cameras) did 0.12 worse on average over seven public copies and 0.37 better over ten
/// synthetic ones: the whole is kept there.
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

    /// How the height was read, `None` when it is not trusted (module docs).
    pub fn reading(&self) -> Option<Reading> {
        if self.textured() {
            Some(Reading::Textured)
        } else if self.broad() {
            Some(Reading::Broad)
        } else {
            None
        }
    }
}

/// Which kind of sweep curve gave a trusted height (module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Reading {
    /// A sharp peak: the table's texture.
    Textured,
    /// One smooth hump: a plain table's shading and soft shadows.
    Broad,
}

impl Reading {
    /// The share of the measured height a refined frame is moved by: all of it for a texture,
    /// [`BROAD_SHARE`] for a broad hump.
    pub fn share(self) -> f64 {
        match self {
            Reading::Textured => 1.0,
            Reading::Broad => BROAD_SHARE,
        }
    }
}

/// Share of the variance of `scores` (at `heights`) that the least-squares parabola explains, or 0
/// when that parabola opens upwards or has its vertex outside `heights`' range. A single hump scores
/// near 1; a comb of alias peaks, or a curve with no top, near 0.
pub fn hump(heights: &[f64], scores: &[f64]) -> f64 {
    let n = scores.len() as f64;
    if scores.len() < 3 {
        return 0.0;
    }
    // Normal equations of s ≈ a h² + b h + c, in h centred on the sweep for conditioning.
    let mid = 0.5 * (heights[0] + heights[heights.len() - 1]);
    let mut m = [[0.0f64; 3]; 3];
    let mut r = [0.0f64; 3];
    for (&h, &s) in heights.iter().zip(scores) {
        let x = h - mid;
        let f = [x * x, x, 1.0];
        for i in 0..3 {
            for j in 0..3 {
                m[i][j] += f[i] * f[j];
            }
            r[i] += f[i] * s;
        }
    }
    let Some([a, b, c]) = solve3(m, r) else {
        return 0.0;
    };
    let vertex = mid - b / (2.0 * a);
    let (lo, hi) = (
        heights[0].min(heights[heights.len() - 1]),
        heights[0].max(heights[heights.len() - 1]),
    );
    if a >= 0.0 || !(lo..=hi).contains(&vertex) {
        return 0.0;
    }
    let mean = scores.iter().sum::<f64>() / n;
    let total: f64 = scores.iter().map(|s| (s - mean).powi(2)).sum();
    let residual: f64 = heights
        .iter()
        .zip(scores)
        .map(|(&h, &s)| {
            let x = h - mid;
            (s - (a * x * x + b * x + c)).powi(2)
        })
        .sum();
    if total <= 0.0 {
        return 0.0;
    }
    (1.0 - residual / total).max(0.0)
}

/// Solves the 3×3 system `m x = r` by Cramer's rule, `None` when it is singular.
fn solve3(m: [[f64; 3]; 3], r: [f64; 3]) -> Option<[f64; 3]> {
    let det = |m: [[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det(m);
    if d.abs() < 1e-300 {
        return None;
    }
    let mut x = [0.0; 3];
    for (k, xk) in x.iter_mut().enumerate() {
        let mut mk = m;
        for i in 0..3 {
            mk[i][k] = r[i];
        }
        *xk = det(mk) / d;
    }
    Some(x)
}

/// What a run did about the table's height, as `run.json` reports it.
#[derive(Clone, Copy, Debug, Serialize, PartialEq)]
pub struct TableLevel {
    /// The sweep through the refined cameras (`None` when no two views saw the table).
    pub fit: Option<TableFit>,
    /// How the height was read when it was trusted (`textured` or `broad`, module docs).
    pub reading: Option<Reading>,
    /// The move (m): the table's height in the frame training used times the reading's
    /// [`Reading::share`] when the fit was trusted and at least [`MIN_TABLE_SHIFT_M`] off z = 0,
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
fn widen(ids: &[u16], (w, h): (usize, usize), r: usize) -> Vec<bool> {
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

/// Tables painted and seen from six views, for the tests of this module and of the frame's move.
#[cfg(test)]
pub(crate) mod painted {
    use super::*;
    use trand_core::Intrinsics;

    /// Value noise on an 8 mm grid (bilinear between hashed corners): a texture with no period.
    pub(crate) fn speckle(x: f64, y: f64) -> f32 {
        let corner = |i: i64, j: i64| {
            let mut k = (i.wrapping_mul(73_856_093) ^ j.wrapping_mul(19_349_663)) as u64;
            k ^= k >> 13;
            k = k.wrapping_mul(0x5bd1_e995);
            k ^= k >> 15;
            (k % 1000) as f64 / 1000.0
        };
        let (u, v) = (x / 0.008, y / 0.008);
        let (i, j) = (u.floor() as i64, v.floor() as i64);
        let (fu, fv) = (u - u.floor(), v - v.floor());
        let top = corner(i, j) * (1.0 - fu) + corner(i + 1, j) * fu;
        let bottom = corner(i, j + 1) * (1.0 - fu) + corner(i + 1, j + 1) * fu;
        (0.2 + 0.6 * (top * (1.0 - fv) + bottom * fv)) as f32
    }

    /// Six views around a table at `height` painted with `paint`, and a 3 cm object standing on it.
    pub(crate) fn views_of_table(height: f64, paint: fn(f64, f64) -> f32) -> Vec<TrainView> {
        let (w, h) = (320, 240);
        (0..6)
            .map(|k| {
                let a = k as f64 * std::f64::consts::TAU / 6.0;
                let eye = DVec3::new(0.6 * a.cos(), 0.6 * a.sin(), 0.45);
                let camera = Camera::look_at(
                    Intrinsics::centered(400.0, w as u32, h as u32),
                    eye,
                    DVec3::ZERO,
                    DVec3::Z,
                );
                let mut grey = vec![0.3; w * h];
                let mut ids = vec![0u16; w * h];
                for y in 0..h {
                    for x in 0..w {
                        let d = camera.ray_direction(x as f64, y as f64);
                        let p = eye + (height - eye.z) / d.z * d;
                        if d.z < 0.0 {
                            grey[y * w + x] = paint(p.x, p.y);
                            ids[y * w + x] = u16::from(p.truncate().length() < 0.03);
                        }
                    }
                }
                TrainView {
                    name: format!("{k}"),
                    camera,
                    width: w,
                    height: h,
                    rgb: Vec::new(),
                    grey,
                    mask: Vec::new(),
                    labels: Vec::new(),
                    label_counts: Vec::new(),
                    ids: ids.clone(),
                    given_ids: ids,
                    band: Vec::new(),
                }
            })
            .collect()
    }

    /// Soft shadows a few centimetres wide on an otherwise even table: a plain table's shading.
    pub(crate) fn soft_shadows(x: f64, y: f64) -> f32 {
        let blob = |cx: f64, cy: f64, s: f64| {
            (-((x - cx).powi(2) + (y - cy).powi(2)) / (2.0 * s * s)).exp()
        };
        (0.7 - 0.25 * blob(0.05, 0.02, 0.03)
            - 0.2 * blob(-0.06, 0.05, 0.04)
            - 0.15 * blob(0.0, -0.07, 0.05)
            + 0.1 * x) as f32
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

    /// Scores measured on public seq_109 (plain table, refined cameras 3 mm low) and on a `trand
    /// synth` wood table whose rings alias (perturbed poses), every 0.5 mm from −10 to +10 mm.
    const PLAIN_SEQ_109: [f64; 41] = [
        0.865, 0.867, 0.868, 0.870, 0.872, 0.874, 0.874, 0.875, 0.877, 0.878, 0.878, 0.879, 0.880,
        0.879, 0.879, 0.878, 0.878, 0.878, 0.878, 0.877, 0.876, 0.876, 0.875, 0.873, 0.871, 0.869,
        0.868, 0.866, 0.865, 0.863, 0.861, 0.858, 0.856, 0.854, 0.851, 0.849, 0.848, 0.845, 0.842,
        0.840, 0.837,
    ];
    const ALIASING_RINGS: [f64; 41] = [
        0.410, 0.439, 0.443, 0.433, 0.418, 0.403, 0.389, 0.376, 0.367, 0.366, 0.374, 0.383, 0.388,
        0.394, 0.405, 0.410, 0.402, 0.380, 0.366, 0.375, 0.402, 0.425, 0.428, 0.416, 0.403, 0.398,
        0.391, 0.377, 0.364, 0.367, 0.388, 0.412, 0.423, 0.419, 0.410, 0.402, 0.392, 0.381, 0.377,
        0.388, 0.405,
    ];

    fn sweep_heights() -> Vec<f64> {
        (-20..=20).map(|k| k as f64 * STEP_M).collect()
    }

    #[test]
    fn one_smooth_hump_is_broad_and_a_comb_of_aliases_is_not() {
        let h = sweep_heights();
        assert!(
            hump(&h, &PLAIN_SEQ_109) >= MIN_HUMP,
            "{}",
            hump(&h, &PLAIN_SEQ_109)
        );
        assert!(
            hump(&h, &ALIASING_RINGS) < 0.5,
            "{}",
            hump(&h, &ALIASING_RINGS)
        );
    }

    #[test]
    fn a_curve_without_a_top_inside_the_sweep_is_no_hump() {
        let h = sweep_heights();
        let flat = vec![0.9; h.len()];
        let rising: Vec<f64> = h.iter().map(|x| 0.5 + 10.0 * x).collect();
        let valley: Vec<f64> = h.iter().map(|x| 0.5 + 1e3 * x * x).collect();
        let top_outside: Vec<f64> = h.iter().map(|x| 0.5 - 1e3 * (x - 0.02).powi(2)).collect();
        for (name, s) in [
            ("flat", flat),
            ("rising", rising),
            ("valley", valley),
            ("top outside", top_outside),
        ] {
            assert_eq!(hump(&h, &s), 0.0, "{name}");
        }
        let top_inside: Vec<f64> = h.iter().map(|x| 0.5 - 1e3 * (x - 0.004).powi(2)).collect();
        assert!(hump(&h, &top_inside) > 0.999);
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
