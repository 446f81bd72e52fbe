//! A step's first half: the action decoded and done in the simulator, the
//! interaction recorded (on the map, or as a point on its object without
//! one), held objects followed, the reward counted; then the next frame
//! is captured for the U-Net.

use super::*;

impl SimEnv {
    /// Applies action `index` of the action space; the next frame is
    /// rendered and mapped, and waits for [`SimEnv::observe`].
    pub fn begin_step(&mut self, index: usize) -> anyhow::Result<ActionOutcome> {
        let action = self.space.get(index).with_context(|| {
            format!(
                "action {index} is outside the action space ({})",
                self.space.len()
            )
        })?;
        let episode = self.episode.as_mut().context("step before reset")?;
        anyhow::ensure!(
            episode.pending.is_none(),
            "step before the last frame was observed"
        );
        let started = Instant::now();
        let dropped = episode.sim.held();
        let interaction = match action {
            PolicyAction::Select { affordance, cell } => episode
                .targets
                .target(affordance, cell)
                .map(|t| (affordance, t)),
            _ => None,
        };
        // Without a map, the interaction leaves a point on the target object,
        // taken where the object is before the action moves it.
        let point = match interaction {
            Some((affordance, target)) if !self.config.uses_map() => {
                let k = intrinsics(&episode.sim.camera());
                interaction_point(episode, &self.config.affordances, affordance, &target, &k)
            }
            _ => None,
        };
        let boxes_before: Vec<OrientedBox> = match action {
            PolicyAction::Select {
                affordance: Affordance::PickUp,
                ..
            } => episode
                .sim
                .scene()
                .objects
                .iter()
                .map(|o| o.bounds)
                .collect(),
            _ => Vec::new(),
        };
        let outcome = match self.space.to_sim(action, &episode.targets) {
            Some(sim_action) => episode.sim.apply(sim_action),
            None => sim::agent::Outcome {
                success: false,
                failure: Some(Failure::NothingThere),
            },
        };
        // The interaction's outcome goes onto the map object that was
        // selected (or, without a map, onto its point).
        let mut interacted_instance = None;
        let evidence = tells_the_affordance(&outcome);
        if let Some(mut point) = point.filter(|_| evidence) {
            point.success = outcome.success;
            episode.points.push(point);
        }
        if let Some((affordance, Target { object, .. })) = interaction {
            interacted_instance = Some((affordance, object as usize));
            episode.attempts[affordance as usize] += 1;
            episode.successes[affordance as usize] += u32::from(outcome.success);
            if let Some(failure) = &outcome.failure {
                let kind = affordance as usize;
                episode.out_of_reach[kind] +=
                    u32::from(matches!(failure, Failure::OutOfReach { .. }));
                episode.unafforded[kind] += u32::from(failure.object_does_not_afford());
            }
        }
        if let Some((affordance, Target { object, .. })) =
            interaction.filter(|_| self.config.uses_map() && evidence)
        {
            let id = ObjectId(object);
            let result = if outcome.success {
                MapOutcome::Success
            } else {
                MapOutcome::Failure
            };
            // Only ids of the frame's objects are selectable, so the object
            // exists; labels of objects the map deletes later stay with it.
            let _ = episode.map.record_interaction(id, affordance, result);
            if outcome.success && affordance == Affordance::Push {
                // The map tracks the pushed object from the next frame on,
                // looking along the push (the camera's heading) for it.
                let yaw = episode.sim.agent().yaw_deg.to_radians();
                let along = nalgebra::Vector3::new(yaw.cos(), yaw.sin(), 0.0);
                let _ = episode.map.notify_pushed(id, along);
            }
            if outcome.success && affordance == Affordance::PickUp {
                // The map keeps the object, unseen, until it is put down.
                if let Some(index) = episode.sim.held() {
                    if episode.map.hold(id).is_ok() {
                        episode.in_hand = Some((id, boxes_before[index]));
                    }
                }
            }
        }
        if let (
            Some(sim::agent::Action::PickUp { u, v } | sim::agent::Action::Push { u, v }),
            true,
        ) = (self.space.to_sim(action, &episode.targets), outcome.success)
        {
            let width = self.config.image_size;
            let instance = episode
                .truth_ids
                .last()
                .and_then(|ids| ids.get(v * width + u).copied())
                .unwrap_or(0);
            if instance > 0 {
                episode.interacted.insert(instance as usize - 1);
            }
        }
        if action == PolicyAction::Drop && outcome.success {
            if let (Some((id, before)), Some(index)) = (episode.in_hand.take(), dropped) {
                let after = episode.sim.scene().objects[index].bounds;
                let pose = |b: &OrientedBox| Pose::from_parts(b.center.coords.into(), b.rotation);
                let _ = episode
                    .map
                    .release(id, pose(&after) * pose(&before).inverse());
            }
        }
        let agent = episode.sim.agent();
        let reward = episode.reward.reward(&StepEvent {
            agent,
            success: outcome.success,
            interaction: interacted_instance,
        });
        episode.episode_return += reward;
        if self.recording.is_some() {
            episode.step_log.push(StepRecord {
                action: index,
                action_name: format!("{action:?}"),
                reward,
                success: outcome.success,
                failure: outcome
                    .failure
                    .as_ref()
                    .map(|f| format!("{f:?}"))
                    .unwrap_or_default(),
                agent: (agent.x, agent.y, agent.yaw_deg),
            });
        }
        episode.visited.push(Point2::new(agent.x, agent.y));
        episode
            .history
            .push(index, outcome.success, reward, self.state_config.history);
        episode.steps += 1;
        let done = episode.steps >= self.config.episode_steps;
        let sim_time = started.elapsed();
        self.capture()?;
        self.timings.sim = sim_time;
        Ok(ActionOutcome {
            reward,
            success: outcome.success,
            failure: outcome.failure,
            done,
        })
    }
}

/// The point an interaction leaves on its target (methods without a map):
/// the aimed pixel back-projected with the last frame's depth, in the
/// object's frame as it was in that frame. `None` where the pixel saw nothing.
fn interaction_point(
    episode: &Episode,
    affordances: &[Affordance],
    affordance: Affordance,
    target: &Target,
    k: &mapper::Intrinsics,
) -> Option<InteractionPoint> {
    let frame = episode.frames.last()?;
    let object = (target.object as usize).checked_sub(1)?;
    let pose = episode.object_poses.last()?.get(object)?;
    let z = *frame.depth_m.get(target.v * k.width + target.u)?;
    if !(z.is_finite() && z > 0.0) {
        return None;
    }
    let p_world = frame.t_world_camera * k.back_project(target.u as f32, target.v as f32, z);
    Some(InteractionPoint {
        object,
        affordance: affordances.iter().position(|&a| a == affordance)?,
        success: false,
        p_object: pose.inverse() * p_world,
    })
}

/// Whether an interaction's outcome says anything about its object's
/// affordance, so that labels may follow from it: a success, or a failure of
/// the object itself. An arm that never reached the object (beyond reach, no
/// room to lift it, nothing under the pixel) learnt nothing about it; the
/// robot knows this from its own arm, and labelling such objects negative
/// taught the U-Net that reachable pickupable objects cannot be picked up
/// (56 % of a trained policy's failed pick-ups were beyond reach).
fn tells_the_affordance(outcome: &sim::agent::Outcome) -> bool {
    outcome.success
        || outcome
            .failure
            .as_ref()
            .is_some_and(Failure::object_does_not_afford)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_successes_and_failures_of_the_object_itself_make_labels() {
        let failed = |failure| sim::agent::Outcome {
            success: false,
            failure: Some(failure),
        };
        let succeeded = sim::agent::Outcome {
            success: true,
            failure: None,
        };
        assert!(tells_the_affordance(&succeeded));
        for evidence in [
            Failure::NotPickupable,
            Failure::TooHeavy { mass_kg: 30.0 },
            Failure::TooWide { width_m: 0.5 },
            Failure::NotPushable,
            Failure::DidNotMove { moved_m: 0.01 },
        ] {
            assert!(
                tells_the_affordance(&failed(evidence.clone())),
                "{evidence:?}"
            );
        }
        for no_evidence in [
            Failure::OutOfReach { distance_m: 1.4 },
            Failure::NothingThere,
            Failure::NoRoom {
                blocked_by: "Shelf".into(),
            },
        ] {
            assert!(
                !tells_the_affordance(&failed(no_evidence.clone())),
                "{no_evidence:?}"
            );
        }
    }
}
