//! Runtime CPU dispatch of the tile kernels.
//!
//! The forward and backward kernels ([`crate::forward::raster_tile`], [`crate::backward::backward_tile`])
//! are written on eight-pixel lanes ([`crate::lanes`]) and marked `#[inline(always)]`. Here each is
//! instantiated three times ([`Isa`]): for the baseline target (SSE2 pairs); inside an `avx2` function,
//! where LLVM maps a lane group of `f32` onto one 256-bit register; and inside an AVX-512 function,
//! where the lane groups stay 256-bit but LLVM has 32 vector registers instead of 16, so the kernels'
//! two dozen live accumulators and constants spill far less (BENCHMARKS.md §5 has the step times).
//! The choice is made per call from the CPU's features (`is_x86_feature_detected!` caches its answer). All builds run the same IEEE operations without
//! fused multiply-adds, so they return identical bits: the choice affects speed only (tested).
//!
//! One exception to "widest wins": a forward pass that renders the dense K-channel object map stays on
//! AVX2. With AVX-512 enabled, LLVM's cost model vectorises its per-channel loop *across* the channel
//! planes with gathers and scatters, which made that forward markedly slower. Training renders object
//! sums instead ([`crate::labels`]), which have no such loop.
//!
//! One of the two places in the crate with `unsafe` (the other is [`crate::intrinsics`]): calling a
//! `#[target_feature]` function is unsafe because it would fault on a CPU without the feature, and the
//! check just before each call rules that out.
#![allow(unsafe_code)]

use std::sync::atomic::{AtomicU8, Ordering};

use trand_core::Real;

use crate::backward::GradMaps;
use crate::binning::Bins;
use crate::camera::CamR;
use crate::layout::Layout;
use crate::preprocess::Proj;

/// Which build of the kernels to run, at most.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Dispatch {
    /// The widest the CPU supports (the default).
    Auto = 0,
    /// AVX2 at most (for tests and benchmarks that compare the builds).
    Avx2 = 1,
    /// The baseline build only.
    Baseline = 2,
}

static DISPATCH: AtomicU8 = AtomicU8::new(Dispatch::Auto as u8);

/// Selects the kernel build for every later render in the process.
pub fn set_dispatch(d: Dispatch) {
    DISPATCH.store(d as u8, Ordering::Relaxed);
}

/// The instruction sets a kernel can be compiled for, narrowest first.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Isa {
    /// The target's baseline (SSE2 on x86-64).
    Baseline,
    /// AVX2: 256-bit lanes, 16 vector registers.
    Avx2,
    /// AVX-512 (F, VL, BW, DQ): the same 256-bit lanes with 32 vector registers.
    Avx512,
}

/// The widest build that both the CPU and [`set_dispatch`] allow.
pub fn isa() -> Isa {
    let cap = match DISPATCH.load(Ordering::Relaxed) {
        0 => Isa::Avx512,
        1 => Isa::Avx2,
        _ => Isa::Baseline,
    };
    cap.min(cpu_isa())
}

#[cfg(target_arch = "x86_64")]
fn cpu_isa() -> Isa {
    use std::arch::is_x86_feature_detected as has;
    if has!("avx512f") && has!("avx512vl") && has!("avx512bw") && has!("avx512dq") {
        Isa::Avx512
    } else if has!("avx2") {
        Isa::Avx2
    } else {
        Isa::Baseline
    }
}

#[cfg(not(target_arch = "x86_64"))]
fn cpu_isa() -> Isa {
    Isa::Baseline
}

macro_rules! dispatch {
    ($(#[$doc:meta])* $name:ident, $avx2:ident, $avx512:ident, $imp:path, isa = $isa:expr,
     ($($arg:ident: $ty:ty),* $(,)?)) => {
        $(#[$doc])*
        #[allow(clippy::too_many_arguments)]
        pub fn $name<R: Real>($($arg: $ty),*) {
            let isa: Isa = $isa;
            #[cfg(target_arch = "x86_64")]
            match isa {
                // SAFETY: `isa` never exceeds `cpu_isa()` (see `isa()`; the callers only lower it), so
                // the CPU has every feature the called function enables.
                Isa::Avx512 => return unsafe { $avx512($($arg),*) },
                // SAFETY: as above.
                Isa::Avx2 => return unsafe { $avx2($($arg),*) },
                Isa::Baseline => {}
            }
            #[cfg(not(target_arch = "x86_64"))]
            let _ = isa;
            $imp($($arg),*)
        }

        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx2")]
        #[allow(clippy::too_many_arguments)]
        fn $avx2<R: Real>($($arg: $ty),*) {
            $imp($($arg),*)
        }

        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx2,avx512f,avx512vl,avx512bw,avx512dq")]
        #[allow(clippy::too_many_arguments)]
        fn $avx512<R: Real>($($arg: $ty),*) {
            $imp($($arg),*)
        }
    };
}

dispatch!(
    /// Stage 3 for tile `t`: see [`crate::forward::raster_tile`]. AVX-512 at most when the layout has
    /// no dense object planes (see the module doc).
    raster_tile, raster_tile_avx2, raster_tile_avx512, crate::forward::raster_tile,
    isa = if lay.has_objects { isa().min(Isa::Avx2) } else { isa() },
    (t: usize, bins: &Bins, projs: &[Proj<R>], probs: &[R], lay: &Layout, cam: &CamR<R>, background: [R; 3],
     labels: Option<&[u8]>, buf: &mut [R], ibuf: &mut [u32], rows: &mut [u16])
);

dispatch!(
    /// Stage 4 for tile `t`: see [`crate::backward::backward_tile`].
    backward_tile, backward_tile_avx2, backward_tile_avx512, crate::backward::backward_tile,
    isa = isa(),
    (t: usize, bins: &Bins, projs: &[Proj<R>], probs: &[R], lay: &Layout, cam: &CamR<R>, background: [R; 3],
     buf: &[R], ibuf: &[u32], rows: &[u16], labels: Option<&[u8]>, grads: &GradMaps<'_, R>, pairs: &mut [R])
);
