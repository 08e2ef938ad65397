//! Read access to surfel parameters in any precision, and a generic parameter/gradient container.
//!
//! Production code stores parameters as `f32` in [`trand_core::Surfels`]; the finite-difference tests
//! need the very same rasterizer to run on `f64` parameters. [`SurfelParams`] abstracts over both:
//! the preprocess stage is the only reader, once per surfel per render.

use rayon::prelude::*;
use trand_core::{Real, Surfels, sh::num_coeffs};

/// Per-surfel parameter access in precision `R` (raw, pre-activation values; see [`Surfels`]).
pub trait SurfelParams<R: Real>: Sync {
    fn len(&self) -> usize;
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    fn sh_degree(&self) -> u32;
    fn num_objects(&self) -> usize;
    fn mean(&self, i: usize) -> [R; 3];
    fn log_scale(&self, i: usize) -> [R; 2];
    fn quat(&self, i: usize) -> [R; 4];
    fn opacity_logit(&self, i: usize) -> R;
    /// RGB SH coefficient `k` (0 = DC) of channel `ch`.
    fn sh(&self, i: usize, k: usize, ch: usize) -> R;
    /// Mask-colour SH coefficient `k` of channel `ch`.
    fn mask_sh(&self, i: usize, k: usize, ch: usize) -> R;
    fn obj_logit(&self, i: usize, k: usize) -> R;
}

impl<R: Real> SurfelParams<R> for Surfels {
    fn len(&self) -> usize {
        Surfels::len(self)
    }
    fn sh_degree(&self) -> u32 {
        self.sh_degree
    }
    fn num_objects(&self) -> usize {
        self.num_objects
    }
    #[inline]
    fn mean(&self, i: usize) -> [R; 3] {
        self.means[i].map(R::from_f32)
    }
    #[inline]
    fn log_scale(&self, i: usize) -> [R; 2] {
        self.log_scales[i].map(R::from_f32)
    }
    #[inline]
    fn quat(&self, i: usize) -> [R; 4] {
        self.quats[i].map(R::from_f32)
    }
    #[inline]
    fn opacity_logit(&self, i: usize) -> R {
        R::from_f32(self.opacity_logits[i])
    }
    #[inline]
    fn sh(&self, i: usize, k: usize, ch: usize) -> R {
        if k == 0 {
            R::from_f32(self.sh_dc[i][ch])
        } else {
            R::from_f32(self.sh_rest[i * self.rest_stride() + (k - 1) * 3 + ch])
        }
    }
    #[inline]
    fn mask_sh(&self, i: usize, k: usize, ch: usize) -> R {
        if k == 0 {
            R::from_f32(self.mask_dc[i][ch])
        } else {
            R::from_f32(self.mask_rest[i * self.rest_stride() + (k - 1) * 3 + ch])
        }
    }
    #[inline]
    fn obj_logit(&self, i: usize, k: usize) -> R {
        R::from_f32(self.obj_logits[i * self.num_objects + k])
    }
}

/// Surfel parameters (or gradients) in precision `R`, struct of arrays, same layout as [`Surfels`]
/// except that the SH arrays hold all `(d+1)²` coefficients per channel, `[surfel][coeff][channel]`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ParamsOf<R> {
    pub sh_degree: u32,
    pub num_objects: usize,
    pub means: Vec<[R; 3]>,
    pub log_scales: Vec<[R; 2]>,
    pub quats: Vec<[R; 4]>,
    pub opacity_logits: Vec<R>,
    pub sh: Vec<R>,
    pub mask_sh: Vec<R>,
    pub obj_logits: Vec<R>,
}

impl<R: Real> ParamsOf<R> {
    /// Zero-filled container for `n` surfels (filled by all threads: the backward pass allocates one
    /// per call).
    pub fn zeros(n: usize, sh_degree: u32, num_objects: usize) -> Self {
        let nc = num_coeffs(sh_degree) * 3;
        Self {
            sh_degree,
            num_objects,
            means: par_zeros(n),
            log_scales: par_zeros(n),
            quats: par_zeros(n),
            opacity_logits: par_zeros(n),
            sh: par_zeros(n * nc),
            mask_sh: par_zeros(n * nc),
            obj_logits: par_zeros(n * num_objects),
        }
    }

    /// Converts `f32` surfels to precision `R`.
    pub fn from_surfels(s: &Surfels) -> Self {
        let n = s.len();
        let nc = num_coeffs(s.sh_degree);
        let mut p = Self::zeros(n, s.sh_degree, s.num_objects);
        for i in 0..n {
            p.means[i] = SurfelParams::<R>::mean(s, i);
            p.log_scales[i] = SurfelParams::<R>::log_scale(s, i);
            p.quats[i] = SurfelParams::<R>::quat(s, i);
            p.opacity_logits[i] = SurfelParams::<R>::opacity_logit(s, i);
            for k in 0..nc {
                for ch in 0..3 {
                    p.sh[(i * nc + k) * 3 + ch] = SurfelParams::<R>::sh(s, i, k, ch);
                    p.mask_sh[(i * nc + k) * 3 + ch] = SurfelParams::<R>::mask_sh(s, i, k, ch);
                }
            }
            for k in 0..s.num_objects {
                p.obj_logits[i * s.num_objects + k] = SurfelParams::<R>::obj_logit(s, i, k);
            }
        }
        p
    }

    /// Writes the values into an `f32` [`Surfels`] of the same shape (e.g. gradients for the optimiser).
    pub fn write_into(&self, s: &mut Surfels) {
        let n = self.means.len();
        assert_eq!(s.len(), n, "surfel count");
        let nc = num_coeffs(self.sh_degree);
        let rs = s.rest_stride();
        for i in 0..n {
            s.means[i] = self.means[i].map(R::to_f32);
            s.log_scales[i] = self.log_scales[i].map(R::to_f32);
            s.quats[i] = self.quats[i].map(R::to_f32);
            s.opacity_logits[i] = self.opacity_logits[i].to_f32();
            for ch in 0..3 {
                s.sh_dc[i][ch] = self.sh[i * nc * 3 + ch].to_f32();
                s.mask_dc[i][ch] = self.mask_sh[i * nc * 3 + ch].to_f32();
            }
            for k in 1..nc.min(rs / 3 + 1) {
                for ch in 0..3 {
                    s.sh_rest[i * rs + (k - 1) * 3 + ch] = self.sh[(i * nc + k) * 3 + ch].to_f32();
                    s.mask_rest[i * rs + (k - 1) * 3 + ch] =
                        self.mask_sh[(i * nc + k) * 3 + ch].to_f32();
                }
            }
            for k in 0..self.num_objects {
                s.obj_logits[i * self.num_objects + k] =
                    self.obj_logits[i * self.num_objects + k].to_f32();
            }
        }
    }
}

impl ParamsOf<f32> {
    /// The values as [`Surfels`] shaped like `like` (e.g. gradients for the optimiser), moving the
    /// arrays whose layouts agree instead of copying them: [`ParamsOf::write_into`] into a
    /// [`Surfels::zeros_like`] cost ~1.3 ms per training step at ~45 k surfels.
    pub fn into_surfels(self, like: &Surfels) -> Surfels {
        let n = self.means.len();
        assert_eq!(like.len(), n, "surfel count");
        let nc = num_coeffs(self.sh_degree);
        let rs = like.rest_stride();
        if self.num_objects != like.num_objects || (nc - 1) * 3 != rs {
            let mut s = like.zeros_like();
            self.write_into(&mut s);
            return s;
        }
        let split = |sh: Vec<f32>| -> (Vec<[f32; 3]>, Vec<f32>) {
            if nc == 1 {
                return (sh.as_chunks::<3>().0.to_vec(), Vec::new());
            }
            let dc = sh
                .chunks_exact(nc * 3)
                .map(|c| [c[0], c[1], c[2]])
                .collect();
            let rest = sh
                .chunks_exact(nc * 3)
                .flat_map(|c| c[3..].iter().copied())
                .collect();
            (dc, rest)
        };
        let (sh_dc, sh_rest) = split(self.sh);
        let (mask_dc, mask_rest) = split(self.mask_sh);
        Surfels {
            sh_degree: like.sh_degree,
            num_objects: like.num_objects,
            means: self.means,
            log_scales: self.log_scales,
            quats: self.quats,
            opacity_logits: self.opacity_logits,
            sh_dc,
            sh_rest,
            mask_dc,
            mask_rest,
            obj_logits: self.obj_logits,
        }
    }
}

impl<R: Real> SurfelParams<R> for ParamsOf<R> {
    fn len(&self) -> usize {
        self.means.len()
    }
    fn sh_degree(&self) -> u32 {
        self.sh_degree
    }
    fn num_objects(&self) -> usize {
        self.num_objects
    }
    fn mean(&self, i: usize) -> [R; 3] {
        self.means[i]
    }
    fn log_scale(&self, i: usize) -> [R; 2] {
        self.log_scales[i]
    }
    fn quat(&self, i: usize) -> [R; 4] {
        self.quats[i]
    }
    fn opacity_logit(&self, i: usize) -> R {
        self.opacity_logits[i]
    }
    fn sh(&self, i: usize, k: usize, ch: usize) -> R {
        self.sh[(i * num_coeffs(self.sh_degree) + k) * 3 + ch]
    }
    fn mask_sh(&self, i: usize, k: usize, ch: usize) -> R {
        self.mask_sh[(i * num_coeffs(self.sh_degree) + k) * 3 + ch]
    }
    fn obj_logit(&self, i: usize, k: usize) -> R {
        self.obj_logits[i * self.num_objects + k]
    }
}

/// A zero-filled buffer of `len` values, written by all threads: the renderer's per-call buffers run to
/// tens of megabytes (tile blocks, pair records, per-surfel records, gradients), and filling them on
/// the calling thread was a serial ~3 % of a training step.
pub(crate) fn par_zeros<T: Default + Copy + Send + Sync>(len: usize) -> Vec<T> {
    let mut v = Vec::new();
    rayon::iter::repeat_n(T::default(), len)
        .with_min_len(1 << 14)
        .collect_into_vec(&mut v);
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A surfel set of SH degree `deg` with every parameter distinct (and rest coefficients set).
    fn numbered(deg: u32, n: usize, k: usize) -> Surfels {
        let mut s = Surfels::new(deg, k).expect("shape");
        for i in 0..n {
            s.push(&trand_core::surfels::Surfel {
                mean: [i as f32, 0.5, 1.0],
                log_scale: [-(i as f32), 0.25],
                quat: [1.0, i as f32, 0.0, 0.5],
                opacity_logit: 0.1 * i as f32,
                sh_dc: [i as f32 + 0.1, 0.2, 0.3],
                mask_dc: [0.4, i as f32 + 0.5, 0.6],
                obj_logits: (0..k).map(|c| (i * k + c) as f32).collect(),
            });
        }
        for (j, v) in s.sh_rest.iter_mut().enumerate() {
            *v = 100.0 + j as f32;
        }
        for (j, v) in s.mask_rest.iter_mut().enumerate() {
            *v = -100.0 - j as f32;
        }
        s
    }

    #[test]
    fn into_surfels_equals_write_into_for_every_sh_degree_and_shape() {
        for deg in 0..=3 {
            let s = numbered(deg, 5, 4);
            let p = ParamsOf::<f32>::from_surfels(&s);
            let mut want = s.zeros_like();
            p.write_into(&mut want);
            assert_eq!(p.clone().into_surfels(&s), want, "degree {deg}");
            assert_eq!(want, s, "degree {deg}: round trip");
            // A target of another degree takes the general path.
            let other = numbered((deg + 1) % 4, 5, 4);
            let mut want = other.zeros_like();
            p.write_into(&mut want);
            assert_eq!(
                p.into_surfels(&other),
                want,
                "degree {deg} into another degree"
            );
        }
    }
}
