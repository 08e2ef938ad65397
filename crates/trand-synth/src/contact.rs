//! How close two placed objects are: the exact gap between their render meshes and the signed
//! distance between their collision hulls.
//!
//! The physics sees only the convex hulls; what the cameras see is the render mesh. A leaning
//! glass can rest on its hull at a point where the hull spans empty space (around a wine glass's
//! stem, over a bottle's concave shoulder), and the rendered glass would then float. The mesh gap
//! is what tells the two apart, so every contact relation is verified on it.
//!
//! * [`mesh_gap_m`]: the smallest distance between two triangle meshes, as the minimum of
//!   vertex-to-triangle distances in both directions (exact for touching or face-near meshes;
//!   an edge crossing an edge is bounded by the adjacent vertices, within a fraction of the
//!   edge length). Only vertices and triangles within the search radius of the other mesh's
//!   bounding box are compared.
//! * [`hull_distance_m`]: signed distance between the two convex hulls (negative: penetration
//!   depth), from parry's GJK/EPA.

use crate::physics::Pose;
use glam::Vec3;
use rapier3d::parry;
use trand_core::Mesh;

/// An axis-aligned box.
#[derive(Clone, Copy, Debug)]
struct Aabb {
    lo: Vec3,
    hi: Vec3,
}

impl Aabb {
    fn of(points: impl IntoIterator<Item = Vec3>) -> Self {
        points.into_iter().fold(
            Aabb {
                lo: Vec3::splat(f32::MAX),
                hi: Vec3::splat(f32::MIN),
            },
            |b, p| Aabb {
                lo: b.lo.min(p),
                hi: b.hi.max(p),
            },
        )
    }

    fn grown(self, by: f32) -> Self {
        Aabb {
            lo: self.lo - Vec3::splat(by),
            hi: self.hi + Vec3::splat(by),
        }
    }

    fn contains(&self, p: Vec3) -> bool {
        p.cmpge(self.lo).all() && p.cmple(self.hi).all()
    }

    fn overlaps(&self, o: &Aabb) -> bool {
        self.lo.cmple(o.hi).all() && o.lo.cmple(self.hi).all()
    }

    /// Distance from `p` to the box (0 inside).
    fn distance(&self, p: Vec3) -> f32 {
        (self.lo - p).max(p - self.hi).max(Vec3::ZERO).length()
    }
}

/// Closest point to `p` on triangle `abc`, by the Voronoi region of `p`: a vertex region
/// (both edge parameters ≤ 0 or ≥ 1), an edge region (the barycentric weight of the opposite
/// vertex ≤ 0 with the edge parameter in (0, 1)), or the face, `a + v·ab + w·ac` with
/// `(v, w) = (vb, vc) / (va + vb + vc)` from the signed sub-triangle areas.
pub fn closest_point_on_triangle(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> Vec3 {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    a + ab * (vb * denom) + ac * (vc * denom)
}

/// A mesh's vertices and triangles in world coordinates.
struct Placed {
    points: Vec<Vec3>,
    triangles: Vec<[Vec3; 3]>,
    bounds: Aabb,
}

impl Placed {
    fn new(mesh: &Mesh, pose: &Pose) -> Self {
        let points: Vec<Vec3> = mesh.points().map(|p| pose.apply(p)).collect();
        let triangles = mesh
            .faces
            .iter()
            .map(|t| t.map(|i| points[i as usize]))
            .collect();
        let bounds = Aabb::of(points.iter().copied());
        Self {
            points,
            triangles,
            bounds,
        }
    }
}

/// Smallest distance from the vertices of `from` to the triangles of `to`, at most `search`.
fn one_way_gap(from: &Placed, to: &Placed, search: f32) -> f32 {
    let reach = from.bounds.grown(search);
    let near: Vec<(&[Vec3; 3], Aabb)> = to
        .triangles
        .iter()
        .map(|t| (t, Aabb::of(t.iter().copied())))
        .filter(|(_, b)| b.overlaps(&reach))
        .collect();
    let zone = to.bounds.grown(search);
    let mut best = search;
    for p in from.points.iter().filter(|p| zone.contains(**p)) {
        for (t, b) in &near {
            if b.distance(*p) >= best {
                continue;
            }
            let q = closest_point_on_triangle(*p, t[0], t[1], t[2]);
            best = best.min(q.distance(*p));
        }
    }
    best
}

/// Gap (m) between two meshes at their poses (see the module docs); `search_m` when they are
/// at least that far apart.
pub fn mesh_gap_m(a: &Mesh, pose_a: &Pose, b: &Mesh, pose_b: &Pose, search_m: f32) -> f32 {
    let (pa, pb) = (Placed::new(a, pose_a), Placed::new(b, pose_b));
    one_way_gap(&pa, &pb, search_m).min(one_way_gap(&pb, &pa, search_m))
}

/// A convex collision shape for [`hull_distance_m`].
pub struct Hull(parry::shape::ConvexPolyhedron);

impl Hull {
    /// The convex hull of `points` (model frame); `None` when they span no volume.
    pub fn new(points: &[Vec3]) -> Option<Self> {
        parry::shape::ConvexPolyhedron::from_convex_hull(points).map(Hull)
    }
}

/// Largest separation for which [`hull_distance_m`] is exact (m); farther apart it reports this.
pub const HULL_DISTANCE_REACH_M: f32 = 1.0;

/// Signed distance (m) between two hulls at their poses: the gap when apart, minus the
/// penetration depth when they overlap.
pub fn hull_distance_m(a: &Hull, pose_a: &Pose, b: &Hull, pose_b: &Pose) -> f32 {
    let iso = |p: &Pose| rapier3d::math::Pose::from_parts(p.translation, p.rotation);
    parry::query::contact(
        &iso(pose_a),
        &a.0,
        &iso(pose_b),
        &b.0,
        HULL_DISTANCE_REACH_M,
    )
    .ok()
    .flatten()
    .map_or(HULL_DISTANCE_REACH_M, |c| c.dist)
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{Quat, Vec2};

    #[test]
    fn closest_point_on_a_triangle_is_the_foot_of_the_perpendicular_or_the_nearest_feature() {
        let (a, b, c) = (Vec3::ZERO, Vec3::X, Vec3::Y);
        let cases = [
            (Vec3::new(0.2, 0.2, 1.0), Vec3::new(0.2, 0.2, 0.0)),
            (Vec3::new(-1.0, -1.0, 0.5), a),
            (Vec3::new(2.0, -0.5, 0.0), b),
            (Vec3::new(-0.3, 3.0, 0.0), c),
            (Vec3::new(0.5, -2.0, 0.0), Vec3::new(0.5, 0.0, 0.0)),
            (Vec3::new(1.0, 1.0, 0.0), Vec3::new(0.5, 0.5, 0.0)),
            (Vec3::new(-2.0, 0.4, 0.0), Vec3::new(0.0, 0.4, 0.0)),
        ];
        for (p, want) in cases {
            let got = closest_point_on_triangle(p, a, b, c);
            assert!((got - want).length() < 1e-6, "{p} -> {got}, want {want}");
        }
    }

    fn cylinder(r: f32, h: f32) -> Mesh {
        let profile = [
            Vec2::new(0.0, 0.0),
            Vec2::new(r, 0.0),
            Vec2::new(r, h),
            Vec2::new(0.0, h),
        ];
        crate::shapes::lathe(&profile, 96)
    }

    #[test]
    fn gap_between_two_cylinders_side_by_side_is_their_centre_distance_minus_the_radii() {
        let m = cylinder(0.03, 0.08);
        let at = |x: f32| Pose {
            rotation: Quat::IDENTITY,
            translation: Vec3::new(x, 0.0, 0.0),
        };
        // Facing vertices lie on the circle at angle 0 and π (96 slices), so the gap is exact.
        let gap = mesh_gap_m(&m, &at(0.0), &m, &at(0.0625), 0.01);
        assert!((gap - 0.0025).abs() < 1e-5, "gap {gap}");
        assert_eq!(mesh_gap_m(&m, &at(0.0), &m, &at(0.2), 0.01), 0.01);
        let points: Vec<Vec3> = m.points().collect();
        let (ha, hb) = (Hull::new(&points).unwrap(), Hull::new(&points).unwrap());
        let d = hull_distance_m(&ha, &at(0.0), &hb, &at(0.0625));
        assert!((d - 0.0025).abs() < 1e-4, "hull distance {d}");
        let d = hull_distance_m(&ha, &at(0.0), &hb, &at(0.055));
        assert!((d + 0.005).abs() < 1e-4, "penetration {d}");
    }
}
