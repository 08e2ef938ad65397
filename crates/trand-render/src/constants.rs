//! Constants of the 2DGS surfel rasterizer, each with its reason. They reproduce the CUDA rasterizer
//! that TRAN-D builds on (`diff-surfel-rasterization`), so trained models behave the same.

/// Tile edge in pixels. 16×16 = 256 pixels: one CUDA block in the reference, and on the CPU a tile's
/// per-pixel state (~40 floats per pixel) stays in L1/L2 cache.
pub const TILE: u32 = 16;

/// Pixels per tile.
pub const TILE_PIXELS: usize = (TILE * TILE) as usize;

/// Bounding-box cutoff in standard deviations: a surfel is binned into the tiles its 3σ contour touches.
pub const SIGMA_CUTOFF: f64 = 3.0;

/// Inverse square of the screen-space low-pass filter's standard deviation (σ = √2/2 px), 2DGS eq. 11:
/// `ρ₂ = 2·|c − x|²`. It keeps surfels seen edge-on or smaller than a pixel visible.
pub const FILTER_INV_SQUARE: f64 = 2.0;

/// The filter's reach in pixels used for the binning radius, `3 · √2/2` (the reference's `3·FilterSize`).
/// The truncated literal is the reference's own (`FilterSize = 0.707106`), kept so radii match it exactly.
#[allow(clippy::approx_constant)]
pub const FILTER_RADIUS: f64 = 3.0 * 0.707106;

/// Surfels whose centre is this close to the camera (metres, camera z) are culled, and per-pixel
/// intersections closer than this are skipped: the reference's `near_n`.
pub const DEFAULT_NEAR: f64 = 0.2;

/// Far plane of the NDC depth mapping used by the distortion loss (the reference's `far_n`).
pub const FAR: f64 = 100.0;

/// Upper bound on a single alpha, so that transmittance can always be recovered by division in the
/// backward pass (`T_i = T_{i+1} / (1 − α_i)`).
pub const MAX_ALPHA: f64 = 0.99;

/// Alphas below this are skipped: they cannot change an 8-bit image.
pub const MIN_ALPHA: f64 = 1.0 / 255.0;

/// A pixel stops before the surfel that would take its transmittance below this value.
pub const MIN_TRANSMITTANCE: f64 = 1e-4;

/// Transmittance threshold defining the median depth: the depth of the last surfel blended while the
/// transmittance in front of it was still above one half.
pub const MEDIAN_TRANSMITTANCE: f64 = 0.5;
