//! Reading and writing trand's data.
//!
//! * Sequences: [`read_sequence`] auto-detects one of four layouts and returns a [`Sequence`] of
//!   [`View`]s (camera + optional RGB, instance map and depth):
//!   [`bop`] (BlenderProc/BOP folders, our Blender data), [`transforms`] (the TRAN-D authors'
//!   `transforms_sparse_*.json`), [`nerfstudio`] (`transforms.json`), [`keypose`] (a KeyPose
//!   capture as the dataset ships it). All cameras come out in trand's
//!   convention (OpenCV axes, world-to-camera, metres, integer pixel centres; see `trand_core::camera`).
//! * [`select_train_views`]: the paper's 3/6/12 training views.
//! * [`textproto`]: a small protobuf text-format reader (KeyPose's camera files).
//! * [`ply`]: surfel PLY (2DGS names + TRAN-D extras), [`mesh`]: triangle-mesh PLY, [`points`]:
//!   point-cloud PLY, [`splats`]: 3DGS PLY for splat viewers.
//! * [`write`], [`npy`]: depth PNG (mm), float `.npy`, RGB/label PNGs, all written atomically; [`RunDir`].
//! * [`arrays`]: cameras and sequences from in-memory arrays (a host program's images and poses).
//! * [`run_manifest`]: `run.json`, the typed record of a run folder.
//! * [`output`]: checks of output folders before work starts, the marker of folders trand wrote, and
//!   the clean-up of temporary folders left by killed runs.

pub mod arrays;
pub mod bop;
pub mod cameras;
pub mod error;
pub mod image;
mod json;
pub mod keypose;
pub mod mesh;
pub mod nerfstudio;
pub mod npy;
pub mod output;
mod paths;
pub mod perturb;
pub mod ply;
pub mod points;
mod pose;
pub mod run_layout;
pub mod run_manifest;
pub mod scratch;
pub mod splats;
pub mod textproto;
pub mod transforms;
pub mod view;
pub mod write;

use std::path::Path;

pub use arrays::{ArrayError, camera_from_matrices, view_from_arrays};
pub use cameras::{NamedCamera, cameras_to_json, read_cameras_json};
pub use error::IoError;
pub use image::{
    DepthMap, Image, InstanceMap, Rgb8Image, read_depth_png, read_gray8, read_gray16,
    read_instance_mask, read_rgb8,
};
pub use mesh::write_mesh_ply;
pub use npy::{read_npy_f32, write_npy_f32};
pub use ply::{read_surfels_ply, write_surfels_ply};
pub use points::{PointCloud, write_point_cloud_ply};
pub use run_manifest::RunManifest;
pub use scratch::ScratchDir;
pub use splats::write_splats_ply;
pub use view::{
    Load, LoadOptions, Sequence, Split, State, TrainSelection, View, ViewCount, select_train_views,
};
pub use write::{
    RunDir, write_atomic, write_depth_png_mm, write_gray8_png, write_gray16_png,
    write_probability_png, write_rgb_f32_png, write_rgb_png,
};

/// The on-disk layout of a sequence.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    Bop,
    Transforms,
    Nerfstudio,
    KeyPose,
}

/// Which layout `path` holds: a folder (checked in the order BOP, authors' transforms, nerfstudio,
/// KeyPose), or
/// a JSON file whose name says it (`transforms_sparse_*.json` → its folder as authors' transforms,
/// `transforms.json` → nerfstudio).
pub fn detect_format(path: &Path) -> Result<(Format, std::path::PathBuf), IoError> {
    if path.is_file() {
        let dir = path.parent().unwrap_or(Path::new(".")).to_path_buf();
        let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
        return match name {
            n if n.starts_with("transforms_sparse_") => Ok((Format::Transforms, dir)),
            nerfstudio::T0_FILE => Ok((Format::Nerfstudio, dir)),
            _ => Err(IoError::UnknownFormat { path: path.into() }),
        };
    }
    if !path.exists() {
        return Err(IoError::Missing {
            path: path.into(),
            what: "sequence folder".into(),
        });
    }
    if bop::is_bop(path) {
        Ok((Format::Bop, path.into()))
    } else if transforms::is_transforms(path) {
        Ok((Format::Transforms, path.into()))
    } else if nerfstudio::is_nerfstudio(path) {
        Ok((Format::Nerfstudio, path.into()))
    } else if keypose::is_keypose(path) {
        Ok((Format::KeyPose, path.into()))
    } else {
        Err(IoError::UnknownFormat { path: path.into() })
    }
}

/// Reads a sequence of any supported layout with everything loaded ([`LoadOptions::default`]).
pub fn read_sequence(path: impl AsRef<Path>) -> Result<Sequence, IoError> {
    read_sequence_with(path, &LoadOptions::default())
}

/// Reads a sequence of any supported layout, decoding what `opts` asks for.
pub fn read_sequence_with(path: impl AsRef<Path>, opts: &LoadOptions) -> Result<Sequence, IoError> {
    let (format, root) = detect_format(path.as_ref())?;
    match format {
        Format::Bop => bop::read_bop(&root, opts),
        Format::Transforms => transforms::read_transforms(&root, opts),
        Format::Nerfstudio => nerfstudio::read_nerfstudio(&root, opts),
        Format::KeyPose => keypose::read_keypose(&root, opts),
    }
}
