//! A frame becomes an observation: rendered and taken in by the episode's
//! object memory ([`SimEnv::capture`]), handed to the U-Net ([`SimEnv::camera_frame`]),
//! then scored against the ground truth, turned into targets and the
//! policy's state ([`SimEnv::observe`]).

use super::*;

impl SimEnv {
    /// Renders the agent's view and lets the object memory name its objects
    /// (integrating it into the map, where there is one); the frame
    /// then waits for the U-Net ([`SimEnv::camera_frame`], [`SimEnv::observe`]).
    pub(super) fn capture(&mut self) -> anyhow::Result<()> {
        let episode = self.episode.as_mut().context("capture before reset")?;
        let t0 = Instant::now();
        let frame: Frame = episode.sim.render(&mut self.renderer)?;
        let t1 = Instant::now();
        let map_ids = episode.memory.take_in(&episode.sim, &frame)?;
        let t2 = Instant::now();
        let map_stages = episode.memory.integrate_timings();
        episode.pending = Some(Captured { frame, map_ids });
        self.timings = StepTimings {
            sim: Duration::ZERO,
            render: t1 - t0,
            map: t2 - t1,
            map_stages,
            unet: Duration::ZERO,
            state: Duration::ZERO,
        };
        Ok(())
    }

    /// The frame of the reset or step begun, for the U-Net; `None` before a
    /// reset or once observed.
    pub(crate) fn camera_frame(&self) -> Option<CameraFrame<'_>> {
        let frame = &self.episode.as_ref()?.pending.as_ref()?.frame;
        Some(CameraFrame {
            rgb: &frame.rgb,
            depth_m: &frame.depth_m,
            height: frame.height,
            width: frame.width,
        })
    }

    /// Completes the reset or step begun: scores the U-Net's `probabilities`
    /// (per affordance, a plane for [`SimEnv::camera_frame`]) against the
    /// ground truth, chooses the interaction targets and builds the state.
    pub fn observe(&mut self, probabilities: Vec<Vec<f32>>) -> anyhow::Result<SimObservation> {
        let episode = self.episode.as_mut().context("observe before reset")?;
        let Captured { frame, map_ids } = episode
            .pending
            .take()
            .context("observe twice, or before a reset or step")?;
        anyhow::ensure!(
            probabilities.len() == self.config.affordances.len()
                && probabilities
                    .iter()
                    .all(|p| p.len() == frame.height * frame.width),
            "the U-Net gave {} planes for {} affordances at {} × {} px",
            probabilities.len(),
            self.config.affordances.len(),
            frame.height,
            frame.width
        );
        let t3 = Instant::now();
        // The agent has not moved since the frame was captured.
        let camera = episode.sim.camera();
        let k = intrinsics(&camera);
        let agent = episode.sim.agent();
        let holding = episode.sim.held().is_some();
        let horizontal_m = horizontal_distances(
            &frame.depth_m,
            &k,
            &camera.t_world_camera,
            (agent.x, agent.y),
        );
        let reachable_ids;
        let selectable: &[u32] = if self.config.selection.within_reach {
            reachable_ids = beyond_reach_hidden(&map_ids, &horizontal_m, self.profile.reach_m);
            &reachable_ids
        } else {
            &map_ids
        };
        episode.targets = match self.config.method.spec().selection {
            Selection::Grid => cell_targets(
                selectable,
                frame.width,
                &self.config.affordances,
                Some(&probabilities),
                self.config.selection_confidence,
                &self.config.selection,
            ),
            Selection::Centred => centred_target(
                selectable,
                frame.width,
                &self.config.affordances,
                &self.config.selection,
            ),
        };
        let ratings = if self.state_config.ratings_len > 0 {
            episode.targets.ratings(&self.config.affordances)
        } else {
            Vec::new()
        };
        let state = build_state(
            &self.state_config,
            &StateInputs {
                rgb: &frame.rgb,
                horizontal_m: &horizontal_m,
                map_ids: &map_ids,
                agent: (agent.x, agent.y, agent.yaw_deg.to_radians()),
                floor_z: episode.sim.scene().floor_top_m,
                reach_m: self.profile.reach_m,
                visited: &episode.visited,
                probabilities: &probabilities,
                map: episode.memory.map(),
                history: &episode.history,
                holding,
                ratings: &ratings,
            },
        );
        if let Some(recorder) = &mut episode.recorder {
            recorder.observation(&state, (agent.x, agent.y, agent.yaw_deg.to_radians()));
        }
        let mask = self.space.mask(holding, &episode.targets);
        episode.metrics.observe_frame(&probabilities, frame.ids);
        episode.probabilities.push(
            probabilities
                .iter()
                .flatten()
                .map(|&p| proto::unit_to_byte(p))
                .collect(),
        );
        episode.frames.push(EpisodeFrame {
            rgb: frame.rgb,
            depth_m: frame.depth_m,
            map_ids,
            t_world_camera: camera.t_world_camera,
        });
        self.timings.state = t3.elapsed();
        Ok(SimObservation { state, mask })
    }
}
