//! The learner's main loop: receive → validate → train → publish → checkpoint.

use std::collections::HashSet;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use anyhow::Context;
use proto::{decode, Limits, Message, MessageKind};
use serde::{Deserialize, Serialize};
use transport::{Delivery, LearnerPorts};

use crate::checkpoint;
use crate::config::LearnerConfig;
use crate::status::LearnerStatus;
use crate::train::Trainer;

/// State shared between the training loop and the HTTP edge.
pub struct Shared {
    /// The live status.
    pub status: Mutex<LearnerStatus>,
    /// Set on SIGINT/SIGTERM; the loop checkpoints and returns.
    pub shutdown: AtomicBool,
    /// The resolved configuration.
    pub config: LearnerConfig,
}

impl Shared {
    /// Locks the status; a poisoned lock (a panicked thread) still yields the data.
    pub fn status(&self) -> MutexGuard<'_, LearnerStatus> {
        self.status
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
    }
}

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
    /// Adam steps taken.
    pub adam_steps: u64,
}

/// The training loop and what it owns.
pub struct Learner {
    shared: Arc<Shared>,
    ports: LearnerPorts,
    trainer: Trainer,
    checkpoint_dir: PathBuf,
    warned: HashSet<(MessageKind, &'static str)>,
    last_checkpoint: Instant,
    updates_at_checkpoint: u64,
}

impl Learner {
    /// Builds the loop over open ports and a (possibly restored) trainer.
    pub fn new(
        shared: Arc<Shared>,
        ports: LearnerPorts,
        trainer: Trainer,
        checkpoint_dir: PathBuf,
    ) -> Self {
        let updates_at_checkpoint = shared.status().updates;
        Self {
            shared,
            ports,
            trainer,
            checkpoint_dir,
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
        self.publish_weights()?;
        let mut last_maintenance = Instant::now();
        while !self.shared.shutdown.load(Ordering::Relaxed) {
            self.ports.wait(Duration::from_millis(100))?;
            for kind in [
                MessageKind::Stats,
                MessageKind::Frames,
                MessageKind::Rollout,
            ] {
                while let Some(message) = self.ports.receive(kind)? {
                    self.handle(kind, message.bytes())?;
                }
            }
            if last_maintenance.elapsed() > Duration::from_millis(250) {
                self.ports.maintain();
                last_maintenance = Instant::now();
            }
            if self.checkpoint_due() {
                self.write_checkpoint()?;
            }
        }
        tracing::info!("shutting down: writing a final checkpoint");
        self.write_checkpoint()
    }

    fn limits(&self, kind: MessageKind) -> Limits {
        let t = &self.shared.config.transport;
        Limits {
            max_actors: t.max_actors,
            max_payload_len: t.max_bytes(kind) as u64,
        }
    }

    fn handle(&mut self, kind: MessageKind, bytes: &[u8]) -> anyhow::Result<()> {
        let decoded = decode(bytes, &self.limits(kind)).and_then(|(header, message)| {
            if message.kind() == kind {
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
                self.shared.status().reject(kind, error.reason());
                if self.warned.insert((kind, error.reason())) {
                    tracing::warn!(service = proto::service::for_kind(kind), "rejected a malformed message: {error} (further ones of this kind are only counted)");
                }
                return Ok(());
            }
        };
        let lost = self.shared.status().accept(
            header.actor_id,
            kind,
            header.sequence,
            header.policy_version,
        );
        if lost > 0 {
            tracing::debug!(
                actor = header.actor_id,
                kind = kind.as_str(),
                lost,
                "messages lost in transit"
            );
        }
        match message {
            Message::Rollout(chunk) => match self.trainer.update(&chunk) {
                Ok(stats) => {
                    let publish = {
                        let mut status = self.shared.status();
                        status.add_steps(header.actor_id, chunk.n_steps() as u64);
                        status.updates += 1;
                        status.last_update = Some(stats);
                        status
                            .updates
                            .is_multiple_of(self.shared.config.policy.publish_every_updates)
                    };
                    if publish {
                        self.shared.status().policy_version += 1;
                        self.publish_weights()?;
                    }
                }
                Err(error) => {
                    self.shared.status().untrainable_chunks += 1;
                    if self.warned.insert((kind, "untrainable")) {
                        tracing::warn!("actor {}: {error}", header.actor_id);
                    }
                }
            },
            Message::Stats(stats) => self.shared.status().add_episode(&stats),
            // Labelled frames are validated and counted; the U-Net trains on them
            // once the affordance learner is part of the loop.
            Message::Frames(_) | Message::Weights(_) => {}
        }
        Ok(())
    }

    fn publish_weights(&mut self) -> anyhow::Result<()> {
        let (policy_version, unet_version) = {
            let status = self.shared.status();
            (status.policy_version, status.unet_version)
        };
        let blob = self.trainer.net.to_tensors().to_safetensors();
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

    fn write_checkpoint(&mut self) -> anyhow::Result<()> {
        let counters = {
            let status = self.shared.status();
            Counters {
                run_id: status.run_id.clone(),
                env_steps: status.env_steps,
                updates: status.updates,
                episodes: status.episodes,
                policy_version: status.policy_version,
                unet_version: status.unet_version,
                adam_steps: self.trainer.adam_steps,
            }
        };
        let weights = self.trainer.net.to_tensors().to_safetensors();
        let optimizer = self.trainer.optimizer_tensors().to_safetensors();
        let counters_json = serde_json::to_vec_pretty(&counters)?;
        let dir = checkpoint::write(
            &self.checkpoint_dir,
            counters.env_steps,
            &[
                ("weights.safetensors", &weights),
                ("optimizer.safetensors", &optimizer),
                ("counters.json", &counters_json),
            ],
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

/// Restores trainer and counters from the newest checkpoint that verifies.
pub fn resume(
    checkpoint_dir: &std::path::Path,
    trainer: &mut Trainer,
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
    trainer
        .restore(
            file("weights.safetensors")?,
            file("optimizer.safetensors")?,
            counters.adam_steps,
        )
        .with_context(|| {
            format!(
                "loading weights from {} (does the [policy] config match the run's?)",
                loaded.dir.display()
            )
        })?;
    status.env_steps = counters.env_steps;
    status.updates = counters.updates;
    status.episodes = counters.episodes;
    status.policy_version = counters.policy_version;
    status.unet_version = counters.unet_version;
    status.last_checkpoint_step = Some(loaded.step);
    tracing::info!(
        "resumed from checkpoint {} (env steps {}, updates {}, policy version {})",
        loaded.dir.display(),
        counters.env_steps,
        counters.updates,
        counters.policy_version
    );
    Ok(())
}
