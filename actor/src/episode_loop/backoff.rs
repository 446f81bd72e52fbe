//! The actor's pause after rollouts the learner had no room for.

use std::time::Duration;

use transport::Delivery;

/// Back-off after rollouts the learner had no room for: its queue for this
/// actor was full, so it is not keeping up. Producing more would only be
/// discarded, and it would keep this actor's queue full, where the learner
/// (which serves its senders in a fixed order) might never reach the others.
/// Sleeps 1 ms after the first drop in a row, doubling to at most 64 ms; a
/// delivered chunk resets it. Simulator actors are far slower than the
/// learner and rarely see it; a fast fixture is paced to the learner.
#[derive(Debug, Default)]
pub(super) struct Backoff {
    sleep: Option<Duration>,
}

impl Backoff {
    pub(super) fn after(&mut self, delivery: Delivery) {
        self.sleep = match delivery {
            Delivery::Delivered(_) => None,
            Delivery::Dropped => {
                let sleep = self.sleep.map_or(Duration::from_millis(1), |s| {
                    (s * 2).min(Duration::from_millis(64))
                });
                std::thread::sleep(sleep);
                Some(sleep)
            }
        };
    }
}
