//! Rigid-body settling with rapier3d.
//!
//! Every object is a dynamic body with one convex-hull collider of its mesh (a hull is exact for
//! the outside of a vessel standing upright or upside down, which is how objects rest and stack
//! here); the table is a fixed box whose top face is `z = 0`. The mass is the real glass mass
//! (mesh volume × density) rather than that of the solid hull.
//!
//! The world is stepped with a fixed time step on one thread (rapier without its `parallel`
//! feature), so a given input always settles to the same poses. A simulation stops when every
//! body is asleep (checked every [`CHECK_EVERY`] steps) or after `max_steps`.
//!
//! For t = 1 a fresh world is built from the t = 0 rest poses without the removed object, and the
//! rest re-settle (chain reactions included). Objects whose vertices all moved less than
//! [`STATIC_SNAP_MM`] are snapped back to their t = 0 pose, so untouched objects are bit-identical
//! between the states (as in the reference data).

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
/// Steps between sleep checks.
pub const CHECK_EVERY: u32 = 24;
/// Minimum simulated steps before a scene may count as settled (0.2 s).
pub const MIN_STEPS: u32 = 48;
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

/// One object for the simulation.
pub struct BodySpec<'a> {
    pub hull_points: &'a [Vec3],
    pub mass_kg: f32,
}

/// Result of one settling run.
#[derive(Clone, Debug, Serialize)]
pub struct SettleStats {
    pub steps: u32,
    pub seconds: f32,
    pub converged: bool,
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
        Self { friction: 0.8, restitution: 0.05, linear_damping: 0.3, angular_damping: 0.8, dt: DT, max_steps: 2400, length_unit: 0.1 }
    }
}

/// Drops the bodies from `start` poses and returns their rest poses.
pub fn settle(bodies: &[BodySpec<'_>], start: &[Pose], params: &PhysicsParams) -> (Vec<Pose>, SettleStats) {
    let mut world = PhysicsWorld::new();
    world.gravity = Vector::new(0.0, 0.0, -9.81);
    world.integration_parameters.dt = params.dt;
    world.integration_parameters.length_unit = params.length_unit;
    let [hx, hy, hz] = TABLE_HALF;
    world.insert(
        RigidBodyBuilder::fixed().translation(Vector::new(0.0, 0.0, -hz)),
        ColliderBuilder::cuboid(hx, hy, hz).friction(params.friction).restitution(params.restitution),
    );
    let mut handles = Vec::with_capacity(bodies.len());
    for (b, p) in bodies.iter().zip(start) {
        let collider = ColliderBuilder::convex_hull(b.hull_points)
            .unwrap_or_else(|| ColliderBuilder::ball(0.01))
            .mass(b.mass_kg)
            .friction(params.friction)
            .restitution(params.restitution);
        let body = RigidBodyBuilder::dynamic()
            .pose(rapier3d::math::Pose::from_parts(p.translation, p.rotation))
            .linear_damping(params.linear_damping)
            .angular_damping(params.angular_damping);
        handles.push(world.insert(body, collider).0);
    }
    let mut steps = 0;
    let mut converged = false;
    while steps < params.max_steps {
        world.step();
        steps += 1;
        if steps >= MIN_STEPS && steps % CHECK_EVERY == 0 && handles.iter().all(|h| world.bodies[*h].is_sleeping()) {
            converged = true;
            break;
        }
    }
    let poses = handles
        .iter()
        .map(|h| {
            let b = &world.bodies[*h];
            Pose { rotation: *b.rotation(), translation: b.translation() }
        })
        .collect();
    (poses, SettleStats { steps, seconds: steps as f32 * params.dt, converged })
}

/// Largest displacement (mm) of any of `points` between two poses.
pub fn max_vertex_displacement_mm(points: &[Vec3], a: &Pose, b: &Pose) -> f32 {
    points.iter().map(|p| (a.apply(*p) - b.apply(*p)).length()).fold(0.0, f32::max) * 1000.0
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
        let pts: Vec<Vec3> = (0..8).map(|i| Vec3::new(if i & 1 == 0 { -h } else { h }, if i & 2 == 0 { -h } else { h }, if i & 4 == 0 { -h } else { h })).collect();
        let start = [Pose { rotation: Quat::IDENTITY, translation: Vec3::new(0.0, 0.0, 0.05) }];
        let (rest, stats) = settle(&[BodySpec { hull_points: &pts, mass_kg: 0.1 }], &start, &PhysicsParams::default());
        assert!(stats.converged, "{stats:?}");
        assert!((rest[0].translation.z - h).abs() < 1e-3, "rests at z = {}", rest[0].translation.z);
    }
}
