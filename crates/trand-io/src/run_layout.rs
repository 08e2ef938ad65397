//! File names of a run folder, shared by the code that writes runs and `trand eval`, which reads them.
//!
//! ```text
//! RUN/run.json                 {"state": "t0" | "t1", ...}  (what was run)
//! RUN/depth/{frame:06}.npy     float32 (H, W) predicted depth in metres, 0 = no prediction,
//!                              one per test view of the state (test_0 for t0, test_1 for t1)
//! RUN/metrics.json             written by `trand eval`
//! ```

use std::path::{Path, PathBuf};

pub const RUN_JSON: &str = "run.json";
pub const METRICS_JSON: &str = "metrics.json";
pub const DEPTH_DIR: &str = "depth";

/// `RUN/depth/{frame:06}.npy`.
pub fn depth_path(run: &Path, frame: u32) -> PathBuf {
    run.join(DEPTH_DIR).join(format!("{frame:06}.npy"))
}
