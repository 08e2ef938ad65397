//! The one error type of `trand-io`. Every variant names the file, and where it applies the field, so a
//! message alone tells the user what to fix.

use std::path::PathBuf;

/// Why a dataset, image, PLY or output file could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum IoError {
    #[error("missing file {path} ({what})")]
    Missing { path: PathBuf, what: String },
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: invalid JSON: {source}")]
    Json {
        path: PathBuf,
        #[source]
        source: serde_json::Error,
    },
    #[error("{path}: field `{field}`: {reason}")]
    Field {
        path: PathBuf,
        field: String,
        reason: String,
    },
    #[error("{path}: cannot decode image: {source}")]
    Image {
        path: PathBuf,
        #[source]
        source: image::ImageError,
    },
    #[error("{path}: expected {expected} image, found {found}")]
    PixelFormat {
        path: PathBuf,
        expected: &'static str,
        found: String,
    },
    #[error("{path}: size {found_w}x{found_h} differs from {field} size {expected_w}x{expected_h}")]
    SizeMismatch {
        path: PathBuf,
        field: String,
        found_w: u32,
        found_h: u32,
        expected_w: u32,
        expected_h: u32,
    },
    #[error("{path}: field `{field}`: pose contains a non-finite value")]
    NonFinitePose { path: PathBuf, field: String },
    #[error("{path}: field `{field}`: {reason}")]
    BadCamera {
        path: PathBuf,
        field: String,
        reason: String,
    },
    #[error(
        "{path}: field `{field}` is depth_scale {found}, but earlier frames use {expected}; all frames must agree"
    )]
    DepthScaleMismatch {
        path: PathBuf,
        field: String,
        found: f64,
        expected: f64,
    },
    #[error(
        "{path}: {field}: object id {id} does not fit {channels} object channels (ids must be 1..{channels}-1; 0 is background)"
    )]
    TooManyObjects {
        path: PathBuf,
        field: String,
        id: u32,
        channels: usize,
    },
    #[error(
        "{path}: not a recognised sequence (expected a BOP folder with train_0/, transforms_sparse_train.json, a nerfstudio transforms.json, or a KeyPose capture's NNNNNN_L.pbtxt files)"
    )]
    UnknownFormat { path: PathBuf },
    #[error("{path}: PLY: {reason}")]
    Ply { path: PathBuf, reason: String },
    #[error("{path}: NPY: {reason}")]
    Npy { path: PathBuf, reason: String },
    #[error("output {path}: {reason}")]
    Output { path: PathBuf, reason: String },
}

impl IoError {
    /// `Ok` when an image of `w × h` read from `path` has the camera's size `k`; else
    /// [`IoError::SizeMismatch`] naming the camera `field` that gave the expected size.
    pub(crate) fn check_size(
        w: u32,
        h: u32,
        k: &trand_core::Intrinsics,
        path: &std::path::Path,
        field: String,
    ) -> Result<(), Self> {
        if (w, h) == (k.width, k.height) {
            return Ok(());
        }
        Err(IoError::SizeMismatch {
            path: path.into(),
            field,
            found_w: w,
            found_h: h,
            expected_w: k.width,
            expected_h: k.height,
        })
    }

    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        let path = path.into();
        if source.kind() == std::io::ErrorKind::NotFound {
            return IoError::Missing {
                path,
                what: source.to_string(),
            };
        }
        IoError::Io { path, source }
    }

    pub(crate) fn field(
        path: impl Into<PathBuf>,
        field: impl Into<String>,
        reason: impl Into<String>,
    ) -> Self {
        IoError::Field {
            path: path.into(),
            field: field.into(),
            reason: reason.into(),
        }
    }
}
