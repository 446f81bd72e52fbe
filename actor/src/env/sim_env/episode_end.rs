//! An episode's end: confidence labels, the labelled frames for the
//! learner, the recording, and the paper's metrics against the
//! simulator's ground truth.

use super::*;

impl SimEnv {
    /// Ends the episode: its labelled frames for the learner (from the
    /// object memory: interaction labels through the map, also for objects
    /// it merged or dropped, or point labels without a map) and its metrics
    /// against the simulator's ground truth; recorded too, if asked.
    pub fn finish_episode(&mut self, episode_id: u64) -> anyhow::Result<EpisodeSummary> {
        let confidence = self.annotates_by_confidence();
        let mut episode = self.episode.take().context("finish before reset")?;
        if confidence {
            episode
                .memory
                .annotate_by_confidence(&episode.frames, &episode.probabilities)?;
        }
        let k = intrinsics(&episode.sim.camera());
        let mut labels = episode.memory.labels(&episode.frames, &k);
        if self.config.background_negative && self.config.method.segments() {
            label_background_negative(&mut labels, episode.metrics.truth_ids());
        }
        if let (Some(recording), Some(recorder)) = (
            self.recording
                .as_ref()
                .filter(|r| episode_id.is_multiple_of(r.every)),
            &episode.recorder,
        ) {
            let path = recording.path(self.global_steps, episode_id);
            self.record(&episode, recorder, &labels, &k, &path)
                .with_context(|| {
                    format!(
                        "recording the episode (--record {})",
                        recording.dir.display()
                    )
                })?;
        }
        if let Some(dataset) = self
            .dataset
            .as_ref()
            .filter(|d| episode_id.is_multiple_of(d.every))
        {
            self.write_dataset_episode(&episode, &labels, &k, dataset, episode_id)
                .context("writing the episode to the label ladder's dataset (--dataset)")?;
        }
        let id_consistency = episode
            .memory
            .id_consistency(episode.metrics.truth_ids(), &episode.frames);
        Ok(EpisodeSummary {
            tries: episode.metrics.tries(),
            stats: episode
                .metrics
                .finish(episode.steps, &labels, k.pixels(), id_consistency),
            frames: frame_batch(
                episode_id,
                &k,
                &episode.frames,
                &labels,
                self.config.affordances.len(),
                self.config.balanced_frames,
            ),
        })
    }
}
