//! Losses with analytic gradients. Every loss returns its value and the gradient with respect to its
//! rendered input(s); the training loop scales and routes those into the rasterizer's backward pass.

pub mod band;
pub mod dice;
pub mod geometry;
pub mod knn;
pub mod object;
pub mod photometric;
