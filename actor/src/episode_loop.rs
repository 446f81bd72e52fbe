//! The actor's episode loop: act with the newest broadcast policy, send
//! rollout chunks, the episode's labelled frames and its stats, and pick up
//! new weights (policy, and the U-Net when its version changes) between steps.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{PoisonError, RwLock, RwLockReadGuard};
use std::time::{Duration, Instant};

use anyhow::{bail, ensure};
use burn::prelude::*;
use proto::{EpisodeStats, RolloutChunk, StatField};
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};
use transport::{ActorPorts, Delivery, TransportConfig};

use crate::env::affordance_model::AffordanceModel;
use crate::env::{Environment, EpisodeEnd, Observation, StepOutcome};
use crate::sampling::env_threads::PolicyPass;
use crate::sampling::Inference;

mod backoff;
mod chunks;
mod loop_clock;
mod policy;
mod rejected_weights;
mod running_episode;
mod scheduler;

use backoff::Backoff;
use chunks::{new_chunk, push_obs, restart_chunk, split_frames};
use policy::{
    choose, forward_batch, hidden_values, load_weights, step_of_thread_pass, Acted, LoadedWeights,
    Policy,
};
use rejected_weights::RejectedWeights;
use running_episode::{ChunkClose, RunningEpisode};

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
    /// Seconds spent waiting for the learner's U-Net to catch up
    /// ([`proto::WEIGHTS_META_HOLD`]).
    pub held_s: f64,
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

/// What the loop keeps between steps besides the environments.
struct Actor<'a> {
    ports: &'a mut ActorPorts,
    transport: &'a TransportConfig,
    settings: &'a LoopSettings,
    device: &'a Device,
    /// The U-Net, shared with the environments' threads, which read it
    /// while the loop may load new weights.
    model: &'a RwLock<Option<AffordanceModel>>,
    /// How the networks see the environments' inputs (suited to `device`).
    inference: Inference,
    policy: Policy,
    seed: u64,
    rng: SmallRng,
    summary: LoopSummary,
    /// Episodes started over all environments (their ids).
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
    /// drawn from the policy with this loop's random numbers, taking the
    /// policy's pass over an observation from `passes` where its
    /// environment's thread made one with the current policy; the others
    /// (passes of a policy that new weights replaced meanwhile, a few per
    /// update, or of a policy without the CPU's own pass) run here, one at
    /// a time: spread over rayon's threads they would compete with the
    /// environments' own.
    fn act(
        &mut self,
        inputs: &[(&Observation, Option<&[f32]>)],
        passes: Vec<Option<PolicyPass>>,
    ) -> anyhow::Result<Vec<Acted>> {
        ensure!(inputs.len() == passes.len(), "one pass or none per input");
        let uniforms: Vec<f32> = inputs.iter().map(|_| self.rng.random::<f32>()).collect();
        let mut steps = Vec::with_capacity(inputs.len());
        for (input, pass) in inputs.iter().zip(passes) {
            match pass.and_then(|pass| step_of_thread_pass(&self.policy, input.0, pass)) {
                Some(step) => steps.push(step),
                None => steps.extend(forward_batch(
                    &self.policy,
                    std::slice::from_ref(input),
                    self.device,
                    self.inference,
                )?),
            }
        }
        choose(steps, &uniforms)
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
        // The environments go on with the current U-Net while this loads
        // (a read lock, as theirs); they wait only for the swap below.
        let loaded = load_weights(
            self.ports,
            &message,
            &layout,
            self.read_model().as_ref(),
            self.device,
            Some(&self.policy),
        );
        match loaded {
            Ok(LoadedWeights { policy, unet }) => {
                if let Some(unet) = unet {
                    *self.model.write().unwrap_or_else(PoisonError::into_inner) = Some(unet);
                }
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

    /// Waits, stepping nothing, while the newest weights say that the
    /// learner's U-Net owes too many episodes ([`proto::WEIGHTS_META_HOLD`]),
    /// taking newer weights meanwhile; returns at once when `stop` is set.
    /// Gives the run's environment steps of the newest weights taken, if
    /// any. Called where every ended episode's frames have gone out, so the
    /// U-Net has what it needs to catch up.
    fn wait_while_held(&mut self, stop: &AtomicBool) -> anyhow::Result<Option<u64>> {
        let mut steps = None;
        if !self.policy.hold {
            return Ok(steps);
        }
        let started = Instant::now();
        if self.summary.held_s == 0.0 {
            tracing::info!(
                "actor {}: waiting for the learner's U-Net to catch up (its [unet] \
                 hold_actors_beyond_episodes; further waits are only counted)",
                self.settings.actor_id
            );
        }
        while self.policy.hold && !stop.load(Ordering::Relaxed) {
            std::thread::sleep(Duration::from_millis(10));
            steps = self.refresh_weights()?.or(steps);
        }
        self.summary.held_s += started.elapsed().as_secs_f64();
        Ok(steps)
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
            chunk: new_chunk(
                id,
                0,
                layout,
                hidden_values(layout, None),
                self.settings.chunk_steps,
            ),
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
        push_obs(chunk, &episode.observation);
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

    /// Sends the chunks of `episodes`, each closed as its [`ChunkClose`]
    /// says: those cut mid-episode whose bootstrap value is not known yet get
    /// the critic's value of their next observation, in one batch.
    fn close_chunks(
        &mut self,
        mut episodes: Vec<(&mut RunningEpisode, ChunkClose)>,
    ) -> anyhow::Result<()> {
        let values = {
            let inputs: Vec<_> = episodes
                .iter()
                .filter(|(_, close)| matches!(close, ChunkClose::Cut(None)))
                .map(|(e, _)| (&e.observation, e.hidden.as_deref()))
                .collect();
            if inputs.is_empty() {
                Vec::new()
            } else {
                forward_batch(&self.policy, &inputs, self.device, self.inference)?
            }
        };
        let mut values = values.into_iter();
        for (episode, close) in &mut episodes {
            episode.chunk.bootstrap_value = match *close {
                ChunkClose::EpisodeEnd => 0.0,
                ChunkClose::Cut(Some(value)) => value,
                ChunkClose::Cut(None) => values.next().map_or(0.0, |step| step.value),
            };
            self.publish_chunk(&episode.chunk)?;
            let start_hidden = hidden_values(&self.policy.layout, episode.hidden.as_deref());
            restart_chunk(&mut episode.chunk, episode.steps, start_hidden);
        }
        Ok(())
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
            for part in split_frames(&frames, self.transport.max_frames_bytes) {
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
        let stats = fitted(stats.with_tries(end.tries), self.transport.max_stats_bytes);
        let delivery = self.ports.publish(&stats, version, unet)?;
        self.count(delivery);
        self.summary.episodes += 1;
        Ok(())
    }
}

/// `stats` with as many of its tries by object type (the most tried) as
/// let it fit `max_bytes`: a transport configured below the largest stats
/// message costs the least tried types, never the episode's metrics.
fn fitted(mut stats: EpisodeStats, max_bytes: usize) -> EpisodeStats {
    let all = stats.tries().len();
    let mut kept = all;
    while kept > 0 && proto::encoded_len(&stats) > max_bytes {
        kept -= 1;
        stats.keep_most_tried(kept);
    }
    if kept < all {
        tracing::warn!(
            "an episode's stats exceed the transport's max_stats_bytes ({max_bytes}): sent {kept} of its {all} tries by object type; raise the limit to keep them all"
        );
    }
    stats
}

/// Runs episodes in every environment of `envs` until `stop` is set or
/// `max_episodes` are done, each environment on a thread of its own
/// ([`scheduler`]). `model` is the affordance U-Net for environments with a
/// camera (it takes the learner's new U-Nets); environments without one
/// need none.
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
    tracing::info!(
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
        match load_weights(ports, &first, &layout, model.as_ref(), device, None) {
            Ok(LoadedWeights { policy, unet }) => {
                if unet.is_some() {
                    model = unet;
                }
                break policy;
            }
            Err(error) => {
                rejected_weights.reject(settings.actor_id, &error, None);
            }
        }
    };
    let model = RwLock::new(model);
    tracing::info!(
        "actor {}: got policy version {}, U-Net version {}; {} environment(s)",
        settings.actor_id,
        policy.policy_version,
        policy.unet_version,
        envs.len()
    );
    let mut envs = envs;
    if let Some(steps) = policy.env_steps {
        for env in &mut envs {
            env.set_global_steps(steps);
        }
    }
    let seed = process_seed(settings.seed, policy.env_steps.unwrap_or(0));
    let mut actor = Actor {
        ports,
        transport,
        settings,
        device,
        inference: Inference::for_device(device),
        model: &model,
        policy,
        seed,
        rng: SmallRng::seed_from_u64(seed ^ (u64::from(settings.actor_id) << 32)),
        summary: LoopSummary::default(),
        started: 0,
        backoff: Backoff::default(),
        rejected_weights,
    };
    scheduler::run(&mut actor, envs, stop)?;
    Ok(actor.summary())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    use crate::env::BanditFixture;
    use nets::policy::PolicyNet;
    use proto::{decode, JoinKey, Limits, Message, MessageKind, WEIGHTS_POLICY_PREFIX};
    use transport::LearnerPorts;

    #[test]
    fn stats_too_large_for_the_transport_give_up_their_least_tried_types() {
        let tries = |name: &str, attempts| proto::TypeTries {
            affordance: proto::Affordance::PickUp,
            object_type: name.into(),
            attempts,
            successes: 0,
            objects: 1,
        };
        let stats = EpisodeStats::new(1, 100, 0)
            .with(StatField::EpisodeReturn, 2.0)
            .with_tries([tries("Chair", 4), tries("Drawer", 1), tries("Vase", 2)]);
        let whole = proto::encoded_len(&stats);
        assert_eq!(fitted(stats.clone(), whole), stats);
        // One record (20 bytes and a 4- or 8-byte name) too few.
        let two = fitted(stats.clone(), whole - 1);
        let names: Vec<_> = two.tries().iter().map(|t| t.object_type.as_str()).collect();
        assert_eq!(names, ["Chair", "Vase"]);
        let none = fitted(stats.clone(), 0);
        assert!(none.tries().is_empty());
        assert_eq!(none.get(StatField::EpisodeReturn), Some(2.0));
    }

    /// What the learner got of one rollout chunk.
    struct Received {
        first_step: u32,
        values: Vec<f32>,
        dones: Vec<u8>,
        bootstrap_value: f32,
    }

    /// Runs `envs` bandit environments through [`run`] for 4 episodes of
    /// 64 steps, in chunks of 5 steps, against a learner's ports in this
    /// process; returns the chunks the learner got, per episode in order.
    fn chunks_of_a_run(envs: usize) -> HashMap<u64, Vec<Received>> {
        let config = TransportConfig {
            service_prefix: format!("afx-loop-test-{}-{envs}", std::process::id()),
            max_actors: 1,
            learner_buffer: 256,
            max_rollout_bytes: 1 << 14,
            max_frames_bytes: 1 << 14,
            max_weights_bytes: 1 << 22,
            ..TransportConfig::default()
        };
        let key = JoinKey::from_bytes([5; proto::JOIN_KEY_LEN]);
        let mut learner = LearnerPorts::open(&config, key.clone()).unwrap();
        let device = nets::device::open_device(nets::device::DeviceChoice::Cpu).unwrap();
        let layout = BanditFixture::new().layout().clone();
        let policy = nets::weights::to_safetensors(&PolicyNet::new(&layout, &device)).unwrap();
        let blob =
            nets::weights::bundle(&[(WEIGHTS_POLICY_PREFIX, &policy)], HashMap::new()).unwrap();
        learner.publish_weights(1, 0, &blob).unwrap();
        let mut ports = ActorPorts::open(&config, 0, key).unwrap();
        learner.maintain();
        let settings = LoopSettings {
            actor_id: 0,
            chunk_steps: 5,
            seed: 3,
            max_episodes: Some(4),
            weights_timeout: Duration::from_secs(10),
        };
        let environments = (0..envs)
            .map(|_| Box::new(BanditFixture::new()) as Box<dyn Environment>)
            .collect();
        let stop = AtomicBool::new(false);
        let summary = run(
            environments,
            None,
            &mut ports,
            &config,
            &settings,
            &device,
            &stop,
        )
        .unwrap();
        assert_eq!((summary.episodes, summary.dropped), (4, 0));
        let limits = Limits {
            max_actors: 1,
            max_payload_len: 1 << 20,
        };
        let mut episodes: HashMap<u64, Vec<Received>> = HashMap::new();
        while let Some(message) = learner.receive(MessageKind::Rollout).unwrap() {
            let (_, Message::Rollout(view)) = decode(message.bytes(), &limits).unwrap() else {
                panic!("a rollout service message that is no rollout");
            };
            episodes.entry(view.episode_id).or_default().push(Received {
                first_step: view.first_step,
                values: view.values.to_vec(),
                dones: view.dones.to_vec(),
                bootstrap_value: view.bootstrap_value,
            });
        }
        for chunks in episodes.values_mut() {
            chunks.sort_by_key(|c| c.first_step);
        }
        episodes
    }

    /// A chunk cut mid-episode bootstraps from the critic's value of the
    /// episode's next observation, which the next chunk's first step carries
    /// as its value (one policy version throughout); an episode's last chunk
    /// bootstraps from nothing; with one environment and with two (the
    /// pass that chose the next action gives the value).
    #[test]
    fn a_cut_chunk_bootstraps_from_the_value_its_next_step_carries() {
        for envs in [1, 2] {
            let episodes = chunks_of_a_run(envs);
            assert_eq!(episodes.len(), 4, "{envs} environment(s)");
            for (id, chunks) in &episodes {
                let steps: usize = chunks.iter().map(|c| c.values.len()).sum();
                assert_eq!(steps, 64, "episode {id}: every step, once");
                for pair in chunks.windows(2) {
                    let (cut, next) = (&pair[0], &pair[1]);
                    assert_eq!(
                        next.first_step as usize,
                        cut.first_step as usize + cut.values.len()
                    );
                    assert!(
                        cut.dones.iter().all(|&d| d == 0),
                        "episode {id}: cut mid-episode"
                    );
                    assert_eq!(
                        cut.bootstrap_value, next.values[0],
                        "episode {id}, {envs} environment(s): the chunk from step {} bootstraps \
                         from its next step's value",
                        cut.first_step
                    );
                }
                let last = chunks.last().unwrap();
                assert_eq!(last.dones.last(), Some(&1));
                assert_eq!(last.bootstrap_value, 0.0);
            }
        }
    }

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
}
