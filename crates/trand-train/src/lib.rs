//! Training of trand's surfels, independent of the rasterizer:
//!
//! * [`losses`]: photometric (L1 + D-SSIM), Dice on the object map, TRAN-D's object-aware 3D loss and
//!   2DGS's normal-consistency and distortion losses, each with an analytic gradient.

pub mod losses;

#[cfg(test)]
mod testutil;
