//! Adaptive density control of 3DGS/2DGS as TRAN-D runs it (reference notes §2.2; 2DGS notes §6).
//!
//! * **Statistics** (every iteration, for surfels with a positive screen radius):
//!   `max_radius = max(max_radius, radius)`, `grad_accum += ‖∂L/∂means2D‖`, `denom += 1`.
//! * **Densify-and-prune**, with `ḡ = grad_accum / denom` (0 where never visible) and
//!   `d = percent_dense · extent`:
//!   1. clone: `ḡ ≥ thr` and `max(s_u, s_v) ≤ d` → an exact copy is appended;
//!   2. split: `ḡ ≥ thr` (on the pre-clone set; clones count as 0) and `max(s) > d` → N = 2 children
//!      with mean `μ + R(q)·(ξ_u s_u, ξ_v s_v, 0)`, `ξ ~ N(0, 1)` (covariance diag(s_u², s_v², 0) in the
//!      surfel frame: children stay in the parent's plane), scales `s / 1.6`, everything else copied; the
//!      parent is removed. Children are appended as `[copy 1 of every parent, copy 2 of every parent]`;
//!   3. prune: `σ(opacity) < opacity_cull`, and with a size threshold also
//!      `max_radius > threshold` (see [`ScreenSizePruning`]) or `max(s) > 0.1 · extent`;
//!   4. statistics reset to zero for all surfels; Adam moments follow the rows (new rows zero).
//! * **Opacity reset**: `o ← logit(min(σ(o), 0.01))`, that group's Adam moments zeroed.

use rand::{Rng, RngExt};
use trand_core::Surfels;
use trand_core::math::{logit, quat_to_rotmat, sigmoid};
use trand_core::surfels::ParamGroup;

use crate::config::{DensifyConfig, ScreenSizePruning};
use crate::optim::Adam;

/// Per-surfel densification statistics, accumulated between densification steps.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DensifyStats {
    pub grad_accum: Vec<f32>,
    pub denom: Vec<u32>,
    pub max_radii: Vec<f32>,
}

impl DensifyStats {
    pub fn new(n: usize) -> Self {
        Self {
            grad_accum: vec![0.0; n],
            denom: vec![0; n],
            max_radii: vec![0.0; n],
        }
    }

    pub fn len(&self) -> usize {
        self.denom.len()
    }

    pub fn is_empty(&self) -> bool {
        self.denom.is_empty()
    }

    /// Adds one view: `radii[i] > 0` marks surfel i visible; `grad2d[i]` is its densification gradient.
    pub fn add(&mut self, radii: &[f32], grad2d: &[[f32; 2]]) {
        assert_eq!(radii.len(), self.len(), "radii length");
        assert_eq!(grad2d.len(), self.len(), "gradient length");
        for i in 0..self.len() {
            if radii[i] > 0.0 {
                self.max_radii[i] = self.max_radii[i].max(radii[i]);
                self.grad_accum[i] +=
                    (grad2d[i][0] * grad2d[i][0] + grad2d[i][1] * grad2d[i][1]).sqrt();
                self.denom[i] += 1;
            }
        }
    }

    /// Mean gradient norm per surfel (0 where never visible).
    pub fn mean_grad(&self) -> Vec<f32> {
        self.grad_accum
            .iter()
            .zip(&self.denom)
            .map(|(&a, &d)| if d > 0 { a / d as f32 } else { 0.0 })
            .collect()
    }

    fn reset(&mut self, n: usize) {
        *self = Self::new(n);
    }
}

/// What one densify-and-prune call did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DensifyReport {
    pub cloned: usize,
    /// Parents split (each replaced by `split_children` children).
    pub split: usize,
    /// Surfels removed by the prune tests (split parents not counted).
    pub pruned: usize,
    pub before: usize,
    pub after: usize,
}

#[inline]
fn max_scale(log_scale: &[f32; 2]) -> f32 {
    log_scale[0].max(log_scale[1]).exp()
}

/// A standard normal sample (Box–Muller on two uniforms; the second value is discarded so each call
/// consumes a fixed amount of the stream).
fn standard_normal<G: Rng + ?Sized>(rng: &mut G) -> f32 {
    let u1: f64 = 1.0 - rng.random::<f64>(); // (0, 1]
    let u2: f64 = rng.random::<f64>();
    ((-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()) as f32
}

/// Clone, split and prune (module docs), keeping `adam`'s moments aligned and resetting `stats`.
pub fn densify_and_prune<G: Rng + ?Sized>(
    surfels: &mut Surfels,
    adam: &mut Adam,
    stats: &mut DensifyStats,
    cfg: &DensifyConfig,
    extent: f32,
    size_threshold: Option<f32>,
    rng: &mut G,
) -> DensifyReport {
    let n0 = surfels.len();
    assert_eq!(adam.len(), n0, "Adam state rows");
    assert_eq!(stats.len(), n0, "statistics rows");
    let grads = stats.mean_grad();
    let dense = cfg.percent_dense * extent;
    let mut radii = stats.max_radii.clone();

    // 1. Clone: small surfels with a large gradient, copied exactly.
    let clone_idx: Vec<usize> = (0..n0)
        .filter(|&i| grads[i] >= cfg.grad_threshold && max_scale(&surfels.log_scales[i]) <= dense)
        .collect();
    let clones = surfels.gather(&clone_idx);
    surfels.append(&clones);
    adam.append_zeros(clone_idx.len());
    radii.extend(clone_idx.iter().map(|&i| stats.max_radii[i]));

    // 2. Split: large surfels with a large gradient (clones have gradient 0 here).
    let split_idx: Vec<usize> = (0..n0)
        .filter(|&i| grads[i] >= cfg.grad_threshold && max_scale(&surfels.log_scales[i]) > dense)
        .collect();
    let n_children = cfg.split_children;
    let child_src: Vec<usize> = (0..n_children)
        .flat_map(|_| split_idx.iter().copied())
        .collect();
    let mut children = surfels.gather(&child_src);
    let log_div = cfg.split_scale_divisor.ln();
    for (c, &parent) in child_src.iter().enumerate() {
        let ls = surfels.log_scales[parent];
        let (su, sv) = (ls[0].exp(), ls[1].exp());
        let (xu, xv) = (standard_normal(rng) * su, standard_normal(rng) * sv);
        // A degenerate quaternion cannot be rotated; the child then stays at the parent's mean.
        if let Some((r, _)) = quat_to_rotmat(surfels.quats[parent]) {
            for (m, row) in children.means[c].iter_mut().zip(&r) {
                *m += row[0] * xu + row[1] * xv;
            }
        }
        children.log_scales[c] = [ls[0] - log_div, ls[1] - log_div];
    }
    surfels.append(&children);
    adam.append_zeros(child_src.len());
    radii.extend(child_src.iter().map(|&i| stats.max_radii[i]));

    // 3. Prune (and drop the split parents) in one pass.
    let n1 = surfels.len();
    let mut is_parent = vec![false; n1];
    for &i in &split_idx {
        is_parent[i] = true;
    }
    let world_limit = cfg.world_size_fraction * extent;
    let mut pruned = 0;
    let keep: Vec<bool> = (0..n1)
        .map(|i| {
            if is_parent[i] {
                return false;
            }
            let mut prune = sigmoid(surfels.opacity_logits[i]) < cfg.opacity_cull;
            if let Some(thr) = size_threshold {
                let screen = match cfg.screen_size_pruning {
                    ScreenSizePruning::AsReference => false,
                    ScreenSizePruning::Active => radii[i] > thr,
                };
                prune |= screen || max_scale(&surfels.log_scales[i]) > world_limit;
            }
            pruned += prune as usize;
            !prune
        })
        .collect();
    surfels.retain(&keep);
    adam.retain(&keep);
    stats.reset(surfels.len());
    DensifyReport {
        cloned: clone_idx.len(),
        split: split_idx.len(),
        pruned,
        before: n0,
        after: surfels.len(),
    }
}

/// Clamps every opacity to at most `max_opacity` (TRAN-D: 0.01) and zeros the opacity moments.
pub fn reset_opacity(surfels: &mut Surfels, adam: &mut Adam, max_opacity: f32) {
    for o in &mut surfels.opacity_logits {
        *o = logit(sigmoid(*o).min(max_opacity));
    }
    adam.reset_group(ParamGroup::Opacity);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::optim::{AdamParams, GroupLr};
    use rand::SeedableRng;
    use rand_pcg::Pcg64;
    use trand_core::surfels::Surfel;

    /// Surfel i at x = i with the given scale, opacity and a distinctive object logit.
    fn scene(specs: &[(f32, f32)]) -> Surfels {
        let mut s = Surfels::new(0, 2).unwrap();
        for (i, &(scale, opacity)) in specs.iter().enumerate() {
            s.push(&Surfel {
                mean: [i as f32, 0.5, -0.25],
                log_scale: [scale.ln(), (0.5 * scale).ln()],
                quat: [0.9, 0.1, -0.3, 0.2],
                opacity_logit: logit(opacity),
                sh_dc: [i as f32, 0.0, 0.0],
                mask_dc: [0.0; 3],
                obj_logits: vec![0.0, i as f32],
            });
        }
        s
    }

    fn adam_with_moments(s: &mut Surfels) -> Adam {
        let mut adam = Adam::new(s, AdamParams::default());
        let mut g = s.zeros_like();
        for (i, m) in g.means.iter_mut().enumerate() {
            m[0] = 1.0 + i as f32;
        }
        adam.step(s, &g, &GroupLr::uniform(0.0));
        adam
    }

    #[test]
    fn clone_split_prune_counts_and_moments_stay_aligned() {
        // extent 1 → dense = 0.01. 0: small, hot → clone. 1: large, hot → split. 2: large, cold → kept.
        // 3: transparent → pruned. 4: small, cold → kept.
        let mut s = scene(&[
            (0.005, 0.5),
            (0.05, 0.5),
            (0.05, 0.5),
            (0.005, 0.001),
            (0.005, 0.5),
        ]);
        let mut adam = adam_with_moments(&mut s);
        let mut stats = DensifyStats::new(5);
        stats.add(
            &[3.0, 4.0, 5.0, 1.0, 0.0],
            &[
                [3e-4, 0.0],
                [0.0, 5e-4],
                [1e-5, 0.0],
                [1.0, 0.0],
                [1.0, 1.0],
            ],
        );
        let cfg = DensifyConfig::default();
        let mut rng = Pcg64::seed_from_u64(7);
        let r = densify_and_prune(&mut s, &mut adam, &mut stats, &cfg, 1.0, None, &mut rng);
        // Clones: 0 and 3 (3 is small and hot, then pruned with its clone for its opacity); split: 1.
        assert_eq!(
            (r.cloned, r.split, r.pruned, r.before, r.after),
            (2, 1, 2, 5, 6)
        );
        // Order: surviving originals 0, 2, 4, then the clone of 0, then the two children of 1.
        assert_eq!(
            s.sh_dc.iter().map(|c| c[0]).collect::<Vec<_>>(),
            vec![0.0, 2.0, 4.0, 0.0, 1.0, 1.0]
        );
        s.validate().unwrap();
        assert_eq!(adam.len(), s.len());
        assert_eq!(stats, DensifyStats::new(s.len()));
        // Moments: surviving originals keep theirs (m = 0.1·g), new rows are zero.
        assert!((adam.m.means[0][0] - 0.1).abs() < 1e-7);
        assert!((adam.m.means[1][0] - 0.3).abs() < 1e-7);
        assert!((adam.m.means[2][0] - 0.5).abs() < 1e-7);
        assert!(adam.m.means[3..].iter().all(|m| *m == [0.0; 3]));
    }

    #[test]
    fn clones_are_exact_copies_and_split_children_lie_in_the_parent_plane() {
        let mut s = scene(&[(0.005, 0.5), (0.2, 0.5)]);
        let parent = s.gather(&[0, 1]);
        let mut adam = adam_with_moments(&mut s);
        let mut stats = DensifyStats::new(2);
        stats.add(&[1.0, 1.0], &[[1.0, 0.0], [1.0, 0.0]]);
        let mut rng = Pcg64::seed_from_u64(3);
        densify_and_prune(
            &mut s,
            &mut adam,
            &mut stats,
            &DensifyConfig::default(),
            1.0,
            None,
            &mut rng,
        );
        // [original 0, clone of 0, child 1a, child 1b]
        assert_eq!(s.len(), 4);
        assert_eq!(s.gather(&[1]), parent.gather(&[0]));
        let (r, _) = quat_to_rotmat(parent.quats[1]).unwrap();
        let normal = [r[0][2], r[1][2], r[2][2]];
        for c in [2, 3] {
            let d: Vec<f32> = (0..3).map(|k| s.means[c][k] - parent.means[1][k]).collect();
            let along_normal: f32 = (0..3).map(|k| d[k] * normal[k]).sum();
            let dist: f32 = d.iter().map(|v| v * v).sum::<f32>().sqrt();
            assert!(
                along_normal.abs() < 1e-6,
                "child {c} leaves the plane by {along_normal}"
            );
            assert!(dist > 0.0 && dist < 1.0);
            assert!((s.log_scales[c][0] - (parent.log_scales[1][0] - 1.6f32.ln())).abs() < 1e-6);
            assert_eq!(s.obj_logits[2 * c + 1], 1.0);
            assert_eq!(s.quats[c], parent.quats[1]);
        }
        assert_ne!(s.means[2], s.means[3]);
    }

    #[test]
    fn split_offsets_have_the_parent_standard_deviations() {
        // Many splits of one axis-aligned parent: sample std of the offsets ≈ (s_u, s_v), none along z.
        let mut s = Surfels::new(0, 1).unwrap();
        for _ in 0..4000 {
            s.push(&Surfel {
                mean: [0.0; 3],
                log_scale: [0.4f32.ln(), 0.1f32.ln()],
                quat: [1.0, 0.0, 0.0, 0.0],
                opacity_logit: 0.0,
                sh_dc: [0.0; 3],
                mask_dc: [0.0; 3],
                obj_logits: vec![],
            });
        }
        let mut adam = Adam::new(&s, AdamParams::default());
        let mut stats = DensifyStats::new(s.len());
        stats.add(&vec![1.0; s.len()], &vec![[1.0, 0.0]; s.len()]);
        densify_and_prune(
            &mut s,
            &mut adam,
            &mut stats,
            &DensifyConfig::default(),
            1.0,
            None,
            &mut Pcg64::seed_from_u64(1),
        );
        let n = s.len() as f64;
        let std =
            |k: usize| (s.means.iter().map(|m| (m[k] as f64).powi(2)).sum::<f64>() / n).sqrt();
        assert!(
            (std(0) - 0.4).abs() < 0.02 && (std(1) - 0.1).abs() < 0.005,
            "{} {}",
            std(0),
            std(1)
        );
        assert_eq!(std(2), 0.0);
    }

    #[test]
    fn size_pruning_applies_only_with_a_threshold() {
        // Surfel 0 is larger than 0.1·extent in world size; surfel 1 had a large screen radius.
        let specs = [(0.5, 0.5), (0.005, 0.5), (0.005, 0.5)];
        let cfg = DensifyConfig::default();
        let run = |thr: Option<f32>, cfg: &DensifyConfig| {
            let mut s = scene(&specs);
            let mut adam = Adam::new(&s, AdamParams::default());
            let mut stats = DensifyStats::new(3);
            stats.add(&[1.0, 50.0, 1.0], &[[0.0; 2]; 3]);
            densify_and_prune(
                &mut s,
                &mut adam,
                &mut stats,
                cfg,
                1.0,
                thr,
                &mut Pcg64::seed_from_u64(0),
            )
            .pruned
        };
        assert_eq!(run(None, &cfg), 0);
        assert_eq!(run(Some(20.0), &cfg), 1); // world size only: the reference's radii are already reset
        let active = DensifyConfig {
            screen_size_pruning: ScreenSizePruning::Active,
            ..cfg.clone()
        };
        assert_eq!(run(Some(20.0), &active), 2);
    }

    #[test]
    fn stats_average_over_visible_views_only() {
        let mut st = DensifyStats::new(2);
        st.add(&[2.0, 0.0], &[[3.0, 4.0], [9.0, 9.0]]);
        st.add(&[1.0, 0.0], &[[0.0, 1.0], [9.0, 9.0]]);
        assert_eq!(st.mean_grad(), vec![3.0, 0.0]);
        assert_eq!(st.max_radii, vec![2.0, 0.0]);
        assert_eq!(st.denom, vec![2, 0]);
    }

    #[test]
    fn opacity_reset_clamps_and_zeros_moments() {
        let mut s = scene(&[(0.01, 0.5), (0.01, 0.001)]);
        let mut adam = Adam::new(&s, AdamParams::default());
        adam.m.opacity_logits = vec![1.0, 1.0];
        adam.v.opacity_logits = vec![1.0, 1.0];
        adam.m.means[0] = [1.0; 3];
        reset_opacity(&mut s, &mut adam, 0.01);
        assert!((sigmoid(s.opacity_logits[0]) - 0.01).abs() < 1e-6);
        assert!((sigmoid(s.opacity_logits[1]) - 0.001).abs() < 1e-6);
        assert_eq!(adam.m.opacity_logits, vec![0.0, 0.0]);
        assert_eq!(adam.v.opacity_logits, vec![0.0, 0.0]);
        assert_eq!(adam.m.means[0], [1.0; 3]);
    }

    #[test]
    fn densification_is_deterministic_for_a_seed() {
        let run = || {
            let mut s = scene(&[(0.2, 0.5), (0.3, 0.5), (0.005, 0.5)]);
            let mut adam = Adam::new(&s, AdamParams::default());
            let mut stats = DensifyStats::new(3);
            stats.add(&[1.0; 3], &[[1.0, 0.0]; 3]);
            densify_and_prune(
                &mut s,
                &mut adam,
                &mut stats,
                &DensifyConfig::default(),
                1.0,
                None,
                &mut Pcg64::seed_from_u64(9),
            );
            s
        };
        assert_eq!(run(), run());
    }
}
