//! Which objects can move when some are taken away: the contact closure of the removed ones.
//!
//! An object at rest stays at rest unless something it touches changes. So the objects that may move
//! at t = 1 are those touching a removed object (it supported them, or they leaned on it), then those
//! touching one of these, and so on. Every other object keeps its t = 0 pose exactly (unless the new
//! mask shows that a falling object knocked it aside: [`crate::new_camera`]). This matters
//! because the simulation's material (the paper's, very soft) sags and slides under gravity even where
//! nothing happens: left to the simulation, objects nobody touched drift by centimetres.
//!
//! Two objects touch when at least [`CONTACT_SURFELS`] surfel centres of one lie within [`CONTACT_M`]
//! of the other's: a real contact is a patch of surface, while a stray surfel (a floater labelled with
//! an object) is a point. Surfels of an object are those whose probability of its channel exceeds ½
//! (as for deletion).

use std::collections::HashMap;

use glam::DVec2;
use trand_core::Surfels;

use crate::relocalise::body::{convex_hull, inside_convex};
use crate::surfel_ops::channel_probs;

/// Largest centre distance of two surfels of objects in contact (m): surfels sit on the surfaces,
/// a few millimetres apart, and glass walls in contact are a wall's thickness apart at most.
pub const CONTACT_M: f32 = 0.008;
/// See [`trim`].
pub const OUTLIER_FACTOR: f32 = 1.5;
/// Surfels near the other object that make a contact (see the module docs).
pub const CONTACT_SURFELS: usize = 8;

/// Centres of the surfels of each `(id, channel)` object, without its outliers (see [`trim`]).
pub fn object_centres(s: &Surfels, objects: &[(u16, usize)]) -> Vec<(u16, Vec<[f32; 3]>)> {
    objects
        .iter()
        .map(|&(id, c)| {
            let p = channel_probs(s, c);
            let pts = (0..s.len())
                .filter(|&i| p[i] > 0.5)
                .map(|i| s.means[i])
                .collect();
            (id, trim(pts))
        })
        .collect()
}

/// Height above the table (m) within which an object's surfel centres are its base.
pub const BASE_M: f32 = 0.005;

/// Whether an object (its surfel centres `points`) stands on the table at `ground` by itself: the
/// horizontal centroid of its centres (its centre of mass, for a glass of even wall) lies inside the
/// convex hull of its base, the centres within [`BASE_M`] of the table. Taking a neighbour away cannot
/// move such an object; one that leans on a neighbour, or sits on it, can.
pub fn stands_alone(points: &[[f32; 3]], ground: f32) -> bool {
    let base: Vec<DVec2> = points
        .iter()
        .filter(|p| p[2] < ground + BASE_M)
        .map(|p| DVec2::new(p[0] as f64, p[1] as f64))
        .collect();
    let n = points.len() as f64;
    let centroid = points.iter().fold(DVec2::ZERO, |a, p| {
        a + DVec2::new(p[0] as f64 / n, p[1] as f64 / n)
    });
    let polygon: Vec<DVec2> = convex_hull(&base).into_iter().map(|i| base[i]).collect();
    polygon.len() >= 3 && inside_convex(&polygon, centroid, 0.0)
}

/// Drops the points farther from the component-wise median than [`OUTLIER_FACTOR`] times the 90th
/// percentile of that distance: floaters, and surfels labelled with an object but lying at another.
pub fn trim(pts: Vec<[f32; 3]>) -> Vec<[f32; 3]> {
    if pts.len() < 10 {
        return pts;
    }
    let median = |k: usize| {
        let mut v: Vec<f32> = pts.iter().map(|p| p[k]).collect();
        v.sort_by(f32::total_cmp);
        v[v.len() / 2]
    };
    let m = [median(0), median(1), median(2)];
    let mut d: Vec<f32> = pts.iter().map(|p| dist2(p, &m).sqrt()).collect();
    d.sort_by(f32::total_cmp);
    let limit = OUTLIER_FACTOR * d[d.len() * 9 / 10];
    pts.into_iter()
        .filter(|p| dist2(p, &m).sqrt() <= limit)
        .collect()
}

/// Ids of the objects that may move: the transitive closure of "touches" from `removed`.
pub fn may_move(objects: &[(u16, Vec<[f32; 3]>)], removed: &[u16]) -> Vec<u16> {
    let grids: Vec<Grid> = objects.iter().map(|(_, p)| Grid::new(p)).collect();
    let mut moving: Vec<bool> = objects.iter().map(|(id, _)| removed.contains(id)).collect();
    let mut frontier: Vec<usize> = (0..objects.len()).filter(|&i| moving[i]).collect();
    while let Some(a) = frontier.pop() {
        for b in 0..objects.len() {
            if !moving[b] && grids[b].touches(&objects[a].1) {
                moving[b] = true;
                frontier.push(b);
            }
        }
    }
    objects
        .iter()
        .zip(&moving)
        .filter(|(o, m)| **m && !removed.contains(&o.0))
        .map(|(o, _)| o.0)
        .collect()
}

/// Points hashed into cubic cells of edge [`CONTACT_M`].
struct Grid<'a> {
    cells: HashMap<[i32; 3], Vec<&'a [f32; 3]>>,
}

fn cell(p: &[f32; 3]) -> [i32; 3] {
    p.map(|x| (x / CONTACT_M).floor() as i32)
}

impl<'a> Grid<'a> {
    fn new(points: &'a [[f32; 3]]) -> Self {
        let mut cells: HashMap<[i32; 3], Vec<&[f32; 3]>> = HashMap::new();
        for p in points {
            cells.entry(cell(p)).or_default().push(p);
        }
        Self { cells }
    }

    /// Whether at least [`CONTACT_SURFELS`] of `points` lie within [`CONTACT_M`] of a grid point.
    fn touches(&self, points: &[[f32; 3]]) -> bool {
        let r2 = CONTACT_M * CONTACT_M;
        let near = points.iter().filter(|p| {
            let c = cell(p);
            (-1..=1).any(|dx| {
                (-1..=1).any(|dy| {
                    (-1..=1).any(|dz| {
                        self.cells
                            .get(&[c[0] + dx, c[1] + dy, c[2] + dz])
                            .is_some_and(|v| v.iter().any(|q| dist2(p, q) < r2))
                    })
                })
            })
        });
        near.take(CONTACT_SURFELS).count() == CONTACT_SURFELS
    }
}

fn dist2(a: &[f32; 3], b: &[f32; 3]) -> f32 {
    (0..3).map(|k| (a[k] - b[k]) * (a[k] - b[k])).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn column(x: f32, n: usize) -> Vec<[f32; 3]> {
        (0..n).map(|i| [x, 0.0, i as f32 * 0.005]).collect()
    }

    #[test]
    fn only_objects_in_a_chain_of_contacts_with_the_removed_one_may_move() {
        // 1 removed; 2 touches 1 (3 mm); 3 touches 2 (5 mm); 4 is 5 cm from everything.
        let objects = vec![
            (1, column(0.0, 10)),
            (2, column(0.003, 10)),
            (3, column(0.008, 10)),
            (4, column(0.058, 10)),
        ];
        assert_eq!(may_move(&objects, &[1]), vec![2, 3]);
        assert_eq!(may_move(&objects, &[4]), Vec::<u16>::new());
        assert_eq!(may_move(&objects, &[]), Vec::<u16>::new());
    }

    #[test]
    fn contact_is_decided_by_distance_not_by_cell() {
        // Neighbouring cells, but 9 mm apart: no contact; 7 mm: contact.
        let a = column(0.0079, 10);
        assert!(!Grid::new(&a).touches(&column(0.0169, 10)));
        assert!(Grid::new(&a).touches(&column(0.0149, 10)));
    }

    /// Centres on the wall of a cylinder (radius 3 cm, 10 cm high) whose axis leans `tilt` radians
    /// towards +x about its foot at the origin, raised `lift` above the table.
    fn wall(tilt: f32, lift: f32) -> Vec<[f32; 3]> {
        let mut out = Vec::new();
        for i in 0..36 {
            let a = i as f32 * std::f32::consts::TAU / 36.0;
            for j in 0..=20 {
                let (u, v, h) = (0.03 * a.cos(), 0.03 * a.sin(), 0.005 * j as f32);
                // Rotate (u, v, h) about the y axis through the foot's edge at x = −3 cm.
                let (x, z) = (u + 0.03, h);
                let (x, z) = (
                    x * tilt.cos() + z * tilt.sin(),
                    -x * tilt.sin() + z * tilt.cos(),
                );
                out.push([x - 0.03, v, z + lift]);
            }
        }
        out
    }

    #[test]
    fn an_upright_glass_stands_alone_a_leaning_or_raised_one_does_not() {
        assert!(stands_alone(&wall(0.0, 0.0), 0.0));
        // Leaning 40° on its foot's edge: its centre of mass is far outside that edge.
        assert!(!stands_alone(&wall(-0.7, 0.0), 0.0));
        // Standing on something 4 cm high.
        assert!(!stands_alone(&wall(0.0, 0.04), 0.0));
    }

    #[test]
    fn surfels_far_from_their_object_are_trimmed() {
        let mut pts = column(0.0, 40);
        pts.push([0.3, 0.0, 0.05]);
        let kept = trim(pts);
        assert_eq!(kept.len(), 40);
        assert!(kept.iter().all(|p| p[0] == 0.0));
    }

    #[test]
    fn a_few_stray_surfels_are_not_a_contact() {
        let a = column(0.0, 10);
        let mut b = column(0.05, 10);
        b.extend(column(0.003, CONTACT_SURFELS - 1));
        assert!(!Grid::new(&a).touches(&b));
        b.push([0.003, 0.0, 0.02]);
        assert!(Grid::new(&a).touches(&b));
    }
}
