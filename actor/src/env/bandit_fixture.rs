//! A deterministic contextual bandit: a **test fixture** for wiring, not a
//! simulator. Each step shows a one-hot context; the right action is
//! `context mod n_actions`; one wrong action is masked at random. Reward 1 for
//! the right action, else 0. A policy that learns reaches a return near the
//! episode length; a uniform one gets about a third of it.

use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};

use proto::{EnvKind, PolicyLayout, StatField, TaskSpec};

use super::affordance_model::CameraFrame;
use super::{Environment, EpisodeEnd, Observation, StepOutcome};

/// The bandit fixture.
#[derive(Debug, Clone)]
pub struct BanditFixture {
    contexts: usize,
    n_actions: usize,
    episode_steps: u32,
    step: u32,
    successes: u32,
    context: usize,
    rng: SmallRng,
    layout: PolicyLayout,
}

impl BanditFixture {
    /// Contexts = observation length 8, 4 actions, 64 steps per episode.
    pub fn new() -> Self {
        Self {
            contexts: proto::task::BANDIT_OBS_DIM,
            n_actions: proto::task::BANDIT_ACTIONS,
            episode_steps: 64,
            step: 0,
            successes: 0,
            context: 0,
            rng: SmallRng::seed_from_u64(0),
            layout: TaskSpec {
                env: EnvKind::BanditFixture,
                ..TaskSpec::default()
            }
            .layout(),
        }
    }

    /// Draws the next context and its mask.
    fn next_context(&mut self) -> Observation {
        self.context = self.rng.random_range(0..self.contexts);
        let mut features = vec![0.0; self.contexts];
        features[self.context] = 1.0;
        let mut action_mask = vec![1u8; self.n_actions];
        let right = self.context % self.n_actions;
        let masked = (right + 1 + self.rng.random_range(0..self.n_actions - 1)) % self.n_actions;
        action_mask[masked] = 0;
        Observation::of_floats(features, action_mask)
    }
}

impl Default for BanditFixture {
    fn default() -> Self {
        Self::new()
    }
}

impl Environment for BanditFixture {
    fn layout(&self) -> &PolicyLayout {
        &self.layout
    }
    fn scene_index(&self) -> u32 {
        0
    }
    fn begin_reset(&mut self, seed: u64) -> anyhow::Result<()> {
        self.rng = SmallRng::seed_from_u64(seed);
        self.step = 0;
        self.successes = 0;
        Ok(())
    }
    fn begin_step(&mut self, action: u32) -> anyhow::Result<StepOutcome> {
        let success = action as usize == self.context % self.n_actions;
        self.step += 1;
        self.successes += u32::from(success);
        Ok(StepOutcome {
            reward: if success { 1.0 } else { 0.0 },
            done: self.step >= self.episode_steps,
            success,
        })
    }
    fn camera_frame(&self) -> Option<CameraFrame<'_>> {
        None
    }
    fn observe(&mut self, _affordances: Vec<Vec<f32>>) -> anyhow::Result<Observation> {
        Ok(self.next_context())
    }
    fn finish_episode(&mut self, _episode_id: u64) -> anyhow::Result<EpisodeEnd> {
        Ok(EpisodeEnd {
            frames: None,
            stats: vec![(
                StatField::InteractionSuccessRate.into(),
                self.successes as f32 / self.step.max(1) as f32,
            )],
            tries: Vec::new(),
        })
    }
    fn set_global_steps(&mut self, _steps: u64) {}
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_seed_same_episode_and_the_right_action_is_never_masked() {
        let (mut a, mut b) = (BanditFixture::new(), BanditFixture::new());
        assert_eq!(a.reset(7, None).unwrap(), b.reset(7, None).unwrap());
        for i in 0..64 {
            let (outcome, observation) = a.step(i % 4, None).unwrap();
            assert_eq!((outcome, observation.clone()), b.step(i % 4, None).unwrap());
            assert_eq!(observation.action_mask[a.context % 4], 1);
            assert_eq!(
                observation.action_mask.iter().filter(|&&m| m == 0).count(),
                1
            );
            assert_eq!(outcome.done, i == 63);
        }
    }
}
