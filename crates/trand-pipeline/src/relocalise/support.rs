//! Physical plausibility of a pose: what the object rests on, whether it floats or sinks into
//! something, whether it would tip over; and a quasi-static settling that turns any pose into one at
//! rest.
//!
//! # The support
//! The table plane (the ground height) and the other objects, as two grids built from their solid
//! points ([`super::pose::Shape`]): a heightfield of their top surfaces ([`CELL_M`] cells, closed
//! morphologically — the 3×3 maximum, then the 3×3 minimum — to fill the gaps between surfels
//! without widening the objects), and a 3D occupancy grid of the same cells dilated by one cell, for
//! contacts from the side. Seen from above the others are solid columns: a point of the object below
//! another object's top surface in its column is inside it. This treats the others as convex from
//! above (a glass cannot slide under another one's overhang), which is what lets resting be decided
//! by a vertical drop.
//!
//! # Resting
//! * *Clearance* of a pose: the least height of the object's solid points above the support
//!   (`z − top(x, y)`); positive floats, negative sinks into the table or another object. Dropping a
//!   pose subtracts it: the lowest point then lies on whatever is below it.
//! * *Contacts* of a dropped pose: solid points within [`CONTACT_M`] of the support below them; and
//!   *side contacts*, solid points in an occupied cell of another object (leaning against its side),
//!   each with the side's outward normal (from the occupied towards the free neighbour cells).
//! * *Overhang*: the horizontal distance of the centre of mass outside the convex hull of the
//!   contacts below. Where it is outside, the side contacts that face the way it would tip (within
//!   [`SIDE_FACING_COS`]) join the hull: a side can push the object back, not hold it from tipping
//!   along it. Zero overhang means the contacts can hold the object; otherwise gravity tips it over
//!   the nearest hull edge.
//!
//! # Settling ([`Support::settle`])
//! Quasi-static toppling: drop; while the centre of mass overhangs (contacts within
//! [`SETTLE_CONTACT_M`]), turn the object about the hull feature nearest to it (the edge through two
//! contacts, or the horizontal axis through a single contact at right angles to the overhang), in the
//! sense that lowers the centre of mass, by [`SETTLE_STEP_DEG`], and drop again. A step after which
//! the object would have to *rise* by more than [`BLOCK_M`] ran into something: it is halved
//! instead, down to [`SETTLE_MIN_STEP_DEG`], which leaves the object touching what stopped it, a new
//! contact for the next round. A glass tilted beyond its base thus falls onto its side, an upright
//! one tilted a little stands back up, one falling towards a neighbour comes to lean on it.

use glam::{DQuat, DVec2, DVec3};

use super::body::{convex_hull, inside_convex};
use super::pose::{Pose, Shape};

/// Heightfield and occupancy cell edge (m).
pub const CELL_M: f64 = 0.004;
/// A solid point this close to the support below it touches it (m).
pub const CONTACT_M: f64 = 0.003;
/// Settling takes contacts this close (m): a looser tolerance would leave a glass tilted on its base
/// by up to `asin(tolerance / base diameter)`.
pub const SETTLE_CONTACT_M: f64 = 0.001;
/// A side contact holds the object only against tipping towards it: where the overhang's direction
/// is within 60° of the side's inward normal (`cos 60° = ½`); a glass tipping along a wall falls.
pub const SIDE_FACING_COS: f64 = 0.5;
/// A pose whose centre of mass overhangs its contacts by less than this is at rest (m).
pub const STABLE_M: f64 = 0.001;
/// A settling step that would lift the object by more than this ran into something (m).
pub const BLOCK_M: f64 = 0.001;
pub const SETTLE_STEP_DEG: f64 = 6.0;
pub const SETTLE_MIN_STEP_DEG: f64 = 0.4;
/// Settling gives up after this many steps (an object rolling on a curved side never stops).
pub const SETTLE_MAX_STEPS: usize = 120;

/// How a pose rests on the support.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Rest {
    /// Least height of the solid points above the support (m): > 0 floats, < 0 sinks in.
    pub clearance_m: f64,
    /// Horizontal distance of the centre of mass outside the hull of the contacts once dropped (m).
    pub overhang_m: f64,
    /// Whether any contact is on another object rather than the table.
    pub on_object: bool,
}

impl Rest {
    /// Implausibility in object sizes: `(max(|clearance| − CONTACT_M, 0) + overhang) / size`.
    pub fn implausibility(&self, size: f64) -> f64 {
        ((self.clearance_m.abs() - CONTACT_M).max(0.0) + self.overhang_m) / size
    }
}

/// The table and the other objects.
pub struct Support {
    ground: f64,
    origin: DVec3,
    dims: [usize; 3],
    /// Top of the other objects per `(x, y)` cell (`NEG_INFINITY`: none).
    top: Vec<f64>,
    /// Occupied `(x, y, z)` cells of the other objects.
    occupied: Vec<bool>,
}

/// Nearest feature of the contact hull to the centre of mass.
enum Pivot {
    Point(DVec3),
    Edge(DVec3, DVec3),
}

impl Support {
    /// The support made of the table at `ground` and the points `others` (solid points of the other
    /// objects, world positions).
    pub fn new(ground: f64, others: &[DVec3]) -> Support {
        if others.is_empty() {
            return Support {
                ground,
                origin: DVec3::ZERO,
                dims: [0; 3],
                top: Vec::new(),
                occupied: Vec::new(),
            };
        }
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for p in others {
            lo = lo.min(*p);
            hi = hi.max(*p);
        }
        let origin = lo - DVec3::splat(2.0 * CELL_M);
        let n = ((hi - origin) / CELL_M).ceil().as_uvec3() + 3;
        let dims = [n.x as usize, n.y as usize, n.z as usize];
        let mut raw = vec![f64::NEG_INFINITY; dims[0] * dims[1]];
        let mut occupied = vec![false; dims[0] * dims[1] * dims[2]];
        for p in others {
            let c = ((*p - origin) / CELL_M).floor().as_uvec3();
            let (x, y, z) = (c.x as usize, c.y as usize, c.z as usize);
            raw[y * dims[0] + x] = raw[y * dims[0] + x].max(p.z);
            for dy in y - 1..=y + 1 {
                for dx in x - 1..=x + 1 {
                    for dz in z - 1..=z + 1 {
                        occupied[(dz * dims[1] + dy) * dims[0] + dx] = true;
                    }
                }
            }
        }
        // Closing: the 3×3 maximum, then the 3×3 minimum of that.
        let window = |f: &[f64], x: usize, y: usize, pick: fn(f64, f64) -> f64, empty: f64| {
            let mut v: Option<f64> = None;
            for dy in [y.wrapping_sub(1), y, y + 1] {
                for dx in [x.wrapping_sub(1), x, x + 1] {
                    let w = if dx < dims[0] && dy < dims[1] {
                        f[dy * dims[0] + dx]
                    } else {
                        empty
                    };
                    v = Some(v.map_or(w, |a| pick(a, w)));
                }
            }
            v.unwrap_or(empty)
        };
        let grid = |f: &[f64], pick: fn(f64, f64) -> f64| -> Vec<f64> {
            (0..dims[0] * dims[1])
                .map(|i| window(f, i % dims[0], i / dims[0], pick, f64::NEG_INFINITY))
                .collect()
        };
        let top = grid(&grid(&raw, f64::max), f64::min);
        Support {
            ground,
            origin,
            dims,
            top,
            occupied,
        }
    }

    /// The table height.
    pub fn ground(&self) -> f64 {
        self.ground
    }

    /// Index of the `(x, y)` column of `p` in the heightfield.
    fn column(&self, p: DVec3) -> Option<usize> {
        let c = ((p - self.origin) / CELL_M).floor();
        (c.x >= 0.0 && c.y >= 0.0 && (c.x as usize) < self.dims[0] && (c.y as usize) < self.dims[1])
            .then(|| c.y as usize * self.dims[0] + c.x as usize)
    }

    /// Height of the support below `p`, and whether it is another object.
    fn below(&self, p: DVec3) -> (f64, bool) {
        match self.column(p).map(|i| self.top[i]) {
            Some(h) if h > self.ground => (h, true),
            _ => (self.ground, false),
        }
    }

    /// Whether `p` lies in a cell occupied by another object.
    fn touches_side(&self, p: DVec3) -> bool {
        let z = ((p.z - self.origin.z) / CELL_M).floor();
        self.column(p).is_some_and(|i| {
            z >= 0.0
                && (z as usize) < self.dims[2]
                && self.occupied[z as usize * self.top.len() + i]
        })
    }

    /// Least clearance of the shape's solid points under `pose`.
    pub fn clearance(&self, shape: &Shape, pose: &Pose) -> f64 {
        shape
            .solid
            .iter()
            .map(|&p| {
                let w = pose.apply(shape.centroid, p);
                w.z - self.below(w).0
            })
            .fold(f64::INFINITY, f64::min)
    }

    /// `pose` lowered (or raised) until its lowest point lies on the support.
    pub fn drop(&self, shape: &Shape, pose: &Pose) -> Pose {
        pose.shifted(DVec3::new(0.0, 0.0, -self.clearance(shape, pose)))
    }

    /// How `pose` rests (the overhang is that of the dropped pose).
    pub fn rest(&self, shape: &Shape, pose: &Pose) -> Rest {
        let clearance_m = self.clearance(shape, pose);
        let dropped = pose.shifted(DVec3::new(0.0, 0.0, -clearance_m));
        let (overhang_m, _, on_object) = self.overhang(shape, &dropped, CONTACT_M);
        Rest {
            clearance_m,
            overhang_m,
            on_object,
        }
    }

    /// Overhang of a dropped pose, the hull feature nearest to the centre of mass, and whether any
    /// contact is on another object (module doc: side contacts count where they face the overhang).
    fn overhang(&self, shape: &Shape, pose: &Pose, contact: f64) -> (f64, Option<Pivot>, bool) {
        let mut below: Vec<DVec3> = Vec::new();
        let mut side: Vec<(DVec3, DVec2)> = Vec::new();
        let mut on_object = false;
        for &p in &shape.solid {
            let w = pose.apply(shape.centroid, p);
            let (h, other) = self.below(w);
            if w.z - h < contact {
                below.push(w);
                on_object |= other;
            } else if let Some(n) = self.side_normal(w) {
                side.push((w, n));
            }
        }
        let com = shape.com_at(pose).truncate();
        let Some((d, pivot, nearest)) = nearest_on_hull(&below, com) else {
            return (f64::INFINITY, None, on_object);
        };
        let Some(out) = (com - nearest).try_normalize().filter(|_| d > 0.0) else {
            return (d, Some(pivot), on_object);
        };
        let facing: Vec<DVec3> = side
            .iter()
            .filter(|(_, n)| n.dot(out) < -SIDE_FACING_COS)
            .map(|(w, _)| *w)
            .collect();
        if facing.is_empty() {
            return (d, Some(pivot), on_object);
        }
        below.extend(facing);
        let (d, pivot, _) = nearest_on_hull(&below, com).expect("not empty");
        (d, Some(pivot), true)
    }

    /// Where `p` lies in a cell occupied by another object, the horizontal direction from its
    /// occupied neighbour cells to its free ones (the outward normal of that object's side there).
    fn side_normal(&self, p: DVec3) -> Option<DVec2> {
        if !self.touches_side(p) {
            return None;
        }
        let mut n = DVec2::ZERO;
        for (dx, dy) in [
            (1, 0),
            (-1, 0),
            (0, 1),
            (0, -1),
            (1, 1),
            (1, -1),
            (-1, 1),
            (-1, -1),
        ] {
            let d = DVec2::new(dx as f64, dy as f64);
            let q = p + (d * CELL_M).extend(0.0);
            if !self.touches_side(q) {
                n += d.normalize();
            }
        }
        n.try_normalize()
    }

    /// The pose at rest reached from `pose` by quasi-static toppling (module doc).
    pub fn settle(&self, shape: &Shape, pose: &Pose) -> Pose {
        let mut pose = self.drop(shape, pose);
        let mut step = SETTLE_STEP_DEG.to_radians();
        for _ in 0..SETTLE_MAX_STEPS {
            let (d, pivot, _) = self.overhang(shape, &pose, SETTLE_CONTACT_M);
            let Some(pivot) = pivot.filter(|_| d > STABLE_M) else {
                break;
            };
            let com = shape.com_at(&pose);
            let (at, axis) = match pivot {
                Pivot::Point(p) => {
                    let out = (com - p).truncate();
                    (p, DVec3::new(-out.y, out.x, 0.0))
                }
                Pivot::Edge(a, b) => (a, b - a),
            };
            let Some(mut axis) = axis.try_normalize() else {
                break;
            };
            // The sense that lowers the centre of mass: (axis × (com − at)).z < 0.
            let descent = axis.cross(com - at).z;
            if descent.abs() < 1e-9 {
                break;
            }
            if descent > 0.0 {
                axis = -axis;
            }
            let turned = pose.turned(shape.centroid, DQuat::from_axis_angle(axis, step), at);
            let c = self.clearance(shape, &turned);
            if c < -BLOCK_M {
                step *= 0.5;
                if step < SETTLE_MIN_STEP_DEG.to_radians() {
                    break;
                }
                continue;
            }
            pose = turned.shifted(DVec3::new(0.0, 0.0, -c));
        }
        pose
    }
}

/// Distance of `q` outside the convex hull of the `points`' horizontal positions (0 inside), the
/// hull's nearest feature (as 3D points) and the nearest point of the hull. `None` without points.
fn nearest_on_hull(points: &[DVec3], q: DVec2) -> Option<(f64, Pivot, DVec2)> {
    let flat: Vec<DVec2> = points.iter().map(|p| p.truncate()).collect();
    let hull: Vec<DVec3> = convex_hull(&flat).into_iter().map(|i| points[i]).collect();
    match hull.len() {
        0 => None,
        1 => Some((
            (hull[0].truncate() - q).length(),
            Pivot::Point(hull[0]),
            hull[0].truncate(),
        )),
        n => {
            let inside = n >= 3 && {
                let polygon: Vec<DVec2> = hull.iter().map(|p| p.truncate()).collect();
                inside_convex(&polygon, q, 0.0)
            };
            let mut best = (f64::INFINITY, Pivot::Point(hull[0]), hull[0].truncate());
            let edges = if n == 2 { 1 } else { n };
            for i in 0..edges {
                let (a3, b3) = (hull[i], hull[(i + 1) % n]);
                let (a, b) = (a3.truncate(), b3.truncate());
                let s = ((q - a).dot(b - a) / (b - a).length_squared().max(1e-18)).clamp(0.0, 1.0);
                let d = (a + s * (b - a) - q).length();
                if d < best.0 {
                    let feature = if s <= 0.0 {
                        Pivot::Point(a3)
                    } else if s >= 1.0 {
                        Pivot::Point(b3)
                    } else {
                        Pivot::Edge(a3, b3)
                    };
                    best = (d, feature, a + s * (b - a));
                }
            }
            if inside {
                best.0 = 0.0;
            }
            Some(best)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_scene::{RADIUS, block, cylinder};

    fn glass() -> Shape {
        let s = cylinder(0.0, 0.0, 0);
        Shape::new(&s, &vec![true; s.len()]).unwrap()
    }

    fn solid_points(shape: &Shape, pose: &Pose) -> Vec<DVec3> {
        shape
            .solid
            .iter()
            .map(|&p| pose.apply(shape.centroid, p))
            .collect()
    }

    /// The upright glass tipped by `deg` towards +x about its base edge (x = R).
    fn tilted(shape: &Shape, deg: f64) -> Pose {
        Pose::IDENTITY.turned(
            shape.centroid,
            DQuat::from_rotation_y(deg.to_radians()),
            DVec3::new(RADIUS as f64, 0.0, 0.0),
        )
    }

    fn lowest(shape: &Shape, pose: &Pose) -> f64 {
        solid_points(shape, pose)
            .iter()
            .map(|p| p.z)
            .fold(f64::INFINITY, f64::min)
    }

    /// The block of the leaning tests: 4 cm thick, from x = 10 cm, 12 cm tall.
    fn wall() -> Support {
        let b = block(0.10, -0.05, 0.14, 0.05, 0.12, 1);
        let shape = Shape::new(&b, &vec![true; b.len()]).unwrap();
        Support::new(0.0, &shape.solid)
    }

    #[test]
    fn a_floating_pose_is_dropped_onto_the_table_and_a_sunk_one_lifted() {
        let shape = glass();
        let table = Support::new(0.0, &[]);
        let z0 = lowest(&shape, &Pose::IDENTITY);
        for dz in [0.03, -0.02] {
            let pose = Pose::IDENTITY.shifted(DVec3::new(0.0, 0.0, dz));
            let rest = table.rest(&shape, &pose);
            assert!((rest.clearance_m - z0 - dz).abs() < 1e-9, "{rest:?}");
            assert!(rest.implausibility(shape.size) > 0.3, "{rest:?}");
            let dropped = table.drop(&shape, &pose);
            let z = lowest(&shape, &dropped);
            assert!(z.abs() < 1e-9, "lowest point at {z}");
            assert_eq!(table.rest(&shape, &dropped).implausibility(shape.size), 0.0);
        }
    }

    #[test]
    fn a_glass_tilted_a_little_stands_back_up() {
        let shape = glass();
        let table = Support::new(0.0, &[]);
        // Tipping angle of the wall-only glass: atan(R / (H/2)) ≈ 31°.
        let pose = table.settle(&shape, &tilted(&shape, 20.0));
        assert!(pose.tilt_deg() < 1.5, "tilt {}", pose.tilt_deg());
        let rest = table.rest(&shape, &pose);
        assert!(
            rest.clearance_m.abs() < 1e-6 && rest.overhang_m == 0.0,
            "{rest:?}"
        );
    }

    #[test]
    fn a_glass_tilted_beyond_its_base_falls_onto_its_side() {
        let shape = glass();
        let table = Support::new(0.0, &[]);
        let pose = table.settle(&shape, &tilted(&shape, 40.0));
        assert!(
            (pose.tilt_deg() - 90.0).abs() < 4.0,
            "tilt {}",
            pose.tilt_deg()
        );
        let com = shape.com_at(&pose);
        assert!(
            (com.z - RADIUS as f64).abs() < 3e-3,
            "centre of mass at {com}"
        );
        assert_eq!(table.rest(&shape, &pose).overhang_m, 0.0);
    }

    #[test]
    fn a_glass_falling_towards_a_neighbour_comes_to_lean_on_it() {
        let shape = glass();
        let support = wall();
        // Tipped towards +x beyond its tipping angle (31°): it would lie flat, but the block is in the
        // way; turning about its base edge (x = 3 cm) its top rim reaches x = 10 cm at
        // asin(0.07 / H) ≈ 44°.
        let pose = support.settle(&shape, &tilted(&shape, 35.0));
        let tilt = pose.tilt_deg();
        assert!((38.0..50.0).contains(&tilt), "tilt {tilt}");
        let rest = support.rest(&shape, &pose);
        assert!(rest.on_object && rest.overhang_m == 0.0, "{rest:?}");
        assert!(rest.clearance_m.abs() < BLOCK_M + 1e-6, "{rest:?}");
        let deepest = solid_points(&shape, &pose)
            .iter()
            .filter(|p| p.z < 0.12)
            .map(|p| p.x)
            .fold(f64::NEG_INFINITY, f64::max);
        assert!(
            deepest < 0.10,
            "a point at x = {deepest} is inside the block"
        );
    }

    #[test]
    fn a_glass_tipping_along_a_neighbours_side_is_not_held_by_it() {
        let shape = glass();
        let support = wall();
        // Upright 2 mm from the block's face, tipped towards +y (along the face) past its tipping
        // angle: the face cannot push it back, it falls onto its side.
        let x = 0.10 - RADIUS as f64 - 0.002;
        let start = Pose::IDENTITY.shifted(DVec3::new(x, 0.0, 0.0)).turned(
            shape.centroid,
            DQuat::from_rotation_x(-40f64.to_radians()),
            DVec3::new(x, RADIUS as f64, 0.0),
        );
        let pose = support.settle(&shape, &start);
        assert!(
            (pose.tilt_deg() - 90.0).abs() < 4.0,
            "tilt {}",
            pose.tilt_deg()
        );
    }

    #[test]
    fn a_pose_inside_another_object_is_implausible_and_drops_onto_it() {
        let shape = glass();
        let support = wall();
        let inside = Pose::IDENTITY.shifted(DVec3::new(0.12, 0.0, 0.0));
        let rest = support.rest(&shape, &inside);
        assert!(rest.clearance_m < -0.1, "{rest:?}");
        assert!(rest.implausibility(shape.size) > 1.0, "{rest:?}");
        let dropped = support.drop(&shape, &inside);
        let z = lowest(&shape, &dropped);
        assert!((z - 0.12).abs() < 2e-3, "lowest point at {z}");
        assert!(support.rest(&shape, &dropped).on_object);
    }
}
