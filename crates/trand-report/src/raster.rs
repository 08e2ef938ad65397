//! Images of the report: scalar maps through the colour map, object maps through the palette,
//! box-filter downscaling, PNG output.

use std::path::Path;

use trand_io::{DepthMap, Image, InstanceMap, Rgb8Image};

use crate::colormap::{NO_VALUE, diverging, object_colour, viridis};
use crate::layout::ReportError;

/// Depth coloured over `[lo, hi]` metres; pixels with no depth (≤ 0, non-finite) get [`NO_VALUE`].
pub fn colour_depth(d: &DepthMap, lo: f64, hi: f64) -> Rgb8Image {
    let span = (hi - lo).max(1e-9);
    map_rgb(d, |v| {
        if v.is_finite() && v > 0.0 {
            viridis((v as f64 - lo) / span)
        } else {
            NO_VALUE
        }
    })
}

/// Per-pixel absolute error of `pred` on the evaluated pixels (object with GT depth, as the metrics;
/// an uncovered prediction costs the GT depth); `NaN` elsewhere.
pub fn abs_error(pred: &DepthMap, gt: &DepthMap, inst: &InstanceMap) -> DepthMap {
    absolute(&signed_error(pred, gt, inst))
}

/// `|e|` per pixel (`NaN` stays `NaN`).
pub fn absolute(e: &DepthMap) -> DepthMap {
    Image {
        data: e.data.iter().map(|v| v.abs()).collect(),
        ..e.clone()
    }
}

/// Per-pixel `e = pred − GT` on the evaluated pixels (an uncovered prediction counts as 0, so
/// `e = −GT`); `NaN` elsewhere. Negative where the prediction is too near (the sign opposite to the
/// metrics' `gt − pred`, so that "too near" reads as "less depth").
pub fn signed_error(pred: &DepthMap, gt: &DepthMap, inst: &InstanceMap) -> DepthMap {
    let data = pred
        .data
        .iter()
        .zip(&gt.data)
        .zip(&inst.data)
        .map(|((&p, &g), &id)| {
            if id == 0 || g.is_nan() || g <= 0.0 || !g.is_finite() {
                f32::NAN
            } else {
                let p = if p.is_finite() { p } else { 0.0 };
                p - g
            }
        })
        .collect();
    Image {
        width: gt.width,
        height: gt.height,
        channels: 1,
        data,
    }
}

/// Signed error `e` coloured on the diverging map at `t = e / max` (saturating beyond ±`max` metres):
/// negative (too near) blue, positive (too far) red; `NaN` gets [`NO_VALUE`].
pub fn colour_signed_error(e: &DepthMap, max: f64) -> Rgb8Image {
    map_rgb(e, |v| diverging(v as f64 / max))
}

/// Error coloured over `[0, max]` metres; `NaN` (not evaluated) gets [`NO_VALUE`].
pub fn colour_error(e: &DepthMap, max: f64) -> Rgb8Image {
    map_rgb(e, |v| {
        if v.is_nan() {
            NO_VALUE
        } else {
            viridis(v as f64 / max)
        }
    })
}

/// Object ids through the palette.
pub fn colour_instances(m: &InstanceMap) -> Rgb8Image {
    map_rgb(m, object_colour)
}

fn map_rgb<T: Copy>(img: &Image<T>, f: impl Fn(T) -> [u8; 3]) -> Rgb8Image {
    Image {
        width: img.width,
        height: img.height,
        channels: 3,
        data: img.data.iter().flat_map(|&v| f(v)).collect(),
    }
}

/// Downscales by the smallest integer factor that brings the width to ≤ `max_width`, averaging
/// blocks (partial blocks at the right and bottom edges are dropped).
pub fn downscale(img: &Rgb8Image, max_width: u32) -> Rgb8Image {
    let k = img.width.div_ceil(max_width.max(1)).max(1);
    if k == 1 {
        return img.clone();
    }
    let (w, h) = ((img.width / k).max(1), (img.height / k).max(1));
    let c = img.channels;
    let mut out = Image::filled(w, h, c, 0u8);
    for y in 0..h {
        for x in 0..w {
            for ch in 0..c {
                let mut sum = 0u32;
                let mut n = 0u32;
                for dy in 0..k {
                    for dx in 0..k {
                        let (sx, sy) = (x * k + dx, y * k + dy);
                        if sx < img.width && sy < img.height {
                            sum += img.get(sx, sy, ch) as u32;
                            n += 1;
                        }
                    }
                }
                out.set(x, y, ch, ((sum + n / 2) / n) as u8);
            }
        }
    }
    out
}

/// Writes an RGB PNG (creating the folder).
pub fn write_png(path: &Path, img: &Rgb8Image) -> Result<(), ReportError> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|e| ReportError::io(dir, e))?;
    }
    trand_io::write_rgb_png(path, img)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn error_is_only_on_evaluated_pixels_and_uncovered_costs_gt() {
        let gt = Image::from_vec(3, 1, 1, vec![1.0f32, 1.0, 0.0]).unwrap();
        let pred = Image::from_vec(3, 1, 1, vec![1.25f32, 0.0, 0.5]).unwrap();
        let inst = Image::from_vec(3, 1, 1, vec![1u16, 2, 1]).unwrap();
        let e = abs_error(&pred, &gt, &inst);
        assert_eq!(e.data[..2], [0.25, 1.0]);
        assert!(e.data[2].is_nan());
        let c = colour_error(&e, 1.0);
        assert_eq!(c.data[6..9], NO_VALUE);
        assert_eq!(c.data[3..6], crate::colormap::VIRIDIS[8]);
    }

    #[test]
    fn signed_error_is_negative_and_blue_where_the_rendering_is_too_near() {
        use crate::colormap::{DIVERGING, diverging};
        // A lid 0.125 m in front of the surface, a surface 0.015625 m behind it, an exact pixel, an
        // uncovered pixel, background.
        let gt = Image::from_vec(5, 1, 1, vec![1.0f32, 1.0, 1.0, 0.5, 1.0]).unwrap();
        let pred = Image::from_vec(5, 1, 1, vec![0.875f32, 1.015625, 1.0, 0.0, 0.5]).unwrap();
        let inst = Image::from_vec(5, 1, 1, vec![1u16, 1, 2, 2, 0]).unwrap();
        let e = signed_error(&pred, &gt, &inst);
        assert_eq!(e.data[..4], [-0.125, 0.015625, 0.0, -0.5]);
        assert!(e.data[4].is_nan(), "background is not evaluated");
        assert_eq!(
            absolute(&e).data[..4],
            abs_error(&pred, &gt, &inst).data[..4]
        );
        let max = 0.0625;
        let c = colour_signed_error(&e, max);
        let px = |i: usize| -> [u8; 3] { c.data[3 * i..3 * i + 3].try_into().unwrap() };
        assert_eq!(px(0), DIVERGING[0], "too near saturates blue");
        assert_eq!(
            px(1),
            diverging(0.25),
            "too far: a quarter of the way to red"
        );
        assert!(px(1)[0] > px(1)[2], "too far is reddish");
        assert_eq!(px(2), DIVERGING[1], "exact is white");
        assert_eq!(px(3), DIVERGING[0], "uncovered reads as too near");
        assert_eq!(px(4), NO_VALUE);
    }

    #[test]
    fn downscale_averages_blocks_to_fit_the_width() {
        let img = Image::from_vec(4, 2, 3, (0..24).map(|i| (i * 10) as u8).collect()).unwrap();
        let d = downscale(&img, 2);
        assert_eq!((d.width, d.height), (2, 1));
        // Block (0..2, 0..2), red: values 0, 30, 120, 150 → 75.
        assert_eq!(d.get(0, 0, 0), 75);
        assert_eq!(downscale(&img, 4), img);
    }
}
