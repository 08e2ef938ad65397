//! TRAN-D's object-aware 3D loss (paper §3.2; official code `train.py`, see the reference notes §4, §10
//! rows 12 and 15).
//!
//! For each object channel k ≥ 1, its **members** are the surfels whose softmax probability `p_k` exceeds
//! 0.5 (a non-differentiable selection; the gradient reaches only the positions). For each level
//! ℓ with `(G, K)` ∈ {(16, 16), (32, 16), (64, 32)}:
//!
//! * `c_1..c_G` = farthest-point sampling of the members (squared Euclidean distance, deterministic start
//!   at the object's first member in storage order, ties to the lowest index);
//! * `N_g` = the K members nearest to `c_g`, the centre itself included;
//! * `S_g = Σ_{j∈N_g} ‖x_j − c_g‖` (spread of the neighbourhood);
//! * `D_g = min_{h≠g} ‖c_g − c_h‖` (gap to the nearest other centre);
//! * `L_ℓ,obj = w_S·mean_g (S_g − S̄)² + w_D·mean_g (D_g − D̄)²`, with the code's weights
//!   `w_S = 1/3`, `w_D = 10000/3` (the paper swaps them; the code produced the results).
//!
//! `L = Σ_ℓ mean_{obj} L_ℓ,obj`, the mean over the objects that have at least G members (an object is
//! skipped at a level it cannot fill; one without members is skipped entirely). Each object uses all its
//! members (no subsampling to the smallest object).
//!
//! Gradients, with `u = (x_j − c_g)/‖x_j − c_g‖`: `∂S_g/∂x_j = u`, `∂S_g/∂c_g = −Σ_j u`;
//! `∂D_g/∂c_g = (c_g − c_h)/D_g = −∂D_g/∂c_h`; `∂ mean_g (S_g − S̄)²/∂S_g = 2(S_g − S̄)/G` (the S̄ term
//! vanishes because the deviations sum to zero). Centres are members, so they receive gradient through
//! both terms. A zero distance (the centre as its own neighbour) has zero gradient, as in PyTorch.
//!
//! Cost: one FPS run per object serves every level (each prefix of an FPS sequence is the FPS of that
//! length), and kNN queries a kd-tree (kiddo) of the object's members, one tree per object and iteration
//! for all levels ([`k_nearest`], the brute-force scan, is the reference it is tested against).
//!
//! The discrete choices (members, FPS centres, neighbour lists, nearest other centre) are made once by
//! [`select`] and then held fixed by [`evaluate`], which is what the finite-difference tests perturb.

use std::num::NonZero;

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use trand_core::Real;
use trand_core::math::softmax;

/// One level of the loss: `centres` FPS samples (G), each with `neighbours` nearest members (K).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ObjectLevel {
    pub centres: usize,
    pub neighbours: usize,
}

/// TRAN-D's levels `(G, K)`: `object_loss_group_cnt = [16, 32, 64]`, `object_loss_group_size = [16, 16, 32]`.
pub const TRAN_D_LEVELS: [ObjectLevel; 3] = [
    ObjectLevel {
        centres: 16,
        neighbours: 16,
    },
    ObjectLevel {
        centres: 32,
        neighbours: 16,
    },
    ObjectLevel {
        centres: 64,
        neighbours: 32,
    },
];

/// Parameters of the object-aware loss.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ObjectLossParams {
    pub levels: Vec<ObjectLevel>,
    /// Weight of the variance of the neighbourhood spreads S (code: `L_uniform` = mean/3).
    pub spread_weight: f64,
    /// Weight of the variance of the nearest-centre gaps D (code: `10000 · L_center_var`, mean/3).
    pub gap_weight: f64,
    /// Membership threshold on the softmax probability; must be ≥ 0.5 so membership is exclusive.
    pub membership_threshold: f64,
}

impl Default for ObjectLossParams {
    fn default() -> Self {
        Self {
            levels: TRAN_D_LEVELS.to_vec(),
            spread_weight: 1.0 / 3.0,
            gap_weight: 10000.0 / 3.0,
            membership_threshold: 0.5,
        }
    }
}

/// The discrete choices of one object at one level (global surfel indices).
#[derive(Clone, Debug, PartialEq)]
pub struct LevelSelection {
    /// FPS centres (G surfel indices), in sampling order.
    pub centres: Vec<usize>,
    /// `G × K` surfel indices, row g = the K nearest members of centre g, nearest first.
    pub neighbours: Vec<usize>,
    /// For each centre, the position (in `centres`) of its nearest other centre.
    pub nearest_centre: Vec<usize>,
}

/// The discrete choices of one object.
#[derive(Clone, Debug, PartialEq)]
pub struct ObjectSelection {
    pub channel: usize,
    pub num_members: usize,
    /// One entry per level; `None` where the object has fewer members than the level's G.
    pub levels: Vec<Option<LevelSelection>>,
}

/// Loss value and gradient with respect to every surfel position.
#[derive(Clone, Debug)]
pub struct ObjectLoss<R> {
    pub value: R,
    /// Same length as the positions; zero for non-members.
    pub grad: Vec<[R; 3]>,
    /// Objects that took part in each level.
    pub objects_per_level: Vec<usize>,
}

impl<R: Real> ObjectLoss<R> {
    /// Adds `weight · grad` to a position gradient (e.g. `grads.means` of the whole step).
    pub fn add_scaled_to(&self, means_grad: &mut [[R; 3]], weight: R) {
        assert_eq!(
            means_grad.len(),
            self.grad.len(),
            "position gradient length"
        );
        for (o, g) in means_grad.iter_mut().zip(&self.grad) {
            for k in 0..3 {
                o[k] += weight * g[k];
            }
        }
    }
}

#[inline]
fn dist2<R: Real>(a: &[R; 3], b: &[R; 3]) -> R {
    let (dx, dy, dz) = (a[0] - b[0], a[1] - b[1], a[2] - b[2]);
    dx * dx + dy * dy + dz * dz
}

/// Members of every channel (index = channel; channel 0, the background, included) by softmax
/// probability `> threshold`, in storage order.
pub fn object_members<R: Real>(
    obj_logits: &[R],
    num_objects: usize,
    threshold: f64,
) -> Vec<Vec<usize>> {
    assert!(
        threshold >= 0.5,
        "membership threshold {threshold} < 0.5 would make membership ambiguous"
    );
    assert_eq!(
        obj_logits.len() % num_objects.max(1),
        0,
        "object logits length"
    );
    let thr = R::from_f64(threshold);
    let owner: Vec<Option<usize>> = obj_logits
        .par_chunks(num_objects)
        .map_init(
            || vec![R::ZERO; num_objects],
            |p, l| {
                softmax(l, p);
                p.iter().position(|&v| v > thr)
            },
        )
        .collect();
    let mut out = vec![Vec::new(); num_objects];
    for (i, o) in owner.into_iter().enumerate() {
        if let Some(c) = o {
            out[c].push(i);
        }
    }
    out
}

/// Farthest-point sampling of `count` of `points`: starts at point 0, then repeatedly takes the point with
/// the largest squared distance to the chosen set (lowest index on ties). Each prefix of the result is the
/// FPS of that length. Requires `count ≤ points.len()`.
#[allow(clippy::neg_cmp_op_on_partial_ord)] // `!(d >= m)` on purpose: NaN handling, see the loop
pub fn farthest_point_sampling<R: Real>(points: &[[R; 3]], count: usize) -> Vec<usize> {
    assert!(
        count <= points.len(),
        "FPS of {count} from {} points",
        points.len()
    );
    if count == 0 {
        return Vec::new();
    }
    let mut chosen = Vec::with_capacity(count);
    chosen.push(0);
    // One pass per new centre: update each point's distance to the chosen set and track the farthest.
    let mut min_d: Vec<R> = vec![R::from_f64(f64::INFINITY); points.len()];
    let mut c = points[0];
    while chosen.len() < count {
        let mut best = 0usize;
        let mut best_d = -R::ONE;
        for (j, (m, p)) in min_d.iter_mut().zip(points).enumerate() {
            // `!(d ≥ m)` rather than `min`: a non-finite point keeps a NaN distance and is never chosen.
            let d = dist2(p, &c);
            let d = if !(d >= *m) { d } else { *m };
            *m = d;
            if d > best_d {
                best = j;
                best_d = d;
            }
        }
        chosen.push(best);
        c = points[best];
    }
    chosen
}

/// The `k` of `points` nearest to `query` (squared Euclidean, ties to the lower index), nearest first.
/// Points at a non-finite distance are never chosen, so fewer than `k` may come back.
pub fn k_nearest<R: Real>(points: &[[R; 3]], query: &[R; 3], k: usize) -> Vec<usize> {
    if k == 0 {
        return Vec::new();
    }
    // A sorted list of the k best (distance, index) pairs; most candidates are rejected by one comparison
    // with the current k-th. A later equal distance does not displace an earlier index.
    let mut best: Vec<(R, usize)> = Vec::with_capacity(k + 1);
    for (j, p) in points.iter().enumerate() {
        let d = dist2(p, query);
        if (best.len() == k && d >= best[k - 1].0) || !d.is_finite() {
            continue;
        }
        let at = best.partition_point(|&(bd, _)| bd <= d);
        best.insert(at, (d, j));
        best.truncate(k);
    }
    best.into_iter().map(|(_, j)| j).collect()
}

/// [`k_nearest`] through a kd-tree of the same points: the same neighbours, nearest first, ties to the
/// lower index (only an exact distance tie at the k-th place could differ). The brute-force scan cost
/// G·n distance evaluations per level (112 centres × ~10 k members per object, every iteration from 100
/// on: a tenth of a training iteration); the tree answers in O(k log n).
fn tree_k_nearest<R: Real>(tree: &ImmutableKdTree<f64, 3>, query: &[R; 3], k: usize) -> Vec<usize> {
    let Some(nk) = NonZero::new(k) else {
        return Vec::new();
    };
    let q = query.map(R::to_f64);
    let mut nn: Vec<(f64, usize)> = tree
        .query(&q)
        .nearest_n::<SquaredEuclidean<f64>>(nk)
        .execute()
        .into_iter()
        .map(|r| (r.distance, r.item as usize))
        .collect();
    nn.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    nn.into_iter().map(|(_, j)| j).collect()
}

/// Selection of one object at one level, given the member positions (`local`, contiguous), their
/// surfel indices and the members' FPS order (at least G long).
fn select_level<R: Real>(
    local: &[[R; 3]],
    tree: Option<&ImmutableKdTree<f64, 3>>,
    members: &[usize],
    fps: &[usize],
    level: ObjectLevel,
) -> Option<LevelSelection> {
    let (g, k) = (level.centres, level.neighbours);
    if g < 2 || local.len() < g || local.len() < k || fps.len() < g {
        return None;
    }
    let centres_pos = &fps[..g];
    let centres: Vec<usize> = centres_pos.iter().map(|&j| members[j]).collect();
    let mut neighbours = Vec::with_capacity(g * k);
    for &c in centres_pos {
        let nn = match tree {
            Some(t) => tree_k_nearest(t, &local[c], k),
            None => k_nearest(local, &local[c], k),
        };
        if nn.len() < k {
            return None; // non-finite positions: no well-defined neighbourhood
        }
        neighbours.extend(nn.into_iter().map(|j| members[j]));
    }
    let nearest_centre = (0..g)
        .map(|a| {
            let mut best = usize::MAX;
            let mut best_d = R::ZERO;
            for b in 0..g {
                if b == a {
                    continue;
                }
                let d = dist2(&local[centres_pos[a]], &local[centres_pos[b]]);
                if best == usize::MAX || d < best_d {
                    best = b;
                    best_d = d;
                }
            }
            best
        })
        .collect();
    Some(LevelSelection {
        centres,
        neighbours,
        nearest_centre,
    })
}

/// Makes the discrete choices (members, FPS centres, kNN lists, nearest centres) for the object channels
/// `1..num_objects` that have members.
pub fn select<R: Real>(
    points: &[[R; 3]],
    obj_logits: &[R],
    num_objects: usize,
    params: &ObjectLossParams,
) -> Vec<ObjectSelection> {
    assert_eq!(
        obj_logits.len(),
        points.len() * num_objects,
        "object logits length"
    );
    let members = object_members(obj_logits, num_objects, params.membership_threshold);
    members
        .into_par_iter()
        .enumerate()
        .skip(1)
        .filter(|(_, m)| !m.is_empty())
        .map(|(channel, m)| {
            // Contiguous member positions (no gather in the inner loops) and one FPS run for the largest
            // G that fits: every level's centres are a prefix of it.
            let local: Vec<[R; 3]> = m.iter().map(|&i| points[i]).collect();
            let max_g = params
                .levels
                .iter()
                .map(|l| l.centres)
                .filter(|&g| g <= local.len())
                .max()
                .unwrap_or(0);
            let fps = farthest_point_sampling(&local, max_g);
            // One kd-tree per object for every level's kNN queries; non-finite positions (no tree)
            // fall back to the scan, which skips them.
            let pts64: Vec<[f64; 3]> = local.iter().map(|p| p.map(R::to_f64)).collect();
            let tree = pts64
                .iter()
                .all(|p| p.iter().all(|v| v.is_finite()))
                .then(|| ImmutableKdTree::<f64, 3>::new_from_slice(&pts64).ok())
                .flatten();
            ObjectSelection {
                channel,
                num_members: m.len(),
                levels: params
                    .levels
                    .iter()
                    .map(|&l| select_level(&local, tree.as_ref(), &m, &fps, l))
                    .collect(),
            }
        })
        .collect()
}

/// Adds `s·(a − b)/‖a − b‖` to `ga` and subtracts it from `gb`; returns ‖a − b‖. Zero distance: no gradient.
#[inline]
fn norm_and_grad<R: Real>(a: &[R; 3], b: &[R; 3]) -> (R, [R; 3]) {
    let d = [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    if n > R::ZERO {
        let inv = R::ONE / n;
        (n, [d[0] * inv, d[1] * inv, d[2] * inv])
    } else {
        (n, [R::ZERO; 3])
    }
}

#[inline]
fn add_scaled<R: Real>(g: &mut [R; 3], s: R, u: &[R; 3]) {
    g[0] += s * u[0];
    g[1] += s * u[1];
    g[2] += s * u[2];
}

/// The loss and its position gradient for fixed discrete choices.
pub fn evaluate<R: Real>(
    points: &[[R; 3]],
    selection: &[ObjectSelection],
    params: &ObjectLossParams,
) -> ObjectLoss<R> {
    let mut grad = vec![[R::ZERO; 3]; points.len()];
    let mut value = R::ZERO;
    let two = R::from_f64(2.0);
    let mut objects_per_level = Vec::with_capacity(params.levels.len());
    for (li, level) in params.levels.iter().enumerate() {
        let sels: Vec<&LevelSelection> = selection
            .iter()
            .filter_map(|o| o.levels.get(li)?.as_ref())
            .collect();
        objects_per_level.push(sels.len());
        if sels.is_empty() {
            continue;
        }
        let inv_obj = R::ONE / R::from_f64(sels.len() as f64);
        let ws = R::from_f64(params.spread_weight) * inv_obj;
        let wd = R::from_f64(params.gap_weight) * inv_obj;
        let (g, k) = (level.centres, level.neighbours);
        let inv_g = R::ONE / R::from_f64(g as f64);
        for sel in sels {
            // Spreads S_g and gaps D_g.
            let mut s = vec![R::ZERO; g];
            let mut d = vec![R::ZERO; g];
            for a in 0..g {
                let c = &points[sel.centres[a]];
                for &j in &sel.neighbours[a * k..(a + 1) * k] {
                    s[a] += norm_and_grad(&points[j], c).0;
                }
                d[a] = norm_and_grad(c, &points[sel.centres[sel.nearest_centre[a]]]).0;
            }
            let s_mean = s.iter().fold(R::ZERO, |acc, &v| acc + v) * inv_g;
            let d_mean = d.iter().fold(R::ZERO, |acc, &v| acc + v) * inv_g;
            let var_s = s
                .iter()
                .fold(R::ZERO, |acc, &v| acc + (v - s_mean) * (v - s_mean))
                * inv_g;
            let var_d = d
                .iter()
                .fold(R::ZERO, |acc, &v| acc + (v - d_mean) * (v - d_mean))
                * inv_g;
            value += ws * var_s + wd * var_d;
            for a in 0..g {
                let ci = sel.centres[a];
                let c = points[ci];
                let gs = ws * two * (s[a] - s_mean) * inv_g;
                for &j in &sel.neighbours[a * k..(a + 1) * k] {
                    let (_, u) = norm_and_grad(&points[j], &c);
                    add_scaled(&mut grad[j], gs, &u);
                    add_scaled(&mut grad[ci], -gs, &u);
                }
                let gd = wd * two * (d[a] - d_mean) * inv_g;
                let hi = sel.centres[sel.nearest_centre[a]];
                let (_, u) = norm_and_grad(&c, &points[hi]);
                add_scaled(&mut grad[ci], gd, &u);
                add_scaled(&mut grad[hi], -gd, &u);
            }
        }
    }
    ObjectLoss {
        value,
        grad,
        objects_per_level,
    }
}

/// [`select`] then [`evaluate`]: the object-aware loss at the current positions.
pub fn object_aware_loss<R: Real>(
    points: &[[R; 3]],
    obj_logits: &[R],
    num_objects: usize,
    params: &ObjectLossParams,
) -> ObjectLoss<R> {
    let sel = select(points, obj_logits, num_objects, params);
    evaluate(points, &sel, params)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::rand_vec;

    fn cloud(seed: u64, n: usize) -> Vec<[f64; 3]> {
        rand_vec(seed, 3 * n, -1.0, 1.0)
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect()
    }

    /// FPS by definition: each next point maximises min distance to all chosen so far (recomputed).
    #[test]
    fn fps_matches_brute_force_definition() {
        let p = cloud(30, 200);
        let idx: Vec<usize> = (0..200).step_by(2).collect();
        let sub: Vec<[f64; 3]> = idx.iter().map(|&i| p[i]).collect();
        let got = farthest_point_sampling(&sub, 20);
        assert_eq!(
            farthest_point_sampling(&sub, 7),
            got[..7].to_vec(),
            "prefix property"
        );
        let mut chosen = vec![0usize];
        while chosen.len() < 20 {
            let score = |j: usize| {
                chosen
                    .iter()
                    .map(|&c| dist2(&p[idx[j]], &p[idx[c]]))
                    .fold(f64::INFINITY, f64::min)
            };
            let best = (0..idx.len()).fold(0, |b, j| if score(j) > score(b) { j } else { b });
            chosen.push(best);
        }
        assert_eq!(got, chosen);
    }

    #[test]
    fn knn_matches_full_sort_and_contains_the_query_point() {
        let p = cloud(31, 300);
        for q in [0usize, 17, 299] {
            let got = k_nearest(&p, &p[q], 16);
            let mut all: Vec<usize> = (0..300).collect();
            all.sort_by(|&a, &b| {
                dist2(&p[a], &p[q])
                    .partial_cmp(&dist2(&p[b], &p[q]))
                    .unwrap()
                    .then(a.cmp(&b))
            });
            assert_eq!(got, all[..16].to_vec());
            assert_eq!(got[0], q);
        }
    }

    #[test]
    fn tree_knn_equals_the_brute_force_scan() {
        let p = cloud(33, 2000);
        let pts64: Vec<[f64; 3]> = p.clone();
        let tree = ImmutableKdTree::<f64, 3>::new_from_slice(&pts64).unwrap();
        for q in (0..2000).step_by(37) {
            for k in [1usize, 16, 32] {
                assert_eq!(
                    tree_k_nearest(&tree, &p[q], k),
                    k_nearest(&p, &p[q], k),
                    "query {q}, k {k}"
                );
            }
        }
    }

    /// Two objects (channels 1, 2) of different sizes, a background group and unassigned surfels.
    fn scene() -> (Vec<[f64; 3]>, Vec<f64>, usize) {
        let k = 4;
        let n = 150;
        let p = cloud(32, n);
        let mut logits = vec![0.0; n * k];
        for i in 0..n {
            let c = match i % 10 {
                0..=5 => 1,
                6..=7 => 2,
                8 => 0,
                _ => usize::MAX, // uniform logits: no channel above 0.5
            };
            if c != usize::MAX {
                logits[i * k + c] = 5.0;
            }
        }
        (p, logits, k)
    }

    fn small_params() -> ObjectLossParams {
        ObjectLossParams {
            levels: vec![
                ObjectLevel {
                    centres: 8,
                    neighbours: 6,
                },
                ObjectLevel {
                    centres: 16,
                    neighbours: 8,
                },
                ObjectLevel {
                    centres: 40,
                    neighbours: 8,
                },
            ],
            ..Default::default()
        }
    }

    #[test]
    fn members_use_softmax_probability_above_half() {
        let (_, logits, k) = scene();
        let m = object_members(&logits, k, 0.5);
        assert_eq!(m[1].len(), 90);
        assert_eq!(m[2].len(), 30);
        assert_eq!(m[0].len(), 15);
        assert!(m[3].is_empty());
    }

    #[test]
    fn small_objects_skip_levels_they_cannot_fill() {
        let (p, logits, k) = scene();
        let sel = select(&p, &logits, k, &small_params());
        assert_eq!(
            sel.iter().map(|o| o.channel).collect::<Vec<_>>(),
            vec![1, 2]
        );
        // Object 2 has 30 members: levels with G = 8, 16 run, G = 40 is skipped.
        assert!(
            sel[1].levels[0].is_some() && sel[1].levels[1].is_some() && sel[1].levels[2].is_none()
        );
        assert!(sel[0].levels.iter().all(Option::is_some));
        let loss = evaluate(&p, &sel, &small_params());
        assert_eq!(loss.objects_per_level, vec![2, 2, 1]);
        // Non-members get no gradient.
        for i in (0..150).filter(|i| i % 10 >= 8) {
            assert_eq!(loss.grad[i], [0.0; 3]);
        }
    }

    #[test]
    fn gradient_matches_finite_differences_with_selection_fixed() {
        let (p, logits, k) = scene();
        let params = small_params();
        let sel = select(&p, &logits, k, &params);
        let loss = evaluate(&p, &sel, &params);
        assert!(loss.value > 0.0);
        let h = 1e-6;
        let mut max_err = 0.0f64;
        for i in 0..p.len() {
            for ax in 0..3 {
                let mut pp = p.clone();
                pp[i][ax] += h;
                let fp = evaluate(&pp, &sel, &params).value;
                pp[i][ax] -= 2.0 * h;
                let fm = evaluate(&pp, &sel, &params).value;
                let fd = (fp - fm) / (2.0 * h);
                let err = (fd - loss.grad[i][ax]).abs();
                max_err = max_err.max(err / (1.0 + fd.abs()));
                assert!(
                    err <= 1e-5 * (1.0 + fd.abs()),
                    "surfel {i} axis {ax}: fd {fd} analytic {}",
                    loss.grad[i][ax]
                );
            }
        }
        assert!(max_err < 1e-5);
    }

    #[test]
    fn evenly_spaced_grid_has_near_zero_gap_variance() {
        // A 4×4×4 lattice; the 64-centre level picks every point, all nearest gaps equal the spacing.
        let mut p = Vec::new();
        for x in 0..4 {
            for y in 0..4 {
                for z in 0..4 {
                    p.push([x as f64 * 0.1, y as f64 * 0.1, z as f64 * 0.1]);
                }
            }
        }
        let logits: Vec<f64> = p.iter().flat_map(|_| [0.0, 9.0]).collect();
        let params = ObjectLossParams {
            levels: vec![ObjectLevel {
                centres: 64,
                neighbours: 1,
            }],
            ..Default::default()
        };
        let loss = object_aware_loss(&p, &logits, 2, &params);
        assert!(loss.value.abs() < 1e-20, "{}", loss.value);
    }

    #[test]
    fn f32_selection_and_value_agree_with_f64() {
        let (p, logits, k) = scene();
        let pf: Vec<[f32; 3]> = p.iter().map(|a| a.map(|v| v as f32)).collect();
        let lf: Vec<f32> = logits.iter().map(|&v| v as f32).collect();
        let a = object_aware_loss(&p, &logits, k, &small_params());
        let b = object_aware_loss(&pf, &lf, k, &small_params());
        assert!(
            (a.value - b.value as f64).abs() < 1e-4 * a.value.abs().max(1.0),
            "{} vs {}",
            a.value,
            b.value
        );
    }
}
