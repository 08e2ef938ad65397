//! TRAN-D's random initialisation (reference notes §2.3), with bounds that can come from the cameras.
//!
//! Points fill a slab standing on the support plane z = 0: `num_volume` uniform in the box
//! `[x0, x1] × [y0, y1] × [0, h]` and `num_per_face` uniform on each of its four vertical faces
//! (y = y0, y = y1, x = x0, x = x1; no top, no bottom face), generated in TRAN-D's order
//! (face y0, volume, face y1, face x0, face x1). TRAN-D's box is `[−0.5, 0.5]² × [0, 0.1]` with 20 000 points
//! per group ([`SlabBox::tran_d`]).
//!
//! When the bounds are not given they are derived from the cameras ([`SlabBox::from_cameras`]): the
//! centre is the least-squares point closest to all optical axes (`Σ (I − d dᵀ)(p − c) = 0`), dropped
//! onto the support plane (the slab starts at z = 0 whatever the focus height); the half-extent is the
//! mean camera distance to that point times a factor, and the height a fixed fraction of the half-extent
//! (TRAN-D's 0.1 / 0.5).
//!
//! Attributes: colour and mask colour `f_dc = rgb_to_dc(127/255)` (grey ≈ 0.5), object logits all equal
//! (uniform softmax), opacity `logit(0.1)`, both log-scales `ln √(mean squared distance to the 3 nearest
//! other points)` (clamped below at 1e-7, as 3DGS's `distCUDA2`), quaternions uniform in `[0, 1)⁴`
//! (normalised at use).

use std::num::NonZero;

use glam::DVec3;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use trand_core::math::logit;
use trand_core::sh::rgb_to_dc;
use trand_core::{Camera, Surfels, SurfelsError};

/// Why the initial surfels cannot be made.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum InitError {
    #[error("bounds must come from the cameras, but there are none")]
    NoCameras,
    #[error(
        "the cameras' optical axes do not determine a focus point (all parallel and not looking down)"
    )]
    DegenerateCameras,
    #[error("slab box is empty or not finite: min {min:?}, max {max:?}")]
    BadBox { min: [f64; 3], max: [f64; 3] },
    #[error(transparent)]
    Surfels(#[from] SurfelsError),
}

/// An axis-aligned box whose four vertical faces and volume are seeded.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SlabBox {
    pub min: [f64; 3],
    pub max: [f64; 3],
}

/// TRAN-D's slab height over its half-extent: 0.1 m over 0.5 m.
pub const TRAN_D_HEIGHT_RATIO: f64 = 0.2;

impl SlabBox {
    /// TRAN-D's fixed box `[−0.5, 0.5]² × [0, 0.1]` (metres).
    pub fn tran_d() -> Self {
        Self {
            min: [-0.5, -0.5, 0.0],
            max: [0.5, 0.5, 0.1],
        }
    }

    /// Box centred under the cameras' common focus (see the module docs).
    pub fn from_cameras(
        cameras: &[Camera],
        distance_factor: f64,
        height_ratio: f64,
    ) -> Result<Self, InitError> {
        let f = focus_point(cameras)?;
        let dist = cameras
            .iter()
            .map(|c| (c.center() - f).length())
            .sum::<f64>()
            / cameras.len() as f64;
        let half = distance_factor * dist;
        let b = Self {
            min: [f.x - half, f.y - half, 0.0],
            max: [f.x + half, f.y + half, height_ratio * half],
        };
        b.validate()?;
        Ok(b)
    }

    fn validate(&self) -> Result<(), InitError> {
        let ok = (0..3).all(|k| {
            self.min[k].is_finite() && self.max[k].is_finite() && self.max[k] > self.min[k]
        });
        if ok {
            Ok(())
        } else {
            Err(InitError::BadBox {
                min: self.min,
                max: self.max,
            })
        }
    }
}

/// [`trand_core::camera::focus_point`], with the reason as an error when there is none.
pub fn focus_point(cameras: &[Camera]) -> Result<DVec3, InitError> {
    if cameras.is_empty() {
        return Err(InitError::NoCameras);
    }
    trand_core::camera::focus_point(cameras).ok_or(InitError::DegenerateCameras)
}

/// Where the slab comes from.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SlabBounds {
    Explicit(SlabBox),
    /// [`SlabBox::from_cameras`] with these factors.
    FromCameras {
        distance_factor: f64,
        height_ratio: f64,
    },
}

/// Random initialisation settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct InitConfig {
    pub num_volume: usize,
    pub num_per_face: usize,
    pub bounds: SlabBounds,
    /// Initial opacity (TRAN-D: 0.1).
    pub opacity: f32,
    /// Initial grey level of colour and mask colour (TRAN-D: uint8 127).
    pub grey: f32,
    pub seed: u64,
}

impl Default for InitConfig {
    fn default() -> Self {
        Self {
            num_volume: 20_000,
            num_per_face: 20_000,
            bounds: SlabBounds::FromCameras {
                distance_factor: 1.0,
                height_ratio: TRAN_D_HEIGHT_RATIO,
            },
            opacity: 0.1,
            grey: 127.0 / 255.0,
            seed: 0,
        }
    }
}

/// Slab points in TRAN-D's group order.
pub fn slab_points(
    b: &SlabBox,
    num_volume: usize,
    num_per_face: usize,
    rng: &mut Pcg64,
) -> Vec<[f32; 3]> {
    let mut pts = Vec::with_capacity(num_volume + 4 * num_per_face);
    let lerp = |k: usize, u: f64| b.min[k] + (b.max[k] - b.min[k]) * u;
    // (fixed axis, value) per face; None = the volume.
    let groups = [
        Some((1, b.min[1])),
        None,
        Some((1, b.max[1])),
        Some((0, b.min[0])),
        Some((0, b.max[0])),
    ];
    for g in groups {
        let count = if g.is_some() {
            num_per_face
        } else {
            num_volume
        };
        for _ in 0..count {
            let mut p = [0.0f64; 3];
            for (k, v) in p.iter_mut().enumerate() {
                *v = lerp(k, rng.random::<f64>());
            }
            if let Some((axis, value)) = g {
                p[axis] = value;
            }
            pts.push(p.map(|v| v as f32));
        }
    }
    pts
}

/// Log-scale from the mean squared distance to the 3 nearest other points (kd-tree, parallel queries).
pub fn knn_log_scales(points: &[[f32; 3]]) -> Vec<f32> {
    /// 3DGS clamps the mean squared distance at this value before the log.
    const MIN_MEAN_SQ: f32 = 1e-7;
    if points.len() < 2 {
        return vec![0.5 * MIN_MEAN_SQ.ln(); points.len()];
    }
    let tree: ImmutableKdTree<f32, 3> =
        ImmutableKdTree::new_from_slice(points).expect("finite points build a kd-tree");
    let k = points.len().min(4);
    let nk = NonZero::new(k).expect("k ≥ 2");
    points
        .par_iter()
        .enumerate()
        .map(|(i, p)| {
            let nn = tree
                .query(p)
                .nearest_n::<SquaredEuclidean<f32>>(nk)
                .execute();
            let others: Vec<f32> = nn
                .iter()
                .filter(|r| r.item as usize != i)
                .map(|r| r.distance)
                .take(3)
                .collect();
            let mean = others.iter().sum::<f32>() / others.len().max(1) as f32;
            0.5 * mean.max(MIN_MEAN_SQ).ln()
        })
        .collect()
}

/// TRAN-D's random initial surfels.
pub fn random_init(
    cfg: &InitConfig,
    cameras: &[Camera],
    sh_degree: u32,
    num_objects: usize,
) -> Result<Surfels, InitError> {
    let bounds = match cfg.bounds {
        SlabBounds::Explicit(b) => {
            b.validate()?;
            b
        }
        SlabBounds::FromCameras {
            distance_factor,
            height_ratio,
        } => SlabBox::from_cameras(cameras, distance_factor, height_ratio)?,
    };
    let mut rng = Pcg64::seed_from_u64(cfg.seed);
    let points = slab_points(&bounds, cfg.num_volume, cfg.num_per_face, &mut rng);
    surfels_from_points(points, cfg, sh_degree, num_objects, &mut rng)
}

/// Initial surfels at `points`: scales from the 3 nearest neighbours, random quaternions in `[0, 1)⁴`,
/// opacity `cfg.opacity`, grey colour and mask colour, uniform object logits.
pub fn surfels_from_points(
    points: Vec<[f32; 3]>,
    cfg: &InitConfig,
    sh_degree: u32,
    num_objects: usize,
    rng: &mut Pcg64,
) -> Result<Surfels, InitError> {
    let n = points.len();
    let mut s = Surfels::new(sh_degree, num_objects)?;
    let scales = knn_log_scales(&points);
    let dc = rgb_to_dc(cfg.grey);
    s.means = points;
    s.log_scales = scales.iter().map(|&l| [l, l]).collect();
    s.quats = (0..n)
        .map(|_| {
            [
                rng.random::<f32>(),
                rng.random::<f32>(),
                rng.random::<f32>(),
                rng.random::<f32>(),
            ]
        })
        .collect();
    s.opacity_logits = vec![logit(cfg.opacity); n];
    s.sh_dc = vec![[dc; 3]; n];
    s.mask_dc = vec![[dc; 3]; n];
    s.sh_rest = vec![0.0; n * s.rest_stride()];
    s.mask_rest = vec![0.0; n * s.rest_stride()];
    s.obj_logits = vec![0.0; n * num_objects];
    s.validate()?;
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;
    use trand_core::Intrinsics;
    use trand_core::math::sigmoid;

    fn ring(n: usize, radius: f64, height: f64, target: DVec3) -> Vec<Camera> {
        (0..n)
            .map(|i| {
                let a = i as f64 / n as f64 * std::f64::consts::TAU;
                let eye = target + DVec3::new(radius * a.cos(), radius * a.sin(), height);
                Camera::look_at(Intrinsics::centered(500.0, 64, 48), eye, target, DVec3::Z)
            })
            .collect()
    }

    #[test]
    fn tran_d_box_has_the_reference_layout() {
        let cfg = InitConfig {
            num_volume: 500,
            num_per_face: 300,
            bounds: SlabBounds::Explicit(SlabBox::tran_d()),
            ..Default::default()
        };
        let s = random_init(&cfg, &[], 0, 15).unwrap();
        assert_eq!(s.len(), 500 + 4 * 300);
        assert!(
            s.means
                .iter()
                .all(|p| p[0].abs() <= 0.5 && p[1].abs() <= 0.5 && (0.0..=0.1).contains(&p[2]))
        );
        assert!(s.means[..300].iter().all(|p| p[1] == -0.5));
        assert!(
            s.means[300..800]
                .iter()
                .all(|p| p[0].abs() < 0.5 && p[1].abs() < 0.5)
        );
        assert!(s.means[800..1100].iter().all(|p| p[1] == 0.5));
        assert!(s.means[1100..1400].iter().all(|p| p[0] == -0.5));
        assert!(s.means[1400..].iter().all(|p| p[0] == 0.5));
        let dc = rgb_to_dc(127.0 / 255.0);
        assert!((dc + 0.00695).abs() < 1e-4);
        assert!(s.sh_dc.iter().chain(&s.mask_dc).all(|c| *c == [dc; 3]));
        assert!(
            s.opacity_logits
                .iter()
                .all(|&o| (sigmoid(o) - 0.1).abs() < 1e-6)
        );
        assert!(s.obj_logits.iter().all(|&l| l == 0.0));
        assert!(s.quats.iter().flatten().all(|&q| (0.0..1.0).contains(&q)));
    }

    #[test]
    fn init_is_deterministic_for_a_seed_and_changes_with_it() {
        let cfg = InitConfig {
            num_volume: 100,
            num_per_face: 50,
            bounds: SlabBounds::Explicit(SlabBox::tran_d()),
            ..Default::default()
        };
        let a = random_init(&cfg, &[], 0, 3).unwrap();
        assert_eq!(a, random_init(&cfg, &[], 0, 3).unwrap());
        let b = random_init(&InitConfig { seed: 1, ..cfg }, &[], 0, 3).unwrap();
        assert_ne!(a.means, b.means);
    }

    #[test]
    fn knn_scales_match_brute_force() {
        let pts = slab_points(&SlabBox::tran_d(), 300, 50, &mut Pcg64::seed_from_u64(5));
        let got = knn_log_scales(&pts);
        for (i, p) in pts.iter().enumerate() {
            let mut d: Vec<f32> = pts
                .iter()
                .enumerate()
                .filter(|&(j, _)| j != i)
                .map(|(_, q)| (0..3).map(|k| (p[k] - q[k]).powi(2)).sum())
                .collect();
            d.sort_by(|a, b| a.partial_cmp(b).unwrap());
            let want = 0.5 * ((d[0] + d[1] + d[2]) / 3.0).max(1e-7).ln();
            assert!(
                (got[i] - want).abs() < 1e-4,
                "point {i}: {} vs {want}",
                got[i]
            );
        }
    }

    #[test]
    fn duplicate_points_get_the_clamped_scale() {
        let got = knn_log_scales(&[[0.0; 3]; 5]);
        assert!(got.iter().all(|&l| (l - 0.5 * 1e-7f32.ln()).abs() < 1e-6));
    }

    #[test]
    fn focus_point_of_a_camera_ring_is_its_target() {
        let target = DVec3::new(0.1, -0.2, 0.05);
        let f = focus_point(&ring(6, 0.6, 0.4, target)).unwrap();
        assert!((f - target).length() < 1e-9, "{f}");
        // One camera looking straight down: the fallback hits the ground under it.
        let down = Camera::look_at(
            Intrinsics::centered(500.0, 64, 48),
            DVec3::new(0.3, 0.2, 1.0),
            DVec3::new(0.3, 0.2, 0.0),
            DVec3::Y,
        );
        assert!((focus_point(&[down]).unwrap() - DVec3::new(0.3, 0.2, 0.0)).length() < 1e-9);
        assert_eq!(focus_point(&[]), Err(InitError::NoCameras));
    }

    #[test]
    fn bounds_from_cameras_centre_the_slab_on_the_ground_under_the_focus() {
        let target = DVec3::new(0.1, -0.2, 0.05);
        let cams = ring(6, 0.6, 0.8, target);
        let b = SlabBox::from_cameras(&cams, 1.0, TRAN_D_HEIGHT_RATIO).unwrap();
        let half = (0.6f64 * 0.6 + 0.8 * 0.8).sqrt();
        assert!((b.min[0] - (0.1 - half)).abs() < 1e-9 && (b.max[1] - (-0.2 + half)).abs() < 1e-9);
        assert_eq!(b.min[2], 0.0);
        assert!((b.max[2] - 0.2 * half).abs() < 1e-9);
        let s = random_init(
            &InitConfig {
                num_volume: 10,
                num_per_face: 10,
                ..Default::default()
            },
            &cams,
            0,
            2,
        )
        .unwrap();
        assert_eq!(s.len(), 50);
    }
}
