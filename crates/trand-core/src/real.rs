//! A minimal floating-point trait.
//!
//! The rasterizer and the losses are written once, generic over `R: Real`, and instantiated with `f32`
//! in production and `f64` in the finite-difference tests: the gradients checked in tests are those of the
//! very code that runs in training, not of a re-implementation.

use core::fmt::Debug;
use core::ops::{
    Add, AddAssign, BitAnd, BitOr, Div, DivAssign, Mul, MulAssign, Neg, Not, Sub, SubAssign,
};

/// Floating-point scalar (`f32` or `f64`).
pub trait Real:
    Copy
    + Debug
    + Default
    + PartialOrd
    + Send
    + Sync
    + 'static
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + AddAssign
    + SubAssign
    + MulAssign
    + DivAssign
{
    const ZERO: Self;
    const ONE: Self;
    /// The signed integer of the same width: the lane type of the rasterizer's lane masks, which hold
    /// `-1` (all bits set, what a SIMD comparison produces) or `0`.
    type Lane: Copy
        + Debug
        + PartialEq
        + PartialOrd
        + Send
        + Sync
        + 'static
        + From<i32>
        + BitAnd<Output = Self::Lane>
        + BitOr<Output = Self::Lane>
        + Not<Output = Self::Lane>;
    fn from_f64(v: f64) -> Self;
    fn to_f64(self) -> f64;
    fn from_f32(v: f32) -> Self;
    fn to_f32(self) -> f32;
    fn exp(self) -> Self;
    fn ln(self) -> Self;
    fn sqrt(self) -> Self;
    fn abs(self) -> Self;
    fn ceil(self) -> Self;
    fn floor(self) -> Self;
    fn is_finite(self) -> bool;
    fn max(self, o: Self) -> Self;
    fn min(self, o: Self) -> Self;
    fn to_bits_u64(self) -> u64;
    /// `exp(x)` for the rasterizer's Gaussian falloff, `x ≤ 0`. Exact (`exp`) by default; `f32`
    /// overrides it with a faster polynomial (relative error < 3e-7 on the rasterizer's range, see
    /// [`fast_exp_f32`]).
    #[inline(always)]
    fn fast_exp(self) -> Self {
        self.exp()
    }
    /// [`Real::fast_exp`] of eight values at once (the rasterizer's pixel lanes). `f32` overrides it
    /// with [`fast_exp_f32x8`], written so that every step is one vector instruction.
    #[inline(always)]
    fn fast_exp8(x: [Self; 8]) -> [Self; 8] {
        x.map(Self::fast_exp)
    }
    /// Eight [`Real::Lane`]s as `i32` when `Self` is `f32` (`None` otherwise): lets the rasterizer's
    /// lane masks take an instruction-level fast path for the production type while staying generic.
    #[inline(always)]
    fn lanes_as_i32(_v: &[Self::Lane; 8]) -> Option<&[i32; 8]> {
        None
    }
}

/// `e^r` for the reduced argument `|r| ≤ ln2/2`: the degree-6 Taylor polynomial (truncation error
/// `r⁷/7! < 1.3e-7` relative), evaluated by Estrin's scheme. Horner's form is a chain of twelve
/// dependent multiplies and adds; grouped as `(1 + r) + r²(½ + r/6) + r⁴((1/24 + r/120) + r²/720)` the
/// longest chain is five, which matters in the rasterizer's kernels, where the exponential is the
/// longest dependency of every eight-pixel group.
#[inline(always)]
fn exp_poly(r: f32) -> f32 {
    let r2 = r * r;
    let r4 = r2 * r2;
    let a = 1.0 + r;
    let b = 0.5 + r * (1.0 / 6.0);
    let c = (1.0 / 24.0 + r * (1.0 / 120.0)) + r2 * (1.0 / 720.0);
    (a + r2 * b) + r4 * c
}

/// [`fast_exp_f32`] on eight lanes, step by step (one loop per operation, which LLVM vectorizes
/// reliably; the fused scalar form is not vectorized once inlined into a larger kernel). Bit-identical
/// to [`fast_exp_f32`] lane by lane.
#[inline(always)]
#[allow(clippy::manual_clamp)] // max/min are vector instructions; `clamp` asserts and is not vectorized the same way
pub fn fast_exp_f32x8(x: [f32; 8]) -> [f32; 8] {
    const MAGIC: f32 = 12_582_912.0;
    // Clamp with min/max (vector instructions), not nested ifs (which stayed branches).
    let xc: [f32; 8] = std::array::from_fn(|l| x[l].max(-87.0).min(88.0));
    let mut k = [0.0f32; 8];
    let mut n = [0.0f32; 8];
    for l in 0..8 {
        k[l] = xc[l] * std::f32::consts::LOG2_E + MAGIC;
        n[l] = k[l] - MAGIC;
    }
    let mut p = [0.0f32; 8];
    for l in 0..8 {
        let r = xc[l] - n[l] * 0.693_145_75 - n[l] * 1.428_606_8e-6;
        p[l] = exp_poly(r);
    }
    let mut out = [0.0f32; 8];
    for l in 0..8 {
        let ni = k[l].to_bits().wrapping_sub(MAGIC.to_bits());
        let e = p[l] * f32::from_bits(ni.wrapping_add(127) << 23);
        out[l] = if x[l] < -87.0 { 0.0 } else { e };
    }
    out
}

/// `exp(x)` in f32 by Cody–Waite range reduction `x = n·ln2 + r`, `|r| ≤ ln2/2` (n = round(x/ln2)),
/// and a degree-6 Taylor polynomial for `e^r` ([`exp_poly`]), scaled by `2ⁿ` through the exponent
/// bits: 2.8e-7 relative error at worst on `[−30, 0]` in f32 (the test's sweep; 2.5e-7 in Horner's
/// form). Inputs below −87 return 0 (the result would be denormal).
#[inline(always)]
pub fn fast_exp_f32(x: f32) -> f32 {
    // Branch-free (a select at the end), so that a loop over lanes vectorizes.
    let underflow = x < -87.0;
    let x = if underflow {
        -87.0
    } else if x > 88.0 {
        88.0
    } else {
        x
    };
    // n = round(x·log2 e) by the 1.5·2²³ trick: after the addition the low mantissa bits hold n, so
    // both n as a float and n as an integer come out without a (saturating, unvectorizable) cast.
    const MAGIC: f32 = 12_582_912.0;
    let k = x * std::f32::consts::LOG2_E + MAGIC;
    let n = k - MAGIC;
    let ni = k.to_bits() as i32 - MAGIC.to_bits() as i32;
    // ln2 split in a high part exact in f32 and a low correction.
    let r = x - n * 0.693_145_75 - n * 1.428_606_8e-6;
    let p = exp_poly(r);
    let bits = ((ni + 127) as u32) << 23;
    let e = p * f32::from_bits(bits);
    if underflow { 0.0 } else { e }
}

macro_rules! impl_real {
    ($t:ty, $lane:ty, $fast:expr, $fast8:expr, $masks32:expr) => {
        impl Real for $t {
            const ZERO: Self = 0.0;
            const ONE: Self = 1.0;
            type Lane = $lane;
            #[inline(always)]
            fn from_f64(v: f64) -> Self {
                v as $t
            }
            #[inline(always)]
            fn to_f64(self) -> f64 {
                self as f64
            }
            #[inline(always)]
            fn from_f32(v: f32) -> Self {
                v as $t
            }
            #[inline(always)]
            fn to_f32(self) -> f32 {
                self as f32
            }
            #[inline(always)]
            fn exp(self) -> Self {
                <$t>::exp(self)
            }
            #[inline(always)]
            fn ln(self) -> Self {
                <$t>::ln(self)
            }
            #[inline(always)]
            fn sqrt(self) -> Self {
                <$t>::sqrt(self)
            }
            #[inline(always)]
            fn abs(self) -> Self {
                <$t>::abs(self)
            }
            #[inline(always)]
            fn ceil(self) -> Self {
                <$t>::ceil(self)
            }
            #[inline(always)]
            fn floor(self) -> Self {
                <$t>::floor(self)
            }
            #[inline(always)]
            fn is_finite(self) -> bool {
                <$t>::is_finite(self)
            }
            #[inline(always)]
            fn max(self, o: Self) -> Self {
                <$t>::max(self, o)
            }
            #[inline(always)]
            fn min(self, o: Self) -> Self {
                <$t>::min(self, o)
            }
            #[inline(always)]
            fn to_bits_u64(self) -> u64 {
                self.to_bits() as u64
            }
            #[inline(always)]
            fn fast_exp(self) -> Self {
                $fast(self)
            }
            #[inline(always)]
            fn fast_exp8(x: [Self; 8]) -> [Self; 8] {
                $fast8(x)
            }
            #[inline(always)]
            fn lanes_as_i32(v: &[Self::Lane; 8]) -> Option<&[i32; 8]> {
                $masks32(v)
            }
        }
    };
}
fn i32_lanes(v: &[i32; 8]) -> Option<&[i32; 8]> {
    Some(v)
}
fn no_i32_lanes(_: &[i64; 8]) -> Option<&[i32; 8]> {
    None
}
impl_real!(f32, i32, fast_exp_f32, fast_exp_f32x8, i32_lanes);
impl_real!(
    f64,
    i64,
    f64::exp,
    |x: [f64; 8]| x.map(f64::exp),
    no_i32_lanes
);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fast_exp_is_accurate_on_the_rasterizer_range() {
        let mut worst = 0.0f64;
        for i in 0..=200_000 {
            let x = -30.0 + 30.0 * i as f32 / 200_000.0;
            let e = (x as f64).exp();
            worst = worst.max(((fast_exp_f32(x) as f64) - e).abs() / e);
        }
        assert!(worst < 5e-7, "relative error {worst}");
        assert_eq!(fast_exp_f32(-100.0), 0.0);
        for i in 0..=20_000 {
            let x: [f32; 8] = std::array::from_fn(|l| -95.0 + 0.000_6 * (8 * i + l) as f32);
            let lanes = fast_exp_f32x8(x);
            for l in 0..8 {
                assert_eq!(
                    lanes[l].to_bits(),
                    fast_exp_f32(x[l]).to_bits(),
                    "x = {}",
                    x[l]
                );
            }
        }
        assert_eq!(fast_exp_f32(0.0), 1.0);
    }
}
