//! Procedural glassware as closed triangle meshes.
//!
//! Every vessel is a **surface of revolution** (a lathe): a 2D profile `(r, z)` that starts on the
//! axis at the bottom, runs up the outside wall, over a rounded rim and back down the inside wall
//! (offset inwards by the wall thickness), and ends on the axis at the top of the base. Revolving
//! a profile that starts and ends on the axis gives a closed, outward-facing surface, so the ray
//! tracer can tell "entering glass" from "leaving glass" by the sign of the geometric normal.
//!
//! Normals: each profile segment gets its own ring of vertices. At a profile vertex where the
//! turn between the two adjacent segments is below [`SMOOTH_ANGLE_DEG`] the two segment normals
//! are averaged (smooth glass walls refract smoothly); sharper turns keep a crease.
//!
//! The mug's handle is a separate closed tube (a torus arc) whose ends are buried in the wall.
//! Models are [`trand_core::Mesh`]es with per-vertex normals, centred on their axis-aligned
//! bounding box, in metres.

use glam::{Vec2, Vec3};
use rand::RngExt;
use serde::Serialize;
use std::f32::consts::{FRAC_PI_2, PI, TAU};
use trand_core::Mesh;

/// Profile turns below this angle are shaded smoothly; above it they keep a crease (rim edges,
/// base corners). 35° keeps the 10-20 segment arcs smooth while the wall/base corner stays sharp.
pub const SMOOTH_ANGLE_DEG: f32 = 35.0;

/// Revolves a closed profile about the z axis. `profile` runs from the axis (r = 0) to the axis;
/// with the outside wall traversed upwards first, triangles face outwards.
pub fn lathe(profile: &[Vec2], slices: u32) -> Mesh {
    let n = profile.len();
    assert!(n >= 2 && slices >= 3);
    // 2D outward normal of each segment: for a profile walked counter-clockwise in the (r, z)
    // half-plane the outward side is the right-hand side, (dz, −dr).
    let seg_normal: Vec<Vec2> = profile
        .windows(2)
        .map(|w| {
            let d = w[1] - w[0];
            Vec2::new(d.y, -d.x).normalize_or_zero()
        })
        .collect();
    let cos_smooth = SMOOTH_ANGLE_DEG.to_radians().cos();
    let vertex_normal = |seg: usize, at_end: bool| -> Vec2 {
        let own = seg_normal[seg];
        let neighbour = if at_end {
            seg_normal.get(seg + 1)
        } else {
            seg.checked_sub(1).map(|s| &seg_normal[s])
        };
        match neighbour {
            Some(nb) if own.dot(*nb) > cos_smooth => (own + *nb).normalize_or_zero(),
            _ => own,
        }
    };
    let mut mesh = Mesh::default();
    for (s, w) in profile.windows(2).enumerate() {
        let (p0, p1) = (w[0], w[1]);
        if (p1 - p0).length() < 1e-9 {
            continue;
        }
        let (n0, n1) = (vertex_normal(s, false), vertex_normal(s, true));
        let base = mesh.vertices.len() as u32;
        for k in 0..=slices {
            let phi = TAU * (k % slices) as f32 / slices as f32;
            let (sn, cs) = phi.sin_cos();
            for (p, nn) in [(p0, n0), (p1, n1)] {
                mesh.vertices.push([p.x * cs, p.x * sn, p.y]);
                mesh.normals.push(
                    Vec3::new(nn.x * cs, nn.x * sn, nn.y)
                        .normalize_or_zero()
                        .to_array(),
                );
            }
        }
        for k in 0..slices {
            let (a0, a1) = (base + 2 * k, base + 2 * k + 1);
            let (b0, b1) = (base + 2 * (k + 1), base + 2 * (k + 1) + 1);
            // Quad (a0, b0, b1, a1); skip the triangle that collapses on the axis.
            if p0.x > 1e-9 {
                mesh.faces.push([a0, b0, b1]);
            }
            if p1.x > 1e-9 {
                mesh.faces.push([a0, b1, a1]);
            }
        }
    }
    mesh
}

/// Appends a circular arc (centre `c`, radius `rad`, from angle `a0` to `a1`, `steps` segments,
/// excluding the start point) to a profile.
fn arc(profile: &mut Vec<Vec2>, c: Vec2, rad: f32, a0: f32, a1: f32, steps: u32) {
    for i in 1..=steps {
        let a = a0 + (a1 - a0) * i as f32 / steps as f32;
        profile.push(c + rad * Vec2::new(a.cos(), a.sin()));
    }
}

/// Builds a thick-walled vessel profile from its outer wall `outer` (bottom corner first, rim
/// last, r > 0): axis → outer wall → half-round rim of diameter `wall` → inner wall (the outer
/// wall offset inwards by `wall` along its normals, kept above the base) → axis at `z = base`.
fn shell(outer: &[Vec2], wall: f32, base: f32) -> Vec<Vec2> {
    let mut p = vec![Vec2::new(0.0, 0.0)];
    p.extend_from_slice(outer);
    let m = outer.len();
    let normal_at = |i: usize| -> Vec2 {
        let d = outer[(i + 1).min(m - 1)] - outer[i.saturating_sub(1)];
        Vec2::new(d.y, -d.x).normalize_or_zero()
    };
    let inner: Vec<Vec2> = (1..m).map(|i| outer[i] - wall * normal_at(i)).collect();
    let (rim_o, rim_i) = (outer[m - 1], inner[m - 2]);
    let c = 0.5 * (rim_o + rim_i);
    let start = (rim_o - c).to_angle();
    arc(
        &mut p,
        c,
        0.5 * (rim_o - rim_i).length(),
        start,
        start + PI,
        8,
    );
    p.pop(); // the arc's last point is the inner rim itself, pushed below
    let mut last_r = rim_i.x;
    for q in inner.iter().rev() {
        if q.y <= base {
            break;
        }
        p.push(*q);
        last_r = q.x;
    }
    p.push(Vec2::new(last_r, base));
    p.push(Vec2::new(0.0, base));
    p
}

/// A straight (possibly tapered) wall from `(r0, z0)` to `(r1, z1)` in `steps` segments, with
/// the bottom corner rounded by `round` (a quarter circle).
fn straight_wall(r0: f32, r1: f32, height: f32, round: f32, steps: u32) -> Vec<Vec2> {
    let mut w = vec![Vec2::new(r0 - round, 0.0)];
    arc(
        &mut w,
        Vec2::new(r0 - round, round),
        round,
        -FRAC_PI_2,
        0.0,
        4,
    );
    for i in 1..=steps {
        let s = i as f32 / steps as f32;
        w.push(Vec2::new(r0 + (r1 - r0) * s, round + (height - round) * s));
    }
    w
}

/// The kinds of object the generator can build.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ShapeKind {
    Tumbler,
    WineGlass,
    Bottle,
    Bowl,
    Mug,
    Sphere,
}

impl ShapeKind {
    /// Every kind, in declaration order.
    pub const ALL: [ShapeKind; 6] = [
        ShapeKind::Tumbler,
        ShapeKind::WineGlass,
        ShapeKind::Bottle,
        ShapeKind::Bowl,
        ShapeKind::Mug,
        ShapeKind::Sphere,
    ];
}

/// A built object model: mesh (centred), its kind and the parameters it was built from.
#[derive(Clone, Debug)]
pub struct Model {
    pub kind: ShapeKind,
    pub mesh: Mesh,
    /// Named dimensions in metres (reported in `sequence.json` as `params_m`).
    pub params: Vec<(&'static str, f32)>,
    /// Points whose convex hull is the collision shape (same frame as `mesh`), see
    /// [`collision_points`].
    pub hull_points: Vec<Vec3>,
}

/// Angular samples of the collision hull. Few, clean hull vertices keep rapier's contact
/// manifolds stable: hulls of the full render mesh (thousands of nearly coplanar points) made
/// resting glasses creep across the table.
pub const HULL_SLICES: u32 = 24;
/// Profile-hull vertices closer than this to the line through their neighbours are dropped
/// (metres). Rims and rounded base corners otherwise leave rings of points within 0.1 mm of the
/// resting face, whose sliver faces jitter the contact normal and make objects walk.
pub const HULL_SIMPLIFY_M: f32 = 3e-4;

/// Removes polygon vertices within `tol` of the chord between their neighbours, repeatedly
/// (closed polygon, counter-clockwise), except those in `pinned`.
fn simplify_closed(mut poly: Vec<Vec2>, tol: f32, pinned: &[Vec2]) -> Vec<Vec2> {
    loop {
        let n = poly.len();
        if n <= 3 {
            return poly;
        }
        let Some(flattest) = (0..n)
            .filter(|&i| !pinned.contains(&poly[i]))
            .map(|i| {
                let (a, p, b) = (poly[(i + n - 1) % n], poly[i], poly[(i + 1) % n]);
                let ab = b - a;
                (i, (p - a).perp_dot(ab).abs() / ab.length().max(1e-12))
            })
            .min_by(|x, y| x.1.total_cmp(&y.1))
        else {
            return poly;
        };
        if flattest.1 >= tol {
            return poly;
        }
        poly.remove(flattest.0);
    }
}

/// The outermost vertices (largest `|x|`) of the lowest and of the highest row of a polygon:
/// the rims of the faces an object stands on upright or upside down.
fn extreme_corners(poly: &[Vec2]) -> Vec<Vec2> {
    let (lo, hi) = poly.iter().fold((f32::MAX, f32::MIN), |(lo, hi), p| {
        (lo.min(p.y), hi.max(p.y))
    });
    let mut corners = Vec::new();
    for y in [lo, hi] {
        let row = poly.iter().filter(|p| p.y == y);
        let widest = row.clone().map(|p| p.x.abs()).fold(0.0, f32::max);
        corners.extend(row.filter(|p| p.x.abs() == widest));
    }
    corners
}

/// 2D convex hull (Andrew's monotone chain), counter-clockwise.
fn hull_2d(mut pts: Vec<Vec2>) -> Vec<Vec2> {
    pts.sort_by(|a, b| a.x.total_cmp(&b.x).then(a.y.total_cmp(&b.y)));
    pts.dedup();
    if pts.len() < 3 {
        return pts;
    }
    let cross = |o: Vec2, a: Vec2, b: Vec2| (a - o).perp_dot(b - o);
    let mut h: Vec<Vec2> = Vec::with_capacity(2 * pts.len());
    for pass in 0..2 {
        let start = h.len();
        let iter: Box<dyn Iterator<Item = &Vec2>> = if pass == 0 {
            Box::new(pts.iter())
        } else {
            Box::new(pts.iter().rev())
        };
        for &p in iter {
            while h.len() >= start + 2 && cross(h[h.len() - 2], h[h.len() - 1], p) <= 1e-12 {
                h.pop();
            }
            h.push(p);
        }
        h.pop();
    }
    h
}

/// How the revolved collision polygon sits against the round surface it stands for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HullFit {
    /// Ring vertices on the profile radius `r`: the polygon's faces lie up to
    /// `r (1 − cos(π/n))` inside the surface (0.26 mm at r = 3 cm, n = 24), which is harmless
    /// for objects standing on flat faces.
    Inscribed,
    /// Ring vertices at `r / cos(π/n)`: every face touches the surface (apothem `r`), so the
    /// render mesh does not poke out of its hull sideways; and the simplification keeps the
    /// outer corners of the base and the top (`extreme_corners`), so it does not poke out
    /// below either. Objects that rest on their round side (lying, leaning) need it, or their
    /// glass would sink into the table or their support.
    Circumscribed,
}

/// Collision points of a lathed profile: the 2D hull of the profile (together with its mirror
/// image across the axis, so the hull is that of the solid of revolution), revolved with
/// [`HULL_SLICES`] samples placed as `fit` says, plus every 4th point of any extra part (the mug
/// handle).
pub fn collision_points(profile: &[Vec2], extra: Option<&Mesh>, fit: HullFit) -> Vec<Vec3> {
    let ring_scale = match fit {
        HullFit::Inscribed => 1.0,
        HullFit::Circumscribed => 1.0 / (PI / HULL_SLICES as f32).cos(),
    };
    let mirrored: Vec<Vec2> = profile
        .iter()
        .flat_map(|p| [*p, Vec2::new(-p.x, p.y)])
        .collect();
    let mut pts = Vec::new();
    let hull = hull_2d(mirrored);
    let pinned = match fit {
        HullFit::Inscribed => Vec::new(),
        HullFit::Circumscribed => extreme_corners(&hull),
    };
    for q in simplify_closed(hull, HULL_SIMPLIFY_M, &pinned)
        .into_iter()
        .filter(|q| q.x >= 0.0)
    {
        if q.x < 1e-9 {
            pts.push(Vec3::new(0.0, 0.0, q.y));
            continue;
        }
        let r = q.x * ring_scale;
        for k in 0..HULL_SLICES {
            let phi = TAU * k as f32 / HULL_SLICES as f32;
            pts.push(Vec3::new(r * phi.cos(), r * phi.sin(), q.y));
        }
    }
    if let Some(e) = extra {
        pts.extend(e.points().step_by(4));
    }
    pts
}

/// Samples a model of `kind` with random proportions (lengths in metres, like real glassware)
/// and an inscribed collision hull ([`HullFit::Inscribed`]).
pub fn build(kind: ShapeKind, rng: &mut impl rand::Rng, slices: u32) -> Model {
    build_fitted(kind, rng, slices, HullFit::Inscribed)
}

/// [`build`] with a chosen collision-hull fit.
pub fn build_fitted(kind: ShapeKind, rng: &mut impl rand::Rng, slices: u32, fit: HullFit) -> Model {
    let mut u = |a: f32, b: f32| rng.random_range(a..b);
    let (profile, mut params, extra) = match kind {
        ShapeKind::Tumbler => {
            let (rb, h, wall) = (u(0.026, 0.032), u(0.07, 0.095), u(0.0018, 0.003));
            let rt = rb + u(0.0, 0.006);
            let base = u(0.006, 0.011);
            let outer = straight_wall(rb, rt, h, 0.002, 6);
            (
                shell(&outer, wall, base),
                vec![
                    ("R_bottom", rb),
                    ("R_top", rt),
                    ("height", h),
                    ("wall", wall),
                    ("base", base),
                ],
                None,
            )
        }
        ShapeKind::Bowl => {
            let (rf, r, h, wall) = (
                u(0.022, 0.03),
                u(0.048, 0.06),
                u(0.035, 0.05),
                u(0.0025, 0.0035),
            );
            let mut outer = vec![Vec2::new(rf, 0.0)];
            for i in 1..=14 {
                let a = FRAC_PI_2 * i as f32 / 14.0;
                outer.push(Vec2::new(rf + (r - rf) * a.sin(), h * (1.0 - a.cos())));
            }
            (
                shell(&outer, wall, wall * 1.6),
                vec![("R_foot", rf), ("R_rim", r), ("height", h), ("wall", wall)],
                None,
            )
        }
        ShapeKind::Bottle => {
            let (rb, rn, h, wall) = (
                u(0.024, 0.031),
                u(0.011, 0.014),
                u(0.12, 0.15),
                u(0.0018, 0.0026),
            );
            let hb = h * u(0.5, 0.6);
            let sh = h * 0.2;
            let mut outer = straight_wall(rb, rb, hb, 0.002, 6);
            for i in 1..=10 {
                let s = i as f32 / 10.0;
                let blend = 0.5 - 0.5 * (PI * s).cos();
                outer.push(Vec2::new(rb + (rn - rb) * blend, hb + sh * s));
            }
            for i in 1..=4 {
                outer.push(Vec2::new(rn, hb + sh + (h - hb - sh) * i as f32 / 4.0));
            }
            let base = u(0.004, 0.007);
            (
                shell(&outer, wall, base),
                vec![
                    ("R_body", rb),
                    ("R_neck", rn),
                    ("height", h),
                    ("wall", wall),
                    ("base", base),
                ],
                None,
            )
        }
        ShapeKind::Mug => {
            let (r, h, wall) = (u(0.034, 0.042), u(0.08, 0.1), u(0.003, 0.0045));
            let base = u(0.007, 0.01);
            let outer = straight_wall(r, r, h, 0.003, 6);
            let (tube, major) = (u(0.005, 0.007), h * 0.28);
            let handle = handle_tube(r - 0.5 * wall, h * 0.5, major, tube, slices);
            (
                shell(&outer, wall, base),
                vec![
                    ("R", r),
                    ("height", h),
                    ("wall", wall),
                    ("base", base),
                    ("handle_tube", tube),
                ],
                Some(handle),
            )
        }
        ShapeKind::WineGlass => wine_glass(&mut u),
        ShapeKind::Sphere => {
            let r = u(0.025, 0.035);
            let mut p = vec![Vec2::new(0.0, -r)];
            arc(&mut p, Vec2::ZERO, r, -FRAC_PI_2, FRAC_PI_2, 24);
            (p, vec![("R", r)], None)
        }
    };
    let mut mesh = lathe(&profile, slices);
    let mut hull_points = collision_points(&profile, extra.as_ref(), fit);
    if let Some(h) = extra {
        mesh.append(&h)
            .expect("a lathed model and its handle both carry normals and few vertices");
    }
    let shift = mesh.center_on_bounds();
    for p in &mut hull_points {
        *p += shift;
    }
    params.push(("volume_m3", mesh.volume()));
    Model {
        kind,
        mesh,
        params,
        hull_points,
    }
}

fn wine_glass(
    u: &mut impl FnMut(f32, f32) -> f32,
) -> (Vec<Vec2>, Vec<(&'static str, f32)>, Option<Mesh>) {
    let (rf, rb, wall, stem) = (
        u(0.03, 0.036),
        u(0.03, 0.038),
        u(0.0015, 0.002),
        u(0.003, 0.005),
    );
    let rrim = rb * u(0.8, 0.92);
    let ah = u(0.035, 0.045);
    let hs = u(0.05, 0.07);
    let mut p = vec![Vec2::ZERO, Vec2::new(rf, 0.0), Vec2::new(rf, 0.002)];
    // Foot rises in a gentle cone to the stem.
    for i in 1..=6 {
        let s = i as f32 / 6.0;
        p.push(Vec2::new(
            rf + (stem - rf) * s.sqrt(),
            0.002 + 0.006 * s * s,
        ));
    }
    p.push(Vec2::new(stem, hs));
    // Bowl: an ellipse (semi-axes rb, ah) from where it meets the stem to where r = rrim.
    let phi0 = -(stem / rb).acos();
    let phi1 = (rrim / rb).acos();
    let zc = hs - ah * phi0.sin();
    for i in 1..=20 {
        let a = phi0 + (phi1 - phi0) * i as f32 / 20.0;
        p.push(Vec2::new(rb * a.cos(), zc + ah * a.sin()));
    }
    let top = zc + ah * phi1.sin();
    let (rbi, ahi) = (rb - wall, ah - wall);
    let phi1i = ((rrim - wall) / rbi).acos();
    let zi_top = zc + ahi * phi1i.sin();
    p.push(Vec2::new(rrim - 0.5 * wall, top.max(zi_top) + 0.4 * wall));
    for i in 0..=20 {
        let a = phi1i + (-FRAC_PI_2 - phi1i) * i as f32 / 20.0;
        p.push(Vec2::new((rbi * a.cos()).max(0.0), zc + ahi * a.sin()));
    }
    let params = vec![
        ("R_foot", rf),
        ("R_bowl", rb),
        ("R_rim", rrim),
        ("height", top),
        ("wall", wall),
        ("stem_radius", stem),
    ];
    (p, params, None)
}

/// A mug handle: a tube of radius `tube` along a half torus of radius `major` centred at height
/// `zc`. The open ends are circles in the plane `x = r_mid` (the middle of the mug wall), so they
/// are buried inside the glass and never seen.
fn handle_tube(r_mid: f32, zc: f32, major: f32, tube: f32, slices: u32) -> Mesh {
    let centre = Vec3::new(r_mid, 0.0, zc);
    let (rings, around) = (24u32, (slices / 4).max(8));
    let mut m = Mesh::default();
    for i in 0..=rings {
        let a = -FRAC_PI_2 + PI * i as f32 / rings as f32;
        let c = centre + major * Vec3::new(a.cos(), 0.0, a.sin());
        let (radial, binormal) = (Vec3::new(a.cos(), 0.0, a.sin()), Vec3::Y);
        for k in 0..around {
            let b = TAU * k as f32 / around as f32;
            let n = radial * b.cos() + binormal * b.sin();
            m.vertices.push((c + tube * n).to_array());
            m.normals.push(n.to_array());
        }
    }
    for i in 0..rings {
        for k in 0..around {
            let k1 = (k + 1) % around;
            let (a0, a1, b0, b1) = (
                i * around + k,
                i * around + k1,
                (i + 1) * around + k,
                (i + 1) * around + k1,
            );
            m.faces.push([a0, a1, b1]);
            m.faces.push([a0, b1, b0]);
        }
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn lathe_of_a_closed_profile_has_positive_volume_close_to_the_solid() {
        // A unit-ish cylinder r = 0.03, h = 0.05 revolved from a rectangle profile.
        let p = [
            Vec2::new(0.0, 0.0),
            Vec2::new(0.03, 0.0),
            Vec2::new(0.03, 0.05),
            Vec2::new(0.0, 0.05),
        ];
        let m = lathe(&p, 128);
        let exact = PI * 0.03f32.powi(2) * 0.05;
        assert!(
            (m.volume() - exact).abs() / exact < 2e-3,
            "{} vs {exact}",
            m.volume()
        );
        let c = m.centroid();
        assert!(
            (c - Vec3::new(0.0, 0.0, 0.025)).length() < 1e-6,
            "centroid {c}"
        );
    }

    #[test]
    fn every_shape_is_closed_outward_and_thin_walled() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(3);
        for kind in ShapeKind::ALL {
            let m = build(kind, &mut rng, 48);
            let v = m.mesh.volume();
            let (lo, hi) = m.mesh.bounds();
            let box_v = (hi - lo).x * (hi - lo).y * (hi - lo).z;
            assert!(
                v > 0.0,
                "{kind:?} volume {v} must be positive (outward faces)"
            );
            if kind != ShapeKind::Sphere {
                assert!(
                    v < 0.5 * box_v,
                    "{kind:?} must be hollow: {v} vs box {box_v}"
                );
            }
            assert!((lo + hi).length() < 1e-5, "{kind:?} is centred");
        }
    }
}
