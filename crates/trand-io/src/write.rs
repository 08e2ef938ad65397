//! Output files, written atomically.
//!
//! Every writer encodes into memory, writes `NAME.tmp` next to the target, flushes it to disk and
//! renames it over `NAME`. A rename within one directory is atomic, so an interrupted run leaves either
//! the old file or the new one, never half of one (at worst a stray `NAME.tmp`). [`RunDir`] does the
//! same for a whole output directory.
//!
//! * [`write_depth_png_mm`]: metres → 16-bit PNG in millimetres (rounded; clamped to 0..=65535;
//!   non-finite and negative values → 0), the BOP/TRAN-D ground-truth format.
//! * [`write_rgb_png`], [`write_gray8_png`]: 8-bit images (RGB, labels, probabilities scaled to 0..255).
//! * [`crate::npy::write_npy_f32`]: float32 `.npy` (exact).

use std::io::Write;
use std::path::{Path, PathBuf};

use image::ImageEncoder;

use crate::error::IoError;
use crate::image::{DepthMap, Image};

/// Millimetres per metre.
const MM_PER_M: f64 = 1000.0;

fn tmp_path(path: &Path) -> PathBuf {
    let mut name = path
        .file_name()
        .map(|n| n.to_os_string())
        .unwrap_or_default();
    name.push(".tmp");
    path.with_file_name(name)
}

/// Writes `bytes` to `path` atomically (temp file, fsync, rename). Creates missing parent folders.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), IoError> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| IoError::io(dir, e))?;
    }
    let tmp = tmp_path(path);
    let result = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    result.map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        IoError::io(path, e)
    })
}

fn encode_png(
    path: &Path,
    data: &[u8],
    w: u32,
    h: u32,
    color: image::ExtendedColorType,
) -> Result<Vec<u8>, IoError> {
    let mut out = Vec::new();
    image::codecs::png::PngEncoder::new(&mut out)
        .write_image(data, w, h, color)
        .map_err(|source| IoError::Image {
            path: path.into(),
            source,
        })?;
    Ok(out)
}

fn expect_channels<T>(img: &Image<T>, channels: u32, path: &Path) -> Result<(), IoError> {
    if img.channels != channels || img.data.len() != img.num_pixels() * channels as usize {
        return Err(IoError::PixelFormat {
            path: path.into(),
            expected: if channels == 3 {
                "3-channel"
            } else {
                "1-channel"
            },
            found: format!("{} channels, {} values", img.channels, img.data.len()),
        });
    }
    Ok(())
}

/// Metres to the 16-bit millimetre value stored in depth PNGs.
pub fn depth_to_mm_u16(m: f32) -> u16 {
    if !m.is_finite() || m <= 0.0 {
        return 0;
    }
    (m as f64 * MM_PER_M).round().min(u16::MAX as f64) as u16
}

/// Depth in metres as a 16-bit PNG in millimetres.
pub fn write_depth_png_mm(path: &Path, depth: &DepthMap) -> Result<(), IoError> {
    expect_channels(depth, 1, path)?;
    // The encoder takes 16-bit samples as native-endian bytes and stores them big-endian.
    let native: Vec<u8> = depth
        .data
        .iter()
        .flat_map(|&m| depth_to_mm_u16(m).to_ne_bytes())
        .collect();
    write_atomic(
        path,
        &encode_png(
            path,
            &native,
            depth.width,
            depth.height,
            image::ExtendedColorType::L16,
        )?,
    )
}

/// 16-bit single-channel PNG (instance maps with ids above 255, raw depth units).
pub fn write_gray16_png(path: &Path, img: &Image<u16>) -> Result<(), IoError> {
    expect_channels(img, 1, path)?;
    let native: Vec<u8> = img.data.iter().flat_map(|v| v.to_ne_bytes()).collect();
    write_atomic(
        path,
        &encode_png(
            path,
            &native,
            img.width,
            img.height,
            image::ExtendedColorType::L16,
        )?,
    )
}

/// 8-bit RGB PNG.
pub fn write_rgb_png(path: &Path, img: &Image<u8>) -> Result<(), IoError> {
    expect_channels(img, 3, path)?;
    write_atomic(
        path,
        &encode_png(
            path,
            &img.data,
            img.width,
            img.height,
            image::ExtendedColorType::Rgb8,
        )?,
    )
}

/// 8-bit single-channel PNG (labels, masks).
pub fn write_gray8_png(path: &Path, img: &Image<u8>) -> Result<(), IoError> {
    expect_channels(img, 1, path)?;
    write_atomic(
        path,
        &encode_png(
            path,
            &img.data,
            img.width,
            img.height,
            image::ExtendedColorType::L8,
        )?,
    )
}

/// A probability map in `[0, 1]` as an 8-bit PNG (`round(255·p)`, clamped; NaN → 0).
pub fn write_probability_png(path: &Path, img: &Image<f32>) -> Result<(), IoError> {
    expect_channels(img, 1, path)?;
    let data = img
        .data
        .iter()
        .map(|&p| {
            if p.is_nan() {
                0
            } else {
                (p.clamp(0.0, 1.0) * 255.0).round() as u8
            }
        })
        .collect();
    write_gray8_png(
        path,
        &Image {
            width: img.width,
            height: img.height,
            channels: 1,
            data,
        },
    )
}

/// An RGB image with values in `[0, 1]` as an 8-bit PNG (clamped, rounded; NaN → 0).
pub fn write_rgb_f32_png(path: &Path, img: &Image<f32>) -> Result<(), IoError> {
    expect_channels(img, 3, path)?;
    let data = img
        .data
        .iter()
        .map(|&p| {
            if p.is_nan() {
                0
            } else {
                (p.clamp(0.0, 1.0) * 255.0).round() as u8
            }
        })
        .collect();
    write_rgb_png(
        path,
        &Image {
            width: img.width,
            height: img.height,
            channels: 3,
            data,
        },
    )
}

/// An output directory built under a temporary name and renamed into place by [`RunDir::commit`].
///
/// Files go to [`RunDir::path`] (`TARGET.tmp-PID`, beside the target), which holds the marker of
/// folders trand wrote ([`crate::output`]) from the start. Dropping an uncommitted `RunDir` deletes
/// the temp folder, so an aborted run leaves nothing behind under the target name; the temp folders
/// of killed runs are removed by the next `RunDir` for the same target.
pub struct RunDir {
    /// The target as given (returned by the commit).
    given: PathBuf,
    /// The target resolved ([`crate::output::resolve_target`]).
    target: PathBuf,
    tmp: PathBuf,
    committed: bool,
}

impl RunDir {
    /// Starts a run directory for `target`, which must not exist yet (nor be the current folder or
    /// one of its ancestors). Errors name `target`, not the temporary folder.
    pub fn create(target: &Path) -> Result<Self, IoError> {
        let resolved = crate::output::resolve_target(target)?;
        if crate::output::occupied(&resolved) {
            return Err(IoError::Output {
                path: target.into(),
                reason: "already exists".into(),
            });
        }
        let name = resolved
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let prefix = format!("{name}.tmp-");
        let parent = resolved.parent().unwrap_or(Path::new("/"));
        crate::output::clean_stale_temps(parent, &prefix);
        let tmp = parent.join(format!("{prefix}{}", std::process::id()));
        if tmp.exists() {
            std::fs::remove_dir_all(&tmp).map_err(|e| IoError::io(&tmp, e))?;
        }
        let unwritable = |e: std::io::Error| IoError::Output {
            path: target.into(),
            reason: format!("cannot create a folder in {}: {e}", parent.display()),
        };
        std::fs::create_dir_all(&tmp).map_err(unwritable)?;
        let dir = Self {
            given: target.into(),
            target: resolved,
            tmp,
            committed: false,
        };
        crate::output::write_marker(&dir.tmp, crate::output::OutputKind::Run)?;
        Ok(dir)
    }

    /// Where to write files until the commit.
    pub fn path(&self) -> &Path {
        &self.tmp
    }

    /// Renames the temporary folder to the target; returns the target path.
    pub fn commit(mut self) -> Result<PathBuf, IoError> {
        if crate::output::occupied(&self.target) {
            return Err(IoError::Output {
                path: self.target.clone(),
                reason: "appeared while the run was being written; the new run is not kept".into(),
            });
        }
        std::fs::rename(&self.tmp, &self.target).map_err(|e| IoError::io(&self.target, e))?;
        self.committed = true;
        Ok(self.given.clone())
    }
}

impl Drop for RunDir {
    fn drop(&mut self) {
        if !self.committed {
            let _ = std::fs::remove_dir_all(&self.tmp);
        }
    }
}
