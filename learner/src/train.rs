//! The policy update: clipped-ratio policy gradient with GAE on one rollout
//! chunk at a time, for the linear actor-critic, with Adam. Reads like the
//! algorithm: GAE → per-step clipped losses → gradient clip → Adam.

use nets::{entropy, log_softmax_masked, LinearActorCritic, NamedTensors, NetsError};
use proto::{ObsDtype, RolloutView};
use serde::Serialize;

use crate::config::PolicyConfig;

/// Why a chunk cannot train the current network.
#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    /// The chunk's shapes do not match the configured policy.
    #[error("rollout has obs {obs_elems} x {dtype:?} and {n_actions} actions; the learner's policy expects obs {obs_dim} x F32 and {expected_actions} actions (check [policy] in the learner config)")]
    Shape {
        /// Observation elements in the chunk.
        obs_elems: u32,
        /// Observation dtype in the chunk.
        dtype: ObsDtype,
        /// Actions in the chunk.
        n_actions: u32,
        /// Configured observation length.
        obs_dim: usize,
        /// Configured action count.
        expected_actions: usize,
    },
}

/// What one update measured, in CleanRL's terms.
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct UpdateStats {
    /// Clipped surrogate loss.
    pub policy_loss: f32,
    /// Value loss (½ squared error).
    pub value_loss: f32,
    /// Mean entropy of the masked policy.
    pub entropy: f32,
    /// Mean of `(r − 1) − ln r`.
    pub approx_kl: f32,
    /// Fraction of steps whose ratio left `[1 − ε, 1 + ε]`.
    pub clip_fraction: f32,
    /// `1 − Var(returns − values) / Var(returns)`.
    pub explained_variance: f32,
}

/// The network and its optimiser state.
#[derive(Debug, Clone)]
pub struct Trainer {
    /// The network being trained.
    pub net: LinearActorCritic,
    adam_m: Vec<f32>,
    adam_v: Vec<f32>,
    /// Adam steps taken.
    pub adam_steps: u64,
    config: PolicyConfig,
}

/// Generalised advantage estimates and returns for one chunk.
pub fn gae(
    rewards: &[f32],
    values: &[f32],
    dones: &[u8],
    bootstrap: f32,
    gamma: f32,
    lambda: f32,
) -> (Vec<f32>, Vec<f32>) {
    let t = rewards.len();
    let mut advantages = vec![0.0; t];
    let mut last = 0.0;
    for i in (0..t).rev() {
        let next_value = if i + 1 == t { bootstrap } else { values[i + 1] };
        let nonterminal = 1.0 - f32::from(dones[i]);
        let delta = rewards[i] + gamma * next_value * nonterminal - values[i];
        last = delta + gamma * lambda * nonterminal * last;
        advantages[i] = last;
    }
    let returns = advantages.iter().zip(values).map(|(a, v)| a + v).collect();
    (advantages, returns)
}

impl Trainer {
    /// A fresh network (uniform policy) and optimiser.
    pub fn new(config: PolicyConfig) -> Self {
        let net = LinearActorCritic::zeros(config.obs_dim, config.n_actions);
        let n = net.params.len();
        Self {
            net,
            adam_m: vec![0.0; n],
            adam_v: vec![0.0; n],
            adam_steps: 0,
            config,
        }
    }

    /// One update on one chunk.
    pub fn update(&mut self, chunk: &RolloutView<'_>) -> Result<UpdateStats, TrainError> {
        let cfg = &self.config;
        if chunk.obs_dtype != ObsDtype::F32
            || chunk.obs_elems as usize != cfg.obs_dim
            || chunk.n_actions as usize != cfg.n_actions
        {
            return Err(TrainError::Shape {
                obs_elems: chunk.obs_elems,
                dtype: chunk.obs_dtype,
                n_actions: chunk.n_actions,
                obs_dim: cfg.obs_dim,
                expected_actions: cfg.n_actions,
            });
        }
        let t = chunk.n_steps();
        let values = chunk.values.to_vec();
        let (mut advantages, returns) = gae(
            &chunk.rewards.to_vec(),
            &values,
            chunk.dones,
            chunk.bootstrap_value,
            cfg.gamma,
            cfg.gae_lambda,
        );
        if t > 1 {
            let mean = advantages.iter().sum::<f32>() / t as f32;
            let std =
                (advantages.iter().map(|a| (a - mean).powi(2)).sum::<f32>() / t as f32).sqrt();
            advantages
                .iter_mut()
                .for_each(|a| *a = (*a - mean) / (std + 1e-8));
        }

        let mut grad = vec![0.0f32; self.net.params.len()];
        let mut stats = UpdateStats::default();
        let scale = 1.0 / t as f32;
        for i in 0..t {
            let obs: Vec<f32> = chunk
                .obs(i)
                .unwrap_or_default()
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect();
            let mask = chunk.mask(i).unwrap_or_default();
            let action = chunk.actions.get(i).unwrap_or(0) as usize;
            let log_probs = log_softmax_masked(&self.net.logits(&obs), mask);
            let h = entropy(&log_probs);
            let log_ratio = log_probs[action] - chunk.log_probs.get(i).unwrap_or(0.0);
            let ratio = log_ratio.exp();
            let adv = advantages[i];
            let clipped = ratio.clamp(1.0 - cfg.clip, 1.0 + cfg.clip);
            stats.policy_loss += -(ratio * adv).min(clipped * adv) * scale;
            stats.approx_kl += ((ratio - 1.0) - log_ratio) * scale;
            stats.entropy += h * scale;
            if (ratio - 1.0).abs() > cfg.clip {
                stats.clip_fraction += scale;
            }
            // d(policy loss)/d logits: zero where the clipped branch is active.
            let clip_active =
                (adv > 0.0 && ratio > 1.0 + cfg.clip) || (adv < 0.0 && ratio < 1.0 - cfg.clip);
            let g_logits: Vec<f32> = log_probs
                .iter()
                .enumerate()
                .map(|(j, &lp)| {
                    let p = if lp.is_finite() { lp.exp() } else { 0.0 };
                    let onehot = if j == action { 1.0 } else { 0.0 };
                    let policy = if clip_active {
                        0.0
                    } else {
                        -adv * ratio * (onehot - p)
                    };
                    let entropy_bonus = if lp.is_finite() {
                        cfg.entropy_coef * p * (lp + h)
                    } else {
                        0.0
                    };
                    policy + entropy_bonus
                })
                .collect();
            let value = self.net.value(&obs);
            stats.value_loss += 0.5 * (value - returns[i]).powi(2) * scale;
            let g_value = cfg.value_coef * (value - returns[i]);
            self.net
                .accumulate_grad(&obs, &g_logits, g_value, scale, &mut grad);
        }
        stats.explained_variance = explained_variance(&values, &returns);
        self.adam_step(&mut grad);
        Ok(stats)
    }

    fn adam_step(&mut self, grad: &mut [f32]) {
        let cfg = &self.config;
        let norm = grad.iter().map(|g| g * g).sum::<f32>().sqrt();
        if norm > cfg.max_grad_norm {
            grad.iter_mut().for_each(|g| *g *= cfg.max_grad_norm / norm);
        }
        let (b1, b2) = (0.9f32, 0.999f32);
        self.adam_steps += 1;
        let step = self.adam_steps as i32;
        let (c1, c2) = (1.0 - b1.powi(step), 1.0 - b2.powi(step));
        for (((p, g), m), v) in self
            .net
            .params
            .iter_mut()
            .zip(grad.iter())
            .zip(&mut self.adam_m)
            .zip(&mut self.adam_v)
        {
            *m = b1 * *m + (1.0 - b1) * g;
            *v = b2 * *v + (1.0 - b2) * g * g;
            *p -= cfg.learning_rate * (*m / c1) / ((*v / c2).sqrt() + cfg.adam_eps);
        }
    }

    /// Adam's moment estimates as named tensors (for checkpoints).
    pub fn optimizer_tensors(&self) -> NamedTensors {
        let n = self.adam_m.len();
        NamedTensors(vec![
            ("policy.adam.m".into(), vec![n], self.adam_m.clone()),
            ("policy.adam.v".into(), vec![n], self.adam_v.clone()),
        ])
    }

    /// Restores network and optimiser from checkpoint bytes.
    pub fn restore(
        &mut self,
        weights: &[u8],
        optimizer: &[u8],
        adam_steps: u64,
    ) -> Result<(), NetsError> {
        let net = LinearActorCritic::from_safetensors(
            weights,
            self.config.obs_dim,
            self.config.n_actions,
        )?;
        let n = net.params.len();
        let file = NamedTensors::parse(optimizer)?;
        self.adam_m = NamedTensors::read(&file, "policy.adam.m", &[n])?;
        self.adam_v = NamedTensors::read(&file, "policy.adam.v", &[n])?;
        self.net = net;
        self.adam_steps = adam_steps;
        Ok(())
    }
}

fn explained_variance(values: &[f32], returns: &[f32]) -> f32 {
    let var = |x: &[f32]| {
        let mean = x.iter().sum::<f32>() / x.len() as f32;
        x.iter().map(|v| (v - mean).powi(2)).sum::<f32>() / x.len() as f32
    };
    let residual: Vec<f32> = returns.iter().zip(values).map(|(r, v)| r - v).collect();
    let var_returns = var(returns);
    if var_returns == 0.0 {
        return 0.0;
    }
    1.0 - var(&residual) / var_returns
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gae_matches_a_hand_computed_example() {
        // γ = 0.5, λ = 0.5; episode ends after step 1, so step 2 starts a new one.
        let (adv, ret) = gae(
            &[1.0, 2.0, 3.0],
            &[0.5, 1.0, 1.5],
            &[0, 1, 0],
            2.0,
            0.5,
            0.5,
        );
        // step 2: δ = 3 + 0.5·2 − 1.5 = 2.5
        // step 1: δ = 2 − 1 = 1 (terminal)            → A = 1
        // step 0: δ = 1 + 0.5·1 − 0.5 = 1; A = 1 + 0.25·1 = 1.25
        let expected = [1.25, 1.0, 2.5];
        for (a, e) in adv.iter().zip(expected) {
            assert!((a - e).abs() < 1e-6, "{adv:?}");
        }
        assert!((ret[0] - 1.75).abs() < 1e-6);
    }
}
