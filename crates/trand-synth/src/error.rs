//! Errors of the generator, each naming the field or file involved.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    #[error("invalid setting `{field}`: {reason}")]
    InvalidConfig { field: &'static str, reason: String },
    #[error("output folder {path} exists and is not empty (use --force to replace it)")]
    OutputNotEmpty { path: PathBuf },
    #[error("output path {path} exists and is not a folder")]
    OutputNotADirectory { path: PathBuf },
    #[error("cannot write {path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("cannot write PNG {path}: {source}")]
    Png { path: PathBuf, source: image::ImageError },
    #[error("cannot write JSON {path}: {source}")]
    Json { path: PathBuf, source: serde_json::Error },
}
