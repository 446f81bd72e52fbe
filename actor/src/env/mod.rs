//! What the episode loop needs from an environment.

pub mod actions;
pub mod affordance_model;
mod bandit_fixture;
pub mod reward;
pub mod sim_env;
pub mod state;

pub use bandit_fixture::BanditFixture;

/// What the policy sees after a reset or a step.
#[derive(Debug, Clone, PartialEq)]
pub struct Observation {
    /// Flat observation features, `obs_dim` long.
    pub features: Vec<f32>,
    /// One byte per action, 1 = allowed; at least one is allowed.
    pub action_mask: Vec<u8>,
}

/// The result of one step.
#[derive(Debug, Clone, PartialEq)]
pub struct Transition {
    /// Observation after the step (of the next episode's first state is not included).
    pub observation: Observation,
    /// Reward for the step.
    pub reward: f32,
    /// True when the episode ended with this step.
    pub done: bool,
    /// Whether the action succeeded.
    pub success: bool,
}

/// An episodic environment with a discrete, maskable action space.
pub trait Environment {
    /// Observation length.
    fn obs_dim(&self) -> usize;
    /// Number of actions.
    fn n_actions(&self) -> usize;
    /// Index of the current scene (reported in episode stats).
    fn scene_index(&self) -> u32;
    /// Starts a new episode, deterministically for a given seed.
    fn reset(&mut self, seed: u64) -> Observation;
    /// Applies an allowed action.
    fn step(&mut self, action: u32) -> Transition;
}
