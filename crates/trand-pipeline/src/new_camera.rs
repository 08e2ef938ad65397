//! The new photo's camera, corrected by the objects that did not move.
//!
//! **Why.** A robot takes the t = 1 photo from a pose its kinematics give, a fraction of a degree and
//! a few millimetres off, like the t = 0 ones. Every object the removal cannot have moved
//! ([`crate::contact::may_move`]) is where the t = 0 model has it, so its silhouette from the given
//! camera should cover its new mask; a camera off by half a degree shifts all of them by several
//! pixels the same way. Left alone, the relocalisation puts the fallen objects where the wrong camera
//! sees them, and the single-view refinement drags every object towards the shifted masks.
//!
//! **How.** Each unmoved object's surfels are rendered alone (`α > ½`) at the given camera. The
//! integer pixel shift `(dx, dy)` within [`MAX_SHIFT_PX`] that maximises the mean IoU of the shifted
//! silhouettes with their masks (pixels of other objects' masks not counted against a silhouette:
//! the object may be behind them) is refined by a parabola through its neighbours in x and in y.
//! A shift of the image is a turn of the camera about its centre by `dx / fx` about its y axis and
//! `−dy / fy` about its x axis (to first order; a translation error of a few millimetres at half a
//! metre looks the same). The turn is applied when it raises the mean IoU by at least [`MIN_GAIN`]
//! and lowers no object's IoU by more than [`MAX_LOSS`].
//!
//! **Knocked objects.** A falling object can knock aside one the removal could not have moved. Its
//! silhouette then fits its mask better shifted, as under a camera error, but alone: the shift that
//! suits it makes the objects that did stay fit worse, which a camera's error cannot do; hence the
//! [`MAX_LOSS`] condition. Each object's own best shift is searched too, and an object that fits by
//! [`DISPLACED_GAIN`] better shifted than at the camera used is reported displaced
//! ([`CameraCorrection::displaced`]): the relocalisation searches it like the objects the simulation
//! moved. These fits are computed even when the turn is switched off, against the camera the masks
//! call for, so that a camera's error is not read as every object knocked.

use glam::DMat3;
use trand_core::{Camera, Surfels};
use trand_io::InstanceMap;
use trand_render::{GeometryMaps, Maps, RenderSettings, render};

use crate::Result;
use crate::simulate::channel_members;
use crate::update_options::Stage;

/// Largest shift searched, native pixels (1° at 600 px focal length is 10.5 px).
pub const MAX_SHIFT_PX: i32 = 16;
/// Mean IoU gain below which the camera is kept as given.
pub const MIN_GAIN: f64 = 0.02;
/// The turn is refused when it lowers any one object's IoU by more than this: a camera's error
/// shifts every unmoved object the same way, so its correction cannot make one of them fit worse.
pub const MAX_LOSS: f64 = 0.01;
/// An object whose silhouette, shifted on its own, fits its mask better by this much than at the
/// camera finally used has moved although the removal could not move it (a falling object knocked
/// it aside): [`CameraCorrection::displaced`].
pub const DISPLACED_GAIN: f64 = 0.1;
/// Objects with fewer silhouette or mask pixels than this are left out.
const MIN_PIXELS: usize = 50;

/// What the correction found, as `run.json` reports it.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct CameraCorrection {
    /// Unmoved objects compared.
    pub objects: usize,
    /// The silhouettes' best shift onto their masks (pixels, x right, y down).
    pub shift_px: [f64; 2],
    /// The camera's turn that makes it (degrees).
    pub turn_deg: f64,
    /// Mean IoU of the silhouettes with their masks, as given and shifted.
    pub iou_given: f64,
    pub iou_shifted: f64,
    /// Whether the camera was turned: the turn is on, raises the mean IoU by [`MIN_GAIN`] and lowers
    /// no object's by more than [`MAX_LOSS`] (at the integer shift).
    pub applied: bool,
    /// Each object's fit: as given, at the integer common shift, and at its own best shift.
    pub per_object: Vec<ObjectFit>,
    /// The objects (new mask ids) that moved although the removal could not move them: shifted
    /// alone, their silhouette fits its mask by [`DISPLACED_GAIN`] better than at the camera the
    /// masks call for (the common shift when it passes the two conditions of `applied`, else the
    /// given camera), whether or not the turn is switched on.
    pub displaced: Vec<u16>,
}

/// How one unmoved object's silhouette fits its mask.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct ObjectFit {
    /// Its id in the new masks.
    pub id: u16,
    pub iou_given: f64,
    pub iou_common: f64,
    /// The integer shift that fits this object alone best, and its IoU.
    pub own_shift_px: [i32; 2],
    pub iou_own: f64,
}

/// One unmoved object: its silhouette's pixels at the given camera and its id in the new masks.
struct Silhouette {
    pixels: Vec<(i32, i32)>,
    id: u16,
    mask_size: usize,
}

impl Silhouette {
    /// IoU of the silhouette shifted by `(dx, dy)` with its mask; other objects' pixels are not
    /// counted against it.
    fn iou(&self, inst: &InstanceMap, dx: i32, dy: i32) -> f64 {
        let (w, h) = (inst.width as i32, inst.height as i32);
        let (mut inter, mut extra) = (0usize, 0usize);
        for &(x, y) in &self.pixels {
            let (x, y) = (x + dx, y + dy);
            let v = if x < 0 || y < 0 || x >= w || y >= h {
                0
            } else {
                inst.data[(y * w + x) as usize]
            };
            if v == self.id {
                inter += 1;
            } else if v == 0 {
                extra += 1;
            }
        }
        inter as f64 / (self.mask_size + extra) as f64
    }
}

/// The correction of `camera` from the objects `unmoved` (channel of `surfels`, id in `inst`), and
/// the camera to use (turned only when `correction` is on). `None` when no unmoved object is large
/// enough in both.
pub fn correct(
    surfels: &Surfels,
    unmoved: &[(usize, u16)],
    camera: &Camera,
    inst: &InstanceMap,
    settings: &RenderSettings,
    correction: Stage,
) -> Result<(Camera, Option<CameraCorrection>)> {
    let settings = RenderSettings {
        maps: Maps::Rgb,
        geometry: GeometryMaps::Skipped,
        sh_degree: Some(0),
        ..*settings
    };
    let w = inst.width as i32;
    let mut sils = Vec::new();
    for &(channel, id) in unmoved {
        let idx: Vec<usize> = channel_members(surfels, channel)
            .into_iter()
            .map(|i| i as usize)
            .collect();
        let mask_size = inst.data.iter().filter(|&&v| v == id).count();
        if idx.len() < 3 || mask_size < MIN_PIXELS {
            continue;
        }
        let out = render::<f32, _>(&surfels.gather(&idx), camera, &settings)?;
        let pixels: Vec<(i32, i32)> = (0..out.alpha.len())
            .filter(|&q| out.alpha[q] > 0.5)
            .map(|q| (q as i32 % w, q as i32 / w))
            .collect();
        if pixels.len() >= MIN_PIXELS {
            sils.push(Silhouette {
                pixels,
                id,
                mask_size,
            });
        }
    }
    if sils.is_empty() {
        return Ok((*camera, None));
    }
    let tables = Tables::new(&sils, inst);
    let given = tables.mean(0, 0);
    let (bx, by, top) = argmax(|dx, dy| tables.mean(dx, dy));
    let vertex = |lo: f64, hi: f64| {
        let curve = lo - 2.0 * top + hi;
        if curve < 0.0 {
            (0.5 * (lo - hi) / curve).clamp(-0.5, 0.5)
        } else {
            0.0
        }
    };
    let shift = [
        bx as f64 + vertex(tables.mean(bx - 1, by), tables.mean(bx + 1, by)),
        by as f64 + vertex(tables.mean(bx, by - 1), tables.mean(bx, by + 1)),
    ];
    let per_object: Vec<ObjectFit> = sils
        .iter()
        .enumerate()
        .map(|(k, s)| {
            let (ox, oy, own) = argmax(|dx, dy| tables.of(k, dx, dy));
            ObjectFit {
                id: s.id,
                iou_given: tables.of(k, 0, 0),
                iou_common: tables.of(k, bx, by),
                own_shift_px: [ox, oy],
                iou_own: own,
            }
        })
        .collect();
    let consistent = per_object
        .iter()
        .all(|o| o.iou_common >= o.iou_given - MAX_LOSS);
    // Whether the masks say the camera is off; the objects are judged against that camera even
    // when the turn is switched off, so a camera's error never reads as every object knocked.
    let camera_off = top >= given + MIN_GAIN && consistent;
    let displaced = per_object
        .iter()
        .filter(|o| {
            let now = if camera_off {
                o.iou_common
            } else {
                o.iou_given
            };
            o.iou_own >= now + DISPLACED_GAIN
        })
        .map(|o| o.id)
        .collect();
    let applied = correction == Stage::On && camera_off;
    let k = camera.intrinsics;
    let report = CameraCorrection {
        objects: sils.len(),
        shift_px: shift,
        turn_deg: (shift[0] / k.fx).hypot(shift[1] / k.fy).to_degrees(),
        iou_given: given,
        iou_shifted: top,
        applied,
        per_object,
        displaced,
    };
    let corrected = if applied {
        let turn =
            DMat3::from_rotation_x(-shift[1] / k.fy) * DMat3::from_rotation_y(shift[0] / k.fx);
        Camera::from_glam(k, turn * camera.rotation(), turn * camera.translation())
    } else {
        *camera
    };
    Ok((corrected, Some(report)))
}

/// Reach of the IoU tables: the search covers ±[`MAX_SHIFT_PX`], and the parabola through the best
/// shift's neighbours one pixel more.
const REACH: i32 = MAX_SHIFT_PX + 1;

/// IoU of every silhouette with its mask at every integer shift within ±[`REACH`], row-major over
/// `(dy, dx)`.
struct Tables(Vec<Vec<f64>>);

impl Tables {
    const SIDE: i32 = 2 * REACH + 1;

    fn new(sils: &[Silhouette], inst: &InstanceMap) -> Self {
        Self(
            sils.iter()
                .map(|s| {
                    let mut t = vec![0.0; (Self::SIDE * Self::SIDE) as usize];
                    for dy in -REACH..=REACH {
                        for dx in -REACH..=REACH {
                            t[Self::at(dx, dy)] = s.iou(inst, dx, dy);
                        }
                    }
                    t
                })
                .collect(),
        )
    }

    fn at(dx: i32, dy: i32) -> usize {
        debug_assert!(dx.abs() <= REACH && dy.abs() <= REACH);
        ((dy + REACH) * Self::SIDE + dx + REACH) as usize
    }

    /// Object `k`'s IoU at shift `(dx, dy)`.
    fn of(&self, k: usize, dx: i32, dy: i32) -> f64 {
        self.0[k][Self::at(dx, dy)]
    }

    /// The mean IoU of all objects at shift `(dx, dy)`.
    fn mean(&self, dx: i32, dy: i32) -> f64 {
        let i = Self::at(dx, dy);
        self.0.iter().map(|t| t[i]).sum::<f64>() / self.0.len() as f64
    }
}

/// The integer shift within ±[`MAX_SHIFT_PX`] that maximises `f` and its value; `(0, 0)` unless
/// another shift is strictly better.
fn argmax(f: impl Fn(i32, i32) -> f64) -> (i32, i32, f64) {
    let mut best = (0, 0, f(0, 0));
    for dy in -MAX_SHIFT_PX..=MAX_SHIFT_PX {
        for dx in -MAX_SHIFT_PX..=MAX_SHIFT_PX {
            let v = f(dx, dy);
            if v > best.2 {
                best = (dx, dy, v);
            }
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_scene::{CHANNELS, block, camera, cylinder};
    use glam::DVec3;

    /// The pixel where `camera` sees `p`.
    fn pixel(camera: &Camera, p: DVec3) -> (f64, f64) {
        let (x, y, _) = camera.project(p).unwrap();
        (x, y)
    }

    /// The instance map of `s` (object channel 0 as id 7, channel 1 as id 9) seen by `cam`.
    fn masks(s: &Surfels, cam: &Camera) -> InstanceMap {
        let k = cam.intrinsics;
        let mut ids = vec![0u16; k.num_pixels()];
        for (c, id) in [(0usize, 7u16), (1, 9)] {
            let idx: Vec<usize> = channel_members(s, c)
                .into_iter()
                .map(|i| i as usize)
                .collect();
            let out = render::<f32, _>(&s.gather(&idx), cam, &RenderSettings::default()).unwrap();
            for (v, a) in ids.iter_mut().zip(&out.alpha) {
                if *a > 0.5 {
                    *v = id;
                }
            }
        }
        InstanceMap::from_vec(k.width, k.height, 1, ids).unwrap()
    }

    /// [`correct`] of `camera` for `objects` with the default render settings, and its report.
    fn check(
        s: &Surfels,
        objects: &[(usize, u16)],
        camera: &Camera,
        inst: &InstanceMap,
        correction: Stage,
    ) -> (Camera, CameraCorrection) {
        let (got, report) = correct(
            s,
            objects,
            camera,
            inst,
            &RenderSettings::default(),
            correction,
        )
        .unwrap();
        (got, report.expect("the objects are large enough"))
    }

    fn two_glasses() -> Surfels {
        let mut s = cylinder(-0.05, 0.0, 0);
        s.append(&cylinder(0.06, 0.03, 1));
        assert_eq!(s.num_objects, CHANNELS);
        s
    }

    /// The true camera and one turned 0.8° about its own y axis and 0.5° about x.
    fn true_and_turned() -> (Camera, Camera) {
        let truth = camera();
        let off = DMat3::from_rotation_y(0.8f64.to_radians())
            * DMat3::from_rotation_x(0.5f64.to_radians());
        let given = Camera::from_glam(
            truth.intrinsics,
            off * truth.rotation(),
            off * truth.translation(),
        );
        (truth, given)
    }

    #[test]
    fn a_camera_turned_off_its_pose_is_turned_back_by_the_unmoved_objects() {
        let s = two_glasses();
        let (truth, given) = true_and_turned();
        let inst = masks(&s, &truth);
        let (got, r) = check(&s, &[(0, 7), (1, 9)], &given, &inst, Stage::On);
        assert!(r.applied && r.iou_shifted > r.iou_given + 0.1, "{r:?}");
        assert!(r.displaced.is_empty(), "{r:?}");
        let p = DVec3::new(0.0, 0.0, 0.05);
        let (a, b) = (pixel(&got, p), pixel(&truth, p));
        assert!((a.0 - b.0).hypot(a.1 - b.1) < 0.7, "{a:?} against {b:?}");
    }

    #[test]
    fn with_the_turn_off_a_camera_error_is_kept_and_not_read_as_knocked_objects() {
        let s = two_glasses();
        let (truth, given) = true_and_turned();
        let inst = masks(&s, &truth);
        let (got, r) = check(&s, &[(0, 7), (1, 9)], &given, &inst, Stage::Off);
        assert!(!r.applied && r.iou_shifted > r.iou_given + 0.1, "{r:?}");
        assert_eq!(got.rotation(), given.rotation());
        // Each glass alone gains as much as under the common shift: neither was knocked.
        assert!(
            r.per_object.iter().all(|o| o.iou_own > o.iou_given + 0.1),
            "{r:?}"
        );
        assert!(r.displaced.is_empty(), "{r:?}");
    }

    #[test]
    fn a_glass_knocked_aside_keeps_the_camera_and_is_found_displaced() {
        // A wide box (7) and a glass (9); the new masks see the glass slid 15 mm along x and the
        // camera is exact. Shifting both silhouettes with the glass raises their mean IoU (the
        // box's edges are a small part of it), but makes the box fit worse: no camera error
        // explains the masks.
        let model_with = |glass_x: f32| {
            let mut s = block(-0.16, -0.04, -0.04, 0.04, 0.10, 0);
            s.append(&cylinder(glass_x, 0.03, 1));
            s
        };
        let cam = camera();
        let inst = masks(&model_with(0.075), &cam);
        let (got, r) = check(&model_with(0.06), &[(0, 7), (1, 9)], &cam, &inst, Stage::On);
        assert!(
            !r.applied && r.iou_shifted >= r.iou_given + MIN_GAIN,
            "{r:?}"
        );
        assert_eq!(got.rotation(), cam.rotation());
        assert_eq!(r.displaced, vec![9], "{r:?}");
    }

    #[test]
    fn a_best_shift_at_the_edge_of_the_search_is_refined_within_the_tables() {
        // The glass's mask lies ~19 px to the right of its silhouette: beyond the search, whose
        // best shift is then its edge, and the parabola reads one pixel further.
        let inst = masks(&cylinder(0.0, 0.0, 0), &camera());
        let (_, r) = check(
            &cylinder(-0.06, 0.0, 0),
            &[(0, 7)],
            &camera(),
            &inst,
            Stage::On,
        );
        assert_eq!(r.per_object[0].own_shift_px[0], MAX_SHIFT_PX, "{r:?}");
        assert!(r.shift_px[0] >= MAX_SHIFT_PX as f64 - 0.5, "{r:?}");
    }

    #[test]
    fn a_camera_on_its_pose_is_kept() {
        let s = two_glasses();
        let cam = camera();
        let inst = masks(&s, &cam);
        let (got, r) = check(&s, &[(0, 7), (1, 9)], &cam, &inst, Stage::On);
        assert!(
            !r.applied && r.shift_px[0].abs() < 0.5 && r.shift_px[1].abs() < 0.5,
            "{r:?}"
        );
        assert_eq!(got.rotation(), cam.rotation());
    }
}
