//! The training cameras aligned on the table's texture before training: each view's pose relative
//! to the table plane, up to the one motion no image of a plane shows.
//!
//! **Why.** Pose refinement (`trand_train::pose`) fits each view's correction to the objects'
//! silhouettes and holds the mean correction at zero: the scene keeps the mean of the given poses'
//! errors, and six views half a degree and 3 mm off leave that at 1–5 mm at the objects (4.9 mm
//! on seq_108's copy with perturbation seed 3, which costs it 3.5 points of depth within 2.5 cm;
//! BENCHMARKS.md §8). A textured table fixes more of it. The table is the plane `z = 0`; a camera's
//! view of a plane fixes its pose relative to the plane except for a motion within the plane (a
//! turn about the vertical and a horizontal shift). So the views' relative poses and the scene's
//! height and tilt are read off the texture, and only those three common parameters are left to
//! the given poses, chosen where the implied per-view errors are likeliest.
//!
//! **Method** (direct alignment; Lucas–Kanade on a plane). Points on a regular grid of `z = 0`
//! (about one pixel's footprint apart) within half the cameras' mean distance of their focus are
//! projected into every view through its corrected camera `x_c = R (exp([ω]×) x + δ) + t` (the
//! correction of `trand_train::pose`, world frame) and read from its grey image, blurred. Points
//! whose projection lies on a widened object mask are left out of that view (refraction, caustics
//! at a rim). Each view is then stepped by Gauss–Newton against the mean of the *other* views'
//! readings `T(x)`: residual `r = I_i(π_i(x)) − (a_i T(x) + b_i)` (gain and offset per view,
//! fitted in closed form), Jacobian `∇I · ∂π/∂x_c · [−R [x']×, R]`, Huber-weighted at
//! [`HUBER_SIGMAS`] robust deviations (a table's edge, a wall, a specular highlight). The step adds
//! a Gaussian prior on each view's error ([`PRIOR_DEG`], [`PRIOR_MM`]: rotation about the camera's
//! centre and the centre's shift, `ε = ω`, `τ = δ + ω × C`) with the data weighted by
//! `1 / (σ² RESIDUAL_CORRELATION)`: neighbouring samples of a blurred image are far from
//! independent, and a striped wood texture fixes nothing along its stripes. Three scales (blur of
//! 4, 2, 1 pixels at 640 wide) widen the basin to several pixels. After each round the common
//! in-plane motion is set by the same prior (three unknowns, a linear least-squares problem).
//!
//! **When it is kept.** A plain table gives its shading, which slides under a pose change: the
//! alignment wanders there. It is kept only when the table's height sweep through the aligned
//! cameras (`table_height::measure`) reads a texture ([`TableFit::textured`]) and peaks
//! [`MIN_PEAK_GAIN`] higher than through the given cameras. Otherwise the given cameras are
//! trained from, as before.

use glam::{DMat3, DVec3};
use rayon::prelude::*;
use serde::Serialize;
use trand_core::Camera;
use trand_train::pose::{corrected, rotation};

use crate::table_height::{self, MASK_MARGIN_SHARE, TableFit, widen};
use crate::targets::{CoarseViews, TrainView};

mod level;

use level::Level;

/// Prior on each view's orientation error (degrees, per axis scale): a hand-eye calibration's.
pub const PRIOR_DEG: f64 = 0.5;
/// Prior on each camera centre's error (mm).
pub const PRIOR_MM: f64 = 3.0;
/// How many grid samples count as one independent observation (module docs). With 1, seq_105's
/// striped table drifted along its stripes (its pose seed-2 copy: 3.5 → 5.0 mm off at the
/// objects); 30 still 3.3 mm; 300 0.9 mm, seq_108's seed-3 copy 4.9 → 1.2 mm.
pub const RESIDUAL_CORRELATION: f64 = 300.0;
/// Huber threshold in robust deviations (1.4826 · the residuals' median absolute value).
pub const HUBER_SIGMAS: f64 = 2.0;
/// Blur of each scale, as a share of the image width (4, 2 and 1 px at 640).
const SCALES: [f64; 3] = [1.0 / 160.0, 1.0 / 320.0, 1.0 / 640.0];
/// The height sweep's peak must rise by this much through the aligned cameras for them to be
/// kept: cameras that already agree are left as given, not moved by the alignment's own noise. With
/// exact poses seq_105's peak rose by 0.0001 (and its depth within 2.5 cm fell 0.5 points when the
/// aligned cameras were kept); on the perturbed copies of seq_105 and seq_108 it rose by 0.16–0.64.
pub const MIN_PEAK_GAIN: f64 = 0.02;
/// Gauss–Newton rounds per scale.
const ROUNDS: usize = 8;
/// Grid step on the table, in pixels' footprints at the cameras' mean distance.
const STEP_PX: f64 = 1.5;
/// Samples within this many pixels of an image's edge are not read.
const BORDER_PX: f64 = 2.0;
/// A view is stepped only with at least this many samples that two other views also see.
const MIN_SAMPLES: usize = 2000;

/// Whether the training cameras are aligned on the table before training (module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, serde::Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum TableAlign {
    /// Aligned where the table's texture shows it, with the poses refined and the views spread.
    #[default]
    Texture,
    /// The given cameras, as training refines them.
    Off,
}

/// What the alignment found, as `run.json` reports it.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct TableAlignment {
    /// Whether training started from the aligned cameras (module docs: when it is kept).
    pub kept: bool,
    /// The table's height sweep through the given cameras.
    pub given: Option<TableFit>,
    /// The sweep through the aligned cameras.
    pub aligned: Option<TableFit>,
    /// Per view: the correction `(ω, δ)` (world frame, radians and metres) from the given camera to
    /// the aligned one, applied to the training views' cameras when `kept`.
    pub corrections: Vec<[f64; 6]>,
    /// Per view: the correction's rotation (degrees) and its camera centre's move (mm).
    pub magnitudes: Vec<(f64, f64)>,
}

impl TableAlignment {
    /// `camera` (view `i`'s given one) as training uses it: aligned when kept.
    pub fn camera(&self, i: usize, camera: &Camera) -> Camera {
        if self.kept {
            corrected(self.corrections[i], camera)
        } else {
            *camera
        }
    }

    /// Every level's views (training resolution and coarse) moved to the cameras training uses:
    /// aligned when kept, as given otherwise.
    pub fn apply(&self, views: &mut [TrainView], coarse: &mut [CoarseViews]) {
        if !self.kept {
            return;
        }
        let levels = std::iter::once(views).chain(coarse.iter_mut().map(|c| &mut c.views[..]));
        for level in levels {
            for (i, v) in level.iter_mut().enumerate() {
                v.camera = self.camera(i, &v.camera);
            }
        }
    }
}

/// Aligns `views`' cameras on the table (module docs); `None` when fewer than three views see it.
pub fn align(views: &[TrainView]) -> Option<TableAlignment> {
    let given: Vec<Camera> = views.iter().map(|v| v.camera).collect();
    let focus = trand_core::camera::focus_point(&given)?;
    let centres: Vec<DVec3> = given.iter().map(Camera::center).collect();
    let distance = centres.iter().map(|c| c.distance(focus)).sum::<f64>() / views.len() as f64;
    let step = STEP_PX * distance / given[0].intrinsics.fx;
    let points = table_grid(focus, 0.5 * distance, step);
    let blocked: Vec<Vec<bool>> = views
        .iter()
        .map(|v| {
            let margin = (v.width as f64 * MASK_MARGIN_SHARE).ceil() as usize;
            widen(&v.given_ids, (v.width, v.height), margin)
        })
        .collect();
    let mut xi = vec![[0.0; 6]; views.len()];
    for share in SCALES {
        let levels: Vec<Level> = views
            .par_iter()
            .map(|v| Level::new(&v.grey, (v.width, v.height), share * v.width as f64))
            .collect();
        for _ in 0..ROUNDS {
            let readings: Vec<Vec<Option<f64>>> = (0..views.len())
                .into_par_iter()
                .map(|i| {
                    read_all(
                        &levels[i],
                        &blocked[i],
                        &corrected(xi[i], &given[i]),
                        &points,
                    )
                })
                .collect();
            let steps: Vec<Option<[f64; 6]>> = (0..views.len())
                .into_par_iter()
                .map(|i| {
                    let target = others_mean(&readings, i);
                    let cam = corrected(xi[i], &given[i]);
                    gauss_newton_step(
                        &levels[i],
                        &blocked[i],
                        &given[i],
                        &cam,
                        xi[i],
                        &points,
                        &target,
                    )
                })
                .collect();
            for (x, s) in xi.iter_mut().zip(steps) {
                if let Some(s) = s {
                    (0..6).for_each(|a| x[a] += s[a]);
                }
            }
            hold_in_plane_gauge(&mut xi, &centres);
        }
    }
    let aligned: Vec<Camera> = given
        .iter()
        .zip(&xi)
        .map(|(c, x)| corrected(*x, c))
        .collect();
    let fit_given = table_height::measure(views, &given);
    let fit_aligned = table_height::measure(views, &aligned);
    let kept = match (fit_given, fit_aligned) {
        (Some(g), Some(a)) => a.textured() && a.peak >= g.peak + MIN_PEAK_GAIN,
        (None, Some(a)) => a.textured(),
        _ => false,
    };
    let magnitudes = xi
        .iter()
        .zip(&centres)
        .map(|(x, c)| {
            let (w, d) = (DVec3::from_slice(&x[..3]), DVec3::from_slice(&x[3..]));
            (w.length().to_degrees(), (d + w.cross(*c)).length() * 1e3)
        })
        .collect();
    Some(TableAlignment {
        kept,
        given: fit_given,
        aligned: fit_aligned,
        corrections: xi,
        magnitudes,
    })
}

/// Points of `z = 0` on a square grid of `step` within `radius` of `focus` (horizontally).
fn table_grid(focus: DVec3, radius: f64, step: f64) -> Vec<DVec3> {
    let n = (radius / step).ceil() as i64;
    let mut points = Vec::new();
    for j in -n..=n {
        for i in -n..=n {
            let (x, y) = (i as f64 * step, j as f64 * step);
            if x.hypot(y) < radius {
                points.push(DVec3::new(focus.x + x, focus.y + y, 0.0));
            }
        }
    }
    points
}

/// The pixel `camera` sees `p` at, inside the image and off every widened mask.
fn pixel(level: &Level, blocked: &[bool], camera: &Camera, p: DVec3) -> Option<(f64, f64, f64)> {
    let (x, y, z) = camera.project(p)?;
    let (xr, yr) = (x.round(), y.round());
    if xr < 0.0 || yr < 0.0 || xr >= level.width as f64 || yr >= level.height as f64 {
        return None;
    }
    (!blocked[yr as usize * level.width + xr as usize]).then_some((x, y, z))
}

/// Every point's blurred grey value in one view, `None` where it is not seen.
fn read_all(
    level: &Level,
    blocked: &[bool],
    camera: &Camera,
    points: &[DVec3],
) -> Vec<Option<f64>> {
    points
        .iter()
        .map(|&p| {
            let (x, y, _) = pixel(level, blocked, camera, p)?;
            level.read(x, y, BORDER_PX).map(|(v, _, _)| v)
        })
        .collect()
}

/// Per point, the mean reading of the views other than `i`, where at least two of them see it.
fn others_mean(readings: &[Vec<Option<f64>>], i: usize) -> Vec<Option<f64>> {
    (0..readings[i].len())
        .map(|k| {
            let (mut sum, mut n) = (0.0, 0usize);
            for (j, r) in readings.iter().enumerate() {
                if let (true, Some(v)) = (j != i, r[k]) {
                    sum += v;
                    n += 1;
                }
            }
            (n >= 2).then(|| sum / n as f64)
        })
        .collect()
}

/// One damped Gauss–Newton step of view `xi` (module docs), `None` with too few samples.
fn gauss_newton_step(
    level: &Level,
    blocked: &[bool],
    given: &Camera,
    camera: &Camera,
    xi: [f64; 6],
    points: &[DVec3],
    target: &[Option<f64>],
) -> Option<[f64; 6]> {
    let r_given = given.rotation();
    let turn = rotation(DVec3::from_slice(&xi[..3]));
    let k = camera.intrinsics;
    // (value, target, jacobian) per sample.
    let mut samples: Vec<(f64, f64, [f64; 6])> = Vec::new();
    for (&p, &t) in points.iter().zip(target) {
        let Some(t) = t else { continue };
        let Some((x, y, _)) = pixel(level, blocked, camera, p) else {
            continue;
        };
        let Some((v, gx, gy)) = level.read(x, y, BORDER_PX) else {
            continue;
        };
        let xc = camera.world_to_camera(p);
        let (du, dv) = (
            DVec3::new(k.fx / xc.z, 0.0, -k.fx * xc.x / (xc.z * xc.z)),
            DVec3::new(0.0, k.fy / xc.z, -k.fy * xc.y / (xc.z * xc.z)),
        );
        // d value / d x_c, then through x_c = R (x' + δ) + t with x' = exp([ω]×) p.
        let g_c = gx * du + gy * dv;
        let g_w = r_given.transpose() * g_c;
        let moved = turn * p;
        let d_omega = moved.cross(g_w);
        samples.push((v, t, [d_omega.x, d_omega.y, d_omega.z, g_w.x, g_w.y, g_w.z]));
    }
    if samples.len() < MIN_SAMPLES {
        return None;
    }
    let (gain, offset) = affine_fit(&samples);
    let residuals: Vec<f64> = samples
        .iter()
        .map(|(v, t, _)| v - (gain * t + offset))
        .collect();
    let scale = robust_scale(&residuals)?;
    let variance = residuals.iter().map(|r| r * r).sum::<f64>() / residuals.len() as f64;
    let data_weight = 1.0 / (variance.max(1e-12) * RESIDUAL_CORRELATION);
    let mut h = [[0.0; 6]; 6];
    let mut b = [0.0; 6];
    for ((_, _, j), &r) in samples.iter().zip(&residuals) {
        let c = HUBER_SIGMAS * scale;
        let w = data_weight * if r.abs() <= c { 1.0 } else { c / r.abs() };
        for a in 0..6 {
            b[a] -= w * j[a] * r;
            for bb in 0..6 {
                h[a][bb] += w * j[a] * j[bb];
            }
        }
    }
    add_prior(&mut h, &mut b, xi, given.center());
    solve6(h, b)
}

/// Gain and offset with `value ≈ gain · target + offset` (least squares).
fn affine_fit(samples: &[(f64, f64, [f64; 6])]) -> (f64, f64) {
    let n = samples.len() as f64;
    let (mut st, mut sv, mut stt, mut stv) = (0.0, 0.0, 0.0, 0.0);
    for &(v, t, _) in samples {
        st += t;
        sv += v;
        stt += t * t;
        stv += t * v;
    }
    let var = stt - st * st / n;
    if var <= 1e-12 {
        return (1.0, (sv - st) / n);
    }
    let gain = (stv - st * sv / n) / var;
    (gain, (sv - gain * st) / n)
}

/// 1.4826 times the median absolute residual; `None` when it is zero.
fn robust_scale(residuals: &[f64]) -> Option<f64> {
    let mut a: Vec<f64> = residuals.iter().map(|r| r.abs()).collect();
    let mid = a.len() / 2;
    let (_, m, _) = a.select_nth_unstable_by(mid, f64::total_cmp);
    let s = 1.4826 * *m;
    (s > 0.0).then_some(s)
}

/// Adds the prior `|ω|²/σ_r² + |δ + ω × C|²/σ_t²` (module docs) at `xi` to the normal equations of
/// the step `dξ`: `H += LᵀWL`, `b −= LᵀWL ξ` with `L ξ = (ω, δ + ω × C)`.
fn add_prior(h: &mut [[f64; 6]; 6], b: &mut [f64; 6], xi: [f64; 6], centre: DVec3) {
    let (wr, wt) = (
        1.0 / PRIOR_DEG.to_radians().powi(2),
        1.0 / (PRIOR_MM * 1e-3).powi(2),
    );
    // L as rows: the first three pick ω; the last three δ + ω × C = δ − [C]× ω.
    let mut l = [[0.0; 6]; 6];
    let cx = [
        [0.0, -centre.z, centre.y],
        [centre.z, 0.0, -centre.x],
        [-centre.y, centre.x, 0.0],
    ];
    for a in 0..3 {
        l[a][a] = 1.0;
        l[3 + a][3 + a] = 1.0;
        for c in 0..3 {
            l[3 + a][c] = -cx[a][c];
        }
    }
    let weight = [wr, wr, wr, wt, wt, wt];
    for r in 0..6 {
        let lx: f64 = (0..6).map(|c| l[r][c] * xi[c]).sum();
        for a in 0..6 {
            b[a] -= l[r][a] * weight[r] * lx;
            for c in 0..6 {
                h[a][c] += l[r][a] * weight[r] * l[r][c];
            }
        }
    }
}

/// Solves `h x = b` (Gaussian elimination with partial pivoting); `None` when singular.
fn solve6(mut h: [[f64; 6]; 6], mut b: [f64; 6]) -> Option<[f64; 6]> {
    for col in 0..6 {
        let pivot = (col..6).max_by(|&i, &j| h[i][col].abs().total_cmp(&h[j][col].abs()))?;
        if h[pivot][col].abs() < 1e-300 {
            return None;
        }
        h.swap(col, pivot);
        b.swap(col, pivot);
        for row in col + 1..6 {
            let f = h[row][col] / h[col][col];
            let top = h[col];
            for (dst, src) in h[row][col..].iter_mut().zip(&top[col..]) {
                *dst -= f * src;
            }
            b[row] -= f * b[col];
        }
    }
    let mut x = [0.0; 6];
    for row in (0..6).rev() {
        let s: f64 = (row + 1..6).map(|c| h[row][c] * x[c]).sum();
        x[row] = (b[row] - s) / h[row][row];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// Adds to every correction the common in-plane motion `g = (0, 0, φ, g_x, g_y, 0)` that minimises
/// `Σ ρ² |ω_i + g_ω|² + |δ_i + g_δ + (ω_i + g_ω) × C_i|²`, `ρ` = [`PRIOR_MM`] / [`PRIOR_DEG`]: the
/// part of the scene's pose the table does not show is where the per-view errors are likeliest.
fn hold_in_plane_gauge(xi: &mut [[f64; 6]], centres: &[DVec3]) {
    let rho = PRIOR_MM * 1e-3 / PRIOR_DEG.to_radians();
    let mut a = [[0.0; 3]; 3];
    let mut rhs = [0.0; 3];
    for (x, c) in xi.iter().zip(centres) {
        let (w, d) = (DVec3::from_slice(&x[..3]), DVec3::from_slice(&x[3..]));
        let r0 = [rho * w, d + w.cross(*c)];
        // Columns of ∂r/∂(φ, g_x, g_y).
        let cols = [
            [rho * DVec3::Z, DVec3::Z.cross(*c)],
            [DVec3::ZERO, DVec3::X],
            [DVec3::ZERO, DVec3::Y],
        ];
        for i in 0..3 {
            rhs[i] -= cols[i][0].dot(r0[0]) + cols[i][1].dot(r0[1]);
            for j in 0..3 {
                a[i][j] += cols[i][0].dot(cols[j][0]) + cols[i][1].dot(cols[j][1]);
            }
        }
    }
    let m = DMat3::from_cols_array_2d(&a).transpose();
    if m.determinant().abs() < 1e-18 {
        return;
    }
    let g = m.inverse() * DVec3::from_array(rhs);
    for x in xi.iter_mut() {
        x[2] += g.x;
        x[3] += g.y;
        x[4] += g.z;
    }
}

#[cfg(test)]
mod tests;
