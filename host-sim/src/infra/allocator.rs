//! The C allocator's thresholds, set once when `dncal diagnose` starts.
//!
//! glibc's `malloc` serves a block above its mmap threshold (128 KiB, rising with the
//! blocks freed, to at most 32 MiB) with a mapping of its own and gives it back with
//! `munmap` when freed; and it trims the heap's free top above 128 KiB. On a machine with
//! more than one core, each unmapping of pages another thread of the process has touched
//! costs a TLB shootdown: an interrupt to every core running the process. The analyses
//! allocate and free per-level and per-block buffers of megabytes in parallel loops, so
//! `perf` showed `native_write_msr` and `smp_call_function_many_cond` (the kernel's side
//! of those shootdowns) at 10.5% of a `dncal diagnose` of a 128 x 128 x 41 set
//! (2026-12-04, 2-vCPU Xeon). With the threshold at its 32 MiB maximum and the heap kept
//! up to 64 MiB of free top, freed blocks are reused instead: the same run took 1.86-1.88 s
//! against 2.15-2.16 s (`GLIBC_TUNABLES`, three runs each); `farm-bench`, pairs of whole
//! commands against the build before: wall 0.884 (8 pairs, 0.859-0.942) and 0.879 (6
//! pairs), peak 84.9 MiB against 84.7 (medians). Blocks of 32 MiB and
//! more (a set's cubes) are still mapped and unmapped on their own.
//!
//! Only `diagnose` sets them: `linearity` on a 512 x 512 x 41 set ran at 1.02-1.03 of
//! before (no gain) and `stream --frames 64` at 1.01 with a peak of 159 MiB against 130
//! (the heap kept what `munmap` had returned).

/// The mmap threshold: glibc's largest (`DEFAULT_MMAP_THRESHOLD_MAX` on 64-bit).
pub const MMAP_THRESHOLD_BYTES: i32 = 32 << 20;
/// The free top the heap keeps before it trims.
pub const TRIM_THRESHOLD_BYTES: i32 = 64 << 20;

/// Sets the thresholds (glibc on Linux; elsewhere nothing). Whether glibc took both (it
/// takes any value here; a newer glibc that capped the threshold would say no). Not
/// tested in the library's tests: it changes the allocator of the whole test process
/// while other tests allocate, and `mallopt` is not safe beside other threads.
pub fn reuse_freed_blocks() -> bool {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        // SAFETY: mallopt only sets the allocator's parameters; `dncal`'s main calls this
        // before any thread starts (mallopt is not thread-safe).
        unsafe { libc::mallopt(libc::M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES) == 1 && libc::mallopt(libc::M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES) == 1 }
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    {
        false
    }
}
