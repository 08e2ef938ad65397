//! t = 0 settling of a **stack** (an object standing on the flat top of an upside-down one) and
//! the check that it holds.
//!
//! Settling runs in two phases: everything but the supported object first; then the supported
//! object alone onto the (now fixed) settled scene. A resting support does not move anyway, and
//! a static support gives the stiff, creep-free contact that a dynamic one lacks in rapier. A
//! contact projection (`seat_on_support`) then removes the degree or two of rocking that
//! rapier leaves between two glasses.

use crate::layout::{Layout, ObjectSpec, RelationKind};
use crate::physics::{self, BodySpec, PhysicsParams, Pose, SettleStats, Wake};
use crate::relation::{Settled, lowest_z, pair_distances, tilt_deg, world_points};
use crate::sequence::{Relation, SeatCorrection};
use crate::{ON_TABLE_M, SEAT_GAP_M, SEAT_MAX_TILT_DEG, SETTLE_ONTO_DAMPING};

/// The collision body of an object.
pub(crate) fn spec(o: &ObjectSpec) -> BodySpec<'_> {
    BodySpec {
        hull_points: &o.model.hull_points,
        mass_kg: o.mass_kg,
        plate: o.plate,
    }
}

/// Settles a stacked layout (see the module docs) and checks the stack.
pub fn settle(layout: &Layout, params: &PhysicsParams) -> Settled {
    let (rest, stats, seat) = settle_stack(layout, params);
    let relation = check_stack(layout, &rest);
    Settled {
        rest,
        stats,
        seat,
        relation,
    }
}

/// How well the stacked pair rests after settling: the supported object's base is above 70 %
/// of the support's height, it tilts less than 15° and its support less than 5°, and every
/// other object stands on the table.
fn check_stack(layout: &Layout, rest: &[Pose]) -> Relation {
    let (s, t) = (layout.event.support, layout.event.supported);
    let height = |i: usize| {
        let (lo, hi) = layout.objects[i].model.mesh.bounds();
        hi.z - lo.z
    };
    let min_z = lowest_z(layout, rest, t);
    let all_on_table = (0..rest.len()).filter(|&i| i != t).all(|i| {
        lowest_z(layout, rest, i) < ON_TABLE_M
            && rest[i].translation.truncate().length() < layout.env.table.half_size_m
    });
    let verified = all_on_table
        && min_z > 0.7 * height(s)
        && tilt_deg(&rest[t]) < 15.0
        && tilt_deg(&rest[s]) < 5.0;
    let (contact_m, mesh_m) = pair_distances(layout, rest, s, t);
    Relation {
        kind: RelationKind::Stack,
        support_obj_id: layout.objects[s].id,
        supported_obj_id: layout.objects[t].id,
        contact_distance_mm: contact_m * 1000.0,
        mesh_distance_mm: mesh_m * 1000.0,
        supported_min_z_mm: min_z * 1000.0,
        supported_tilt_deg: tilt_deg(&rest[t]),
        all_on_table,
        verified,
        support_tipping_margin: None,
    }
}

/// The two settling phases of the module docs.
fn settle_stack(
    layout: &Layout,
    params: &PhysicsParams,
) -> (Vec<Pose>, SettleStats, Option<SeatCorrection>) {
    let top = layout.event.supported;
    let rest_idx: Vec<usize> = (0..layout.objects.len()).filter(|&i| i != top).collect();
    let specs: Vec<BodySpec> = rest_idx.iter().map(|&i| spec(&layout.objects[i])).collect();
    let start: Vec<Pose> = rest_idx.iter().map(|&i| layout.start[i]).collect();
    let (phase_a, stats_a) =
        physics::settle(&specs, &start, &vec![Wake::Awake; specs.len()], params);
    // The supported object keeps its height above its support's settled pose.
    let mut poses = layout.start.clone();
    for (k, &i) in rest_idx.iter().enumerate() {
        poses[i] = phase_a[k];
    }
    let support = layout.event.support;
    let lift = poses[support].translation - layout.start[support].translation;
    poses[top].translation += lift;
    let (mut rest, stats_b) = settle_one_onto_fixed(layout, &poses, top, params);
    let seat = seat_on_support(layout, &mut rest);
    (
        rest,
        physics::SettleStats::sum(&stats_a, &stats_b, params),
        seat,
    )
}

/// Settles object `moving` from `poses` with every other object fixed, under the strong
/// [`SETTLE_ONTO_DAMPING`]: only its rest pose matters, and damping stops tall glasses rocking
/// on the contact.
pub(crate) fn settle_one_onto_fixed(
    layout: &Layout,
    poses: &[Pose],
    moving: usize,
    params: &PhysicsParams,
) -> (Vec<Pose>, SettleStats) {
    let specs: Vec<BodySpec> = layout.objects.iter().map(spec).collect();
    let wake: Vec<Wake> = (0..specs.len())
        .map(|i| {
            if i == moving {
                Wake::Awake
            } else {
                Wake::Fixed
            }
        })
        .collect();
    physics::settle(
        &specs,
        poses,
        &wake,
        &PhysicsParams {
            linear_damping: SETTLE_ONTO_DAMPING.0,
            angular_damping: SETTLE_ONTO_DAMPING.1,
            ..*params
        },
    )
}

/// Contact projection of the supported object: rapier leaves a glass on a glass rocking by a
/// degree or two (see [`settle_stack`]); when it came to rest on its support within
/// [`SEAT_MAX_TILT_DEG`] of the support's axis, it is turned about its centre to stand exactly
/// along that axis (yaw kept) and moved along it so that its base is [`SEAT_GAP_M`] above the
/// support's top. The glasses then neither float on one side nor intersect.
fn seat_on_support(layout: &Layout, rest: &mut [Pose]) -> Option<SeatCorrection> {
    let (s, t) = (layout.event.support, layout.event.supported);
    let axis_s = rest[s].rotation * glam::Vec3::Z;
    let up = if axis_s.z >= 0.0 { axis_s } else { -axis_s };
    let axis_t = rest[t].rotation * glam::Vec3::Z;
    let tilt_deg = axis_t.angle_between(up).to_degrees();
    if tilt_deg > SEAT_MAX_TILT_DEG {
        return None;
    }
    let before = rest[t].translation;
    let fix = glam::Quat::from_rotation_arc(axis_t, up);
    // Untilt about the object's centre (its translation is kept), then slide it along the axis.
    rest[t].rotation = (fix * rest[t].rotation).normalize();
    let top_of_support = world_points(layout, rest, s)
        .map(|p| p.dot(up))
        .fold(f32::MIN, f32::max);
    let base_of_top = world_points(layout, rest, t)
        .map(|p| p.dot(up))
        .fold(f32::MAX, f32::min);
    rest[t].translation += (top_of_support + SEAT_GAP_M - base_of_top) * up;
    Some(SeatCorrection {
        tilt_deg,
        shift_mm: 1000.0 * rest[t].translation.distance(before),
    })
}
