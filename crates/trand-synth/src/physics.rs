//! Rigid-body settling with rapier3d.
//!
//! Every object is a dynamic body with one convex-hull collider built from a simplified
//! revolution of its profile ([`crate::shapes::collision_points`]; a hull is exact for the outside
//! of a vessel standing upright or upside down, which is how objects rest and stack here), plus,
//! for upside-down vessels, a thin box "plate" flush with the flat top ([`Plate`]). The table is a
//! fixed box whose top face is `z = 0`. The mass is the real glass mass (mesh volume × density)
//! rather than that of the solid hull.
//!
//! The world is stepped with a fixed time step on one thread (rapier without its `parallel`
//! feature), so a given input always settles to the same poses. A simulation stops when every
//! body is at rest (see [`settle`]) or after `max_steps`.
//!
//! For t = 1 a fresh world is built from the t = 0 rest poses without the removed object; objects
//! that were not standing on the table start awake, all others asleep ([`Wake`]), so only what is
//! disturbed moves (chain reactions wake what they hit). Objects whose vertices all moved less than
//! [`STATIC_SNAP_MM`] are snapped back to their t = 0 pose, so untouched objects are bit-identical
//! between the states (as in the reference data). Sleeping bodies do get woken, though, and then
//! creep by millimetres to centimetres while anything else moves; [`settle_spreading`] keeps
//! every object fixed until a moving one touches it instead.

use glam::{Quat, Vec3};
use rapier3d::prelude::*;
use serde::Serialize;

/// Table box half-extents (m); its top face is the plane `z = 0`.
pub const TABLE_HALF: [f32; 3] = [0.6, 0.6, 0.05];
/// Soda-lime glass density, kg/m³.
pub const GLASS_DENSITY: f32 = 2500.0;
/// Glazed ceramic density, kg/m³.
pub const CERAMIC_DENSITY: f32 = 2300.0;
/// Fixed physics step (s): 240 Hz keeps 2 mm glass walls from tunnelling at drop speeds.
pub const DT: f32 = 1.0 / 240.0;
/// Steps between rest checks (0.1 s).
pub const CHECK_EVERY: u32 = 24;
/// A body is at rest when no hull vertex moved more than this during one check window
/// (0.5 mm per 0.1 s: slower than any real fall or topple, faster than contact creep).
pub const REST_TOL_MM: f32 = 0.5;
/// Minimum simulated steps before a scene may count as settled (0.5 s: a removed support's
/// load needs a moment to start falling).
pub const MIN_STEPS: u32 = 120;
/// Objects that moved less than this at t = 1 are snapped back to their t = 0 pose.
pub const STATIC_SNAP_MM: f32 = 1.0;

/// A rigid pose: `p_world = rotation · p_model + translation` (metres).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    pub rotation: Quat,
    pub translation: Vec3,
}

impl Pose {
    pub fn apply(&self, p: Vec3) -> Vec3 {
        self.rotation * p + self.translation
    }
}

/// Plate proud of a support's flat top (m): contact then happens against the plate, which the
/// supported object meets at most this far above the glass (sub-pixel in every view).
pub const PLATE_PROUD_M: f32 = 3e-4;
/// Plate half-thickness (m); the rest of the plate is buried in the glass base.
pub const PLATE_HALF_THICKNESS_M: f32 = 1e-3;

/// Extra collision geometry of an object.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Plate {
    None,
    /// A thin box inscribed in the flat face at the model's lowest z (the base of an upside-down
    /// vessel, which is then its top). Hull-on-hull face contacts between two flat 24-gons
    /// chatter in rapier 0.36 (a glass on a fixed upside-down glass walked off within seconds);
    /// box-on-hull contacts rest like the table does.
    OnModelBase,
}

/// One object for the simulation.
pub struct BodySpec<'a> {
    pub hull_points: &'a [Vec3],
    pub mass_kg: f32,
    pub plate: Plate,
}

/// Centre and half-extents (model frame) of the plate of [`Plate::OnModelBase`].
fn base_plate(points: &[Vec3]) -> (Vec3, Vec3) {
    let lo = points.iter().map(|p| p.z).fold(f32::MAX, f32::min);
    let r = points
        .iter()
        .filter(|p| p.z < lo + 1e-5)
        .map(|p| p.truncate().length())
        .fold(0.0, f32::max);
    // Inscribed square of the base disc (half-side r/√2), slightly inset.
    let half = 0.65 * r;
    (
        Vec3::new(0.0, 0.0, lo + PLATE_HALF_THICKNESS_M - PLATE_PROUD_M),
        Vec3::new(half, half, PLATE_HALF_THICKNESS_M),
    )
}

/// Result of one settling run.
#[derive(Clone, Debug, Serialize)]
pub struct SettleStats {
    pub steps: u32,
    pub seconds: f32,
    pub converged: bool,
}

impl SettleStats {
    /// Two runs one after the other: steps add up, simulated time is `steps · dt`, and the
    /// whole converged only if both did.
    pub fn sum(a: &SettleStats, b: &SettleStats, params: &PhysicsParams) -> SettleStats {
        let steps = a.steps + b.steps;
        SettleStats {
            steps,
            seconds: steps as f32 * params.dt,
            converged: a.converged && b.converged,
        }
    }
}

/// Contact and damping parameters (reported in `sequence.json`).
#[derive(Clone, Copy, Debug, Serialize)]
pub struct PhysicsParams {
    pub friction: f32,
    pub restitution: f32,
    pub linear_damping: f32,
    pub angular_damping: f32,
    pub dt: f32,
    pub max_steps: u32,
    pub length_unit: f32,
}

impl Default for PhysicsParams {
    fn default() -> Self {
        // Damping and restitution as in the reference data's Bullet settings; `length_unit` 0.1
        // because objects are ~10 cm (rapier's sleep and contact thresholds scale with it).
        Self {
            friction: 0.8,
            restitution: 0.05,
            linear_damping: 0.3,
            angular_damping: 0.8,
            dt: DT,
            max_steps: 2400,
            length_unit: 0.1,
        }
    }
}

/// Whether a body takes part in the simulation from the first step.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Wake {
    /// Simulated from the start.
    Awake,
    /// Starts asleep: it keeps its pose exactly until something moving touches it (rapier wakes
    /// the whole contact island then), which is how chain reactions reach it.
    Asleep,
    /// Never moves (an already settled support under an object being settled onto it).
    Fixed,
}

/// A simulation world with one rigid body per [`BodySpec`], in input order.
struct World {
    world: PhysicsWorld,
    handles: Vec<RigidBodyHandle>,
}

impl World {
    /// The table, then the bodies at their `start` poses.
    fn new(bodies: &[BodySpec<'_>], start: &[Pose], wake: &[Wake], params: &PhysicsParams) -> Self {
        let mut world = PhysicsWorld::new();
        world.gravity = Vector::new(0.0, 0.0, -9.81);
        world.integration_parameters.dt = params.dt;
        world.integration_parameters.length_unit = params.length_unit;
        let [hx, hy, hz] = TABLE_HALF;
        world.insert(
            RigidBodyBuilder::fixed().translation(Vector::new(0.0, 0.0, -hz)),
            ColliderBuilder::cuboid(hx, hy, hz)
                .friction(params.friction)
                .restitution(params.restitution),
        );
        let mut handles = Vec::with_capacity(bodies.len());
        for ((b, p), w) in bodies.iter().zip(start).zip(wake) {
            let collider = ColliderBuilder::convex_hull(b.hull_points)
                .unwrap_or_else(|| ColliderBuilder::ball(0.01))
                .mass(b.mass_kg)
                .friction(params.friction)
                .restitution(params.restitution);
            let body = (if *w == Wake::Fixed {
                RigidBodyBuilder::fixed()
            } else {
                RigidBodyBuilder::dynamic()
            })
            .pose(rapier3d::math::Pose::from_parts(p.translation, p.rotation))
            .linear_damping(params.linear_damping)
            .angular_damping(params.angular_damping)
            .sleeping(*w == Wake::Asleep);
            let handle = world.insert(body, collider).0;
            if b.plate == Plate::OnModelBase {
                let (c, h) = base_plate(b.hull_points);
                let plate = ColliderBuilder::cuboid(h.x, h.y, h.z)
                    .translation(c)
                    .mass(0.0)
                    .friction(params.friction)
                    .restitution(params.restitution);
                world.insert_collider(plate, Some(handle));
            }
            handles.push(handle);
        }
        Self { world, handles }
    }

    fn poses(&self) -> Vec<Pose> {
        self.handles
            .iter()
            .map(|h| {
                let b = &self.world.bodies[*h];
                Pose {
                    rotation: *b.rotation(),
                    translation: b.translation(),
                }
            })
            .collect()
    }

    /// Steps until every body is at rest (see [`settle`]) or `max_steps`; `after_step` sees
    /// the world after every step.
    fn run(
        &mut self,
        bodies: &[BodySpec<'_>],
        params: &PhysicsParams,
        mut after_step: impl FnMut(&World),
    ) -> (Vec<Pose>, SettleStats) {
        let mut last = self.poses();
        let mut steps = 0;
        let mut converged = false;
        while steps < params.max_steps {
            self.world.step();
            after_step(self);
            steps += 1;
            if steps % CHECK_EVERY == 0 {
                let now = self.poses();
                let still = bodies.iter().zip(last.iter().zip(&now)).all(|(b, (a, c))| {
                    max_vertex_displacement_mm(b.hull_points, a, c) < REST_TOL_MM
                });
                last = now;
                if still && steps >= MIN_STEPS {
                    converged = true;
                    break;
                }
            }
        }
        (
            last,
            SettleStats {
                steps,
                seconds: steps as f32 * params.dt,
                converged,
            },
        )
    }

    /// Indices of the fixed bodies that a body in `moving` is in contact with now.
    fn touched_fixed(&self, moving: &[bool], into: &mut [bool]) {
        let index_of = |h: RigidBodyHandle| self.handles.iter().position(|x| *x == h);
        for (i, h) in self.handles.iter().enumerate().filter(|(i, _)| moving[*i]) {
            for c in self.world.bodies[*h].colliders() {
                for pair in self.world.narrow_phase.contact_pairs_with(*c) {
                    if !pair.has_any_active_contact() {
                        continue;
                    }
                    let other = if pair.collider1 == *c {
                        pair.collider2
                    } else {
                        pair.collider1
                    };
                    let parent = self.world.colliders[other].parent();
                    if let Some(j) = parent.and_then(index_of).filter(|&j| j != i && !moving[j]) {
                        into[j] = true;
                    }
                }
            }
        }
    }
}

/// Drops the bodies from `start` poses and returns their rest poses.
///
/// Rest criterion (instead of rapier's own sleeping, which the contact creep of tall light
/// glasses on flat hulls can postpone indefinitely): every [`CHECK_EVERY`] steps each body's
/// largest hull-vertex displacement since the previous check is measured; the scene is at rest
/// when all are below [`REST_TOL_MM`] (after at least [`MIN_STEPS`]).
pub fn settle(
    bodies: &[BodySpec<'_>],
    start: &[Pose],
    wake: &[Wake],
    params: &PhysicsParams,
) -> (Vec<Pose>, SettleStats) {
    World::new(bodies, start, wake, params).run(bodies, params, |_| {})
}

/// Settles with only the bodies marked in `moving` simulated and every other body fixed,
/// widening the moving set by contact: when a moving body touches a fixed one, that body joins
/// the moving set and the whole simulation restarts from `start`, until a run touches nothing
/// new. Returns the rest poses, the stats summed over all runs, and the final moving set.
///
/// A resting object that nothing touches then keeps its pose exactly. Simulating it instead (as
/// a sleeping body that rapier may wake) lets rapier's contact creep walk it across the table
/// by millimetres to centimetres while something else is still moving.
pub fn settle_spreading(
    bodies: &[BodySpec<'_>],
    start: &[Pose],
    moving: &[bool],
    params: &PhysicsParams,
) -> (Vec<Pose>, SettleStats, Vec<bool>) {
    let mut moving = moving.to_vec();
    let mut total = SettleStats {
        steps: 0,
        seconds: 0.0,
        converged: true,
    };
    loop {
        let wake: Vec<Wake> = moving
            .iter()
            .map(|&m| if m { Wake::Awake } else { Wake::Fixed })
            .collect();
        let mut touched = vec![false; bodies.len()];
        let (rest, stats) = World::new(bodies, start, &wake, params)
            .run(bodies, params, |w| w.touched_fixed(&moving, &mut touched));
        total = SettleStats::sum(&total, &stats, params);
        if !touched.iter().any(|&t| t) {
            return (rest, total, moving);
        }
        for (m, t) in moving.iter_mut().zip(&touched) {
            *m |= *t;
        }
    }
}

/// Largest displacement (mm) of any of `points` between two poses.
pub fn max_vertex_displacement_mm(points: &[Vec3], a: &Pose, b: &Pose) -> f32 {
    points
        .iter()
        .map(|p| (a.apply(*p) - b.apply(*p)).length())
        .fold(0.0, f32::max)
        * 1000.0
}

/// Rotation angle (degrees) of `b.rotation · a.rotation⁻¹`.
pub fn rotation_deg(a: &Pose, b: &Pose) -> f32 {
    let q = b.rotation * a.rotation.inverse();
    (2.0 * q.w.abs().clamp(0.0, 1.0).acos()).to_degrees()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_dropped_box_comes_to_rest_on_the_table_plane() {
        let h = 0.02;
        let pts: Vec<Vec3> = (0..8)
            .map(|i| {
                Vec3::new(
                    if i & 1 == 0 { -h } else { h },
                    if i & 2 == 0 { -h } else { h },
                    if i & 4 == 0 { -h } else { h },
                )
            })
            .collect();
        let start = [Pose {
            rotation: Quat::IDENTITY,
            translation: Vec3::new(0.0, 0.0, 0.05),
        }];
        let (rest, stats) = settle(
            &[BodySpec {
                hull_points: &pts,
                mass_kg: 0.1,
                plate: Plate::None,
            }],
            &start,
            &[Wake::Awake],
            &PhysicsParams::default(),
        );
        assert!(stats.converged, "{stats:?}");
        assert!(
            (rest[0].translation.z - h).abs() < 1e-3,
            "rests at z = {}",
            rest[0].translation.z
        );
    }
}
