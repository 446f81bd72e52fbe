//! Proximal policy optimisation in the CleanRL style, readable top to bottom:
//! clipped policy loss, clipped value loss, entropy bonus, global gradient-norm
//! clipping, epochs × minibatches. Rollouts carry the log-probabilities of the
//! policy that acted (the *behaviour* policy), so data from a slightly older
//! policy is handled by the importance ratio; the update reports how old it was.

use crate::adam::{Adam, AdamSettings};
use burn::optim::{GradientsParams, ModuleOptimizer};
use burn::prelude::*;
use burn::tensor::{Bool, Int};
use nets::policy::{PolicyInput, PolicyNet};
use rand::seq::SliceRandom;
use rand::Rng;
use std::ops::Range;

use crate::grad_norm::clip_global_norm;
use crate::optimizer_state::{OptimizerState, OptimizerStateError};

/// PPO settings; defaults are the paper's (IntExp's) values. A learner
/// config's `[policy.ppo]` table.
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    serde::Serialize,
    serde::Deserialize,
    documented::DocumentedFields,
)]
#[serde(default, deny_unknown_fields)]
pub struct PpoConfig {
    /// Adam learning rate.
    pub learning_rate: f64,
    /// Adam epsilon.
    pub adam_eps: f32,
    /// PPO ratio clip ε (also clips the value loss when `clip_value_loss`).
    pub clip: f32,
    /// Clip the value loss around the old values (as the policy's ratio).
    pub clip_value_loss: bool,
    /// Passes over each batch.
    pub epochs: usize,
    /// Minibatches per pass.
    pub minibatches: usize,
    /// Weight of the value loss.
    pub value_coef: f32,
    /// Weight of the entropy bonus.
    pub entropy_coef: f32,
    /// Largest global gradient norm; larger gradients are scaled down.
    pub max_grad_norm: f32,
    /// Discount factor γ (used by [`crate::gae::gae`] when the caller builds batches).
    pub gamma: f32,
    /// GAE λ.
    pub gae_lambda: f32,
    /// Normalise advantages per minibatch.
    pub normalize_advantages: bool,
}

impl Default for PpoConfig {
    fn default() -> Self {
        Self {
            learning_rate: 2e-4,
            adam_eps: 1e-5,
            clip: 0.2,
            clip_value_loss: true,
            epochs: 4,
            minibatches: 2,
            value_coef: 0.5,
            entropy_coef: 0.01,
            max_grad_norm: 0.5,
            gamma: 0.99,
            gae_lambda: 0.95,
            normalize_advantages: true,
        }
    }
}

/// Recurrent layout of a batch (GRU variant): rows are `n` sequences, one
/// after the other, of any lengths; minibatches take whole sequences.
#[derive(Debug, Clone, PartialEq)]
pub struct Sequences {
    /// Rows of each sequence, in row order (they sum to the batch's rows).
    pub lengths: Vec<usize>,
    /// `[n, hidden]` GRU state before each sequence's first step, row-major.
    pub start_hidden: Vec<f32>,
    /// Hidden size.
    pub hidden: usize,
    /// Per row: 1 where an episode starts at that step (the state is reset).
    pub episode_starts: Vec<f32>,
}

impl Sequences {
    /// The rows of each sequence.
    pub fn ranges(&self) -> Vec<Range<usize>> {
        let mut at = 0;
        self.lengths
            .iter()
            .map(|&len| {
                let range = at..at + len;
                at += len;
                range
            })
            .collect()
    }
}

/// Replays sequences `which` (indices into `sequences`, in this order)
/// through the GRU from their start states. Shorter sequences are padded to
/// the longest by repeating their last row; padding comes after a
/// sequence's real steps, so it cannot change them, and its outputs are
/// dropped. Returns log-probabilities `[rows, actions]` and values `[rows]`
/// for the real rows of the chosen sequences, in order.
pub fn replay_sequences(
    net: &PolicyNet,
    input: &PolicyInput,
    sequences: &Sequences,
    which: &[usize],
    device: &Device,
) -> (Tensor<2>, Tensor<1>) {
    let ranges = sequences.ranges();
    let steps = which.iter().map(|&u| ranges[u].len()).max().unwrap_or(0);
    let mut padded = Vec::with_capacity(which.len() * steps);
    let mut real = Vec::new();
    for (k, &u) in which.iter().enumerate() {
        let r = &ranges[u];
        for t in 0..steps {
            padded.push((r.start + t.min(r.len().saturating_sub(1))) as i64);
            if t < r.len() {
                real.push((k * steps + t) as i64);
            }
        }
    }
    let padded = Tensor::<1, Int>::from_ints(padded.as_slice(), device);
    let real = Tensor::<1, Int>::from_ints(real.as_slice(), device);
    let h = sequences.hidden;
    let start: Vec<f32> = which
        .iter()
        .flat_map(|&u| sequences.start_hidden[u * h..(u + 1) * h].iter().copied())
        .collect();
    let start = Tensor::<1>::from_floats(start.as_slice(), device).reshape([which.len(), h]);
    let starts = Tensor::<1>::from_floats(sequences.episode_starts.as_slice(), device)
        .select(0, padded.clone());
    let out = net.forward_sequences(&select_rows(input, &padded), start, starts, steps);
    (
        out.log_probs.select(0, real.clone()),
        out.values.select(0, real),
    )
}

/// A batch of experience, one row per step.
#[derive(Debug, Clone)]
pub struct PpoBatch {
    /// Observations, `[rows, …]` per input.
    pub input: PolicyInput,
    /// Action taken.
    pub actions: Vec<u32>,
    /// Log-probability of that action under the behaviour policy.
    pub behaviour_log_probs: Vec<f32>,
    /// Critic value when acting.
    pub values: Vec<f32>,
    /// GAE advantages.
    pub advantages: Vec<f32>,
    /// Value targets (advantages + values).
    pub returns: Vec<f32>,
    /// Version of the policy that acted, per row.
    pub policy_versions: Vec<u64>,
    /// Recurrent layout, for the GRU variant.
    pub sequences: Option<Sequences>,
}

impl PpoBatch {
    /// Number of rows.
    pub fn len(&self) -> usize {
        self.actions.len()
    }

    /// True when empty.
    pub fn is_empty(&self) -> bool {
        self.actions.is_empty()
    }
}

/// The loss and its parts for one minibatch (scalars for logging).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct LossTerms {
    /// Clipped surrogate policy loss.
    pub policy: f32,
    /// (Clipped) value loss, ½ mean squared error.
    pub value: f32,
    /// Mean entropy of the action distribution.
    pub entropy: f32,
    /// KL(old ‖ new) estimate `mean((r − 1) − log r)`.
    pub approx_kl: f32,
    /// Fraction of rows whose ratio left `[1 − ε, 1 + ε]`.
    pub clip_fraction: f32,
}

/// What one update did (means over minibatches; explained variance over the batch).
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct PpoStats {
    /// See [`LossTerms`].
    pub policy_loss: f32,
    /// See [`LossTerms`].
    pub value_loss: f32,
    /// See [`LossTerms`].
    pub entropy: f32,
    /// See [`LossTerms`].
    pub approx_kl: f32,
    /// See [`LossTerms`].
    pub clip_fraction: f32,
    /// `1 − Var(returns − values) / Var(returns)` of the batch's critic values.
    pub explained_variance: f32,
    /// Mean gradient norm before clipping.
    pub grad_norm: f32,
    /// Mean over rows of (current version − acting version).
    pub mean_policy_lag: f32,
    /// Largest such lag.
    pub max_policy_lag: u64,
}

/// The clipped PPO loss for one minibatch. `log_probs` is `[b, actions]`,
/// the rest `[b]`. Returns the scalar loss (differentiable) and its parts as
/// one detached tensor in [`LossTerms::read`]'s order, left on the device so
/// that a minibatch never waits for a read-back.
#[allow(clippy::too_many_arguments)]
pub fn ppo_loss(
    log_probs: Tensor<2>,
    values: Tensor<1>,
    actions: Tensor<1, Int>,
    old_log_probs: Tensor<1>,
    old_values: Tensor<1>,
    advantages: Tensor<1>,
    returns: Tensor<1>,
    config: &PpoConfig,
) -> (Tensor<1>, Tensor<1>) {
    let [b, _] = log_probs.dims();
    let new_log_probs: Tensor<1> = log_probs
        .clone()
        .gather(1, actions.reshape([b, 1]))
        .reshape([b]);
    let log_ratio = new_log_probs - old_log_probs;
    let ratio = log_ratio.clone().exp();
    let clipped_ratio = ratio.clone().clamp(1.0 - config.clip, 1.0 + config.clip);
    let policy = (advantages.clone().neg() * ratio.clone())
        .max_pair(advantages.neg() * clipped_ratio)
        .mean();
    let unclipped_value = (values.clone() - returns.clone()).square();
    let value = if config.clip_value_loss {
        let clipped = old_values.clone() + (values - old_values).clamp(-config.clip, config.clip);
        unclipped_value
            .max_pair((clipped - returns).square())
            .mean()
            * 0.5
    } else {
        unclipped_value.mean() * 0.5
    };
    let entropy = (log_probs.clone().exp() * log_probs)
        .sum_dim(1)
        .neg()
        .mean();
    let loss =
        policy.clone() - entropy.clone() * config.entropy_coef + value.clone() * config.value_coef;
    let approx_kl = ((ratio.clone() - 1.0) - log_ratio).mean();
    let clip_fraction = (ratio - 1.0).abs().greater_elem(config.clip).float().mean();
    let terms = Tensor::cat(vec![policy, value, entropy, approx_kl, clip_fraction], 0).inner();
    (loss, terms)
}

impl LossTerms {
    /// Values in a terms tensor of [`ppo_loss`].
    pub const LEN: usize = 5;

    /// Reads a terms tensor of [`ppo_loss`] (or a mean of several) back to
    /// the host: one read-back.
    pub fn read(terms: Tensor<1>) -> Self {
        let v: Vec<f32> = terms
            .into_data()
            .convert::<f32>()
            .try_into_vec::<f32>()
            .unwrap_or_default();
        let at = |i: usize| v.get(i).copied().unwrap_or(f32::NAN);
        Self {
            policy: at(0),
            value: at(1),
            entropy: at(2),
            approx_kl: at(3),
            clip_fraction: at(4),
        }
    }
}

/// A fresh Adam optimiser with the run's settings.
fn adam(config: &PpoConfig) -> ModuleOptimizer {
    Adam::for_module(AdamSettings {
        epsilon: config.adam_eps,
        ..AdamSettings::default()
    })
}

/// The learner side of PPO: the network being trained and its optimiser.
pub struct Ppo {
    /// The policy (on an autodiff device).
    pub net: PolicyNet,
    optimizer: ModuleOptimizer,
    config: PpoConfig,
    device: Device,
    version: u64,
}

fn explained_variance(values: &[f32], returns: &[f32]) -> f32 {
    let variance = |x: &[f64]| {
        let n = x.len().max(1) as f64;
        let m = x.iter().sum::<f64>() / n;
        x.iter().map(|v| (v - m).powi(2)).sum::<f64>() / n
    };
    let r: Vec<f64> = returns.iter().map(|&x| f64::from(x)).collect();
    let residual: Vec<f64> = returns
        .iter()
        .zip(values)
        .map(|(r, v)| f64::from(r - v))
        .collect();
    let vr = variance(&r);
    if vr == 0.0 {
        return f32::NAN;
    }
    (1.0 - variance(&residual) / vr) as f32
}

/// Selects rows of every input tensor.
fn select_rows(input: &PolicyInput, rows: &Tensor<1, Int>) -> PolicyInput {
    PolicyInput {
        images: input
            .images
            .iter()
            .map(|t| t.clone().select(0, rows.clone()))
            .collect(),
        vectors: input
            .vectors
            .iter()
            .map(|t| t.clone().select(0, rows.clone()))
            .collect(),
        // Through floats: burn-flex 0.22's `select` on a bool tensor yields
        // one that `bool_not` rejects.
        mask: input
            .mask
            .clone()
            .float()
            .select(0, rows.clone())
            .greater_elem(0.5),
    }
}

fn to_device(input: &PolicyInput, device: &Device) -> PolicyInput {
    PolicyInput {
        images: input
            .images
            .iter()
            .map(|t| t.clone().to_device(device))
            .collect(),
        vectors: input
            .vectors
            .iter()
            .map(|t| t.clone().to_device(device))
            .collect(),
        mask: input.mask.clone().to_device(device),
    }
}

impl Ppo {
    /// Trains `net` on `device` (made autodiff here).
    pub fn new(net: PolicyNet, config: PpoConfig, device: &Device) -> Self {
        let device = device.clone().autodiff();
        Self {
            net: net.fork(&device).train(),
            optimizer: adam(&config),
            config,
            device,
            version: 0,
        }
    }

    /// Updates applied so far (the version of the current weights).
    pub fn version(&self) -> u64 {
        self.version
    }

    /// Continues counting versions from `version` (after a resume).
    pub fn set_version(&mut self, version: u64) {
        self.version = version;
    }

    /// The settings.
    pub fn config(&self) -> &PpoConfig {
        &self.config
    }

    /// Adam's state, for a checkpoint.
    pub fn optimizer_state(&self) -> Result<OptimizerState, OptimizerStateError> {
        OptimizerState::capture(&self.optimizer, &self.net)
    }

    /// Continues from a saved Adam state (after the weights were restored).
    /// On error nothing changes.
    pub fn restore_optimizer(&mut self, state: &OptimizerState) -> Result<(), OptimizerStateError> {
        let (net, optimizer) = state.restore(self.net.clone(), adam(&self.config))?;
        self.net = net;
        self.optimizer = optimizer;
        Ok(())
    }

    /// The network without autodiff, for inference on `device`.
    pub fn inference_net(&self, device: &Device) -> PolicyNet {
        self.net.valid().to_device(device)
    }

    /// One PPO update on `batch`; minibatch order drawn from `rng`.
    pub fn update(&mut self, batch: &PpoBatch, rng: &mut impl Rng) -> PpoStats {
        let n = batch.len();
        let c = self.config;
        let device = self.device.clone();
        let input = to_device(&batch.input, &device);
        let floats = |v: &[f32]| Tensor::<1>::from_floats(v, &device);
        let actions = Tensor::<1, Int>::from_ints(
            batch
                .actions
                .iter()
                .map(|&a| a as i64)
                .collect::<Vec<_>>()
                .as_slice(),
            &device,
        );
        let (old_lp, old_v, returns) = (
            floats(&batch.behaviour_log_probs),
            floats(&batch.values),
            floats(&batch.returns),
        );
        let advantages = floats(&batch.advantages);
        // Units of minibatching: rows, or whole sequences for the GRU variant.
        let units: Vec<Range<usize>> = match &batch.sequences {
            Some(s) => s.ranges(),
            None => (0..n).map(|r| r..r + 1).collect(),
        };
        let per_minibatch = units.len().div_ceil(c.minibatches.max(1));
        let mut order: Vec<usize> = (0..units.len()).collect();
        let mut sums: Option<Tensor<1>> = None;
        let mut count = 0usize;
        for _ in 0..c.epochs {
            order.shuffle(rng);
            for chunk in order.chunks(per_minibatch) {
                let rows: Vec<i64> = chunk
                    .iter()
                    .flat_map(|&u| units[u].clone().map(|r| r as i64))
                    .collect();
                let index = Tensor::<1, Int>::from_ints(rows.as_slice(), &device);
                let (log_probs, values) = match &batch.sequences {
                    Some(s) => replay_sequences(&self.net, &input, s, chunk, &device),
                    None => {
                        let out = self.net.forward(&select_rows(&input, &index), None);
                        (out.log_probs, out.values)
                    }
                };
                let mut mb_adv = advantages.clone().select(0, index.clone());
                if c.normalize_advantages && rows.len() > 1 {
                    let mean = mb_adv.clone().mean();
                    let std = mb_adv.clone().var(0).sqrt();
                    mb_adv = (mb_adv - mean) / (std + 1e-8);
                }
                let (loss, terms) = ppo_loss(
                    log_probs,
                    values,
                    actions.clone().select(0, index.clone()),
                    old_lp.clone().select(0, index.clone()),
                    old_v.clone().select(0, index.clone()),
                    mb_adv,
                    returns.clone().select(0, index),
                    &c,
                );
                let mut grads = GradientsParams::from_grads(loss.backward(), &self.net);
                let norm = clip_global_norm(&self.net, &mut grads, c.max_grad_norm)
                    .map_or_else(|| Tensor::zeros([1], &device), Tensor::inner);
                self.net = self
                    .optimizer
                    .step(c.learning_rate, self.net.clone(), grads);
                // Summed on the device and read back once, after the update.
                let step = Tensor::cat(vec![terms, norm.inner()], 0);
                sums = Some(match sums {
                    Some(sum) => sum + step,
                    None => step,
                });
                count += 1;
            }
        }
        let (terms, grad_norm) = match sums {
            Some(sums) => {
                let means = sums / count as f32;
                let norm = means.clone().slice(LossTerms::LEN..LossTerms::LEN + 1);
                (
                    LossTerms::read(means.slice(0..LossTerms::LEN)),
                    norm.into_scalar::<f32>(),
                )
            }
            None => (LossTerms::default(), 0.0),
        };
        let lags: Vec<u64> = batch
            .policy_versions
            .iter()
            .map(|&v| self.version.saturating_sub(v))
            .collect();
        self.version += 1;
        PpoStats {
            policy_loss: terms.policy,
            value_loss: terms.value,
            entropy: terms.entropy,
            approx_kl: terms.approx_kl,
            clip_fraction: terms.clip_fraction,
            grad_norm,
            explained_variance: explained_variance(&batch.values, &batch.returns),
            mean_policy_lag: lags.iter().sum::<u64>() as f32 / lags.len().max(1) as f32,
            max_policy_lag: lags.iter().copied().max().unwrap_or(0),
        }
    }
}

/// A mask tensor from per-row booleans (`[rows, n_actions]`, row-major).
pub fn mask_tensor(allowed: &[bool], n_actions: usize, device: &Device) -> Tensor<2, Bool> {
    Tensor::<2, Bool>::from_data(
        TensorData::new(allowed.to_vec(), [allowed.len() / n_actions, n_actions]),
        device,
    )
}
