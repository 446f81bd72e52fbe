//! The learner's side of a checkpoint: when one is due, what goes into it
//! (weights, optimiser states, the U-Net in training, counters), and
//! restoring all of it on `--resume`. The directory format (manifest,
//! verification, keeping the newest) is `crate::checkpoint`.

use super::*;

impl Learner {
    pub(super) fn checkpoint_due(&self) -> bool {
        let config = &self.shared.config;
        let updates = self.shared.status().counters.updates;
        if updates == self.updates_at_checkpoint {
            return false;
        }
        // A run's first checkpoint comes after its first update, so that
        // a learner killed in its first minutes leaves a run to resume.
        if self.updates_at_checkpoint == 0 {
            return true;
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
    pub(super) fn write_checkpoint(
        &mut self,
        policy: &PolicySnapshot,
        unet_training: Option<&UnetTrainingState>,
    ) -> anyhow::Result<()> {
        let counters = {
            let status = self.shared.status();
            Counters {
                run_id: status.run_id.clone(),
                env_steps: status.counters.env_steps,
                updates: policy.updates,
                episodes: status.counters.episodes,
                policy_version: policy.version,
                // The version of the U-Net the weights file holds.
                unet_version: self.unet.as_ref().map_or(0, |unet| unet.version),
            }
        };
        // The snapshot's weights: the broadcast may already be newer.
        let weights = self.weights_blob(&policy.weights, false)?;
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
            if let Some(average) = &unet.average {
                files.push((UNET_AVERAGE, average));
            }
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
        {
            let mut status = self.shared.status();
            status.counters.checkpoints_written += 1;
            status.counters.last_checkpoint_step = Some(counters.env_steps);
        }
        tracing::info!(dir = %dir.display(), updates = counters.updates, "checkpoint written");
        if let Some(scorer) = &self.validation_scorer {
            scorer.submit(counters.env_steps);
        }
        Ok(())
    }
}

/// Checkpoint file with the policy optimiser's record (burnpack).
const POLICY_OPTIMIZER_RECORD: &str = "policy_optimizer.bpk";

/// Checkpoint file naming the parameters that record refers to (JSON).
const POLICY_OPTIMIZER_PARAMETERS: &str = "policy_optimizer_parameters.json";

/// Checkpoint file: the U-Net in training (not yet through the validation gate).
const UNET_CANDIDATE: &str = "unet_candidate.safetensors";

/// Checkpoint file: the average of the U-Net's recent weights, when the run
/// averages them (`[unet] weight_average`).
const UNET_AVERAGE: &str = "unet_average.safetensors";

/// Checkpoint file: the U-Net's Adam state (burn's record).
const UNET_OPTIMIZER_RECORD: &str = "unet_optimizer.bpk";

/// Checkpoint file: module path → id and shape of the U-Net's parameters.
const UNET_OPTIMIZER_PARAMETERS: &str = "unet_optimizer_parameters.json";

/// Restores trainer and counters from the newest checkpoint that verifies.
/// Returns `false`, restoring nothing, when there is no checkpoint at all
/// (the run's learner stopped before writing one): the run starts afresh.
/// Checkpoints that all fail to verify are an error.
pub fn resume(
    checkpoint_dir: &std::path::Path,
    trainers: &mut Trainers,
    status: &mut LearnerStatus,
) -> anyhow::Result<bool> {
    let Some(loaded) = checkpoint::load_newest_valid(checkpoint_dir)? else {
        return Ok(false);
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
                    average: loaded.files.get(UNET_AVERAGE).cloned(),
                };
                affordance.restore_training(&state).with_context(|| {
                    format!(
                        "loading the U-Net in training from {} (does the [task] config match the run's?)",
                        loaded.dir.display()
                    )
                })?;
                unet_training = if state.average.is_some() && affordance.averages_weights() {
                    "state restored, with its weight average"
                } else {
                    "state restored"
                };
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
    status.counters.env_steps = counters.env_steps;
    status.counters.updates = counters.updates;
    status.counters.episodes = counters.episodes;
    status.counters.policy_version = counters.policy_version;
    status.counters.unet_version = counters.unet_version;
    status.counters.last_checkpoint_step = Some(loaded.step);
    tracing::info!(
        "resumed from checkpoint {} (env steps {}, updates {}, policy version {}, policy optimiser {}, U-Net training {})",
        loaded.dir.display(),
        counters.env_steps,
        counters.updates,
        counters.policy_version,
        if optimizer.is_some() { "state restored" } else { "afresh" },
        unet_training
    );
    Ok(true)
}
