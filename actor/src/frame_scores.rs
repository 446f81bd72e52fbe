//! Per-frame scores against the simulator's ground truth (the paper's
//! training metrics): affordance IoU of the U-Net's prediction, object-level
//! accuracy by majority vote of each visible object's pixels, and the
//! interactable / non-interactable annotation rates of the labeller.
//!
//! Ground truth comes as a per-pixel instance image (the simulator's ids,
//! 0 for structure) and a function telling whether an instance affords the
//! affordance (from `sim::affordances::ground_truth`).

use std::collections::BTreeMap;

use proto::{Affordance, LABEL_NEGATIVE, LABEL_POSITIVE};
use sim::affordances::{can_pick_up, can_push};
use sim::profile::RobotProfile;
use sim::scene::Scene;

/// Per scene object (by index, so instance id − 1), whether it affords each
/// of `affordances` (plane order) for `profile`: the rules and physics the
/// actions use. The floor affords nothing.
pub fn ground_truth_planes(
    scene: &Scene,
    profile: &RobotProfile,
    affordances: &[Affordance],
) -> Vec<Vec<bool>> {
    (0..scene.objects.len())
        .map(|i| {
            let object = &scene.objects[i];
            affordances
                .iter()
                .map(|a| {
                    !object.is_floor()
                        && match a {
                            Affordance::PickUp => can_pick_up(object, profile),
                            Affordance::Push => can_push(scene, i, profile),
                        }
                })
                .collect()
        })
        .collect()
}

/// Scores of one frame for one affordance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct FrameScores {
    /// |predicted ∩ true| / |predicted ∪ true| over every pixel, structure
    /// (instance 0) a negative like the floor, as in the paper and in
    /// [`pixel_scores`]; `None` when both are empty.
    pub iou: Option<f32>,
    /// Fraction of visible objects whose majority-voted prediction is right;
    /// `None` when no object is visible.
    pub object_accuracy: Option<f32>,
}

/// The paper's threshold: a pixel (or an object's mean) at or above it is
/// predicted to afford the affordance.
pub const PAPER_THRESHOLD: f32 = 0.5;

/// Scores a probability plane (predicted where at or above `threshold`)
/// against the ground truth.
pub(crate) fn score_frame(
    probabilities: &[f32],
    instances: &[u32],
    affords: &dyn Fn(u32) -> bool,
    threshold: f32,
) -> FrameScores {
    let (mut intersection, mut union) = (0usize, 0usize);
    let mut votes: BTreeMap<u32, (usize, usize)> = BTreeMap::new();
    for (&p, &id) in probabilities.iter().zip(instances) {
        let (predicted, truth) = (p >= threshold, id != 0 && affords(id));
        intersection += usize::from(predicted && truth);
        union += usize::from(predicted || truth);
        if id == 0 {
            continue;
        }
        let v = votes.entry(id).or_default();
        v.0 += usize::from(predicted);
        v.1 += 1;
    }
    let correct = votes
        .iter()
        .filter(|(&id, &(yes, all))| (2 * yes > all) == affords(id))
        .count();
    FrameScores {
        iou: (union > 0).then(|| intersection as f32 / union as f32),
        object_accuracy: (!votes.is_empty()).then(|| correct as f32 / votes.len() as f32),
    }
}

/// Pixel-level precision, recall and F1 of one frame for one affordance
/// (the paper's Table 1), over every pixel: structure (instance 0) and
/// objects that do not afford the action are negatives. Each is `None`
/// where it is undefined: precision without predicted positives, recall
/// without true ones, F1 without either.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct PixelScores {
    /// True positives over predicted positives.
    pub precision: Option<f32>,
    /// True positives over true positives and false negatives.
    pub recall: Option<f32>,
    /// 2·TP / (2·TP + FP + FN).
    pub f1: Option<f32>,
}

/// Scores a probability plane (predicted where at or above `threshold`)
/// pixel by pixel against the ground truth (see [`PixelScores`]).
pub(crate) fn pixel_scores(
    probabilities: &[f32],
    instances: &[u32],
    affords: &dyn Fn(u32) -> bool,
    threshold: f32,
) -> PixelScores {
    let (mut tp, mut fp, mut fn_) = (0usize, 0usize, 0usize);
    for (&p, &id) in probabilities.iter().zip(instances) {
        let (predicted, truth) = (p >= threshold, id != 0 && affords(id));
        tp += usize::from(predicted && truth);
        fp += usize::from(predicted && !truth);
        fn_ += usize::from(!predicted && truth);
    }
    let ratio = |num: usize, den: usize| (den > 0).then(|| num as f32 / den as f32);
    PixelScores {
        precision: ratio(tp, tp + fp),
        recall: ratio(tp, tp + fn_),
        f1: ratio(2 * tp, 2 * tp + fp + fn_),
    }
}

/// The annotation rates of a label plane: pixels correctly labelled
/// positive over all pixels, and pixels correctly labelled negative over
/// all pixels.
pub(crate) fn annotation_rates(
    labels: &[u8],
    instances: &[u32],
    affords: &dyn Fn(u32) -> bool,
) -> (f32, f32) {
    let (mut positive, mut negative) = (0usize, 0usize);
    for (&l, &id) in labels.iter().zip(instances) {
        let truth = id != 0 && affords(id);
        positive += usize::from(l == LABEL_POSITIVE && truth);
        negative += usize::from(l == LABEL_NEGATIVE && !truth);
    }
    let n = labels.len().max(1) as f32;
    (positive as f32 / n, negative as f32 / n)
}

/// How consistently the map re-identified the scene's objects over an
/// episode ([`proto::StatField::MapIdConsistency`]). `frames` yields each
/// frame's ground-truth instance image and the map ids the frame got;
/// `current` maps an id to the one it stands for now (copies merged since).
/// Per scene object (instance ≠ 0), its pixels that got a map id are
/// counted per id; the result is the share of all of them that carry their
/// object's most common id. `None` when no object pixel got an id.
pub fn map_id_consistency<'a>(
    frames: impl IntoIterator<Item = (&'a [u32], &'a [u32])>,
    current: impl Fn(u32) -> u32,
) -> Option<f32> {
    let mut counts: BTreeMap<(u32, u32), u64> = BTreeMap::new();
    for (instances, map_ids) in frames {
        for (&instance, &id) in instances.iter().zip(map_ids) {
            if instance != 0 && id != 0 {
                *counts.entry((instance, current(id))).or_default() += 1;
            }
        }
    }
    let mut most: BTreeMap<u32, u64> = BTreeMap::new();
    let mut total = 0u64;
    for (&(instance, _), &n) in &counts {
        let m = most.entry(instance).or_default();
        *m = (*m).max(n);
        total += n;
    }
    (total > 0).then(|| most.values().sum::<u64>() as f32 / total as f32)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proto::LABEL_UNKNOWN;

    #[test]
    fn map_id_consistency_counts_each_object_under_its_most_common_id() {
        // Object 1: 3 px as map 7, then 1 px as map 8 (a second copy);
        // object 2: 2 px as map 9 and 2 px as map 10, which was merged into 9.
        let truth: [&[u32]; 2] = [&[1, 1, 1, 2, 2, 0], &[1, 2, 2, 0, 0, 0]];
        let ids: [&[u32]; 2] = [&[7, 7, 7, 9, 9, 0], &[8, 10, 10, 5, 0, 0]];
        let current = |id: u32| if id == 10 { 9 } else { id };
        let frames = truth.iter().copied().zip(ids.iter().copied());
        assert_eq!(map_id_consistency(frames, current), Some(7.0 / 8.0));
        let unmerged = truth.iter().copied().zip(ids.iter().copied());
        assert_eq!(map_id_consistency(unmerged, |id| id), Some(5.0 / 8.0));
        let none: [&[u32]; 1] = [&[0, 0, 0, 0, 0, 0]];
        let frames = truth[..1].iter().copied().zip(none.iter().copied());
        assert_eq!(map_id_consistency(frames, |id| id), None);
    }

    #[test]
    fn iou_and_object_accuracy_on_a_crafted_frame() {
        // Object 1 affords (4 px), object 2 does not (4 px), structure (2 px).
        let ids = [1, 1, 1, 1, 2, 2, 2, 2, 0, 0];
        let affords = |id: u32| id == 1;
        // Predicted: three of object 1, one of object 2, and the structure.
        let p = [0.9, 0.9, 0.9, 0.1, 0.8, 0.2, 0.2, 0.2, 0.9, 0.9];
        let s = score_frame(&p, &ids, &affords, PAPER_THRESHOLD);
        assert_eq!(s.iou, Some(3.0 / 7.0), "structure called positive is wrong");
        assert_eq!(s.object_accuracy, Some(1.0), "both majorities are right");
        let all_yes = [0.9; 10];
        let s = score_frame(&all_yes, &ids, &affords, PAPER_THRESHOLD);
        assert_eq!(s.iou, Some(0.4));
        assert_eq!(s.object_accuracy, Some(0.5));
        let s = score_frame(&[0.1; 2], &[0, 0], &affords, PAPER_THRESHOLD);
        assert_eq!((s.iou, s.object_accuracy), (None, None));
        let s = score_frame(&[0.9, 0.1], &[0, 0], &affords, PAPER_THRESHOLD);
        assert_eq!(
            (s.iou, s.object_accuracy),
            (Some(0.0), None),
            "a frame of structure called positive scores zero"
        );
    }

    #[test]
    fn pixel_scores_count_structure_as_negative_and_leave_undefined_ratios_out() {
        // Object 1 affords (4 px), object 2 does not (2 px), structure (2 px).
        let ids = [1, 1, 1, 1, 2, 2, 0, 0];
        let affords = |id: u32| id == 1;
        // Hits 3 of object 1; false alarms on object 2 (1 px) and the floor (1 px).
        let p = [0.9, 0.9, 0.9, 0.1, 0.7, 0.1, 0.6, 0.0];
        let s = pixel_scores(&p, &ids, &affords, PAPER_THRESHOLD);
        assert_eq!(s.precision, Some(3.0 / 5.0));
        assert_eq!(s.recall, Some(3.0 / 4.0));
        assert_eq!(s.f1, Some(6.0 / 9.0));
        // Nothing affords and nothing is predicted: all undefined.
        let s = pixel_scores(&[0.1; 8], &ids, &|_| false, PAPER_THRESHOLD);
        assert_eq!((s.precision, s.recall, s.f1), (None, None, None));
        // Nothing predicted where something affords: recall and F1 are 0.
        let s = pixel_scores(&[0.1; 8], &ids, &affords, PAPER_THRESHOLD);
        assert_eq!((s.precision, s.recall, s.f1), (None, Some(0.0), Some(0.0)));
        // A higher threshold drops the floor's 0.6; a lower one adds 0.1s.
        let s = pixel_scores(&p, &ids, &affords, 0.65);
        assert_eq!((s.precision, s.recall), (Some(3.0 / 4.0), Some(3.0 / 4.0)));
        let s = pixel_scores(&p, &ids, &affords, 0.05);
        assert_eq!((s.precision, s.recall), (Some(4.0 / 7.0), Some(1.0)));
    }

    #[test]
    fn annotation_rates_count_only_correct_labels() {
        let ids = [1, 1, 2, 2, 0];
        let affords = |id: u32| id == 1;
        let u = LABEL_UNKNOWN;
        let labels = [
            LABEL_POSITIVE,
            u,
            LABEL_POSITIVE,
            LABEL_NEGATIVE,
            LABEL_NEGATIVE,
        ];
        assert_eq!(annotation_rates(&labels, &ids, &affords), (0.2, 0.4));
    }
}
