//! The actor's episode loop: act with the newest broadcast policy, send
//! rollout chunks, the episode's labelled frames and its stats, and pick up
//! new weights (policy, and the U-Net when its version changes) between steps.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{PoisonError, RwLock, RwLockReadGuard};
use std::time::{Duration, Instant};

use anyhow::{bail, ensure, Context};
use burn::prelude::*;
use nets::policy::{CpuPolicy, PolicyInput, PolicyLayout, PolicyNet};
use nets::sample;
use nets::weights::{load_safetensors, unbundle};
use proto::{
    EpisodeStats, FrameBatch, ObsDtype, RolloutChunk, StatField, WEIGHTS_META_ENV_STEPS,
    WEIGHTS_META_TEMPERATURE, WEIGHTS_POLICY_PREFIX, WEIGHTS_UNET_PREFIX,
};
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};
use transport::{ActorPorts, Delivery, ReceivedMessage, TransportConfig};

use rayon::prelude::*;

use crate::env::affordance_model::AffordanceModel;
use crate::env::{lockstep, Environment, EpisodeEnd, Observation, StepOutcome};

mod free_running;
mod rejected_weights;

use rejected_weights::RejectedWeights;

/// Settings of one actor's loop.
#[derive(Debug, Clone)]
pub struct LoopSettings {
    /// This actor's id.
    pub actor_id: u32,
    /// Steps per rollout chunk.
    pub chunk_steps: usize,
    /// Base seed; episode `k` of actor `a` resets with a seed derived from
    /// all three and from the run's environment steps when the actor
    /// started (`episode_seed`).
    pub seed: u64,
    /// Stop after this many episodes over all environments (None = until
    /// SIGINT/SIGTERM).
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
    /// Weights messages refused as invalid (the actor kept its weights).
    pub weights_rejected: u64,
}

/// The broadcast policy the actor acts with.
struct Policy {
    net: PolicyNet,
    /// The same weights for the CPU's own pass (`nets::policy::CpuPolicy`),
    /// used on every device where the policy has one.
    cpu: Option<CpuPolicy>,
    layout: PolicyLayout,
    policy_version: u64,
    unet_version: u64,
    /// The run's environment steps over all actors when the learner sent
    /// these weights, if it said.
    env_steps: Option<u64>,
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

/// Loads a weights message once `ports` has checked it (layout, size, the
/// run key's signature): the policy always, the U-Net (into `model`) when
/// the message carries one of another version than `current`'s.
fn load_weights(
    ports: &ActorPorts,
    message: &ReceivedMessage,
    layout: &PolicyLayout,
    model: Option<&mut AffordanceModel>,
    device: &Device,
    current: Option<&Policy>,
) -> anyhow::Result<Policy> {
    let (header, weights) = ports
        .check_weights(message)
        .context("invalid weights on the weights service")?;
    let mut net = PolicyNet::new(layout, device);
    let policy_bytes = unbundle(weights.bytes(), WEIGHTS_POLICY_PREFIX)
        .context("the learner's weights hold no policy")?;
    load_safetensors(&mut net, policy_bytes).context(
        "the learner's policy does not fit this actor's task (start the actor with the learner's config.toml: --config RUN_DIR/config.toml)",
    )?;
    let metadata = nets::weights::metadata(weights.bytes()).unwrap_or_default();
    let number = |key: &str| metadata.get(key).and_then(|v| v.parse::<f64>().ok());
    let env_steps = number(WEIGHTS_META_ENV_STEPS).map(|steps| steps as u64);
    let has_unet = weights
        .tensors()
        .names()
        .iter()
        .any(|n| n.starts_with(WEIGHTS_UNET_PREFIX));
    let unet_changed = current.is_none_or(|p| p.unet_version != header.unet_version);
    if let (true, true, Some(model)) = (has_unet, unet_changed, model) {
        let temperature = number(WEIGHTS_META_TEMPERATURE).unwrap_or(1.0) as f32;
        model
            .load_weights(unbundle(weights.bytes(), WEIGHTS_UNET_PREFIX)?)
            .context("loading the learner's U-Net")?;
        model.temperature = temperature;
        eprintln!(
            "actor: loaded U-Net version {} (temperature {temperature:.3})",
            header.unet_version
        );
    }
    // The policy is small (about 15 MFLOP a pass at 64 px): on a GPU, burn's
    // pass is bound by its per-operation overhead, so the CPU's own pass
    // serves every device (docs/decisions/0007-policy-pass-on-the-cpu.md).
    let cpu = CpuPolicy::from_network(&net, layout);
    Ok(Policy {
        net,
        cpu,
        layout: layout.clone(),
        policy_version: header.policy_version,
        unet_version: header.unet_version,
        env_steps,
    })
}

/// What the policy chose for one environment at one step.
struct Acted {
    action: u32,
    log_prob: f32,
    /// The critic's value of the observation.
    value: f32,
    /// The GRU state after this step (policies with memory).
    hidden: Option<Vec<f32>>,
}

/// The policy's output for one environment's observation.
struct PolicyStep {
    /// Log-probabilities of the actions, −∞ where masked.
    log_probs: Vec<f32>,
    /// The critic's value.
    value: f32,
    /// The GRU state after the step (policies with memory).
    hidden: Option<Vec<f32>>,
}

/// The policy over several environments' observations, each with its
/// recurrent state before this step (`None` = zeros, an episode's start):
/// one per observation and thread where the policy has the CPU's own pass
/// or runs on a CPU device, else one batched forward pass.
fn forward_batch(
    policy: &Policy,
    inputs: &[(&Observation, Option<&[f32]>)],
    device: &Device,
    inference: lockstep::Inference,
) -> anyhow::Result<Vec<PolicyStep>> {
    let per_observation = policy.cpu.is_some() || inference == lockstep::Inference::PerEnvironment;
    if inputs.len() > 1 && per_observation {
        return inputs
            .par_iter()
            .map(|input| forward(policy, std::slice::from_ref(input), device))
            .collect::<anyhow::Result<Vec<_>>>()
            .map(|steps| steps.into_iter().flatten().collect());
    }
    forward(policy, inputs, device)
}

/// One forward pass of the policy over `inputs` (see [`forward_batch`]).
fn forward(
    policy: &Policy,
    inputs: &[(&Observation, Option<&[f32]>)],
    device: &Device,
) -> anyhow::Result<Vec<PolicyStep>> {
    if let Some(cpu) = &policy.cpu {
        return Ok(inputs
            .iter()
            .map(|(observation, hidden)| {
                let step = cpu.forward(&observation.features, &observation.action_mask, *hidden);
                PolicyStep {
                    log_probs: masked(step.log_probs, &observation.action_mask),
                    value: step.value,
                    hidden: step.hidden,
                }
            })
            .collect());
    }
    let n = inputs.len();
    let features: Vec<f32> = inputs
        .iter()
        .flat_map(|(o, _)| o.features.iter().copied())
        .collect();
    let masks: Vec<u8> = inputs
        .iter()
        .flat_map(|(o, _)| o.action_mask.iter().copied())
        .collect();
    let hidden = policy.layout.gru_hidden.map(|size| {
        let values: Vec<f32> = inputs
            .iter()
            .flat_map(|(_, h)| hidden_values(&policy.layout, *h))
            .collect();
        Tensor::<1>::from_floats(values.as_slice(), device).reshape([n, size])
    });
    let out = policy.net.forward(
        &PolicyInput::from_flat(&policy.layout, &features, &masks, n, device),
        hidden,
    );
    let read = |t: Tensor<1>| -> anyhow::Result<Vec<f32>> {
        t.into_data()
            .try_to_vec()
            .map_err(|e| anyhow::anyhow!("reading the policy's output: {e:?}"))
    };
    let log_probs = read(out.log_probs.reshape([-1]))?;
    let values = read(out.values)?;
    let hidden = out.hidden.map(|h| read(h.reshape([-1]))).transpose()?;
    let n_actions = policy.layout.n_actions;
    Ok((0..n)
        .map(|i| {
            let lp = masked(
                log_probs[i * n_actions..(i + 1) * n_actions].to_vec(),
                &inputs[i].0.action_mask,
            );
            let h = hidden.as_ref().map(|h| {
                let size = h.len() / n;
                h[i * size..(i + 1) * size].to_vec()
            });
            PolicyStep {
                log_probs: lp,
                value: values[i],
                hidden: h,
            }
        })
        .collect())
}

/// `log_probs` with −∞ for the actions `mask` forbids.
fn masked(mut log_probs: Vec<f32>, mask: &[u8]) -> Vec<f32> {
    for (lp, &allowed) in log_probs.iter_mut().zip(mask) {
        if allowed == 0 {
            *lp = f32::NEG_INFINITY;
        }
    }
    log_probs
}

/// One action per environment sampled from the policy in one batch; the
/// `uniforms` decide the draws.
fn act_batch(
    policy: &Policy,
    inputs: &[(&Observation, Option<&[f32]>)],
    uniforms: &[f32],
    device: &Device,
    inference: lockstep::Inference,
) -> anyhow::Result<Vec<Acted>> {
    forward_batch(policy, inputs, device, inference)?
        .into_iter()
        .zip(uniforms)
        .map(|(step, &uniform)| {
            let (action, log_prob) =
                sample(&step.log_probs, uniform).context("the environment allowed no action")?;
            Ok(Acted {
                action,
                log_prob,
                value: step.value,
                hidden: step.hidden,
            })
        })
        .collect()
}

/// The recurrent state as the chunk carries it: zeros before an episode's
/// first step, nothing for a policy without memory.
fn hidden_values(layout: &PolicyLayout, hidden: Option<&[f32]>) -> Vec<f32> {
    match (layout.gru_hidden, hidden) {
        (None, _) => Vec::new(),
        (Some(size), None) => vec![0.0; size],
        (Some(_), Some(h)) => h.to_vec(),
    }
}

/// An empty chunk in `layout`, starting from recurrent state `start_hidden`.
fn new_chunk(
    episode_id: u64,
    first_step: u32,
    layout: &PolicyLayout,
    start_hidden: Vec<f32>,
) -> RolloutChunk {
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

/// One environment of the actor and its running episode.
struct Slot {
    env: Box<dyn Environment>,
    /// `None` once the actor starts no more episodes here.
    episode: Option<RunningEpisode>,
}

/// The bookkeeping of one running episode.
struct RunningEpisode {
    id: u64,
    steps: u32,
    episode_return: f32,
    started: Instant,
    /// The actor's steps (all environments) when the episode started.
    actor_steps_at_start: u64,
    observation: Observation,
    /// The GRU state before the next step; `None` = zeros (episode start).
    hidden: Option<Vec<f32>>,
    chunk: RolloutChunk,
}

/// The environments of `slots`, for [`lockstep`].
fn envs_of<'a>(slots: &'a mut [&mut Slot]) -> Vec<&'a mut (dyn Environment + 'static)> {
    slots.iter_mut().map(|s| s.env.as_mut()).collect()
}

/// What the loop keeps between steps besides the slots.
struct Actor<'a> {
    ports: &'a mut ActorPorts,
    transport: &'a TransportConfig,
    settings: &'a LoopSettings,
    device: &'a Device,
    /// The U-Net, shared with the threads of free-running environments
    /// (`free_running`), which read it while the loop may load new weights.
    model: &'a RwLock<Option<AffordanceModel>>,
    /// How the networks see the environments' inputs (suited to `device`).
    inference: lockstep::Inference,
    policy: Policy,
    seed: u64,
    rng: SmallRng,
    summary: LoopSummary,
    /// Episodes started over all slots (their ids).
    started: u64,
    backoff: Backoff,
    rejected_weights: RejectedWeights,
}

impl<'a> Actor<'a> {
    /// What the loop did, with the newest weights' versions.
    fn summary(&self) -> LoopSummary {
        LoopSummary {
            policy_version: self.policy.policy_version,
            unet_version: self.policy.unet_version,
            weights_rejected: self.rejected_weights.count(),
            ..self.summary
        }
    }

    /// One action for each of `inputs` (observation, recurrent state),
    /// drawn from the policy with this loop's random numbers.
    fn act(&mut self, inputs: &[(&Observation, Option<&[f32]>)]) -> anyhow::Result<Vec<Acted>> {
        let uniforms: Vec<f32> = inputs.iter().map(|_| self.rng.random::<f32>()).collect();
        act_batch(&self.policy, inputs, &uniforms, self.device, self.inference)
    }

    fn count(&mut self, delivery: Delivery) {
        match delivery {
            Delivery::Delivered(_) => self.summary.delivered += 1,
            Delivery::Dropped => self.summary.dropped += 1,
        }
    }

    fn publish_chunk(&mut self, chunk: &RolloutChunk) -> anyhow::Result<()> {
        let delivery =
            self.ports
                .publish(chunk, self.policy.policy_version, self.policy.unet_version)?;
        self.count(delivery);
        self.backoff.after(delivery);
        Ok(())
    }

    /// The U-Net (between the loads of new weights).
    fn read_model(&self) -> RwLockReadGuard<'a, Option<AffordanceModel>> {
        self.model.read().unwrap_or_else(PoisonError::into_inner)
    }

    /// Takes the newest weights, if the learner sent any since the last
    /// look; returns the run's environment steps they came with, which the
    /// environments must be told. Invalid weights are counted and skipped:
    /// the actor keeps the ones it has.
    fn refresh_weights(&mut self) -> anyhow::Result<Option<u64>> {
        let Some(message) = self.ports.take_latest_weights()? else {
            return Ok(None);
        };
        let layout = self.policy.layout.clone();
        let mut model = self.model.write().unwrap_or_else(PoisonError::into_inner);
        match load_weights(
            self.ports,
            &message,
            &layout,
            model.as_mut(),
            self.device,
            Some(&self.policy),
        ) {
            Ok(policy) => {
                self.policy = policy;
                Ok(self.policy.env_steps)
            }
            Err(error) => {
                self.rejected_weights.reject(
                    self.settings.actor_id,
                    &error,
                    Some(self.policy.policy_version),
                );
                Ok(None)
            }
        }
    }

    /// The id of the next episode to start; `None` once `max_episodes` have started.
    fn next_episode_id(&mut self) -> Option<u64> {
        if self
            .settings
            .max_episodes
            .is_some_and(|max| self.started >= max)
        {
            return None;
        }
        self.started += 1;
        Some(self.started - 1)
    }

    /// The reset seed of episode `id`.
    fn seed_of(&self, id: u64) -> u64 {
        episode_seed(self.seed, self.settings.actor_id, id)
    }

    /// The bookkeeping of episode `id`, which starts at `observation`.
    fn begin_episode(&self, id: u64, observation: Observation) -> RunningEpisode {
        let layout = &self.policy.layout;
        RunningEpisode {
            id,
            steps: 0,
            episode_return: 0.0,
            started: Instant::now(),
            actor_steps_at_start: self.summary.steps,
            observation,
            hidden: None,
            chunk: new_chunk(id, 0, layout, hidden_values(layout, None)),
        }
    }

    /// Adds one step to `episode`: what was `acted` on its observation, the
    /// `outcome`, and the `observation` that follows. Returns `Some(done)`
    /// when its chunk must go out now (full, the episode ended, or the loop
    /// is `stopping`).
    fn record_step(
        &mut self,
        episode: &mut RunningEpisode,
        acted: Acted,
        outcome: &StepOutcome,
        observation: Observation,
        stopping: bool,
    ) -> Option<bool> {
        episode.steps += 1;
        episode.episode_return += outcome.reward;
        let chunk = &mut episode.chunk;
        push_obs(chunk, &episode.observation.features);
        chunk
            .masks
            .extend_from_slice(&episode.observation.action_mask);
        chunk.actions.push(acted.action);
        chunk.log_probs.push(acted.log_prob);
        chunk.values.push(acted.value);
        chunk.rewards.push(outcome.reward);
        chunk.dones.push(u8::from(outcome.done));
        episode.observation = observation;
        episode.hidden = acted.hidden;
        self.summary.steps += 1;
        let full = chunk.actions.len() >= self.settings.chunk_steps;
        (full || outcome.done || stopping).then_some(outcome.done)
    }

    /// Starts the next episode in each of `slots` (resets in parallel, the
    /// first frames through the U-Net in one batch); a slot gets none once
    /// `max_episodes` have started.
    fn start_episodes(&mut self, slots: Vec<&mut Slot>) -> anyhow::Result<()> {
        let mut starting = Vec::new();
        for slot in slots {
            match self.next_episode_id() {
                Some(id) => starting.push((slot, id)),
                None => slot.episode = None,
            }
        }
        let (mut slots, ids): (Vec<&mut Slot>, Vec<u64>) = starting.into_iter().unzip();
        let seeds: Vec<u64> = ids.iter().map(|&id| self.seed_of(id)).collect();
        let observations = lockstep::reset_all(
            &mut envs_of(&mut slots),
            &seeds,
            self.read_model().as_ref(),
            self.inference,
        )?;
        for ((slot, id), observation) in slots.into_iter().zip(ids).zip(observations) {
            slot.episode = Some(self.begin_episode(id, observation));
        }
        Ok(())
    }

    /// One step of every slot with a running episode: the policy over all
    /// observations in one batch, the actions in parallel, the U-Net over
    /// all new frames in one batch. Full chunks go to the learner; ended
    /// episodes (or all, once `stopping`) are finished and reported.
    /// Returns the slots whose episodes ended.
    fn step_all<'s>(
        &mut self,
        slots: &'s mut [Slot],
        stopping: bool,
    ) -> anyhow::Result<Vec<&'s mut Slot>> {
        let mut running: Vec<&mut Slot> =
            slots.iter_mut().filter(|s| s.episode.is_some()).collect();
        let acted = {
            let inputs: Vec<_> = running
                .iter()
                .filter_map(|s| s.episode.as_ref())
                .map(|e| (&e.observation, e.hidden.as_deref()))
                .collect();
            self.act(&inputs)?
        };
        let actions: Vec<u32> = acted.iter().map(|a| a.action).collect();
        let (outcomes, observations): (Vec<StepOutcome>, Vec<Observation>) = lockstep::step_all(
            &mut envs_of(&mut running),
            &actions,
            self.read_model().as_ref(),
            self.inference,
        )?
        .into_iter()
        .unzip();
        // The slots whose chunk goes out now, and whether their episode ended.
        let mut closing = Vec::with_capacity(running.len());
        for (((slot, acted), outcome), observation) in running
            .iter_mut()
            .zip(acted)
            .zip(&outcomes)
            .zip(observations)
        {
            let episode = slot.episode.as_mut().context("a running episode")?;
            if let Some(done) = self.record_step(episode, acted, outcome, observation, stopping) {
                closing.push((episode, done));
            }
        }
        self.close_chunks(closing)?;
        let ended: Vec<&mut Slot> = running
            .into_iter()
            .zip(&outcomes)
            .filter(|(_, o)| o.done || stopping)
            .map(|(slot, _)| slot)
            .collect();
        self.finish_episodes(ended)
    }

    /// Sends the chunks of `episodes` (each with whether it ended): those
    /// cut mid-episode get the critic's value of their next observation, in
    /// one batch.
    fn close_chunks(
        &mut self,
        mut episodes: Vec<(&mut RunningEpisode, bool)>,
    ) -> anyhow::Result<()> {
        let values = {
            let inputs: Vec<_> = episodes
                .iter()
                .filter(|(_, done)| !done)
                .map(|(e, _)| (&e.observation, e.hidden.as_deref()))
                .collect();
            if inputs.is_empty() {
                Vec::new()
            } else {
                forward_batch(&self.policy, &inputs, self.device, self.inference)?
            }
        };
        let mut values = values.into_iter();
        let layout = self.policy.layout.clone();
        for (episode, done) in &mut episodes {
            if !*done {
                episode.chunk.bootstrap_value = values.next().map_or(0.0, |step| step.value);
            }
            let next = new_chunk(
                episode.id,
                episode.steps,
                &layout,
                hidden_values(&layout, episode.hidden.as_deref()),
            );
            let chunk = std::mem::replace(&mut episode.chunk, next);
            self.publish_chunk(&chunk)?;
        }
        Ok(())
    }

    /// Ends the episodes of `ended` (labelling in parallel) and sends their
    /// labelled frames and stats.
    fn finish_episodes<'s>(
        &mut self,
        ended: Vec<&'s mut Slot>,
    ) -> anyhow::Result<Vec<&'s mut Slot>> {
        let mut finishing: Vec<(&mut Slot, RunningEpisode)> = ended
            .into_iter()
            .filter_map(|slot| slot.episode.take().map(|e| (slot, e)))
            .collect();
        // Read before the environment lets go of the episode.
        let scenes: Vec<u32> = finishing.iter().map(|(s, _)| s.env.scene_index()).collect();
        let ends: Vec<EpisodeEnd> = finishing
            .par_iter_mut()
            .map(|(slot, episode)| slot.env.finish_episode(episode.id))
            .collect::<anyhow::Result<_>>()?;
        let mut slots = Vec::new();
        for (((slot, episode), end), scene) in finishing.into_iter().zip(ends).zip(scenes) {
            self.publish_end(&episode, end, scene)?;
            slots.push(slot);
        }
        Ok(slots)
    }

    /// Sends an ended episode's labelled frames and stats (`scene`: the
    /// scene it ran in).
    fn publish_end(
        &mut self,
        episode: &RunningEpisode,
        end: EpisodeEnd,
        scene: u32,
    ) -> anyhow::Result<()> {
        let (version, unet) = (self.policy.policy_version, self.policy.unet_version);
        if let Some(frames) = end.frames.filter(|f| f.n_frames() > 0) {
            for part in split_frames(frames, self.transport.max_frames_bytes) {
                let delivery = self.ports.publish(&part, version, unet)?;
                self.count(delivery);
            }
        }
        let seconds = episode.started.elapsed().as_secs_f64().max(1e-9);
        let steps_per_second = (self.summary.steps - episode.actor_steps_at_start) as f64 / seconds;
        let mut stats = EpisodeStats::new(episode.id, episode.steps, scene)
            .with(StatField::EpisodeReturn, episode.episode_return)
            .with(StatField::StepsPerSecond, steps_per_second as f32);
        for (field, value) in end.stats {
            stats = stats.with(field, value);
        }
        let delivery = self.ports.publish(&stats, version, unet)?;
        self.count(delivery);
        self.summary.episodes += 1;
        Ok(())
    }
}

/// Runs episodes in every environment of `envs` until `stop` is set or
/// `max_episodes` are done: free-running where that pays
/// (`free_running::suits`), in lock-step otherwise. `model` is the affordance
/// U-Net for environments with a camera (it takes the learner's new
/// U-Nets); environments without one need none.
pub fn run(
    envs: Vec<Box<dyn Environment>>,
    model: Option<AffordanceModel>,
    ports: &mut ActorPorts,
    transport: &TransportConfig,
    settings: &LoopSettings,
    device: &Device,
    stop: &AtomicBool,
) -> anyhow::Result<LoopSummary> {
    let Some(layout) = envs.first().map(|e| e.layout().clone()) else {
        bail!("an actor needs at least one environment");
    };
    ensure!(
        envs.iter().all(|e| *e.layout() == layout),
        "an actor's environments share one task"
    );
    eprintln!(
        "actor {}: waiting up to {:.0} s for weights on service prefix {:?}",
        settings.actor_id,
        settings.weights_timeout.as_secs_f64(),
        transport.service_prefix
    );
    let deadline = Instant::now() + settings.weights_timeout;
    let mut rejected_weights = RejectedWeights::default();
    let mut model = model;
    let policy = loop {
        let left = deadline.saturating_duration_since(Instant::now());
        let Some(first) = ports.wait_for_weights(left)? else {
            if let Some(reason) = rejected_weights.last() {
                bail!(
                    "no valid weights on service prefix {:?} within {:.0} s: {} weights messages \
                     were refused, the last because {reason}",
                    transport.service_prefix,
                    settings.weights_timeout.as_secs_f64(),
                    rejected_weights.count()
                );
            }
            bail!(
                "no weights from a learner on service prefix {:?} within {:.0} s: start the learner first (deploy/local.sh does), or check --learner and the transport config",
                transport.service_prefix,
                settings.weights_timeout.as_secs_f64()
            );
        };
        match load_weights(ports, &first, &layout, model.as_mut(), device, None) {
            Ok(policy) => break policy,
            Err(error) => {
                rejected_weights.reject(settings.actor_id, &error, None);
            }
        }
    };
    let model = RwLock::new(model);
    eprintln!(
        "actor {}: got policy version {}, U-Net version {}; {} environment(s)",
        settings.actor_id,
        policy.policy_version,
        policy.unet_version,
        envs.len()
    );
    let mut slots: Vec<Slot> = envs
        .into_iter()
        .map(|env| Slot { env, episode: None })
        .collect();
    if let Some(steps) = policy.env_steps {
        for slot in &mut slots {
            slot.env.set_global_steps(steps);
        }
    }
    let seed = process_seed(settings.seed, policy.env_steps.unwrap_or(0));
    let mut actor = Actor {
        ports,
        transport,
        settings,
        device,
        inference: lockstep::Inference::for_device(device),
        model: &model,
        policy,
        seed,
        rng: SmallRng::seed_from_u64(seed ^ (u64::from(settings.actor_id) << 32)),
        summary: LoopSummary::default(),
        started: 0,
        backoff: Backoff::default(),
        rejected_weights,
    };
    if free_running::suits(&actor, slots.len()) {
        eprintln!(
            "actor {}: the environments run free, each on its own thread",
            settings.actor_id
        );
        let envs = slots.into_iter().map(|s| s.env).collect();
        free_running::run(&mut actor, envs, stop)?;
        return Ok(actor.summary());
    }
    if !stop.load(Ordering::Relaxed) {
        actor.start_episodes(slots.iter_mut().collect())?;
    }
    while slots.iter().any(|s| s.episode.is_some()) {
        if let Some(steps) = actor.refresh_weights()? {
            for slot in &mut slots {
                slot.env.set_global_steps(steps);
            }
        }
        let stopping = stop.load(Ordering::Relaxed);
        let ended = actor.step_all(&mut slots, stopping)?;
        if !stopping && !stop.load(Ordering::Relaxed) {
            actor.start_episodes(ended)?;
        }
    }
    Ok(actor.summary())
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
    fn one_batched_forward_equals_a_forward_per_environment() {
        let device = nets::device::open_device(nets::device::DeviceChoice::Cpu).unwrap();
        let layout = PolicyLayout {
            image_channels: vec![2],
            image_size: 64,
            vector_dims: vec![5],
            n_actions: 4,
            obs_dtype: ObsDtype::F32,
            gru_hidden: Some(8),
        };
        let policy = Policy {
            net: PolicyNet::new(&layout, &device),
            cpu: None,
            layout: layout.clone(),
            policy_version: 1,
            unet_version: 0,
            env_steps: None,
        };
        let observations: Vec<Observation> = (0..3)
            .map(|k| Observation {
                features: (0..layout.obs_len())
                    .map(|i| ((i * 7 + k * 13) % 17) as f32 / 17.0)
                    .collect(),
                action_mask: (0..4).map(|a| u8::from(a != k)).collect(),
            })
            .collect();
        // An episode's start (zeros) beside two running recurrent states.
        let hidden = [
            None,
            Some((0..8).map(|i| i as f32 / 8.0 - 0.5).collect::<Vec<f32>>()),
            Some(vec![0.3; 8]),
        ];
        let inputs: Vec<_> = observations
            .iter()
            .zip(&hidden)
            .map(|(o, h)| (o, h.as_deref()))
            .collect();
        // One pass over the batch (as on a GPU) against one per environment.
        let batched = forward(&policy, &inputs, &device).unwrap();
        assert_eq!(batched.len(), 3);
        let threaded = forward_batch(
            &policy,
            &inputs,
            &device,
            lockstep::Inference::PerEnvironment,
        )
        .unwrap();
        assert_eq!(threaded.len(), 3);
        let close = |a: f32, b: f32| (a == b) || (a - b).abs() < 1e-5;
        for (k, (input, together)) in inputs.iter().zip(&batched).enumerate() {
            let alone = forward(&policy, std::slice::from_ref(input), &device)
                .unwrap()
                .remove(0);
            assert_eq!(
                threaded[k].log_probs, alone.log_probs,
                "threads keep the order"
            );
            assert!(close(together.value, alone.value), "value of {k}");
            assert_eq!(together.log_probs[k], f32::NEG_INFINITY, "masked action");
            assert!(
                together
                    .log_probs
                    .iter()
                    .zip(&alone.log_probs)
                    .all(|(&a, &b)| close(a, b)),
                "log-probabilities of {k}: {:?} vs {:?}",
                together.log_probs,
                alone.log_probs
            );
            let (t, a) = (
                together.hidden.as_ref().unwrap(),
                alone.hidden.as_ref().unwrap(),
            );
            assert_eq!(t.len(), 8);
            assert!(t.iter().zip(a).all(|(&x, &y)| close(x, y)), "state of {k}");
        }
        // The recurrent state matters: another state, another output.
        assert!(batched[1].hidden != batched[2].hidden);
    }

    #[test]
    fn the_cpu_pass_acts_as_burns_pass_does() {
        let device = nets::device::open_device(nets::device::DeviceChoice::Cpu).unwrap();
        for gru_hidden in [None, Some(8)] {
            let layout = PolicyLayout {
                image_channels: vec![3, 2],
                image_size: 64,
                vector_dims: vec![5, 1],
                n_actions: 6,
                obs_dtype: ObsDtype::U8,
                gru_hidden,
            };
            let net = PolicyNet::new(&layout, &device);
            let cpu = CpuPolicy::from_network(&net, &layout);
            assert!(
                cpu.is_some(),
                "{gru_hidden:?}: the policy gets the CPU pass"
            );
            let policy = |cpu: Option<CpuPolicy>| Policy {
                net: net.clone(),
                cpu,
                layout: layout.clone(),
                policy_version: 1,
                unet_version: 0,
                env_steps: None,
            };
            let (with_cpu, burn_only) = (policy(cpu), policy(None));
            let observations: Vec<Observation> = (0..2)
                .map(|k| Observation {
                    features: (0..layout.obs_len())
                        .map(|i| ((i * 11 + k * 5) % 19) as f32 / 19.0)
                        .collect(),
                    action_mask: (0..6).map(|a| u8::from(a != 2 * k + 1)).collect(),
                })
                .collect();
            // An episode's start beside a running recurrent state.
            let running: Vec<f32> = (0..8).map(|i| i as f32 / 8.0 - 0.4).collect();
            let states = [None, gru_hidden.map(|_| running.as_slice())];
            let inputs: Vec<_> = observations.iter().zip(states).collect();
            let fast = forward(&with_cpu, &inputs, &device).unwrap();
            let reference = forward(&burn_only, &inputs, &device).unwrap();
            let close = |x: f32, y: f32| x == y || (x - y).abs() < 1e-5;
            for (k, (f, r)) in fast.iter().zip(&reference).enumerate() {
                assert_eq!(f.log_probs[2 * k + 1], f32::NEG_INFINITY, "masked action");
                assert!(close(f.value, r.value), "value of {k}");
                for (a, (&x, &y)) in f.log_probs.iter().zip(&r.log_probs).enumerate() {
                    assert!(close(x, y), "action {a} of {k}: {x} vs {y}");
                }
                match (&f.hidden, &r.hidden) {
                    (None, None) => assert!(gru_hidden.is_none()),
                    (Some(x), Some(y)) => {
                        assert_eq!(x.len(), 8);
                        assert!(x.iter().zip(y).all(|(&x, &y)| close(x, y)), "state of {k}");
                    }
                    _ => panic!("{gru_hidden:?}: one pass gave a state, the other not"),
                }
            }
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
