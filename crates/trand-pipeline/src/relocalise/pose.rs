//! Rigid poses of one object, its shape as the search sees it, and the orientations the search
//! samples.
//!
//! A pose moves the object's undeformed (t = 0) shape: `p ↦ R (p − c) + c + t` with `c` the centroid
//! of the shape's surfel centres, so the identity is the t = 0 pose. The shape keeps two point sets:
//! every surfel centre (for silhouettes) and a thinned, floater-free set of *solid* points (for
//! contacts with the table and the other objects; see [`Shape::new`]).

use std::collections::HashMap;

use glam::{DMat3, DQuat, DVec3, Quat};
use trand_core::Surfels;

use crate::surfel_ops::turn;

/// Edge of the voxels that thin the solid points (m): one point per occupied voxel.
pub const SOLID_VOXEL_M: f64 = 0.004;
/// A voxel counts as solid when it and its 26 neighbours hold at least this many opaque surfels:
/// a floater (an isolated surfel) never makes the object rest higher than its surface.
pub const SOLID_MIN_SURFELS: usize = 6;
/// Surfels with opacity below sigmoid(−3) ≈ 5 % are neither solid nor drawn in splat silhouettes.
pub const MIN_OPACITY_LOGIT: f32 = -3.0;

/// `p ↦ R (p − c) + c + t`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    pub rot: DQuat,
    pub t: DVec3,
}

impl Pose {
    pub const IDENTITY: Pose = Pose {
        rot: DQuat::IDENTITY,
        t: DVec3::ZERO,
    };

    /// Where the pose takes the shape point `p` (`c` the shape's centroid).
    pub fn apply(&self, c: DVec3, p: DVec3) -> DVec3 {
        self.rot * (p - c) + c + self.t
    }

    /// This pose followed by the rotation `q` about the world point `pivot`: from
    /// `q (R (p − c) + c + t − pivot) + pivot` the new `R' = q R`, `t' = q (c + t − pivot) + pivot − c`.
    pub fn turned(&self, c: DVec3, q: DQuat, pivot: DVec3) -> Pose {
        Pose {
            rot: (q * self.rot).normalize(),
            t: q * (c + self.t - pivot) + pivot - c,
        }
    }

    /// This pose followed by the translation `d`.
    pub fn shifted(&self, d: DVec3) -> Pose {
        Pose {
            rot: self.rot,
            t: self.t + d,
        }
    }

    /// The surfels `s` (a shape with centroid `c`) moved by this pose: centres moved, orientations
    /// turned by `R`.
    pub fn place(&self, s: &Surfels, c: DVec3) -> Surfels {
        let mut out = s.clone();
        let r = self.rot;
        let rf = Quat::from_xyzw(r.x as f32, r.y as f32, r.z as f32, r.w as f32);
        for m in out.means.iter_mut() {
            let q = self.apply(c, DVec3::new(m[0] as f64, m[1] as f64, m[2] as f64));
            *m = [q.x as f32, q.y as f32, q.z as f32];
        }
        for q in &mut out.quats {
            *q = turn(rf, *q);
        }
        out
    }

    /// Angle (degrees) between the world vertical and where this pose turns the shape's t = 0
    /// vertical: the tilt relative to t = 0.
    pub fn tilt_deg(&self) -> f64 {
        (self.rot * DVec3::Z).z.clamp(-1.0, 1.0).acos().to_degrees()
    }
}

/// One object's undeformed shape.
#[derive(Clone, Debug)]
pub struct Shape {
    /// `c`: mean of the surfel centres.
    pub centroid: DVec3,
    /// Solid points (t = 0 positions).
    pub solid: Vec<DVec3>,
    /// Centre of mass: mean of the solid points (a thin-walled vessel's mass lies on its surface).
    pub com: DVec3,
    /// RMS distance of the solid points from the centre of mass: the length unit of the scores.
    pub size: f64,
    /// Least height of the centre of mass above the lowest solid point over [`ENERGY_DIRECTIONS`]
    /// orientations: how low the object can lie (`R` for a cylinder of radius `R` lying on its side).
    pub lowest_com: f64,
}

/// Orientations sampled for [`Shape::lowest_com`].
pub const ENERGY_DIRECTIONS: usize = 200;

impl Shape {
    /// The shape of `s` (the object's surfels only; `body` says which may be solid, see
    /// [`mod@super::body`]). Solid points: opaque body surfels binned into [`SOLID_VOXEL_M`] voxels; each
    /// voxel with at least [`SOLID_MIN_SURFELS`] surfels in its 3×3×3 neighbourhood gives the mean of
    /// its own surfels. `None` when no voxel is solid.
    pub fn new(s: &Surfels, body: &[bool]) -> Option<Shape> {
        let v = |a: [f32; 3]| DVec3::new(a[0] as f64, a[1] as f64, a[2] as f64);
        if s.is_empty() {
            return None;
        }
        let centroid = s.means.iter().map(|&m| v(m)).sum::<DVec3>() / s.len() as f64;
        let key = |p: DVec3| (p / SOLID_VOXEL_M).floor().as_ivec3().to_array();
        let mut cells: HashMap<[i32; 3], (DVec3, usize)> = HashMap::new();
        for ((m, &o), &b) in s.means.iter().zip(&s.opacity_logits).zip(body) {
            if b && o > MIN_OPACITY_LOGIT {
                let e = cells.entry(key(v(*m))).or_insert((DVec3::ZERO, 0));
                e.0 += v(*m);
                e.1 += 1;
            }
        }
        let mut keys: Vec<&[i32; 3]> = cells.keys().collect();
        keys.sort_unstable();
        let solid: Vec<DVec3> = keys
            .into_iter()
            .filter(|k| {
                let mut n = 0;
                for d in 0..27 {
                    let o = [d % 3 - 1, d / 3 % 3 - 1, d / 9 - 1];
                    n += cells
                        .get(&[k[0] + o[0], k[1] + o[1], k[2] + o[2]])
                        .map_or(0, |c| c.1);
                }
                n >= SOLID_MIN_SURFELS
            })
            .map(|k| cells[k].0 / cells[k].1 as f64)
            .collect();
        if solid.is_empty() {
            return None;
        }
        let com = solid.iter().sum::<DVec3>() / solid.len() as f64;
        let size = (solid
            .iter()
            .map(|p| (*p - com).length_squared())
            .sum::<f64>()
            / solid.len() as f64)
            .sqrt()
            .max(1e-3);
        let lowest_com = sphere(ENERGY_DIRECTIONS)
            .into_iter()
            .map(|up| {
                let r = DQuat::from_rotation_arc(up, DVec3::Z);
                let c = (r * com).z;
                solid
                    .iter()
                    .map(|&p| c - (r * p).z)
                    .fold(f64::NEG_INFINITY, f64::max)
            })
            .fold(f64::INFINITY, f64::min);
        Some(Shape {
            centroid,
            solid,
            com,
            size,
            lowest_com,
        })
    }

    /// Mean distance between the solid points under two poses (m).
    pub fn distance(&self, a: &Pose, b: &Pose) -> f64 {
        self.solid
            .iter()
            .map(|&p| (a.apply(self.centroid, p) - b.apply(self.centroid, p)).length())
            .sum::<f64>()
            / self.solid.len() as f64
    }

    /// Potential energy above the lowest the object can lie, in object sizes: `(z_com − ground −
    /// lowest_com) / size` (0 at best).
    pub fn energy(&self, pose: &Pose, ground: f64) -> f64 {
        ((self.com_at(pose).z - ground - self.lowest_com) / self.size).max(0.0)
    }

    /// World position of the centre of mass under `pose`.
    pub fn com_at(&self, pose: &Pose) -> DVec3 {
        pose.apply(self.centroid, self.com)
    }
}

/// `n` near-uniform directions on the unit sphere (Fibonacci lattice), starting at the north pole.
pub fn sphere(n: usize) -> Vec<DVec3> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let z = if n == 1 {
                1.0
            } else {
                1.0 - 2.0 * i as f64 / (n - 1) as f64
            };
            let r = (1.0 - z * z).max(0.0).sqrt();
            let a = golden * i as f64;
            DVec3::new(r * a.cos(), r * a.sin(), z)
        })
        .collect()
}

/// The rotation that turns the shape direction `up` to the world vertical and then by `yaw` about it.
pub fn orientation(up: DVec3, yaw: f64) -> DQuat {
    DQuat::from_rotation_z(yaw) * DQuat::from_rotation_arc(up.normalize(), DVec3::Z)
}

/// The pose that moves the points `from` onto `to` best in the least-squares sense (Kabsch): `R` is
/// the polar rotation of `Σ (q − q̄)(p − p̄)ᵀ`, and `t` puts `p̄` on `q̄`; expressed about `c`.
pub fn rigid_fit(from: &[DVec3], to: &[DVec3], c: DVec3) -> Pose {
    let n = from.len().max(1) as f64;
    let pbar = from.iter().sum::<DVec3>() / n;
    let qbar = to.iter().sum::<DVec3>() / n;
    let mut m = DMat3::ZERO;
    for (p, q) in from.iter().zip(to) {
        let (p, q) = (*p - pbar, *q - qbar);
        m += DMat3::from_cols(q * p.x, q * p.y, q * p.z);
    }
    let rot = trand_physics::mpm::polar_rotation(m, DQuat::IDENTITY);
    // R (p̄ − c) + c + t = q̄.
    Pose {
        rot,
        t: qbar - rot * (pbar - c) - c,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn turning_a_pose_about_a_pivot_keeps_the_pivot_and_composes_the_rotations() {
        let c = DVec3::new(0.1, -0.2, 0.05);
        let pose = Pose {
            rot: DQuat::from_rotation_x(0.4),
            t: DVec3::new(0.01, 0.02, 0.03),
        };
        let pivot = DVec3::new(0.0, 0.1, 0.0);
        let q = DQuat::from_rotation_y(-0.7);
        let turned = pose.turned(c, q, pivot);
        for p in [DVec3::ZERO, DVec3::new(0.3, 0.1, -0.2), c] {
            let want = q * (pose.apply(c, p) - pivot) + pivot;
            assert!((turned.apply(c, p) - want).length() < 1e-12);
        }
    }

    #[test]
    fn rigid_fit_recovers_the_pose_that_moved_the_points() {
        let from: Vec<DVec3> = sphere(40).iter().map(|d| *d * 0.05 + DVec3::X).collect();
        let c = DVec3::new(1.0, 0.0, 0.01);
        let truth = Pose {
            rot: DQuat::from_axis_angle(DVec3::new(1.0, 2.0, 0.5).normalize(), 1.1),
            t: DVec3::new(-0.02, 0.04, 0.01),
        };
        let to: Vec<DVec3> = from.iter().map(|&p| truth.apply(c, p)).collect();
        let fit = rigid_fit(&from, &to, c);
        for p in &from {
            let e = (fit.apply(c, *p) - truth.apply(c, *p)).length();
            assert!(e < 2e-5, "{e} m off");
        }
    }

    #[test]
    fn sphere_directions_cover_both_poles_and_are_unit() {
        let d = sphere(50);
        assert!(d.iter().all(|v| (v.length() - 1.0).abs() < 1e-12));
        assert!(d[0].z > 0.999 && d[49].z < -0.999);
        // Every direction of a coarse probe set has a sample within 25°.
        for probe in sphere(500) {
            let best = d.iter().map(|v| v.dot(probe)).fold(-1.0, f64::max);
            assert!(best > 25f64.to_radians().cos(), "{probe:?}: {best}");
        }
    }
}
