//! Front fill: closing a hole that training left in a transparent object's front.
//!
//! The object losses ask only that a ray through an object's mask meet *some* opaque surfel of that
//! object; for glass the back wall serves as well as the front. Where a training view's mask is eroded
//! along a convex object's silhouette, its background pixels train the surfels of that strip of the
//! object's front to transparency (and the visual hull they start from is shaved there), and no other
//! view asks them back: every other view sees the strip inside the object and is satisfied by the back
//! wall. A view looking at the strip then sees through the object, its depth the back wall's
//! (BENCHMARKS.md §8).
//!
//! Such a hole shows in the training views themselves. For every interior pixel of an object's mask
//! (stride [`STRIDE`]) the trained model's median depth `d` is compared with the object's visual hull
//! along the pixel's ray, sampled every [`STEP_M`] of camera depth up to [`REACH_M`] in front of `d`.
//! The hull's *material* is the hull outside every carved opening. The ray crossed the object before
//! it stopped when
//! * the median surfel lies at the far end of the hull's material (inside the hull, outside every
//!   carved opening): the material ends within [`EXIT_M`] behind `d`; or inside a carved opening (a
//!   back wall seen through a hole in the front wall);
//! * going back along the ray through the hull (openings included) to where it entered, within
//!   [`REACH_M`], the first material met from the entry (the front) lies more than [`THICKNESS_M`] in
//!   front of `d`: less is within the depth tolerance anyway, and is the scale of the hull's excess
//!   over concave shapes;
//! * the hull 3 mm in front of `d` lies [`ABOVE_BASE_M`] or more above the object's base (the
//!   [`BASE_QUANTILE`] height quantile of its trained surfels above the table), and the front is not
//!   at or above an opening's rim (where a ray from above may pass over the glass into the opening);
//! * the pixel is a pit in the object's depth: the nearest depth of the same object within
//!   [`AROUND_PX`] lies more than [`THICKNESS_M`] in front of `d`, and the front no more than
//!   [`FRONT_SLACK_M`] in front of that.
//!
//! Then a surfel of that object is put at the front (the hull's surface, at most the mask error away
//! from the true one), facing the camera, its σ one stride's footprint, nearly opaque. The object's
//! hull ([`Hull::holds`]) asks the object's channel of at least two views, so that the hull of an
//! object standing on another ends where the other begins.
//!
//! The fill runs once, after training, on the views at their corrected poses; every view is tested
//! against the same trained model, so the result does not depend on the order of the views or the
//! thread count. Where the support prior applies (a narrow baseline) the hull reaches far in front of
//! the objects and the fill is not applied (see `reconstruct`). Several views may fill the same hole;
//! `run.json` counts every surfel added.

use glam::DVec3;
use rayon::prelude::*;
use trand_core::surfels::Surfel;
use trand_core::{Surfels, math::logit, sh::rgb_to_dc};
use trand_render::RenderSettings;

use crate::Result;
use crate::at_cameras::render_with_objects;
use crate::targets::{TrainView, palette};

/// Whether holes in an object's front are filled after training (module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum FrontFill {
    /// Surfels are added at the visual hull's front where a training view sees through an object.
    HullFront,
    /// The trained surfels as they are.
    Off,
}

/// Pixel stride of the tested grid; a filled surfel's σ is one stride's footprint.
pub const STRIDE: usize = 2;
/// Step of the samples along a ray, in camera depth (metres).
pub const STEP_M: f64 = 0.001;
/// How far behind the median depth the hull's material may end for the ray to count as having
/// crossed the object (metres): the hull's back surface lies within a few pixels of the true one.
pub const EXIT_M: f64 = 0.005;
/// How far in front of the median depth the front must lie (metres): a front missed by less is
/// within the depth tolerance anyway, and thin walls are not mistaken for the object's depth.
pub const THICKNESS_M: f64 = 0.025;
/// Half-width of the window whose nearest depth of the same object stands for the front around a
/// tested pixel (pixels).
const AROUND_PX: usize = 12;
/// How far in front of that nearest depth a filled surfel may lie (metres).
const FRONT_SLACK_M: f64 = 0.01;
/// How high above the object's base the median surfel must lie (metres): a surface lower than that,
/// seen through more than [`THICKNESS_M`] of hull, is a foot or a base under an overhang (a wine
/// glass's foot, over which the hull is its bowl's shadow), not a back wall.
pub const ABOVE_BASE_M: f64 = 0.012;
/// The share of an object's surfels below its base.
const BASE_QUANTILE: f64 = 0.01;
/// How far in front of the median depth the ray is sampled (metres).
const REACH_M: f64 = 0.3;
/// Pixels of the same object all around a tested pixel, so that a mask's edge is never tested.
const INTERIOR_PX: isize = 2;
/// Opacity of a filled surfel.
const OPACITY: f32 = 0.9;
/// Object logit of a filled surfel's channel (others 0): probability above 0.95 with 64 channels.
const OBJECT_LOGIT: f32 = 8.0;

/// What the fill reads of the visual hull.
pub trait Hull: Sync {
    /// Inside the visual hull of the training masks, carved openings included, and object channel `c`
    /// in at least two views (so that objects standing on each other are told apart).
    fn holds(&self, p: DVec3, c: u8) -> bool;
    /// Inside an open vessel's carved region (see [`crate::openings::Opening::carves`]).
    fn carved(&self, p: DVec3) -> bool;
    /// At an opening's rim, within a few millimetres under it, or above the opening: a ray entering
    /// the hull there from above may pass over the glass into the opening.
    fn at_rim(&self, p: DVec3) -> bool;
}

/// The surfels that close the holes `surfels` leaves in the fronts of the objects of `views`
/// (cameras as trained), read against `hull`.
pub fn fill(
    surfels: &Surfels,
    views: &[TrainView],
    settings: &RenderSettings,
    hull: &dyn Hull,
) -> Result<Surfels> {
    let mut added = surfels.gather(&[]);
    let bases = object_bases(surfels);
    for v in views {
        let out = render_with_objects(surfels, &v.camera, settings)?;
        if (out.width as usize, out.height as usize) != (v.width, v.height) {
            return Err(crate::PipelineError::Invalid(format!(
                "{}: rendered {}x{} for a {}x{} view",
                v.name, out.width, out.height, v.width, v.height
            )));
        }
        let rows: Vec<Vec<Surfel>> = (0..v.height)
            .into_par_iter()
            .step_by(STRIDE)
            .map(|y| {
                (0..v.width)
                    .step_by(STRIDE)
                    .filter_map(|x| hole_surfel(v, &out.median, (x, y), hull, &bases, surfels))
                    .collect()
            })
            .collect();
        for s in rows.iter().flatten() {
            added.push(s);
        }
    }
    Ok(added)
}

/// Per object channel, the height under which [`BASE_QUANTILE`] of the surfels of that object (its
/// probability above ½, above the table as the object filter keeps them) lie; infinite for a channel
/// with no surfel.
fn object_bases(surfels: &Surfels) -> Vec<f64> {
    let k = surfels.num_objects;
    let mut heights = vec![Vec::new(); k];
    let mut p = vec![0.0f32; k];
    for (i, m) in surfels.means.iter().enumerate() {
        trand_core::math::softmax(&surfels.obj_logits[i * k..(i + 1) * k], &mut p);
        if m[2] <= 0.0 {
            continue;
        }
        if let Some(c) = (1..k).find(|&c| p[c] > 0.5) {
            heights[c].push(m[2] as f64);
        }
    }
    heights
        .into_iter()
        .map(|mut h| {
            if h.is_empty() {
                return f64::INFINITY;
            }
            h.sort_by(f64::total_cmp);
            h[((h.len() - 1) as f64 * BASE_QUANTILE) as usize]
        })
        .collect()
}

/// The nearest median depth of channel `c` within [`AROUND_PX`] of pixel `(x, y)`.
fn nearest_around(v: &TrainView, median: &[f32], x: usize, y: usize, c: u8) -> Option<f64> {
    let (x0, x1) = (
        x.saturating_sub(AROUND_PX),
        (x + AROUND_PX).min(v.width - 1),
    );
    let (y0, y1) = (
        y.saturating_sub(AROUND_PX),
        (y + AROUND_PX).min(v.height - 1),
    );
    (y0..=y1)
        .flat_map(|yy| (x0..=x1).map(move |xx| yy * v.width + xx))
        .filter(|&i| v.labels[i] == c && median[i] > 0.0)
        .map(|i| median[i] as f64)
        .min_by(f64::total_cmp)
}

/// The channel of pixel `(x, y)` when every pixel within [`INTERIOR_PX`] has it too.
fn interior_channel(v: &TrainView, x: usize, y: usize) -> Option<u8> {
    let c = v.labels[y * v.width + x];
    if c == 0 {
        return None;
    }
    let r = INTERIOR_PX;
    for dy in -r..=r {
        for dx in -r..=r {
            let (xx, yy) = (x as isize + dx, y as isize + dy);
            if xx < 0 || yy < 0 || xx >= v.width as isize || yy >= v.height as isize {
                return None;
            }
            if v.labels[yy as usize * v.width + xx as usize] != c {
                return None;
            }
        }
    }
    Some(c)
}

/// The surfel closing the hole at pixel `(x, y)` of `v`, if its ray crossed the object (module docs).
fn hole_surfel(
    v: &TrainView,
    median: &[f32],
    (x, y): (usize, usize),
    hull: &dyn Hull,
    bases: &[f64],
    surfels: &Surfels,
) -> Option<Surfel> {
    let c = interior_channel(v, x, y)?;
    let base = *bases.get(c as usize)?;
    let d = median[y * v.width + x] as f64;
    if d <= 0.0 {
        return None;
    }
    // A hole is a pit in the object's depth: the front around it lies far nearer.
    let around = nearest_around(v, median, x, y, c)?;
    if d - around <= THICKNESS_M {
        return None;
    }
    let front = crossed_front(v, (x, y), d, base, hull)?;
    if front < around - FRONT_SLACK_M {
        return None;
    }
    let ray = camera_ray(v, x, y);
    let p = v.camera.center() + ray * front;
    let sigma = STRIDE as f64 * front / v.camera.intrinsics.fx;
    let n = -ray.normalize();
    let i = (y * v.width + x) * 3;
    let rgb = [v.rgb[i], v.rgb[i + 1], v.rgb[i + 2]];
    let pal = palette(c as usize);
    let mut obj_logits = vec![0.0; surfels.num_objects];
    obj_logits[c as usize] = OBJECT_LOGIT;
    Some(Surfel {
        mean: [p.x as f32, p.y as f32, p.z as f32],
        log_scale: [sigma.ln() as f32; 2],
        quat: quat_facing(n),
        opacity_logit: logit(OPACITY),
        sh_dc: rgb.map(rgb_to_dc),
        mask_dc: std::array::from_fn(|j| rgb_to_dc(0.3 * rgb[j] + 0.7 * pal[j])),
        obj_logits,
    })
}

/// The camera depth of the object's front along the ray of pixel `(x, y)` whose median depth is `d`,
/// when the ray crossed the object before it stopped (the first three conditions of the module docs).
fn crossed_front(
    v: &TrainView,
    (x, y): (usize, usize),
    d: f64,
    base: f64,
    hull: &dyn Hull,
) -> Option<f64> {
    let cam = &v.camera;
    let ray = camera_ray(v, x, y);
    // Sample `j` lies `j` steps in front of the median depth (negative: behind it).
    let at = |j: isize| cam.center() + ray * (d - j as f64 * STEP_M);
    let c = v.labels[y * v.width + x];
    let holds = |j: isize| hull.holds(at(j), c);
    let material = |j: isize| holds(j) && !hull.carved(at(j));
    let exit = (EXIT_M / STEP_M).ceil() as isize;
    let reach = ((d - STEP_M).min(REACH_M) / STEP_M).floor() as isize;
    // The median surfel's sample: the hull's back surface may lie a little in front of the surfel.
    let j0 = (0..=3).find(|&j| holds(j))?;
    if at(j0).z < base + ABOVE_BASE_M {
        return None;
    }
    if material(j0) && (-exit..j0).all(material) {
        return None;
    }
    // Back to where the ray entered the hull; the entry must lie within reach.
    let mut entry = j0;
    while entry < reach && holds(entry + 1) {
        entry += 1;
    }
    if entry >= reach {
        return None;
    }
    let front = (j0..=entry).rev().find(|&j| material(j))?;
    let t = d - front as f64 * STEP_M;
    (d - t > THICKNESS_M && !hull.at_rim(at(front))).then_some(t)
}

/// The ray through pixel `(x, y)` of `v`, scaled to unit camera depth (world frame).
fn camera_ray(v: &TrainView, x: usize, y: usize) -> DVec3 {
    let k = &v.camera.intrinsics;
    v.camera.rotation().transpose()
        * DVec3::new((x as f64 - k.cx) / k.fx, (y as f64 - k.cy) / k.fy, 1.0)
}

/// A unit quaternion `(w, x, y, z)` turning the surfel's normal (its local z axis) onto `n`.
fn quat_facing(n: DVec3) -> [f32; 4] {
    // The shortest arc from z to n; glam turns n = −z about an axis perpendicular to z.
    let q = glam::DQuat::from_rotation_arc(DVec3::Z, n.normalize());
    [q.w as f32, q.x as f32, q.y as f32, q.z as f32]
}

#[cfg(test)]
mod tests {
    use super::*;
    use trand_core::{Camera, Intrinsics};

    /// A glass of radius 4 cm from z = 0 to 10 cm about the z axis; `open` carves its inside (walls
    /// 5 mm) above a 1 cm base, with the rim at 10 cm and [`Hull::at_rim`] above `rim_from`.
    struct Cylinder {
        open: bool,
        rim_from: f64,
    }

    impl Hull for Cylinder {
        fn holds(&self, p: DVec3, c: u8) -> bool {
            c == 1 && p.truncate().length() <= 0.04 && (0.0..=0.1).contains(&p.z)
        }
        fn carved(&self, p: DVec3) -> bool {
            self.open && p.truncate().length() < 0.035 && p.z > 0.01
        }
        fn at_rim(&self, p: DVec3) -> bool {
            self.open && p.z > self.rim_from
        }
    }

    /// A view of the glass from `eye`, every pixel labelled with the glass.
    fn view(eye: DVec3) -> TrainView {
        let (w, h) = (64, 48);
        let camera = Camera::look_at(
            Intrinsics::centered(60.0, w as u32, h as u32),
            eye,
            DVec3::new(0.0, 0.0, 0.05),
            DVec3::Z,
        );
        let mut v = TrainView::from_ids("v".into(), camera, (w, h), vec![1; w * h]);
        v.rgb = vec![0.5; w * h * 3];
        v.grey = vec![0.5; w * h];
        v.labels = vec![1; w * h];
        v
    }

    /// The camera depths where the centre pixel's ray enters and leaves the glass's hull.
    fn crossings(v: &TrainView, hull: &Cylinder) -> (f64, f64) {
        let (x, y) = (v.width / 2, v.height / 2);
        let ray = camera_ray(v, x, y);
        let inside: Vec<f64> = (1..2000)
            .map(|k| k as f64 * 1e-3)
            .filter(|&t| hull.holds(v.camera.center() + ray * t, 1))
            .collect();
        (inside[0], *inside.last().unwrap())
    }

    #[test]
    fn a_median_on_the_back_wall_of_a_closed_object_is_filled_at_its_front() {
        let hull = Cylinder {
            open: false,
            rim_from: 0.095,
        };
        let v = view(DVec3::new(0.5, 0.0, 0.05));
        let (near, far) = crossings(&v, &hull);
        let (x, y) = (v.width / 2, v.height / 2);
        let front = crossed_front(&v, (x, y), far - 0.001, 0.0, &hull).expect("seen through");
        assert!(
            (front - near).abs() < 2.0 * STEP_M,
            "{front} against {near}"
        );
        // The front itself is no hole, nor is a surface inside the object short of its back.
        assert_eq!(crossed_front(&v, (x, y), near + 0.001, 0.0, &hull), None);
        assert_eq!(
            crossed_front(&v, (x, y), 0.5 * (near + far), 0.0, &hull),
            None
        );
    }

    #[test]
    fn the_back_wall_seen_through_an_open_glass_s_front_wall_is_filled_at_the_front_wall() {
        let hull = Cylinder {
            open: true,
            rim_from: 0.095,
        };
        let v = view(DVec3::new(0.5, 0.0, 0.05));
        let (near, far) = crossings(&v, &hull);
        let (x, y) = (v.width / 2, v.height / 2);
        // The inner face of the back wall lies in the wall band, the band ends at the hull.
        let front = crossed_front(&v, (x, y), far - 0.004, 0.0, &hull).expect("seen through");
        assert!(
            (front - near).abs() < 2.0 * STEP_M,
            "{front} against {near}"
        );
        // A surfel left inside the opening counts as behind the front wall too.
        let front =
            crossed_front(&v, (x, y), 0.5 * (near + far), 0.0, &hull).expect("seen through");
        assert!((front - near).abs() < 2.0 * STEP_M);
    }

    #[test]
    fn looking_into_an_opening_from_above_is_no_hole() {
        let hull = Cylinder {
            open: true,
            rim_from: 0.095,
        };
        let v = view(DVec3::new(0.0, 0.001, 0.6));
        let (near, _) = crossings(&v, &hull);
        let (x, y) = (v.width / 2, v.height / 2);
        // A surfel floating in the opening, 5 cm under the top: only the opening lies in front of it,
        // whether or not the rim's band is told apart.
        assert_eq!(crossed_front(&v, (x, y), near + 0.05, 0.0, &hull), None);
        let no_band = Cylinder {
            open: true,
            rim_from: f64::INFINITY,
        };
        assert_eq!(crossed_front(&v, (x, y), near + 0.05, 0.0, &no_band), None);
        // Nor is the glass's bottom, seen from above through the opening.
        let bottom = near + 0.09;
        assert_eq!(
            crossed_front(&v, (x, y), bottom + 0.001, 0.0, &no_band),
            None
        );
        // Closed, the same surfel lies inside the material, short of its back: no hole either.
        let closed = Cylinder {
            open: false,
            rim_from: f64::INFINITY,
        };
        assert_eq!(crossed_front(&v, (x, y), near + 0.05, 0.0, &closed), None);
    }

    #[test]
    fn a_surface_at_the_object_s_base_is_not_taken_for_a_back_wall() {
        let hull = Cylinder {
            open: false,
            rim_from: 0.095,
        };
        let v = view(DVec3::new(0.0, 0.001, 0.6));
        let (near, far) = crossings(&v, &hull);
        let (x, y) = (v.width / 2, v.height / 2);
        // From above, the hull's last sample is its bottom at the table: a foot under an overhang.
        assert!(far - near > THICKNESS_M);
        assert_eq!(crossed_front(&v, (x, y), far - 0.001, 0.0, &hull), None);
    }

    #[test]
    fn an_object_s_base_is_its_lowest_surfels_and_unlabelled_surfels_count_for_none() {
        let mut s = Surfels::new(0, 3).unwrap();
        let put = |s: &mut Surfels, z: f32, logits: Vec<f32>| {
            s.push(&Surfel {
                mean: [0.0, 0.0, z],
                log_scale: [-5.0; 2],
                quat: [1.0, 0.0, 0.0, 0.0],
                opacity_logit: 0.0,
                sh_dc: [0.0; 3],
                mask_dc: [0.0; 3],
                obj_logits: logits,
            })
        };
        for k in 0..200 {
            put(&mut s, 0.04 + 0.001 * k as f32, vec![0.0, 8.0, 0.0]);
        }
        // Undecided surfels (no channel above ½), background ones and those under the table lie
        // lower but do not count.
        put(&mut s, 0.0, vec![0.0, 0.0, 0.0]);
        put(&mut s, 0.001, vec![8.0, 0.0, 0.0]);
        put(&mut s, -0.01, vec![0.0, 8.0, 0.0]);
        let b = object_bases(&s);
        assert!((b[1] - 0.041).abs() < 1e-6, "{b:?}");
        assert!(b[2].is_infinite());
    }

    #[test]
    fn a_pixel_s_ray_at_camera_depth_t_projects_back_onto_the_pixel_at_depth_t() {
        // Off-centre pixels of a camera looking down at an angle: a ray wrong in its axes, its
        // sign or its scale would land elsewhere.
        let v = view(DVec3::new(0.3, -0.2, 0.4));
        for (x, y) in [(0, 0), (63, 0), (5, 40), (40, 17)] {
            let p = v.camera.center() + camera_ray(&v, x, y) * 0.37;
            let (u, w, z) = v.camera.project(p).expect("in front of the camera");
            assert!(
                (u - x as f64).abs() < 1e-9 && (w - y as f64).abs() < 1e-9,
                "({x}, {y}) → ({u}, {w})"
            );
            assert!((z - 0.37).abs() < 1e-12, "depth {z}");
        }
    }

    #[test]
    fn quat_facing_turns_the_local_normal_onto_the_target() {
        for n in [
            DVec3::Z,
            -DVec3::Z,
            DVec3::X,
            DVec3::new(0.3, -0.5, 0.8).normalize(),
            DVec3::new(-0.1, 0.2, -0.97).normalize(),
        ] {
            let q = quat_facing(n).map(|c| c as f64);
            let (r, _) = trand_core::math::quat_to_rotmat(q).expect("unit quaternion");
            let col = DVec3::new(r[0][2], r[1][2], r[2][2]);
            assert!((col - n).length() < 1e-6, "{n} → {col}");
        }
    }
}
