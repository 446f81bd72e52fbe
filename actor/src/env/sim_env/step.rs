//! A step's first half: the action decoded and done in the simulator, the
//! interaction told to the episode's object memory (which records it on the
//! map, or as a point on its object without one, and follows held
//! objects) and counted in its metrics, the reward computed; then the next
//! frame is captured for the U-Net.

use super::*;

impl SimEnv {
    /// Applies action `index` of the action space; the next frame is
    /// rendered and mapped, and waits for [`SimEnv::observe`].
    pub(crate) fn begin_step(&mut self, index: usize) -> anyhow::Result<ActionOutcome> {
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
        let held_before = episode.sim.held();
        let interaction = match action {
            PolicyAction::Select { affordance, cell } => episode
                .targets
                .target(affordance, cell)
                .map(|target| Interaction { affordance, target }),
            _ => None,
        };
        if let Some(interaction) = interaction {
            episode
                .memory
                .before_interaction(&episode.sim, &episode.frames, interaction);
        }
        let sim_action = self.space.to_sim(action, &episode.targets);
        let outcome = match sim_action {
            Some(sim_action) => episode.sim.apply(sim_action),
            None => sim::agent::Outcome {
                success: false,
                failure: Some(Failure::NothingThere),
            },
        };
        if let Some(Interaction { affordance, target }) = interaction {
            episode.memory.after_interaction(&episode.sim, &outcome);
            episode.metrics.interaction(
                affordance,
                &outcome,
                (target.u, target.v, self.config.image_size),
            );
        }
        if let (PolicyAction::Drop, true, Some(object)) = (action, outcome.success, held_before) {
            episode.memory.put_down(&episode.sim, object);
        }
        let agent = episode.sim.agent();
        let reward = episode.reward.reward(&StepEvent {
            agent,
            success: outcome.success,
            interaction: interaction.map(|i| (i.affordance, i.target.object as usize)),
            informative: crate::env::object_memory::tells_the_affordance(&outcome),
        });
        episode.metrics.reward(reward);
        if let Some(recorder) = &mut episode.recorder {
            recorder.step(StepRecord {
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
            .push(index, outcome.success, reward, proto::HISTORY_STEPS);
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
