//! Float depth maps as NumPy `.npy` files (`<f4`, C order, shape `(H, W)`), via `npyz`. The reader
//! checks the header's shape against the bytes present before decoding (no allocation sized by an
//! unchecked header).

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

/// Checks the preamble (`\x93NUMPY`, version, header length) against the file's size (the decoder
/// allocates the header's stated length before reading it), and that the element count of the
/// header's `shape` fits in 64 bits (the decoder multiplies the dimensions unchecked).
fn check_header(bytes: &[u8]) -> Result<(), String> {
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err("not an NPY file (no \\x93NUMPY magic)".into());
    }
    let (len, start) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 if bytes.len() >= 12 => (
            u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
            12,
        ),
        v => return Err(format!("NPY version {v} is not supported")),
    };
    if len > bytes.len() - start {
        return Err(format!(
            "header of {len} bytes is longer than the file's {} bytes",
            bytes.len()
        ));
    }
    let header = String::from_utf8_lossy(&bytes[start..start + len]);
    let dims = shape_of(&header).ok_or("the header's 'shape' is not a tuple of integers")?;
    if dims
        .iter()
        .try_fold(1u64, |n, &d| n.checked_mul(d))
        .is_none()
    {
        return Err(format!("shape {dims:?} has more elements than 2^64"));
    }
    Ok(())
}

/// The dimensions in the header dictionary's `'shape': (...)`; `None` unless every one is an integer.
fn shape_of(header: &str) -> Option<Vec<u64>> {
    let rest = &header[header.find("'shape'")?..];
    let open = rest.find('(')?;
    let close = open + rest[open..].find(')')?;
    rest[open + 1..close]
        .split(',')
        .map(str::trim)
        .filter(|d| !d.is_empty())
        .map(|d| d.parse().ok())
        .collect()
}

/// Reads a `(H, W)` (or `(H, W, 1)`) float32 or float64 `.npy` in C order as a single-channel image.
pub fn read_npy_f32(path: &Path) -> Result<Image<f32>, IoError> {
    let bytes = std::fs::read(path).map_err(|e| IoError::io(path, e))?;
    let err = |reason: String| IoError::Npy {
        path: path.into(),
        reason,
    };
    check_header(&bytes).map_err(err)?;
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
    // The shape comes from the file: check that its data is there before anything is allocated.
    let item = match descr.as_str() {
        "<f8" => 8u64,
        _ => 4,
    };
    let need = h.checked_mul(w).and_then(|n| n.checked_mul(item));
    if need.is_none_or(|n| n > bytes.len() as u64) {
        return Err(err(format!(
            "shape ({h}, {w}) needs more data than the file's {} bytes",
            bytes.len()
        )));
    }
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
