//! The learner's receive loop: receive → validate → hand over → publish →
//! checkpoint. Training runs on two threads of its own, PPO
//! (`policy_worker`) and the U-Net (`unet_worker`), so that the loop keeps
//! taking messages while either updates.

use std::collections::HashSet;
use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::Context;
use proto::{decode, Join, JoinKey, Limits, Message, MessageKind};
use serde::{Deserialize, Serialize};
use transport::{Delivery, LearnerPorts};

use crate::affordance::{checked_frames, AffordanceLearner, UnetTrainingState};
use crate::checkpoint;
use crate::config::LearnerConfig;
use crate::history::History;
use crate::membership::{Joined, Membership};
use crate::policy_worker::{PolicySnapshot, PolicyWorker};
use crate::shared::Shared;
use crate::status::LearnerStatus;
use crate::train::PolicyTrainer;
use crate::unet_worker::UnetWorker;
use training::optimizer_state::OptimizerState;

/// Counters saved in every checkpoint.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct Counters {
    /// Run id.
    pub run_id: String,
    /// Environment steps trained on.
    pub env_steps: u64,
    /// Policy updates done.
    pub updates: u64,
    /// Episodes reported.
    pub episodes: u64,
    /// Policy version.
    pub policy_version: u64,
    /// U-Net version.
    pub unet_version: u64,
}

/// What the learner trains: the policy, and the U-Net when the task has one.
pub struct Trainers {
    /// PPO on the policy network.
    pub policy: PolicyTrainer,
    /// U-Net training on labelled frames (`None` for the bandit fixture).
    pub affordance: Option<AffordanceLearner>,
}

impl Trainers {
    /// Fresh networks for the configured task, the U-Net on `device` and
    /// the policy on `policy_device`, initialised from the run's seed
    /// (`[policy] seed`): runs with the same seed start from the same
    /// weights, runs with different seeds from different ones.
    pub fn new(
        config: &LearnerConfig,
        device: &burn::prelude::Device,
        policy_device: &burn::prelude::Device,
    ) -> Self {
        device.seed(config.policy.seed);
        if policy_device != device {
            policy_device.seed(config.policy.seed);
        }
        let affordance = (config.task.env == proto::EnvKind::Sim).then(|| {
            AffordanceLearner::new(
                config.task.affordances.len(),
                &config.unet,
                config.policy.seed,
                device,
            )
        });
        Self {
            policy: PolicyTrainer::new(&config.task, &config.policy, policy_device),
            affordance,
        }
    }
}

/// The receive loop and what it owns. Training runs on two threads of its
/// own (PPO and the U-Net), so that receiving never waits for an update.
pub struct Learner {
    shared: Arc<Shared>,
    ports: LearnerPorts,
    /// The policy's trainer until `run` hands it to the PPO thread.
    policy_trainer: Option<PolicyTrainer>,
    /// The U-Net's learner until `run` hands it to the U-Net thread.
    affordance: Option<AffordanceLearner>,
    checkpoint_dir: PathBuf,
    history: Arc<Mutex<History>>,
    /// The PPO thread, started by `run`.
    policy_worker: Option<PolicyWorker>,
    /// The newest policy's weights (safetensors), broadcast and checkpointed.
    policy_weights: Vec<u8>,
    /// A checkpoint waits for the PPO thread's snapshot.
    checkpoint_requested: bool,
    /// The U-Net thread (tasks with a U-Net), started by `run`.
    unet_worker: Option<UnetWorker>,
    /// The deployed U-Net's weights and temperature, broadcast and checkpointed.
    unet_weights: Option<(Vec<u8>, f32)>,
    affordances: usize,
    /// Which publishers speak for which actor id.
    membership: Membership,
    warned: HashSet<(MessageKind, &'static str)>,
    last_checkpoint: Instant,
    updates_at_checkpoint: u64,
}

impl Learner {
    /// Builds the loop over open ports and a (possibly restored) trainer;
    /// actors join with `join_key`.
    pub fn new(
        shared: Arc<Shared>,
        ports: LearnerPorts,
        mut trainers: Trainers,
        checkpoint_dir: PathBuf,
        history: History,
        join_key: JoinKey,
    ) -> Self {
        trainers
            .policy
            .set_version(shared.status().policy_version.max(1));
        let updates_at_checkpoint = shared.status().updates;
        let affordances = shared.config.task.affordances.len();
        Self {
            shared,
            ports,
            policy_trainer: Some(trainers.policy),
            affordance: trainers.affordance,
            checkpoint_dir,
            history: Arc::new(Mutex::new(history)),
            policy_worker: None,
            policy_weights: Vec::new(),
            checkpoint_requested: false,
            unet_worker: None,
            unet_weights: None,
            affordances,
            membership: Membership::new(join_key),
            warned: HashSet::new(),
            last_checkpoint: Instant::now(),
            updates_at_checkpoint,
        }
    }

    /// Runs until shutdown is requested, then writes a final checkpoint.
    pub fn run(mut self) -> anyhow::Result<()> {
        {
            let mut status = self.shared.status();
            status.policy_version = status.policy_version.max(1);
        }
        let trainer = self
            .policy_trainer
            .take()
            .context("the learner runs only once")?;
        self.policy_weights = trainer.weights().context("serialising the policy")?;
        let policy = &self.shared.config.policy;
        self.policy_worker = Some(PolicyWorker::start(
            trainer,
            self.shared.clone(),
            self.history.clone(),
            policy.queue_batches.max(1) * policy.batch_steps.max(1),
        )?);
        if let Some(affordance) = self.affordance.take() {
            self.unet_weights = Some((
                affordance
                    .deployed_weights()
                    .context("serialising the U-Net")?,
                affordance.temperature(),
            ));
            self.unet_worker = Some(UnetWorker::start(
                affordance,
                self.shared.clone(),
                self.history.clone(),
                self.shared.config.unet.max_frames,
            )?);
        }
        let result = self.serve();
        // Both training threads stop first (after their current update or
        // round), so the final checkpoint holds their last state. Should a
        // thread have failed, the checkpoint is still written, with the state
        // it left after its last good round, and the failure reported after.
        let policy = self.policy_worker.take().map(PolicyWorker::stop);
        let (policy, policy_failure) = match policy {
            Some(Ok(snapshot)) => (Some(snapshot), None),
            Some(Err(e)) => (None, Some(e)),
            None => (None, None),
        };
        let (mut unet_training, mut unet_failure) = (None, None);
        if let Some(worker) = self.unet_worker.take() {
            tracing::info!("stopping the U-Net thread after its current round");
            let (stopped, outcome) = worker.stop();
            if let Some(weights) = stopped.deployed {
                self.unet_weights = Some(weights);
            }
            unet_training = stopped.training;
            unet_failure = outcome.err();
            if result.is_ok() && !self.shared.shutdown.load(Ordering::Relaxed) {
                unet_failure.get_or_insert_with(|| {
                    anyhow::anyhow!("the U-Net training thread ended unexpectedly")
                });
            }
        }
        result?;
        let Some(policy) = policy else {
            return Err(policy_failure
                .unwrap_or_else(|| anyhow::anyhow!("the PPO thread never started"))
                .context("the PPO training thread failed; no final checkpoint"));
        };
        tracing::info!("shutting down: writing a final checkpoint");
        self.write_checkpoint(&policy, unet_training.as_ref())?;
        unet_failure.map_or(Ok(()), Err)
    }

    /// The loop proper.
    fn serve(&mut self) -> anyhow::Result<()> {
        self.publish_weights()?;
        let mut last_maintenance = Instant::now();
        while !self.shared.shutdown.load(Ordering::Relaxed) {
            self.ports.wait(Duration::from_millis(100))?;
            // Per kind, first take what is queued (at most one buffer's worth
            // per sender, so a fast stream cannot starve stats, frames or
            // checkpoints), then handle it. Taking before handling matters:
            // the subscriber serves its senders in a fixed order, and while a
            // message was handled a fast actor refilled its queue, so the
            // others' queues were never reached.
            let t = &self.shared.config.transport;
            let per_pass = t.learner_buffer.max(1) * (t.max_actors + t.spare_ports).max(1) as usize;
            for kind in [
                MessageKind::Stats,
                MessageKind::Frames,
                MessageKind::Rollout,
            ] {
                let mut taken = Vec::new();
                let max_bytes = self.shared.config.transport.max_bytes(kind);
                for _ in 0..per_pass {
                    let Some(message) = self.ports.receive(kind)? else {
                        break;
                    };
                    // The length comes from shared memory any process may
                    // write: check it before copying a byte (a lying length
                    // would otherwise allocate whatever it claims).
                    let len = message.bytes().len();
                    if len > max_bytes {
                        self.reject(
                            kind,
                            proto::ProtoError::PayloadTooLarge {
                                len: len as u64,
                                limit: max_bytes as u64,
                            },
                        );
                        continue;
                    }
                    taken.push((message.origin(), message.bytes().to_vec()));
                }
                for (origin, bytes) in taken {
                    self.handle(kind, origin, bytes)?;
                }
            }
            let published = self
                .policy_worker
                .as_ref()
                .and_then(PolicyWorker::take_published);
            if let Some(policy) = published {
                self.policy_weights = policy.weights;
                self.publish_weights()?;
            }
            if let Some(weights) = self
                .unet_worker
                .as_ref()
                .and_then(UnetWorker::take_deployed)
            {
                self.unet_weights = Some(weights);
                self.publish_weights()?;
            }
            if last_maintenance.elapsed() > Duration::from_millis(250) {
                self.ports.maintain();
                self.shared.status().publishers = self.ports.publishers().into_iter().collect();
                last_maintenance = Instant::now();
            }
            if self.unet_worker.as_ref().is_some_and(UnetWorker::finished) {
                tracing::error!("the U-Net training thread stopped; shutting down");
                break;
            }
            if self
                .policy_worker
                .as_ref()
                .is_some_and(PolicyWorker::finished)
            {
                tracing::error!("the PPO training thread stopped; shutting down");
                break;
            }
            if !self.checkpoint_requested && self.checkpoint_due() {
                if let Some(worker) = &self.policy_worker {
                    worker.request_snapshot();
                    self.checkpoint_requested = true;
                }
            }
            let snapshot = self
                .policy_worker
                .as_ref()
                .filter(|_| self.checkpoint_requested)
                .and_then(PolicyWorker::take_snapshot);
            if let Some(policy) = snapshot {
                self.checkpoint_requested = false;
                let unet_training = self
                    .unet_worker
                    .as_ref()
                    .and_then(UnetWorker::training_state);
                self.write_checkpoint(&policy, unet_training.as_ref())?;
            }
        }
        Ok(())
    }

    fn limits(&self, kind: MessageKind) -> Limits {
        let t = &self.shared.config.transport;
        Limits {
            max_actors: t.max_actors,
            max_payload_len: t.max_bytes(kind) as u64,
        }
    }

    /// Counts a malformed message of `kind`, warning once per reason.
    fn reject(&mut self, kind: MessageKind, error: proto::ProtoError) {
        self.shared.status().reject(kind, error.reason());
        if self.warned.insert((kind, error.reason())) {
            tracing::warn!(service = proto::service::for_kind(kind), "rejected a malformed message: {error} (further ones of this kind are only counted)");
        }
    }

    /// Validates a message of the service that carries `kind`, which came
    /// through the publisher `origin`, and uses it.
    fn handle(&mut self, kind: MessageKind, origin: u128, bytes: Vec<u8>) -> anyhow::Result<()> {
        let decoded = decode(&bytes, &self.limits(kind)).and_then(|(header, message)| {
            if proto::service::for_kind(message.kind()) == proto::service::for_kind(kind) {
                Ok((header, message))
            } else {
                Err(proto::ProtoError::WrongKind {
                    expected: kind,
                    got: message.kind(),
                })
            }
        });
        let (header, message) = match decoded {
            Ok(ok) => ok,
            Err(error) => {
                self.reject(kind, error);
                return Ok(());
            }
        };
        if let Message::Join(join) = &message {
            self.join(header.actor_id, join, origin);
            return Ok(());
        }
        if let Err(reason) = self.membership.admit(header.actor_id, kind, origin) {
            self.shared.status().reject(kind, reason);
            if self.warned.insert((kind, reason)) {
                tracing::warn!(
                    service = proto::service::for_kind(kind),
                    actor = header.actor_id,
                    "refused a message ({reason}): only the publishers that joined as an actor id \
                     speak for it (further ones are only counted)"
                );
            }
            return Ok(());
        }
        let accepted = self.shared.status().accept(
            header.actor_id,
            kind,
            header.sequence,
            header.policy_version,
        );
        let Some(lost) = accepted else {
            const REASON: &str = "sequence_out_of_window";
            self.shared.status().reject(kind, REASON);
            if self.warned.insert((kind, REASON)) {
                tracing::warn!(
                    service = proto::service::for_kind(kind),
                    actor = header.actor_id,
                    sequence = header.sequence,
                    "refused a message whose sequence number no loss explains (further ones are only counted)"
                );
            }
            return Ok(());
        };
        if lost > 0 {
            tracing::debug!(
                actor = header.actor_id,
                kind = kind.as_str(),
                lost,
                "messages lost in transit"
            );
        }
        let mut rollout_steps = None;
        match message {
            Message::Rollout(chunk) => {
                let steps = chunk.n_steps();
                self.shared
                    .status()
                    .add_steps(header.actor_id, steps as u64);
                rollout_steps = Some(steps);
            }
            Message::Stats(stats) => {
                let env_steps = {
                    let mut status = self.shared.status();
                    status.add_episode(&stats);
                    status.env_steps
                };
                let fields: serde_json::Map<String, serde_json::Value> = stats
                    .present()
                    .map(|(f, v)| (f.as_str().to_string(), serde_json::json!(v)))
                    .collect();
                self.history
                    .lock()
                    .unwrap_or_else(|p| p.into_inner())
                    .record(
                        "episode",
                        env_steps,
                        serde_json::json!({
                            "actor": header.actor_id,
                            "episode": stats.episode_id,
                            "steps": stats.steps,
                            "scene": stats.scene_index,
                            "stats": fields,
                        }),
                    )?;
            }
            Message::Frames(frames) => {
                let Some(worker) = self.unet_worker.as_ref() else {
                    return Ok(());
                };
                let episode = (u64::from(header.actor_id) << 40) | frames.episode_id;
                match checked_frames(
                    &frames,
                    self.affordances,
                    self.shared.config.task.image_size,
                ) {
                    Ok(batch) => {
                        let n = batch.len() as u64;
                        if worker.offer(episode, batch) {
                            self.shared.status().frames_received += n;
                        } else {
                            self.shared.status().frames_skipped += n;
                            if self.warned.insert((kind, "unet busy")) {
                                tracing::warn!("the U-Net trainer is behind: skipping episodes' frames until it catches up (further skips are only counted in frames_skipped)");
                            }
                        }
                    }
                    Err(error) => {
                        self.shared.status().untrainable_chunks += 1;
                        if self.warned.insert((kind, "untrainable")) {
                            tracing::warn!("actor {}: {error}", header.actor_id);
                        }
                    }
                }
            }
            Message::Weights(_) | Message::Join(_) => {}
        }
        // The message's views borrow `bytes` until here; the PPO thread
        // decodes its own (moved, not copied) bytes.
        if let (Some(steps), Some(worker)) = (rollout_steps, &self.policy_worker) {
            let discarded = worker.offer(bytes, steps);
            let queued = worker.queued_steps();
            let mut status = self.shared.status();
            status.rollout_steps_discarded += discarded as u64;
            status.rollout_steps_queued = queued as u64;
            if discarded > 0 && self.warned.insert((kind, "ppo behind")) {
                tracing::warn!("PPO is behind the actors: discarding the oldest queued rollout steps (further ones are only counted in rollout_steps_discarded)");
            }
        }
        Ok(())
    }

    /// Records an actor's join, or counts why it is refused.
    fn join(&mut self, actor_id: u32, join: &Join, origin: u128) {
        match self.membership.join(actor_id, join, origin) {
            Ok(Joined::New) => tracing::info!(actor = actor_id, "actor joined"),
            Ok(Joined::Again) => {
                tracing::info!(
                    actor = actor_id,
                    "actor joined again from new publishers (restarted)"
                )
            }
            Ok(Joined::Unchanged) => {}
            Err(reason) => {
                self.shared.status().reject(MessageKind::Join, reason);
                if self.warned.insert((MessageKind::Join, reason)) {
                    tracing::warn!(
                        actor = actor_id,
                        "refused a join ({reason}): a join must carry a proof made with the run's \
                         join key and come through the stats publisher it names (further ones are \
                         only counted)"
                    );
                }
            }
        }
    }

    fn publish_weights(&mut self) -> anyhow::Result<()> {
        let (policy_version, unet_version) = {
            let status = self.shared.status();
            (status.policy_version, status.unet_version)
        };
        let blob = self.weights_blob(&self.policy_weights)?;
        match self
            .ports
            .publish_weights(policy_version, unet_version, &blob)?
        {
            Delivery::Delivered(_) => self.shared.status().weights_published += 1,
            Delivery::Dropped => tracing::debug!(
                policy_version,
                "weights pool busy; the next publish carries newer weights"
            ),
        }
        Ok(())
    }

    /// Both networks in one safetensors blob, names prefixed `policy.` and
    /// `unet.`: `policy` (safetensors bytes) and the deployed U-Net.
    fn weights_blob(&self, policy: &[u8]) -> anyhow::Result<Vec<u8>> {
        let mut parts: Vec<(&str, &[u8])> = vec![(proto::WEIGHTS_POLICY_PREFIX, policy)];
        let mut metadata = std::collections::HashMap::from([(
            proto::WEIGHTS_META_ENV_STEPS.to_string(),
            self.shared.status().env_steps.to_string(),
        )]);
        if let Some((unet, temperature)) = &self.unet_weights {
            parts.push((proto::WEIGHTS_UNET_PREFIX, unet));
            metadata.insert(
                proto::WEIGHTS_META_TEMPERATURE.to_string(),
                temperature.to_string(),
            );
        }
        nets::weights::bundle(&parts, metadata).context("bundling the weights")
    }

    fn checkpoint_due(&self) -> bool {
        let config = &self.shared.config;
        let updates = self.shared.status().updates;
        if updates == self.updates_at_checkpoint {
            return false;
        }
        let by_count = config.checkpoint_every_updates > 0
            && updates - self.updates_at_checkpoint >= config.checkpoint_every_updates;
        let by_time = config.checkpoint_interval_s > 0.0
            && self.last_checkpoint.elapsed().as_secs_f64() >= config.checkpoint_interval_s;
        by_count || by_time
    }

    /// Writes a checkpoint of both trainers: `policy` is the PPO thread's
    /// snapshot, `unet_training` the U-Net thread's state, when the task
    /// has a U-Net.
    fn write_checkpoint(
        &mut self,
        policy: &PolicySnapshot,
        unet_training: Option<&UnetTrainingState>,
    ) -> anyhow::Result<()> {
        let counters = {
            let status = self.shared.status();
            Counters {
                run_id: status.run_id.clone(),
                env_steps: status.env_steps,
                updates: policy.updates,
                episodes: status.episodes,
                policy_version: policy.version,
                unet_version: status.unet_version,
            }
        };
        // The snapshot's weights: the broadcast may already be newer.
        let weights = self.weights_blob(&policy.weights)?;
        let counters_json = serde_json::to_vec_pretty(&counters)?;
        let adam = &policy.optimizer;
        let adam_parameters = adam.parameter_list_json();
        let mut files: Vec<(&str, &[u8])> = vec![
            ("weights.safetensors", &weights),
            ("counters.json", &counters_json),
            (POLICY_OPTIMIZER_RECORD, &adam.record),
            (POLICY_OPTIMIZER_PARAMETERS, &adam_parameters),
        ];
        let unet_parameters;
        if let Some(unet) = unet_training {
            unet_parameters = unet.optimizer.parameter_list_json();
            files.extend([
                (UNET_CANDIDATE, &unet.candidate[..]),
                (UNET_OPTIMIZER_RECORD, &unet.optimizer.record[..]),
                (UNET_OPTIMIZER_PARAMETERS, &unet_parameters[..]),
            ]);
        }
        let dir = checkpoint::write(
            &self.checkpoint_dir,
            counters.env_steps,
            &files,
            self.shared.config.keep_checkpoints,
        )
        .context("writing a checkpoint (is the disk full?)")?;
        self.last_checkpoint = Instant::now();
        self.updates_at_checkpoint = counters.updates;
        let mut status = self.shared.status();
        status.checkpoints_written += 1;
        status.last_checkpoint_step = Some(counters.env_steps);
        tracing::info!(dir = %dir.display(), updates = counters.updates, "checkpoint written");
        Ok(())
    }
}

/// Starts the learner on a thread of its own and returns once its
/// shared-memory services are open. iceoryx2 ports are not `Send`, so the
/// thread opens its own; the history goes into the run directory. The
/// thread sets `shutdown` when it ends, whatever the reason.
pub fn spawn(
    shared: Arc<Shared>,
    trainers: Trainers,
    checkpoint_dir: PathBuf,
) -> anyhow::Result<std::thread::JoinHandle<anyhow::Result<()>>> {
    let key_file = shared.run_dir.join(transport::JOIN_KEY_FILE);
    let join_key = transport::load_or_create_join_key(&key_file).context(
        "preparing the run's join key (actors prove with it that they belong to the run)",
    )?;
    let (opened_tx, opened_rx) = std::sync::mpsc::channel();
    let thread = std::thread::Builder::new()
        .name("learner".into())
        .spawn(move || {
            let ports = match LearnerPorts::open(&shared.config.transport) {
                Ok(ports) => ports,
                Err(e) => {
                    let _ = opened_tx.send(Err(e));
                    return Ok(());
                }
            };
            let _ = opened_tx.send(Ok(()));
            let result = History::open(&shared.run_dir).and_then(|history| {
                Learner::new(
                    shared.clone(),
                    ports,
                    trainers,
                    checkpoint_dir,
                    history,
                    join_key,
                )
                .run()
            });
            shared.shutdown.store(true, Ordering::Relaxed);
            result
        })
        .context("starting the learner thread")?;
    opened_rx
        .recv()
        .context("the learner thread died while opening the shared-memory services")?
        .context("opening the shared-memory services (is another learner running with the same service prefix?)")?;
    Ok(thread)
}

/// Checkpoint file with the policy optimiser's record (burnpack).
const POLICY_OPTIMIZER_RECORD: &str = "policy_optimizer.bpk";
/// Checkpoint file naming the parameters that record refers to (JSON).
const POLICY_OPTIMIZER_PARAMETERS: &str = "policy_optimizer_parameters.json";
/// Checkpoint file: the U-Net in training (not yet through the validation gate).
const UNET_CANDIDATE: &str = "unet_candidate.safetensors";
/// Checkpoint file: the U-Net's Adam state (burn's record).
const UNET_OPTIMIZER_RECORD: &str = "unet_optimizer.bpk";
/// Checkpoint file: module path → id and shape of the U-Net's parameters.
const UNET_OPTIMIZER_PARAMETERS: &str = "unet_optimizer_parameters.json";

/// Restores trainer and counters from the newest checkpoint that verifies.
pub fn resume(
    checkpoint_dir: &std::path::Path,
    trainers: &mut Trainers,
    status: &mut LearnerStatus,
) -> anyhow::Result<()> {
    let Some(loaded) = checkpoint::load_newest_valid(checkpoint_dir)? else {
        anyhow::bail!(
            "no checkpoint under {}: nothing to resume (start without --resume for a new run)",
            checkpoint_dir.display()
        );
    };
    for (dir, reason) in &loaded.skipped {
        tracing::warn!(
            "skipping damaged checkpoint {}: {reason}; falling back to an older one",
            dir.display()
        );
    }
    let file = |name: &str| {
        loaded
            .files
            .get(name)
            .with_context(|| format!("checkpoint {} lacks {name}", loaded.dir.display()))
    };
    let counters: Counters =
        serde_json::from_slice(file("counters.json")?).context("parsing counters.json")?;
    let weights = file("weights.safetensors")?;
    let restore = |prefix: &str| {
        nets::weights::unbundle(weights, prefix).with_context(|| {
            format!(
                "reading the {prefix}* weights of {} (does the [task] config match the run's?)",
                loaded.dir.display()
            )
        })
    };
    let optimizer_state = |record: &str, parameters: &str| -> anyhow::Result<_> {
        match (loaded.files.get(record), loaded.files.get(parameters)) {
            (Some(r), Some(p)) => Ok(Some(
                OptimizerState::from_parts(r.clone(), p)
                    .with_context(|| format!("reading {parameters} of {}", loaded.dir.display()))?,
            )),
            _ => Ok(None),
        }
    };
    let optimizer = optimizer_state(POLICY_OPTIMIZER_RECORD, POLICY_OPTIMIZER_PARAMETERS)?;
    if optimizer.is_none() {
        tracing::warn!(
            "checkpoint {} holds no optimiser state (written by an older learner); \
             the policy's Adam starts afresh",
            loaded.dir.display()
        );
    }
    trainers
        .policy
        .restore(
            restore(proto::WEIGHTS_POLICY_PREFIX)?,
            counters.policy_version,
            optimizer.as_ref(),
        )
        .with_context(|| {
            format!(
                "loading the policy from {} (does the [task] config match the run's?)",
                loaded.dir.display()
            )
        })?;
    let mut unet_training = "none (no U-Net in this task)";
    if let Some(affordance) = trainers.affordance.as_mut() {
        let temperature = nets::weights::metadata(weights)
            .ok()
            .and_then(|m| m.get(proto::WEIGHTS_META_TEMPERATURE)?.parse().ok())
            .unwrap_or(1.0);
        affordance
            .restore(restore(proto::WEIGHTS_UNET_PREFIX)?, temperature)
            .with_context(|| format!("loading the U-Net from {}", loaded.dir.display()))?;
        let optimizer = optimizer_state(UNET_OPTIMIZER_RECORD, UNET_OPTIMIZER_PARAMETERS)?;
        match (loaded.files.get(UNET_CANDIDATE), optimizer) {
            (Some(candidate), Some(optimizer)) => {
                let state = UnetTrainingState {
                    candidate: candidate.clone(),
                    optimizer,
                };
                affordance.restore_training(&state).with_context(|| {
                    format!(
                        "loading the U-Net in training from {} (does the [task] config match the run's?)",
                        loaded.dir.display()
                    )
                })?;
                unet_training = "state restored";
            }
            _ => {
                tracing::warn!(
                    "checkpoint {} holds no U-Net training state (written by an older learner); \
                     U-Net training restarts from the deployed network with a fresh Adam",
                    loaded.dir.display()
                );
                unet_training = "afresh from the deployed network";
            }
        }
    }
    status.env_steps = counters.env_steps;
    status.updates = counters.updates;
    status.episodes = counters.episodes;
    status.policy_version = counters.policy_version;
    status.unet_version = counters.unet_version;
    status.last_checkpoint_step = Some(loaded.step);
    tracing::info!(
        "resumed from checkpoint {} (env steps {}, updates {}, policy version {}, policy optimiser {}, U-Net training {})",
        loaded.dir.display(),
        counters.env_steps,
        counters.updates,
        counters.policy_version,
        if optimizer.is_some() { "state restored" } else { "afresh" },
        unet_training
    );
    Ok(())
}
