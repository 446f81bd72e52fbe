//! Where the environments' threads of this process spent their steps, in
//! all: read as the difference of two readings, like
//! [`crate::sampling::unet_batcher::batch_times`].
//!
//! Why it exists: one actor process alone steps faster at 128 px on an H200
//! than the whole system there with the learner beside it
//! (docs/performance.md, "One actor" and "The whole system"), while the
//! actor's loop thread and its U-Net batching thread were both far from
//! busy. Each environment's step is its own work (acting,
//! rendering, mapping, the state, the policy's pass) and its waits (a
//! render's read-back, its frame's U-Net batch); an actor says
//! how long each took on average when it stops, so that a run beside the
//! learner tells which of them grew.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use super::time_tally::TimeTally;

/// Time the environments' threads spent on the parts of their steps.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct StepPhases {
    /// Steps taken.
    pub steps: u64,
    /// The step begun: the action, the camera frame rendered, the map.
    pub acting: Duration,
    /// Of `acting`, rendering (zero for environments without a camera).
    pub rendering: Duration,
    /// The U-Net's planes for the frame, waiting for a batch included.
    pub unet: Duration,
    /// The observation completed: the state, targets and mask.
    pub state: Duration,
    /// The policy's CPU pass over the observation.
    pub policy: Duration,
}

impl StepPhases {
    /// What happened from `earlier` to this reading.
    pub fn since(&self, earlier: &StepPhases) -> StepPhases {
        StepPhases {
            steps: self.steps - earlier.steps,
            acting: self.acting - earlier.acting,
            rendering: self.rendering - earlier.rendering,
            unet: self.unet - earlier.unet,
            state: self.state - earlier.state,
            policy: self.policy - earlier.policy,
        }
    }

    /// One phrase: the mean time of each part of a step; `None` when no
    /// step was taken.
    pub fn describe(&self) -> Option<String> {
        (self.steps > 0).then(|| {
            let ms = |d: Duration| d.as_secs_f64() * 1e3 / self.steps as f64;
            format!(
                "its environments' steps took {:.2} ms each on average: acting and mapping {:.2} \
                 (rendering {:.2} of it), the U-Net's planes {:.2} (waiting for a batch \
                 included), the state {:.2}, the policy's pass {:.2}",
                ms(self.acting + self.unet + self.state + self.policy),
                ms(self.acting),
                ms(self.rendering),
                ms(self.unet),
                ms(self.state),
                ms(self.policy),
            )
        })
    }
}

static STEPS: AtomicU64 = AtomicU64::new(0);
static ACTING: TimeTally = TimeTally::new();
static RENDERING: TimeTally = TimeTally::new();
static UNET: TimeTally = TimeTally::new();
static STATE: TimeTally = TimeTally::new();
static POLICY: TimeTally = TimeTally::new();

/// This process's [`StepPhases`] so far.
pub fn step_phases() -> StepPhases {
    StepPhases {
        steps: STEPS.load(Ordering::Relaxed),
        acting: ACTING.total(),
        rendering: RENDERING.total(),
        unet: UNET.total(),
        state: STATE.total(),
        policy: POLICY.total(),
    }
}

/// Books one step's parts.
pub(crate) fn record(step: &StepPhases) {
    STEPS.fetch_add(step.steps, Ordering::Relaxed);
    ACTING.add(step.acting);
    RENDERING.add(step.rendering);
    UNET.add(step.unet);
    STATE.add(step.state);
    POLICY.add(step.policy);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn describes_the_mean_of_each_part_since_an_earlier_reading() {
        let ms = Duration::from_millis;
        let earlier = StepPhases {
            steps: 10,
            acting: ms(100),
            ..StepPhases::default()
        };
        let now = StepPhases {
            steps: 14,
            acting: ms(120),
            rendering: ms(4),
            unet: ms(8),
            state: ms(6),
            policy: ms(2),
        };
        let line = now.since(&earlier).describe().expect("four steps");
        assert_eq!(
            line,
            "its environments' steps took 9.00 ms each on average: acting and mapping 5.00 \
             (rendering 1.00 of it), the U-Net's planes 2.00 (waiting for a batch included), \
             the state 1.50, the policy's pass 0.50"
        );
        assert_eq!(earlier.since(&earlier).describe(), None, "no steps");
    }
}
