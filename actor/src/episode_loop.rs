//! The actor's episode loop: act with the newest broadcast policy, send
//! rollout chunks and episode stats, pick up new weights between steps.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use nets::{log_softmax_masked, sample, LinearActorCritic};
use proto::{EpisodeStats, Limits, Message, ObsDtype, RolloutChunk, StatField};
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};
use transport::{ActorPorts, Delivery, ReceivedMessage, TransportConfig};

use crate::env::{Environment, Observation};

/// Settings of one actor's loop.
#[derive(Debug, Clone)]
pub struct LoopSettings {
    /// This actor's id.
    pub actor_id: u32,
    /// Steps per rollout chunk.
    pub chunk_steps: usize,
    /// Base seed; episode `k` of actor `a` resets with a seed derived from all three.
    pub seed: u64,
    /// Stop after this many episodes (None = until SIGINT/SIGTERM).
    pub max_episodes: Option<u64>,
    /// How long to wait for the first weights.
    pub weights_timeout: Duration,
}

/// What the loop did, for the exit summary.
#[derive(Debug, Default, Clone, Copy)]
pub struct LoopSummary {
    /// Episodes finished.
    pub episodes: u64,
    /// Environment steps taken.
    pub steps: u64,
    /// Messages delivered to the learner.
    pub delivered: u64,
    /// Messages dropped (learner absent or busy).
    pub dropped: u64,
    /// Newest policy version used.
    pub policy_version: u64,
}

struct Policy {
    net: LinearActorCritic,
    policy_version: u64,
    unet_version: u64,
}

fn load_policy(
    message: &ReceivedMessage,
    transport: &TransportConfig,
    env: &dyn Environment,
) -> anyhow::Result<Policy> {
    let limits = Limits {
        max_actors: transport.max_actors,
        max_payload_len: transport.max_weights_bytes as u64,
    };
    let (header, message) =
        proto::decode(message.bytes(), &limits).context("the learner sent invalid weights")?;
    let Message::Weights(weights) = message else {
        bail!(
            "expected weights on the weights service, got {:?}",
            message.kind()
        );
    };
    let net = LinearActorCritic::from_safetensors(weights.bytes(), env.obs_dim(), env.n_actions())
        .context("the learner's policy does not fit this environment (check [policy] obs_dim / n_actions in the learner config)")?;
    Ok(Policy {
        net,
        policy_version: header.policy_version,
        unet_version: header.unet_version,
    })
}

/// Collects steps until a chunk is full or the episode ends.
struct ChunkBuilder {
    chunk: RolloutChunk,
}

impl ChunkBuilder {
    fn new(episode_id: u64, first_step: u32, env: &dyn Environment) -> Self {
        Self {
            chunk: RolloutChunk {
                episode_id,
                first_step,
                n_actions: env.n_actions() as u32,
                obs_dtype: ObsDtype::F32,
                obs_elems: env.obs_dim() as u32,
                obs: Vec::new(),
                actions: Vec::new(),
                masks: Vec::new(),
                log_probs: Vec::new(),
                values: Vec::new(),
                rewards: Vec::new(),
                dones: Vec::new(),
                bootstrap_value: 0.0,
            },
        }
    }
}

/// Runs episodes until `stop` is set or `max_episodes` are done.
pub fn run(
    env: &mut dyn Environment,
    ports: &mut ActorPorts,
    transport: &TransportConfig,
    settings: &LoopSettings,
    stop: &AtomicBool,
) -> anyhow::Result<LoopSummary> {
    eprintln!(
        "actor {}: waiting up to {:.0} s for weights on service prefix {:?}",
        settings.actor_id,
        settings.weights_timeout.as_secs_f64(),
        transport.service_prefix
    );
    let first = ports.wait_for_weights(settings.weights_timeout)?;
    let Some(first) = first else {
        bail!(
            "no weights from a learner on service prefix {:?} within {:.0} s: start the learner first (deploy/local.sh does), or check --learner and the transport config",
            transport.service_prefix,
            settings.weights_timeout.as_secs_f64()
        );
    };
    let mut policy = load_policy(&first, transport, env)?;
    drop(first);
    eprintln!(
        "actor {}: got policy version {}",
        settings.actor_id, policy.policy_version
    );

    let mut rng = SmallRng::seed_from_u64(settings.seed ^ (u64::from(settings.actor_id) << 32));
    let mut summary = LoopSummary::default();
    let count = |d: Delivery, s: &mut LoopSummary| match d {
        Delivery::Delivered(_) => s.delivered += 1,
        Delivery::Dropped => s.dropped += 1,
    };
    while !stop.load(Ordering::Relaxed)
        && settings.max_episodes.is_none_or(|m| summary.episodes < m)
    {
        let episode_id = summary.episodes;
        let started = Instant::now();
        let mut observation: Observation = env.reset(
            settings
                .seed
                .wrapping_add(episode_id.wrapping_mul(1_000_003))
                .wrapping_add(u64::from(settings.actor_id)),
        );
        let (mut step, mut episode_return, mut successes) = (0u32, 0.0f32, 0u32);
        let mut builder = ChunkBuilder::new(episode_id, 0, env);
        loop {
            if let Some(message) = ports.take_latest_weights()? {
                policy = load_policy(&message, transport, env)?;
            }
            let log_probs = log_softmax_masked(
                &policy.net.logits(&observation.features),
                &observation.action_mask,
            );
            let Some((action, log_prob)) = sample(&log_probs, rng.random::<f32>()) else {
                bail!("the environment allowed no action at step {step}");
            };
            let value = policy.net.value(&observation.features);
            let transition = env.step(action);
            step += 1;
            episode_return += transition.reward;
            successes += u32::from(transition.success);
            let c = &mut builder.chunk;
            c.obs
                .extend(observation.features.iter().flat_map(|v| v.to_le_bytes()));
            c.masks.extend_from_slice(&observation.action_mask);
            c.actions.push(action);
            c.log_probs.push(log_prob);
            c.values.push(value);
            c.rewards.push(transition.reward);
            c.dones.push(u8::from(transition.done));
            observation = transition.observation;
            let stopping = stop.load(Ordering::Relaxed);
            if c.actions.len() >= settings.chunk_steps || transition.done || stopping {
                c.bootstrap_value = if transition.done {
                    0.0
                } else {
                    policy.net.value(&observation.features)
                };
                let delivery =
                    ports.publish(&builder.chunk, policy.policy_version, policy.unet_version)?;
                count(delivery, &mut summary);
                builder = ChunkBuilder::new(episode_id, step, env);
            }
            if transition.done || stopping {
                break;
            }
        }
        summary.steps += u64::from(step);
        let seconds = started.elapsed().as_secs_f64().max(1e-9);
        let stats = EpisodeStats::new(episode_id, step, env.scene_index())
            .with(StatField::EpisodeReturn, episode_return)
            .with(
                StatField::InteractionSuccessRate,
                successes as f32 / step.max(1) as f32,
            )
            .with(
                StatField::StepsPerSecond,
                (f64::from(step) / seconds) as f32,
            );
        let delivery = ports.publish(&stats, policy.policy_version, policy.unet_version)?;
        count(delivery, &mut summary);
        summary.episodes += 1;
    }
    summary.policy_version = policy.policy_version;
    Ok(summary)
}
