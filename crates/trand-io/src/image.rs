//! A minimal row-major, channel-interleaved image and the PNG readers of the datasets.
//!
//! * [`Rgb8Image`]: 8-bit sRGB, 3 channels (an alpha channel in the file is dropped).
//! * [`InstanceMap`]: one `u16` object id per pixel, 0 = background.
//! * [`DepthMap`]: one `f32` per pixel, planar camera-z depth in **metres**, 0 = no value.
//!
//! Pixel `(x, y)` channel `c` is `data[(y·width + x)·channels + c]`.

use std::path::Path;

use crate::error::IoError;

/// Row-major interleaved image. `Debug` prints the shape, not the pixels.
#[derive(Clone, PartialEq)]
pub struct Image<T> {
    pub width: u32,
    pub height: u32,
    pub channels: u32,
    pub data: Vec<T>,
}

impl<T> std::fmt::Debug for Image<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "Image({}x{}x{}, {} values)",
            self.width,
            self.height,
            self.channels,
            self.data.len()
        )
    }
}

/// 8-bit RGB image.
pub type Rgb8Image = Image<u8>;
/// Per-pixel object id, 0 = background.
pub type InstanceMap = Image<u16>;
/// Depth in metres, 0 = no value.
pub type DepthMap = Image<f32>;

impl<T> Image<T> {
    pub fn num_pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }

    pub fn same_size<U>(&self, other: &Image<U>) -> bool {
        self.width == other.width && self.height == other.height
    }
}

impl<T: Copy> Image<T> {
    /// An image with every value `fill`.
    pub fn filled(width: u32, height: u32, channels: u32, fill: T) -> Self {
        Self {
            width,
            height,
            channels,
            data: vec![fill; width as usize * height as usize * channels as usize],
        }
    }

    /// Wraps `data`; `None` if its length is not `width·height·channels`.
    pub fn from_vec(width: u32, height: u32, channels: u32, data: Vec<T>) -> Option<Self> {
        (data.len() == width as usize * height as usize * channels as usize).then_some(Self {
            width,
            height,
            channels,
            data,
        })
    }

    /// Value at column `x`, row `y`, channel `c`.
    pub fn get(&self, x: u32, y: u32, c: u32) -> T {
        self.data[((y as usize * self.width as usize + x as usize) * self.channels as usize)
            + c as usize]
    }

    pub fn set(&mut self, x: u32, y: u32, c: u32, v: T) {
        let i =
            ((y as usize * self.width as usize + x as usize) * self.channels as usize) + c as usize;
        self.data[i] = v;
    }
}

impl Image<u8> {
    /// Values in `[0, 1]` (`v / 255`), same layout.
    pub fn to_f32(&self) -> Image<f32> {
        Image {
            width: self.width,
            height: self.height,
            channels: self.channels,
            data: self.data.iter().map(|&v| v as f32 / 255.0).collect(),
        }
    }
}

impl InstanceMap {
    /// Binary mask of the pixels labelled `id` (row-major).
    pub fn mask(&self, id: u16) -> Vec<bool> {
        self.data.iter().map(|&v| v == id).collect()
    }

    /// Binary mask of all object pixels (id ≠ 0).
    pub fn foreground(&self) -> Vec<bool> {
        self.data.iter().map(|&v| v != 0).collect()
    }

    /// Sorted distinct non-zero ids present in the map.
    pub fn ids(&self) -> Vec<u16> {
        let mut seen = vec![false; u16::MAX as usize + 1];
        for &v in &self.data {
            seen[v as usize] = true;
        }
        (1..=u16::MAX).filter(|&i| seen[i as usize]).collect()
    }
}

fn decode(path: &Path) -> Result<image::DynamicImage, IoError> {
    let reader = image::ImageReader::open(path).map_err(|e| IoError::io(path, e))?;
    let reader = reader
        .with_guessed_format()
        .map_err(|e| IoError::io(path, e))?;
    reader.decode().map_err(|source| IoError::Image {
        path: path.to_path_buf(),
        source,
    })
}

/// Reads an 8-bit RGB or RGBA PNG as RGB.
pub fn read_rgb8(path: &Path) -> Result<Rgb8Image, IoError> {
    let img = decode(path)?;
    match img.color() {
        image::ColorType::Rgb8
        | image::ColorType::Rgba8
        | image::ColorType::L8
        | image::ColorType::La8 => {}
        other => {
            return Err(IoError::PixelFormat {
                path: path.into(),
                expected: "8-bit RGB",
                found: format!("{other:?}"),
            });
        }
    }
    let rgb = img.into_rgb8();
    let (w, h) = rgb.dimensions();
    Ok(Image {
        width: w,
        height: h,
        channels: 3,
        data: rgb.into_raw(),
    })
}

/// Reads a single-channel 8-bit PNG (masks, class/label maps).
pub fn read_gray8(path: &Path) -> Result<Image<u8>, IoError> {
    match decode(path)? {
        image::DynamicImage::ImageLuma8(g) => {
            let (w, h) = g.dimensions();
            Ok(Image {
                width: w,
                height: h,
                channels: 1,
                data: g.into_raw(),
            })
        }
        other => Err(IoError::PixelFormat {
            path: path.into(),
            expected: "8-bit grayscale",
            found: format!("{:?}", other.color()),
        }),
    }
}

/// Reads a single-channel 8- or 16-bit PNG as `u16` (depth PNGs, instance-id maps).
pub fn read_gray16(path: &Path) -> Result<Image<u16>, IoError> {
    match decode(path)? {
        image::DynamicImage::ImageLuma16(g) => {
            let (w, h) = g.dimensions();
            Ok(Image {
                width: w,
                height: h,
                channels: 1,
                data: g.into_raw(),
            })
        }
        image::DynamicImage::ImageLuma8(g) => {
            let (w, h) = g.dimensions();
            Ok(Image {
                width: w,
                height: h,
                channels: 1,
                data: g.into_raw().into_iter().map(u16::from).collect(),
            })
        }
        other => Err(IoError::PixelFormat {
            path: path.into(),
            expected: "8- or 16-bit grayscale",
            found: format!("{:?}", other.color()),
        }),
    }
}

/// Reads an instance mask of any common kind as object ids (0 = background):
/// * 8- or 16-bit grayscale ids, as [`read_gray16`];
/// * a single-object 0/255 mask (8 bits, 255 the only non-zero value) as id 1;
/// * an RGBA cut-out (the object's pixels opaque, the rest transparent; with or without a gray
///   level) as id 1 where alpha is above half.
pub fn read_instance_mask(path: &Path) -> Result<InstanceMap, IoError> {
    let img = decode(path)?;
    let (w, h) = (img.width(), img.height());
    let data: Vec<u16> = match img {
        image::DynamicImage::ImageLuma16(g) => g.into_raw(),
        image::DynamicImage::ImageLuma8(g) => {
            let raw = g.into_raw();
            let binary = raw.iter().all(|&v| v == 0 || v == 255) && raw.contains(&255);
            raw.into_iter()
                .map(|v| {
                    if binary {
                        u16::from(v == 255)
                    } else {
                        u16::from(v)
                    }
                })
                .collect()
        }
        image::DynamicImage::ImageRgba8(_) | image::DynamicImage::ImageLumaA8(_) => img
            .into_rgba8()
            .pixels()
            .map(|p| u16::from(p.0[3] > 127))
            .collect(),
        other => {
            return Err(IoError::PixelFormat {
                path: path.into(),
                expected: "instance-id grayscale (8/16-bit), 0/255 or RGBA cut-out mask",
                found: format!("{:?}", other.color()),
            });
        }
    };
    Ok(Image::from_vec(w, h, 1, data).expect("decoded sizes agree"))
}

/// Reads a 16-bit depth PNG whose values times `mm_per_unit` are millimetres, as metres.
pub fn read_depth_png(path: &Path, mm_per_unit: f64) -> Result<DepthMap, IoError> {
    let raw = match decode(path)? {
        image::DynamicImage::ImageLuma16(g) => g,
        other => {
            return Err(IoError::PixelFormat {
                path: path.into(),
                expected: "16-bit grayscale depth",
                found: format!("{:?}", other.color()),
            });
        }
    };
    let (w, h) = raw.dimensions();
    let s = mm_per_unit / 1000.0;
    Ok(Image {
        width: w,
        height: h,
        channels: 1,
        data: raw
            .into_raw()
            .into_iter()
            .map(|v| (v as f64 * s) as f32)
            .collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn binary_and_cut_out_masks_read_as_object_one_and_id_maps_as_they_are() {
        let dir = crate::ScratchDir::new("masks").unwrap();
        let write = |name: &str, img: image::DynamicImage| {
            let p = dir.path().join(name);
            img.save(&p).unwrap();
            read_instance_mask(&p).unwrap().data
        };
        let gray = |v: Vec<u8>| image::GrayImage::from_raw(3, 1, v).unwrap().into();
        assert_eq!(write("bin.png", gray(vec![0, 255, 255])), vec![0, 1, 1]);
        assert_eq!(write("ids.png", gray(vec![0, 2, 255])), vec![0, 2, 255]);
        let rgba = image::RgbaImage::from_raw(3, 1, vec![9, 9, 9, 0, 9, 9, 9, 255, 1, 2, 3, 200]);
        assert_eq!(write("cut.png", rgba.unwrap().into()), vec![0, 1, 1]);
    }

    #[test]
    fn instance_map_lists_ids_and_masks() {
        let m: InstanceMap = Image::from_vec(3, 1, 1, vec![0, 7, 300]).unwrap();
        assert_eq!(m.ids(), vec![7, 300]);
        assert_eq!(m.mask(7), vec![false, true, false]);
        assert_eq!(m.foreground(), vec![false, true, true]);
        assert_eq!(format!("{m:?}"), "Image(3x1x1, 3 values)");
        assert!(Image::from_vec(2, 2, 1, vec![0u8; 3]).is_none());
    }
}
