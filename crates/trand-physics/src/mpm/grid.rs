//! The global grid of a substep: the chunk grids added in chunk order, then the grid update.

use glam::{IVec3, Vec4};

use super::config::{Ground, StepParams};

/// A dense grid over the box `[lo, lo + dims)`, x fastest, one `(mv_x, mv_y, mv_z, m)` per node
/// (after the grid update `(v_x, v_y, v_z, m)`).
#[derive(Clone, Copy)]
pub(super) struct GridView<'a> {
    pub nodes: &'a [Vec4],
    pub lo: IVec3,
    pub dims: IVec3,
}

/// Nodes of the box `[lo, hi + pad)`, computed in `i64` (no overflow for any `i32` corners).
pub(super) fn grid_nodes(lo: IVec3, hi: IVec3, pad: i64) -> usize {
    let d = (hi.as_i64vec3() - lo.as_i64vec3() + pad).max(glam::I64Vec3::ZERO);
    d.x.saturating_mul(d.y).saturating_mul(d.z) as usize
}

/// Adds the part of the grid `part` that lies in layer `gz` of the grid `[lo, lo + dims)`.
pub(super) fn add_layer(layer: &mut [Vec4], lo: IVec3, dims: IVec3, gz: i32, part: GridView) {
    let lz = gz - part.lo.z;
    if lz < 0 || lz >= part.dims.z {
        return;
    }
    let (cnx, cny) = (part.dims.x as usize, part.dims.y as usize);
    let off = part.lo - lo;
    for y in 0..cny {
        let src = &part.nodes[(lz as usize * cny + y) * cnx..][..cnx];
        let dst_start = (off.y as usize + y) * dims.x as usize + off.x as usize;
        for (d, s) in layer[dst_start..dst_start + cnx].iter_mut().zip(src) {
            *d += *s;
        }
    }
}

/// Grid update of one z-layer: momentum → velocity, gravity, sticky ground.
pub(super) fn update_layer(layer: &mut [Vec4], gz: i32, sp: &StepParams) {
    let below_ground = match sp.ground {
        Ground::Sticky { height } => (gz as f32) * sp.dx < height,
        Ground::None => false,
    };
    let dv = (sp.dt * sp.gravity).extend(0.0);
    for n in layer.iter_mut() {
        if n.w > 0.0 {
            let v = if below_ground {
                Vec4::ZERO
            } else {
                *n / n.w + dv
            };
            *n = v.truncate().extend(n.w);
        }
    }
}
