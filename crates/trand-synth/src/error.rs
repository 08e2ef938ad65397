//! Errors of the generator, each naming the field or file involved (the underlying I/O error
//! is the `source`, printed by `{:#}` in the CLI).

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    #[error("invalid setting `{field}`: {reason}")]
    InvalidConfig { field: &'static str, reason: String },
    #[error("output folder {path} exists and is not empty (use --force to replace it)")]
    OutputNotEmpty { path: PathBuf },
    #[error(transparent)]
    Output(#[from] trand_io::IoError),
    #[error("output path {path} exists and is not a folder")]
    OutputNotADirectory { path: PathBuf },
    #[error("cannot create the output next to {path} (is the parent folder writable?)")]
    OutputUnwritable {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot write {path}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot write PNG {path}")]
    Png {
        path: PathBuf,
        source: image::ImageError,
    },
    #[error("cannot write JSON {path}")]
    Json {
        path: PathBuf,
        source: serde_json::Error,
    },
}
