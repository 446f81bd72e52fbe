//! The label ladder's dataset (`actor --dataset`): every N-th episode's
//! frames (every K-th of them) with the three label sources of
//! [`proto::LabelRung`] side by side, one file per episode, for training
//! the U-Net offline on each (`learner train-unet`, `docs/ladder.md`).

use super::*;
use crate::ladder_labels::{ground_truth_labels, stack_rungs, tried_truth_labels};

/// Which episodes go to the dataset, and where.
#[derive(Debug, Clone)]
pub(super) struct DatasetRecording {
    /// The dataset's directory (its episode files go to `episodes/`).
    dir: std::path::PathBuf,
    /// File-name prefix (the actor's).
    prefix: String,
    /// Every how many episodes one is written.
    pub(super) every: u64,
    /// Every how many frames of an episode one is kept.
    frame_every: usize,
}

impl SimEnv {
    /// Writes every `every`-th episode (by id) from now on, every
    /// `frame_every`-th of its frames, to `dir/episodes/` as the label
    /// ladder's dataset ([`proto::LabelRung`]). Only methods with a map
    /// (`ours`) know which map objects were tried; others fail at their
    /// first episode's end.
    pub fn dataset_to(
        &mut self,
        dir: std::path::PathBuf,
        prefix: String,
        every: u64,
        frame_every: usize,
    ) {
        self.dataset = Some(DatasetRecording {
            dir,
            prefix,
            every: every.max(1),
            frame_every: frame_every.max(1),
        });
    }

    /// Writes `episode`'s dataset file: its kept frames, each with the
    /// ground truth (L0), the tried objects' ground truth (L1) and the
    /// run's own `labels` (L2), the background labelled as the run labels
    /// it. A kept frame that no source labels at all is left out.
    pub(super) fn write_dataset_episode(
        &self,
        episode: &Episode,
        labels: &[Vec<u8>],
        k: &mapper::Intrinsics,
        dataset: &DatasetRecording,
        episode_id: u64,
    ) -> anyhow::Result<std::path::PathBuf> {
        let tried = episode
            .memory
            .tried_objects(&episode.frames)
            .with_context(|| {
                format!(
                    "the label ladder's dataset needs a method with a map (ours); this run's is {}",
                    self.config.method.as_str()
                )
            })?;
        let truth_ids = episode.metrics.truth_ids();
        let truth = episode.metrics.truth();
        let mut ground = ground_truth_labels(truth_ids, truth, self.config.affordances.len());
        let mut tried = tried_truth_labels(&tried, truth_ids, truth, &self.config.affordances);
        if self.config.background_negative && self.config.method.segments() {
            label_background_negative(&mut ground, truth_ids);
            label_background_negative(&mut tried, truth_ids);
        }
        let stacked = stack_rungs([&ground, &tried, labels]);
        let kept: Vec<usize> = (0..episode.frames.len())
            .step_by(dataset.frame_every)
            .collect();
        let frames: Vec<EpisodeFrame> = kept.iter().map(|&i| episode.frames[i].clone()).collect();
        let planes: Vec<Vec<u8>> = kept.iter().map(|&i| stacked[i].clone()).collect();
        let batch = frame_batch(
            episode_id,
            k,
            &frames,
            &planes,
            proto::LabelRung::ALL.len() * self.config.affordances.len(),
            false,
        );
        let episodes = dataset.dir.join(proto::DATASET_EPISODES_DIR);
        std::fs::create_dir_all(&episodes)
            .with_context(|| format!("creating {}", episodes.display()))?;
        let stem = format!(
            "{}step{:09}_episode{episode_id:06}",
            dataset.prefix, self.global_steps
        );
        let extension = proto::DATASET_EPISODE_EXTENSION;
        let mut path = episodes.join(format!("{stem}.{extension}"));
        let mut n = 1;
        while path.exists() {
            n += 1;
            path = episodes.join(format!("{stem}_{n}.{extension}"));
        }
        // Written whole under a temporary name, then renamed: a reader never
        // sees half an episode.
        let tmp = path.with_extension("tmp");
        std::fs::write(&tmp, proto::encode(&batch, proto::MessageHeader::default()))
            .with_context(|| format!("writing {}", tmp.display()))?;
        std::fs::rename(&tmp, &path).with_context(|| format!("renaming {}", tmp.display()))?;
        Ok(path)
    }
}
