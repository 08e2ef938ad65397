//! Bounding-volume hierarchy over triangles, built with the binned surface-area heuristic.
//!
//! Build (top-down): at each node the triangle centroids are binned into [`BINS`] slabs along each
//! axis; the split plane minimising the SAH cost
//! `C = C_trav + (A_L·N_L + A_R·N_R) / A_parent` (`A` = box surface area, `N` = triangle count)
//! is taken, unless splitting costs more than intersecting the leaf (`N` triangles). Nodes are
//! stored depth-first in one array; a node's left child is the next node, the right child is
//! stored by index, so traversal is a plain loop with a small stack, nearer child first.
//!
//! Ray–triangle tests use the Möller–Trumbore algorithm (barycentrics from two cross products).

use glam::{Vec3, Vec3A};

/// Centroid bins per axis for the SAH sweep: 12 is the usual quality/speed balance for binned
/// builds (more bins barely change tree quality for meshes of this size).
pub const BINS: usize = 12;
/// Leaves never hold more triangles than this (keeps worst-case leaf cost bounded).
pub const MAX_LEAF: usize = 4;
/// Cost of one traversal step relative to one triangle test (typical value for CPU tracers).
pub const TRAVERSAL_COST: f32 = 1.0;

/// A triangle prepared for intersection: `v0` and the edges `e1 = v1 − v0`, `e2 = v2 − v0`.
#[derive(Clone, Copy, Debug)]
pub struct Tri {
    pub v0: Vec3,
    pub e1: Vec3,
    pub e2: Vec3,
}

impl Tri {
    pub fn new(a: Vec3, b: Vec3, c: Vec3) -> Self {
        Self {
            v0: a,
            e1: b - a,
            e2: c - a,
        }
    }

    /// Möller–Trumbore: returns `(t, u, v)` with the hit point `v0 + u·e1 + v·e2 = o + t·d`.
    #[inline]
    pub fn intersect(&self, o: Vec3, d: Vec3, t_max: f32) -> Option<(f32, f32, f32)> {
        let p = d.cross(self.e2);
        let det = self.e1.dot(p);
        if det.abs() < 1e-14 {
            return None;
        }
        let inv = 1.0 / det;
        let s = o - self.v0;
        let u = s.dot(p) * inv;
        if !(0.0..=1.0).contains(&u) {
            return None;
        }
        let q = s.cross(self.e1);
        let v = d.dot(q) * inv;
        if v < 0.0 || u + v > 1.0 {
            return None;
        }
        let t = self.e2.dot(q) * inv;
        (t > 0.0 && t < t_max).then_some((t, u, v))
    }
}

/// Box with SIMD-friendly corners (`Vec3A`: the slab test runs on 4-wide lanes).
#[derive(Clone, Copy, Debug)]
struct Aabb {
    lo: Vec3A,
    hi: Vec3A,
}

impl Aabb {
    const EMPTY: Aabb = Aabb {
        lo: Vec3A::splat(f32::INFINITY),
        hi: Vec3A::splat(f32::NEG_INFINITY),
    };
    fn grow(&mut self, p: Vec3) {
        self.lo = self.lo.min(p.into());
        self.hi = self.hi.max(p.into());
    }
    fn merge(&mut self, o: &Aabb) {
        self.lo = self.lo.min(o.lo);
        self.hi = self.hi.max(o.hi);
    }
    fn area(&self) -> f32 {
        let e = (self.hi - self.lo).max(Vec3A::ZERO);
        2.0 * (e.x * e.y + e.y * e.z + e.z * e.x)
    }
    /// Slab test; returns the entry distance when the box is hit before `t_max`.
    #[inline]
    fn hit(&self, o: Vec3A, inv_d: Vec3A, t_max: f32) -> Option<f32> {
        let t0 = (self.lo - o) * inv_d;
        let t1 = (self.hi - o) * inv_d;
        let tn = t0.min(t1).max_element().max(0.0);
        let tf = t0.max(t1).min_element().min(t_max);
        (tn <= tf).then_some(tn)
    }
}

#[derive(Clone, Copy, Debug)]
struct Node {
    bounds: Aabb,
    /// Leaf: first index into `order`; inner: index of the right child.
    start_or_right: u32,
    /// Leaf: triangle count (> 0); inner: 0.
    count: u32,
}

/// A closest hit: distance along the ray, triangle index, barycentrics `(u, v)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    pub t: f32,
    pub tri: u32,
    pub u: f32,
    pub v: f32,
}

/// The hierarchy; triangles are referenced by their index in the slice given to [`Bvh::build`].
pub struct Bvh {
    nodes: Vec<Node>,
    order: Vec<u32>,
    tris: Vec<Tri>,
}

impl Bvh {
    pub fn build(tris: Vec<Tri>) -> Self {
        let bounds: Vec<Aabb> = tris
            .iter()
            .map(|t| {
                let mut b = Aabb::EMPTY;
                for p in [t.v0, t.v0 + t.e1, t.v0 + t.e2] {
                    b.grow(p);
                }
                b
            })
            .collect();
        let centroids: Vec<Vec3> = bounds
            .iter()
            .map(|b| Vec3::from(0.5 * (b.lo + b.hi)))
            .collect();
        let mut order: Vec<u32> = (0..tris.len() as u32).collect();
        let mut nodes = Vec::with_capacity(2 * tris.len().max(1));
        if !tris.is_empty() {
            build_rec(&mut nodes, &mut order, 0, tris.len(), &bounds, &centroids);
        }
        Self { nodes, order, tris }
    }

    pub fn len(&self) -> usize {
        self.tris.len()
    }

    pub fn is_empty(&self) -> bool {
        self.tris.is_empty()
    }

    /// The `i`-th triangle as given to [`Bvh::build`].
    pub fn tri(&self, i: u32) -> &Tri {
        &self.tris[i as usize]
    }

    /// Closest hit with `0 < t < t_max`.
    pub fn closest(&self, o: Vec3, d: Vec3, t_max: f32) -> Option<Hit> {
        if self.nodes.is_empty() {
            return None;
        }
        let inv_d = Vec3A::from(d.recip());
        let oa = Vec3A::from(o);
        let mut best: Option<Hit> = None;
        let mut t_best = t_max;
        let mut stack = [0u32; 64];
        let mut sp = 0usize;
        let mut node = 0u32;
        self.nodes[0].bounds.hit(oa, inv_d, t_best)?;
        loop {
            let n = &self.nodes[node as usize];
            if n.count > 0 {
                for &ti in
                    &self.order[n.start_or_right as usize..(n.start_or_right + n.count) as usize]
                {
                    if let Some((t, u, v)) = self.tris[ti as usize].intersect(o, d, t_best) {
                        t_best = t;
                        best = Some(Hit { t, tri: ti, u, v });
                    }
                }
            } else {
                let (l, r) = (node + 1, n.start_or_right);
                let hl = self.nodes[l as usize].bounds.hit(oa, inv_d, t_best);
                let hr = self.nodes[r as usize].bounds.hit(oa, inv_d, t_best);
                match (hl, hr) {
                    (Some(a), Some(b)) => {
                        let (near, far) = if a <= b { (l, r) } else { (r, l) };
                        stack[sp] = far;
                        sp += 1;
                        node = near;
                        continue;
                    }
                    (Some(_), None) => {
                        node = l;
                        continue;
                    }
                    (None, Some(_)) => {
                        node = r;
                        continue;
                    }
                    (None, None) => {}
                }
            }
            // Pop the next subtree that can still contain a closer hit.
            loop {
                if sp == 0 {
                    return best;
                }
                sp -= 1;
                node = stack[sp];
                if self.nodes[node as usize]
                    .bounds
                    .hit(oa, inv_d, t_best)
                    .is_some()
                {
                    break;
                }
            }
        }
    }
}

fn build_rec(
    nodes: &mut Vec<Node>,
    order: &mut [u32],
    start: usize,
    end: usize,
    bounds: &[Aabb],
    centroids: &[Vec3],
) -> usize {
    let idx = nodes.len();
    let mut bb = Aabb::EMPTY;
    let mut cb = Aabb::EMPTY;
    for &i in &order[start..end] {
        bb.merge(&bounds[i as usize]);
        cb.grow(centroids[i as usize]);
    }
    nodes.push(Node {
        bounds: bb,
        start_or_right: start as u32,
        count: (end - start) as u32,
    });
    let n = end - start;
    if n <= 2 {
        return idx;
    }
    // Binned SAH over the three axes.
    let mut best: Option<(f32, usize, usize)> = None; // (cost, axis, split bin)
    for (axis, (lo, hi)) in cb
        .lo
        .to_array()
        .into_iter()
        .zip(cb.hi.to_array())
        .enumerate()
    {
        if hi - lo < 1e-9 {
            continue;
        }
        let scale = BINS as f32 / (hi - lo);
        let mut bin_box = [Aabb::EMPTY; BINS];
        let mut bin_n = [0usize; BINS];
        for &i in &order[start..end] {
            let b = (((centroids[i as usize][axis] - lo) * scale) as usize).min(BINS - 1);
            bin_n[b] += 1;
            bin_box[b].merge(&bounds[i as usize]);
        }
        // Sweep from the right to get suffix areas/counts, then from the left.
        let mut right_area = [0.0f32; BINS];
        let mut right_n = [0usize; BINS];
        let (mut acc, mut cnt) = (Aabb::EMPTY, 0);
        for b in (1..BINS).rev() {
            acc.merge(&bin_box[b]);
            cnt += bin_n[b];
            right_area[b] = acc.area();
            right_n[b] = cnt;
        }
        let (mut acc, mut cnt) = (Aabb::EMPTY, 0);
        for b in 0..BINS - 1 {
            acc.merge(&bin_box[b]);
            cnt += bin_n[b];
            if cnt == 0 || right_n[b + 1] == 0 {
                continue;
            }
            let cost = TRAVERSAL_COST
                + (acc.area() * cnt as f32 + right_area[b + 1] * right_n[b + 1] as f32)
                    / bb.area().max(1e-30);
            if best.is_none_or(|(c, _, _)| cost < c) {
                best = Some((cost, axis, b + 1));
            }
        }
    }
    let Some((cost, axis, split)) = best else {
        return idx;
    };
    if cost >= n as f32 && n <= MAX_LEAF {
        return idx;
    }
    let (lo, scale) = (cb.lo[axis], BINS as f32 / (cb.hi[axis] - cb.lo[axis]));
    let slice = &mut order[start..end];
    let mut mid = 0;
    for k in 0..slice.len() {
        let b = (((centroids[slice[k] as usize][axis] - lo) * scale) as usize).min(BINS - 1);
        if b < split {
            slice.swap(k, mid);
            mid += 1;
        }
    }
    let mid = start + mid;
    build_rec(nodes, order, start, mid, bounds, centroids);
    let right = build_rec(nodes, order, mid, end, bounds, centroids);
    nodes[idx].start_or_right = right as u32;
    nodes[idx].count = 0;
    idx
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};

    #[test]
    fn bvh_closest_hit_equals_brute_force() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
        let mut r = |a: f32, b: f32| rng.random_range(a..b);
        let tris: Vec<Tri> = (0..2000)
            .map(|_| {
                let c = Vec3::new(r(-1.0, 1.0), r(-1.0, 1.0), r(-1.0, 1.0));
                let s = 0.08;
                Tri::new(
                    c,
                    c + Vec3::new(r(-s, s), r(-s, s), r(-s, s)),
                    c + Vec3::new(r(-s, s), r(-s, s), r(-s, s)),
                )
            })
            .collect();
        let bvh = Bvh::build(tris.clone());
        let mut hits = 0;
        for _ in 0..2000 {
            let o = Vec3::new(r(-2.0, 2.0), r(-2.0, 2.0), 3.0);
            let d = (Vec3::new(r(-1.0, 1.0), r(-1.0, 1.0), r(-1.0, 1.0)) - o).normalize();
            let brute = tris
                .iter()
                .enumerate()
                .filter_map(|(i, t)| t.intersect(o, d, f32::INFINITY).map(|h| (h.0, i)))
                .min_by(|a, b| a.0.total_cmp(&b.0));
            let got = bvh.closest(o, d, f32::INFINITY);
            assert_eq!(brute.map(|b| b.1 as u32), got.map(|h| h.tri));
            hits += got.is_some() as usize;
        }
        assert!(hits > 50, "test rays should hit something ({hits})");
    }
}
