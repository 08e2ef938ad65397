//! TSDF fusion of depth maps (Curless & Levoy 1996) and surface extraction.
//!
//! Hand-written because no maintained Rust crate does TSDF fusion (the dependency survey found
//! none), and the algorithm is short: every voxel centre `p` is projected into each depth map;
//! with `z` its camera-frame depth and `D` the depth at the nearest pixel, the projective signed
//! distance `η = D − z` (positive in front of the surface) is truncated to
//! `φ = min(1, η / trunc)` and averaged with the voxel's running value,
//! `Φ ← (W Φ + φ) / (W + 1)`, `W ← W + 1` (unit weight per observation). Voxels with
//! `η < −trunc` (far behind the observed surface) are left untouched, as are voxels outside the
//! image, beyond `max_depth`, or where `D` is 0 / not finite (no depth).
//!
//! Depth maps hold camera-frame z in metres (OpenCV z, not ray length), row-major `H × W`, pixel
//! `(i, j)` (column, row) at index `j·W + i`, sampled at integer pixel centres (the
//! [`trand_core::camera`] convention); the voxel takes the nearest pixel, like Open3D.
//!
//! Buffer layout: `tsdf` and `weight` are `[z][y][x]`, x fastest; voxel `(i, j, k)` has its
//! centre at `bounds_min + (i + ½, j + ½, k + ½)·voxel`. Integration runs in parallel over
//! z-layers; each voxel is independent, so the result does not depend on the thread count.
//!
//! Extraction runs surface nets (fast-surface-nets) on `Φ`, negative inside, then drops every
//! vertex whose 2×2×2 voxel cell touches an unobserved voxel (`W = 0`): otherwise the border of
//! the truncation band behind a surface, next to never-seen voxels, would produce a second,
//! spurious surface (Open3D's marching cubes skips such cubes in the same way).

use fast_surface_nets::ndshape::{RuntimeShape, Shape};
use fast_surface_nets::{SurfaceNetsBuffer, surface_nets};
use glam::DVec3;
use rayon::prelude::*;
use trand_core::{Camera, Mesh};

use crate::mesh::remove_small_components;

/// Refuse volumes with more voxels than this (2²⁸ voxels = 2 GiB of `tsdf` + `weight`).
pub const MAX_VOXELS: usize = 1 << 28;

/// Why a volume cannot be built or a depth map integrated.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum TsdfError {
    #[error("bounds {min:?}..{max:?} are empty or not finite")]
    BadBounds { min: [f32; 3], max: [f32; 3] },
    #[error("voxel size {0} must be finite and positive")]
    BadVoxel(f32),
    #[error("the volume would have {voxels} voxels (max {max})")]
    TooManyVoxels { voxels: usize, max: usize },
    #[error("depth map has {got} values, the camera needs {width}x{height}")]
    DepthSize { got: usize, width: u32, height: u32 },
    #[error("truncation {trunc} and max depth {max_depth} must be finite and positive")]
    BadTruncation { trunc: f32, max_depth: f32 },
}

/// Fusion parameters. [`TsdfSettings::tran_d`] gives the authors' choice (Open3D
/// `ScalableTSDFVolume` in `GaussianExtractor.extract_mesh_bounded`): depth range `2·radius`,
/// voxel `range / 256`, truncation `5·voxel`, with `radius` the scene radius of the cameras
/// ([`crate::virtual_views::scene_radius`]).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TsdfSettings {
    pub voxel: f32,
    pub trunc: f32,
    pub max_depth: f32,
}

impl TsdfSettings {
    /// Voxels across the depth range in the authors' setting.
    pub const VOXELS_PER_RANGE: f32 = 256.0;
    /// Truncation in voxels in the authors' setting.
    pub const TRUNC_VOXELS: f32 = 5.0;

    pub fn tran_d(radius: f32) -> Self {
        let max_depth = 2.0 * radius;
        let voxel = max_depth / Self::VOXELS_PER_RANGE;
        Self {
            voxel,
            trunc: Self::TRUNC_VOXELS * voxel,
            max_depth,
        }
    }
}

/// A dense truncated signed distance volume.
#[derive(Clone, Debug)]
pub struct TsdfVolume {
    origin: DVec3,
    voxel: f64,
    dims: [usize; 3],
    tsdf: Vec<f32>,
    weight: Vec<f32>,
}

impl TsdfVolume {
    /// An empty (all unobserved) volume covering `[bounds_min, bounds_max]` with cubic voxels.
    pub fn new(bounds_min: [f32; 3], bounds_max: [f32; 3], voxel: f32) -> Result<Self, TsdfError> {
        if !(voxel.is_finite() && voxel > 0.0) {
            return Err(TsdfError::BadVoxel(voxel));
        }
        let ok = (0..3).all(|k| {
            bounds_min[k].is_finite() && bounds_max[k].is_finite() && bounds_max[k] > bounds_min[k]
        });
        if !ok {
            return Err(TsdfError::BadBounds {
                min: bounds_min,
                max: bounds_max,
            });
        }
        let dims: [usize; 3] = std::array::from_fn(|k| {
            (((bounds_max[k] - bounds_min[k]) / voxel).ceil() as usize).max(2)
        });
        let voxels = dims
            .iter()
            .try_fold(1usize, |a, &d| a.checked_mul(d))
            .unwrap_or(usize::MAX);
        if voxels > MAX_VOXELS {
            return Err(TsdfError::TooManyVoxels {
                voxels,
                max: MAX_VOXELS,
            });
        }
        Ok(Self {
            origin: DVec3::from_array(bounds_min.map(f64::from)),
            voxel: voxel as f64,
            dims,
            tsdf: vec![1.0; voxels],
            weight: vec![0.0; voxels],
        })
    }

    /// Voxels per axis `[x, y, z]`.
    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }

    pub fn voxel_size(&self) -> f32 {
        self.voxel as f32
    }

    /// World position of voxel `(i, j, k)`'s centre.
    pub fn voxel_center(&self, i: usize, j: usize, k: usize) -> DVec3 {
        self.origin + (DVec3::new(i as f64, j as f64, k as f64) + 0.5) * self.voxel
    }

    /// Truncated SDF values (`[z][y][x]`, in units of `trunc`, 1 where unobserved).
    pub fn tsdf(&self) -> &[f32] {
        &self.tsdf
    }

    /// Accumulated weights (observations per voxel).
    pub fn weights(&self) -> &[f32] {
        &self.weight
    }

    /// Fuses one depth map (see the module docs for the update rule and depth convention).
    pub fn integrate(
        &mut self,
        camera: &Camera,
        depth: &[f32],
        trunc: f32,
        max_depth: f32,
    ) -> Result<(), TsdfError> {
        let k = camera.intrinsics;
        if depth.len() != k.num_pixels() {
            return Err(TsdfError::DepthSize {
                got: depth.len(),
                width: k.width,
                height: k.height,
            });
        }
        if !(trunc.is_finite() && trunc > 0.0 && max_depth.is_finite() && max_depth > 0.0) {
            return Err(TsdfError::BadTruncation { trunc, max_depth });
        }
        let (r, t) = (camera.rotation(), camera.translation());
        let [nx, ny, _] = self.dims;
        let (origin, voxel) = (self.origin, self.voxel);
        let (w, h) = (k.width as usize, k.height as usize);
        self.tsdf
            .par_chunks_mut(nx * ny)
            .zip(self.weight.par_chunks_mut(nx * ny))
            .enumerate()
            .for_each(|(kz, (tsdf, weight))| {
                for jy in 0..ny {
                    // p_cam is affine in the voxel index: start of the row, then one step per x.
                    let p0 = origin + (DVec3::new(0.0, jy as f64, kz as f64) + 0.5) * voxel;
                    let c0 = r * p0 + t;
                    let step = r.x_axis * voxel;
                    for ix in 0..nx {
                        let c = c0 + step * ix as f64;
                        if c.z <= 0.0 {
                            continue;
                        }
                        let u = (k.fx * c.x / c.z + k.cx).round();
                        let v = (k.fy * c.y / c.z + k.cy).round();
                        if !(u >= 0.0 && v >= 0.0 && u < w as f64 && v < h as f64) {
                            continue;
                        }
                        let d = depth[v as usize * w + u as usize];
                        if !(d.is_finite() && d > 0.0 && d <= max_depth) {
                            continue;
                        }
                        let eta = d as f64 - c.z;
                        if eta < -(trunc as f64) {
                            continue;
                        }
                        let phi = (eta / trunc as f64).min(1.0) as f32;
                        let n = jy * nx + ix;
                        let wv = weight[n];
                        tsdf[n] = (wv * tsdf[n] + phi) / (wv + 1.0);
                        weight[n] = wv + 1.0;
                    }
                }
            });
        Ok(())
    }

    /// The zero level set as an indexed mesh in world coordinates (outward normals), after the
    /// connected-component cleanup of [`remove_small_components`].
    pub fn extract_mesh(&self) -> Mesh {
        let mut mesh = self.extract_raw_mesh();
        remove_small_components(&mut mesh);
        mesh
    }

    /// The zero level set without the component cleanup.
    pub fn extract_raw_mesh(&self) -> Mesh {
        let [nx, ny, nz] = self.dims;
        let shape = RuntimeShape::<u32, 3>::new([nx as u32, ny as u32, nz as u32]);
        let mut buf = SurfaceNetsBuffer::default();
        surface_nets(
            &self.tsdf,
            &shape,
            [0; 3],
            [nx as u32 - 1, ny as u32 - 1, nz as u32 - 1],
            &mut buf,
        );
        // A vertex sits in the cell with min corner `surface_points[i]`; keep it only when all
        // 8 corner voxels were observed.
        let observed = |c: [u32; 3]| {
            (0..8u32).all(|o| {
                let p = [c[0] + (o & 1), c[1] + ((o >> 1) & 1), c[2] + (o >> 2)];
                self.weight[shape.linearize(p) as usize] > 0.0
            })
        };
        let keep: Vec<bool> = buf.surface_points.iter().map(|&c| observed(c)).collect();
        let mut mesh = Mesh {
            vertices: buf
                .positions
                .iter()
                .map(|p| {
                    (self.origin + (DVec3::from_array(p.map(f64::from)) + 0.5) * self.voxel)
                        .as_vec3()
                        .to_array()
                })
                .collect(),
            normals: buf
                .normals
                .iter()
                .map(|n| {
                    glam::Vec3::from_array(*n)
                        .try_normalize()
                        .unwrap_or(glam::Vec3::Z)
                        .to_array()
                })
                .collect(),
            faces: buf
                .indices
                .chunks_exact(3)
                .map(|t| [t[0], t[1], t[2]])
                .filter(|t| t.iter().all(|&v| keep[v as usize]))
                .collect(),
            ..Mesh::default()
        };
        mesh.remove_unreferenced_vertices();
        mesh
    }
}
