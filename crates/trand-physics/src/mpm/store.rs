//! Particle storage: packs of [`LANES`] particles, each field one SIMD vector across the pack
//! (an array of structures of arrays), so that the per-particle material update
//! ([`super::material`]) runs on four particles per instruction without gathering fields, while
//! the grid transfers read one particle (one lane) at a time.
//!
//! Only the last pack may be partly filled; its free lanes hold a copy of a particle's position at
//! rest (`v = 0`, `C = 0`, `F = I`): G2P keeps them there, the material update leaves them
//! unchanged, and P2G skips them.

use glam::{Mat3, Quat, Vec3};
use rayon::prelude::*;
use wide::f32x4;

/// Particles per pack: one SSE register of `f32`.
pub(super) const LANES: usize = 4;

/// A 3×3 matrix per lane, `m[column][row]` like glam's.
pub(super) type LaneMat3 = [[f32x4; 3]; 3];

/// [`LANES`] material points.
#[derive(Clone, Copy)]
pub(super) struct Pack {
    pub x: [f32x4; 3],
    pub v: [f32x4; 3],
    /// APIC affine velocity matrix (≈ ∇v).
    pub c: LaneMat3,
    /// Deformation gradient.
    pub f: LaneMat3,
    /// Polar rotation of `f` as a quaternion `(x, y, z, w)` (also the warm start of the next
    /// extraction).
    pub rot: [f32x4; 4],
    /// Index of each lane's particle in the caller's input order.
    pub id: [u32; LANES],
    /// Lanes in use (`LANES` except possibly in the last pack).
    pub live: usize,
}

impl Pack {
    pub fn x(&self, l: usize) -> Vec3 {
        Vec3::new(
            self.x[0].as_array()[l],
            self.x[1].as_array()[l],
            self.x[2].as_array()[l],
        )
    }

    pub fn v(&self, l: usize) -> Vec3 {
        Vec3::new(
            self.v[0].as_array()[l],
            self.v[1].as_array()[l],
            self.v[2].as_array()[l],
        )
    }

    pub fn f(&self, l: usize) -> Mat3 {
        lane_mat3(&self.f, l)
    }

    pub fn rot(&self, l: usize) -> Quat {
        let q = self.rot.map(|c| c.as_array()[l]);
        Quat::from_xyzw(q[0], q[1], q[2], q[3])
    }

    /// Copies lane `from` of `src` into lane `to`.
    fn set_lane(&mut self, to: usize, src: &Pack, from: usize) {
        assert!(to < LANES && from < LANES);
        let copy = |d: &mut [f32x4], s: &[f32x4]| {
            for (d, s) in d.iter_mut().zip(s) {
                d.as_mut_array()[to] = s.as_array()[from];
            }
        };
        copy(&mut self.x, &src.x);
        copy(&mut self.v, &src.v);
        copy(self.c.as_flattened_mut(), src.c.as_flattened());
        copy(self.f.as_flattened_mut(), src.f.as_flattened());
        copy(&mut self.rot, &src.rot);
        self.id[to] = src.id[from];
    }
}

/// Lane `l` of a lane matrix.
pub(super) fn lane_mat3(m: &LaneMat3, l: usize) -> Mat3 {
    let col =
        |c: &[f32x4; 3]| Vec3::new(c[0].as_array()[l], c[1].as_array()[l], c[2].as_array()[l]);
    Mat3::from_cols(col(&m[0]), col(&m[1]), col(&m[2]))
}

impl Pack {
    /// Every lane the particle `id` at rest (`v = 0`, `C = 0`, `F = I`, `R = I`) at `x`; no lane
    /// live yet.
    fn at_rest(x: [f32; 3], id: u32) -> Self {
        let (zero, one) = (f32x4::ZERO, f32x4::ONE);
        Pack {
            x: x.map(f32x4::splat),
            v: [zero; 3],
            c: [[zero; 3]; 3],
            f: [[one, zero, zero], [zero, one, zero], [zero, zero, one]],
            rot: [zero, zero, zero, one],
            id: [id; LANES],
            live: 0,
        }
    }
}

/// Packs of particles at rest at `positions`, in that order.
pub(super) fn packs_at_rest(positions: &[[f32; 3]]) -> Vec<Pack> {
    positions
        .chunks(LANES)
        .enumerate()
        .map(|(k, ps)| {
            let first = (k * LANES) as u32;
            let rest = |l: usize| Pack::at_rest(ps[l], first + l as u32);
            let mut p = rest(0);
            for l in 1..ps.len() {
                p.set_lane(l, &rest(l), l);
            }
            p.live = ps.len();
            p
        })
        .collect()
}

/// Reorders the particles of `packs` stably by their `keys` (per pack) when they are not in that
/// order already.
pub(super) fn sort_packs(packs: &mut Vec<Pack>, keys: impl Fn(&Pack) -> [u64; LANES] + Sync) {
    let keys = &keys;
    let keyed: Vec<(u64, u32)> = packs
        .par_iter()
        .enumerate()
        .flat_map_iter(|(k, p)| {
            let keys = keys(p);
            (0..p.live).map(move |l| (keys[l], (k * LANES + l) as u32))
        })
        .collect();
    if keyed.is_sorted_by_key(|k| k.0) {
        return;
    }
    let mut keyed = keyed;
    // Stable and adaptive (the order of the last frame is nearly sorted).
    keyed.sort_by_key(|k| k.0);
    let old = std::mem::take(packs);
    *packs = keyed
        .par_chunks(LANES)
        .map(|group| {
            let at = |i: u32| (&old[i as usize / LANES], i as usize % LANES);
            let (src, sl) = at(group[0].1);
            // Free lanes: the first particle at rest.
            let mut p = Pack::at_rest(src.x(sl).to_array(), src.id[sl]);
            for (l, &(_, i)) in group.iter().enumerate() {
                let (src, sl) = at(i);
                p.set_lane(l, src, sl);
            }
            p.live = group.len();
            p
        })
        .collect();
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sorting_moves_whole_particles_into_key_order_and_keeps_free_lanes_at_rest() {
        // Seven particles (one free lane), keyed by descending x; two share a key (stable).
        let xs: Vec<[f32; 3]> = [3.0, 1.0, 6.0, 5.0, 1.0, 0.0, 2.0]
            .iter()
            .map(|&x| [x, 10.0 * x, -x])
            .collect();
        let mut packs = packs_at_rest(&xs);
        for p in &mut packs {
            for l in 0..p.live {
                // A velocity and deformation gradient that name the particle.
                let id = p.id[l] as f32;
                p.v[1].as_mut_array()[l] = id;
                p.f[2][0].as_mut_array()[l] = 100.0 + id;
            }
        }
        let key = |p: &Pack| std::array::from_fn(|l| (1000.0 - p.x[0].as_array()[l]) as u64);
        sort_packs(&mut packs, key);
        let order: Vec<u32> = packs.iter().flat_map(|p| p.id[..p.live].to_vec()).collect();
        assert_eq!(order, [2, 3, 0, 6, 1, 4, 5]);
        for p in &packs {
            for l in 0..p.live {
                let id = p.id[l] as usize;
                assert_eq!(p.x(l).to_array(), xs[id]);
                assert_eq!(p.v(l).y, id as f32);
                assert_eq!(p.f(l).z_axis.x, 100.0 + id as f32);
            }
        }
        let last = packs.last().unwrap();
        assert_eq!(last.live, 3);
        assert_eq!((last.v(3), last.f(3)), (Vec3::ZERO, Mat3::IDENTITY));
    }
}
