//! Where the episode loop's thread spends its time: waiting for its
//! environments, or on one of its chores, reported per step when the loop
//! ends.

use std::time::{Duration, Instant};

/// What the loop's thread spends its time on besides waiting.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Chore {
    /// Loading the learner's new weights.
    Weights,
    /// Choosing actions and sending the tasks.
    Actions,
    /// Adding steps to their episodes' rollout chunks.
    Booking,
    /// Closing full chunks and sending them to the learner.
    Chunks,
    /// Sending ended episodes' labelled frames and stats.
    Ends,
}

impl Chore {
    const ALL: [Chore; 5] = [
        Chore::Weights,
        Chore::Actions,
        Chore::Booking,
        Chore::Chunks,
        Chore::Ends,
    ];

    fn name(self) -> &'static str {
        match self {
            Chore::Weights => "new weights",
            Chore::Actions => "actions",
            Chore::Booking => "booking steps",
            Chore::Chunks => "sending chunks",
            Chore::Ends => "sending episode ends",
        }
    }
}

/// Where the loop's thread spent its time. Every environment waits for
/// this thread between its steps, so a loop busy nearly all the time is
/// what holds a process back, and the split says which chore to move or
/// cut.
#[derive(Debug, Default)]
pub(super) struct LoopClock {
    /// Time spent waiting for the environments.
    pub(super) waited: Duration,
    chores: [Duration; Chore::ALL.len()],
}

impl LoopClock {
    /// Runs `chore`, adding its time to its account.
    pub(super) fn time<T>(&mut self, chore: Chore, f: impl FnOnce() -> T) -> T {
        let started = Instant::now();
        let result = f();
        self.chores[chore as usize] += started.elapsed();
        result
    }

    /// One line: the busy share of `all` and, per step of `steps`, the
    /// time of each chore.
    pub(super) fn report(&self, all: Duration, steps: u64) -> String {
        let all_s = all.as_secs_f64().max(1e-9);
        let busy = (all_s - self.waited.as_secs_f64()).max(0.0);
        let per_step_ms = |d: Duration| 1e3 * d.as_secs_f64() / steps.max(1) as f64;
        let split: Vec<String> = Chore::ALL
            .iter()
            .map(|&c| format!("{} {:.3}", c.name(), per_step_ms(self.chores[c as usize])))
            .collect();
        format!(
            "the loop's thread was busy {:.0} % of {:.0} s (waiting for its environments the rest): \
             {:.3} ms a step over {steps} steps ({} ms)",
            100.0 * busy / all_s,
            all_s,
            1e3 * busy / steps.max(1) as f64,
            split.join(", ")
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_loops_report_splits_its_busy_time_per_step() {
        let mut clock = LoopClock {
            waited: Duration::from_millis(600),
            ..LoopClock::default()
        };
        clock.chores[Chore::Chunks as usize] = Duration::from_millis(300);
        clock.chores[Chore::Ends as usize] = Duration::from_millis(100);
        let line = clock.report(Duration::from_secs(1), 200);
        assert!(
            line.starts_with("the loop's thread was busy 40 % of 1 s"),
            "{line}"
        );
        assert!(line.contains("2.000 ms a step over 200 steps"), "{line}");
        assert!(
            line.contains("sending chunks 1.500, sending episode ends 0.500 ms"),
            "{line}"
        );
        assert!(line.contains("new weights 0.000,"), "{line}");
    }
}
