//! A deterministic contextual bandit: a **test fixture** for wiring, not a
//! simulator. Each step shows a one-hot context; the right action is
//! `context mod n_actions`; one wrong action is masked at random. Reward 1 for
//! the right action, else 0. A policy that learns reaches a return near the
//! episode length; a uniform one gets about a third of it.

use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};

use super::{Environment, Observation, Transition};

/// The bandit fixture.
#[derive(Debug, Clone)]
pub struct BanditFixture {
    contexts: usize,
    n_actions: usize,
    episode_steps: u32,
    step: u32,
    context: usize,
    rng: SmallRng,
}

impl BanditFixture {
    /// Contexts = observation length 8, 4 actions, 64 steps per episode.
    pub fn new() -> Self {
        Self {
            contexts: 8,
            n_actions: 4,
            episode_steps: 64,
            step: 0,
            context: 0,
            rng: SmallRng::seed_from_u64(0),
        }
    }

    fn observe(&mut self) -> Observation {
        self.context = self.rng.random_range(0..self.contexts);
        let mut features = vec![0.0; self.contexts];
        features[self.context] = 1.0;
        let mut action_mask = vec![1u8; self.n_actions];
        let right = self.context % self.n_actions;
        let masked = (right + 1 + self.rng.random_range(0..self.n_actions - 1)) % self.n_actions;
        action_mask[masked] = 0;
        Observation {
            features,
            action_mask,
        }
    }
}

impl Default for BanditFixture {
    fn default() -> Self {
        Self::new()
    }
}

impl Environment for BanditFixture {
    fn obs_dim(&self) -> usize {
        self.contexts
    }
    fn n_actions(&self) -> usize {
        self.n_actions
    }
    fn scene_index(&self) -> u32 {
        0
    }
    fn reset(&mut self, seed: u64) -> Observation {
        self.rng = SmallRng::seed_from_u64(seed);
        self.step = 0;
        self.observe()
    }
    fn step(&mut self, action: u32) -> Transition {
        let success = action as usize == self.context % self.n_actions;
        self.step += 1;
        Transition {
            observation: self.observe(),
            reward: if success { 1.0 } else { 0.0 },
            done: self.step >= self.episode_steps,
            success,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_seed_same_episode_and_the_right_action_is_never_masked() {
        let (mut a, mut b) = (BanditFixture::new(), BanditFixture::new());
        assert_eq!(a.reset(7), b.reset(7));
        for i in 0..64 {
            let ta = a.step(i % 4);
            assert_eq!(ta, b.step(i % 4));
            assert_eq!(ta.observation.action_mask[a.context % 4], 1);
            assert_eq!(
                ta.observation
                    .action_mask
                    .iter()
                    .filter(|&&m| m == 0)
                    .count(),
                1
            );
            assert_eq!(ta.done, i == 63);
        }
    }
}
