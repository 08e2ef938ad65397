//! Which surfels of an object belong to its body, for resting it on something.
//!
//! Where one object stood on another at t = 0, the reconstruction cannot tell where the upper glass
//! ends and the lower begins: the upper one's surfels reach down into the lower one's space (on the
//! Blender sequences a dome 10–30 mm deep under the base, a few percent of the surfels). Once the
//! lower object is gone, that dome is the lowest part of the upper one, and resting it on the table
//! leaves the object floating by the dome's depth, or balancing on its tip.
//!
//! The t = 0 scene was at rest and no two bodies overlapped. So a surfel of one object that at t = 0
//! lay inside another object's hull (that other object removed or not) is not part of its body. The
//! hull of an object is a prism: the convex hull of its solid points' horizontal positions shrunk by
//! [`HULL_MARGIN_M`], between their lowest and highest points (solid points are free of floaters). An
//! object with more than half of its solid points inside another's hull is nested in it
//! (a glass inside a bowl): that pair is left alone.
//!
//! An object that *sat on* another at t = 0 ([`sits_on`]: it reaches into the other's hull from
//! above and does not itself come down to the table) had its base on that object's top, so none of
//! its body is lower than that top, inside the hull or beside it. The shrunk hull alone misses what
//! hangs just outside it: a mug that stood off-centre on an upturned tumbler or bowl, its base seen
//! merged with the support, keeps a skirt 1 cm deep on the side that overhangs the hull, and on the
//! table that skirt holds the mug up 10–20° tilted.

use glam::{DVec2, DVec3};

/// The horizontal hull is shrunk by this much (m), so that objects merely touching keep their surfels.
pub const HULL_MARGIN_M: f64 = 0.003;

/// A vertical prism around an object.
#[derive(Clone, Debug)]
pub struct Hull {
    /// Counter-clockwise convex polygon (shrunk).
    polygon: Vec<DVec2>,
    z: (f64, f64),
}

impl Hull {
    /// The hull of an object's solid points (`None` for fewer than three distinct ones).
    pub fn of(solid: &[DVec3]) -> Option<Hull> {
        let pts: Vec<DVec2> = solid.iter().map(|p| p.truncate()).collect();
        let poly: Vec<DVec2> = convex_hull(&pts).into_iter().map(|i| pts[i]).collect();
        if poly.len() < 3 {
            return None;
        }
        let z = solid
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                (lo.min(p.z), hi.max(p.z))
            });
        Some(Hull { polygon: poly, z })
    }

    /// Whether `p` lies inside the prism, at least [`HULL_MARGIN_M`] from its sides.
    pub fn contains(&self, p: DVec3) -> bool {
        if p.z < self.z.0 || p.z > self.z.1 {
            return false;
        }
        inside_convex(&self.polygon, p.truncate(), HULL_MARGIN_M)
    }
}

/// Whether `q` lies inside the counter-clockwise convex `polygon`, at least `margin` from every side
/// (its signed distance to the left of each edge; with a margin of 0 a point on a side is inside).
pub fn inside_convex(polygon: &[DVec2], q: DVec2, margin: f64) -> bool {
    let n = polygon.len();
    (0..n).all(|i| {
        let (a, b) = (polygon[i], polygon[(i + 1) % n]);
        let e = b - a;
        e.perp_dot(q - a) / e.length().max(1e-12) >= margin
    })
}

/// Per point of `points`, whether it belongs to the body: not inside any of `hulls`, unless more than
/// half of `solid` (the same object's solid points) lies inside that hull; and not below the top of
/// an object it sat on ([`sits_on`]; the table at `ground`).
pub fn body(points: &[DVec3], solid: &[DVec3], hulls: &[Hull], ground: f64) -> Vec<bool> {
    let applies: Vec<&Hull> = hulls
        .iter()
        .filter(|h| 2 * solid.iter().filter(|&&p| h.contains(p)).count() <= solid.len())
        .collect();
    let tops: Vec<f64> = applies
        .iter()
        .filter(|h| sits_on(solid, h, ground))
        .map(|h| h.z.1)
        .collect();
    points
        .iter()
        .map(|&p| !applies.iter().any(|h| h.contains(p)) && tops.iter().all(|&top| p.z >= top))
        .collect()
}

/// An object off the table by less than this (m) stands on it.
pub const OFF_TABLE_M: f64 = 0.005;

/// Whether the object of `solid` sat on the hull's object at t = 0 rather than beside it: part of it
/// reaches into the hull from above (its centre higher than the hull's top), and nothing of it
/// outside the hull comes down to the table at `ground` (a glass leaning on a neighbour stands on the
/// table). Then its base lay on that top, a plane, and whatever of it is lower is not body wherever it
/// is. The hull is the other object's horizontal extent shrunk by a margin, so where the two were seen
/// as one, what hangs below that top just outside the hull (a base wider than what held it) escapes
/// [`Hull::contains`]; once the support is gone, that edge alone would hold the object up, tilted.
pub fn sits_on(solid: &[DVec3], h: &Hull, ground: f64) -> bool {
    let n = solid.len().max(1) as f64;
    let centre = solid.iter().map(|p| p.z).sum::<f64>() / n;
    let lowest_beside = solid
        .iter()
        .filter(|&&p| !h.contains(p))
        .map(|p| p.z)
        .fold(f64::INFINITY, f64::min);
    centre > h.z.1 && solid.iter().any(|&p| h.contains(p)) && lowest_beside > ground + OFF_TABLE_M
}

/// Indices of the convex hull of 2D points, counter-clockwise (Andrew's monotone chain); repeated
/// points count once, and fewer than three distinct points are returned as they are.
pub fn convex_hull(points: &[DVec2]) -> Vec<usize> {
    let mut p: Vec<usize> = (0..points.len()).collect();
    p.sort_by(|&a, &b| {
        (points[a].x.total_cmp(&points[b].x)).then(points[a].y.total_cmp(&points[b].y))
    });
    p.dedup_by(|a, b| (points[*a] - points[*b]).length_squared() < 1e-14);
    if p.len() < 3 {
        return p;
    }
    let mut hull: Vec<usize> = Vec::with_capacity(2 * p.len());
    for pass in 0..2 {
        let start = hull.len();
        for k in 0..p.len() {
            let q = if pass == 0 { p[k] } else { p[p.len() - 1 - k] };
            while hull.len() >= start + 2 && {
                let (o, a) = (points[hull[hull.len() - 2]], points[hull[hull.len() - 1]]);
                (a - o).perp_dot(points[q] - o) <= 0.0
            } {
                hull.pop();
            }
            hull.push(q);
        }
        hull.pop();
    }
    hull
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points on a vertical cylinder wall (radius `r`, from `z0` to `z1`) around `(x, y)`.
    fn wall(x: f64, y: f64, r: f64, z0: f64, z1: f64) -> Vec<DVec3> {
        let mut v = Vec::new();
        for i in 0..36 {
            let a = i as f64 * std::f64::consts::TAU / 36.0;
            for j in 0..=10 {
                let z = z0 + (z1 - z0) * j as f64 / 10.0;
                v.push(DVec3::new(x + r * a.cos(), y + r * a.sin(), z));
            }
        }
        v
    }

    #[test]
    fn a_dome_reaching_into_the_object_below_is_not_body_but_the_glass_above_is() {
        // Lower object: radius 4 cm, 0–6 cm. Upper glass from 6.1 cm up, with a dome hanging to 4 cm.
        let lower = Hull::of(&wall(0.0, 0.0, 0.04, 0.0, 0.06)).unwrap();
        let mut glass = wall(0.0, 0.0, 0.03, 0.061, 0.14);
        let dome: Vec<DVec3> = (0..20)
            .map(|i| DVec3::new(0.001 * i as f64, 0.0, 0.04 + 0.00099 * i as f64))
            .collect();
        glass.extend(&dome);
        let b = body(&glass, &glass, &[lower], 0.0);
        let n = glass.len();
        assert!(b[n - 20..].iter().all(|x| !x), "the dome is excluded");
        assert!(b[..n - 20].iter().all(|x| *x), "the glass is kept");
    }

    #[test]
    fn a_glass_that_sat_on_a_narrower_object_loses_what_hangs_below_its_top_beside_it() {
        // Lower object: radius 2 cm, 0–6 cm. Upper glass (radius 3 cm) on it, off-centre by 1 cm,
        // its base seen merged with the lower object's top: a ring hanging 1 cm below that top, part
        // of it outside the lower object's hull.
        let lower = Hull::of(&wall(0.0, 0.0, 0.02, 0.0, 0.06)).unwrap();
        let mut glass = wall(0.01, 0.0, 0.03, 0.061, 0.14);
        let ring: Vec<DVec3> = wall(0.01, 0.0, 0.025, 0.05, 0.059)
            .into_iter()
            .step_by(4)
            .collect();
        glass.extend(&ring);
        let b = body(&glass, &glass, &[lower], 0.0);
        let n = glass.len();
        assert!(
            b[n - ring.len()..].iter().all(|x| !x),
            "the ring is excluded"
        );
        assert!(b[..n - ring.len()].iter().all(|x| *x), "the glass is kept");
    }

    #[test]
    fn a_glass_leaning_against_a_neighbour_keeps_its_points_below_the_neighbours_top() {
        let a = Hull::of(&wall(0.0, 0.0, 0.04, 0.0, 0.06)).unwrap();
        // Leaning: its foot on the table beside the neighbour, its top above the neighbour's.
        let glass: Vec<DVec3> = (0..60)
            .map(|i| DVec3::new(0.05 + 0.0005 * i as f64, 0.0, 0.002 * i as f64))
            .collect();
        assert!(body(&glass, &glass, &[a], 0.0).iter().all(|x| *x));
    }

    #[test]
    fn a_glass_nested_inside_a_bowl_keeps_all_its_points() {
        let bowl = Hull::of(&wall(0.0, 0.0, 0.08, 0.0, 0.08)).unwrap();
        let glass = wall(0.01, 0.0, 0.03, 0.005, 0.07);
        assert!(body(&glass, &glass, &[bowl], 0.0).iter().all(|x| *x));
    }

    #[test]
    fn a_neighbour_touching_the_side_keeps_its_points() {
        let a = Hull::of(&wall(0.0, 0.0, 0.04, 0.0, 0.1)).unwrap();
        // Touching: the neighbour's wall passes 1 mm inside the first one's radius at one point.
        let b = wall(0.079, 0.0, 0.04, 0.0, 0.1);
        assert!(body(&b, &b, &[a], 0.0).iter().all(|x| *x));
    }
}
