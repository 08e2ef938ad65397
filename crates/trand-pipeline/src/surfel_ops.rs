//! Per-surfel helpers the update's stages share (simulation, contact, relocalisation).

use glam::Quat;
use trand_core::{Surfels, math::softmax};

/// Probability of channel `c` for every surfel.
pub(crate) fn channel_probs(s: &Surfels, c: usize) -> Vec<f32> {
    let k = s.num_objects;
    let mut p = vec![0.0f32; k];
    (0..s.len())
        .map(|i| {
            softmax(&s.obj_logits[i * k..(i + 1) * k], &mut p);
            p[c]
        })
        .collect()
}

/// A surfel orientation (stored `[w, x, y, z]`) turned by the rotation `r`: `r · q/|q|`.
pub(crate) fn turn(r: Quat, q: [f32; 4]) -> [f32; 4] {
    let q = r * Quat::from_xyzw(q[1], q[2], q[3], q[0]).normalize();
    [q.w, q.x, q.y, q.z]
}
