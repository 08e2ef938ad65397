//! Where each object's mask edge lies in its photograph: how far a segmenter's mask was cut inside
//! the object, read from the image alone.
//!
//! A segmenter's boundary is a few pixels off, and the two ways do not cost alike (BENCHMARKS.md §8,
//! "Which way a boundary is off matters"): an eroded mask carves a notch into the visual hull and
//! trains the surfels there to transparency, so the test views see through the object's edge, while
//! a mask a pixel or two too large costs little. So each (view, object) mask is moved to where the
//! image has its edge, and only outwards.
//!
//! **The estimate.** For every offset `d` in `−SEARCH_PX..=SEARCH_PX` the mask `M` is moved by `d`:
//! `M_d = {p : dist(p, M) ≤ d}` for `d ≥ 0`, `M_d = {p ∈ M : dist(p, ∁M) > |d|}` for `d < 0`
//! (Euclidean disc dilation and erosion). Its score is the mean edge strength across its boundary:
//! over every pair of 4-neighbours `p ∈ M_d`, `q ∉ M_d`, `(S(p) + S(q)) / 2`, where `S` is the Sobel
//! gradient magnitude `√(G_x² + G_y²)` of the channel where it is largest. A Sobel response is as
//! strong on either side of a sharp edge, so a pair straddling it scores highest, while one pixel
//! off the pair holds only one strong side. The offset of the highest score (ties: the smallest
//! `|d|`) is where the mask's edge meets the image's (the image's border is no edge). A glass edge refracts
//! the table behind it, which shows as an edge in every view, even where the glass itself is clear.
//!
//! **Only growth is applied** (`max(0, d)`): a shrink read from the image is where the table's texture
//! inside the silhouette is stronger than the edge (an upturned bowl on wood reads −3 to −4 px with
//! exact masks), while a growth read wrongly costs what a dilated mask costs. Masks smaller than
//! [`MIN_PIXELS`] keep their edge. Growth is into the background only ([`crate::targets`]).
//!
//! Written by hand: the image crates' morphology works on whole images, and this needs a signed,
//! capped distance in a window around one object, at a handful of offsets.

use trand_io::{InstanceMap, Rgb8Image};

/// How far a mask's edge is searched, in native pixels each way (the boundary errors measured are
/// 1–3 px).
pub const SEARCH_PX: usize = 4;

/// Masks of fewer pixels keep their edge: their boundaries are too short to read.
pub const MIN_PIXELS: usize = 50;

/// Edge strength per pixel (row-major `w × h`): the Sobel gradient magnitude of the RGB channel
/// where it is largest, the image's border replicated.
pub fn edge_strength(rgb: &Rgb8Image) -> Vec<f32> {
    let (w, h, c) = (
        rgb.width as usize,
        rgb.height as usize,
        rgb.channels as usize,
    );
    let at = |x: isize, y: isize, k: usize| -> f32 {
        let xx = x.clamp(0, w as isize - 1) as usize;
        let yy = y.clamp(0, h as isize - 1) as usize;
        rgb.data[(yy * w + xx) * c + k] as f32
    };
    let mut out = vec![0.0f32; w * h];
    for y in 0..h as isize {
        for x in 0..w as isize {
            let mut best = 0.0f32;
            for k in 0..c.min(3) {
                let px = |dx, dy| at(x + dx, y + dy, k);
                let gx = px(1, -1) + 2.0 * px(1, 0) + px(1, 1)
                    - px(-1, -1)
                    - 2.0 * px(-1, 0)
                    - px(-1, 1);
                let gy = px(-1, 1) + 2.0 * px(0, 1) + px(1, 1)
                    - px(-1, -1)
                    - 2.0 * px(0, -1)
                    - px(1, -1);
                best = best.max(gx.hypot(gy));
            }
            out[y as usize * w + x as usize] = best;
        }
    }
    out
}

/// Per object id of `inst` (ascending), how many native pixels its mask grows to meet the image's
/// edge (0 for most exact masks). `strength` is [`edge_strength`] of the view's photograph.
pub fn growth(inst: &InstanceMap, strength: &[f32]) -> Vec<(u16, usize)> {
    let (w, h) = (inst.width as usize, inst.height as usize);
    assert_eq!(strength.len(), w * h, "mask edges: strength size");
    let mut ids: Vec<u16> = inst.data.iter().copied().filter(|&i| i != 0).collect();
    ids.sort_unstable();
    ids.dedup();
    ids.into_iter()
        .map(|id| {
            let offset = best_offset(&Window::around(inst, id), strength);
            (id, offset.max(0) as usize)
        })
        .collect()
}

/// The offsets `(dx, dy) ≠ (0, 0)` of a disc of radius `r` (`dx² + dy² ≤ r²`), nearest first, then
/// row-major: the first pixel of a kind met in this order is the nearest one.
pub fn disc_offsets(r: usize) -> Vec<(isize, isize)> {
    let r = r as isize;
    let mut offsets: Vec<(isize, isize)> = (-r..=r)
        .flat_map(|dy| (-r..=r).map(move |dx| (dx, dy)))
        .filter(|&(dx, dy)| (dx, dy) != (0, 0) && dx * dx + dy * dy <= r * r)
        .collect();
    offsets.sort_by_key(|&(dx, dy)| (dx * dx + dy * dy, dy, dx));
    offsets
}

/// One object's mask in a window `SEARCH_PX + 1` pixels larger than its bounding box, with every
/// pixel's squared distance to the nearest pixel on the other side of the mask's edge (capped:
/// `u32::MAX` past `SEARCH_PX`).
struct Window {
    /// The window's origin and size in the image.
    x0: usize,
    y0: usize,
    w: usize,
    h: usize,
    /// The image's size: the window never leaves it.
    image: (usize, usize),
    inside: Vec<bool>,
    dist2: Vec<u32>,
    pixels: usize,
}

impl Window {
    fn around(inst: &InstanceMap, id: u16) -> Self {
        let (iw, ih) = (inst.width as usize, inst.height as usize);
        let (mut x_lo, mut y_lo, mut x_hi, mut y_hi) = (iw, ih, 0, 0);
        let mut pixels = 0;
        for (o, _) in inst.data.iter().enumerate().filter(|(_, v)| **v == id) {
            let (x, y) = (o % iw, o / iw);
            (x_lo, x_hi, y_lo, y_hi) = (x_lo.min(x), x_hi.max(x), y_lo.min(y), y_hi.max(y));
            pixels += 1;
        }
        let m = SEARCH_PX + 1;
        let (x0, y0) = (x_lo.saturating_sub(m), y_lo.saturating_sub(m));
        let (x1, y1) = ((x_hi + m).min(iw - 1), (y_hi + m).min(ih - 1));
        let (w, h) = (x1 - x0 + 1, y1 - y0 + 1);
        let inside: Vec<bool> = (0..w * h)
            .map(|o| inst.data[(y0 + o / w) * iw + x0 + o % w] == id)
            .collect();
        let offsets = disc_offsets(SEARCH_PX);
        let dist2 = (0..w * h)
            .map(|o| {
                let (x, y) = ((o % w) as isize, (o / w) as isize);
                // Pixels past the window are background (the window holds the whole mask); the
                // image's outside is no edge, so a mask the border cuts is not eroded from it.
                let other = |dx: isize, dy: isize| {
                    let (xx, yy) = (x + dx, y + dy);
                    let (gx, gy) = (x0 as isize + xx, y0 as isize + yy);
                    if !(0..iw as isize).contains(&gx) || !(0..ih as isize).contains(&gy) {
                        return false;
                    }
                    let there = (0..w as isize).contains(&xx)
                        && (0..h as isize).contains(&yy)
                        && inside[yy as usize * w + xx as usize];
                    there != inside[o]
                };
                offsets
                    .iter()
                    .find(|&&(dx, dy)| other(dx, dy))
                    .map_or(u32::MAX, |&(dx, dy)| (dx * dx + dy * dy) as u32)
            })
            .collect();
        Self {
            x0,
            y0,
            w,
            h,
            image: (iw, ih),
            inside,
            dist2,
            pixels,
        }
    }

    /// Whether window pixel `o` is in the mask moved by `d`.
    fn in_moved(&self, o: usize, d: isize) -> bool {
        let r2 = (d * d) as u32;
        match (self.inside[o], d >= 0) {
            (true, true) => true,
            (false, true) => self.dist2[o] <= r2,
            (true, false) => self.dist2[o] > r2,
            (false, false) => false,
        }
    }

    /// Mean edge strength across the boundary of the mask moved by `d`: over every pair of
    /// 4-neighbours `p ∈ M_d`, `q ∉ M_d` (both in the image), `(S(p) + S(q)) / 2`; `None` where
    /// there is no such pair.
    fn boundary_score(&self, d: isize, strength: &[f32]) -> Option<f32> {
        let (mut sum, mut n) = (0.0f64, 0usize);
        let iw = self.image.0;
        for y in 0..self.h {
            for x in 0..self.w {
                let o = y * self.w + x;
                if !self.in_moved(o, d) {
                    continue;
                }
                let (gx, gy) = (self.x0 + x, self.y0 + y);
                for (dx, dy) in [(1isize, 0isize), (-1, 0), (0, 1), (0, -1)] {
                    let (qx, qy) = (gx as isize + dx, gy as isize + dy);
                    if !(0..iw as isize).contains(&qx) || !(0..self.image.1 as isize).contains(&qy)
                    {
                        continue;
                    }
                    let (wx, wy) = (qx as usize - self.x0, qy as usize - self.y0);
                    // Past the window by its margin is outside every moved mask.
                    let q_in = wx < self.w && wy < self.h && self.in_moved(wy * self.w + wx, d);
                    if !q_in {
                        let q = qy as usize * iw + qx as usize;
                        sum += 0.5 * (strength[gy * iw + gx] + strength[q]) as f64;
                        n += 1;
                    }
                }
            }
        }
        (n > 0).then(|| (sum / n as f64) as f32)
    }
}

/// The offset whose boundary scores highest (ties: the smallest `|d|`); 0 for a small mask.
fn best_offset(win: &Window, strength: &[f32]) -> isize {
    if win.pixels < MIN_PIXELS {
        return 0;
    }
    let r = SEARCH_PX as isize;
    let mut order: Vec<isize> = (-r..=r).collect();
    order.sort_by_key(|d| d.abs());
    let mut best = (0isize, f32::NEG_INFINITY);
    for d in order {
        if let Some(s) = win.boundary_score(d, strength)
            && s > best.1
        {
            best = (d, s);
        }
    }
    best.0
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `w × h` image of a disc of radius `r` (grey 200 on 40), and its mask cut `cut` px inside
    /// (negative: outside) the disc's edge.
    fn disc_scene(w: usize, h: usize, r: f64, cut: f64) -> (Rgb8Image, InstanceMap) {
        let (cx, cy) = (w as f64 / 2.0 - 0.3, h as f64 / 2.0 + 0.2);
        let d = |o: usize| ((o % w) as f64 - cx).hypot((o / w) as f64 - cy);
        let rgb = (0..w * h)
            .flat_map(|o| [if d(o) <= r { 200u8 } else { 40 }; 3])
            .collect();
        let ids = (0..w * h).map(|o| u16::from(d(o) <= r - cut)).collect();
        (
            Rgb8Image {
                width: w as u32,
                height: h as u32,
                channels: 3,
                data: rgb,
            },
            InstanceMap {
                width: w as u32,
                height: h as u32,
                channels: 1,
                data: ids,
            },
        )
    }

    #[test]
    fn an_eroded_mask_grows_back_to_the_images_edge() {
        for cut in 1..=3 {
            let (rgb, inst) = disc_scene(64, 48, 15.0, cut as f64);
            assert_eq!(
                growth(&inst, &edge_strength(&rgb)),
                vec![(1, cut)],
                "cut {cut}"
            );
        }
    }

    #[test]
    fn an_exact_or_dilated_mask_keeps_its_edge() {
        for cut in [0.0, -1.0, -3.0] {
            let (rgb, inst) = disc_scene(64, 48, 15.0, cut);
            assert_eq!(
                growth(&inst, &edge_strength(&rgb)),
                vec![(1, 0)],
                "cut {cut}"
            );
        }
    }

    #[test]
    fn a_mask_cut_by_the_images_border_reads_its_edge_inside_the_image() {
        // The disc's centre near the left border: a third of it is outside the image.
        let (w, h) = (40usize, 40usize);
        let (cx, cy, r) = (3.7, 20.2, 10.0);
        let d = |o: usize| ((o % w) as f64 - cx).hypot((o / w) as f64 - cy);
        let rgb = Rgb8Image {
            width: w as u32,
            height: h as u32,
            channels: 3,
            data: (0..w * h)
                .flat_map(|o| [if d(o) <= r { 220u8 } else { 30 }; 3])
                .collect(),
        };
        let inst = InstanceMap {
            width: w as u32,
            height: h as u32,
            channels: 1,
            data: (0..w * h).map(|o| 7 * u16::from(d(o) <= r - 2.0)).collect(),
        };
        assert_eq!(growth(&inst, &edge_strength(&rgb)), vec![(7, 2)]);
    }

    #[test]
    fn a_small_mask_and_a_flat_image_grow_nothing() {
        let (rgb, inst) = disc_scene(32, 32, 3.0, 1.0);
        assert_eq!(growth(&inst, &edge_strength(&rgb)), vec![(1, 0)]);
        let (mut rgb, inst) = disc_scene(64, 48, 15.0, 2.0);
        rgb.data.fill(90);
        assert_eq!(growth(&inst, &edge_strength(&rgb)), vec![(1, 0)]);
    }

    #[test]
    fn edge_strength_is_the_sobel_magnitude_of_the_strongest_channel() {
        // A vertical step of 100 in the green channel alone: |G_x| = 4 · 100 beside it.
        let (w, h) = (6usize, 4usize);
        let data = (0..w * h)
            .flat_map(|o| [10u8, if o % w >= 3 { 110 } else { 10 }, 10])
            .collect();
        let rgb = Rgb8Image {
            width: w as u32,
            height: h as u32,
            channels: 3,
            data,
        };
        let s = edge_strength(&rgb);
        for y in 0..h {
            assert_eq!(s[y * w + 2], 400.0);
            assert_eq!(s[y * w + 3], 400.0);
            assert_eq!(s[y * w], 0.0);
            assert_eq!(s[y * w + 5], 0.0);
        }
    }
}
