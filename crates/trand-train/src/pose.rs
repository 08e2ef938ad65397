//! Per-view pose refinement: a small rigid correction of each training camera, optimised with the
//! surfels.
//!
//! A robot's hand-eye calibration puts each view a fraction of a degree and a few millimetres off.
//! Half a degree is five pixels at 640×480: the masks of different views then disagree about every
//! silhouette edge, and the surfels settle where no view is satisfied (on the Blender sequences that
//! costs 2–10 points of depth within 2.5 cm). Here each training view `i` sees the world moved by its
//! own correction `ξ_i = (ω_i, δ_i)`:
//!
//! `x_c = R_i (exp([ω_i]×) x + δ_i) + t_i`, so `R'_i = R_i exp([ω_i]×)`, `t'_i = R_i δ_i + t_i`.
//!
//! **Gradient.** The rasterizer returns `∂L/∂(ω_c, δ_c)` for a motion `x_c ↦ exp([ω_c]×) x_c + δ_c` of
//! the camera frame (`trand_render::Gradients::camera`). A world motion `(dω, dδ)` applied after the
//! current correction moves camera points by `ω_c = R dω`, `δ_c = R dδ + t × R dω` (with the view's
//! uncorrected `R`, `t`), hence `∂L/∂dω = Rᵀ(∂L/∂ω_c + ∂L/∂δ_c × t)`, `∂L/∂dδ = Rᵀ ∂L/∂δ_c`. The
//! update adds `dξ` to `ξ` (composition is additive to first order; corrections stay below a degree).
//!
//! **Gauge.** Moving the whole scene and every camera together changes no image, so only the views'
//! corrections relative to each other are observable. After each step the mean correction over the
//! views is subtracted: the cameras keep their average pose, which is the best estimate when the
//! errors are independent per view (a bias shared by every view cannot be seen in the images). The
//! table's height through the corrected cameras (`trand_pipeline::table_height`) is the one part of
//! that bias that can be measured: once training ends, [`PoseCorrections::shift_world`] moves the
//! whole frame towards it (and would hold the mean correction there if training went on). A scaling of every camera
//! centre is nearly a gauge too (the scene scaled with its cameras looks alike): the cameras drift
//! along their rays, which the mean turns into a vertical shift of the frame, yet removing that mode
//! as well, or holding each camera's distance to the scene, cost depth (BENCHMARKS.md §10).
//!
//! Each view has its own Adam moments and step count (a view is stepped only in the iterations that
//! render it); the learning rates decay log-linearly to `final_ratio` over the run.

use glam::{DMat3, DVec3};
use serde::{Deserialize, Serialize};
use trand_core::Camera;

/// Whether and how the training cameras' poses are refined.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PoseRefinement {
    /// The poses are taken as exact.
    Fixed,
    /// Each view's pose gets a correction (module docs), stepped from `from_iteration` on.
    Refine {
        from_iteration: u32,
        /// From this iteration the corrections count as settled: what a run decides once from the
        /// cameras before training (the opening prior) is decided again with the corrected ones when
        /// they moved the views by more than that decision resolves.
        settled_at: u32,
        /// Adam learning rate of the rotation vector (radians per step) at `from_iteration`.
        lr_rotation: f64,
        /// Adam learning rate of the translation (metres per step) at `from_iteration`.
        lr_translation: f64,
        /// The learning rates at the last iteration, as a share of the first.
        final_ratio: f64,
    },
}

impl PoseRefinement {
    /// The default for multi-view training: a view is stepped about 150 times, enough for a degree
    /// (5e-4 beat 2e-4 on exact and on perturbed poses of the Blender sequences, BENCHMARKS §10).
    pub fn refine() -> Self {
        PoseRefinement::Refine {
            from_iteration: 100,
            settled_at: 400,
            lr_rotation: 5e-4,
            lr_translation: 5e-4,
            final_ratio: 0.1,
        }
    }

    /// Whether the poses are refined at all.
    pub fn refines(self) -> bool {
        self != PoseRefinement::Fixed
    }

    /// Whether the corrections count as settled at `iteration` (never when the poses are fixed).
    pub fn settled(self, iteration: u32) -> bool {
        matches!(self, PoseRefinement::Refine { settled_at, .. } if iteration >= settled_at)
    }

    /// `(rotation, translation)` learning rates at `iteration` of a run ending at `last`, `None` when
    /// the poses are not stepped then.
    pub fn rates(self, iteration: u32, last: u32) -> Option<(f64, f64)> {
        let PoseRefinement::Refine {
            from_iteration,
            lr_rotation,
            lr_translation,
            final_ratio,
            ..
        } = self
        else {
            return None;
        };
        if iteration < from_iteration {
            return None;
        }
        let span = last.saturating_sub(from_iteration).max(1) as f64;
        let t = ((iteration - from_iteration) as f64 / span).min(1.0);
        let f = final_ratio.max(1e-12).powf(t);
        Some((lr_rotation * f, lr_translation * f))
    }
}

/// The corrections of every training view and their optimiser state.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PoseCorrections {
    /// Per view: `(ω, δ)`, world frame (radians, metres).
    pub xi: Vec<[f64; 6]>,
    /// `xi` as it was when the corrections were taken as settled ([`PoseRefinement::settled`]): the
    /// cameras the run's one-off decisions were retaken with, kept so a resumed run retakes them alike.
    pub settled: Option<Vec<[f64; 6]>>,
    /// The world translation every correction carries on top of the zero-mean gauge (m): what
    /// [`PoseCorrections::shift_world`] added.
    #[serde(default)]
    pub world_shift: [f64; 3],
    m: Vec<[f64; 6]>,
    v: Vec<[f64; 6]>,
    steps: Vec<u64>,
}

const BETA1: f64 = 0.9;
const BETA2: f64 = 0.999;
const EPS: f64 = 1e-12;

impl PoseCorrections {
    /// No correction for `n` views.
    pub fn new(n: usize) -> Self {
        Self {
            xi: vec![[0.0; 6]; n],
            settled: None,
            world_shift: [0.0; 3],
            m: vec![[0.0; 6]; n],
            v: vec![[0.0; 6]; n],
            steps: vec![0; n],
        }
    }

    /// Checks state read back from a file: `n` views in every array, finite values.
    pub fn validate(&self, n: usize) -> Result<(), String> {
        let lens = [self.xi.len(), self.m.len(), self.v.len(), self.steps.len()];
        if lens != [n; 4] {
            return Err(format!("pose corrections for {lens:?} views, expected {n}"));
        }
        let finite = |a: &[[f64; 6]]| a.iter().flatten().all(|v| v.is_finite());
        if self
            .settled
            .as_ref()
            .is_some_and(|s| s.len() != n || !finite(s))
        {
            return Err(format!("settled pose corrections do not fit {n} views"));
        }
        let shift = self.world_shift.iter().all(|v| v.is_finite());
        if !(finite(&self.xi) && finite(&self.m) && finite(&self.v) && shift) {
            return Err("pose corrections are not finite".into());
        }
        Ok(())
    }

    pub fn len(&self) -> usize {
        self.xi.len()
    }

    pub fn is_empty(&self) -> bool {
        self.xi.is_empty()
    }

    /// `cam` (view `view`'s given pose) with its correction applied.
    pub fn camera(&self, view: usize, cam: &Camera) -> Camera {
        corrected(self.xi[view], cam)
    }

    /// `cam` with view `view`'s settled correction, `None` before the corrections settled.
    pub fn settled_camera(&self, view: usize, cam: &Camera) -> Option<Camera> {
        self.settled.as_ref().map(|s| corrected(s[view], cam))
    }

    /// Takes the current corrections as settled ([`PoseCorrections::settled`]).
    pub fn settle(&mut self) {
        self.settled = Some(self.xi.clone());
    }

    /// One Adam step of view `view` from the rasterizer's camera-frame gradient `g_cam`
    /// (`trand_render::Gradients::camera`) of a render at `self.camera(view, cam)`, then the gauge
    /// (mean correction) is removed.
    pub fn step(&mut self, view: usize, cam: &Camera, g_cam: [f64; 6], (lr_w, lr_d): (f64, f64)) {
        let rt = cam.rotation().transpose();
        let gw = DVec3::from_slice(&g_cam[..3]);
        let gd = DVec3::from_slice(&g_cam[3..]);
        let g_omega = rt * (gw + gd.cross(cam.translation()));
        let g_delta = rt * gd;
        let g = [
            g_omega.x, g_omega.y, g_omega.z, g_delta.x, g_delta.y, g_delta.z,
        ];
        if !g.iter().all(|v| v.is_finite()) {
            return;
        }
        self.steps[view] += 1;
        let k = self.steps[view] as i32;
        let (c1, c2) = (1.0 - BETA1.powi(k), 1.0 - BETA2.powi(k));
        let (m, v, xi) = (&mut self.m[view], &mut self.v[view], &mut self.xi[view]);
        for (a, &ga) in g.iter().enumerate() {
            m[a] = BETA1 * m[a] + (1.0 - BETA1) * ga;
            v[a] = BETA2 * v[a] + (1.0 - BETA2) * ga * ga;
            let lr = if a < 3 { lr_w } else { lr_d };
            xi[a] -= lr * (m[a] / c1) / ((v[a] / c2).sqrt() + EPS);
        }
        self.remove_gauge();
    }

    /// Moves the world frame by `d` (m) under every camera, settled ones included: a world point `x`
    /// is then seen where `x + d` was, since `exp([ω]×)(x + d) + δ ≈ exp([ω]×) x + (δ + d)` to first
    /// order (corrections stay below a degree, `d` at a centimetre). The surfels must move by `−d`.
    pub fn shift_world(&mut self, d: [f64; 3]) {
        let shift = |x: &mut [f64; 6]| (0..3).for_each(|a| x[3 + a] += d[a]);
        self.xi.iter_mut().for_each(shift);
        if let Some(s) = self.settled.as_mut() {
            s.iter_mut().for_each(shift);
        }
        (0..3).for_each(|a| self.world_shift[a] += d[a]);
    }

    /// Sets the mean correction of the views to zero rotation and [`PoseCorrections::world_shift`]
    /// (module docs: gauge).
    fn remove_gauge(&mut self) {
        let n = self.xi.len() as f64;
        let mut mean = [0.0; 6];
        for x in &self.xi {
            for a in 0..6 {
                mean[a] += x[a] / n;
            }
        }
        for a in 0..3 {
            mean[3 + a] -= self.world_shift[a];
        }
        for x in &mut self.xi {
            for a in 0..6 {
                x[a] -= mean[a];
            }
        }
    }

    /// Per view: the correction's rotation in degrees and translation in millimetres.
    pub fn magnitudes(&self) -> Vec<(f64, f64)> {
        self.xi
            .iter()
            .map(|x| {
                let w = DVec3::new(x[0], x[1], x[2]).length().to_degrees();
                let d = DVec3::new(x[3], x[4], x[5]).length() * 1e3;
                (w, d)
            })
            .collect()
    }
}

/// `cam` seeing the world moved by `x = (ω, δ)` (module docs).
pub fn corrected(x: [f64; 6], cam: &Camera) -> Camera {
    if x == [0.0; 6] {
        return *cam;
    }
    let r = cam.rotation();
    Camera::from_glam(
        cam.intrinsics,
        r * rotation(DVec3::new(x[0], x[1], x[2])),
        r * DVec3::new(x[3], x[4], x[5]) + cam.translation(),
    )
}

/// `exp([ω]×)`.
pub fn rotation(w: DVec3) -> DMat3 {
    match w.try_normalize() {
        Some(axis) => DMat3::from_axis_angle(axis, w.length()),
        None => DMat3::IDENTITY,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use trand_core::Intrinsics;

    fn cam() -> Camera {
        Camera::look_at(
            Intrinsics::centered(500.0, 640, 480),
            DVec3::new(0.4, -0.5, 0.6),
            DVec3::new(0.02, 0.01, 0.05),
            DVec3::Z,
        )
    }

    /// The world-frame gradient [`PoseCorrections::step`] steps on: the derivative of a loss under a
    /// world motion applied after the current correction, `x ↦ exp([dω]×)(exp([ω]×)x + δ) + dδ`, at the
    /// corrected camera; and at `ξ = 0` the derivative under adding to `ξ` (what the update does).
    /// The loss is written on camera-frame points, so its camera-frame gradient is known in closed form.
    #[test]
    fn world_gradient_matches_finite_differences_of_the_corrected_camera() {
        let c = cam();
        let pts = [
            DVec3::new(0.0, 0.0, 0.05),
            DVec3::new(0.05, -0.03, 0.1),
            DVec3::new(-0.04, 0.02, 0.0),
        ];
        let a = [
            DVec3::new(0.3, -0.2, 0.5),
            DVec3::new(-0.1, 0.4, 0.2),
            DVec3::new(0.2, 0.1, -0.3),
        ];
        // L = Σ a_k · x_c,k; for x_c ↦ exp(ω)x_c + δ: ∂L/∂ω = Σ x_c × a, ∂L/∂δ = Σ a.
        let loss = |cam: &Camera| -> f64 {
            pts.iter()
                .zip(&a)
                .map(|(p, a)| a.dot(cam.world_to_camera(*p)))
                .sum()
        };
        for xi in [[0.0; 6], [0.003, -0.002, 0.001, 0.002, 0.001, -0.003]] {
            let mut pc = PoseCorrections::new(1);
            pc.xi[0] = xi;
            let cc = pc.camera(0, &c);
            let (mut gw, mut gd) = (DVec3::ZERO, DVec3::ZERO);
            for (p, a) in pts.iter().zip(&a) {
                gw += cc.world_to_camera(*p).cross(*a);
                gd += *a;
            }
            let rt = c.rotation().transpose();
            let g_omega = rt * (gw + gd.cross(c.translation()));
            let g_delta = rt * gd;
            let analytic = [
                g_omega.x, g_omega.y, g_omega.z, g_delta.x, g_delta.y, g_delta.z,
            ];
            for k in 0..6 {
                let h = 1e-6;
                // The world motion after the correction, composed exactly.
                let after = |s: f64| {
                    let mut d = [0.0; 6];
                    d[k] = s;
                    let dr = rotation(DVec3::new(d[0], d[1], d[2]));
                    let (r, t) = (c.rotation(), c.translation());
                    let delta = DVec3::new(xi[3], xi[4], xi[5]);
                    let cam = Camera::from_glam(
                        c.intrinsics,
                        r * dr * rotation(DVec3::new(xi[0], xi[1], xi[2])),
                        r * (dr * delta + DVec3::new(d[3], d[4], d[5])) + t,
                    );
                    loss(&cam)
                };
                let fd = (after(h) - after(-h)) / (2.0 * h);
                let tol = 1e-7 * analytic[k].abs().max(1.0);
                assert!(
                    (fd - analytic[k]).abs() < tol,
                    "ξ {xi:?}, component {k}: fd {fd} analytic {}",
                    analytic[k]
                );
                if xi == [0.0; 6] {
                    let additive = |s: f64| {
                        let mut q = pc.clone();
                        q.xi[0][k] += s;
                        loss(&q.camera(0, &c))
                    };
                    let fd = (additive(h) - additive(-h)) / (2.0 * h);
                    assert!((fd - analytic[k]).abs() < tol, "additive, component {k}");
                }
            }
        }
    }

    #[test]
    fn gauge_is_removed_so_corrections_average_to_zero() {
        let c = cam();
        let mut pc = PoseCorrections::new(3);
        pc.step(1, &c, [1.0, -2.0, 0.5, 0.3, 0.0, -1.0], (1e-3, 1e-3));
        pc.step(2, &c, [0.2, 0.1, -0.7, 0.0, 2.0, 0.4], (1e-3, 1e-3));
        let mut mean = [0.0; 6];
        for x in &pc.xi {
            for a in 0..6 {
                mean[a] += x[a];
            }
        }
        assert!(mean.iter().all(|m| m.abs() < 1e-15), "{mean:?}");
        assert!(pc.xi[1] != [0.0; 6] && pc.xi[0] != [0.0; 6]);
    }

    #[test]
    fn a_shifted_world_is_seen_where_the_shifted_point_was_and_the_gauge_keeps_the_shift() {
        let c = cam();
        let mut pc = PoseCorrections::new(3);
        pc.step(1, &c, [1.0, -2.0, 0.5, 0.3, 0.0, -1.0], (1e-3, 1e-3));
        pc.settle();
        let before = pc.camera(1, &c);
        let d = DVec3::new(0.0, 0.0, -0.004);
        pc.shift_world(d.to_array());
        let after = pc.camera(1, &c);
        let settled = pc.settled_camera(1, &c).expect("settled");
        let x = DVec3::new(0.03, -0.02, 0.05);
        let (u, v, _) = after.project(x).expect("in front");
        let (u0, v0, _) = before.project(x + d).expect("in front");
        // Exact up to |ω|·|d| (1.7 mrad × 4 mm = 7 µm at the point): under 0.01 px here.
        assert!(
            (u - u0).abs() < 1e-2 && (v - v0).abs() < 1e-2,
            "{u} {v} / {u0} {v0}"
        );
        assert_eq!(settled, after);
        pc.step(2, &c, [0.2, 0.1, -0.7, 0.0, 2.0, 0.4], (1e-3, 1e-3));
        for a in 0..6 {
            let mean: f64 = pc.xi.iter().map(|x| x[a]).sum::<f64>() / 3.0;
            let want = if a < 3 { 0.0 } else { d[a - 3] };
            assert!((mean - want).abs() < 1e-15, "component {a}: {mean}");
        }
    }

    #[test]
    fn zero_correction_leaves_the_camera_unchanged() {
        let c = cam();
        assert_eq!(PoseCorrections::new(2).camera(1, &c), c);
    }

    #[test]
    fn rates_decay_from_the_first_to_the_final_ratio_and_are_off_before_the_start() {
        let p = PoseRefinement::refine();
        let PoseRefinement::Refine {
            from_iteration,
            lr_rotation,
            final_ratio,
            ..
        } = p
        else {
            unreachable!()
        };
        assert_eq!(p.rates(from_iteration - 1, 1000), None);
        let (w0, _) = p.rates(from_iteration, 1000).unwrap();
        let (w1, _) = p.rates(1000, 1000).unwrap();
        assert!((w0 - lr_rotation).abs() < 1e-18);
        assert!((w1 - lr_rotation * final_ratio).abs() < 1e-15);
        assert_eq!(PoseRefinement::Fixed.rates(500, 1000), None);
    }
}
