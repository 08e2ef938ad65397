//! Surfels as a standard 3D Gaussian Splatting PLY, the file splat viewers (SuperSplat, the INRIA
//! viewer) open:
//!
//! ```text
//! x y z  nx ny nz  f_dc_0..2  f_rest_0..44  opacity  scale_0 scale_1 scale_2  rot_0..3
//! ```
//! all `float`, raw values as 3DGS stores them: `opacity` a logit, `scale_*` natural-log scales,
//! `rot_0..3` the unnormalised quaternion `(w, x, y, z)`, `f_rest` channel-major.
//!
//! * A 2D surfel is a Gaussian with two scales; its normal, the local z axis of `R(q)`, gets the third
//!   scale [`THIN_RATIO`] × the geometric mean of the other two, i.e.
//!   `scale_2 = (scale_0 + scale_1)/2 + ln(THIN_RATIO)` in log space. A relative thickness keeps the
//!   disc's shape at every size; a thousandth is far below a pixel at any distance the disc itself
//!   is visible, so a 3DGS rasterizer draws the same ellipse seen face on.
//! * The SH coefficients are always written at degree 3 (45 `f_rest`), the higher ones zero where the
//!   surfels have a lower degree: the INRIA viewer reads a fixed degree-3 record, and the extra zero
//!   coefficients change no colour.
//! * `nx ny nz` hold the surfel normal (3DGS writes zeros there; viewers ignore it).
//! * The object channels and mask colours are not part of the format; `trand export` writes the objects
//!   as separate point clouds.

use std::path::Path;

use trand_core::Surfels;
use trand_core::math::quat_to_rotmat;

use crate::error::IoError;
use crate::write::write_atomic;

/// Thickness of a surfel along its normal, relative to the geometric mean of its two scales.
pub const THIN_RATIO: f64 = 1e-3;

/// SH coefficients beyond DC per channel in the written file (degree 3).
const REST: usize = 15;

/// The property names of the 3DGS layout, in file order.
pub fn splat_property_names() -> Vec<String> {
    let mut names: Vec<String> = ["x", "y", "z", "nx", "ny", "nz"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    names.extend((0..3).map(|i| format!("f_dc_{i}")));
    names.extend((0..3 * REST).map(|i| format!("f_rest_{i}")));
    names.push("opacity".into());
    names.extend((0..3).map(|i| format!("scale_{i}")));
    names.extend((0..4).map(|i| format!("rot_{i}")));
    names
}

/// The third log-scale given to a surfel with log-scales `ls` ([`THIN_RATIO`]).
pub fn thin_log_scale(ls: [f32; 2]) -> f32 {
    0.5 * (ls[0] + ls[1]) + THIN_RATIO.ln() as f32
}

/// Serialises surfels as a 3DGS PLY (the surfels must be consistent, `Surfels::validate`'s lengths).
pub fn splats_to_ply_bytes(s: &Surfels) -> Vec<u8> {
    let names = splat_property_names();
    let mut out = Vec::with_capacity(256 + names.len() * 24 + s.len() * names.len() * 4);
    out.extend_from_slice(b"ply\nformat binary_little_endian 1.0\ncomment trand splats (2D surfels, thin third scale)\n");
    out.extend_from_slice(format!("element vertex {}\n", s.len()).as_bytes());
    for n in &names {
        out.extend_from_slice(format!("property float {n}\n").as_bytes());
    }
    out.extend_from_slice(b"end_header\n");
    let rest = s.rest_coeffs();
    let rs = 3 * rest;
    let mut push = |v: f32| out.extend_from_slice(&v.to_le_bytes());
    for i in 0..s.len() {
        s.means[i].iter().for_each(|&v| push(v));
        let normal = quat_to_rotmat(s.quats[i])
            .map(|(m, _)| [m[0][2], m[1][2], m[2][2]])
            .unwrap_or([0.0; 3]);
        normal.iter().for_each(|&v| push(v));
        s.sh_dc[i].iter().for_each(|&v| push(v));
        for c in 0..3 {
            for j in 0..REST {
                push(if j < rest {
                    s.sh_rest[i * rs + 3 * j + c]
                } else {
                    0.0
                });
            }
        }
        push(s.opacity_logits[i]);
        let ls = s.log_scales[i];
        [ls[0], ls[1], thin_log_scale(ls)]
            .iter()
            .for_each(|&v| push(v));
        s.quats[i].iter().for_each(|&v| push(v));
    }
    out
}

/// Writes surfels as a 3DGS PLY, atomically.
pub fn write_splats_ply(path: &Path, s: &Surfels) -> Result<(), IoError> {
    if let Err(e @ trand_core::SurfelsError::Length { .. }) = s.validate() {
        return Err(IoError::Ply {
            path: path.into(),
            reason: e.to_string(),
        });
    }
    write_atomic(path, &splats_to_ply_bytes(s))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ply::surfels_from_ply_bytes;

    fn surfels(degree: u32) -> Surfels {
        let mut s = Surfels::new(degree, 3).unwrap();
        for i in 0..5 {
            let f = i as f32;
            s.push(&trand_core::surfels::Surfel {
                mean: [0.1 * f, -0.2 + f, 0.03 * f],
                sh_dc: [0.5, -0.25 * f, 1.0],
                opacity_logit: -1.0 + f,
                log_scale: [-4.0 - 0.1 * f, -5.0],
                quat: [1.0, 0.1 * f, -0.2, 0.3],
                mask_dc: [0.0; 3],
                obj_logits: vec![0.0, f, -f],
            });
            let rs = s.rest_stride();
            for (k, v) in s.sh_rest[i * rs..].iter_mut().enumerate() {
                *v = 0.01 * (k as f32 + f);
            }
        }
        s
    }

    #[test]
    fn splat_ply_round_trips_positions_and_rotations() {
        for degree in [0, 1, 3] {
            let s = surfels(degree);
            let bytes = splats_to_ply_bytes(&s);
            let back = surfels_from_ply_bytes(&bytes, Path::new("splats.ply")).unwrap();
            assert_eq!(back.sh_degree, 3, "always written at degree 3");
            assert_eq!(back.means, s.means);
            assert_eq!(back.quats, s.quats);
            assert_eq!(back.sh_dc, s.sh_dc);
            assert_eq!(back.opacity_logits, s.opacity_logits);
            assert_eq!(back.log_scales, s.log_scales);
            let (r, rb) = (s.rest_coeffs(), back.rest_coeffs());
            for i in 0..s.len() {
                for k in 0..rb {
                    for c in 0..3 {
                        let want = if k < r {
                            s.sh_rest[i * 3 * r + 3 * k + c]
                        } else {
                            0.0
                        };
                        assert_eq!(back.sh_rest[i * 3 * rb + 3 * k + c], want);
                    }
                }
            }
        }
    }

    #[test]
    fn third_scale_is_a_thousandth_of_the_disc_along_its_normal() {
        let s = surfels(0);
        let bytes = splats_to_ply_bytes(&s);
        let text = String::from_utf8_lossy(&bytes);
        let names = splat_property_names();
        assert_eq!(names.len(), 62);
        assert!(text.contains("element vertex 5\n"));
        let body = &bytes[text.find("end_header\n").unwrap() + 11..];
        assert_eq!(body.len(), 5 * 62 * 4);
        let col = |name: &str| names.iter().position(|n| n == name).unwrap();
        for i in 0..5 {
            let rec = &body[i * 248..(i + 1) * 248];
            let get = |c: usize| f32::from_le_bytes(rec[4 * c..4 * c + 4].try_into().unwrap());
            let (s0, s1, s2) = (
                get(col("scale_0")),
                get(col("scale_1")),
                get(col("scale_2")),
            );
            let ratio = (s2 - 0.5 * (s0 + s1)).exp();
            assert!((ratio as f64 / THIN_RATIO - 1.0).abs() < 1e-4, "{ratio}");
            // The written normal is the rotation's third column, unit length.
            let n = [get(col("nx")), get(col("ny")), get(col("nz"))];
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            assert!((len - 1.0).abs() < 1e-5);
        }
    }
}
