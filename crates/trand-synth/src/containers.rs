//! The containers family: scenes built around what is hardest for depth from a few views, open
//! containers standing upright (the inside of the opening) and a t = 1 event that leaves an
//! object tilted, lying or turned.
//!
//! A scene of `n` objects (3 ≤ n ≤ 6) holds:
//! * the **event pair** (ids 1 and 2, both glass), with probability [`LEAN_PROBABILITY`] a
//!   **lean**, else a **stack**:
//!   - lean (as the reference `seq_109`): a wine glass or tumbler ([`LEANER_KINDS`]) with its
//!     foot on the table and its side against an upright tumbler, mug or bottle
//!     ([`SUPPORT_KINDS`]; a mug turns its handle away from the leaning object), tilted before
//!     settling by its tipping angle plus U([`LEAN_TILT_BEYOND_TIPPING_DEG`]) (less, and it
//!     would stand back up instead of leaning). Tilts are redrawn (up to
//!     [`LEAN_TILT_TRIES`]) until the hull contact is a glass contact, i.e. the render meshes
//!     are within [`crate::lean::MAX_LEAN_MESH_GAP_MM`] (placement: [`crate::lean`]). When the
//!     support is removed the leaning object falls towards it and turns;
//!   - stack: an upright wine glass, mug or bowl on an upside-down tumbler or bowl; when the
//!     support is removed it drops onto the table;
//! * the others on the table around the pair: upright bowls, mugs and wine glasses, and, with
//!   probability [`LYING_PROBABILITY`] each, tumblers lying on their side. Enough of them are
//!   open containers that the scene has at least [`MIN_UPRIGHT_OPEN`] upright open containers
//!   (the upright top of a stack and a mug support count); with three objects a lean's support
//!   is therefore a mug.
//!
//! The pair stands near the middle; the others are placed by rejection sampling outside the
//! circles the pair occupies, including the disc the leaning object sweeps when it falls
//! (centre `foot + u h/2`, radius `h/2 + r` for height `h`, footprint radius `r`, lean
//! direction `u`), so the fall itself hits nothing. Every object gets a circumscribed collision
//! hull ([`HullFit::Circumscribed`]): lying and leaning objects rest on their round sides.
//! Materials as in the stacked family: the pair is glass, the others glass with probability
//! [`crate::layout::GLASS_PROBABILITY`], else glazed.

use crate::layout::{
    DROP_GAP_M, Event, GLASS_PROBABILITY, Layout, ObjectSpec, Orientation, RelationKind, glass,
    glazed, object_of, orientation_quat, place_in_disc, z_range,
};
use crate::lean::{MAX_LEAN_MESH_GAP_MM, lean_quat, place_leaner, tipping_tilt_rad};
use crate::physics::{Plate, Pose};
use crate::relation::GAP_SEARCH_M;
use crate::shapes::{HULL_SLICES, HullFit, Model, ShapeKind, build_fitted};
use crate::{contact, layout};
use glam::{Quat, Vec2, Vec3};
use rand::RngExt;
use std::f32::consts::{FRAC_PI_2, PI, TAU};

/// Fewest objects of a containers scene: the pair and one more.
pub const MIN_OBJECTS: u32 = 3;
/// Fewest upright open containers (bowls, mugs, wine glasses) per scene.
pub const MIN_UPRIGHT_OPEN: usize = 2;
/// Probability that the event is a lean rather than a stack.
pub const LEAN_PROBABILITY: f64 = 0.6;
/// Probability that an object beyond the required open containers is a lying tumbler.
pub const LYING_PROBABILITY: f64 = 0.4;
/// The leaning object's tilt before settling exceeds its tipping angle
/// ([`crate::lean::tipping_tilt_rad`]) by an amount drawn from this range (degrees).
pub const LEAN_TILT_BEYOND_TIPPING_DEG: (f32, f32) = (4.0, 18.0);
/// Tilts tried per layout until the lean is a glass contact.
pub const LEAN_TILT_TRIES: u32 = 8;
/// The pair's centre is drawn uniformly in `±PAIR_OFFSET_M` (both axes, m).
pub const PAIR_OFFSET_M: f32 = 0.04;
/// Kinds that lean, with their weights. Bottles do not: their hull spans the concave shoulder,
/// so a lean on it is a hull contact with the glass millimetres away.
pub const LEANER_KINDS: [(ShapeKind, f32); 2] =
    [(ShapeKind::WineGlass, 0.6), (ShapeKind::Tumbler, 0.4)];
/// Kinds that are leant against (standing upright), with their weights.
pub const SUPPORT_KINDS: [(ShapeKind, f32); 3] = [
    (ShapeKind::Tumbler, 0.45),
    (ShapeKind::Mug, 0.35),
    (ShapeKind::Bottle, 0.2),
];
/// Open containers: what may stand upright around the pair or on a stack.
pub const OPEN_KINDS: [ShapeKind; 3] = [ShapeKind::Bowl, ShapeKind::Mug, ShapeKind::WineGlass];
/// Largest angle between a mug support's handle and the lean direction (radians).
pub const HANDLE_SPREAD_RAD: f32 = PI / 3.0;

/// One weighted draw.
fn weighted(rng: &mut impl rand::Rng, table: &[(ShapeKind, f32)]) -> ShapeKind {
    let total: f32 = table.iter().map(|(_, w)| w).sum();
    let mut x = rng.random_range(0.0..total);
    for (k, w) in table {
        if x < *w {
            return *k;
        }
        x -= w;
    }
    table[table.len() - 1].0
}

fn any_open(rng: &mut impl rand::Rng) -> ShapeKind {
    OPEN_KINDS[rng.random_range(0..OPEN_KINDS.len())]
}

/// Whether an object counts as an upright open container.
fn is_upright_open(o: &ObjectSpec) -> bool {
    o.orientation == Orientation::Upright && OPEN_KINDS.contains(&o.model.kind)
}

/// Builds an object with a circumscribed hull.
fn object(
    id: u32,
    kind: ShapeKind,
    material: crate::material::Material,
    orientation: Orientation,
    rng: &mut impl rand::Rng,
    slices: u32,
) -> ObjectSpec {
    let model = build_fitted(kind, rng, slices, HullFit::Circumscribed);
    object_of(id, model, material, orientation)
}

/// Footprint radius of a model under rotation `q`: the largest horizontal distance of a vertex
/// from the model origin.
fn footprint_at(m: &Model, q: Quat) -> f32 {
    m.mesh
        .points()
        .map(|p| (q * p).truncate().length())
        .fold(0.0, f32::max)
}

/// A pose resting [`DROP_GAP_M`] above the table at `xy`.
fn dropped(m: &Model, q: Quat, xy: Vec2) -> Pose {
    let (lo, _) = z_range(m, q);
    Pose {
        rotation: q,
        translation: xy.extend(DROP_GAP_M - lo),
    }
}

/// Rotation of a lying tumbler: axis horizontal (`R_x(π/2)`), turned about its axis by half a
/// hull sector (`R_z(π/n)`) so that a hull face, not an edge, is down, then yawed.
fn lying_quat(yaw: f32) -> Quat {
    Quat::from_rotation_z(yaw)
        * Quat::from_rotation_x(FRAC_PI_2)
        * Quat::from_rotation_z(PI / HULL_SLICES as f32)
}

/// The event pair: objects (support first), start poses, and the circles they keep free.
struct Pair {
    objects: [ObjectSpec; 2],
    start: [Pose; 2],
    keep_free: Vec<(Vec2, f32)>,
    kind: RelationKind,
}

/// Stack: an upright open container on an upside-down tumbler or bowl, offset by up to 4 mm.
fn stack_pair(rng: &mut impl rand::Rng, slices: u32, centre: Vec2) -> Pair {
    let support_kind = if rng.random_bool(0.6) {
        ShapeKind::Tumbler
    } else {
        ShapeKind::Bowl
    };
    let top_kind = any_open(rng);
    let g = glass(rng);
    let mut support = object(1, support_kind, g, Orientation::Inverted, rng, slices);
    support.plate = Plate::OnModelBase;
    let g = glass(rng);
    let top = object(2, top_kind, g, Orientation::Upright, rng, slices);
    let q_s = orientation_quat(Orientation::Inverted, rng.random_range(0.0..TAU));
    let support_pose = dropped(&support.model, q_s, centre);
    let (_, hi_s) = z_range(&support.model, q_s);
    let q_t = orientation_quat(Orientation::Upright, rng.random_range(0.0..TAU));
    let (lo_t, _) = z_range(&top.model, q_t);
    let offset = Vec2::from_angle(rng.random_range(0.0..TAU)) * rng.random_range(0.0..0.004);
    let top_pose = Pose {
        rotation: q_t,
        translation: (centre + offset)
            .extend(support_pose.translation.z + hi_s + DROP_GAP_M - lo_t),
    };
    let r = footprint_at(&support.model, q_s).max(footprint_at(&top.model, q_t));
    Pair {
        objects: [support, top],
        start: [support_pose, top_pose],
        keep_free: vec![(centre, r)],
        kind: RelationKind::Stack,
    }
}

/// Lean: see the module docs. `n` is the scene's object count (three objects force a mug
/// support).
fn lean_pair(rng: &mut impl rand::Rng, slices: u32, centre: Vec2, n: u32) -> Pair {
    let support_kind = if n <= MIN_OBJECTS {
        ShapeKind::Mug
    } else {
        weighted(rng, &SUPPORT_KINDS)
    };
    let leaner_kind = weighted(rng, &LEANER_KINDS);
    let g = glass(rng);
    let support = object(1, support_kind, g, Orientation::Upright, rng, slices);
    let g = glass(rng);
    let leaner = object(2, leaner_kind, g, Orientation::Tilted, rng, slices);
    let toward = Vec2::from_angle(rng.random_range(0.0..TAU));
    // The mug's handle is along its model +x: turn it away from the leaning object.
    let yaw_s = match support_kind {
        ShapeKind::Mug => {
            toward.to_angle() + rng.random_range(-HANDLE_SPREAD_RAD..HANDLE_SPREAD_RAD)
        }
        _ => rng.random_range(0.0..TAU),
    };
    let q_s = orientation_quat(Orientation::Upright, yaw_s);
    let support_pose = dropped(&support.model, q_s, centre);
    let mut leaner_pose = support_pose;
    let tipping = tipping_tilt_rad(&leaner.model);
    let beyond = LEAN_TILT_BEYOND_TIPPING_DEG;
    for _ in 0..LEAN_TILT_TRIES {
        let tilt = tipping + rng.random_range(beyond.0..beyond.1).to_radians();
        let q = lean_quat(rng.random_range(0.0..TAU), tilt, toward);
        leaner_pose = place_leaner(&leaner.model, q, &support.model, &support_pose, toward);
        let gap = contact::mesh_gap_m(
            &leaner.model.mesh,
            &leaner_pose,
            &support.model.mesh,
            &support_pose,
            GAP_SEARCH_M,
        );
        if gap * 1000.0 <= MAX_LEAN_MESH_GAP_MM {
            break;
        }
    }
    let keep_free = vec![
        (centre, footprint_at(&support.model, q_s)),
        fall_disc(&leaner.model, &leaner_pose, toward),
    ];
    Pair {
        objects: [support, leaner],
        start: [support_pose, leaner_pose],
        keep_free,
        kind: RelationKind::Lean,
    }
}

/// The disc a leaning object sweeps when it falls over towards `toward` (module docs).
fn fall_disc(m: &Model, pose: &Pose, toward: Vec2) -> (Vec2, f32) {
    let (lo, hi) = m.mesh.bounds();
    let foot = pose.apply(Vec3::new(0.0, 0.0, lo.z)).truncate();
    let h = hi.z - lo.z;
    let r = footprint_at(m, Quat::IDENTITY);
    (foot + toward * (0.5 * h), 0.5 * h + r)
}

/// What one object around the pair is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Slot {
    UprightOpen,
    LyingTumbler,
}

/// Composes a containers scene of `n` objects (`MIN_OBJECTS ≤ n`; see the module docs).
pub fn sample(rng: &mut impl rand::Rng, n: u32, slices: u32) -> Layout {
    let env = layout::environment(rng);
    let centre = Vec2::new(
        rng.random_range(-PAIR_OFFSET_M..PAIR_OFFSET_M),
        rng.random_range(-PAIR_OFFSET_M..PAIR_OFFSET_M),
    );
    let pair = if rng.random_bool(LEAN_PROBABILITY) {
        lean_pair(rng, slices, centre, n)
    } else {
        stack_pair(rng, slices, centre)
    };
    let open_in_pair = pair.objects.iter().filter(|o| is_upright_open(o)).count();
    let mut need_open = MIN_UPRIGHT_OPEN.saturating_sub(open_in_pair);
    let Pair {
        objects,
        start,
        keep_free,
        kind,
    } = pair;
    let (mut objects, mut start, mut placed) = (objects.to_vec(), start.to_vec(), keep_free);
    for id in 3..=n {
        let slot = if need_open > 0 || !rng.random_bool(LYING_PROBABILITY) {
            Slot::UprightOpen
        } else {
            Slot::LyingTumbler
        };
        need_open = need_open.saturating_sub(1);
        let material = if rng.random_bool(GLASS_PROBABILITY) {
            glass(rng)
        } else {
            glazed(rng)
        };
        let yaw = rng.random_range(0.0..TAU);
        let (o, q) = match slot {
            Slot::UprightOpen => {
                let kind = any_open(rng);
                let o = object(id, kind, material, Orientation::Upright, rng, slices);
                (o, orientation_quat(Orientation::Upright, yaw))
            }
            Slot::LyingTumbler => {
                let o = object(
                    id,
                    ShapeKind::Tumbler,
                    material,
                    Orientation::Lying,
                    rng,
                    slices,
                );
                (o, lying_quat(yaw))
            }
        };
        let r = footprint_at(&o.model, q);
        let xy = place_in_disc(rng, &placed, r);
        placed.push((xy, r));
        start.push(dropped(&o.model, q, xy));
        objects.push(o);
    }
    Layout {
        objects,
        start,
        event: Event {
            kind,
            support: 0,
            supported: 1,
        },
        env,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn every_scene_has_two_upright_open_containers_and_its_event_pair_first() {
        for seed in 0..40 {
            let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
            let n = 3 + (seed % 4) as u32;
            let l = sample(&mut rng, n, 24);
            assert_eq!(l.objects.len(), n as usize);
            let open = l.objects.iter().filter(|o| is_upright_open(o)).count();
            assert!(
                open >= MIN_UPRIGHT_OPEN,
                "seed {seed}: {open} open containers"
            );
            let modes = (l.objects[0].orientation, l.objects[1].orientation);
            match l.event.kind {
                RelationKind::Lean => {
                    assert_eq!(modes, (Orientation::Upright, Orientation::Tilted))
                }
                RelationKind::Stack => {
                    assert_eq!(modes, (Orientation::Inverted, Orientation::Upright))
                }
            }
            for o in &l.objects[2..] {
                assert!(
                    is_upright_open(o)
                        || (o.orientation == Orientation::Lying
                            && o.model.kind == ShapeKind::Tumbler),
                    "seed {seed}: {:?} {:?}",
                    o.model.kind,
                    o.orientation
                );
            }
        }
    }

    #[test]
    fn a_lying_tumbler_starts_with_its_axis_horizontal_and_a_hull_face_down() {
        let q = lying_quat(0.4);
        assert!((q * Vec3::Z).z.abs() < 1e-6);
        // The face centre at model angle −(π/2 + π/n) points straight down.
        let a = -(FRAC_PI_2 + PI / HULL_SLICES as f32);
        let down = q * Vec3::new(a.cos(), a.sin(), 0.0);
        assert!((down + Vec3::Z).length() < 1e-6, "{down}");
    }
}
