//! The global allocator: mimalloc, told to keep the pages it frees.
//!
//! Every training iteration allocates and frees the same large buffers (preprocessed surfels, tile
//! blocks, pair records, gradient maps: tens of MiB). glibc's allocator returned them to the kernel and
//! took a page fault per 4 KiB on the next iteration (0.9 M faults, a fifth of the time, in a
//! 100-iteration refinement), hence mimalloc.
//!
//! mimalloc in turn *purges* free memory after a delay (decommits it, `MADV_DONTNEED`), and the next
//! iteration faults it back in, zero-filled by the kernel. How often that happens depends on timing,
//! and on this project's 2-core machine it swung from a few thousand faults per run to millions: a
//! seq_105 t=0 run (1000 iterations) took 89.7 s with 6.4 M page faults and 164 s of CPU, and 64.4 s
//! with 465 faults and 125 s of CPU once purging was off (BENCHMARKS.md §10). So trand turns
//! purging off: freed pages stay with the process for reuse, and the resident size stays at the run's
//! high-water mark (360–400 MB for a t=0 run at 320×240) instead of shrinking between iterations.
//!
//! A `MIMALLOC_PURGE_DELAY` set in the environment (milliseconds; mimalloc's own variable) wins.
#![allow(unsafe_code)]

use libmimalloc_sys::{mi_option_get, mi_option_set, mi_option_t};

#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// `mi_option_purge_delay` in mimalloc v3's option enum (`mimalloc.h`). The bindings do not export
/// option constants, so [`keep_freed_pages`] checks that this index holds the option's documented
/// default before changing it.
const PURGE_DELAY: mi_option_t = 15;

/// mimalloc v3's default purge delay (ms), used to recognise the option.
const DEFAULT_PURGE_DELAY_MS: std::os::raw::c_long = 1000;

/// "Never purge".
const NEVER: std::os::raw::c_long = -1;

/// Turns mimalloc's purging off, unless the environment sets it or the option is not where expected.
/// Call it first thing in `main`, before any other thread exists: mimalloc's option calls are not
/// thread-safe.
pub fn keep_freed_pages() {
    if std::env::var_os("MIMALLOC_PURGE_DELAY").is_none() {
        never_purge_if_default();
    }
}

/// Sets the purge delay to [`NEVER`] if [`PURGE_DELAY`] holds the option's default, and leaves any other
/// value alone (a set option, or an index that names another option in this mimalloc build).
fn never_purge_if_default() {
    // SAFETY: plain C calls on an integer option index; `mi_option_get`/`mi_option_set` accept any
    // index below the option count (15 is below it in both mimalloc v2 and v3), and no other thread
    // can call into mimalloc's options concurrently this early in `main`.
    unsafe {
        if mi_option_get(PURGE_DELAY) == DEFAULT_PURGE_DELAY_MS {
            mi_option_set(PURGE_DELAY, NEVER);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn purge_delay() -> std::os::raw::c_long {
        // SAFETY: as in `never_purge_if_default`; the option is a plain integer that other test threads
        // only read.
        unsafe { mi_option_get(PURGE_DELAY) }
    }

    fn set_purge_delay(v: std::os::raw::c_long) {
        // SAFETY: as above.
        unsafe { mi_option_set(PURGE_DELAY, v) }
    }

    /// `cargo test` sets `MIMALLOC_PURGE_DELAY` for the processes it starts (`.cargo/config.toml`), so
    /// [`keep_freed_pages`] itself returns early here; the test drives the option change directly, from
    /// the default, and checks that the index is the purge delay by finding the environment's value
    /// (or the default) there first.
    #[test]
    fn index_is_the_purge_delay_and_only_its_default_is_turned_off() {
        let before = purge_delay();
        match std::env::var("MIMALLOC_PURGE_DELAY") {
            Ok(s) => assert_eq!(before.to_string(), s.trim(), "option {PURGE_DELAY}"),
            Err(_) => assert_eq!(before, DEFAULT_PURGE_DELAY_MS, "option {PURGE_DELAY}"),
        }
        set_purge_delay(DEFAULT_PURGE_DELAY_MS);
        never_purge_if_default();
        assert_eq!(purge_delay(), NEVER);
        set_purge_delay(500);
        never_purge_if_default();
        assert_eq!(purge_delay(), 500, "a value set by the user is kept");
        set_purge_delay(before);
    }
}
