//! t = 0 settling of a layout by its event kind ([`crate::stack`] or [`crate::lean`]), and the
//! measurements both use to check a relation.

use crate::contact::{Hull, hull_distance_m, mesh_gap_m};
use crate::layout::{Layout, RelationKind};
use crate::physics::{PhysicsParams, Pose, SettleStats};
use crate::sequence::{Relation, SeatCorrection};
use glam::Vec3;

/// Mesh gaps are searched up to this distance (m); larger gaps are reported as this value.
pub const GAP_SEARCH_M: f32 = 0.01;

/// A settled t = 0 scene.
pub struct Settled {
    pub rest: Vec<Pose>,
    pub stats: SettleStats,
    /// Contact projection of a stacked object (none for other relations).
    pub seat: Option<SeatCorrection>,
    pub relation: Relation,
}

/// Settles `layout` at t = 0 as its event kind requires and checks the relation.
pub fn settle_event(layout: &Layout, params: &PhysicsParams) -> Settled {
    match layout.event.kind {
        RelationKind::Stack => crate::stack::settle(layout, params),
        RelationKind::Lean => crate::lean::settle(layout, params),
    }
}

/// The mesh vertices of object `i` at its pose in `rest`, in world coordinates.
pub fn world_points<'a>(
    layout: &'a Layout,
    rest: &[Pose],
    i: usize,
) -> impl Iterator<Item = Vec3> + 'a {
    let pose = rest[i];
    layout.objects[i]
        .model
        .mesh
        .points()
        .map(move |p| pose.apply(p))
}

/// Lowest world z of object `i`'s mesh (m).
pub fn lowest_z(layout: &Layout, rest: &[Pose], i: usize) -> f32 {
    world_points(layout, rest, i)
        .map(|p| p.z)
        .fold(f32::MAX, f32::min)
}

/// Angle (degrees) between an object's axis and the vertical, `acos |R ẑ · ẑ|` (upside down
/// counts as untilted).
pub fn tilt_deg(pose: &Pose) -> f32 {
    (pose.rotation * Vec3::Z)
        .z
        .abs()
        .clamp(0.0, 1.0)
        .acos()
        .to_degrees()
}

/// Signed hull distance and mesh gap (m) between objects `a` and `b` (see [`crate::contact`]).
pub fn pair_distances(layout: &Layout, rest: &[Pose], a: usize, b: usize) -> (f32, f32) {
    let (oa, ob) = (&layout.objects[a], &layout.objects[b]);
    let hull = match (
        Hull::new(&oa.model.hull_points),
        Hull::new(&ob.model.hull_points),
    ) {
        (Some(ha), Some(hb)) => hull_distance_m(&ha, &rest[a], &hb, &rest[b]),
        _ => f32::NAN,
    };
    let mesh = mesh_gap_m(
        &oa.model.mesh,
        &rest[a],
        &ob.model.mesh,
        &rest[b],
        GAP_SEARCH_M,
    );
    (hull, mesh)
}
