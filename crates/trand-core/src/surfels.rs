//! Struct-of-arrays store of 2D Gaussian surfels (raw, pre-activation parameters).
//!
//! A surfel is the disk `P(u, v) = μ + s_u t_u u + s_v t_v v` where `t_u, t_v` are the first two columns
//! of `R(q)` and the third column `t_w` is its normal (2DGS, eq. 1). Per surfel we store:
//!
//! | field | per surfel | activation |
//! |---|---|---|
//! | `means` | 3 | none (metres) |
//! | `log_scales` | 2 | `exp` → `s_u, s_v` |
//! | `quats` | 4 `(w, x, y, z)` | normalise |
//! | `opacity_logits` | 1 | sigmoid |
//! | `sh_dc`, `sh_rest` | 3, `3·((d+1)²−1)` | SH eval + ½, clamp ≥ 0 (RGB image) |
//! | `mask_dc`, `mask_rest` | same | same (colour-coded instance-mask image) |
//! | `obj_logits` | K | softmax → object probabilities |
//!
//! `sh_rest` is laid out `[surfel][coefficient 1..][channel]`. The same struct stores gradients (a
//! gradient has the shape of its parameter), see [`Surfels::zeros_like`].

use serde::{Deserialize, Serialize};

use crate::sh::{MAX_SH_DEGREE, num_coeffs};

/// Default number of object channels (TRAN-D's `NUM_OBJ`: background + up to 14 objects).
pub const DEFAULT_NUM_OBJECTS: usize = 15;

/// The most object channels (background included) any stage supports: the rasterizer keeps one
/// accumulator per channel on the stack. Readers refuse larger counts before allocating.
pub const MAX_NUM_OBJECTS: usize = 64;

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SurfelsError {
    #[error("SH degree {0} is above the supported maximum {MAX_SH_DEGREE}")]
    ShDegree(u32),
    #[error("number of object channels must be at least 1")]
    NoObjects,
    #[error("field `{field}` has {got} values, expected {expected} for {n} surfels")]
    Length {
        field: &'static str,
        got: usize,
        expected: usize,
        n: usize,
    },
    #[error("surfel {index}: field `{field}` is not finite")]
    NonFinite { field: &'static str, index: usize },
}

/// Surfel parameters (or their gradients), struct of arrays.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Surfels {
    pub sh_degree: u32,
    pub num_objects: usize,
    pub means: Vec<[f32; 3]>,
    pub log_scales: Vec<[f32; 2]>,
    pub quats: Vec<[f32; 4]>,
    pub opacity_logits: Vec<f32>,
    pub sh_dc: Vec<[f32; 3]>,
    pub sh_rest: Vec<f32>,
    pub mask_dc: Vec<[f32; 3]>,
    pub mask_rest: Vec<f32>,
    pub obj_logits: Vec<f32>,
}

/// One surfel's parameters, for building scenes by hand and in tests.
#[derive(Clone, Debug, PartialEq)]
pub struct Surfel {
    pub mean: [f32; 3],
    pub log_scale: [f32; 2],
    pub quat: [f32; 4],
    pub opacity_logit: f32,
    pub sh_dc: [f32; 3],
    pub mask_dc: [f32; 3],
    /// `num_objects` logits; empty means all zero.
    pub obj_logits: Vec<f32>,
}

impl Surfels {
    /// An empty set with the given SH degree and object-channel count.
    pub fn new(sh_degree: u32, num_objects: usize) -> Result<Self, SurfelsError> {
        if sh_degree > MAX_SH_DEGREE {
            return Err(SurfelsError::ShDegree(sh_degree));
        }
        if num_objects == 0 {
            return Err(SurfelsError::NoObjects);
        }
        Ok(Self {
            sh_degree,
            num_objects,
            ..Default::default()
        })
    }

    pub fn len(&self) -> usize {
        self.means.len()
    }

    pub fn is_empty(&self) -> bool {
        self.means.is_empty()
    }

    /// SH coefficients per channel beyond the DC term.
    pub fn rest_coeffs(&self) -> usize {
        num_coeffs(self.sh_degree) - 1
    }

    /// Floats per surfel in `sh_rest` / `mask_rest`.
    pub fn rest_stride(&self) -> usize {
        3 * self.rest_coeffs()
    }

    /// Appends one surfel; the SH rest coefficients start at zero.
    pub fn push(&mut self, s: &Surfel) {
        self.means.push(s.mean);
        self.log_scales.push(s.log_scale);
        self.quats.push(s.quat);
        self.opacity_logits.push(s.opacity_logit);
        self.sh_dc.push(s.sh_dc);
        self.mask_dc.push(s.mask_dc);
        let rs = self.rest_stride();
        self.sh_rest.extend(std::iter::repeat_n(0.0, rs));
        self.mask_rest.extend(std::iter::repeat_n(0.0, rs));
        if s.obj_logits.is_empty() {
            self.obj_logits
                .extend(std::iter::repeat_n(0.0, self.num_objects));
        } else {
            assert_eq!(s.obj_logits.len(), self.num_objects, "object logits length");
            self.obj_logits.extend_from_slice(&s.obj_logits);
        }
    }

    /// A set of the same shape with every value zero (a gradient buffer).
    pub fn zeros_like(&self) -> Self {
        let n = self.len();
        Self {
            sh_degree: self.sh_degree,
            num_objects: self.num_objects,
            means: vec![[0.0; 3]; n],
            log_scales: vec![[0.0; 2]; n],
            quats: vec![[0.0; 4]; n],
            opacity_logits: vec![0.0; n],
            sh_dc: vec![[0.0; 3]; n],
            sh_rest: vec![0.0; self.sh_rest.len()],
            mask_dc: vec![[0.0; 3]; n],
            mask_rest: vec![0.0; self.mask_rest.len()],
            obj_logits: vec![0.0; self.obj_logits.len()],
        }
    }

    /// Every parameter group as a flat slice with its per-surfel stride, in a fixed order
    /// (what an optimiser iterates over).
    pub fn groups_mut(&mut self) -> [(ParamGroup, &mut [f32]); 9] {
        [
            (ParamGroup::Means, self.means.as_flattened_mut()),
            (ParamGroup::LogScales, self.log_scales.as_flattened_mut()),
            (ParamGroup::Quats, self.quats.as_flattened_mut()),
            (ParamGroup::Opacity, &mut self.opacity_logits[..]),
            (ParamGroup::ShDc, self.sh_dc.as_flattened_mut()),
            (ParamGroup::ShRest, &mut self.sh_rest[..]),
            (ParamGroup::MaskDc, self.mask_dc.as_flattened_mut()),
            (ParamGroup::MaskRest, &mut self.mask_rest[..]),
            (ParamGroup::ObjLogits, &mut self.obj_logits[..]),
        ]
    }

    /// Immutable counterpart of [`Self::groups_mut`].
    pub fn groups(&self) -> [(ParamGroup, &[f32]); 9] {
        [
            (ParamGroup::Means, self.means.as_flattened()),
            (ParamGroup::LogScales, self.log_scales.as_flattened()),
            (ParamGroup::Quats, self.quats.as_flattened()),
            (ParamGroup::Opacity, &self.opacity_logits[..]),
            (ParamGroup::ShDc, self.sh_dc.as_flattened()),
            (ParamGroup::ShRest, &self.sh_rest[..]),
            (ParamGroup::MaskDc, self.mask_dc.as_flattened()),
            (ParamGroup::MaskRest, &self.mask_rest[..]),
            (ParamGroup::ObjLogits, &self.obj_logits[..]),
        ]
    }

    /// Floats per surfel of a group.
    pub fn stride(&self, g: ParamGroup) -> usize {
        match g {
            ParamGroup::Means | ParamGroup::ShDc | ParamGroup::MaskDc => 3,
            ParamGroup::LogScales => 2,
            ParamGroup::Quats => 4,
            ParamGroup::Opacity => 1,
            ParamGroup::ShRest | ParamGroup::MaskRest => self.rest_stride(),
            ParamGroup::ObjLogits => self.num_objects,
        }
    }

    /// Keeps the surfels whose `keep[i]` is true, in order.
    pub fn retain(&mut self, keep: &[bool]) {
        assert_eq!(keep.len(), self.len());
        let idx: Vec<usize> = (0..self.len()).filter(|&i| keep[i]).collect();
        *self = self.gather(&idx);
    }

    /// A new set made of the surfels at `idx` (repeats allowed), in that order.
    pub fn gather(&self, idx: &[usize]) -> Self {
        let mut out = Self {
            sh_degree: self.sh_degree,
            num_objects: self.num_objects,
            ..Default::default()
        };
        for (g, src) in self.groups() {
            let stride = self.stride(g);
            let mut dst = Vec::with_capacity(idx.len() * stride);
            for &i in idx {
                dst.extend_from_slice(&src[i * stride..(i + 1) * stride]);
            }
            out.set_group(g, dst);
        }
        out
    }

    /// Appends all surfels of `other` (same degree and object count).
    pub fn append(&mut self, other: &Self) {
        assert_eq!(
            (self.sh_degree, self.num_objects),
            (other.sh_degree, other.num_objects)
        );
        self.means.extend_from_slice(&other.means);
        self.log_scales.extend_from_slice(&other.log_scales);
        self.quats.extend_from_slice(&other.quats);
        self.opacity_logits.extend_from_slice(&other.opacity_logits);
        self.sh_dc.extend_from_slice(&other.sh_dc);
        self.sh_rest.extend_from_slice(&other.sh_rest);
        self.mask_dc.extend_from_slice(&other.mask_dc);
        self.mask_rest.extend_from_slice(&other.mask_rest);
        self.obj_logits.extend_from_slice(&other.obj_logits);
    }

    fn set_group(&mut self, g: ParamGroup, v: Vec<f32>) {
        fn chunk<const N: usize>(v: Vec<f32>) -> Vec<[f32; N]> {
            v.chunks_exact(N)
                .map(|c| c.try_into().expect("chunk length"))
                .collect()
        }
        match g {
            ParamGroup::Means => self.means = chunk(v),
            ParamGroup::LogScales => self.log_scales = chunk(v),
            ParamGroup::Quats => self.quats = chunk(v),
            ParamGroup::Opacity => self.opacity_logits = v,
            ParamGroup::ShDc => self.sh_dc = chunk(v),
            ParamGroup::ShRest => self.sh_rest = v,
            ParamGroup::MaskDc => self.mask_dc = chunk(v),
            ParamGroup::MaskRest => self.mask_rest = v,
            ParamGroup::ObjLogits => self.obj_logits = v,
        }
    }

    /// Changes the SH degree, keeping the coefficients that exist in both (new ones start at zero).
    pub fn set_sh_degree(&mut self, degree: u32) -> Result<(), SurfelsError> {
        if degree > MAX_SH_DEGREE {
            return Err(SurfelsError::ShDegree(degree));
        }
        let old = self.rest_stride();
        let new = 3 * (num_coeffs(degree) - 1);
        let keep = old.min(new);
        let n = self.len();
        let resize = |v: &Vec<f32>| {
            let mut out = vec![0.0; n * new];
            for i in 0..n {
                out[i * new..i * new + keep].copy_from_slice(&v[i * old..i * old + keep]);
            }
            out
        };
        self.sh_rest = resize(&self.sh_rest);
        self.mask_rest = resize(&self.mask_rest);
        self.sh_degree = degree;
        Ok(())
    }

    /// Checks that every array has the right length and that all values are finite.
    pub fn validate(&self) -> Result<(), SurfelsError> {
        if self.sh_degree > MAX_SH_DEGREE {
            return Err(SurfelsError::ShDegree(self.sh_degree));
        }
        if self.num_objects == 0 {
            return Err(SurfelsError::NoObjects);
        }
        let n = self.len();
        for (g, v) in self.groups() {
            let expected = n * self.stride(g);
            if v.len() != expected {
                return Err(SurfelsError::Length {
                    field: g.name(),
                    got: v.len(),
                    expected,
                    n,
                });
            }
            if let Some(p) = v.iter().position(|x| !x.is_finite()) {
                return Err(SurfelsError::NonFinite {
                    field: g.name(),
                    index: p / self.stride(g).max(1),
                });
            }
        }
        Ok(())
    }
}

/// The parameter groups of [`Surfels`], each with its own learning rate in training.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum ParamGroup {
    Means,
    LogScales,
    Quats,
    Opacity,
    ShDc,
    ShRest,
    MaskDc,
    MaskRest,
    ObjLogits,
}

impl ParamGroup {
    pub const ALL: [ParamGroup; 9] = [
        ParamGroup::Means,
        ParamGroup::LogScales,
        ParamGroup::Quats,
        ParamGroup::Opacity,
        ParamGroup::ShDc,
        ParamGroup::ShRest,
        ParamGroup::MaskDc,
        ParamGroup::MaskRest,
        ParamGroup::ObjLogits,
    ];

    pub fn name(self) -> &'static str {
        match self {
            ParamGroup::Means => "means",
            ParamGroup::LogScales => "log_scales",
            ParamGroup::Quats => "quats",
            ParamGroup::Opacity => "opacity_logits",
            ParamGroup::ShDc => "sh_dc",
            ParamGroup::ShRest => "sh_rest",
            ParamGroup::MaskDc => "mask_dc",
            ParamGroup::MaskRest => "mask_rest",
            ParamGroup::ObjLogits => "obj_logits",
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn surfel(x: f32) -> Surfel {
        Surfel {
            mean: [x, 0.0, 0.0],
            log_scale: [-3.0, -3.0],
            quat: [1.0, 0.0, 0.0, 0.0],
            opacity_logit: 0.0,
            sh_dc: [0.1, 0.2, 0.3],
            mask_dc: [0.0; 3],
            obj_logits: vec![],
        }
    }

    #[test]
    fn gather_and_retain_keep_all_groups_aligned() {
        let mut s = Surfels::new(1, 4).unwrap();
        for i in 0..5 {
            s.push(&surfel(i as f32));
            let base = s.sh_rest.len() - 9;
            s.sh_rest[base] = i as f32;
            s.obj_logits[i * 4 + 2] = i as f32;
        }
        s.validate().unwrap();
        let g = s.gather(&[3, 1, 3]);
        assert_eq!(g.len(), 3);
        assert_eq!(g.means[0][0], 3.0);
        assert_eq!(g.sh_rest[9], 1.0);
        assert_eq!(g.obj_logits[4 * 2 + 2], 3.0);
        s.retain(&[true, false, true, false, true]);
        assert_eq!(
            s.means.iter().map(|m| m[0]).collect::<Vec<_>>(),
            vec![0.0, 2.0, 4.0]
        );
        assert_eq!(s.obj_logits[4 + 2], 2.0);
        s.validate().unwrap();
    }

    #[test]
    fn validate_reports_non_finite_field_and_index() {
        let mut s = Surfels::new(0, 2).unwrap();
        s.push(&surfel(0.0));
        s.push(&surfel(1.0));
        s.opacity_logits[1] = f32::NAN;
        assert_eq!(
            s.validate(),
            Err(SurfelsError::NonFinite {
                field: "opacity_logits",
                index: 1
            })
        );
    }

    #[test]
    fn raising_sh_degree_keeps_low_coefficients() {
        let mut s = Surfels::new(1, 1).unwrap();
        s.push(&surfel(0.0));
        s.sh_rest
            .copy_from_slice(&[1., 2., 3., 4., 5., 6., 7., 8., 9.]);
        s.set_sh_degree(3).unwrap();
        assert_eq!(s.sh_rest.len(), 45);
        assert_eq!(&s.sh_rest[..9], &[1., 2., 3., 4., 5., 6., 7., 8., 9.]);
        assert!(s.sh_rest[9..].iter().all(|&v| v == 0.0));
        assert!(s.set_sh_degree(4).is_err());
    }
}
