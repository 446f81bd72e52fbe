//! What the episode loop needs from an environment.

pub mod actions;
pub mod affordance_model;
mod bandit_fixture;
pub mod reward;
pub mod sim_env;
mod sim_environment;
pub mod state;

pub use bandit_fixture::BanditFixture;
pub use sim_environment::SimEnvironment;

use proto::{FrameBatch, PolicyLayout, StatField};

/// What the policy sees after a reset or a step.
#[derive(Debug, Clone, PartialEq)]
pub struct Observation {
    /// Flat observation features, the layout's `obs_len` long (for a byte
    /// layout, multiples of 1/255 in 0..1: exactly what travels).
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

/// What an episode leaves behind besides its rollout.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct EpisodeEnd {
    /// Labelled frames for the U-Net (environments with a labeler).
    pub frames: Option<FrameBatch>,
    /// Metrics the environment measured (the loop adds return and steps/s).
    pub stats: Vec<(StatField, f32)>,
}

/// An episodic environment with a discrete, maskable action space.
pub trait Environment {
    /// Shapes of the observation and the action count.
    fn layout(&self) -> &PolicyLayout;
    /// Index of the current scene (reported in episode stats).
    fn scene_index(&self) -> u32;
    /// Starts a new episode, deterministically for a given seed.
    fn reset(&mut self, seed: u64) -> anyhow::Result<Observation>;
    /// Applies an allowed action.
    fn step(&mut self, action: u32) -> anyhow::Result<Transition>;
    /// Ends the episode: labelled frames and metrics.
    fn finish_episode(&mut self, episode_id: u64) -> anyhow::Result<EpisodeEnd>;
    /// Takes new U-Net weights (safetensors bytes) and their calibration
    /// temperature from the learner.
    fn load_unet(&mut self, weights: Vec<u8>, temperature: f32) -> anyhow::Result<()>;
    /// The run's environment steps over all actors, as the learner last reported them.
    fn set_global_steps(&mut self, steps: u64);
}
