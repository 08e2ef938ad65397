//! The camera in the rasterizer's precision.

use trand_core::{Camera, Real};

/// Camera data the kernels need, converted once per render.
#[derive(Clone, Copy, Debug)]
pub struct CamR<R> {
    pub fx: R,
    pub fy: R,
    pub cx: R,
    pub cy: R,
    pub width: u32,
    pub height: u32,
    /// World-to-camera rotation, row-major.
    pub rot: [[R; 3]; 3],
    pub trans: [R; 3],
    /// Camera centre in world coordinates.
    pub center: [R; 3],
    pub near: R,
}

impl<R: Real> CamR<R> {
    pub fn new(c: &Camera, near: f64) -> Self {
        let k = &c.intrinsics;
        let center = c.center();
        Self {
            fx: R::from_f64(k.fx),
            fy: R::from_f64(k.fy),
            cx: R::from_f64(k.cx),
            cy: R::from_f64(k.cy),
            width: k.width,
            height: k.height,
            rot: c.r_w2c.map(|r| r.map(R::from_f64)),
            trans: c.t_w2c.map(R::from_f64),
            center: [
                R::from_f64(center.x),
                R::from_f64(center.y),
                R::from_f64(center.z),
            ],
            near: R::from_f64(near),
        }
    }

    /// `R · v`.
    #[inline]
    pub fn rotate(&self, v: [R; 3]) -> [R; 3] {
        let r = &self.rot;
        [
            r[0][0] * v[0] + r[0][1] * v[1] + r[0][2] * v[2],
            r[1][0] * v[0] + r[1][1] * v[1] + r[1][2] * v[2],
            r[2][0] * v[0] + r[2][1] * v[1] + r[2][2] * v[2],
        ]
    }

    /// `Rᵀ · v`.
    #[inline]
    pub fn rotate_t(&self, v: [R; 3]) -> [R; 3] {
        let r = &self.rot;
        [
            r[0][0] * v[0] + r[1][0] * v[1] + r[2][0] * v[2],
            r[0][1] * v[0] + r[1][1] * v[1] + r[2][1] * v[2],
            r[0][2] * v[0] + r[1][2] * v[1] + r[2][2] * v[2],
        ]
    }

    pub fn tiles_x(&self) -> u32 {
        self.width.div_ceil(crate::constants::TILE)
    }

    pub fn tiles_y(&self) -> u32 {
        self.height.div_ceil(crate::constants::TILE)
    }
}
