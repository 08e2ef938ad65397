//! Depth, object ids, alpha and normals of a finished run at any camera (`trand render`).
//!
//! The depth is the one the run wrote for its test views, computed the same way
//! ([`crate::outputs::render_views`] shares [`median_depth`]): the median depth of the rasterizer with
//! the run's near plane and SH degree, clamped at the run's far clamp. A camera equal to a test camera
//! therefore gets the same bits. The other maps:
//! * object id: the run's object id of the most probable object channel where its probability is
//!   above ½ (the rule of the run's `objects/` images), else 0;
//! * alpha: `1 − T`, the opacity accumulated along the pixel's ray;
//! * normal: the alpha-weighted surfel normal, normalised, in the camera frame (OpenCV axes), zero
//!   where alpha is below 1e-6.

use rayon::prelude::*;
use trand_core::{Camera, Surfels};
use trand_io::{DepthMap, Image};
use trand_render::{Maps, RenderSettings, Rendered, render};

use crate::Result;

/// Everything `trand render` writes for one camera.
pub struct CameraMaps {
    pub depth: DepthMap,
    /// Object id per pixel (0 = background).
    pub ids: Image<u16>,
    pub alpha: Image<f32>,
    /// Unit camera-frame normals, 3 channels.
    pub normal: Image<f32>,
}

/// The run's rendering of one camera: RGB, object map and geometry at full resolution.
pub(crate) fn render_with_objects(
    surfels: &Surfels,
    camera: &Camera,
    settings: &RenderSettings,
) -> Result<Rendered<f32>> {
    let settings = RenderSettings {
        maps: Maps::RgbObjects,
        ..*settings
    };
    Ok(render::<f32, _>(surfels, camera, &settings)?)
}

/// The median depth clamped at `clamp` metres (0 where nothing reached transmittance ½).
pub(crate) fn median_depth(out: &Rendered<f32>, clamp: f32) -> DepthMap {
    let depth: Vec<f32> = out.median.iter().map(|&d| d.min(clamp)).collect();
    Image::from_vec(out.width, out.height, 1, depth).expect("sizes agree")
}

/// The most probable object channel of every pixel, if its probability is above ½.
pub(crate) fn argmax_channels(out: &Rendered<f32>) -> Vec<Option<usize>> {
    let k = out.num_objects;
    out.objects
        .par_chunks(k)
        .map(|p| {
            let (c, &m) = p
                .iter()
                .enumerate()
                .max_by(|a, b| a.1.total_cmp(b.1))
                .expect("K ≥ 1");
            (m > 0.5).then_some(c)
        })
        .collect()
}

/// Renders every map of one camera. `channels` maps object ids to channels (the run's
/// `object_channels`); `clamp` is the run's far clamp in metres.
pub fn render_at(
    surfels: &Surfels,
    camera: &Camera,
    settings: &RenderSettings,
    clamp: f32,
    channels: &[(u16, usize)],
) -> Result<CameraMaps> {
    let out = render_with_objects(surfels, camera, settings)?;
    let (w, h) = (out.width, out.height);
    let mut id_of = vec![0u16; out.num_objects];
    for &(id, c) in channels {
        if c < id_of.len() {
            id_of[c] = id;
        }
    }
    let ids = argmax_channels(&out)
        .into_iter()
        .map(|c| c.map_or(0, |c| id_of[c]))
        .collect();
    let normal = out
        .normal
        .chunks(3)
        .zip(&out.alpha)
        .flat_map(|(n, &a)| {
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            if a > 1e-6 && len > 0.0 {
                [n[0] / len, n[1] / len, n[2] / len]
            } else {
                [0.0; 3]
            }
        })
        .collect();
    Ok(CameraMaps {
        depth: median_depth(&out, clamp),
        ids: Image::from_vec(w, h, 1, ids).expect("sizes agree"),
        alpha: Image::from_vec(w, h, 1, out.alpha.clone()).expect("sizes agree"),
        normal: Image::from_vec(w, h, 3, normal).expect("sizes agree"),
    })
}
