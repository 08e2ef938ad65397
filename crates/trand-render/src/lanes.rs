//! Eight-pixel lanes for the tile kernels.
//!
//! A tile row is 16 pixels; the kernels process it as two halves of [`LANES`] = 8 pixels with the same
//! arithmetic in every lane, masks instead of branches. [`V`] is a plain `[R; 8]` whose operators are
//! element-wise loops: with the kernels inlined into an AVX2 function (see [`crate::simd`]) LLVM turns
//! each operator into one 256-bit instruction for `f32`, and into SSE2 pairs on the baseline target.
//! No fused multiply-add is ever formed (Rust does not contract `a * b + c`), so every lane computes
//! bit for bit what the scalar expression would: the vector width changes speed, never results.
//!
//! Lanes outside the mask are *sanitised* (finite placeholder values, zero weight) rather than skipped,
//! so that `0 · x` never meets an infinity or NaN.

use core::ops::{Add, AddAssign, BitAnd, Div, Mul, Not, Sub, SubAssign};

use trand_core::Real;

/// Pixels per lane group: half a tile row.
pub const LANES: usize = 8;

/// Eight values of `R`.
#[derive(Clone, Copy, Debug)]
pub struct V<R>(pub [R; LANES]);

/// A lane mask in the lanes' own width: `-1` (all bits set) where set, `0` where clear ([`Real::Lane`]),
/// the form a SIMD comparison produces. A comparison is then one instruction, `&` and `!` are bitwise,
/// [`select`] is one blend on the sign bit and [`M::bits`] one `movmskps`. (A `[bool; 8]` mask made
/// LLVM extract every lane and branch on it; 0.0/1.0 float masks cost a compare or an `and` more per
/// comparison and per select.)
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct M<R: Real>(pub [R::Lane; LANES]);

/// Lane masks of every byte: `MASK_TABLE[b][l]` is -1 where bit `l` of `b` is set (8 KiB).
static MASK_TABLE: [[i32; LANES]; 256] = {
    let mut t = [[0i32; LANES]; 256];
    let mut b = 0;
    while b < 256 {
        let mut l = 0;
        while l < LANES {
            if (b >> l) & 1 != 0 {
                t[b][l] = -1;
            }
            l += 1;
        }
        b += 1;
    }
    t
};

/// `[f(0), …, f(7)]` by a plain loop (the standard `from_fn`/`map` are not always inlined into the AVX2
/// kernels, and a call per lane would cost more than the arithmetic).
macro_rules! lanes {
    ($init:expr, |$l:ident| $e:expr) => {{
        let mut out = [$init; LANES];
        for $l in 0..LANES {
            out[$l] = $e;
        }
        out
    }};
}

impl<R: Real> V<R> {
    #[inline(always)]
    pub fn splat(r: R) -> Self {
        Self([r; LANES])
    }
    #[inline(always)]
    pub fn load(s: &[R]) -> Self {
        Self(lanes!(R::ZERO, |l| s[l]))
    }
    #[inline(always)]
    pub fn store(self, s: &mut [R]) {
        s[..LANES].copy_from_slice(&self.0);
    }
    /// `s[l] += self[l]`.
    #[inline(always)]
    pub fn add_to(self, s: &mut [R]) {
        for (d, v) in s[..LANES].iter_mut().zip(self.0) {
            *d += v;
        }
    }
    #[inline(always)]
    pub fn map(self, f: impl Fn(R) -> R) -> Self {
        Self(lanes!(R::ZERO, |l| f(self.0[l])))
    }
    #[inline(always)]
    pub fn lt(self, o: Self) -> M<R> {
        M(lanes!(lane_false::<R>(), |l| if self.0[l] < o.0[l] {
            lane_true::<R>()
        } else {
            lane_false::<R>()
        }))
    }
    #[inline(always)]
    pub fn le(self, o: Self) -> M<R> {
        M(lanes!(lane_false::<R>(), |l| if self.0[l] <= o.0[l] {
            lane_true::<R>()
        } else {
            lane_false::<R>()
        }))
    }
    #[inline(always)]
    pub fn gt(self, o: Self) -> M<R> {
        M(lanes!(lane_false::<R>(), |l| if self.0[l] > o.0[l] {
            lane_true::<R>()
        } else {
            lane_false::<R>()
        }))
    }
    #[inline(always)]
    pub fn ne(self, o: Self) -> M<R> {
        M(lanes!(lane_false::<R>(), |l| if self.0[l] != o.0[l] {
            lane_true::<R>()
        } else {
            lane_false::<R>()
        }))
    }
    /// Lane sum as a fixed tree, `((v0 + v4) + (v2 + v6)) + ((v1 + v5) + (v3 + v7))`: deterministic,
    /// and the shape of a vector reduction (upper half onto lower half, twice, then one add): a few
    /// instructions, where the sum in lane order took an extraction and a dependent add per lane. The
    /// backward pass sums ~30 accumulators per pair this way.
    #[inline(always)]
    pub fn sum(self) -> R {
        let v = self.0;
        let s4 = [v[0] + v[4], v[1] + v[5], v[2] + v[6], v[3] + v[7]];
        let s2 = [s4[0] + s4[2], s4[1] + s4[3]];
        s2[0] + s2[1]
    }
}

/// `m ? a : b` per lane.
#[inline(always)]
pub fn select<R: Real>(m: M<R>, a: V<R>, b: V<R>) -> V<R> {
    V(lanes!(R::ZERO, |l| if m.0[l] < lane_false::<R>() {
        a.0[l]
    } else {
        b.0[l]
    }))
}

/// The set lane value, `-1`.
#[inline(always)]
fn lane_true<R: Real>() -> R::Lane {
    R::Lane::from(-1)
}

/// The clear lane value, `0`.
#[inline(always)]
fn lane_false<R: Real>() -> R::Lane {
    R::Lane::from(0)
}

impl<R: Real> M<R> {
    /// Lane `l` set where bit `l` of `bits` is: one row of [`MASK_TABLE`] (a 32-byte load for `f32`;
    /// building the lanes bit by bit compiled to a dozen shuffles and compares).
    #[inline(always)]
    pub fn from_bits(bits: u8) -> Self {
        let row = &MASK_TABLE[bits as usize];
        Self(lanes!(lane_false::<R>(), |l| R::Lane::from(row[l])))
    }
    /// Lane `l` set where `f(l)`.
    #[inline(always)]
    pub fn from_fn(f: impl Fn(usize) -> bool) -> Self {
        Self(lanes!(lane_false::<R>(), |l| if f(l) {
            lane_true::<R>()
        } else {
            lane_false::<R>()
        }))
    }
    /// Whether lane `l` is set.
    #[inline(always)]
    pub fn lane(self, l: usize) -> bool {
        self.0[l] < lane_false::<R>()
    }
    /// Bit `l` set where lane `l` is (the lanes' sign bits: one `movmskps` for `f32`).
    #[inline(always)]
    pub fn bits(self) -> u8 {
        crate::intrinsics::sign_bits::<R>(&self.0)
    }
    #[inline(always)]
    pub fn any(self) -> bool {
        self.bits() != 0
    }
}

impl<R: Real> BitAnd for M<R> {
    type Output = M<R>;
    #[inline(always)]
    fn bitand(self, o: M<R>) -> M<R> {
        M(lanes!(lane_false::<R>(), |l| self.0[l] & o.0[l]))
    }
}

impl<R: Real> Not for M<R> {
    type Output = M<R>;
    #[inline(always)]
    fn not(self) -> M<R> {
        M(lanes!(lane_false::<R>(), |l| !self.0[l]))
    }
}

macro_rules! lane_op {
    ($tr:ident, $f:ident, $op:tt) => {
        impl<R: Real> $tr for V<R> {
            type Output = V<R>;
            #[inline(always)]
            fn $f(self, o: V<R>) -> V<R> {
                V(lanes!(R::ZERO, |l| self.0[l] $op o.0[l]))
            }
        }
        impl<R: Real> $tr<R> for V<R> {
            type Output = V<R>;
            #[inline(always)]
            fn $f(self, o: R) -> V<R> {
                V(lanes!(R::ZERO, |l| self.0[l] $op o))
            }
        }
    };
}
lane_op!(Add, add, +);
lane_op!(Sub, sub, -);
lane_op!(Mul, mul, *);
lane_op!(Div, div, /);

impl<R: Real> AddAssign for V<R> {
    #[inline(always)]
    fn add_assign(&mut self, o: V<R>) {
        *self = *self + o;
    }
}

impl<R: Real> SubAssign for V<R> {
    #[inline(always)]
    fn sub_assign(&mut self, o: V<R>) {
        *self = *self - o;
    }
}

/// `r − v` per lane.
#[inline(always)]
pub fn rsub<R: Real>(r: R, v: V<R>) -> V<R> {
    V(lanes!(R::ZERO, |l| r - v.0[l]))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mask_bits_round_trip_every_pattern() {
        for b in 0..=255u8 {
            assert_eq!(M::<f32>::from_bits(b).bits(), b);
            assert_eq!((!M::<f64>::from_bits(b)).bits(), !b);
            assert_eq!(
                (M::<f32>::from_bits(b) & M::from_bits(0b0110_1100)).bits(),
                b & 0b0110_1100
            );
        }
    }

    #[test]
    fn select_takes_a_where_set_and_b_elsewhere() {
        let a = V([1.0f32; LANES]);
        let b = V([2.0f32; LANES]);
        let r = select(M::from_bits(0b1010_0101), a, b);
        assert_eq!(r.0, [1.0, 2.0, 1.0, 2.0, 2.0, 1.0, 2.0, 1.0]);
    }
}
