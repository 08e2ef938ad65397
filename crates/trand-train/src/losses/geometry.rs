//! 2DGS geometric regularisers (2DGS `train.py`; reference notes §2.5, §4).
//!
//! **Normal consistency.** From a depth map, [`depth_to_normal`] unprojects every pixel with the
//! integer-pixel-centre convention of [`trand_core::camera`], `P = z·((x − cx)/fx, (y − cy)/fy, 1)`, and
//! takes central differences `a = P[y+1, x] − P[y−1, x]`, `b = P[y, x+1] − P[y, x−1]`; the normal is
//! `n = (a × b)/max(‖a × b‖, ε)` (facing the camera), zero on the one-pixel border. Then
//!
//! `L_n = mean_pixels (1 − Σ_ch N_rend · n·α)`,
//!
//! with α the rendered alpha, **detached** (no gradient). Both normals are in the camera frame (the dot
//! product is invariant under the camera-to-world rotation 2DGS applies to both). Gradients:
//! `∂L/∂N_rend = −n α / N_pix`; towards depth through `n(a, b)`: `∂n/∂c = (I − n nᵀ)/‖c‖`,
//! `∂/∂a = b × g_c`, `∂/∂b = g_c × a`, then `∂P/∂z = ray`. (2DGS itself unprojects with `cx = W/2`, half
//! a pixel off its rasterizer; trand uses the camera's `cx, cy` as given.)
//!
//! **Distortion.** The rasterizer accumulates the per-pixel distortion `Σ_i Σ_{j<i} w_i w_j (m_i − m_j)²`;
//! the loss is its mean, so the gradient is `1/N_pix` for every pixel.

use rayon::prelude::*;
use trand_core::{Intrinsics, Real};

/// `ε` of the normalisation (PyTorch `F.normalize` default).
const NORMALIZE_EPS: f64 = 1e-12;

/// Pinhole intrinsics in the loss's scalar type.
#[derive(Clone, Copy, Debug)]
pub struct Pinhole<R> {
    pub fx: R,
    pub fy: R,
    pub cx: R,
    pub cy: R,
}

impl<R: Real> Pinhole<R> {
    pub fn from_intrinsics(k: &Intrinsics) -> Self {
        Self {
            fx: R::from_f64(k.fx),
            fy: R::from_f64(k.fy),
            cx: R::from_f64(k.cx),
            cy: R::from_f64(k.cy),
        }
    }

    /// Camera-frame ray with z = 1 through the pixel centre `(col, row)`.
    #[inline]
    fn ray(&self, col: usize, row: usize) -> [R; 3] {
        [
            (R::from_f64(col as f64) - self.cx) / self.fx,
            (R::from_f64(row as f64) - self.cy) / self.fy,
            R::ONE,
        ]
    }
}

#[inline]
fn sub<R: Real>(a: [R; 3], b: [R; 3]) -> [R; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

#[inline]
fn cross<R: Real>(a: [R; 3], b: [R; 3]) -> [R; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

#[inline]
fn dot<R: Real>(a: [R; 3], b: [R; 3]) -> R {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Camera-frame points of a depth map.
fn unproject<R: Real>(depth: &[R], k: &Pinhole<R>, width: usize) -> Vec<[R; 3]> {
    depth
        .par_iter()
        .enumerate()
        .map(|(p, &z)| {
            let r = k.ray(p % width, p / width);
            [r[0] * z, r[1] * z, z]
        })
        .collect()
}

/// Difference vectors `(a, b)` at an interior pixel.
#[inline]
fn diffs<R: Real>(pts: &[[R; 3]], p: usize, width: usize) -> ([R; 3], [R; 3]) {
    (
        sub(pts[p + width], pts[p - width]),
        sub(pts[p + 1], pts[p - 1]),
    )
}

#[inline]
fn is_interior(p: usize, width: usize, height: usize) -> bool {
    let (c, r) = (p % width, p / width);
    c > 0 && r > 0 && c + 1 < width && r + 1 < height
}

/// Unit normals (camera frame, per pixel, zero on the border) of a depth map.
pub fn depth_to_normal<R: Real>(
    depth: &[R],
    k: &Pinhole<R>,
    width: usize,
    height: usize,
) -> Vec<[R; 3]> {
    assert_eq!(depth.len(), width * height, "depth map size");
    let pts = unproject(depth, k, width);
    let eps = R::from_f64(NORMALIZE_EPS);
    (0..depth.len())
        .into_par_iter()
        .map(|p| {
            if !is_interior(p, width, height) {
                return [R::ZERO; 3];
            }
            let (a, b) = diffs(&pts, p, width);
            let c = cross(a, b);
            let inv = R::ONE / dot(c, c).sqrt().max(eps);
            [c[0] * inv, c[1] * inv, c[2] * inv]
        })
        .collect()
}

/// Value and gradients of the normal-consistency loss.
#[derive(Clone, Debug)]
pub struct NormalConsistency<R> {
    pub value: R,
    /// `∂L/∂N_rend`, per pixel.
    pub grad_normal: Vec<[R; 3]>,
    /// `∂L/∂depth`, per pixel.
    pub grad_depth: Vec<R>,
}

/// `mean(1 − N_rend · n(depth)·α)` with α detached; normals in the camera frame, one `[x, y, z]` per pixel.
pub fn normal_consistency<R: Real>(
    rend_normal: &[[R; 3]],
    depth: &[R],
    alpha: &[R],
    k: &Pinhole<R>,
    width: usize,
    height: usize,
) -> NormalConsistency<R> {
    let n_pix = width * height;
    assert_eq!(rend_normal.len(), n_pix, "rendered normal map size");
    assert_eq!(depth.len(), n_pix, "depth map size");
    assert_eq!(alpha.len(), n_pix, "alpha map size");
    if n_pix == 0 {
        return NormalConsistency {
            value: R::ZERO,
            grad_normal: Vec::new(),
            grad_depth: Vec::new(),
        };
    }
    let inv_n = R::ONE / R::from_f64(n_pix as f64);
    let eps = R::from_f64(NORMALIZE_EPS);
    let pts = unproject(depth, k, width);
    // Per pixel: loss term, ∂/∂N_rend, and the gradients g_a, g_b on the two difference vectors.
    struct Px<R> {
        term: R,
        g_rend: [R; 3],
        g_a: [R; 3],
        g_b: [R; 3],
    }
    let px: Vec<Px<R>> = (0..n_pix)
        .into_par_iter()
        .map(|p| {
            let zero = [R::ZERO; 3];
            if !is_interior(p, width, height) {
                return Px {
                    term: R::ONE,
                    g_rend: zero,
                    g_a: zero,
                    g_b: zero,
                };
            }
            let (a, b) = diffs(&pts, p, width);
            let c = cross(a, b);
            let len = dot(c, c).sqrt();
            let inv = R::ONE / len.max(eps);
            let n = [c[0] * inv, c[1] * inv, c[2] * inv];
            let al = alpha[p];
            let rn = rend_normal[p];
            let term = R::ONE - al * dot(rn, n);
            let g_rend = [-al * n[0] * inv_n, -al * n[1] * inv_n, -al * n[2] * inv_n];
            let g_n = [
                -al * rn[0] * inv_n,
                -al * rn[1] * inv_n,
                -al * rn[2] * inv_n,
            ];
            let g_c = if len > eps {
                let d = dot(g_n, n);
                [
                    (g_n[0] - d * n[0]) * inv,
                    (g_n[1] - d * n[1]) * inv,
                    (g_n[2] - d * n[2]) * inv,
                ]
            } else {
                [g_n[0] * inv, g_n[1] * inv, g_n[2] * inv]
            };
            Px {
                term,
                g_rend,
                g_a: cross(b, g_c),
                g_b: cross(g_c, a),
            }
        })
        .collect();
    // Gather: P[p] enters a at p − W (+), at p + W (−), and b at p − 1 (+), at p + 1 (−).
    let grad_depth: Vec<R> = (0..n_pix)
        .into_par_iter()
        .map(|p| {
            let (col, row) = (p % width, p / width);
            let mut g = [R::ZERO; 3];
            let mut acc = |v: [R; 3], s: R| {
                g[0] += s * v[0];
                g[1] += s * v[1];
                g[2] += s * v[2];
            };
            if row >= 1 {
                acc(px[p - width].g_a, R::ONE);
            }
            if row + 1 < height {
                acc(px[p + width].g_a, -R::ONE);
            }
            if col >= 1 {
                acc(px[p - 1].g_b, R::ONE);
            }
            if col + 1 < width {
                acc(px[p + 1].g_b, -R::ONE);
            }
            dot(g, k.ray(col, row))
        })
        .collect();
    let value = px
        .chunks(4096)
        .map(|c| c.iter().fold(R::ZERO, |s, q| s + q.term))
        .fold(R::ZERO, |s, v| s + v)
        * inv_n;
    NormalConsistency {
        value,
        grad_normal: px.iter().map(|q| q.g_rend).collect(),
        grad_depth,
    }
}

/// Mean of the rendered distortion map and the (uniform) per-pixel gradient `1/N`.
pub fn distortion<R: Real>(dist: &[R]) -> (R, R) {
    if dist.is_empty() {
        return (R::ZERO, R::ZERO);
    }
    let inv_n = R::ONE / R::from_f64(dist.len() as f64);
    let sum = dist
        .chunks(4096)
        .map(|c| c.iter().fold(R::ZERO, |s, &v| s + v))
        .fold(R::ZERO, |s, v| s + v);
    (sum * inv_n, inv_n)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::{assert_grad_matches_fd, rand_vec};

    fn cam() -> Pinhole<f64> {
        Pinhole {
            fx: 50.0,
            fy: 45.0,
            cx: 4.5,
            cy: 3.0,
        }
    }

    #[test]
    fn fronto_parallel_plane_gives_normal_towards_camera() {
        let (w, h) = (8, 7);
        let depth = vec![1.3f64; w * h];
        let n = depth_to_normal(&depth, &cam(), w, h);
        for (p, np) in n.iter().enumerate() {
            if is_interior(p, w, h) {
                assert!(
                    (np[2] + 1.0).abs() < 1e-12 && np[0].abs() < 1e-12 && np[1].abs() < 1e-12,
                    "{np:?}"
                );
            } else {
                assert_eq!(*np, [0.0; 3]);
            }
        }
    }

    #[test]
    fn tilted_plane_normal_is_recovered() {
        // Plane n·X = d with n = normalize(0.3, −0.2, −1): depth along each ray z = d / (n·ray).
        let (w, h) = (9, 8);
        let k = cam();
        let nn = {
            let v = [0.3f64, -0.2, -1.0];
            let l = dot(v, v).sqrt();
            v.map(|x| x / l)
        };
        let depth: Vec<f64> = (0..w * h)
            .map(|p| -1.0 / dot(nn, k.ray(p % w, p / w)))
            .collect();
        let n = depth_to_normal(&depth, &k, w, h);
        for p in (0..w * h).filter(|&p| is_interior(p, w, h)) {
            for i in 0..3 {
                assert!(
                    (n[p][i] - nn[i]).abs() < 1e-9,
                    "pixel {p}: {:?} vs {:?}",
                    n[p],
                    nn
                );
            }
        }
    }

    #[test]
    fn normal_consistency_gradients_match_finite_differences() {
        let (w, h) = (6, 5);
        let k = cam();
        let depth = rand_vec(40, w * h, 0.8, 1.2);
        let alpha = rand_vec(41, w * h, 0.2, 1.0);
        let rn: Vec<[f64; 3]> = rand_vec(42, 3 * w * h, -1.0, 1.0)
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect();
        let r = normal_consistency(&rn, &depth, &alpha, &k, w, h);
        assert_grad_matches_fd(
            &depth,
            &r.grad_depth,
            |d| normal_consistency(&rn, d, &alpha, &k, w, h).value,
            1e-6,
            1e-8,
        );
        let flat: Vec<f64> = rn.iter().flatten().copied().collect();
        let gflat: Vec<f64> = r.grad_normal.iter().flatten().copied().collect();
        let as_normals = |f: &[f64]| {
            f.chunks_exact(3)
                .map(|c| [c[0], c[1], c[2]])
                .collect::<Vec<_>>()
        };
        assert_grad_matches_fd(
            &flat,
            &gflat,
            |f| normal_consistency(&as_normals(f), &depth, &alpha, &k, w, h).value,
            1e-6,
            1e-9,
        );
    }

    #[test]
    fn border_pixels_cost_one_and_get_no_gradient() {
        let (w, h) = (3, 3);
        let rn = vec![[0.0, 0.0, -1.0]; 9];
        let r = normal_consistency(&rn, &[1.0; 9], &[1.0; 9], &cam(), w, h);
        // Eight border pixels cost 1, the centre (fronto-parallel, agreeing normal) costs 0.
        assert!((r.value - 8.0 / 9.0).abs() < 1e-12);
        assert_eq!(r.grad_normal[0], [0.0; 3]);
    }

    #[test]
    fn distortion_is_the_mean_with_uniform_gradient() {
        let (v, g) = distortion(&[1.0f64, 2.0, 3.0, 6.0]);
        assert_eq!((v, g), (3.0, 0.25));
    }
}
