//! trand as a Python package: `import trand` (see `python/trand/__init__.py` for the API and
//! `README.md` of the repository for an example).
//!
//! * [`scene`]: the scene the package works on, in plain Rust — reconstruct from in-memory views,
//!   render at any camera, update from one new view, save and load run folders.
//! * `python` (feature `python`, which maturin turns on): the native module `trand._trand`, flat
//!   buffers in and out; the Python layer checks shapes and dtypes and makes numpy arrays.
//! * `interrupt` (feature `python`): the work runs without the GIL, and Ctrl-C stops it.
//!
//! Without the `python` feature the crate builds and tests with no Python toolchain, so the
//! workspace's `cargo test` does not need one.

#[cfg(feature = "python")]
mod interrupt;
#[cfg(feature = "python")]
mod python;
pub mod scene;

pub use scene::{Scene, SceneError};
