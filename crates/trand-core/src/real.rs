//! A minimal floating-point trait.
//!
//! The rasterizer and the losses are written once, generic over `R: Real`, and instantiated with `f32`
//! in production and `f64` in the finite-difference tests: the gradients checked in tests are those of the
//! very code that runs in training, not of a re-implementation.

use core::fmt::Debug;
use core::ops::{Add, AddAssign, Div, DivAssign, Mul, MulAssign, Neg, Sub, SubAssign};

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
    /// overrides it with a faster polynomial (relative error < 2e-7, see [`fast_exp_f32`]).
    #[inline(always)]
    fn fast_exp(self) -> Self {
        self.exp()
    }
}

/// `exp(x)` in f32 by Cody–Waite range reduction `x = n·ln2 + r`, `|r| ≤ ln2/2`, and a degree-6
/// Taylor polynomial for `e^r` (truncation error < 2e-7 relative on that interval), scaled by `2ⁿ`
/// through the exponent bits. Inputs below −87 return 0 (the result would be denormal).
#[inline(always)]
pub fn fast_exp_f32(x: f32) -> f32 {
    if x < -87.0 {
        return 0.0;
    }
    let x = x.min(88.0);
    // floor(y + ½) without a libm call (no SSE4.1 rounding instruction on baseline x86-64).
    let y = x * std::f32::consts::LOG2_E + 0.5;
    let t = y as i32;
    let n = (t - i32::from((t as f32) > y)) as f32;
    // ln2 split in a high part exact in f32 and a low correction.
    let r = x - n * 0.693_145_75 - n * 1.428_606_8e-6;
    let p = 1.0
        + r * (1.0 + r * (0.5 + r * (1.0 / 6.0 + r * (1.0 / 24.0 + r * (1.0 / 120.0 + r * (1.0 / 720.0))))));
    let bits = ((n as i32 + 127) as u32) << 23;
    p * f32::from_bits(bits)
}

macro_rules! impl_real {
    ($t:ty, $fast:expr) => {
        impl Real for $t {
            const ZERO: Self = 0.0;
            const ONE: Self = 1.0;
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
        }
    };
}
impl_real!(f32, fast_exp_f32);
impl_real!(f64, f64::exp);

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
        assert_eq!(fast_exp_f32(0.0), 1.0);
    }
}
