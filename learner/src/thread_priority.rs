//! Lowering the priority of the learner's training threads, so that its
//! receive loop runs first on a host whose cores the actors fill.
//!
//! Why it exists: an actor's messages wait in a buffer of
//! `transport.learner_buffer` per service, and the newest is lost when the
//! receive loop has not emptied it in time. With the actors and the
//! learner at one priority, the loop waits its turn behind the actors'
//! threads on a busy host: on the 2-core VM the bandit fixture's flood of
//! messages lost about a third as many with the loop first
//! (docs/performance.md, "The whole system";
//! docs/notebook/2026-11-28-what-holds-the-whole-system.md). On an H200
//! the 128-px whole system lost messages while the same learner fed by
//! synthetic actors (no competition for the CPU) lost none at a higher
//! rate; whether the loop's turn is why there is measured next on a GPU.
//! `deploy/local.sh` starts its actors at a niceness (`--actor-nice`, 10)
//! and gives the learner the same for its training threads
//! ([`crate::config::LearnerConfig::training_nice`]): training and actors
//! share the CPU as they did at one priority, and only the receive loop
//! (and the HTTP endpoint) run before them. Linux keeps a niceness per
//! thread, and threads a thread starts (a backend's worker pool) inherit
//! it.

/// Raises the calling thread's niceness by `by` (0..=19; lower priority),
/// leaving the process's other threads as they are. On failure, says so
/// and carries on at the old priority: a slower receive loop costs
/// messages, not correctness.
pub(crate) fn lower_this_thread(by: i32) {
    if by <= 0 {
        return;
    }
    // SAFETY: gettid has no preconditions.
    let tid = unsafe { libc::gettid() } as libc::id_t;
    // getpriority may return -1 as a niceness: errno tells an error apart.
    // SAFETY: errno is this thread's; the calls take plain integers.
    let current = unsafe {
        *libc::__errno_location() = 0;
        libc::getpriority(libc::PRIO_PROCESS, tid)
    };
    // SAFETY: as above.
    let failed = current == -1 && unsafe { *libc::__errno_location() } != 0;
    let wanted = (current + by).min(19);
    // SAFETY: setpriority takes plain integers; with a thread id, Linux
    // changes that thread only.
    if failed || unsafe { libc::setpriority(libc::PRIO_PROCESS, tid, wanted) } != 0 {
        tracing::warn!(
            "cannot lower this training thread's priority ({}); it runs at the receive loop's",
            std::io::Error::last_os_error()
        );
    }
}

/// This thread's niceness (for tests).
#[cfg(test)]
fn this_threads_niceness() -> i32 {
    // SAFETY: as in `lower_this_thread`.
    unsafe { libc::getpriority(libc::PRIO_PROCESS, libc::gettid() as libc::id_t) }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lowers_only_the_calling_thread() {
        let before = this_threads_niceness();
        let inside = std::thread::spawn(move || {
            lower_this_thread(3);
            let lowered = this_threads_niceness();
            // A thread started from a lowered one inherits its niceness.
            let child = std::thread::spawn(this_threads_niceness).join().unwrap();
            (lowered, child)
        })
        .join()
        .unwrap();
        let expected = (before + 3).min(19);
        assert_eq!(inside, (expected, expected));
        assert_eq!(
            this_threads_niceness(),
            before,
            "the caller's thread is untouched"
        );
        std::thread::spawn(|| {
            let at = this_threads_niceness();
            lower_this_thread(0);
            assert_eq!(this_threads_niceness(), at, "0 changes nothing");
        })
        .join()
        .unwrap();
    }
}
