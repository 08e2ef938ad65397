//! One module per subcommand.
pub mod bench;
pub mod demo;
pub mod eval;
pub mod export;
pub mod info;
pub mod perturb;
pub mod reconstruct;
pub mod render;
pub mod synth;
pub mod update;

/// The name an enum value has in TOML and JSON (its serde name, given as `json!(value)`).
pub(crate) fn name_of(v: serde_json::Value) -> String {
    match v {
        serde_json::Value::String(s) => s,
        other => other.to_string(),
    }
}

/// `path` canonicalised where it exists, as `run.json` records folders.
pub(crate) fn canonical(path: &std::path::Path) -> String {
    path.canonicalize()
        .unwrap_or(path.to_path_buf())
        .to_string_lossy()
        .into_owned()
}
