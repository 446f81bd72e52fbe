//! The actor's episode loop: act with the newest broadcast policy, send
//! rollout chunks, the episode's labelled frames and its stats, and pick up
//! new weights (policy, and the U-Net when its version changes) between steps.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use burn::prelude::*;
use nets::policy::{PolicyInput, PolicyLayout, PolicyNet};
use nets::sample;
use nets::weights::{load_safetensors, unbundle};
use proto::{
    EpisodeStats, FrameBatch, Limits, Message, ObsDtype, RolloutChunk, StatField,
    WEIGHTS_META_ENV_STEPS, WEIGHTS_META_TEMPERATURE, WEIGHTS_POLICY_PREFIX, WEIGHTS_UNET_PREFIX,
};
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
    /// Base seed; episode `k` of actor `a` resets with a seed derived from
    /// all three and from the run's environment steps when the actor
    /// started ([`episode_seed`]).
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
    /// Newest U-Net version used.
    pub unet_version: u64,
}

/// The broadcast policy the actor acts with.
struct Policy {
    net: PolicyNet,
    layout: PolicyLayout,
    policy_version: u64,
    unet_version: u64,
    /// The run's environment steps over all actors when the learner sent
    /// these weights (0 if it did not say).
    env_steps: u64,
}

/// The seed of this process's random choices: the `base` seed, moved on by
/// the run's environment steps when the process got its first weights. A
/// fresh run starts at 0 steps, so its seeds are the base seed's; an actor
/// restarted mid-run, or a resumed run, starts later and does not replay
/// the rooms and actions of the episodes it ran before.
fn process_seed(base: u64, started_at_steps: u64) -> u64 {
    base.wrapping_add(started_at_steps.wrapping_mul(0x9E37_79B9_7F4A_7C15))
}

/// The reset seed of this process's episode `episode`: distinct per actor
/// and per episode.
fn episode_seed(process_seed: u64, actor_id: u32, episode: u64) -> u64 {
    process_seed
        .wrapping_add(episode.wrapping_mul(1_000_003))
        .wrapping_add(u64::from(actor_id))
}

/// Back-off after rollouts the learner had no room for: its queue for this
/// actor was full, so it is not keeping up. Producing more would only be
/// discarded, and it would keep this actor's queue full, where the learner
/// (which serves its senders in a fixed order) might never reach the others.
/// Sleeps 1 ms after the first drop in a row, doubling to at most 64 ms; a
/// delivered chunk resets it. Simulator actors are far slower than the
/// learner and rarely see it; a fast fixture is paced to the learner.
#[derive(Debug, Default)]
struct Backoff {
    sleep: Option<Duration>,
}

impl Backoff {
    fn after(&mut self, delivery: Delivery) {
        self.sleep = match delivery {
            Delivery::Delivered(_) => None,
            Delivery::Dropped => {
                let sleep = self.sleep.map_or(Duration::from_millis(1), |s| {
                    (s * 2).min(Duration::from_millis(64))
                });
                std::thread::sleep(sleep);
                Some(sleep)
            }
        };
    }
}

/// Loads a weights message: the policy always, the U-Net when the message
/// carries one of another version than `current`'s.
fn load_weights(
    message: &ReceivedMessage,
    transport: &TransportConfig,
    env: &mut dyn Environment,
    device: &Device,
    current: Option<&Policy>,
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
    let layout = env.layout().clone();
    let mut net = PolicyNet::new(&layout, device);
    let policy_bytes = unbundle(weights.bytes(), WEIGHTS_POLICY_PREFIX)
        .context("the learner's weights hold no policy")?;
    load_safetensors(&mut net, policy_bytes).context(
        "the learner's policy does not fit this actor's task (start the actor with the learner's config.toml: --config RUN_DIR/config.toml)",
    )?;
    let metadata = nets::weights::metadata(weights.bytes()).unwrap_or_default();
    let number = |key: &str| metadata.get(key).and_then(|v| v.parse::<f64>().ok());
    let env_steps = number(WEIGHTS_META_ENV_STEPS).map(|steps| steps as u64);
    if let Some(steps) = env_steps {
        env.set_global_steps(steps);
    }
    let has_unet = weights
        .tensors()
        .names()
        .iter()
        .any(|n| n.starts_with(WEIGHTS_UNET_PREFIX));
    let unet_changed = current.is_none_or(|p| p.unet_version != header.unet_version);
    if has_unet && unet_changed {
        let temperature = number(WEIGHTS_META_TEMPERATURE).unwrap_or(1.0) as f32;
        env.load_unet(unbundle(weights.bytes(), WEIGHTS_UNET_PREFIX)?, temperature)?;
        eprintln!(
            "actor: loaded U-Net version {} (temperature {temperature:.3})",
            header.unet_version
        );
    }
    Ok(Policy {
        net,
        layout,
        policy_version: header.policy_version,
        unet_version: header.unet_version,
        env_steps: env_steps.unwrap_or(0),
    })
}

/// What the policy did at one step.
struct Acted {
    action: u32,
    log_prob: f32,
    /// The critic's value of the observation.
    value: f32,
    /// The GRU state after this step (policies with memory).
    hidden: Option<Tensor<2>>,
}

/// One action sampled from the policy, given its recurrent state before
/// this step (`None` at an episode's start, or without a GRU).
fn act(
    policy: &Policy,
    observation: &Observation,
    hidden: Option<Tensor<2>>,
    uniform: f32,
    device: &Device,
) -> Option<Acted> {
    let out = policy.net.forward(
        &PolicyInput::from_flat(
            &policy.layout,
            &observation.features,
            &observation.action_mask,
            1,
            device,
        ),
        hidden,
    );
    let mut log_probs: Vec<f32> = out.log_probs.into_data().try_to_vec().ok()?;
    for (lp, &allowed) in log_probs.iter_mut().zip(&observation.action_mask) {
        if allowed == 0 {
            *lp = f32::NEG_INFINITY;
        }
    }
    let value = out.values.into_scalar::<f32>();
    sample(&log_probs, uniform).map(|(action, log_prob)| Acted {
        action,
        log_prob,
        value,
        hidden: out.hidden,
    })
}

/// The critic's value of `observation` (the recurrent state is not advanced).
fn value_of(
    policy: &Policy,
    observation: &Observation,
    hidden: Option<Tensor<2>>,
    device: &Device,
) -> f32 {
    act(policy, observation, hidden, 0.0, device).map_or(0.0, |a| a.value)
}

/// The recurrent state as the chunk carries it: zeros before an episode's
/// first step, nothing for a policy without memory.
fn hidden_values(layout: &PolicyLayout, hidden: Option<&Tensor<2>>) -> Vec<f32> {
    match (layout.gru_hidden, hidden) {
        (None, _) => Vec::new(),
        (Some(size), None) => vec![0.0; size],
        (Some(_), Some(h)) => h.clone().into_data().try_to_vec().unwrap_or_default(),
    }
}

/// An empty chunk for `env`'s layout, starting from recurrent state `start_hidden`.
fn new_chunk(
    episode_id: u64,
    first_step: u32,
    env: &dyn Environment,
    start_hidden: Vec<f32>,
) -> RolloutChunk {
    let layout = env.layout();
    RolloutChunk {
        episode_id,
        first_step,
        n_actions: layout.n_actions as u32,
        obs_dtype: layout.obs_dtype,
        obs_elems: layout.obs_len() as u32,
        obs: Vec::new(),
        actions: Vec::new(),
        masks: Vec::new(),
        log_probs: Vec::new(),
        values: Vec::new(),
        rewards: Vec::new(),
        dones: Vec::new(),
        bootstrap_value: 0.0,
        start_hidden,
    }
}

/// Appends an observation in the chunk's element type.
fn push_obs(chunk: &mut RolloutChunk, features: &[f32]) {
    match chunk.obs_dtype {
        ObsDtype::U8 => chunk
            .obs
            .extend(features.iter().map(|&v| proto::unit_to_byte(v))),
        ObsDtype::F32 => chunk
            .obs
            .extend(features.iter().flat_map(|v| v.to_le_bytes())),
    }
}

/// Splits an episode's frames into messages of at most `max_bytes` payload.
fn split_frames(batch: FrameBatch, max_bytes: usize) -> Vec<FrameBatch> {
    let pixels = (batch.height * batch.width) as usize;
    let planes = batch.n_affordances as usize;
    let per_frame = pixels * (4 + 3 + planes);
    let per_message = (max_bytes.saturating_sub(64) / per_frame.max(1)).max(1);
    let n = batch.n_frames();
    (0..n)
        .step_by(per_message)
        .map(|start| {
            let end = (start + per_message).min(n);
            FrameBatch {
                episode_id: batch.episode_id,
                height: batch.height,
                width: batch.width,
                n_affordances: batch.n_affordances,
                depth_m: batch.depth_m[start * pixels..end * pixels].to_vec(),
                rgb: batch.rgb[3 * start * pixels..3 * end * pixels].to_vec(),
                labels: batch.labels[planes * start * pixels..planes * end * pixels].to_vec(),
            }
        })
        .collect()
}

/// Runs episodes until `stop` is set or `max_episodes` are done.
pub fn run(
    env: &mut dyn Environment,
    ports: &mut ActorPorts,
    transport: &TransportConfig,
    settings: &LoopSettings,
    device: &Device,
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
    let mut policy = load_weights(&first, transport, env, device, None)?;
    drop(first);
    eprintln!(
        "actor {}: got policy version {}, U-Net version {}",
        settings.actor_id, policy.policy_version, policy.unet_version
    );

    let seed = process_seed(settings.seed, policy.env_steps);
    let mut rng = SmallRng::seed_from_u64(seed ^ (u64::from(settings.actor_id) << 32));
    let mut summary = LoopSummary::default();
    let mut backoff = Backoff::default();
    let count = |d: Delivery, s: &mut LoopSummary| match d {
        Delivery::Delivered(_) => s.delivered += 1,
        Delivery::Dropped => s.dropped += 1,
    };
    while !stop.load(Ordering::Relaxed)
        && settings.max_episodes.is_none_or(|m| summary.episodes < m)
    {
        let episode_id = summary.episodes;
        let started = Instant::now();
        let mut observation: Observation =
            env.reset(episode_seed(seed, settings.actor_id, episode_id))?;
        let (mut step, mut episode_return) = (0u32, 0.0f32);
        // The GRU state before the next step; `None` = zeros (episode start).
        let mut hidden: Option<Tensor<2>> = None;
        let mut chunk = new_chunk(episode_id, 0, env, hidden_values(env.layout(), None));
        loop {
            if let Some(message) = ports.take_latest_weights()? {
                policy = load_weights(&message, transport, env, device, Some(&policy))?;
            }
            let Some(Acted {
                action,
                log_prob,
                value,
                hidden: next_hidden,
            }) = act(
                &policy,
                &observation,
                hidden.take(),
                rng.random::<f32>(),
                device,
            )
            else {
                bail!("the environment allowed no action at step {step}");
            };
            hidden = next_hidden;
            let transition = env.step(action)?;
            step += 1;
            episode_return += transition.reward;
            push_obs(&mut chunk, &observation.features);
            chunk.masks.extend_from_slice(&observation.action_mask);
            chunk.actions.push(action);
            chunk.log_probs.push(log_prob);
            chunk.values.push(value);
            chunk.rewards.push(transition.reward);
            chunk.dones.push(u8::from(transition.done));
            observation = transition.observation;
            let stopping = stop.load(Ordering::Relaxed);
            if chunk.actions.len() >= settings.chunk_steps || transition.done || stopping {
                chunk.bootstrap_value = if transition.done {
                    0.0
                } else {
                    value_of(&policy, &observation, hidden.clone(), device)
                };
                let delivery = ports.publish(&chunk, policy.policy_version, policy.unet_version)?;
                count(delivery, &mut summary);
                backoff.after(delivery);
                chunk = new_chunk(
                    episode_id,
                    step,
                    env,
                    hidden_values(env.layout(), hidden.as_ref()),
                );
            }
            if transition.done || stopping {
                break;
            }
        }
        summary.steps += u64::from(step);
        let seconds = started.elapsed().as_secs_f64().max(1e-9);
        let end = env.finish_episode(episode_id)?;
        if let Some(frames) = end.frames.filter(|f| f.n_frames() > 0) {
            for part in split_frames(frames, transport.max_frames_bytes) {
                let delivery = ports.publish(&part, policy.policy_version, policy.unet_version)?;
                count(delivery, &mut summary);
            }
        }
        let mut stats = EpisodeStats::new(episode_id, step, env.scene_index())
            .with(StatField::EpisodeReturn, episode_return)
            .with(
                StatField::StepsPerSecond,
                (f64::from(step) / seconds) as f32,
            );
        for (field, value) in end.stats {
            stats = stats.with(field, value);
        }
        let delivery = ports.publish(&stats, policy.policy_version, policy.unet_version)?;
        count(delivery, &mut summary);
        summary.episodes += 1;
    }
    summary.policy_version = policy.policy_version;
    summary.unet_version = policy.unet_version;
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_fresh_run_keeps_its_seeds_and_a_restarted_actor_does_not_replay_them() {
        let seeds = |started_at_steps: u64, actor_id: u32| -> Vec<u64> {
            let seed = process_seed(7, started_at_steps);
            (0..2000).map(|k| episode_seed(seed, actor_id, k)).collect()
        };
        // A fresh run: the seeds runs have always had, so runs reproduce.
        let fresh = seeds(0, 1);
        assert_eq!(fresh[3], 7 + 3 * 1_000_003 + 1);
        // The same actor restarted (or the run resumed) later in the run, and
        // another actor: none of their episodes repeats one of these.
        let fresh: std::collections::HashSet<u64> = fresh.into_iter().collect();
        for (started_at_steps, actor_id) in [(1, 1), (600, 1), (48_000, 1), (0, 2), (600, 2)] {
            let other = seeds(started_at_steps, actor_id);
            let repeated = other.iter().filter(|s| fresh.contains(s)).count();
            assert_eq!(
                repeated, 0,
                "started at {started_at_steps} steps, actor {actor_id}: {repeated} repeated seeds"
            );
        }
    }

    #[test]
    fn frames_split_into_messages_that_fit_and_lose_nothing() {
        let (h, w, a, n) = (4u32, 5u32, 2u32, 7usize);
        let pixels = (h * w) as usize;
        let batch = FrameBatch {
            episode_id: 3,
            height: h,
            width: w,
            n_affordances: a,
            depth_m: (0..n * pixels).map(|i| i as f32).collect(),
            rgb: (0..3 * n * pixels).map(|i| i as u8).collect(),
            labels: (0..2 * n * pixels).map(|i| (i % 2) as u8).collect(),
        };
        let per_frame = pixels * 9;
        let parts = split_frames(batch.clone(), 64 + 3 * per_frame);
        assert_eq!(parts.len(), 3);
        assert_eq!(
            parts.iter().map(|p| p.n_frames()).collect::<Vec<_>>(),
            [3, 3, 1]
        );
        let joined: Vec<f32> = parts.iter().flat_map(|p| p.depth_m.clone()).collect();
        assert_eq!(joined, batch.depth_m);
        let labels: Vec<u8> = parts.iter().flat_map(|p| p.labels.clone()).collect();
        assert_eq!(labels, batch.labels);
        assert!(parts.iter().all(|p| p.episode_id == 3));
    }
}
