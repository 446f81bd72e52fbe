//! The simulator environment behind the episode loop's [`Environment`]
//! interface ([`SimEnv`] flattened, hence the name): the state's inputs
//! flattened in the task's layout order
//! (camera, global map, local map, history, inventory; those the method
//! does not have are empty) and quantised to
//! bytes, which is exactly what the policy acts on and what the learner
//! trains on.

use std::time::Duration;

use anyhow::ensure;
use proto::{PolicyLayout, TaskSpec};

use super::affordance_model::CameraFrame;
use super::sim_env::{SimEnv, SimObservation};
use super::{Environment, EpisodeEnd, Observation, ObservationValues, StepOutcome};

/// [`SimEnv`] as an [`Environment`].
pub struct FlatSimEnv {
    env: SimEnv,
    layout: PolicyLayout,
}

impl FlatSimEnv {
    /// Wraps `env`, which must produce `task`'s layout.
    pub fn new(env: SimEnv, task: &TaskSpec) -> anyhow::Result<Self> {
        let layout = task.layout();
        let config = env.state_config();
        let (image_channels, vector_dims) = config.input_shapes();
        ensure!(
            env.action_space().len() == layout.n_actions
                && layout.image_channels == image_channels
                && layout.vector_dims == vector_dims
                && config.image_size == layout.image_size
                && config.map_cells == layout.image_size,
            "the environment's state ({} actions, {} px) does not match the task's layout ({} actions, {} px)",
            env.action_space().len(),
            config.image_size,
            layout.n_actions,
            layout.image_size
        );
        Ok(Self { env, layout })
    }

    /// The wrapped environment.
    pub fn inner(&self) -> &SimEnv {
        &self.env
    }

    /// The state's bytes as the policy's flat observation (the state is
    /// built in bytes, in the policy's input order: nothing to copy).
    fn observation(&self, o: SimObservation) -> Observation {
        let values = o.state.into_values();
        debug_assert_eq!(values.len(), self.layout.obs_len(), "state length");
        Observation {
            values: ObservationValues::Bytes(values),
            action_mask: o.mask,
        }
    }
}

impl Environment for FlatSimEnv {
    fn layout(&self) -> &PolicyLayout {
        &self.layout
    }

    fn scene_index(&self) -> u32 {
        self.env.scene_index() as u32
    }

    fn begin_reset(&mut self, seed: u64) -> anyhow::Result<()> {
        self.env.begin_reset(seed)
    }

    fn begin_step(&mut self, action: u32) -> anyhow::Result<StepOutcome> {
        let outcome = self.env.begin_step(action as usize)?;
        Ok(StepOutcome {
            reward: outcome.reward,
            done: outcome.done,
            success: outcome.success,
        })
    }

    fn camera_frame(&self) -> Option<CameraFrame<'_>> {
        self.env.camera_frame()
    }

    fn observe(&mut self, affordances: Vec<Vec<f32>>) -> anyhow::Result<Observation> {
        let o = self.env.observe(affordances)?;
        Ok(self.observation(o))
    }

    fn finish_episode(&mut self, episode_id: u64) -> anyhow::Result<EpisodeEnd> {
        let summary = self.env.finish_episode(episode_id)?;
        Ok(EpisodeEnd {
            frames: Some(summary.frames),
            stats: summary.stats,
            tries: summary.tries,
        })
    }

    fn set_global_steps(&mut self, steps: u64) {
        self.env.set_global_steps(steps);
    }

    fn last_render_time(&self) -> Duration {
        self.env.last_timings().render
    }
}
