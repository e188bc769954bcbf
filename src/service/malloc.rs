//! The C allocator's handling of the daemon's large, short-lived buffers.
//!
//! Why: an ingestion request holds its body and its samples (megabytes) for a few
//! milliseconds. glibc's malloc serves such blocks with `mmap` and returns them on `free`, but
//! after the first such `free` it raises its mmap threshold (up to 32 MiB) and serves the next
//! ones from its per-thread heaps, which keep freed memory. Bursts of 16 concurrent 4 MB bodies
//! then pushed the daemon's peak resident memory from 167 MiB after the first burst to 313 MiB
//! after the third (`tests/service_memory.rs`), over the documented bound (`docs/design.md`,
//! "Memory"). A fixed threshold keeps every block of 256 KiB and more on `mmap`: 197 MiB after
//! three bursts. Small allocations (the windows, the identification) are below it and unchanged.

/// Blocks at least this large are mapped and unmapped on their own.
pub const MMAP_THRESHOLD_BYTES: i32 = 256 * 1024;

/// Fixes glibc's mmap threshold at [`MMAP_THRESHOLD_BYTES`]. Call before the runtime's threads
/// start. Elsewhere than Linux with glibc it does nothing (other allocators decide themselves).
pub fn return_large_buffers_to_the_os() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        // SAFETY: `mallopt` takes two integers and no pointer, so it cannot touch Rust-owned
        // memory; glibc documents M_MMAP_THRESHOLD as settable at any time (it takes the
        // allocator's lock), and setting it also turns off the dynamic adjustment. It returns
        // 0 on an out-of-range value, which 256 KiB is not (the maximum is 32 MiB on 64-bit).
        let ok = unsafe { libc::mallopt(libc::M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES) };
        if ok == 0 {
            tracing::warn!("mallopt(M_MMAP_THRESHOLD) refused: the memory bound may not hold");
        }
    }
}
