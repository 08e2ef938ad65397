//! Float depth maps as NumPy `.npy` files (`<f4`, C order, shape `(H, W)`), via `npyz`.

use std::path::Path;

use npyz::WriterBuilder;

use crate::error::IoError;
use crate::image::Image;
use crate::write::write_atomic;

/// Writes a float image as a float32 `.npy`, atomically: shape `(H, W)` for one channel, `(H, W, C)`
/// for more (e.g. normals).
pub fn write_npy_f32(path: &Path, img: &Image<f32>) -> Result<(), IoError> {
    let mut shape = vec![img.height as u64, img.width as u64];
    if img.channels != 1 {
        shape.push(img.channels as u64);
    }
    let mut buf = Vec::with_capacity(128 + img.data.len() * 4);
    let npy_err = |e: std::io::Error| IoError::Npy {
        path: path.into(),
        reason: e.to_string(),
    };
    {
        let mut w = npyz::WriteOptions::new()
            .default_dtype()
            .shape(&shape)
            .writer(&mut buf)
            .begin_nd()
            .map_err(npy_err)?;
        w.extend(img.data.iter().copied()).map_err(npy_err)?;
        w.finish().map_err(npy_err)?;
    }
    write_atomic(path, &buf)
}

/// Reads a `(H, W)` (or `(H, W, 1)`) float32 or float64 `.npy` in C order as a single-channel image.
pub fn read_npy_f32(path: &Path) -> Result<Image<f32>, IoError> {
    let bytes = std::fs::read(path).map_err(|e| IoError::io(path, e))?;
    let err = |reason: String| IoError::Npy {
        path: path.into(),
        reason,
    };
    let npy = npyz::NpyFile::new(&bytes[..]).map_err(|e| err(e.to_string()))?;
    let shape = npy.shape().to_vec();
    let (h, w) = match shape.as_slice() {
        [h, w] | [h, w, 1] => (*h, *w),
        s => return Err(err(format!("expected shape (H, W), found {s:?}"))),
    };
    if npy.order() != npyz::Order::C {
        return Err(err(
            "Fortran order is not supported; save with C order".into()
        ));
    }
    let descr = npy.dtype().descr().trim_matches('\'').to_string();
    let data: Vec<f32> = match descr.as_str() {
        "<f4" => npy.into_vec::<f32>().map_err(|e| err(e.to_string()))?,
        "<f8" => npy
            .into_vec::<f64>()
            .map_err(|e| err(e.to_string()))?
            .into_iter()
            .map(|v| v as f32)
            .collect(),
        d => return Err(err(format!("expected float32 ('<f4') data, found '{d}'"))),
    };
    let (w, h) = (
        u32::try_from(w).map_err(|_| err("too wide".into()))?,
        u32::try_from(h).map_err(|_| err("too tall".into()))?,
    );
    Image::from_vec(w, h, 1, data).ok_or_else(|| err("data length does not match the shape".into()))
}
