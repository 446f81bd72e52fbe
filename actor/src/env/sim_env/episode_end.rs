//! An episode's end: confidence labels, the labelled frames for the
//! learner, the recording, and the paper's metrics against the
//! simulator's ground truth.

use super::*;
use proto::{AffordanceStat, LabelSource, StatField};

impl SimEnv {
    /// Ends the episode: its labelled frames for the learner (interaction
    /// labels through the map, also for objects it merged or dropped, or
    /// point labels without a map) and its metrics against the simulator's
    /// ground truth; recorded too, if asked.
    pub fn finish_episode(&mut self, episode_id: u64) -> anyhow::Result<EpisodeSummary> {
        let confidence = self.annotates_by_confidence();
        let mut episode = self.episode.take().context("finish before reset")?;
        if confidence {
            self.annotate_by_confidence(&mut episode)?;
        }
        let k = intrinsics(&episode.sim.camera());
        let mut labels = self.labels(&episode, &k);
        if self.config.background_negative && self.config.method.segments() {
            label_background_negative(&mut labels, &episode.truth_ids);
        }
        if let Some(recording) = self
            .recording
            .as_ref()
            .filter(|r| episode_id.is_multiple_of(r.every))
        {
            let path = recording.path(self.global_steps, episode_id);
            self.record(&episode, &labels, &k, &path).with_context(|| {
                format!(
                    "recording the episode (--record {})",
                    recording.dir.display()
                )
            })?;
        }
        Ok(EpisodeSummary {
            stats: episode_stats(
                &episode,
                &labels,
                k.pixels(),
                self.config.uses_map(),
                &self.config.affordances,
            ),
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

    /// Stores on the map a confidence label for every untouched object the
    /// calibrated U-Net is sure about over the episode's frames.
    fn annotate_by_confidence(&self, episode: &mut Episode) -> anyhow::Result<()> {
        let pixels = self.config.image_size * self.config.image_size;
        for (plane, &affordance) in self.config.affordances.iter().enumerate() {
            let planes: Vec<Vec<f32>> = episode
                .probabilities
                .iter()
                .map(|p| {
                    p[plane * pixels..(plane + 1) * pixels]
                        .iter()
                        .map(|&b| proto::byte_to_unit(b))
                        .collect()
                })
                .collect();
            let decided = confidence_labels(
                &episode.map,
                &episode.frames,
                &planes,
                affordance,
                &self.config.confidence,
            );
            apply_confidence_labels(&mut episode.map, affordance, &decided)
                .context("storing confidence labels on the map")?;
        }
        Ok(())
    }

    /// Every frame's label planes, made the method's way.
    fn labels(&self, episode: &Episode, k: &mapper::Intrinsics) -> Vec<Vec<u8>> {
        let planes = self.config.affordances.len();
        let poses = &episode.object_poses;
        let pose_of = |frame: usize, object: usize| poses[frame][object];
        match self.config.method.spec().labels {
            LabelSource::Map => map_labels(&episode.map, &episode.frames, &self.config.affordances),
            LabelSource::Segments => segment_labels(
                &episode.frames,
                k,
                &episode.points,
                planes,
                &pose_of,
                &self.config.sphere,
            ),
            LabelSource::Spheres => sphere_labels(
                &episode.frames,
                k,
                &episode.points,
                planes,
                &pose_of,
                &self.config.sphere,
            ),
        }
    }
}

/// A sum of per-frame scores over its `frames`, as their mean; `None`
/// without frames.
fn per_frame(sum: f64, frames: u32) -> Option<f32> {
    (frames > 0).then(|| (sum / f64::from(frames)) as f32)
}

/// The paper's per-episode metrics against the simulator's ground truth:
/// return, interaction success rate (and why attempts failed),
/// interacted object rate, both
/// annotation rates of `labels`, the U-Net's mean IoU and object
/// accuracy over the episode's frames (means over affordances), and, for
/// methods with a map (`uses_map`), how consistently it re-identified the
/// scene's objects.
fn episode_stats(
    episode: &Episode,
    labels: &[Vec<u8>],
    pixels: usize,
    uses_map: bool,
    affordances: &[Affordance],
) -> Vec<(StatKey, f32)> {
    let planes = episode.scores.len();
    // Annotation rates of the labels over every frame of the episode.
    let (mut positive, mut negative) = (0.0f64, 0.0f64);
    for (frame_labels, ids) in labels.iter().zip(&episode.truth_ids) {
        for (plane, plane_labels) in frame_labels.chunks(pixels).enumerate() {
            let truth = &episode.truth;
            let affords = |id: u32| truth.get(id as usize - 1).is_some_and(|t| t[plane]);
            let (p, n) = annotation_rates(plane_labels, ids, &affords);
            positive += f64::from(p);
            negative += f64::from(n);
        }
    }
    let rated = (episode.truth_ids.len() * planes).max(1) as f64;
    let interactable = episode
        .truth
        .iter()
        .filter(|t| t.iter().any(|&x| x))
        .count();
    let interacted = episode
        .interacted
        .iter()
        .filter(|&&i| episode.truth.get(i).is_some_and(|t| t.iter().any(|&x| x)))
        .count();
    let mean = |f: fn(&ScoreSums) -> (f64, u32)| -> Option<f32> {
        let (sum, n) = episode
            .scores
            .iter()
            .map(f)
            .fold((0.0, 0), |(s, c), (x, k)| (s + x, c + k));
        per_frame(sum, n)
    };
    let attempts: u32 = episode.attempts.iter().sum();
    let successes: u32 = episode.successes.iter().sum();
    let episode_wide = |field: StatField, value: f32| (StatKey::Episode(field), value);
    let mut stats = vec![
        episode_wide(StatField::EpisodeReturn, episode.episode_return),
        episode_wide(
            StatField::InteractionSuccessRate,
            successes as f32 / attempts.max(1) as f32,
        ),
        episode_wide(
            StatField::InteractionAttemptRate,
            attempts as f32 / episode.steps.max(1) as f32,
        ),
        episode_wide(
            StatField::InteractedObjectRate,
            interacted as f32 / interactable.max(1) as f32,
        ),
        episode_wide(
            StatField::InteractableAnnotationRate,
            (positive / rated) as f32,
        ),
        episode_wide(
            StatField::NonInteractableAnnotationRate,
            (negative / rated) as f32,
        ),
    ];
    if attempts > 0 {
        let attempts = attempts as f32;
        stats.push(episode_wide(
            StatField::InteractionOutOfReachRate,
            episode.out_of_reach.iter().sum::<u32>() as f32 / attempts,
        ));
        stats.push(episode_wide(
            StatField::InteractionUnaffordedRate,
            episode.unafforded.iter().sum::<u32>() as f32 / attempts,
        ));
    }
    if let Some(iou) = mean(|s| (s.iou, s.iou_frames)) {
        stats.push(episode_wide(StatField::AffordanceIou, iou));
    }
    if let Some(accuracy) = mean(|s| (s.accuracy, s.accuracy_frames)) {
        stats.push(episode_wide(StatField::ObjectAccuracy, accuracy));
    }
    for (&affordance, sums) in affordances.iter().zip(&episode.scores) {
        let of = |stat| StatKey::Affordance(affordance, stat);
        let kind = affordance.code() as usize;
        let (attempts, successes) = (episode.attempts[kind], episode.successes[kind]);
        stats.push((
            of(AffordanceStat::AttemptRate),
            attempts as f32 / episode.steps.max(1) as f32,
        ));
        if attempts > 0 {
            let share = |n: u32| n as f32 / attempts as f32;
            stats.push((of(AffordanceStat::SuccessRate), share(successes)));
            stats.push((
                of(AffordanceStat::OutOfReachRate),
                share(episode.out_of_reach[kind]),
            ));
            stats.push((
                of(AffordanceStat::UnaffordedRate),
                share(episode.unafforded[kind]),
            ));
        }
        stats.extend(per_frame(sums.iou, sums.iou_frames).map(|v| (of(AffordanceStat::Iou), v)));
        stats.extend(
            per_frame(sums.accuracy, sums.accuracy_frames)
                .map(|v| (of(AffordanceStat::ObjectAccuracy), v)),
        );
    }
    if uses_map {
        let frames = episode
            .truth_ids
            .iter()
            .zip(&episode.frames)
            .map(|(truth, frame)| (truth.as_slice(), frame.map_ids.as_slice()));
        let current = |id: u32| episode.map.current_id(ObjectId(id)).0;
        if let Some(consistency) = map_id_consistency(frames, current) {
            stats.push(episode_wide(StatField::MapIdConsistency, consistency));
        }
    }
    stats
}
