//! Training targets, as the authors' loader builds them (official-code notes §2.5, §3, §7.4):
//!
//! * **RGB**: the photograph with every background pixel (instance id 0) set to the background colour
//!   (black by default), so the surfels only have to explain the objects.
//! * **Colour-coded mask**: `0.3 · rgb + 0.7 · palette[channel]` on object pixels, background black.
//! * **Object map**: one-hot over K channels (channel 0 = background, object `k` → channel `k`).
//!
//! The plain-2DGS baseline ([`Supervision::FullImage`]) fits the unmasked photograph only.
//! Images may be box-downsampled by an integer factor for faster training (`--downsample`): colours are
//! averaged over each block and the instance id is the block's most frequent id, so ids stay exact.

use trand_core::Camera;
use trand_io::View;
use trand_train::config::MaskSnap;

use crate::{PipelineError, Result};

/// What the surfels are fitted to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Supervision {
    /// TRAN-D: masked RGB, colour-coded masks and the one-hot object map.
    ObjectAware,
    /// Plain 2DGS: the whole photograph, no masks.
    FullImage,
}

/// One training view with its targets (row-major, interleaved).
#[derive(Clone, Debug)]
pub struct TrainView {
    pub name: String,
    pub camera: Camera,
    pub width: usize,
    pub height: usize,
    pub rgb: Vec<f32>,
    /// The image in grey (mean of R, G, B in [0, 1]), background included: `rgb` holds the
    /// background colour outside the objects with object supervision, and the table's height is read
    /// from the table ([`crate::table_height`]).
    pub grey: Vec<f32>,
    /// Empty for [`Supervision::FullImage`].
    pub mask: Vec<f32>,
    /// Object channel per pixel (the one-hot target's hot channel, 0 = background); empty for
    /// [`Supervision::FullImage`].
    pub labels: Vec<u8>,
    /// Pixels per channel (`Σ t` of the Dice loss); empty for [`Supervision::FullImage`].
    pub label_counts: Vec<f32>,
    /// Instance id per pixel (after downsampling), each object grown by [`MaskEdges::grow_px`]: what
    /// the losses and the visual-hull initialisation fit.
    pub ids: Vec<u16>,
    /// The instance ids as given (after downsampling). The decisions taken from the masks (the
    /// open-vessel and support priors) read these: their thresholds were measured on masks as a
    /// segmenter gives them, and a grown hull's top and footprint are not an object's.
    pub given_ids: Vec<u16>,
    /// Background pixels left out of the photometric gradients
    /// ([`trand_train::losses::band::background_band`]); empty when none are.
    pub band: Vec<bool>,
}

impl TrainView {
    /// A view of instance ids alone (`ids` row-major over `size` = (width, height), the given ids
    /// the same) with no image, labels or band: what the mask-reading priors look at, and the base
    /// a test builds a view on.
    pub fn from_ids(name: String, camera: Camera, size: (usize, usize), ids: Vec<u16>) -> Self {
        Self {
            name,
            camera,
            width: size.0,
            height: size.1,
            rgb: Vec::new(),
            grey: Vec::new(),
            mask: Vec::new(),
            labels: Vec::new(),
            label_counts: Vec::new(),
            given_ids: ids.clone(),
            ids,
            band: Vec::new(),
        }
    }

    /// [`pixel_index`] in this view's image. The mask-reading tests (visual hull, open-vessel and
    /// support priors) all look a point up this way.
    pub fn pixel_of(&self, p: glam::DVec3) -> Option<usize> {
        pixel_index(&self.camera, (self.width, self.height), p)
    }
}

/// The visual-hull test: whether `q` projects onto an object pixel of `ids(v)` in every view `v` of
/// `views` that sees it, and at least two do.
pub fn in_hull_of<'a>(
    views: impl IntoIterator<Item = &'a TrainView>,
    q: glam::DVec3,
    ids: impl Fn(&'a TrainView) -> &'a [u16],
) -> bool {
    let mut seen = 0;
    for v in views {
        let Some(px) = v.pixel_of(q) else {
            continue;
        };
        if ids(v)[px] == 0 {
            return false;
        }
        seen += 1;
    }
    seen >= 2
}

/// Index of the pixel (row-major, rounded to the nearest centre) of a `w × h` image that `p`
/// projects to through `camera`: `None` behind the camera or outside the image.
pub fn pixel_index(camera: &Camera, (w, h): (usize, usize), p: glam::DVec3) -> Option<usize> {
    let (x, y, _) = camera.project(p)?;
    let (xi, yi) = (x.round(), y.round());
    if xi < 0.0 || yi < 0.0 || xi >= w as f64 || yi >= h as f64 {
        return None;
    }
    Some(yi as usize * w + xi as usize)
}

/// The training views for a coarse level of a [`trand_train::config::ResolutionSchedule`], same order
/// as the training views.
#[derive(Clone, Debug)]
pub struct CoarseViews {
    /// The level's factor in the schedule (the key the trainer looks the views up by).
    pub factor: u32,
    pub views: Vec<TrainView>,
}

/// The views of every level of `schedule` coarser than the training downsampling, for native images of
/// `width × height`: `build_at(factor)` builds the views at a factor (see
/// [`trand_train::config::ResolutionLevel::factor_for`]).
pub fn coarse_views(
    schedule: &trand_train::config::ResolutionSchedule,
    downsample: u32,
    (width, height): (u32, u32),
    build_at: impl Fn(u32) -> Result<Vec<TrainView>>,
) -> Result<Vec<CoarseViews>> {
    schedule
        .coarse_levels(downsample)
        .into_iter()
        .filter_map(|level| {
            let f = level.factor_for(downsample, width, height)?;
            Some(build_at(f).map(|views| CoarseViews {
                factor: level.factor,
                views,
            }))
        })
        .collect()
}

/// Colour of object channel `c` in the colour-coded mask: evenly spaced hues, full saturation, so that
/// any two objects differ in at least one channel by ≥ 0.5. Channel 0 (background) is black.
pub fn palette(c: usize) -> [f32; 3] {
    if c == 0 {
        return [0.0; 3];
    }
    // Golden-ratio hue stepping keeps consecutive ids far apart in hue.
    let h = ((c as f64 - 1.0) * 0.618_033_988_75).fract() * 6.0;
    let x = 1.0 - ((h % 2.0) - 1.0).abs();
    let (r, g, b) = match h as u32 {
        0 => (1.0, x, 0.0),
        1 => (x, 1.0, 0.0),
        2 => (0.0, 1.0, x),
        3 => (0.0, x, 1.0),
        4 => (x, 0.0, 1.0),
        _ => (1.0, 0.0, x),
    };
    [r as f32, g as f32, b as f32]
}

/// `(object id, channel)`: objects in increasing id order get channels 1, 2, …
pub fn channel_map(object_ids: &[u16], num_objects: usize) -> Result<Vec<(u16, usize)>> {
    let mut ids: Vec<u16> = object_ids.iter().copied().filter(|&i| i != 0).collect();
    ids.sort_unstable();
    ids.dedup();
    if ids.len() + 1 > num_objects {
        return Err(PipelineError::Invalid(format!(
            "the sequence has {} objects but only {} object channels (background included); raise --objects",
            ids.len(),
            num_objects
        )));
    }
    Ok(ids
        .into_iter()
        .enumerate()
        .map(|(k, id)| (id, k + 1))
        .collect())
}

/// Checks an `(object id, channel)` list read from a run folder against `num_objects` channels:
/// what [`channel_map`] gives — at least one object, ids above 0 and channels in `1..num_objects`,
/// each id and each channel once. The reason names the offending entry.
pub fn check_channels(
    channels: &[(u16, usize)],
    num_objects: usize,
) -> std::result::Result<(), String> {
    if channels.is_empty() {
        return Err("no objects (an object-aware run has at least one)".into());
    }
    for (i, &(id, c)) in channels.iter().enumerate() {
        if id == 0 {
            return Err(format!("entry {i}: object id 0 is the background"));
        }
        if c == 0 || c >= num_objects {
            return Err(format!(
                "entry {i}: channel {c} of object {id} is outside 1..{num_objects} (0 is the background)"
            ));
        }
        if let Some(j) = channels[..i].iter().position(|x| x.0 == id) {
            return Err(format!("entries {j} and {i}: object {id} listed twice"));
        }
        if let Some(j) = channels[..i].iter().position(|x| x.1 == c) {
            return Err(format!(
                "entries {j} and {i}: channel {c} given to two objects"
            ));
        }
    }
    Ok(())
}

/// How a view's mask edges are treated, in native pixels
/// ([`trand_train::config::ImageLossConfig`]'s `boundary_tolerance_px`, `mask_grow_px` and
/// `snap_masks`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MaskEdges {
    /// The background band's radius, rounded up at the view's resolution.
    pub tolerance_px: f64,
    /// How far every object grows into the background, rounded down at the view's resolution.
    pub grow_px: f64,
    /// `(instance id, px)`: how far each object grows besides, to meet the photograph's edge
    /// ([`crate::mask_edges`]); an id not listed grows by `grow_px` alone.
    pub to_image_edge: Vec<(u16, usize)>,
}

impl MaskEdges {
    /// The edges of `view`'s masks under `il`; with [`MaskSnap::GrowToImageEdges`] this reads where
    /// each mask's edge lies in the photograph (a view without image or mask grows by `grow_px`).
    pub fn for_view(il: &trand_train::config::ImageLossConfig, view: &View) -> Self {
        let to_image_edge = match (il.snap_masks, &view.rgb, &view.instance) {
            (MaskSnap::GrowToImageEdges, Some(rgb), Some(inst)) if rgb.same_size(inst) => {
                crate::mask_edges::growth(inst, &crate::mask_edges::edge_strength(rgb))
            }
            _ => Vec::new(),
        };
        Self {
            tolerance_px: il.boundary_tolerance_px,
            grow_px: il.mask_grow_px,
            to_image_edge,
        }
    }

    /// How many pixels object `id` grows by at a view downsampled by `factor` (rounded down).
    fn radius(&self, id: u16, factor: usize) -> usize {
        let snap = self
            .to_image_edge
            .iter()
            .find(|e| e.0 == id)
            .map_or(0, |e| e.1);
        ((self.grow_px.max(0.0) + snap as f64) / factor as f64).floor() as usize
    }
}

/// Builds the targets of one view, downsampled by `downsample`, with its mask edges treated as `edges`
/// says.
pub fn build(
    view: &View,
    channels: &[(u16, usize)],
    num_objects: usize,
    background: [f32; 3],
    supervision: Supervision,
    (downsample, edges): (u32, &MaskEdges),
) -> Result<TrainView> {
    let err = |what: String| PipelineError::View {
        view: view.name.clone(),
        what,
    };
    let rgb8 = view
        .rgb
        .as_ref()
        .ok_or_else(|| err("no RGB image".into()))?;
    let inst = view
        .instance
        .as_ref()
        .ok_or_else(|| err("no instance mask".into()))?;
    if !rgb8.same_size(inst) {
        return Err(err(format!(
            "mask is {}x{} but the image is {}x{}",
            inst.width, inst.height, rgb8.width, rgb8.height
        )));
    }
    let f = downsample.max(1) as usize;
    let (w0, h0) = (rgb8.width as usize, rgb8.height as usize);
    let (w, h) = (w0 / f, h0 / f);
    if w == 0 || h == 0 {
        return Err(err(format!(
            "downsampling {w0}x{h0} by {f} leaves no pixels"
        )));
    }
    let mut lut = vec![usize::MAX; u16::MAX as usize + 1];
    lut[0] = 0;
    for &(id, c) in channels {
        lut[id as usize] = c;
    }
    let mut rgb = vec![0.0f32; w * h * 3];
    let mut ids = vec![0u16; w * h];
    for y in 0..h {
        for x in 0..w {
            let mut acc = [0.0f32; 3];
            let mut votes: Vec<(u16, usize)> = Vec::new();
            for dy in 0..f {
                for dx in 0..f {
                    let p = (y * f + dy) * w0 + x * f + dx;
                    for (a, &v) in acc.iter_mut().zip(&rgb8.data[p * 3..p * 3 + 3]) {
                        *a += v as f32 / 255.0;
                    }
                    let id = inst.data[p];
                    match votes.iter_mut().find(|v| v.0 == id) {
                        Some(v) => v.1 += 1,
                        None => votes.push((id, 1)),
                    }
                }
            }
            let id = votes
                .iter()
                .max_by_key(|v| (v.1, std::cmp::Reverse(v.0)))
                .map_or(0, |v| v.0);
            // Whole-image supervision ignores the masks, so their ids need not be known objects.
            if supervision == Supervision::ObjectAware && lut[id as usize] == usize::MAX {
                return Err(err(format!(
                    "instance id {id} is not one of the sequence's objects"
                )));
            }
            let o = y * w + x;
            ids[o] = id;
            for c in 0..3 {
                rgb[o * 3 + c] = acc[c] / (f * f) as f32;
            }
        }
    }
    let given_ids = ids;
    let grey = rgb
        .chunks_exact(3)
        .map(|p| (p[0] + p[1] + p[2]) / 3.0)
        .collect();
    let ids = match supervision {
        Supervision::ObjectAware => grow_objects_by(&given_ids, w, h, |id| edges.radius(id, f)),
        Supervision::FullImage => given_ids.clone(),
    };
    // The blocks tile the image from its top-left corner and drop the last `w0 mod f` columns (and
    // rows), so the image is `w0 / f` wide, not the rounded `w0 / f` of the scaled intrinsics.
    let mut intrinsics = view.camera.intrinsics.scaled(1.0 / f as f64);
    (intrinsics.width, intrinsics.height) = (w as u32, h as u32);
    let camera = Camera {
        intrinsics,
        ..view.camera
    };
    if supervision == Supervision::FullImage {
        return Ok(TrainView {
            name: view.name.clone(),
            camera,
            width: w,
            height: h,
            rgb,
            grey,
            mask: Vec::new(),
            labels: Vec::new(),
            label_counts: Vec::new(),
            ids,
            given_ids,
            band: Vec::new(),
        });
    }
    let mut mask = vec![0.0f32; w * h * 3];
    let mut labels = vec![0u8; w * h];
    let mut label_counts = vec![0.0f32; num_objects];
    for o in 0..w * h {
        let c = lut[ids[o] as usize];
        // Channels are below the rasterizer's 64 (channel_map checks against K).
        labels[o] = c as u8;
        label_counts[c] += 1.0;
        if c == 0 {
            rgb[o * 3..o * 3 + 3].copy_from_slice(&background);
            mask[o * 3..o * 3 + 3].copy_from_slice(&background);
        } else {
            let p = palette(c);
            for k in 0..3 {
                mask[o * 3 + k] = 0.3 * rgb[o * 3 + k] + 0.7 * p[k];
            }
        }
    }
    let radius = (edges.tolerance_px.max(0.0) / f as f64).ceil() as usize;
    let band = if radius > 0 {
        trand_train::losses::band::background_band(&labels, w, h, radius)
    } else {
        Vec::new()
    };
    Ok(TrainView {
        name: view.name.clone(),
        camera,
        width: w,
        height: h,
        rgb,
        grey,
        mask,
        labels,
        label_counts,
        ids,
        given_ids,
        band,
    })
}

/// The row-major id map `given` (`w × h`, 0 = background) with every object grown into the background
/// pixels within `radius` pixels (Euclidean) of it ([`MaskEdges::grow_px`]). A background pixel takes
/// the id of its nearest object pixel in `given` (ties: the first offset in the order below), so objects
/// never grow into each other or through a grown pixel.
pub fn grow_objects(given: &[u16], w: usize, h: usize, radius: usize) -> Vec<u16> {
    grow_objects_by(given, w, h, |_| radius)
}

/// [`grow_objects`] with a radius per object: a background pixel takes the id of the nearest object
/// pixel of `given` whose object's `radius` reaches it.
pub fn grow_objects_by(
    given: &[u16],
    w: usize,
    h: usize,
    radius: impl Fn(u16) -> usize,
) -> Vec<u16> {
    assert_eq!(given.len(), w * h, "grow: id map size");
    let mut ids = given.to_vec();
    let mut present: Vec<u16> = given.iter().copied().filter(|&i| i != 0).collect();
    present.sort_unstable();
    present.dedup();
    let reach: Vec<(u16, isize)> = present.iter().map(|&i| (i, radius(i) as isize)).collect();
    let r = reach.iter().map(|x| x.1).max().unwrap_or(0);
    if r == 0 {
        return ids;
    }
    let reach_of = |id: u16| reach.iter().find(|x| x.0 == id).map_or(0, |x| x.1);
    // Nearest first (then row-major), so the first object pixel met is the nearest.
    let offsets = crate::mask_edges::disc_offsets(r as usize);
    let (wi, hi) = (w as isize, h as isize);
    for y in 0..hi {
        for x in 0..wi {
            let o = (y * wi + x) as usize;
            if given[o] != 0 {
                continue;
            }
            ids[o] = offsets
                .iter()
                .filter(|&&(xx, yy)| (0..wi).contains(&(x + xx)) && (0..hi).contains(&(y + yy)))
                .map(|&(dx, dy)| (given[((y + dy) * wi + x + dx) as usize], dx * dx + dy * dy))
                .find(|&(id, d2)| id != 0 && d2 <= reach_of(id) * reach_of(id))
                .map_or(0, |(id, _)| id);
        }
    }
    ids
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn palette_colours_are_distinct() {
        for a in 1..15 {
            for b in a + 1..15 {
                let (pa, pb) = (palette(a), palette(b));
                let d = (0..3).map(|k| (pa[k] - pb[k]).abs()).fold(0.0, f32::max);
                assert!(d > 0.2, "channels {a} and {b} too close: {pa:?} {pb:?}");
            }
        }
        assert_eq!(palette(0), [0.0; 3]);
    }

    /// The masks as given: no band, no growth.
    fn as_given() -> MaskEdges {
        MaskEdges::default()
    }

    /// A background band of `px` native pixels, no growth.
    fn band_of(px: f64) -> MaskEdges {
        MaskEdges {
            tolerance_px: px,
            ..MaskEdges::default()
        }
    }

    /// Every object grown by `px` native pixels, no band.
    fn grown_by(px: f64) -> MaskEdges {
        MaskEdges {
            grow_px: px,
            ..MaskEdges::default()
        }
    }

    /// A 12 x 2 strip of grey pixels with object 3 as a 2 x 2 square in its middle (x = 6, 7).
    fn strip_view() -> View {
        let mut ids = vec![0u16; 24];
        for o in [6, 7, 18, 19] {
            ids[o] = 3;
        }
        grey_view(12, 2, ids)
    }

    /// Object-aware targets of `view`, whose one object has id 3 (channel 1).
    fn object_targets(view: &View, (f, edges): (u32, MaskEdges)) -> Result<TrainView> {
        build(
            view,
            &[(3, 1)],
            15,
            [0.0; 3],
            Supervision::ObjectAware,
            (f, &edges),
        )
    }

    /// A `w × h` view of grey pixels with the given instance ids, seen from 1 m.
    fn grey_view(w: u32, h: u32, ids: Vec<u16>) -> View {
        let k = trand_core::Intrinsics::centered(10.0, w, h);
        let camera = Camera::look_at(
            k,
            glam::DVec3::new(0.0, 0.0, 1.0),
            glam::DVec3::ZERO,
            glam::DVec3::Y,
        );
        View {
            name: "v".into(),
            frame: 0,
            camera,
            rgb: trand_io::Image::from_vec(w, h, 3, vec![128; (w * h * 3) as usize]),
            instance: trand_io::Image::from_vec(w, h, 1, ids),
            depth: None,
        }
    }

    #[test]
    fn whole_image_targets_ignore_unknown_mask_ids_but_object_targets_reject_them() {
        let view = grey_view(4, 2, vec![0, 0, 3, 3, 0, 0, 3, 3]);
        let t = build(
            &view,
            &[],
            15,
            [0.0; 3],
            Supervision::FullImage,
            (1, &band_of(3.0)),
        )
        .expect("masks are not used");
        assert_eq!(t.rgb.len(), 24);
        assert!(t.mask.is_empty() && t.labels.is_empty());
        assert!(
            build(
                &view,
                &[],
                15,
                [0.0; 3],
                Supervision::ObjectAware,
                (1, &as_given())
            )
            .is_err()
        );
        let t = object_targets(&view, (1, as_given())).expect("id 3 is known");
        assert_eq!(t.labels, vec![0, 0, 1, 1, 0, 0, 1, 1]);
        assert_eq!(t.label_counts[..3], [4.0, 4.0, 0.0]);
        assert_eq!(t.rgb[0], 0.0, "background blacked out");
    }

    #[test]
    fn the_band_radius_is_given_in_native_pixels_and_rounded_up_at_the_view_resolution() {
        // Downsampled 1 and 2.
        let view = strip_view();
        // The indices of the band's pixels.
        let band = |f, px| -> Vec<usize> {
            let t = object_targets(&view, (f, band_of(px))).unwrap();
            (0..t.band.len()).filter(|&o| t.band[o]).collect()
        };
        assert!(
            object_targets(&view, (1, as_given()))
                .unwrap()
                .band
                .is_empty()
        );
        assert_eq!(band(1, 3.0), [3, 4, 5, 8, 9, 10, 15, 16, 17, 20, 21, 22]);
        // 3 native pixels are 1.5 at half resolution: 2 pixels on each side of the pixel at x = 3.
        assert_eq!(band(2, 3.0), [1, 2, 4, 5]);
    }

    /// 7 x 3: object 3 at x = 1, object 5 at x = 4..5, row y = 1; background elsewhere.
    fn two_objects_in_a_row() -> Vec<u16> {
        let mut given = vec![0u16; 21];
        given[8] = 3;
        given[11] = 5;
        given[12] = 5;
        given
    }

    #[test]
    fn grown_masks_claim_the_background_disc_around_each_object_but_never_another_object() {
        let given = two_objects_in_a_row();
        let ids = grow_objects(&given, 7, 3, 1);
        #[rustfmt::skip]
        let want = [
            0, 3, 0, 0, 5, 5, 0,
            3, 3, 3, 5, 5, 5, 5,
            0, 3, 0, 0, 5, 5, 0,
        ];
        assert_eq!(ids, want);
        // Radius 2 from the same map: the pixel between them (x = 3) is 2 from object 3 and 1 from
        // object 5, so it goes to 5; x = 2 is nearer 3. Nothing is grown from a grown pixel.
        let ids = grow_objects(&given, 7, 3, 2);
        assert_eq!(&ids[7..14], &[3, 3, 3, 5, 5, 5, 5]);
        assert_eq!(
            &ids[0..7],
            &[3, 3, 3, 5, 5, 5, 5],
            "diagonal (1, 1) is within 2"
        );
    }

    #[test]
    fn each_object_grows_by_its_own_radius_and_only_into_the_background() {
        // Object 3 grows by 2, object 5 by none; the pixel at x = 3 (2 from object 3, 1 from
        // object 5) now goes to 3, and object 5 keeps its pixels.
        let given = two_objects_in_a_row();
        let ids = grow_objects_by(&given, 7, 3, |id| if id == 3 { 2 } else { 0 });
        assert_eq!(&ids[7..14], &[3, 3, 3, 3, 5, 5, 0]);
        assert_eq!(&ids[0..7], &[3, 3, 3, 0, 0, 0, 0]);
        assert_eq!(grow_objects_by(&given, 7, 3, |_| 0), given);
    }

    #[test]
    fn a_mask_cut_inside_the_photographs_edge_is_grown_back_for_the_losses_not_for_the_priors() {
        // A bright 15 x 15 square on a dark image; its mask is the 11 x 11 square 2 px inside it.
        let (w, h) = (30u32, 28u32);
        let inside = |o: u32, m: u32| {
            (8 + m..23 - m).contains(&(o % w)) && (6 + m..21 - m).contains(&(o / w))
        };
        let mut view = grey_view(
            w,
            h,
            (0..w * h).map(|o| 3 * u16::from(inside(o, 2))).collect(),
        );
        view.rgb = trand_io::Image::from_vec(
            w,
            h,
            3,
            (0..w * h)
                .flat_map(|o| [if inside(o, 0) { 230 } else { 20 }; 3])
                .collect(),
        );
        let il = trand_train::config::ImageLossConfig::default();
        let edges = MaskEdges::for_view(&il, &view);
        assert_eq!(edges.to_image_edge, vec![(3, 2)]);
        let t = object_targets(&view, (1, edges)).unwrap();
        // The 11 x 11 square grown by a 2 px disc: the 15 x 15 less three pixels at each corner.
        assert_eq!(t.ids.iter().filter(|&&i| i == 3).count(), 225 - 4 * 3);
        assert_eq!(t.given_ids.iter().filter(|&&i| i == 3).count(), 121);
        let off = trand_train::config::ImageLossConfig {
            snap_masks: MaskSnap::AsGiven,
            ..il
        };
        assert!(MaskEdges::for_view(&off, &view).to_image_edge.is_empty());
    }

    #[test]
    fn mask_growth_is_given_in_native_pixels_and_rounded_down_at_the_view_resolution() {
        let view = strip_view();
        let grown = |f, px| -> usize {
            let t = object_targets(&view, (f, grown_by(px))).unwrap();
            t.labels.iter().filter(|&&l| l == 1).count()
        };
        assert_eq!(grown(1, 0.0), 4);
        assert_eq!(grown(1, 2.0), 12, "two columns each side, both rows");
        // 3 native pixels are 1.5 at half resolution: one pixel each side of the 1-pixel object.
        assert_eq!(grown(2, 3.0), 3);
        assert_eq!(grown(2, 1.0), 1, "half a pixel grows nothing");
        // The hull reads the same grown ids, and grown pixels keep the photograph's colour.
        let t = object_targets(&view, (1, grown_by(1.0))).unwrap();
        assert_eq!(t.ids[5], 3);
        assert_eq!(t.given_ids[5], 0, "the priors read the masks as given");
        assert!((t.rgb[5 * 3] - 128.0 / 255.0).abs() < 1e-6);
    }

    #[test]
    fn a_factor_that_does_not_divide_the_image_gives_a_camera_of_the_image_size() {
        let view = grey_view(8, 5, vec![3; 40]);
        // 8 / 3 rounds to 3 but two blocks fit; 5 / 3 rounds to 2 but one block fits.
        let t = object_targets(&view, (3, as_given())).unwrap();
        assert_eq!((t.width, t.height), (2, 1));
        let k = &t.camera.intrinsics;
        assert_eq!((k.width, k.height), (2, 1));
        assert_eq!(t.labels.len(), k.num_pixels());
    }

    #[test]
    fn object_channels_out_of_range_duplicated_or_empty_are_refused() {
        assert!(check_channels(&[(3, 1), (7, 2)], 15).is_ok());
        for bad in [
            vec![],
            vec![(3, 15)],
            vec![(3, 0)],
            vec![(0, 1)],
            vec![(3, 1), (3, 2)],
            vec![(3, 1), (4, 1)],
        ] {
            assert!(check_channels(&bad, 15).is_err(), "{bad:?} accepted");
        }
    }

    #[test]
    fn channel_map_rejects_too_many_objects() {
        assert_eq!(
            channel_map(&[4, 2, 0, 9], 15).unwrap(),
            vec![(2, 1), (4, 2), (9, 3)]
        );
        assert!(channel_map(&[1, 2, 3], 3).is_err());
    }
}
