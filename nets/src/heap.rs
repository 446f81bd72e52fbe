//! The C allocator's settings for the actor and learner processes.
//!
//! Both allocate and free a few MiB at every step: an actor's environment
//! step its state's planes, the observation's bytes and features, the camera
//! frame and the map's per-frame buffers; the learner's U-Net and PPO steps
//! their tensors and batches. With glibc's defaults, blocks that large are handed
//! back to the kernel when freed (the free top of a heap above the trim
//! threshold is trimmed, and blocks above the mmap threshold are unmapped),
//! so the next step touches fresh pages, and each page faults in, zeroed, by
//! the kernel: at 128 px a noticeable share of an actor's step, most of it
//! in the state (docs/performance.md, the actor's work per step), and of the
//! learner's training steps. Keeping freed memory in the process removes
//! that cost; the heap then holds its high-water mark (a few MiB per
//! environment, the largest batch's tensors in the learner). Lives in
//! `nets`, the crate both binaries share that is about their steps' work.

/// Blocks up to this size come from the heap, not from a mapping of their
/// own (the upper limit `mallopt(3)` documents for 64-bit systems).
#[cfg(all(target_os = "linux", target_env = "gnu"))]
const MMAP_THRESHOLD: libc::c_int = 32 << 20;

/// Free memory at a heap's top kept before any is given back.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
const TRIM_THRESHOLD: libc::c_int = 1 << 30;

/// Tells the allocator to keep freed memory for the next step instead of
/// returning it to the kernel; call it before any thread starts. Returns
/// whether the allocator took the settings (always true off glibc, where
/// there is nothing to set).
pub fn keep_freed_memory() -> bool {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        // SAFETY: mallopt only changes the allocator's parameters; called
        // before other threads allocate, as glibc asks.
        unsafe {
            libc::mallopt(libc::M_MMAP_THRESHOLD, MMAP_THRESHOLD) == 1
                && libc::mallopt(libc::M_TRIM_THRESHOLD, TRIM_THRESHOLD) == 1
        }
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    {
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_allocator_takes_the_settings() {
        assert!(keep_freed_memory());
    }
}
