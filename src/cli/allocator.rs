//! The process's allocator settings: glibc's malloc keeps freed memory for reuse instead of
//! mapping and unmapping every large block.
//!
//! Input: nothing. Output: on Linux with glibc, `M_MMAP_MAX` 0 (no block is served by its own
//! `mmap`) and `M_TRIM_THRESHOLD` at its largest (freed memory stays with the process), set once
//! at start-up before any other thread exists; elsewhere nothing. Invariant: outputs do not
//! depend on it (it changes where memory comes from, not what is computed).
//!
//! Why: a run allocates and frees arrays the size of the point cloud (72 MB per coordinate
//! array at 3M points) many times over. Above its mmap threshold glibc maps each one afresh and
//! unmaps it on free, so the kernel faults in and zeroes its pages again every time. Kept in the
//! heap, they are reused, for less system time and a little more peak memory. The library
//! never calls this: a program that links it keeps its own settings.

/// Applies the settings above; call first thing in `main`.
pub fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: `mallopt` only sets malloc's parameters; it is called before any other thread
    // exists, so no allocation runs beside it.
    unsafe {
        libc::mallopt(libc::M_MMAP_MAX, 0);
        libc::mallopt(libc::M_TRIM_THRESHOLD, libc::c_int::MAX);
    }
}
