//! What the receive loop does with one message (validated, from a joined
//! actor's own publisher), and the weights it publishes back.

use super::*;

impl Learner {
    /// Validates a message of the service that carries `kind`, which came
    /// through the publisher `origin`, and uses it.
    pub(super) fn handle(
        &mut self,
        kind: MessageKind,
        origin: u128,
        bytes: Vec<u8>,
    ) -> anyhow::Result<()> {
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
            self.refuse(kind, Some(header.actor_id), reason);
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
                    status.counters.env_steps
                };
                let fields: serde_json::Map<String, serde_json::Value> = stats
                    .present()
                    .map(|(f, v)| (f.name().into_owned(), serde_json::json!(v)))
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
                            "tries": stats.tries().iter().map(|t| serde_json::json!({
                                "affordance": t.affordance.as_str(),
                                "type": t.object_type,
                                "attempts": t.attempts,
                                "successes": t.successes,
                                "objects": t.objects,
                            })).collect::<Vec<_>>(),
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
                            self.shared.status().counters.frames_received += n;
                        } else {
                            self.shared.status().counters.frames_skipped += n;
                            if self.warned.insert((kind, "unet busy")) {
                                tracing::warn!("the U-Net trainer is behind: skipping episodes' frames until it catches up (further skips are only counted in frames_skipped)");
                            }
                        }
                    }
                    Err(error) => {
                        self.shared.status().counters.untrainable_chunks += 1;
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
            if discarded > 0 && self.warned.insert((kind, "ppo behind")) {
                tracing::warn!("PPO is behind the actors: discarding the oldest queued rollout steps (further ones are only counted in rollout_steps_discarded)");
            }
        }
        Ok(())
    }

    /// Records an actor's join, or counts why it is refused.
    pub(super) fn join(&mut self, actor_id: u32, join: &Join, origin: u128) {
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

    /// Whether the actors must wait for the U-Net: it owes the steps of more
    /// than `[unet] hold_actors_beyond_episodes` episodes (never when that
    /// is 0, or without a U-Net).
    pub(super) fn unet_owes_too_much(&self) -> bool {
        let unet = &self.shared.config.unet;
        self.unet_worker.is_some()
            && unet.hold_actors_beyond_episodes > 0
            && self.shared.status().counters.unet_owed_steps
                > (unet.hold_actors_beyond_episodes * unet.steps_per_episode) as u64
    }

    pub(super) fn publish_weights(&mut self) -> anyhow::Result<()> {
        let policy_version = self.policy.version;
        let unet_version = self.unet.as_ref().map_or(0, |unet| unet.version);
        let hold = self.unet_owes_too_much();
        let blob = self.weights_blob(&self.policy.weights, hold)?;
        match self
            .ports
            .publish_weights(policy_version, unet_version, &blob)?
        {
            Delivery::Delivered(_) => {
                let mut status = self.shared.status();
                let counters = &mut status.counters;
                counters.weights_published += 1;
                counters.actor_holds += u64::from(hold && !counters.actors_held);
                counters.actors_held = hold;
                self.hold_sent = Some(hold);
            }
            Delivery::Dropped => tracing::debug!(
                policy_version,
                "weights pool busy; the next publish carries newer weights"
            ),
        }
        Ok(())
    }

    /// Both networks in one safetensors blob, names prefixed `policy.` and
    /// `unet.`: `policy` (safetensors bytes) and the deployed U-Net; `hold`
    /// tells the actors to wait for the U-Net.
    pub(super) fn weights_blob(&self, policy: &[u8], hold: bool) -> anyhow::Result<Vec<u8>> {
        let mut parts: Vec<(&str, &[u8])> = vec![(proto::WEIGHTS_POLICY_PREFIX, policy)];
        let mut metadata = std::collections::HashMap::from([(
            proto::WEIGHTS_META_ENV_STEPS.to_string(),
            self.shared.status().counters.env_steps.to_string(),
        )]);
        if hold {
            metadata.insert(proto::WEIGHTS_META_HOLD.to_string(), "1".to_string());
        }
        if let Some(unet) = &self.unet {
            parts.push((proto::WEIGHTS_UNET_PREFIX, &unet.weights));
            metadata.insert(
                proto::WEIGHTS_META_TEMPERATURE.to_string(),
                unet.temperature.to_string(),
            );
        }
        nets::weights::bundle(&parts, metadata).context("bundling the weights")
    }
}
