//! Random scene composition: which objects, what they are made of, where they start, and the
//! relation between two of them that makes the t = 1 removal interesting ([`Event`]).
//!
//! [`sample`] is the stacked family: one pair is always a **stack**, an upside-down tumbler or
//! bowl (its base is then a flat top) with a tumbler, wine glass or bottle standing on it, as in
//! the reference `seq_101`/`seq_105`. The other objects stand on the table around it, placed by
//! rejection sampling so that their footprints (circumscribed circles plus [`CLEARANCE_M`]) do
//! not overlap. Each object starts [`DROP_GAP_M`] above its support and is settled by
//! [`crate::physics`]. The containers family ([`crate::containers`]) reuses the pieces here.

use crate::material::{Material, Texture};
use crate::physics::{CERAMIC_DENSITY, GLASS_DENSITY, Plate, Pose};
use crate::scene::{AreaLight, Background, Environment, Table};
use crate::shapes::{Model, ShapeKind, build};
use glam::Quat;
use rand::RngExt;
use serde::Serialize;

/// Gap between footprints of neighbouring objects at placement (m).
pub const CLEARANCE_M: f32 = 0.012;
/// Objects start this far above what they will rest on (m): short drops settle fast.
pub const DROP_GAP_M: f32 = 0.0005;
/// Radius of the disc the non-stacked objects are placed in (m).
pub const PLACEMENT_RADIUS_M: f32 = 0.17;
/// Probability that a non-stacked object is glass (the rest are glazed, opaque).
pub const GLASS_PROBABILITY: f64 = 0.7;

/// How an object starts (`initial_mode` in `sequence.json`, as in the reference data).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Orientation {
    /// Standing on its base, opening up.
    Upright,
    /// Upside down, resting on its rim.
    Inverted,
    /// On its side, axis (nearly) horizontal.
    Lying,
    /// Foot on the table, leaning against another object.
    Tilted,
}

/// One object of the scene.
#[derive(Clone, Debug)]
pub struct ObjectSpec {
    /// 1-based, stable across both states.
    pub id: u32,
    pub model: Model,
    pub material: Material,
    pub mass_kg: f32,
    pub orientation: Orientation,
    /// Support plate for the physics (set on the object others are stacked on).
    pub plate: Plate,
}

/// How the supported object of the t = 1 event rests on its support at t = 0.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum RelationKind {
    /// Standing on the support's flat top.
    Stack,
    /// Foot on the table, side against the support.
    Lean,
}

impl RelationKind {
    /// The name written to `sequence.json`.
    pub fn name(self) -> &'static str {
        match self {
            RelationKind::Stack => "stack",
            RelationKind::Lean => "lean",
        }
    }
}

/// The pair whose separation at t = 1 makes the removal interesting: `support` is removed,
/// `supported` loses what held it. Indices into [`Layout::objects`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Event {
    pub kind: RelationKind,
    pub support: usize,
    pub supported: usize,
}

/// The composed scene before physics.
#[derive(Clone, Debug)]
pub struct Layout {
    pub objects: Vec<ObjectSpec>,
    pub start: Vec<Pose>,
    pub event: Event,
    pub env: Environment,
}

pub(crate) fn color(rng: &mut impl rand::Rng, lo: f32, hi: f32) -> [f32; 3] {
    [
        rng.random_range(lo..hi),
        rng.random_range(lo..hi),
        rng.random_range(lo..hi),
    ]
}

pub(crate) fn glass(rng: &mut impl rand::Rng) -> Material {
    Material::Glass {
        ior: rng.random_range(1.45..1.55),
        tint: color(rng, 0.9, 1.0),
    }
}

pub(crate) fn glazed(rng: &mut impl rand::Rng) -> Material {
    // A saturated colour: one channel strong, the others random.
    let mut c = color(rng, 0.08, 0.6);
    c[rng.random_range(0..3usize)] = rng.random_range(0.6..0.85);
    Material::Glazed { color: c }
}

pub(crate) fn environment(rng: &mut impl rand::Rng) -> Environment {
    let texture = match rng.random_range(0..4u32) {
        0 => Texture::Plain {
            color: color(rng, 0.3, 0.75),
        },
        1 => Texture::Checker {
            a: color(rng, 0.5, 0.8),
            b: color(rng, 0.1, 0.35),
            size: rng.random_range(0.02..0.05),
        },
        2 => Texture::Marble {
            base: color(rng, 0.65, 0.85),
            vein: color(rng, 0.15, 0.4),
            frequency: rng.random_range(30.0..60.0),
        },
        _ => Texture::Wood {
            light: [0.62, 0.42, 0.24],
            dark: [0.33, 0.19, 0.09],
            ring_spacing: rng.random_range(0.006..0.012),
        },
    };
    let background = if rng.random_bool(0.5) {
        Background::Sky {
            horizon: color(rng, 0.6, 0.85),
            zenith: color(rng, 0.35, 0.6),
        }
    } else {
        Background::Wall {
            color: color(rng, 0.2, 0.7),
        }
    };
    let centre: [f32; 3] = [
        rng.random_range(-0.3..0.3),
        rng.random_range(-0.3..0.3),
        rng.random_range(0.9..1.1),
    ];
    let half = rng.random_range(0.2..0.35);
    // Radiance such that the table centre receives E/π ≈ 0.8 (a well exposed diffuse surface):
    // E = L A cos²θ / r², cosθ = z / r.
    let r2 = centre[0] * centre[0] + centre[1] * centre[1] + centre[2] * centre[2];
    let cos = centre[2] / r2.sqrt();
    let radiance = 0.8 * std::f32::consts::PI * r2 / (4.0 * half * half * cos * cos);
    Environment {
        table: Table {
            half_size_m: 0.5,
            texture,
        },
        background,
        light: AreaLight {
            centre_m: centre,
            half_size_m: half,
            radiance,
        },
        ambient: 0.22,
    }
}

fn make_object(
    id: u32,
    kind: ShapeKind,
    material: Material,
    orientation: Orientation,
    rng: &mut impl rand::Rng,
    slices: u32,
) -> ObjectSpec {
    object_of(id, build(kind, rng, slices), material, orientation)
}

/// An object from a built model: its mass is the mesh volume times the material's density.
pub(crate) fn object_of(
    id: u32,
    model: Model,
    material: Material,
    orientation: Orientation,
) -> ObjectSpec {
    let density = if material.is_transparent() {
        GLASS_DENSITY
    } else {
        CERAMIC_DENSITY
    };
    let mass_kg = model.mesh.volume() * density;
    ObjectSpec {
        id,
        model,
        material,
        mass_kg,
        orientation,
        plate: Plate::None,
    }
}

/// Rotation of an upright or upside-down object: yaw about z, flipped about x when inverted.
pub(crate) fn orientation_quat(o: Orientation, yaw: f32) -> Quat {
    let flip = match o {
        Orientation::Inverted => Quat::from_rotation_x(std::f32::consts::PI),
        Orientation::Upright | Orientation::Lying | Orientation::Tilted => Quat::IDENTITY,
    };
    Quat::from_rotation_z(yaw) * flip
}

/// Lowest and highest world z of a model under a rotation.
pub(crate) fn z_range(m: &Model, q: Quat) -> (f32, f32) {
    m.mesh
        .points()
        .map(|p| (q * p).z)
        .fold((f32::MAX, f32::MIN), |(lo, hi), z| (lo.min(z), hi.max(z)))
}

/// Footprint radius: largest horizontal distance of a vertex from the model origin.
pub(crate) fn footprint(m: &Model) -> f32 {
    m.mesh
        .points()
        .map(|p| p.truncate().length())
        .fold(0.0, f32::max)
}

/// Rejection sampling of a footprint centre in the placement disc: a uniform point in the disc
/// whose circle of radius `r` clears every `placed` circle by [`CLEARANCE_M`]; after every 100
/// failures the disc grows by [`PLACEMENT_RADIUS_M`], and after 400 the last candidate is kept.
pub(crate) fn place_in_disc(
    rng: &mut impl rand::Rng,
    placed: &[(glam::Vec2, f32)],
    r: f32,
) -> glam::Vec2 {
    let mut xy = glam::Vec2::ZERO;
    for attempt in 0..400 {
        let rad = PLACEMENT_RADIUS_M * (1.0 + attempt as f32 / 100.0);
        let cand = glam::Vec2::from_angle(rng.random_range(0.0..std::f32::consts::TAU))
            * rad
            * rng.random_range(0.0f32..1.0).sqrt();
        xy = cand;
        if placed
            .iter()
            .all(|(c, rc)| (cand - *c).length() > r + rc + CLEARANCE_M)
        {
            break;
        }
    }
    xy
}

/// Composes a scene of `n` objects (`n ≥ 2`).
pub fn sample(rng: &mut impl rand::Rng, n: u32, slices: u32) -> Layout {
    let env = environment(rng);
    let support_kind = if rng.random_bool(0.6) {
        ShapeKind::Tumbler
    } else {
        ShapeKind::Bowl
    };
    let top_kind =
        [ShapeKind::Tumbler, ShapeKind::WineGlass, ShapeKind::Bottle][rng.random_range(0..3usize)];
    let mut objects = Vec::new();
    let g = glass(rng);
    objects.push(make_object(
        1,
        support_kind,
        g,
        Orientation::Inverted,
        rng,
        slices,
    ));
    objects[0].plate = Plate::OnModelBase;
    let g = glass(rng);
    objects.push(make_object(
        2,
        top_kind,
        g,
        Orientation::Upright,
        rng,
        slices,
    ));
    for id in 3..=n {
        let kind = ShapeKind::ALL[rng.random_range(0..ShapeKind::ALL.len())];
        let material = if rng.random_bool(GLASS_PROBABILITY) {
            glass(rng)
        } else {
            glazed(rng)
        };
        let orientation =
            if matches!(kind, ShapeKind::Tumbler | ShapeKind::Bowl) && rng.random_bool(0.25) {
                Orientation::Inverted
            } else {
                Orientation::Upright
            };
        objects.push(make_object(id, kind, material, orientation, rng, slices));
        if orientation == Orientation::Inverted {
            objects.last_mut().expect("just pushed").plate = Plate::OnModelBase;
        }
    }

    // Stack near the middle; its small lateral offset makes the top object fall sideways later.
    let mut start = Vec::new();
    let mut placed: Vec<(glam::Vec2, f32)> = Vec::new();
    let base_xy = glam::Vec2::new(rng.random_range(-0.04..0.04), rng.random_range(-0.04..0.04));
    let q_support = orientation_quat(
        Orientation::Inverted,
        rng.random_range(0.0..std::f32::consts::TAU),
    );
    let (lo_s, hi_s) = z_range(&objects[0].model, q_support);
    let support_pose = Pose {
        rotation: q_support,
        translation: base_xy.extend(DROP_GAP_M - lo_s),
    };
    start.push(support_pose);
    let q_top = orientation_quat(
        Orientation::Upright,
        rng.random_range(0.0..std::f32::consts::TAU),
    );
    let (lo_t, _) = z_range(&objects[1].model, q_top);
    let offset = glam::Vec2::from_angle(rng.random_range(0.0..std::f32::consts::TAU))
        * rng.random_range(0.0..0.004);
    let support_top = support_pose.translation.z + hi_s;
    start.push(Pose {
        rotation: q_top,
        translation: (base_xy + offset).extend(support_top + DROP_GAP_M - lo_t),
    });
    placed.push((
        base_xy,
        footprint(&objects[0].model).max(footprint(&objects[1].model)),
    ));

    for obj in objects.iter().skip(2) {
        let q = orientation_quat(
            obj.orientation,
            rng.random_range(0.0..std::f32::consts::TAU),
        );
        let (lo, _) = z_range(&obj.model, q);
        let r = footprint(&obj.model);
        let xy = place_in_disc(rng, &placed, r);
        placed.push((xy, r));
        start.push(Pose {
            rotation: q,
            translation: xy.extend(DROP_GAP_M - lo),
        });
    }
    Layout {
        objects,
        start,
        event: Event {
            kind: RelationKind::Stack,
            support: 0,
            supported: 1,
        },
        env,
    }
}
