//! The learner's receive loop: receive → validate → hand over → publish →
//! checkpoint. Training runs on two threads of its own, PPO
//! (`policy_worker`) and the U-Net (`unet_worker`), so that the loop keeps
//! taking messages while either updates.
//!
//! This file holds the loop and the learner's state; `dispatch` what one
//! message does (and the weights published back), `run_checkpoint` the
//! checkpoints written and restored.

use std::collections::HashSet;
use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::Context;
use proto::{decode, Join, JoinKey, Limits, Message, MessageKind};
use serde::{Deserialize, Serialize};
use transport::{Delivery, LearnerPorts};

use crate::checkpoint;
use crate::config::LearnerConfig;
use crate::history::History;
use crate::policy_worker::{PolicySnapshot, PolicyWorker, PublishedPolicy};
use crate::shared::Shared;
use crate::status::LearnerStatus;
use crate::unet_worker::{DeployedUnet, UnetWorker};
use crate::validation_scorer::ValidationScorer;
use training::affordance_learner::{checked_frames, AffordanceLearner, UnetTrainingState};
use training::optimizer_state::OptimizerState;
use training::ppo_batcher::PolicyTrainer;
use transport::membership::{Joined, Membership, Sender};

mod dispatch;
mod run_checkpoint;

pub use run_checkpoint::resume;

/// Counters saved in every checkpoint.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub(crate) struct Counters {
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
    /// The newest policy (safetensors and the version they are), broadcast
    /// under that version: the status's version may already be a newer
    /// update's, whose weights are still on their way.
    policy: PublishedPolicy,
    /// A checkpoint waits for the PPO thread's snapshot.
    checkpoint_requested: bool,
    /// The U-Net thread (tasks with a U-Net), started by `run`.
    unet_worker: Option<UnetWorker>,
    /// The deployed U-Net (weights, temperature, version), broadcast and
    /// checkpointed.
    unet: Option<DeployedUnet>,
    /// Whether the newest weights the actors got tell them to wait for the
    /// U-Net (`None` before the first delivered publish).
    hold_sent: Option<bool>,
    affordances: usize,
    /// Which publishers speak for which actor id.
    membership: Membership,
    warned: HashSet<(MessageKind, &'static str)>,
    last_checkpoint: Instant,
    updates_at_checkpoint: u64,
    /// Scores each checkpoint on the validation rooms, started by `run`
    /// (`None` when scoring is off).
    validation_scorer: Option<ValidationScorer>,
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
            .set_version(shared.status().counters.policy_version.max(1));
        let updates_at_checkpoint = shared.status().counters.updates;
        let affordances = shared.config.task.affordances.len();
        Self {
            shared,
            ports,
            policy_trainer: Some(trainers.policy),
            affordance: trainers.affordance,
            checkpoint_dir,
            history: Arc::new(Mutex::new(history)),
            policy_worker: None,
            policy: PublishedPolicy {
                version: 0,
                weights: Vec::new(),
            },
            checkpoint_requested: false,
            unet_worker: None,
            unet: None,
            hold_sent: None,
            affordances,
            membership: Membership::new(join_key),
            warned: HashSet::new(),
            last_checkpoint: Instant::now(),
            updates_at_checkpoint,
            validation_scorer: None,
        }
    }

    /// Runs until shutdown is requested, then writes a final checkpoint.
    pub fn run(mut self) -> anyhow::Result<()> {
        {
            let mut status = self.shared.status();
            status.counters.policy_version = status.counters.policy_version.max(1);
        }
        let trainer = self
            .policy_trainer
            .take()
            .context("the learner runs only once")?;
        self.policy = PublishedPolicy {
            version: trainer.version(),
            weights: trainer.weights().context("serialising the policy")?,
        };
        let policy = &self.shared.config.policy;
        self.policy_worker = Some(PolicyWorker::start(
            trainer,
            self.shared.clone(),
            self.history.clone(),
            policy.queue_batches.max(1) * policy.batch_steps.max(1),
        )?);
        if let Some(affordance) = self.affordance.take() {
            self.unet = Some(DeployedUnet {
                version: self.shared.status().counters.unet_version,
                weights: affordance
                    .deployed_weights()
                    .context("serialising the U-Net")?,
                temperature: affordance.temperature(),
            });
            self.unet_worker = Some(UnetWorker::start(
                affordance,
                self.shared.clone(),
                self.history.clone(),
                self.shared.config.unet.max_frames,
            )?);
        }
        self.validation_scorer = ValidationScorer::start(self.shared.clone(), self.history.clone());
        let result = self.serve();
        // A scoring in progress is killed: the learner stops now.
        if let Some(scorer) = self.validation_scorer.take() {
            scorer.stop();
        }
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
            if let Some(unet) = stopped.deployed {
                self.unet = Some(unet);
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

    /// Books each actor→learner service's publishers in the status, and says
    /// when a service's slots are all taken: an actor that is not running
    /// then cannot join (its supervisor retries) until a holder ends.
    fn note_publishers(&mut self) {
        let t = &self.shared.config.transport;
        let slots = (t.max_actors + t.spare_ports) as usize;
        let publishers: std::collections::BTreeMap<_, _> =
            self.ports.publishers().into_iter().collect();
        let full: Vec<&'static str> = publishers
            .iter()
            .filter(|&(_, &n)| n >= slots)
            .map(|(&service, _)| service)
            .collect();
        let mut status = self.shared.status();
        for service in &full {
            if !status.services_full.contains(service) {
                tracing::warn!(
                    service,
                    "every publisher slot of the service is taken ({slots} of {slots}: max_actors + \
                     spare_ports): an actor that is not running cannot join until a holder ends"
                );
            }
        }
        status.services_full = full;
        status.publishers = publishers;
    }

    /// The loop proper.
    fn serve(&mut self) -> anyhow::Result<()> {
        self.publish_weights()?;
        let mut last_maintenance = Instant::now();
        while !self.shared.shutdown.load(Ordering::Relaxed) {
            self.ports.wait(Duration::from_millis(100))?;
            let pass_started = Instant::now();
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
                    // write: screen the publisher and check the length before
                    // reading or copying a byte (a lying length would
                    // otherwise read past a stranger's segment, or allocate
                    // whatever it claims).
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
                    match self.membership.screen(kind, message.origin(), len) {
                        Err(reason) => self.refuse(kind, None, reason),
                        Ok(Sender::Member) => {
                            taken.push((message.origin(), message.bytes().to_vec()))
                        }
                        // A join (a few bytes) is handled at once, so that
                        // the joiner's next messages in this pass are screened
                        // as a member's.
                        Ok(Sender::Stranger) => {
                            self.handle(kind, message.origin(), message.bytes().to_vec())?
                        }
                    }
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
                self.policy = policy;
                self.publish_weights()?;
            }
            if let Some(unet) = self
                .unet_worker
                .as_ref()
                .and_then(UnetWorker::take_deployed)
            {
                self.unet = Some(unet);
                self.publish_weights()?;
            }
            // Actors learn that they must wait for the U-Net, or may go on,
            // only from weights: sent again when that changes (and until
            // delivered, or held actors would wait for ever).
            if self
                .hold_sent
                .is_some_and(|sent| sent != self.unet_owes_too_much())
            {
                self.publish_weights()?;
            }
            if last_maintenance.elapsed() > Duration::from_millis(250) {
                self.ports.maintain();
                self.note_publishers();
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
            self.shared
                .status()
                .add_receive_pass(pass_started.elapsed().as_secs_f64());
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
    /// Counts a message refused for who sent it (`reason`, a metrics
    /// label); warns the first time per service and reason.
    fn refuse(&mut self, kind: MessageKind, actor: Option<u32>, reason: &'static str) {
        self.shared.status().reject(kind, reason);
        if self.warned.insert((kind, reason)) {
            tracing::warn!(
                service = proto::service::for_kind(kind),
                actor,
                "refused a message ({reason}): only the publishers that joined as an actor id \
                 speak for it (further ones are only counted)"
            );
        }
    }

    fn reject(&mut self, kind: MessageKind, error: proto::ProtoError) {
        self.shared.status().reject(kind, error.reason());
        if self.warned.insert((kind, error.reason())) {
            tracing::warn!(service = proto::service::for_kind(kind), "rejected a malformed message: {error} (further ones of this kind are only counted)");
        }
    }
}

/// Asks the whole process to stop when dropped: the receive loop holds one,
/// so that its end, by error or by panic, ends the process too.
struct StopOnExit(Arc<Shared>);

impl Drop for StopOnExit {
    fn drop(&mut self) {
        self.0.shutdown.store(true, Ordering::Relaxed);
    }
}

/// Starts the learner on a thread of its own and returns once its
/// shared-memory services are open. iceoryx2 ports are not `Send`, so the
/// thread opens its own; the history goes into the run directory. The
/// thread sets `shutdown` when it ends, whatever the reason (a panic too).
pub fn spawn(
    shared: Arc<Shared>,
    trainers: Trainers,
    checkpoint_dir: PathBuf,
) -> anyhow::Result<std::thread::JoinHandle<anyhow::Result<()>>> {
    let key_file = shared.run_dir.join(transport::JOIN_KEY_FILE);
    let join_key = transport::load_or_create_join_key(&key_file).context(
        "preparing the run's join key (actors prove with it that they belong to the run; the \
         learner signs its weights with it)",
    )?;
    let (opened_tx, opened_rx) = std::sync::mpsc::channel();
    let thread = std::thread::Builder::new()
        .name("receive-loop".into())
        .spawn(move || {
            // However the loop ends, a panic included, the process stops:
            // the HTTP endpoint must not go on serving a run that no longer
            // trains.
            let _stop = StopOnExit(shared.clone());
            let ports = match LearnerPorts::open(&shared.config.transport, join_key.clone()) {
                Ok(ports) => ports,
                Err(e) => {
                    let _ = opened_tx.send(Err(e));
                    return Ok(());
                }
            };
            let _ = opened_tx.send(Ok(()));
            History::open(&shared.run_dir).and_then(|history| {
                Learner::new(
                    shared.clone(),
                    ports,
                    trainers,
                    checkpoint_dir,
                    history,
                    join_key,
                )
                .run()
            })
        })
        .context("starting the learner thread")?;
    opened_rx
        .recv()
        .context("the learner thread died while opening the shared-memory services")?
        .context("opening the shared-memory services (is another learner running with the same service prefix?)")?;
    Ok(thread)
}
