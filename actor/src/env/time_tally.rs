//! A process-wide running total of time, for the counters benchmarks and
//! an actor's last lines read as the difference of two readings (the
//! U-Net's batches, the environments' steps).

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

/// Time added up from many threads without a lock (nanoseconds).
pub(crate) struct TimeTally(AtomicU64);

impl TimeTally {
    /// Nothing added yet (usable in a `static`).
    pub(crate) const fn new() -> Self {
        Self(AtomicU64::new(0))
    }

    /// Adds `time` (saturating at about 584 years).
    pub(crate) fn add(&self, time: Duration) {
        let ns = u64::try_from(time.as_nanos()).unwrap_or(u64::MAX);
        self.0.fetch_add(ns, Ordering::Relaxed);
    }

    /// Everything added so far.
    pub(crate) fn total(&self) -> Duration {
        Duration::from_nanos(self.0.load(Ordering::Relaxed))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn adds_up_what_threads_add() {
        static TALLY: TimeTally = TimeTally::new();
        std::thread::scope(|s| {
            for _ in 0..4 {
                s.spawn(|| (0..100).for_each(|_| TALLY.add(Duration::from_micros(5))));
            }
        });
        assert_eq!(TALLY.total(), Duration::from_millis(2));
    }
}
