//! Where the tests find the data that the repository does not hold: the Blender sequences and the real
//! photographs, `$TRAND_SHARED/data/...`, with `TRAND_SHARED` defaulting to `../shared` beside the
//! workspace root. A test that reads it is marked `#[ignore = "needs ../shared/data/..."]`, so the
//! README's test command lists it as ignored on a clone without the data; `-- --include-ignored` (or
//! `--ignored`) runs it, and a missing folder then fails the test, naming the path, instead of passing.
//!
//! Included by the test files that need it with `#[path = "../../../testdata/shared_data.rs"] mod
//! shared_data;` (one copy of the convention for every crate).
#![allow(dead_code)]

use std::path::PathBuf;

/// The shared folder: `$TRAND_SHARED`, else `../shared` beside the workspace root.
pub fn shared_root() -> PathBuf {
    std::env::var_os("TRAND_SHARED")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared"))
}

/// The folder `data/<rel>` of the shared folder, e.g. `blender/seq_101`. Panics, naming the path and
/// the variable, when it is not a directory.
pub fn shared_data(rel: &str) -> PathBuf {
    let path = shared_root().join("data").join(rel);
    assert!(
        path.is_dir(),
        "{} is missing: this test needs the shared data (README: Tests); \
         set TRAND_SHARED to the folder that holds data/",
        path.display()
    );
    path
}
