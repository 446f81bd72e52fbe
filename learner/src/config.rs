//! Every learner setting with its default, in one serde struct (CleanRL style).
//! Loaded from TOML, overridden by CLI flags, printed at start and saved in
//! the run directory.

use serde::{Deserialize, Serialize};
use transport::TransportConfig;

/// The learner's configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LearnerConfig {
    /// Address of the HTTP endpoint (`/metrics`, `/api/status`, `/healthz`). Port 0 picks a free port.
    pub http_addr: String,
    /// Seconds without a message after which an actor counts as not alive.
    pub actor_timeout_s: f64,
    /// Write a checkpoint after this many policy updates (0 = never by count).
    pub checkpoint_every_updates: u64,
    /// Write a checkpoint at least this often, in seconds (0 = never by time).
    pub checkpoint_interval_s: f64,
    /// How many checkpoints to keep; older ones are deleted.
    pub keep_checkpoints: usize,
    /// Policy settings.
    pub policy: PolicyConfig,
    /// Shared-memory transport limits (must match the actors').
    pub transport: TransportConfig,
}

/// The policy the learner trains and broadcasts.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PolicyConfig {
    /// Observation length the actors' environment produces.
    pub obs_dim: usize,
    /// Size of the actors' action space.
    pub n_actions: usize,
    /// Adam learning rate.
    pub learning_rate: f32,
    /// Adam epsilon.
    pub adam_eps: f32,
    /// Discount factor γ.
    pub gamma: f32,
    /// GAE λ.
    pub gae_lambda: f32,
    /// PPO ratio clip ε.
    pub clip: f32,
    /// Weight of the value loss.
    pub value_coef: f32,
    /// Weight of the entropy bonus.
    pub entropy_coef: f32,
    /// Largest global gradient norm; larger gradients are scaled down.
    pub max_grad_norm: f32,
    /// Publish new weights after this many updates.
    pub publish_every_updates: u64,
}

impl Default for LearnerConfig {
    fn default() -> Self {
        Self {
            http_addr: "127.0.0.1:9464".into(),
            actor_timeout_s: 10.0,
            checkpoint_every_updates: 10_000,
            checkpoint_interval_s: 300.0,
            keep_checkpoints: 3,
            policy: PolicyConfig::default(),
            transport: TransportConfig::default(),
        }
    }
}

impl Default for PolicyConfig {
    fn default() -> Self {
        Self {
            obs_dim: 8,
            n_actions: 4,
            learning_rate: 2e-2,
            adam_eps: 1e-5,
            gamma: 0.99,
            gae_lambda: 0.95,
            clip: 0.2,
            value_coef: 0.5,
            entropy_coef: 0.01,
            max_grad_norm: 0.5,
            publish_every_updates: 1,
        }
    }
}

impl LearnerConfig {
    /// Reads a TOML file; unknown keys are errors so typos never pass silently.
    pub fn from_toml_file(path: &std::path::Path) -> anyhow::Result<Self> {
        use anyhow::Context;
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("reading learner config {}", path.display()))?;
        toml::from_str(&text).with_context(|| {
            format!("parsing learner config {} (run `learner print-config` for every key and its default)", path.display())
        })
    }

    /// The config as TOML text.
    pub fn to_toml(&self) -> String {
        toml::to_string_pretty(self).unwrap_or_else(|e| format!("# could not render config: {e}"))
    }

    /// Checks values that would make the learner misbehave.
    pub fn validate(&self) -> anyhow::Result<()> {
        anyhow::ensure!(self.policy.obs_dim > 0, "policy.obs_dim must be > 0");
        anyhow::ensure!(
            (1..=proto::MAX_ACTIONS as usize).contains(&self.policy.n_actions),
            "policy.n_actions must be in 1..={}",
            proto::MAX_ACTIONS
        );
        anyhow::ensure!(self.keep_checkpoints >= 1, "keep_checkpoints must be >= 1");
        anyhow::ensure!(
            self.transport.max_actors >= 1,
            "transport.max_actors must be >= 1"
        );
        anyhow::ensure!(
            self.policy.publish_every_updates >= 1,
            "policy.publish_every_updates must be >= 1"
        );
        anyhow::ensure!(self.actor_timeout_s > 0.0, "actor_timeout_s must be > 0");
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_survive_a_toml_round_trip_and_typos_are_refused() {
        let config = LearnerConfig::default();
        assert_eq!(
            toml::from_str::<LearnerConfig>(&config.to_toml()).unwrap(),
            config
        );
        assert!(toml::from_str::<LearnerConfig>("actor_timeout = 3").is_err());
        let partial: LearnerConfig = toml::from_str("[policy]\nn_actions = 6").unwrap();
        assert_eq!(partial.policy.n_actions, 6);
        assert_eq!(partial.policy.obs_dim, 8);
    }
}
