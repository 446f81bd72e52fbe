//! What the episode loop needs from an environment.

pub mod actions;
pub mod affordance_model;
mod bandit_fixture;
pub(crate) mod episode_metrics;
mod flat_sim_env;
pub(crate) mod object_memory;
pub mod reach;
pub mod reward;
pub mod sim_env;
pub mod state;
pub mod step_phases;
pub(crate) mod time_tally;
mod training_rooms;

pub use bandit_fixture::BanditFixture;
pub use flat_sim_env::FlatSimEnv;
pub use training_rooms::training_rooms;

use std::time::Duration;

use nets::policy::{CpuPolicy, CpuPolicyStep, ObservationValue};
use proto::{FrameBatch, PolicyLayout, StatKey, TypeTries};

use affordance_model::{AffordanceModel, CameraFrame};

/// What the policy sees after a reset or a step.
#[derive(Debug, Clone, PartialEq)]
pub struct Observation {
    /// The flat observation, the layout's `obs_len` values.
    pub values: ObservationValues,
    /// One byte per action, 1 = allowed; at least one is allowed.
    pub action_mask: Vec<u8>,
}

impl Observation {
    /// An observation of float values.
    pub fn of_floats(features: Vec<f32>, action_mask: Vec<u8>) -> Self {
        Self {
            values: ObservationValues::Floats(features),
            action_mask,
        }
    }

    /// `net`'s CPU pass over this observation from recurrent state `hidden`.
    pub fn cpu_pass(&self, net: &CpuPolicy, hidden: Option<&[f32]>) -> CpuPolicyStep {
        match &self.values {
            ObservationValues::Floats(v) => net.forward(v, &self.action_mask, hidden),
            ObservationValues::Bytes(v) => net.forward(v, &self.action_mask, hidden),
        }
    }
}

/// An observation's values as the environment made them.
#[derive(Debug, Clone, PartialEq)]
pub enum ObservationValues {
    /// Values as the network reads them (a byte layout's, multiples of 1/255
    /// in 0..1).
    Floats(Vec<f32>),
    /// A byte layout's bytes (`proto::unit_to_byte` of each value; the
    /// network reads `proto::byte_to_unit` of each): exactly what travels,
    /// so that neither the environment nor the loop's thread, which every
    /// environment waits for between its steps, expands 426 k values a step
    /// at 128 px into floats or converts them back.
    Bytes(Vec<u8>),
}

impl ObservationValues {
    /// The values as the network reads them.
    pub fn floats(&self) -> std::borrow::Cow<'_, [f32]> {
        match self {
            Self::Floats(v) => v.into(),
            Self::Bytes(v) => v.iter().map(|&b| b.unit()).collect(),
        }
    }
}

/// What an action did, known before the next observation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepOutcome {
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
    pub stats: Vec<(StatKey, f32)>,
    /// Interactions by object type (environments with a simulator).
    pub tries: Vec<TypeTries>,
}

/// An episodic environment with a discrete, maskable action space.
///
/// A reset or step comes in two halves: `begin_*` does everything up to the
/// affordance U-Net (simulate, render, map), [`Environment::observe`] the
/// rest, given the U-Net's probabilities for [`Environment::camera_frame`].
/// An actor running several environments thus infers all their frames in
/// one batch; [`Environment::reset`] and [`Environment::step`] do both
/// halves for one environment.
pub trait Environment: Send {
    /// Shapes of the observation and the action count.
    fn layout(&self) -> &PolicyLayout;
    /// Index of the current scene (reported in episode stats).
    fn scene_index(&self) -> u32;
    /// Starts a new episode, deterministically for a given seed.
    fn begin_reset(&mut self, seed: u64) -> anyhow::Result<()>;
    /// Applies an allowed action.
    fn begin_step(&mut self, action: u32) -> anyhow::Result<StepOutcome>;
    /// The camera frame the U-Net must see before [`Environment::observe`];
    /// `None` for an environment without a camera.
    fn camera_frame(&self) -> Option<CameraFrame<'_>>;
    /// Completes the reset or step begun, with the U-Net's probability
    /// planes for its camera frame (empty without one).
    fn observe(&mut self, affordances: Vec<Vec<f32>>) -> anyhow::Result<Observation>;
    /// Ends the episode: labelled frames and metrics.
    fn finish_episode(&mut self, episode_id: u64) -> anyhow::Result<EpisodeEnd>;
    /// The run's environment steps over all actors, as the learner last reported them.
    fn set_global_steps(&mut self, steps: u64);
    /// How long the last reset's or step's camera frame took to render
    /// (zero without a camera): for where a step's time goes
    /// ([`step_phases`]).
    fn last_render_time(&self) -> Duration {
        Duration::ZERO
    }

    /// Both halves of a reset, `model` seeing the camera frame (an
    /// environment with a camera needs one).
    fn reset(&mut self, seed: u64, model: Option<&AffordanceModel>) -> anyhow::Result<Observation>
    where
        Self: Sized,
    {
        self.begin_reset(seed)?;
        let planes = affordance_model::planes_for(self.camera_frame(), model)?;
        self.observe(planes)
    }

    /// Both halves of a step, `model` seeing the camera frame (an
    /// environment with a camera needs one).
    fn step(
        &mut self,
        action: u32,
        model: Option<&AffordanceModel>,
    ) -> anyhow::Result<(StepOutcome, Observation)>
    where
        Self: Sized,
    {
        let outcome = self.begin_step(action)?;
        let planes = affordance_model::planes_for(self.camera_frame(), model)?;
        Ok((outcome, self.observe(planes)?))
    }
}
