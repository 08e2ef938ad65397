//! Per-tile buffer layout shared by the forward and backward kernels.
//!
//! The forward pass writes, for every tile, one block of `256 × channels` values in channel-planar
//! order (`block[c·256 + pixel]`, pixel = `ly·16 + lx`). The block holds both the rendered outputs and
//! the per-pixel state the backward pass needs (final transmittance, distortion moments); a second,
//! integer block holds the index of the last blended surfel and of the median surfel per pixel. The
//! blocks are converted to row-major images once the tiles are done.

use crate::constants::TILE_PIXELS;

/// Whether the geometric maps (expected and median depth, normal, distortion) are rendered. Training
/// on images alone (TRAN-D's default, with the 2DGS normal and distortion losses off) needs none of
/// them; skipping their accumulation saves about a quarter of the forward kernel's arithmetic.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum GeometryMaps {
    #[default]
    Rendered,
    /// Not rendered: `depth`, `median`, `normal` and `distortion` come back empty, and the backward pass
    /// accepts no gradient for `median` or `distortion` (it would need their forward state).
    Skipped,
}

/// Channel offsets inside a tile block. Mask and object channels exist only when requested; the object
/// channels are either K planes (the map) or, against a label map, one plane of per-tile sums
/// ([`crate::labels`]). The geometric planes (depth, median, normal, distortion and its two moments)
/// exist only when the geometry is rendered: a training step without geometric losses skips them, and
/// with them eight of its seventeen planes (half the block memory the forward pass writes and clears).
///
/// Order: `rgb, [mask], [obj…], alpha, t_final, [depth, median, normal×3, dist, m1, m2], [sums]`.
#[derive(Clone, Copy, Debug)]
pub struct Layout {
    pub num_objects: usize,
    pub has_mask: bool,
    pub has_objects: bool,
    pub geometry: GeometryMaps,
    pub rgb: usize,
    pub mask: usize,
    pub obj: usize,
    pub alpha: usize,
    pub t_final: usize,
    /// The geometric planes' offsets; meaningful only with [`GeometryMaps::Rendered`].
    pub depth: usize,
    pub median: usize,
    pub normal: usize,
    pub dist: usize,
    pub m1: usize,
    pub m2: usize,
    /// Plane of the per-tile object sums (`P` then `I`, 2K values), when rendering against labels.
    pub sums: Option<usize>,
    pub channels: usize,
}

impl Layout {
    pub fn new(
        num_objects: usize,
        has_mask: bool,
        has_objects: bool,
        geometry: GeometryMaps,
    ) -> Self {
        let rgb = 0;
        let mask = rgb + 3;
        let obj = mask + if has_mask { 3 } else { 0 };
        let alpha = obj + if has_objects { num_objects } else { 0 };
        let t_final = alpha + 1;
        let depth = t_final + 1;
        let median = depth + 1;
        let normal = median + 1;
        let dist = normal + 3;
        let m1 = dist + 1;
        let m2 = m1 + 1;
        let channels = match geometry {
            GeometryMaps::Rendered => m2 + 1,
            GeometryMaps::Skipped => depth,
        };
        Self {
            num_objects,
            has_mask,
            has_objects,
            geometry,
            rgb,
            mask,
            obj,
            alpha,
            t_final,
            depth,
            median,
            normal,
            dist,
            m1,
            m2,
            sums: None,
            channels,
        }
    }

    /// The layout with object sums instead of object planes.
    pub fn with_sums(num_objects: usize, has_mask: bool, geometry: GeometryMaps) -> Self {
        let l = Self::new(num_objects, has_mask, false, geometry);
        Self {
            sums: Some(l.channels),
            channels: l.channels + 1,
            ..l
        }
    }

    /// Whether the geometric planes exist.
    pub fn has_geometry(&self) -> bool {
        self.geometry == GeometryMaps::Rendered
    }

    /// Values per tile block.
    pub fn block(&self) -> usize {
        self.channels * TILE_PIXELS
    }
}

/// Per-pixel integer state: `last[p]` (one past the last blended surfel's list position, 0 = none) and
/// `median[p]` (list position of the median surfel, `u32::MAX` = none). Two planes of 256.
pub const INT_CHANNELS: usize = 2;
