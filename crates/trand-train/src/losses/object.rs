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
//! length), and each FPS centre's neighbours are found once, for the largest K of the levels, in a
//! uniform grid of the object's members ([`crate::losses::knn`]; [`k_nearest`], the plain scan, is the
//! reference it is tested against).
//!
//! The discrete choices (members, FPS centres, neighbour lists, nearest other centre) are made once by
//! [`select`] and then held fixed by [`evaluate`], which is what the finite-difference tests perturb.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use trand_core::Real;
use trand_core::math::softmax_numerators8;

pub use super::knn::k_nearest;
use super::knn::{PointGrid, dist2};

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

/// Surfels per block of [`object_members`]: one per lane of [`Real::fast_exp8`].
const MEMBER_LANES: usize = 8;

/// Members of every channel (index = channel; channel 0, the background, included) by softmax
/// probability `> threshold`, in storage order.
///
/// The softmax is the rasterizer's ([`softmax_numerators8`]): eight surfels at once, one per lane, so
/// a visible surfel is a member exactly when its rendered probability exceeds the threshold. With the
/// scalar `exp` of the standard library and one surfel at a time, this was a third of the loss's
/// selection (15 exponentials for each of ~50 k surfels, every iteration).
pub fn object_members<R: Real>(
    obj_logits: &[R],
    num_objects: usize,
    threshold: f64,
) -> Vec<Vec<usize>> {
    assert!(
        threshold >= 0.5,
        "membership threshold {threshold} < 0.5 would make membership ambiguous"
    );
    let k = num_objects;
    if k == 0 {
        return Vec::new();
    }
    assert_eq!(obj_logits.len() % k, 0, "object logits length");
    let thr = R::from_f64(threshold);
    let sure_gap = R::from_f64(sure_member_gap(k, threshold));
    // Channel + 1 of the surfel's owner, 0 for none.
    const CHUNK: usize = MEMBER_LANES * 64;
    let mut owner = vec![0u16; obj_logits.len() / k];
    owner
        .par_chunks_mut(CHUNK)
        .zip(obj_logits.par_chunks(CHUNK * k))
        .for_each(|(own, logits)| {
            let mut e = vec![[R::ZERO; MEMBER_LANES]; k];
            for (o, block) in own
                .chunks_mut(MEMBER_LANES)
                .zip(logits.chunks(MEMBER_LANES * k))
            {
                block_owners(block, k, thr, sure_gap, &mut e, o);
            }
        });
    let mut out = vec![Vec::new(); k];
    for (i, o) in owner.into_iter().enumerate() {
        if o > 0 {
            out[o as usize - 1].push(i);
        }
    }
    out
}

/// The logit gap above which a surfel's largest channel surely exceeds probability `thr` (≥ ½) among
/// `k` channels: `p_max = 1/(1 + Σ_{c≠max} e^{l_c − l_max}) ≥ 1/(1 + (k − 1) e^{−gap})`, which exceeds
/// `thr` once `gap > ln((k − 1)/(1/thr − 1))`. The margin keeps such a surfel's computed probability
/// well clear of `thr` (a few hundredths), so skipping its exponentials never changes a decision the
/// rasterizer's softmax would make.
fn sure_member_gap(k: usize, thr: f64) -> f64 {
    const MARGIN: f64 = 0.1;
    let room = 1.0 / thr - 1.0;
    if room > 0.0 {
        ((k.max(2) - 1) as f64 / room).ln() + MARGIN
    } else {
        f64::INFINITY
    }
}

/// The owner (channel + 1 whose probability exceeds `thr`, or 0) of each of the ≤ 8 surfels in `block`
/// (surfel-major logits, `k` per surfel) into `owner`; `e` is scratch (`k` lanes).
///
/// Trained surfels mostly belong clearly to one channel: when every lane's largest logit leads the
/// second by more than `sure_gap` ([`sure_member_gap`]), the owners are the largest channels and the
/// K exponentials per surfel are skipped. Otherwise (or with a non-finite logit, whose softmax
/// is NaN: no owner) the block goes through the softmax.
fn block_owners<R: Real>(
    block: &[R],
    k: usize,
    thr: R,
    sure_gap: R,
    e: &mut [[R; MEMBER_LANES]],
    owner: &mut [u16],
) {
    const L: usize = MEMBER_LANES;
    // Channel-major lanes (`e[c][l]` = logit c of surfel l; missing surfels 0), then in place the
    // softmax numerators.
    for (l, logits) in block.chunks_exact(k).enumerate() {
        for (c, &v) in logits.iter().enumerate() {
            e[c][l] = v;
        }
    }
    for ec in e.iter_mut() {
        ec[owner.len()..].fill(R::ZERO);
    }
    // Largest and second largest logit, the largest's channel (the first on ties), the logits' sum
    // (non-finite when any logit is).
    let neg_inf = R::from_f64(f64::NEG_INFINITY);
    let (mut top, mut second, mut arg, mut sum) = (e[0], [neg_inf; L], [0i32; L], e[0]);
    for (c, ec) in e.iter().enumerate().skip(1) {
        for l in 0..L {
            let (v, above) = (ec[l], ec[l] > top[l]);
            second[l] = if above {
                top[l]
            } else if v > second[l] {
                v
            } else {
                second[l]
            };
            arg[l] = if above { c as i32 } else { arg[l] };
            top[l] = if above { v } else { top[l] };
            sum[l] += v;
        }
    }
    let sure = (0..owner.len()).all(|l| sum[l].is_finite() && top[l] - second[l] > sure_gap);
    if sure {
        for (o, &a) in owner.iter_mut().zip(&arg) {
            *o = a as u16 + 1;
        }
        return;
    }
    let s = softmax_numerators8(e);
    let inv: [R; L] = std::array::from_fn(|l| R::ONE / s[l]);
    let mut own = [0i32; L];
    for (c, ec) in e.iter().enumerate() {
        for l in 0..L {
            let hit = own[l] == 0 && ec[l] * inv[l] > thr;
            own[l] = if hit { c as i32 + 1 } else { own[l] };
        }
    }
    for (o, &v) in owner.iter_mut().zip(&own) {
        *o = v as u16;
    }
}

/// Farthest-point sampling of `count` of `points`: starts at point 0, then repeatedly takes the point with
/// the largest squared distance to the chosen set (lowest index on ties). Each prefix of the result is the
/// FPS of that length. Requires `count ≤ points.len()`. Points with a non-finite coordinate are never
/// chosen (unless point 0 is one: then every distance is NaN and the result repeats point 0).
///
/// Each round updates every point's distance to the chosen set and the largest distance in eight
/// independent lanes (point `j` in lane `j mod 8`), a loop LLVM vectorizes, then takes the first point
/// at the largest lane maximum: the same choice as one sequential scan with a running argmax, whose
/// serial dependency chain kept it scalar (3.4 ms of the ~9 ms selection on a trained five-object
/// scene).
pub fn farthest_point_sampling<R: Real>(points: &[[R; 3]], count: usize) -> Vec<usize> {
    const L: usize = 8;
    assert!(
        count <= points.len(),
        "FPS of {count} from {} points",
        points.len()
    );
    if count == 0 {
        return Vec::new();
    }
    let n = points.len();
    // Structure of arrays, padded to whole lanes with NaN points; a point with a non-finite coordinate
    // becomes a NaN point too, so its distance is NaN in every round and it is never chosen (an
    // infinite coordinate would otherwise be the farthest point).
    let padded = n.div_ceil(L) * L;
    let nan = R::from_f64(f64::NAN);
    let coord = |a: usize| -> Vec<R> {
        (0..padded)
            .map(|j| match points.get(j) {
                Some(p) if p.iter().all(|v| v.is_finite()) => p[a],
                _ => nan,
            })
            .collect()
    };
    let (xs, ys, zs) = (coord(0), coord(1), coord(2));
    let mut min_d: Vec<R> = vec![R::from_f64(f64::INFINITY); padded];
    let mut chosen = Vec::with_capacity(count);
    chosen.push(0);
    let mut c = points[0];
    while chosen.len() < count {
        // Pass 1 (vectorized): distances to the newest centre.
        for (((md, &x), &y), &z) in min_d.iter_mut().zip(&xs).zip(&ys).zip(&zs) {
            let (dx, dy, dz) = (x - c[0], y - c[1], z - c[2]);
            let d = dx * dx + dy * dy + dz * dz;
            // `!(d ≥ m)` rather than `min`: a non-finite point keeps a NaN distance, which fails
            // every `>` below, so it is never chosen.
            #[allow(clippy::neg_cmp_op_on_partial_ord)]
            let keep_new = !(d >= *md);
            *md = if keep_new { d } else { *md };
        }
        // Pass 2: the largest distance, per lane, then over the lanes.
        let mut lane_max = [-R::ONE; L];
        for ch in min_d.chunks_exact(L) {
            for l in 0..L {
                lane_max[l] = if ch[l] > lane_max[l] {
                    ch[l]
                } else {
                    lane_max[l]
                };
            }
        }
        let mut far = -R::ONE;
        for m in lane_max {
            if m > far {
                far = m;
            }
        }
        // Pass 3: the first point at that distance (point 0 if every distance is NaN).
        // Whole lanes first (a branch-free compare LLVM vectorizes), then the point within them.
        let best = min_d
            .chunks_exact(L)
            .position(|ch| ch.iter().fold(false, |hit, &d| hit | (d == far)))
            .and_then(|b| {
                let at = min_d[b * L..(b + 1) * L].iter().position(|&d| d == far)?;
                Some(b * L + at)
            })
            .unwrap_or(0);
        chosen.push(best);
        c = points[best];
    }
    chosen
}

/// Selection of one object at one level, given the member positions (`local`, contiguous), their
/// surfel indices, the members' FPS order (at least G long) and each FPS centre's nearest members
/// (nearest first, at least K long where the positions are finite).
fn select_level<R: Real>(
    local: &[[R; 3]],
    members: &[usize],
    fps: &[usize],
    nearest: &[Vec<usize>],
    level: ObjectLevel,
) -> Option<LevelSelection> {
    let (g, k) = (level.centres, level.neighbours);
    if g < 2 || local.len() < g || local.len() < k || fps.len() < g || nearest.len() < g {
        return None;
    }
    let centres_pos = &fps[..g];
    let centres: Vec<usize> = centres_pos.iter().map(|&j| members[j]).collect();
    let mut neighbours = Vec::with_capacity(g * k);
    for nn in &nearest[..g] {
        if nn.len() < k {
            return None; // non-finite positions: no well-defined neighbourhood
        }
        // The K nearest are the first K of a longer nearest-first list (same order, same ties).
        neighbours.extend(nn[..k].iter().map(|&j| members[j]));
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
            // Each centre's neighbours once, for the largest K of the levels the object can fill.
            let max_k = params
                .levels
                .iter()
                .filter(|l| l.centres <= local.len() && l.neighbours <= local.len())
                .map(|l| l.neighbours)
                .max()
                .unwrap_or(0);
            let grid = PointGrid::new(&local);
            let nearest: Vec<Vec<usize>> = fps
                .par_iter()
                .map(|&c| grid.k_nearest(&local[c].map(R::to_f64), max_k))
                .collect();
            ObjectSelection {
                channel,
                num_members: m.len(),
                levels: params
                    .levels
                    .iter()
                    .map(|&l| select_level(&local, &m, &fps, &nearest, l))
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
    use trand_core::math::softmax;

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
    fn fps_takes_the_lowest_index_on_ties_and_never_a_non_finite_point() {
        // 14 points (not a whole number of lanes): a symmetric cross, so later rounds tie, and two
        // non-finite points that a NaN-unaware min/max would pick.
        let mut p: Vec<[f32; 3]> = vec![[0.0; 3]];
        for r in [1.0f32, 2.0, 3.0] {
            p.extend([[r, 0.0, 0.0], [-r, 0.0, 0.0], [0.0, r, 0.0], [0.0, -r, 0.0]]);
        }
        p[5] = [f32::NAN, 0.0, 0.0];
        p.insert(9, [f32::INFINITY, 0.0, 0.0]);
        assert_eq!(p.len(), 14);
        let got = farthest_point_sampling(&p, 6);
        // Sequential reference: running argmax with `>`; a non-finite point is at distance NaN.
        let mut chosen = vec![0usize];
        let mut md = vec![f32::INFINITY; p.len()];
        while chosen.len() < 6 {
            let c = p[*chosen.last().unwrap()];
            let (mut best, mut best_d) = (0, -1.0f32);
            for (j, m) in md.iter_mut().enumerate() {
                let finite = p[j].iter().all(|v| v.is_finite());
                let d = if finite { dist2(&p[j], &c) } else { f32::NAN };
                if d < *m || d.is_nan() {
                    *m = d;
                }
                if *m > best_d {
                    best = j;
                    best_d = *m;
                }
            }
            chosen.push(best);
        }
        assert_eq!(got, chosen);
        assert!(got.iter().all(|&j| p[j].iter().all(|v| v.is_finite())));
    }

    #[test]
    fn members_agree_with_the_scalar_softmax_away_from_the_threshold() {
        // The lane softmax uses the rasterizer's exponential; membership may differ from the standard
        // library's only where the largest probability is within rounding of the threshold.
        let k = 7;
        let n = 1001; // not a whole number of lanes or chunks
        let logits: Vec<f32> = rand_vec(41, n * k, -4.0, 4.0)
            .into_iter()
            .map(|v: f64| v as f32)
            .collect();
        let m = object_members(&logits, k, 0.5);
        let mut owner = vec![None; n];
        for (c, members) in m.iter().enumerate() {
            for &i in members {
                assert!(owner[i].is_none(), "surfel {i} in two channels");
                owner[i] = Some(c);
            }
        }
        let mut p = vec![0.0f32; k];
        let mut assigned = 0;
        for i in 0..n {
            softmax(&logits[i * k..(i + 1) * k], &mut p);
            let (c, pmax) = p
                .iter()
                .copied()
                .enumerate()
                .fold((0, -1.0), |b, (c, v)| if v > b.1 { (c, v) } else { b });
            if (pmax - 0.5).abs() > 1e-5 {
                assert_eq!(owner[i], (pmax > 0.5).then_some(c), "surfel {i}");
            }
            assigned += usize::from(owner[i].is_some());
        }
        assert!(
            assigned > n / 10 && assigned < n,
            "{assigned} members: a weak test"
        );
    }

    #[test]
    fn members_equal_the_lane_softmax_decision_with_and_without_the_gap_shortcut() {
        // Blocks of clearly assigned surfels (large gaps: the shortcut), mixed blocks, exact ties at the
        // top, non-finite logits and a partial last block; membership must be the lane softmax's
        // `p > thr` everywhere.
        let k = 15;
        let n = 803;
        let noise = rand_vec(43, n * k, -3.0, 3.0);
        let mut logits: Vec<f32> = noise.iter().map(|&v| v as f32).collect();
        for i in 0..n {
            let row = &mut logits[i * k..(i + 1) * k];
            match (i / 8) % 4 {
                0 => row[(i * 7) % k] += 12.0, // sure
                1 if i % 3 == 0 => row[(i * 5) % k] += 9.0,
                2 if i % 5 == 0 => row[1] = row[2].max(row[1]) + 4.0, // tie between 1 and 2 below
                _ => {}
            }
            if (i / 8) % 4 == 2 && i % 5 == 0 {
                row[2] = row[1];
            }
        }
        logits[100 * k + 3] = f32::NAN;
        logits[8 * k + 4] = f32::INFINITY;
        for thr in [0.5, 0.6, 0.9] {
            let m = object_members(&logits, k, thr);
            let mut owner = vec![0usize; n];
            for (c, members) in m.iter().enumerate() {
                for &i in members {
                    owner[i] = c + 1;
                }
            }
            for b in 0..n.div_ceil(8) {
                let mut e = vec![[0.0f32; 8]; k];
                let len = (n - b * 8).min(8);
                for l in 0..len {
                    for c in 0..k {
                        e[c][l] = logits[(b * 8 + l) * k + c];
                    }
                }
                let s = softmax_numerators8(&mut e);
                for l in 0..len {
                    let inv = 1.0 / s[l];
                    let want = (0..k)
                        .find(|&c| e[c][l] * inv > thr as f32)
                        .map_or(0, |c| c + 1);
                    assert_eq!(owner[b * 8 + l], want, "surfel {}, thr {thr}", b * 8 + l);
                }
            }
        }
        let members = object_members(&logits, k, 0.5)
            .iter()
            .skip(1)
            .map(Vec::len)
            .sum::<usize>();
        assert!(members > n / 4, "{members} members: a weak test");
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
