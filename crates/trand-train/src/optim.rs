//! Adam over [`Surfels`] with one learning rate per [`ParamGroup`], and the learning-rate schedules of
//! 3DGS/2DGS/TRAN-D.
//!
//! Adam (Kingma & Ba), as `torch.optim.Adam` computes it: with the group's step count t,
//!
//! `m ← β1 m + (1 − β1) g`, `v ← β2 v + (1 − β2) g²`,
//! `θ ← θ − (lr / (1 − β1ᵗ)) · m / (√v / √(1 − β2ᵗ) + ε)`,
//!
//! β1 = 0.9, β2 = 0.999, **ε = 1e-15** (3DGS's choice: the tiny ε lets parameters with tiny gradients still
//! move at the full learning rate). The moments are stored as `Surfels`-shaped buffers so densification can
//! keep them aligned with the parameters: rows of new surfels start at zero, pruned rows are dropped, and
//! the step counts are kept (as the reference's optimiser-state surgery does).
//!
//! Schedules: constant, or log-linear (`get_expon_lr_func` without delay):
//! `lr(s) = exp((1 − τ) ln a + τ ln b)`, `τ = clip(s / max_steps, 0, 1)`.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use trand_core::Surfels;
use trand_core::surfels::ParamGroup;

/// A learning-rate schedule over the (1-based) training iteration.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LrSchedule {
    Constant(f64),
    /// Log-linear interpolation from `from` (step 0) to `to` (step ≥ `max_steps`).
    LogLinear {
        from: f64,
        to: f64,
        max_steps: u32,
    },
}

impl LrSchedule {
    /// The learning rate at `step`.
    pub fn at(&self, step: u32) -> f64 {
        match *self {
            LrSchedule::Constant(lr) => lr,
            LrSchedule::LogLinear {
                from,
                to,
                max_steps,
            } => {
                if from == 0.0 && to == 0.0 {
                    return 0.0;
                }
                let tau = if max_steps == 0 {
                    1.0
                } else {
                    (step as f64 / max_steps as f64).clamp(0.0, 1.0)
                };
                ((1.0 - tau) * from.ln() + tau * to.ln()).exp()
            }
        }
    }

    /// The same schedule with every rate multiplied by `s` (the spatial scale of the position rate).
    pub fn scaled(&self, s: f64) -> Self {
        match *self {
            LrSchedule::Constant(lr) => LrSchedule::Constant(lr * s),
            LrSchedule::LogLinear {
                from,
                to,
                max_steps,
            } => LrSchedule::LogLinear {
                from: from * s,
                to: to * s,
                max_steps,
            },
        }
    }
}

/// Position of a group in [`ParamGroup::ALL`] (the index of per-group arrays).
pub fn group_index(g: ParamGroup) -> usize {
    ParamGroup::ALL
        .iter()
        .position(|&x| x == g)
        .expect("every group is in ParamGroup::ALL")
}

/// One learning rate per parameter group, for one step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GroupLr(pub [f64; 9]);

impl GroupLr {
    /// The same rate for every group.
    pub fn uniform(lr: f64) -> Self {
        GroupLr([lr; 9])
    }

    pub fn get(&self, g: ParamGroup) -> f64 {
        self.0[group_index(g)]
    }

    pub fn set(&mut self, g: ParamGroup, lr: f64) {
        self.0[group_index(g)] = lr;
    }
}

/// Adam's constants.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct AdamParams {
    pub beta1: f64,
    pub beta2: f64,
    pub eps: f64,
}

impl Default for AdamParams {
    fn default() -> Self {
        Self {
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-15,
        }
    }
}

/// A `Surfels`-shaped set of zeros with `n` rows.
pub fn zero_surfels(sh_degree: u32, num_objects: usize, n: usize) -> Surfels {
    let mut s = Surfels {
        sh_degree,
        num_objects,
        ..Default::default()
    };
    let rs = s.rest_stride();
    s.means = vec![[0.0; 3]; n];
    s.log_scales = vec![[0.0; 2]; n];
    s.quats = vec![[0.0; 4]; n];
    s.opacity_logits = vec![0.0; n];
    s.sh_dc = vec![[0.0; 3]; n];
    s.sh_rest = vec![0.0; n * rs];
    s.mask_dc = vec![[0.0; 3]; n];
    s.mask_rest = vec![0.0; n * rs];
    s.obj_logits = vec![0.0; n * num_objects];
    s
}

/// Elements per parallel chunk of the update (fixed, so the update is the same for any thread count —
/// it is element-wise anyway).
const CHUNK: usize = 16 * 1024;

/// Adam state over a set of surfels.
#[derive(Clone, Debug, PartialEq)]
pub struct Adam {
    pub params: AdamParams,
    /// First moments, shaped like the parameters.
    pub m: Surfels,
    /// Second moments, shaped like the parameters.
    pub v: Surfels,
    /// Steps taken per group (index: [`group_index`]), kept through densification. They differ only when
    /// a group was left out of a step ([`Adam::step_groups`]), as PyTorch's per-parameter counts do when
    /// a parameter has no gradient.
    pub steps: [u64; 9],
}

impl Adam {
    /// Fresh state (zero moments, step 0) for parameters shaped like `like`.
    pub fn new(like: &Surfels, params: AdamParams) -> Self {
        Self {
            params,
            m: like.zeros_like(),
            v: like.zeros_like(),
            steps: [0; 9],
        }
    }

    pub fn len(&self) -> usize {
        self.m.len()
    }

    pub fn is_empty(&self) -> bool {
        self.m.is_empty()
    }

    /// Steps taken by a group.
    pub fn steps_of(&self, g: ParamGroup) -> u64 {
        self.steps[group_index(g)]
    }

    /// One Adam step on every group with its learning rate.
    pub fn step(&mut self, params: &mut Surfels, grads: &Surfels, lr: &GroupLr) {
        self.step_groups(params, grads, lr, &ParamGroup::ALL);
    }

    /// One Adam step on the listed groups only; the others (parameters, moments, step counts) are left
    /// untouched. The reference skips a group whose tensor was replaced in this iteration (it has no
    /// gradient), e.g. the opacity right after an opacity reset.
    pub fn step_groups(
        &mut self,
        params: &mut Surfels,
        grads: &Surfels,
        lr: &GroupLr,
        groups: &[ParamGroup],
    ) {
        assert_eq!(
            params.len(),
            self.m.len(),
            "Adam state has {} rows, parameters {}",
            self.m.len(),
            params.len()
        );
        assert_eq!(grads.len(), params.len(), "gradient rows");
        let AdamParams { beta1, beta2, eps } = self.params;
        let (b1, b2) = (beta1 as f32, beta2 as f32);
        let (ob1, ob2) = ((1.0 - beta1) as f32, (1.0 - beta2) as f32);
        let eps = eps as f32;
        let grad_groups = grads.groups();
        for (((g, p), (_, m)), ((_, v), (gg, gr))) in params
            .groups_mut()
            .into_iter()
            .zip(self.m.groups_mut())
            .zip(self.v.groups_mut().into_iter().zip(grad_groups))
        {
            debug_assert_eq!(g, gg);
            assert_eq!(
                p.len(),
                gr.len(),
                "gradient of {} has the wrong length",
                g.name()
            );
            if !groups.contains(&g) {
                continue;
            }
            let count = &mut self.steps[group_index(g)];
            *count += 1;
            let t = i32::try_from(*count).unwrap_or(i32::MAX);
            let bc1 = 1.0 - beta1.powi(t);
            let inv_bc2_sqrt = (1.0 / (1.0 - beta2.powi(t)).sqrt()) as f32;
            let step_size = (lr.get(g) / bc1) as f32;
            p.par_chunks_mut(CHUNK)
                .zip(m.par_chunks_mut(CHUNK))
                .zip(v.par_chunks_mut(CHUNK).zip(gr.par_chunks(CHUNK)))
                .for_each(|((p, m), (v, gr))| {
                    for (((p, m), v), &gr) in
                        p.iter_mut().zip(m.iter_mut()).zip(v.iter_mut()).zip(gr)
                    {
                        *m = b1 * *m + ob1 * gr;
                        *v = b2 * *v + ob2 * gr * gr;
                        *p -= step_size * *m / (v.sqrt() * inv_bc2_sqrt + eps);
                    }
                });
        }
    }

    /// Reorders/duplicates the moments like [`Surfels::gather`].
    pub fn gather(&mut self, idx: &[usize]) {
        self.m = self.m.gather(idx);
        self.v = self.v.gather(idx);
    }

    /// Keeps the rows where `keep` is true, like [`Surfels::retain`].
    pub fn retain(&mut self, keep: &[bool]) {
        self.m.retain(keep);
        self.v.retain(keep);
    }

    /// Appends `n` rows of zero moments (for new surfels).
    pub fn append_zeros(&mut self, n: usize) {
        let z = zero_surfels(self.m.sh_degree, self.m.num_objects, n);
        self.m.append(&z);
        self.v.append(&z);
    }

    /// Zeros both moments of one group (after its parameters were overwritten, e.g. an opacity reset).
    pub fn reset_group(&mut self, group: ParamGroup) {
        for s in [&mut self.m, &mut self.v] {
            for (g, d) in s.groups_mut() {
                if g == group {
                    d.fill(0.0);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use trand_core::surfels::Surfel;

    fn two_surfels() -> Surfels {
        let mut s = Surfels::new(1, 3).unwrap();
        for i in 0..2 {
            s.push(&Surfel {
                mean: [i as f32, 1.0, 2.0],
                log_scale: [-3.0, -2.0],
                quat: [1.0, 0.0, 0.0, 0.0],
                opacity_logit: 0.5,
                sh_dc: [0.1, 0.2, 0.3],
                mask_dc: [0.0; 3],
                obj_logits: vec![0.0, 1.0, 2.0],
            });
        }
        s
    }

    #[test]
    fn log_linear_schedule_hits_endpoints_and_midpoint() {
        let s = LrSchedule::LogLinear {
            from: 1.6e-4,
            to: 1.6e-6,
            max_steps: 1500,
        };
        assert!((s.at(0) - 1.6e-4).abs() < 1e-18);
        assert!((s.at(1500) - 1.6e-6).abs() < 1e-18);
        assert!((s.at(3000) - 1.6e-6).abs() < 1e-18);
        assert!((s.at(750) - 1.6e-5).abs() < 1e-17); // geometric mean
        // TRAN-D's note: at iteration 1000 the rate is 1.6e-4 · 0.01^(2/3) ≈ 7.43e-6.
        assert!((s.at(1000) - 7.42654e-6).abs() < 1e-10);
        assert_eq!(LrSchedule::Constant(0.1).at(12345), 0.1);
    }

    #[test]
    fn two_adam_steps_match_hand_computation() {
        let mut p = two_surfels();
        let mut g = p.zeros_like();
        g.means[0] = [0.5, -2.0, 0.0];
        g.opacity_logits[1] = 3.0;
        let lr = GroupLr::uniform(0.01);
        let mut adam = Adam::new(&p, AdamParams::default());
        let p0 = p.clone();
        adam.step(&mut p, &g, &lr);
        // Step 1: m = 0.1 g, v = 0.001 g², m̂ = g, v̂ = g² → Δ = −lr·sign(g) (ε negligible).
        assert!((p.means[0][0] - (p0.means[0][0] - 0.01)).abs() < 1e-7);
        assert!((p.means[0][1] - (p0.means[0][1] + 0.01)).abs() < 1e-7);
        assert_eq!(p.means[0][2], p0.means[0][2]);
        assert!((p.opacity_logits[1] - (p0.opacity_logits[1] - 0.01)).abs() < 1e-7);
        // Step 2 with gradient g2 = −g/2 on means[0][0]: by hand in f64.
        let mut g2 = p.zeros_like();
        g2.means[0][0] = -0.25;
        let before = p.means[0][0] as f64;
        adam.step(&mut p, &g2, &lr);
        let m = 0.9 * (0.1 * 0.5) + 0.1 * -0.25;
        let v: f64 = 0.999 * (0.001 * 0.25) + 0.001 * 0.0625;
        let (bc1, bc2) = (1.0 - 0.9f64.powi(2), 1.0 - 0.999f64.powi(2));
        let expected = before - 0.01 / bc1 * m / (v.sqrt() / bc2.sqrt() + 1e-15);
        assert!(
            (p.means[0][0] as f64 - expected).abs() < 1e-6,
            "{} vs {expected}",
            p.means[0][0]
        );
        assert_eq!(adam.steps, [2; 9]);
    }

    #[test]
    fn per_group_rates_apply_to_their_group_only() {
        let mut p = two_surfels();
        let mut g = p.zeros_like();
        g.means[0][0] = 1.0;
        g.obj_logits[0] = 1.0;
        let mut lr = GroupLr::uniform(0.0);
        lr.set(ParamGroup::ObjLogits, 0.1);
        let p0 = p.clone();
        let mut adam = Adam::new(&p, AdamParams::default());
        adam.step(&mut p, &g, &lr);
        assert_eq!(p.means, p0.means);
        assert!((p.obj_logits[0] - (p0.obj_logits[0] - 0.1)).abs() < 1e-6);
    }

    #[test]
    fn moment_bookkeeping_follows_surfel_bookkeeping() {
        let mut p = two_surfels();
        let mut g = p.zeros_like();
        g.means[0][0] = 1.0;
        g.means[1][0] = 2.0;
        let mut adam = Adam::new(&p, AdamParams::default());
        adam.step(&mut p, &g, &GroupLr::uniform(0.01));
        adam.gather(&[1, 0, 1]);
        assert_eq!(adam.len(), 3);
        assert!((adam.m.means[0][0] - 0.2).abs() < 1e-7 && (adam.m.means[1][0] - 0.1).abs() < 1e-7);
        adam.append_zeros(2);
        assert_eq!(adam.len(), 5);
        assert_eq!(adam.m.means[4], [0.0; 3]);
        assert_eq!(adam.v.sh_rest.len(), 5 * 9);
        adam.retain(&[false, true, true, false, true]);
        assert_eq!(adam.len(), 3);
        assert!((adam.m.means[0][0] - 0.1).abs() < 1e-7);
        adam.m.opacity_logits.fill(1.0);
        adam.reset_group(ParamGroup::Opacity);
        assert!(adam.m.opacity_logits.iter().all(|&x| x == 0.0));
        assert!((adam.m.means[0][0] - 0.1).abs() < 1e-7);
        assert_eq!(adam.steps_of(ParamGroup::Means), 1);
    }

    #[test]
    fn skipped_groups_keep_parameters_moments_and_step_count() {
        let mut p = two_surfels();
        let mut g = p.zeros_like();
        g.means[0][0] = 1.0;
        g.opacity_logits[0] = 1.0;
        let mut adam = Adam::new(&p, AdamParams::default());
        let p0 = p.clone();
        let others: Vec<ParamGroup> = ParamGroup::ALL
            .into_iter()
            .filter(|&x| x != ParamGroup::Opacity)
            .collect();
        adam.step_groups(&mut p, &g, &GroupLr::uniform(0.01), &others);
        assert_eq!(p.opacity_logits, p0.opacity_logits);
        assert_eq!(adam.m.opacity_logits, vec![0.0, 0.0]);
        assert_eq!(
            (
                adam.steps_of(ParamGroup::Opacity),
                adam.steps_of(ParamGroup::Means)
            ),
            (0, 1)
        );
        assert_ne!(p.means, p0.means);
        // The next full step is the opacity group's first: bias-corrected to exactly −lr·sign(g).
        adam.step(&mut p, &g, &GroupLr::uniform(0.01));
        assert!((p.opacity_logits[0] - (p0.opacity_logits[0] - 0.01)).abs() < 1e-7);
    }
}
