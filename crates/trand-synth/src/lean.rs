//! t = 0 settling of a **lean** (an object with its foot on the table and its side against an
//! upright support, as in the reference `seq_109`) and the check that it holds.
//!
//! Placement is geometric: the leaning object's axis is tilted by θ from the vertical towards a
//! horizontal direction `u` ([`lean_quat`]), its lowest hull point is put [`DROP_GAP_M`] above
//! the table, and it is slid along `−u` from the support's axis to the largest offset where the
//! two convex hulls are [`LEAN_GAP_M`] apart, found by bisection on the signed hull distance
//! (the set of offsets where two convex bodies overlap is an interval, and offset 0 is inside
//! it). Whether the hull contact is a glass contact (and not, say, the hull spanning a wine
//! glass's stem) is the mesh gap's business ([`crate::contact`]). θ must exceed the object's
//! tipping angle ([`tipping_tilt_rad`]), or it stands back up instead of leaning.
//!
//! Settling, as for a stack: everything but the leaning object first; the leaning object is
//! re-placed against its support's settled pose and settled alone with the rest fixed, under
//! strong damping. A lean on a round support holds by static friction against sideways slip,
//! which rapier's regularised friction only approximates: released with ordinary damping a
//! rapier lean slowly slides off even a fixed support. The rest pose is therefore the damped
//! one (as for a stack), and whether a free support would stay up is checked by statics
//! ([`support_tipping_margin`]).

use crate::layout::{DROP_GAP_M, Layout, RelationKind};
use crate::physics::{self, BodySpec, PhysicsParams, Pose, SettleStats, Wake};
use crate::relation::{Settled, lowest_z, pair_distances, tilt_deg};
use crate::sequence::Relation;
use crate::shapes::Model;
use crate::stack::{settle_one_onto_fixed, spec};
use crate::{ON_TABLE_M, contact};
use glam::{Quat, Vec2, Vec3};

/// Hull gap at which the leaning object is placed before settling (m).
pub const LEAN_GAP_M: f32 = DROP_GAP_M;
/// A lean must tilt at least this much (degrees)...
pub const MIN_LEAN_TILT_DEG: f32 = 15.0;
/// ... and at most this much: beyond it the object is lying, not leaning.
pub const MAX_LEAN_TILT_DEG: f32 = 75.0;
/// Largest mesh gap between a leaning object and its support (mm): above it the glass floats.
pub const MAX_LEAN_MESH_GAP_MM: f32 = 1.0;
/// Largest overlap of the two collision hulls in a verified lean (mm): rapier's resting contacts
/// sink a few hundredths of a millimetre; a rim caught on a rim can sink millimetres, and since
/// each render mesh lies inside its hull, a hull overlap bounds the glass overlap.
pub const MAX_LEAN_HULL_OVERLAP_MM: f32 = 0.3;
/// Largest support tilt of a verified lean (degrees).
pub const MAX_SUPPORT_TILT_DEG: f32 = 5.0;
/// Bisection steps of [`place_leaner`]: the offset interval halves each step, so 40 steps end
/// far below a micrometre for any starting interval under a metre.
const BISECTION_STEPS: u32 = 40;

/// Rotation of a leaning object: a yaw `yaw` about its own axis, then the axis tilted by `tilt`
/// (radians) from `ẑ` towards the horizontal unit `toward`, a rotation about `ẑ × toward`
/// (Rodrigues: `ẑ ↦ cos θ ẑ + sin θ toward`).
pub fn lean_quat(yaw: f32, tilt: f32, toward: Vec2) -> Quat {
    let axis = Vec3::Z.cross(toward.extend(0.0)).normalize();
    Quat::from_axis_angle(axis, tilt) * Quat::from_rotation_z(yaw)
}

/// The horizontal direction an object's axis tilts towards (`x̂` for an untilted one).
pub fn lean_direction(pose: &Pose) -> Vec2 {
    (pose.rotation * Vec3::Z).truncate().normalize_or(Vec2::X)
}

/// Tilt (radians) at which an object standing on its base is balanced on the base rim: its
/// centre of mass `c` is then straight above the rim, `θ = atan(r_base / (c_z − z_base))`
/// with `r_base` the radius of the hull's lowest ring. Tilted less, it stands back up.
pub fn tipping_tilt_rad(m: &Model) -> f32 {
    let z_base = m.hull_points.iter().map(|p| p.z).fold(f32::MAX, f32::min);
    let r_base = m
        .hull_points
        .iter()
        .filter(|p| p.z < z_base + 1e-5)
        .map(|p| p.truncate().length())
        .fold(0.0, f32::max);
    r_base.atan2(m.mesh.centroid().z - z_base)
}

/// Pose of `leaner` with rotation `q` leaning against `support` at `support_pose` (see the
/// module docs): on the line through the support's axis along `−toward`, lowest hull point
/// [`DROP_GAP_M`] above the table, hulls [`LEAN_GAP_M`] apart.
pub fn place_leaner(
    leaner: &Model,
    q: Quat,
    support: &Model,
    support_pose: &Pose,
    toward: Vec2,
) -> Pose {
    let lowest = leaner
        .hull_points
        .iter()
        .map(|p| (q * *p).z)
        .fold(f32::MAX, f32::min);
    let z = DROP_GAP_M - lowest;
    let axis_xy = support_pose.translation.truncate();
    let at = |s: f32| Pose {
        rotation: q,
        translation: (axis_xy - toward * s).extend(z),
    };
    let (Some(hl), Some(hs)) = (
        contact::Hull::new(&leaner.hull_points),
        contact::Hull::new(&support.hull_points),
    ) else {
        return at(0.0);
    };
    let reach = |m: &Model| {
        let (lo, hi) = m.mesh.bounds();
        (hi - lo).length()
    };
    let (mut inside, mut apart) = (0.0f32, reach(leaner) + reach(support));
    for _ in 0..BISECTION_STEPS {
        let mid = 0.5 * (inside + apart);
        if contact::hull_distance_m(&hl, &at(mid), &hs, support_pose) > LEAN_GAP_M {
            apart = mid;
        } else {
            inside = mid;
        }
    }
    at(apart)
}

/// Settles a leaning layout (see the module docs) and checks the lean.
pub fn settle(layout: &Layout, params: &PhysicsParams) -> Settled {
    let (s, l) = (layout.event.support, layout.event.supported);
    let others: Vec<usize> = (0..layout.objects.len()).filter(|&i| i != l).collect();
    let specs: Vec<BodySpec> = others.iter().map(|&i| spec(&layout.objects[i])).collect();
    let start: Vec<Pose> = others.iter().map(|&i| layout.start[i]).collect();
    let (phase_a, stats_a) =
        physics::settle(&specs, &start, &vec![Wake::Awake; specs.len()], params);
    let mut poses = layout.start.clone();
    for (k, &i) in others.iter().enumerate() {
        poses[i] = phase_a[k];
    }
    poses[l] = place_leaner(
        &layout.objects[l].model,
        layout.start[l].rotation,
        &layout.objects[s].model,
        &poses[s],
        lean_direction(&layout.start[l]),
    );
    let (rest, stats_b) = settle_one_onto_fixed(layout, &poses, l, params);
    Settled {
        relation: check_lean(layout, &rest),
        rest,
        stats: SettleStats::sum(&stats_a, &stats_b, params),
        seat: None,
    }
}

/// How far a free support is from being pushed over by the object leaning on it, as the ratio
/// of the restoring to the overturning moment about the support's base rim on the far side.
///
/// Bound from a frictionless support contact (friction there carries part of the leaning
/// object's weight and only helps): the leaning object's moment balance about its foot pivot
/// gives the horizontal push `N` at the contact height `z_c`, `N z_c = m_l g x`, with `x` the
/// horizontal offset of its centre of mass beyond the pivot along the lean direction. The
/// support tips when `N z_c > m_s g r_s`, so the margin is `m_s r_s / (m_l x)`, whatever the
/// contact height (infinite when `x ≤ 0`: nothing pushes).
pub fn support_tipping_margin(layout: &Layout, rest: &[Pose]) -> f32 {
    let (s, l) = (layout.event.support, layout.event.supported);
    let (os, ol) = (&layout.objects[s], &layout.objects[l]);
    let pivot = ol
        .model
        .hull_points
        .iter()
        .map(|p| rest[l].apply(*p))
        .min_by(|a, b| a.z.total_cmp(&b.z))
        .unwrap_or(rest[l].translation);
    let centre = rest[l].apply(ol.model.mesh.centroid());
    let x = (centre - pivot).truncate().dot(lean_direction(&rest[l]));
    let r_s = base_radius(&os.model);
    if x <= 0.0 {
        f32::INFINITY
    } else {
        os.mass_kg * r_s / (ol.mass_kg * x)
    }
}

/// Radius of the ring an upright object stands on: the mesh vertices at its lowest z, measured
/// from their mean.
fn base_radius(m: &Model) -> f32 {
    let (lo, _) = m.mesh.bounds();
    let ring: Vec<Vec3> = m.mesh.points().filter(|p| p.z < lo.z + 1e-5).collect();
    let centre = ring.iter().sum::<Vec3>() / ring.len().max(1) as f32;
    ring.iter()
        .map(|p| (*p - centre).truncate().length())
        .fold(0.0, f32::max)
}

/// Whether the lean holds: the leaning object tilts between [`MIN_LEAN_TILT_DEG`] and
/// [`MAX_LEAN_TILT_DEG`], its foot is on the table, its glass is within
/// [`MAX_LEAN_MESH_GAP_MM`] of the support's and the hulls overlap by at most
/// [`MAX_LEAN_HULL_OVERLAP_MM`], the support stands within
/// [`MAX_SUPPORT_TILT_DEG`] of upright and would not be pushed over
/// ([`support_tipping_margin`] above 1), and every other object stands on the table.
fn check_lean(layout: &Layout, rest: &[Pose]) -> Relation {
    let (s, l) = (layout.event.support, layout.event.supported);
    let (contact_m, mesh_m) = pair_distances(layout, rest, s, l);
    let min_z = lowest_z(layout, rest, l);
    let tilt = tilt_deg(&rest[l]);
    let margin = support_tipping_margin(layout, rest);
    let all_on_table = (0..rest.len()).all(|i| {
        lowest_z(layout, rest, i) < ON_TABLE_M
            && rest[i].translation.truncate().length() < layout.env.table.half_size_m
    });
    let verified = all_on_table
        && (MIN_LEAN_TILT_DEG..=MAX_LEAN_TILT_DEG).contains(&tilt)
        && mesh_m * 1000.0 <= MAX_LEAN_MESH_GAP_MM
        && contact_m * 1000.0 >= -MAX_LEAN_HULL_OVERLAP_MM
        && tilt_deg(&rest[s]) < MAX_SUPPORT_TILT_DEG
        && margin > 1.0;
    Relation {
        kind: RelationKind::Lean,
        support_obj_id: layout.objects[s].id,
        supported_obj_id: layout.objects[l].id,
        contact_distance_mm: contact_m * 1000.0,
        mesh_distance_mm: mesh_m * 1000.0,
        supported_min_z_mm: min_z * 1000.0,
        supported_tilt_deg: tilt,
        all_on_table,
        verified,
        support_tipping_margin: Some(margin.min(MARGIN_REPORTED_MAX)),
    }
}

/// Tipping margins are reported up to this value (JSON has no infinity).
pub const MARGIN_REPORTED_MAX: f32 = 1000.0;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lean_quat_tilts_the_axis_towards_the_given_direction() {
        let toward = Vec2::from_angle(0.7);
        let q = lean_quat(1.3, 0.5, toward);
        let axis = q * Vec3::Z;
        let want = 0.5f32.cos() * Vec3::Z + 0.5f32.sin() * toward.extend(0.0);
        assert!((axis - want).length() < 1e-6, "{axis} vs {want}");
        let pose = Pose {
            rotation: q,
            translation: Vec3::ZERO,
        };
        assert!((lean_direction(&pose) - toward).length() < 1e-6);
    }
}
