//! The paper's per-episode metrics against the simulator's ground truth,
//! accumulated as the episode runs: return, how often interactions were
//! tried and succeeded (and why they failed), which interactable objects
//! were touched, the U-Net's frame scores; at the end the annotation rates
//! of the episode's labels join them ([`EpisodeMetrics::finish`]).

use std::collections::{BTreeMap, BTreeSet};

use mapper::Affordance;
use proto::{AffordanceStat, StatField, StatKey, TypeTries, LABEL_NEGATIVE, LABEL_POSITIVE};
use sim::agent::{Failure, Outcome};

use crate::frame_scores::{annotation_rates, score_frame, PAPER_THRESHOLD};

/// Counts per affordance, indexed by [`Affordance::code`].
type PerAffordance = [u32; Affordance::COUNT];

/// Running sums of per-frame scores.
#[derive(Debug, Clone, Copy, Default)]
struct ScoreSums {
    iou: f64,
    iou_frames: u32,
    accuracy: f64,
    accuracy_frames: u32,
}

/// One episode's metrics so far.
#[derive(Debug, Clone)]
pub(crate) struct EpisodeMetrics {
    /// Affordances scored, in plane order.
    affordances: Vec<Affordance>,
    /// Ground truth per scene object and affordance (plane order).
    truth: Vec<Vec<bool>>,
    /// The simulator's instance ids of every frame (object index + 1).
    truth_ids: Vec<Vec<u32>>,
    /// Per plane: sums and counts of the U-Net's frame IoU and object accuracy.
    scores: Vec<ScoreSums>,
    attempts: PerAffordance,
    successes: PerAffordance,
    /// Interactions that failed because the object was beyond reach, and
    /// because it does not afford the action ([`Failure::object_does_not_afford`]).
    out_of_reach: PerAffordance,
    unafforded: PerAffordance,
    /// Interactions that reached the object but found no room to lift or
    /// put it.
    no_room: PerAffordance,
    /// The simulator's type of each scene object (by object index).
    object_types: Vec<String>,
    /// Per affordance code and scene object tried (the one at the aimed
    /// pixel): attempts and successes.
    tried: BTreeMap<(u32, usize), (u32, u32)>,
    episode_return: f32,
}

impl EpisodeMetrics {
    /// Nothing counted yet, on a scene whose objects afford what `truth`
    /// says (per object, one flag per affordance of `affordances`) and are
    /// of the types `object_types` (per object).
    pub fn new(
        truth: Vec<Vec<bool>>,
        object_types: Vec<String>,
        affordances: &[Affordance],
    ) -> Self {
        Self {
            affordances: affordances.to_vec(),
            truth,
            truth_ids: Vec::new(),
            scores: vec![ScoreSums::default(); affordances.len()],
            attempts: Default::default(),
            successes: Default::default(),
            out_of_reach: Default::default(),
            unafforded: Default::default(),
            no_room: Default::default(),
            object_types,
            tried: BTreeMap::new(),
            episode_return: 0.0,
        }
    }

    /// A frame observed: the U-Net's `probabilities` (one plane per
    /// affordance) scored against the frame's instance ids `ids`, which are
    /// kept.
    pub(crate) fn observe_frame(&mut self, probabilities: &[Vec<f32>], ids: Vec<u32>) {
        for (plane, (probabilities, sums)) in probabilities.iter().zip(&mut self.scores).enumerate()
        {
            let scores = score_frame(
                probabilities,
                &ids,
                &|id| affords(&self.truth, id, plane),
                PAPER_THRESHOLD,
            );
            if let Some(iou) = scores.iou {
                sums.iou += f64::from(iou);
                sums.iou_frames += 1;
            }
            if let Some(accuracy) = scores.object_accuracy {
                sums.accuracy += f64::from(accuracy);
                sums.accuracy_frames += 1;
            }
        }
        self.truth_ids.push(ids);
    }

    /// An interaction of `affordance` aimed at pixel `(u, v)` of the last
    /// frame observed (`width` wide) tried, and what came of it.
    pub fn interaction(
        &mut self,
        affordance: Affordance,
        outcome: &Outcome,
        (u, v, width): (usize, usize, usize),
    ) {
        let kind = affordance.code() as usize;
        self.attempts[kind] += 1;
        self.successes[kind] += u32::from(outcome.success);
        if let Some(object) = self.object_at(u, v, width) {
            let tally = self.tried.entry((affordance.code(), object)).or_default();
            tally.0 += 1;
            tally.1 += u32::from(outcome.success);
        }
        if let Some(failure) = &outcome.failure {
            self.out_of_reach[kind] += u32::from(matches!(failure, Failure::OutOfReach { .. }));
            self.unafforded[kind] += u32::from(failure.object_does_not_afford());
            self.no_room[kind] += u32::from(matches!(failure, Failure::NoRoom { .. }));
        }
    }

    /// The scene object (its index) at pixel `(u, v)` of the last frame
    /// observed, if any.
    fn object_at(&self, u: usize, v: usize, width: usize) -> Option<usize> {
        let instance = self
            .truth_ids
            .last()
            .and_then(|ids| ids.get(v * width + u).copied())
            .unwrap_or(0);
        (instance > 0).then(|| instance as usize - 1)
    }

    /// The episode's tries by object type (the simulator's type of the
    /// object at the aimed pixel; tries that aimed at no scene object are
    /// left out): which objects carry the labels.
    pub(crate) fn tries(&self) -> Vec<TypeTries> {
        let mut by_type: BTreeMap<(u32, &str), TypeTries> = BTreeMap::new();
        for (&(code, object), &(attempts, successes)) in &self.tried {
            let (Some(affordance), Some(object_type)) =
                (Affordance::from_code(code), self.object_types.get(object))
            else {
                continue;
            };
            let entry = by_type
                .entry((code, object_type.as_str()))
                .or_insert_with(|| TypeTries {
                    affordance,
                    object_type: object_type.clone(),
                    attempts: 0,
                    successes: 0,
                    objects: 0,
                });
            entry.attempts += attempts;
            entry.successes += successes;
            entry.objects += 1;
        }
        by_type.into_values().collect()
    }

    /// A step's reward.
    pub fn reward(&mut self, reward: f32) {
        self.episode_return += reward;
    }

    /// Per scene object, whether it affords each affordance (plane order).
    pub(crate) fn truth(&self) -> &[Vec<bool>] {
        &self.truth
    }

    /// The simulator's instance ids of every frame observed.
    pub(crate) fn truth_ids(&self) -> &[Vec<u32>] {
        &self.truth_ids
    }

    /// The episode's metrics after `steps` steps, with the annotation rates
    /// of its `labels` (per frame observed, one byte per pixel of its
    /// `pixels` and affordance) and the memory's `id_consistency`
    /// ([`crate::env::object_memory::ObjectMemory::id_consistency`]).
    /// Rates per affordance are means over the affordances where episode-wide.
    pub(crate) fn finish(
        &self,
        steps: usize,
        labels: &[Vec<u8>],
        pixels: usize,
        id_consistency: Option<f32>,
    ) -> Vec<(StatKey, f32)> {
        let (positive, negative, rated) = self.annotation_rates(labels, pixels);
        let interactable = self.truth.iter().filter(|t| t.iter().any(|&x| x)).count();
        // Scene objects an interaction succeeded on.
        let interacted: BTreeSet<usize> = self
            .tried
            .iter()
            .filter(|(_, &(_, successes))| successes > 0)
            .map(|(&(_, object), _)| object)
            .collect();
        let interacted = interacted
            .iter()
            .filter(|&&i| self.truth.get(i).is_some_and(|t| t.iter().any(|&x| x)))
            .count();
        let attempts: u32 = self.attempts.iter().sum();
        let successes: u32 = self.successes.iter().sum();
        let per_step = |n: u32| n as f32 / steps.max(1) as f32;
        let episode_wide = |field: StatField, value: f32| (StatKey::Episode(field), value);
        let mut stats = vec![
            episode_wide(StatField::EpisodeReturn, self.episode_return),
            episode_wide(
                StatField::InteractionSuccessRate,
                successes as f32 / attempts.max(1) as f32,
            ),
            episode_wide(StatField::InteractionAttemptRate, per_step(attempts)),
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
            let share = |n: &PerAffordance| n.iter().sum::<u32>() as f32 / attempts as f32;
            stats.push(episode_wide(
                StatField::InteractionOutOfReachRate,
                share(&self.out_of_reach),
            ));
            stats.push(episode_wide(
                StatField::InteractionUnaffordedRate,
                share(&self.unafforded),
            ));
        }
        let total = |f: fn(&ScoreSums) -> (f64, u32)| {
            let (sum, n) = self
                .scores
                .iter()
                .map(f)
                .fold((0.0, 0), |(s, c), (x, k)| (s + x, c + k));
            per_frame(sum, n)
        };
        if let Some(iou) = total(|s| (s.iou, s.iou_frames)) {
            stats.push(episode_wide(StatField::AffordanceIou, iou));
        }
        if let Some(accuracy) = total(|s| (s.accuracy, s.accuracy_frames)) {
            stats.push(episode_wide(StatField::ObjectAccuracy, accuracy));
        }
        for (plane, (&affordance, sums)) in self.affordances.iter().zip(&self.scores).enumerate() {
            let of = |stat| StatKey::Affordance(affordance, stat);
            let kind = affordance.code() as usize;
            let attempts = self.attempts[kind];
            stats.push((of(AffordanceStat::AttemptRate), per_step(attempts)));
            if attempts > 0 {
                let share = |n: &PerAffordance| n[kind] as f32 / attempts as f32;
                stats.push((of(AffordanceStat::SuccessRate), share(&self.successes)));
                stats.push((
                    of(AffordanceStat::OutOfReachRate),
                    share(&self.out_of_reach),
                ));
                stats.push((of(AffordanceStat::UnaffordedRate), share(&self.unafforded)));
                stats.push((of(AffordanceStat::NoRoomRate), share(&self.no_room)));
            }
            if let Some((positive, negative)) = label_shares(labels, pixels, plane) {
                stats.push((of(AffordanceStat::PositiveLabelShare), positive));
                stats.push((of(AffordanceStat::NegativeLabelShare), negative));
            }
            let quality = LabelQuality::of(labels, &self.truth_ids, pixels, plane, &|id| {
                affords(&self.truth, id, plane)
            });
            stats.extend(
                [
                    (
                        AffordanceStat::PositiveLabelPrecision,
                        quality.positive_precision(),
                    ),
                    (
                        AffordanceStat::NegativeLabelPrecision,
                        quality.negative_precision(),
                    ),
                    (
                        AffordanceStat::PositiveLabelRecall,
                        quality.positive_recall(),
                    ),
                    (
                        AffordanceStat::NegativeLabelRecall,
                        quality.negative_recall(),
                    ),
                ]
                .into_iter()
                .filter_map(|(stat, value)| Some((of(stat), value?))),
            );
            stats
                .extend(per_frame(sums.iou, sums.iou_frames).map(|v| (of(AffordanceStat::Iou), v)));
            stats.extend(
                per_frame(sums.accuracy, sums.accuracy_frames)
                    .map(|v| (of(AffordanceStat::ObjectAccuracy), v)),
            );
        }
        if let Some(consistency) = id_consistency {
            stats.push(episode_wide(StatField::MapIdConsistency, consistency));
        }
        stats
    }

    /// Sums of the positive and negative annotation rates of `labels` over
    /// every frame and plane, and how many (frame, plane) pairs were rated.
    fn annotation_rates(&self, labels: &[Vec<u8>], pixels: usize) -> (f64, f64, f64) {
        let (mut positive, mut negative) = (0.0f64, 0.0f64);
        for (frame_labels, ids) in labels.iter().zip(&self.truth_ids) {
            for (plane, plane_labels) in frame_labels.chunks(pixels).enumerate() {
                let (p, n) =
                    annotation_rates(plane_labels, ids, &|id| affords(&self.truth, id, plane));
                positive += f64::from(p);
                negative += f64::from(n);
            }
        }
        let rated = (self.truth_ids.len() * self.scores.len()).max(1) as f64;
        (positive, negative, rated)
    }
}

/// Of every frame's pixels, the shares `labels` (per frame, planes of
/// `pixels` one after the other) call positive and negative in `plane`;
/// `None` without frames.
fn label_shares(labels: &[Vec<u8>], pixels: usize, plane: usize) -> Option<(f32, f32)> {
    let (mut positive, mut negative, mut all) = (0usize, 0usize, 0usize);
    for frame in labels {
        let Some(plane) = frame.chunks(pixels.max(1)).nth(plane) else {
            continue;
        };
        positive += plane.iter().filter(|&&l| l == LABEL_POSITIVE).count();
        negative += plane.iter().filter(|&&l| l == LABEL_NEGATIVE).count();
        all += plane.len();
    }
    (all > 0).then(|| (positive as f32 / all as f32, negative as f32 / all as f32))
}

/// How one plane's labels of an episode agree with the ground truth,
/// counted over its frames' pixels.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct LabelQuality {
    /// Pixels labelled positive, and of those the ones whose object affords it.
    positive: usize,
    true_positive: usize,
    /// Pixels labelled negative, and of those the ones whose object does
    /// not afford it (or that show no object).
    negative: usize,
    true_negative: usize,
    /// Pixels of objects that afford it.
    afforded: usize,
    /// Pixels of objects that do not afford it, and of those the ones
    /// labelled negative.
    unafforded_objects: usize,
    unafforded_objects_negative: usize,
}

impl LabelQuality {
    /// Counts plane `plane` of `labels` (per frame, planes of `pixels` one
    /// after the other) against each frame's instance ids `truth_ids` and
    /// whether an instance `affords` the plane's affordance.
    fn of(
        labels: &[Vec<u8>],
        truth_ids: &[Vec<u32>],
        pixels: usize,
        plane: usize,
        affords: &dyn Fn(u32) -> bool,
    ) -> Self {
        let mut q = Self::default();
        for (frame, ids) in labels.iter().zip(truth_ids) {
            let Some(plane) = frame.chunks(pixels.max(1)).nth(plane) else {
                continue;
            };
            // Runs of equal ids share one lookup, as the state's planes do.
            let mut last: Option<(u32, bool)> = None;
            for (&label, &id) in plane.iter().zip(ids) {
                let truth = match last {
                    Some((seen, truth)) if seen == id => truth,
                    _ => {
                        let truth = id != 0 && affords(id);
                        last = Some((id, truth));
                        truth
                    }
                };
                q.afforded += usize::from(truth);
                let unafforded_object = id != 0 && !truth;
                q.unafforded_objects += usize::from(unafforded_object);
                q.unafforded_objects_negative +=
                    usize::from(unafforded_object && label == LABEL_NEGATIVE);
                q.positive += usize::from(label == LABEL_POSITIVE);
                q.true_positive += usize::from(label == LABEL_POSITIVE && truth);
                q.negative += usize::from(label == LABEL_NEGATIVE);
                q.true_negative += usize::from(label == LABEL_NEGATIVE && !truth);
            }
        }
        q
    }

    fn positive_precision(&self) -> Option<f32> {
        ratio(self.true_positive, self.positive)
    }

    fn negative_precision(&self) -> Option<f32> {
        ratio(self.true_negative, self.negative)
    }

    fn positive_recall(&self) -> Option<f32> {
        ratio(self.true_positive, self.afforded)
    }

    fn negative_recall(&self) -> Option<f32> {
        ratio(self.unafforded_objects_negative, self.unafforded_objects)
    }
}

/// `part / whole`, `None` when `whole` is zero.
fn ratio(part: usize, whole: usize) -> Option<f32> {
    (whole > 0).then(|| part as f32 / whole as f32)
}

/// A sum of per-frame scores over its `frames`, as their mean; `None`
/// without frames.
fn per_frame(sum: f64, frames: u32) -> Option<f32> {
    (frames > 0).then(|| (sum / f64::from(frames)) as f32)
}

/// Whether scene instance `id` (object index + 1) affords plane `plane`'s
/// affordance, by the ground truth `truth`.
fn affords(truth: &[Vec<bool>], id: u32, plane: usize) -> bool {
    (id as usize)
        .checked_sub(1)
        .and_then(|object| truth.get(object))
        .is_some_and(|t| t[plane])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn label_shares_count_a_scripted_episodes_labels_exactly() {
        const U: u8 = proto::LABEL_UNKNOWN;
        const P: u8 = LABEL_POSITIVE;
        const N: u8 = LABEL_NEGATIVE;
        // Two frames of 4 pixels, two planes each.
        let labels = vec![vec![P, N, N, U, U, U, N, N], vec![P, P, U, U, N, N, N, N]];
        assert_eq!(label_shares(&labels, 4, 0), Some((3.0 / 8.0, 2.0 / 8.0)));
        assert_eq!(label_shares(&labels, 4, 1), Some((0.0, 6.0 / 8.0)));
        assert_eq!(label_shares(&[], 4, 0), None);
    }

    #[test]
    fn label_quality_counts_agreement_with_the_ground_truth_exactly() {
        const U: u8 = proto::LABEL_UNKNOWN;
        const P: u8 = LABEL_POSITIVE;
        const N: u8 = LABEL_NEGATIVE;
        // Instance 1 affords plane 0 only, instance 2 nothing, 0 is no object.
        let truth = vec![vec![true, false], vec![false, false]];
        let ids = vec![vec![1, 1, 2, 0], vec![0, 2, 1, 1]];
        // Plane 0: frame 0 labels instance 1 positive once, instance 2
        // positive (wrong) and the background negative; frame 1 labels one
        // pixel of instance 1 negative (wrong) and misses the other.
        let labels = vec![vec![P, U, P, N, N, N, N, N], vec![N, N, N, U, U, U, P, U]];
        let plane = |p: usize| LabelQuality::of(&labels, &ids, 4, p, &|id| affords(&truth, id, p));
        let q = plane(0);
        assert_eq!(q.positive_precision(), Some(1.0 / 2.0));
        assert_eq!(q.negative_precision(), Some(3.0 / 4.0));
        assert_eq!(q.positive_recall(), Some(1.0 / 4.0));
        // Instance 2's two pixels: one labelled positive, one negative.
        assert_eq!(q.negative_recall(), Some(1.0 / 2.0));
        // Plane 1: nothing affords it; one wrong positive, every negative right.
        let q = plane(1);
        assert_eq!(q.positive_precision(), Some(0.0));
        assert_eq!(q.negative_precision(), Some(1.0));
        assert_eq!(q.positive_recall(), None);
        // Instances 1 and 2 (six pixels), the background left out: three negative.
        assert_eq!(q.negative_recall(), Some(3.0 / 6.0));
        assert_eq!(
            LabelQuality::of(&[], &[], 4, 0, &|_| true),
            LabelQuality::default()
        );
    }

    #[test]
    fn tries_count_each_affordance_and_type_of_the_objects_aimed_at() {
        // Objects 0 and 1 are drawers, 2 a key chain; a 2 × 2 frame shows
        // object 0 (id 1), object 2 (id 3), object 1 (id 2) and nothing.
        let types = ["Drawer", "Drawer", "KeyChain"].map(String::from).to_vec();
        let truth = vec![vec![false, true], vec![false, true], vec![true, true]];
        let mut m = EpisodeMetrics::new(truth, types, &[Affordance::PickUp, Affordance::Push]);
        m.observe_frame(&[vec![0.5; 4], vec![0.5; 4]], vec![1, 3, 2, 0]);
        let (success, failure) = (
            Outcome {
                success: true,
                failure: None,
            },
            Outcome {
                success: false,
                failure: Some(Failure::NotPickupable),
            },
        );
        let at = |p: usize| (p % 2, p / 2, 2);
        m.interaction(Affordance::PickUp, &failure, at(0)); // drawer 0
        m.interaction(Affordance::PickUp, &failure, at(0)); // drawer 0 again
        m.interaction(Affordance::PickUp, &failure, at(2)); // drawer 1
        m.interaction(Affordance::PickUp, &success, at(1)); // the key chain
        m.interaction(Affordance::Push, &success, at(2)); // drawer 1
        m.interaction(Affordance::PickUp, &failure, at(3)); // nothing there
        let got: Vec<_> = m
            .tries()
            .into_iter()
            .map(|t| {
                (
                    t.affordance,
                    t.object_type,
                    t.attempts,
                    t.successes,
                    t.objects,
                )
            })
            .collect();
        assert_eq!(
            got,
            vec![
                (Affordance::PickUp, "Drawer".to_string(), 3, 0, 2),
                (Affordance::PickUp, "KeyChain".to_string(), 1, 1, 1),
                (Affordance::Push, "Drawer".to_string(), 1, 1, 1),
            ]
        );
    }
}
