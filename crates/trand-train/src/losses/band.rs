//! The background band: background pixels of a label map that lie within a few pixels of an object.
//!
//! A segmenter's boundary is a few pixels off, differently in every view. Where a view's mask is
//! eroded, object pixels are labelled background; the photometric losses then pull every surfel seen
//! there towards the background colour, and with the other views wanting the same surfels opaque, the
//! fit settles on a hole in the object's front (seen through, its depth is the back wall's). On
//! request (`ImageLossConfig::boundary_tolerance_px`, off by default) the training loop leaves the band
//! of background pixels within `radius` pixels of an object out of the photometric gradients. Only the
//! background side is left out: the object side keeps pulling surfels in, so the silhouette stays pinned
//! from inside, and from outside only by the visual hull the surfels start from — which is why the band
//! costs depth where that hull is loose (a narrow baseline) or absent (the one image of t = 1).
//!
//! Distance is Euclidean on the pixel grid: pixel `p` is in the band when it is labelled 0 and some
//! pixel `q ≠ 0`-labelled has `|p − q|² ≤ radius²`.

/// `true` for the background pixels within `radius` pixels of an object pixel (module docs); all
/// `false` for `radius` 0. `labels` is row-major `width × height`, 0 = background.
pub fn background_band(labels: &[u8], width: usize, height: usize, radius: usize) -> Vec<bool> {
    assert_eq!(labels.len(), width * height, "band: label map size");
    let mut band = vec![false; labels.len()];
    if radius == 0 {
        return band;
    }
    let r = radius as isize;
    // The disc's half-width per row offset, so each object pixel marks its disc row by row.
    let half: Vec<isize> = (-r..=r)
        .map(|dy| {
            let mut dx = 0;
            while (dx + 1) * (dx + 1) + dy * dy <= r * r {
                dx += 1;
            }
            dx
        })
        .collect();
    let (w, h) = (width as isize, height as isize);
    for y in 0..h {
        for x in 0..w {
            let o = (y * w + x) as usize;
            // Only object pixels on the object's edge can reach a background pixel first.
            if labels[o] == 0 || !touches_background(labels, w, h, x, y) {
                continue;
            }
            for (k, &dx) in half.iter().enumerate() {
                let yy = y + k as isize - r;
                if !(0..h).contains(&yy) {
                    continue;
                }
                for xx in (x - dx).max(0)..=(x + dx).min(w - 1) {
                    let q = (yy * w + xx) as usize;
                    band[q] |= labels[q] == 0;
                }
            }
        }
    }
    band
}

/// Whether a 4-neighbour of `(x, y)` is background (outside the image does not count).
fn touches_background(labels: &[u8], w: isize, h: isize, x: isize, y: isize) -> bool {
    [(-1, 0), (1, 0), (0, -1), (0, 1)].iter().any(|&(dx, dy)| {
        let (xx, yy) = (x + dx, y + dy);
        (0..w).contains(&xx) && (0..h).contains(&yy) && labels[(yy * w + xx) as usize] == 0
    })
}

/// Zeroes the gradient of an interleaved `channels`-per-pixel image at the band's pixels.
pub fn clear_band(grad: &mut [f32], band: &[bool], channels: usize) {
    assert_eq!(grad.len(), band.len() * channels, "band: gradient size");
    for (g, _) in grad
        .chunks_exact_mut(channels)
        .zip(band)
        .filter(|(_, b)| **b)
    {
        g.fill(0.0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The band by definition: every background pixel against every object pixel.
    fn brute(labels: &[u8], w: usize, h: usize, r: usize) -> Vec<bool> {
        (0..w * h)
            .map(|p| {
                labels[p] == 0
                    && (0..w * h).any(|q| {
                        let (dx, dy) = (
                            (p % w) as isize - (q % w) as isize,
                            (p / w) as isize - (q / w) as isize,
                        );
                        labels[q] != 0 && ((dx * dx + dy * dy) as usize) <= r * r
                    })
            })
            .collect()
    }

    #[test]
    fn band_is_the_background_within_the_radius_of_any_object_pixel() {
        let (w, h) = (23, 17);
        let mut labels = vec![0u8; w * h];
        // A filled blob, a lone pixel at the border and a second object touching the first.
        for y in 4..10 {
            for x in 5..12 {
                labels[y * w + x] = 1;
            }
        }
        labels[w - 1] = 2;
        for y in 6..12 {
            labels[y * w + 12] = 3;
        }
        for r in 0..5 {
            assert_eq!(
                background_band(&labels, w, h, r),
                brute(&labels, w, h, r),
                "radius {r}"
            );
        }
    }

    #[test]
    fn band_never_holds_an_object_pixel_and_is_empty_without_objects() {
        let (w, h) = (9, 7);
        assert!(!background_band(&[0; 63], w, h, 3).iter().any(|&b| b));
        let band = background_band(&[1; 63], w, h, 3);
        assert!(!band.iter().any(|&b| b));
    }

    #[test]
    fn clearing_zeroes_only_the_band_pixels_channels() {
        let mut g = vec![1.0f32; 3 * 4];
        clear_band(&mut g, &[false, true, false, true], 3);
        assert_eq!(g, [1., 1., 1., 0., 0., 0., 1., 1., 1., 0., 0., 0.]);
    }
}
