//! The paper's reward, R = α1·R_nav + α2·R_int + α3·R_fail:
//! R_nav is 1 for a position not visited before in the episode and 0.3 for
//! a new heading at a visited position; R_int is 1 for the first successful
//! interaction of each kind with an object instance; R_fail is −1 for any
//! failed action. Beyond the paper, `first_try` pays the first attempt of
//! each kind on an object instance whose outcome labels it.

use std::collections::HashSet;

use mapper::Affordance;
use sim::agent::{AgentState, STEP_M};

pub use proto::RewardWeights;

/// Reward for a new position.
const NEW_POSITION: f32 = 1.0;
/// Reward for a new heading at a known position.
const NEW_HEADING: f32 = 0.3;

/// What happened in a step, as the reward sees it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct StepEvent {
    /// The agent after the step.
    pub agent: AgentState,
    /// Whether the action succeeded.
    pub success: bool,
    /// For interactions: the affordance tried and the object instance.
    pub interaction: Option<(Affordance, usize)>,
    /// Whether the interaction's outcome tells the affordance of its object
    /// (a success, or a failure of the object itself), so that it labels it.
    pub informative: bool,
}

/// The reward's memory of one episode.
#[derive(Debug, Clone, Default)]
pub(crate) struct RewardTracker {
    weights: RewardWeights,
    positions: HashSet<(i32, i32)>,
    headings: HashSet<(i32, i32, i32)>,
    interacted: HashSet<(Affordance, usize)>,
    tried: HashSet<(Affordance, usize)>,
}

impl RewardTracker {
    /// A tracker for a new episode starting at `start` (the start counts as visited).
    pub fn new(weights: RewardWeights, start: AgentState) -> Self {
        let mut tracker = Self {
            weights,
            ..Default::default()
        };
        tracker.visit(&start);
        tracker
    }

    /// Marks a pose visited; returns R_nav for it.
    fn visit(&mut self, a: &AgentState) -> f32 {
        let cell = ((a.x / STEP_M).round() as i32, (a.y / STEP_M).round() as i32);
        let heading = (cell.0, cell.1, a.yaw_deg.round() as i32 % 360);
        let new_position = self.positions.insert(cell);
        let new_heading = self.headings.insert(heading);
        if new_position {
            NEW_POSITION
        } else if new_heading {
            NEW_HEADING
        } else {
            0.0
        }
    }

    /// The reward for a step.
    pub fn reward(&mut self, event: &StepEvent) -> f32 {
        let navigation = self.visit(&event.agent);
        let interaction = match event.interaction {
            Some(key) if event.success && self.interacted.insert(key) => {
                self.weights.interaction_for(key.0)
            }
            _ => 0.0,
        };
        let first_try = match event.interaction {
            Some(key) if event.informative && self.tried.insert(key) => self.weights.first_try,
            _ => 0.0,
        };
        let failure = if event.success { 0.0 } else { -1.0 };
        self.weights.navigation * navigation
            + interaction
            + first_try
            + self.weights.failure * failure
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(x: f32, y: f32, yaw_deg: f32) -> AgentState {
        AgentState {
            x,
            y,
            yaw_deg,
            horizon_deg: 0.0,
        }
    }

    fn step(
        agent: AgentState,
        success: bool,
        interaction: Option<(Affordance, usize)>,
    ) -> StepEvent {
        StepEvent {
            agent,
            success,
            interaction,
            informative: success,
        }
    }

    #[test]
    fn a_first_informative_try_pays_once_per_object_and_kind_even_when_it_fails() {
        let weights = RewardWeights {
            first_try: 0.5,
            ..RewardWeights::PAPER
        };
        let mut r = RewardTracker::new(weights, at(0.0, 0.0, 0.0));
        let here = at(0.0, 0.0, 0.0);
        let tried = |object, informative| StepEvent {
            agent: here,
            success: false,
            interaction: Some((Affordance::PickUp, object)),
            informative,
        };
        assert_eq!(r.reward(&tried(1, false)), -1.0, "beyond reach: no label");
        assert_eq!(r.reward(&tried(1, true)), -0.5, "the object itself failed");
        assert_eq!(r.reward(&tried(1, true)), -1.0, "once per object");
        assert_eq!(
            r.reward(&step(here, true, Some((Affordance::Push, 1)))),
            1.5,
            "another kind, a success"
        );
        assert_eq!(r.reward(&tried(2, true)), -0.5, "another object");
    }

    #[test]
    fn each_affordance_can_have_its_own_interaction_weight() {
        let weights = RewardWeights {
            pick_up_interaction: Some(5.0),
            ..RewardWeights::PAPER
        };
        let mut r = RewardTracker::new(weights, at(0.0, 0.0, 0.0));
        let here = at(0.0, 0.0, 0.0);
        assert_eq!(
            r.reward(&step(here, true, Some((Affordance::PickUp, 1)))),
            5.0
        );
        assert_eq!(
            r.reward(&step(here, true, Some((Affordance::Push, 1)))),
            1.0,
            "push keeps α2"
        );
        assert_eq!(
            r.reward(&step(here, false, Some((Affordance::PickUp, 2)))),
            -1.0,
            "a failure costs α3 whatever the affordance"
        );
    }

    #[test]
    fn novelty_interactions_and_failures_are_rewarded_as_the_paper_says() {
        let mut r = RewardTracker::new(RewardWeights::PAPER, at(0.0, 0.0, 0.0));
        assert_eq!(
            r.reward(&step(at(0.25, 0.0, 0.0), true, None)),
            1.0,
            "new position"
        );
        assert_eq!(
            r.reward(&step(at(0.25, 0.0, 30.0), true, None)),
            0.3,
            "new heading"
        );
        assert_eq!(
            r.reward(&step(at(0.25, 0.0, 30.0), true, None)),
            0.0,
            "looked up"
        );
        assert_eq!(
            r.reward(&step(at(0.25, 0.0, 30.0), false, None)),
            -1.0,
            "blocked"
        );
        let pick = Some((Affordance::PickUp, 4));
        assert_eq!(
            r.reward(&step(at(0.25, 0.0, 30.0), true, pick)),
            1.0,
            "new object"
        );
        assert_eq!(
            r.reward(&step(at(0.25, 0.0, 30.0), true, pick)),
            0.0,
            "same object"
        );
        let push = Some((Affordance::Push, 4));
        assert_eq!(
            r.reward(&step(at(0.25, 0.0, 30.0), true, push)),
            1.0,
            "new kind"
        );
        assert_eq!(
            r.reward(&step(
                at(0.25, 0.0, 30.0),
                false,
                Some((Affordance::Push, 5))
            )),
            -1.0
        );
        // The weights scale each term.
        let weights = RewardWeights {
            navigation: 0.5,
            interaction: 2.0,
            failure: 0.1,
            ..RewardWeights::PAPER
        };
        let mut r = RewardTracker::new(weights, at(0.0, 0.0, 0.0));
        assert_eq!(r.reward(&step(at(0.25, 0.0, 0.0), true, pick)), 0.5 + 2.0);
        assert!((r.reward(&step(at(0.25, 0.0, 0.0), false, None)) + 0.1).abs() < 1e-6);
    }
}
