//! The few CPU intrinsics the tile kernels call directly: cache prefetch hints for the surfel a few
//! places ahead in a tile's list, and the lane mask's sign bits.
//!
//! Kept apart from the run-time dispatch ([`crate::simd`]) because the kernels use these while the
//! dispatch uses the kernels: one module each keeps the imports one-way. Each `unsafe` block here is a
//! baseline x86-64 instruction that cannot fault (SAFETY comments at each).
#![allow(unsafe_code)]

use trand_core::Real;

/// Asks the CPU to start loading the cache lines of `*r` (up to 256 bytes): the kernels call it for
/// the surfel a few places ahead in a tile's list, whose data sits at a random address. A hint only:
/// no effect on results, and a no-op off x86-64.
#[inline(always)]
pub fn prefetch<T>(r: &T) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        let p = (r as *const T).cast::<i8>();
        let lines = std::mem::size_of::<T>().div_ceil(64).min(4);
        for l in 0..lines {
            // SAFETY: prefetching never faults, and `p + 64·l` stays within (or one line past) `*r`.
            unsafe { _mm_prefetch::<_MM_HINT_T0>(p.wrapping_add(64 * l)) };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = r;
}

/// [`prefetch`] for the cache lines of a slice (up to 256 bytes from its start): a surfel's object
/// probabilities live in their own array, as far from the last surfel's as its `Proj`.
#[inline(always)]
pub fn prefetch_slice<T>(s: &[T]) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        let p = s.as_ptr().cast::<i8>();
        let bytes = std::mem::size_of_val(s).min(256);
        // The lines the slice's first `bytes` touch, from its (possibly unaligned) start.
        let lines = (p as usize % 64 + bytes).div_ceil(64);
        for l in 0..lines {
            // SAFETY: prefetching never faults; the addresses stay within one line past the slice.
            unsafe { _mm_prefetch::<_MM_HINT_T0>(p.wrapping_add(64 * l)) };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = s;
}

/// Bit `l` set where lane `l` of the mask `m` is (its sign bit): two `movmskps` for `f32` lanes on
/// x86-64 (LLVM compiled the portable loop below to shifts, ands and a horizontal reduction).
#[inline(always)]
pub fn sign_bits<R: Real>(m: &[R::Lane; 8]) -> u8 {
    #[cfg(target_arch = "x86_64")]
    if let Some(v) = R::lanes_as_i32(m) {
        use std::arch::x86_64::{_mm_castsi128_ps, _mm_loadu_si128, _mm_movemask_ps};
        // SAFETY: SSE2 is part of the x86-64 baseline; both loads read four `i32` inside `v`.
        let (lo, hi) = unsafe {
            let p = v.as_ptr().cast::<std::arch::x86_64::__m128i>();
            (
                _mm_movemask_ps(_mm_castsi128_ps(_mm_loadu_si128(p))),
                _mm_movemask_ps(_mm_castsi128_ps(_mm_loadu_si128(p.add(1)))),
            )
        };
        return (lo | hi << 4) as u8;
    }
    let zero = R::Lane::from(0);
    let mut b = 0u8;
    for (l, &x) in m.iter().enumerate() {
        b |= u8::from(x < zero) << l;
    }
    b
}

/// How many list entries ahead the kernels prefetch.
pub const PREFETCH_AHEAD: usize = 4;
