//! The seam a second rasterizer plugs into: forward and backward behind one type.
//!
//! [`Rasterizer::forward`] renders the maps and keeps whatever its backward pass needs in a
//! [`Rasterizer::Frame`]; [`Rasterizer::backward`] turns gradients of those maps into gradients of the
//! surfel parameters. [`Cpu`] is this crate's tile rasterizer ([`crate::render`],
//! [`crate::render_object_sums`], [`crate::Rendered::backward`]) behind the trait, unchanged.
//!
//! A GPU backend (wgpu) is a port of the same six stages (see the crate doc): it implements this trait
//! with its own frame type (buffers on the device plus the maps read back), and the training loop,
//! written against the trait, needs no other change. The frame type is the backend's own because what
//! the backward pass needs (tile blocks, pair lists) lives wherever the forward pass ran.

use trand_core::{Camera, Real};

use crate::params::SurfelParams;
use crate::render::{
    Gradients, OutputGrads, RenderError, RenderSettings, Rendered, render, render_object_sums,
};

/// A differentiable surfel rasterizer.
pub trait Rasterizer<R: Real> {
    /// The forward pass's result: the rendered maps and the state the backward pass reads.
    type Frame;

    /// Renders `params` from `camera`. With `labels` (one object channel per pixel, row-major), the
    /// object channels are reduced to their sums against the labels instead of the K-channel map.
    fn forward<P: SurfelParams<R>>(
        &self,
        params: &P,
        camera: &Camera,
        settings: &RenderSettings,
        labels: Option<&[u8]>,
    ) -> Result<Self::Frame, RenderError>;

    /// Gradients of a loss with respect to every surfel parameter, from its gradients with respect to
    /// the maps of `frame` (which `forward` rendered from the same `params`).
    fn backward<P: SurfelParams<R>>(
        &self,
        frame: &Self::Frame,
        params: &P,
        grads: &OutputGrads<R>,
    ) -> Gradients<R>;
}

/// The CPU tile rasterizer of this crate.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Cpu;

impl<R: Real> Rasterizer<R> for Cpu {
    type Frame = Rendered<R>;

    fn forward<P: SurfelParams<R>>(
        &self,
        params: &P,
        camera: &Camera,
        settings: &RenderSettings,
        labels: Option<&[u8]>,
    ) -> Result<Rendered<R>, RenderError> {
        match labels {
            Some(labels) => render_object_sums(params, camera, settings, labels),
            None => render(params, camera, settings),
        }
    }

    fn backward<P: SurfelParams<R>>(
        &self,
        frame: &Rendered<R>,
        params: &P,
        grads: &OutputGrads<R>,
    ) -> Gradients<R> {
        frame.backward(params, grads)
    }
}
