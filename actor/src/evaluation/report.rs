//! The evaluation's results as the paper reports them: per-frame scores as
//! median with 10th and 90th percentile (Table 1), object-level scores from
//! a confusion matrix (Table 2), rendered as Markdown tables.

use std::fmt::Write as _;

use serde::{Deserialize, Serialize};

use super::selection::{Candidate, Selection};

/// Median and 10th / 90th percentiles of a per-frame score (linear
/// interpolation between order statistics), over the frames where it is
/// defined.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Percentiles {
    /// 50th percentile.
    pub median: f32,
    /// 10th percentile.
    pub p10: f32,
    /// 90th percentile.
    pub p90: f32,
    /// Frames the score was defined in.
    pub frames: usize,
}

impl Percentiles {
    /// The percentiles of the defined values of `values`; `None` if none is.
    pub fn of(values: impl IntoIterator<Item = Option<f32>>) -> Option<Self> {
        let mut sorted: Vec<f32> = values.into_iter().flatten().collect();
        if sorted.is_empty() {
            return None;
        }
        sorted.sort_by(f32::total_cmp);
        let at = |q: f32| {
            let position = q * (sorted.len() - 1) as f32;
            let (low, high) = (position.floor() as usize, position.ceil() as usize);
            let t = position - low as f32;
            sorted[low] + t * (sorted[high] - sorted[low])
        };
        Some(Self {
            median: at(0.5),
            p10: at(0.1),
            p90: at(0.9),
            frames: sorted.len(),
        })
    }
}

/// Counts of object-level predictions against outcomes.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Confusion {
    /// Predicted to afford, and the attempt succeeded.
    pub true_positives: usize,
    /// Predicted to afford, and the attempt failed.
    pub false_positives: usize,
    /// Predicted not to afford, and the attempt failed.
    pub true_negatives: usize,
    /// Predicted not to afford, and the attempt succeeded.
    pub false_negatives: usize,
}

impl Confusion {
    /// Counts one object.
    pub fn add(&mut self, predicted: bool, truth: bool) {
        match (predicted, truth) {
            (true, true) => self.true_positives += 1,
            (true, false) => self.false_positives += 1,
            (false, false) => self.true_negatives += 1,
            (false, true) => self.false_negatives += 1,
        }
    }

    /// Right predictions over all; `None` without objects.
    pub fn accuracy(&self) -> Option<f32> {
        let right = self.true_positives + self.true_negatives;
        ratio(right, right + self.false_positives + self.false_negatives)
    }

    /// True positives over predicted positives.
    pub fn precision(&self) -> Option<f32> {
        ratio(
            self.true_positives,
            self.true_positives + self.false_positives,
        )
    }

    /// True positives over actual positives.
    pub fn recall(&self) -> Option<f32> {
        ratio(
            self.true_positives,
            self.true_positives + self.false_negatives,
        )
    }

    /// 2·TP / (2·TP + FP + FN).
    pub fn f1(&self) -> Option<f32> {
        ratio(
            2 * self.true_positives,
            2 * self.true_positives + self.false_positives + self.false_negatives,
        )
    }
}

fn ratio(num: usize, den: usize) -> Option<f32> {
    (den > 0).then(|| num as f32 / den as f32)
}

/// Table 1's row for one affordance.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PixelRow {
    /// The affordance (`pick_up`, `push`).
    pub affordance: String,
    /// Per-frame pixel precision.
    pub precision: Option<Percentiles>,
    /// Per-frame pixel recall.
    pub recall: Option<Percentiles>,
    /// Per-frame pixel F1.
    pub f1: Option<Percentiles>,
    /// Per-frame object accuracy (majority vote of each visible object's pixels).
    pub object_accuracy: Option<Percentiles>,
    /// Of the pixels wrongly predicted positive (all frames pooled), the
    /// share on the floor and walls rather than on objects that do not
    /// afford it: a network that has not learnt what an object is spends
    /// its false positives there (the paper saw this in its baselines).
    pub false_positives_on_structure: Option<f32>,
    /// The median per-frame F1 at each of [`THRESHOLDS`]: where a network's
    /// probabilities are too low or too high for the paper's 0.5, how much
    /// a threshold chosen on the validation rooms would give back.
    #[serde(default)]
    pub f1_by_threshold: Vec<ThresholdF1>,
}

/// Thresholds tried for [`PixelRow::f1_by_threshold`] and [`ObjectRow::best`].
pub const THRESHOLDS: [f32; 18] = [
    0.01, 0.02, 0.03, 0.05, 0.07, 0.1, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.45, 0.5, 0.6, 0.7, 0.8,
    0.9,
];

/// An F1 score at a threshold.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ThresholdF1 {
    /// The threshold.
    pub threshold: f32,
    /// The F1 there.
    pub f1: f32,
}

impl ThresholdF1 {
    /// The highest F1 of `scores` (the lower threshold on a tie); `None` if empty.
    pub fn best(scores: &[ThresholdF1]) -> Option<ThresholdF1> {
        scores
            .iter()
            .copied()
            .reduce(|best, s| if s.f1 > best.f1 { s } else { best })
    }
}

impl PixelRow {
    /// The threshold of [`THRESHOLDS`] with the highest median per-frame F1.
    pub fn best(&self) -> Option<ThresholdF1> {
        ThresholdF1::best(&self.f1_by_threshold)
    }
}

/// Table 2's row for one affordance.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ObjectRow {
    /// The affordance (`pick_up`, `push`).
    pub affordance: String,
    /// The threshold of the predictions (0.5, the paper's, unless the
    /// evaluation was given another).
    #[serde(default = "paper_threshold")]
    pub threshold: f32,
    /// Predictions (mean probability over the object's pixels ≥
    /// [`ObjectRow::threshold`]) against the outcome of trying.
    pub confusion: Confusion,
    /// [`Confusion::accuracy`].
    pub accuracy: Option<f32>,
    /// [`Confusion::precision`].
    pub precision: Option<f32>,
    /// [`Confusion::recall`].
    pub recall: Option<f32>,
    /// [`Confusion::f1`].
    pub f1: Option<f32>,
    /// Area under the ROC curve of the mean probability as a score for
    /// success: how well the network ranks the objects whatever the
    /// threshold (0.5 = chance), so a network that rates every object
    /// below 0.5 still shows whether it has learnt which ones afford it.
    pub auc: Option<f32>,
    /// The threshold of [`THRESHOLDS`] that maximises F1 on these objects,
    /// with that F1: choose it on the validation rooms and evaluate the
    /// test rooms at it (`actor evaluate --threshold`), never the other way.
    #[serde(default)]
    pub best: Option<ThresholdF1>,
}

fn paper_threshold() -> f32 {
    crate::frame_scores::PAPER_THRESHOLD
}

impl ObjectRow {
    /// The row of `affordance` from each tried object's mean probability
    /// and whether trying succeeded, at the paper's threshold.
    pub fn new(affordance: String, scored: &[(f32, bool)]) -> Self {
        Self::at(affordance, scored, paper_threshold())
    }

    /// The row of `affordance` with objects predicted where their mean
    /// probability is at least `threshold`.
    pub fn at(affordance: String, scored: &[(f32, bool)], threshold: f32) -> Self {
        let confusion_at = |threshold: f32| {
            let mut confusion = Confusion::default();
            for &(probability, succeeded) in scored {
                confusion.add(probability >= threshold, succeeded);
            }
            confusion
        };
        let confusion = confusion_at(threshold);
        let by_threshold: Vec<ThresholdF1> = THRESHOLDS
            .iter()
            .filter_map(|&threshold| {
                let f1 = confusion_at(threshold).f1()?;
                Some(ThresholdF1 { threshold, f1 })
            })
            .collect();
        Self {
            affordance,
            threshold,
            best: ThresholdF1::best(&by_threshold),
            confusion,
            accuracy: confusion.accuracy(),
            precision: confusion.precision(),
            recall: confusion.recall(),
            f1: confusion.f1(),
            auc: roc_auc(scored),
        }
    }
}

/// The probability that a random positive scores above a random negative
/// (ties count half); `None` without both.
fn roc_auc(scored: &[(f32, bool)]) -> Option<f32> {
    let positives: Vec<f32> = scored.iter().filter(|s| s.1).map(|s| s.0).collect();
    let negatives: Vec<f32> = scored.iter().filter(|s| !s.1).map(|s| s.0).collect();
    if positives.is_empty() || negatives.is_empty() {
        return None;
    }
    let wins: f64 = positives
        .iter()
        .flat_map(|&p| {
            negatives.iter().map(move |&n| match p.total_cmp(&n) {
                std::cmp::Ordering::Greater => 1.0,
                std::cmp::Ordering::Equal => 0.5,
                std::cmp::Ordering::Less => 0.0,
            })
        })
        .sum();
    Some((wins / (positives.len() * negatives.len()) as f64) as f32)
}

/// One object's trial: what the U-Net predicted from in front of it and
/// what trying each affordance there did.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ObjectTrial {
    /// The room.
    pub scene: String,
    /// The object's id.
    pub object: String,
    /// Its type.
    pub object_type: String,
    /// Pixels it covered in the view it was tried from.
    pub pixels: usize,
    /// Horizontal distance from the agent to the object's centre, metres.
    pub distance_m: f32,
    /// Per affordance (plane order), the mean probability over its pixels.
    pub predicted: Vec<f32>,
    /// How the outcome was found.
    pub scored_by: ScoredBy,
    /// Per affordance, whether trying it succeeded (for an object judged by
    /// the ground truth: whether the robot could).
    pub succeeded: Vec<bool>,
    /// Per affordance, why it failed (`None` on success, and for an object
    /// judged by the ground truth).
    pub failure: Vec<Option<String>>,
}

/// Where Table 2's outcome for an object came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ScoredBy {
    /// The robot tried each affordance on it.
    Trial,
    /// No reachable position brings it within reach: the simulator's rules
    /// for the robot (pickupable, payload, gripper width, movable) decide.
    GroundTruth,
}

/// One affordance's scores in these rooms at the thresholds that did best
/// on the validation rooms: a threshold read off the validation rooms and
/// applied here, never chosen on these rooms' own scores.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AtValidationThreshold {
    /// The affordance (`pick_up`, `push`).
    pub affordance: String,
    /// Table 1: the threshold with the best median pixel F1 on the
    /// validation rooms, with that F1 there.
    pub pixel_validation: Option<ThresholdF1>,
    /// Table 1: the median pixel F1 in these rooms at that threshold.
    pub pixel_f1: Option<f32>,
    /// Table 2: the threshold with the best F1 on the validation rooms,
    /// with that F1 there.
    pub object_validation: Option<ThresholdF1>,
    /// Table 2 in these rooms at that threshold.
    pub object: Option<ObjectRow>,
}

/// The scores of a fixed prediction that needs no network, beside which a
/// network's scores mean something.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Reference {
    /// What the reference predicts.
    pub name: String,
    /// Its Table 1 rows.
    pub pixel: Vec<PixelRow>,
    /// Its Table 2 rows.
    pub object: Vec<ObjectRow>,
}

/// Everything one evaluation measured.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Report {
    /// What was evaluated (a checkpoint, or an untrained network).
    pub model: String,
    /// The checkpoint's environment step (`None` for an untrained network).
    pub checkpoint_step: Option<u64>,
    /// How the checkpoint was chosen on the validation rooms, when it was.
    pub selection: Option<Selection>,
    /// The rooms.
    pub scenes: Vec<String>,
    /// Test frames scored (Table 1).
    pub frames: usize,
    /// The threshold of both tables' predictions (0.5, the paper's, unless
    /// the evaluation was given one chosen on the validation rooms).
    #[serde(default = "paper_threshold")]
    pub threshold: f32,
    /// Table 1, one row per affordance.
    pub pixel: Vec<PixelRow>,
    /// Objects of the rooms (the floor excluded).
    pub objects: usize,
    /// Objects no reachable position shows (`room/id`): the only ones left
    /// out of Table 2.
    pub objects_unseen: Vec<String>,
    /// Table 2, one row per affordance, over every object in
    /// [`Report::trials`].
    pub object: Vec<ObjectRow>,
    /// Every scored object, tried or judged by the ground truth.
    pub trials: Vec<ObjectTrial>,
    /// Predicting every pixel and object positive, on the same views and
    /// objects: the floor that recall alone reaches.
    pub all_positive: Reference,
    /// Both tables at the thresholds chosen on the validation rooms, per
    /// affordance (`evaluate --select`; empty otherwise).
    #[serde(default)]
    pub at_validation_thresholds: Vec<AtValidationThreshold>,
}

impl Report {
    /// This report as a candidate for checkpoint selection: its median
    /// pixel F1 (Table 1) and its F1 (Table 2) per affordance.
    pub fn candidate(&self, step: u64) -> Candidate {
        Candidate::new(
            step,
            self.pixel
                .iter()
                .map(|row| row.f1.map(|p| p.median))
                .collect(),
            self.object.iter().map(|row| row.f1).collect(),
        )
    }

    /// Scores both tables of this report at the thresholds that did best in
    /// `validation` (the same network on the validation rooms): Table 1 from
    /// this report's sweep over [`THRESHOLDS`], Table 2 from its trials.
    pub fn score_at_validation_thresholds(&mut self, validation: &Report) {
        self.at_validation_thresholds = self
            .pixel
            .iter()
            .zip(&self.object)
            .enumerate()
            .map(|(plane, (pixel, object))| {
                let pixel_validation = validation.pixel.get(plane).and_then(PixelRow::best);
                let object_validation = validation.object.get(plane).and_then(|row| row.best);
                let scored: Vec<(f32, bool)> = self
                    .trials
                    .iter()
                    .map(|t| (t.predicted[plane], t.succeeded[plane]))
                    .collect();
                AtValidationThreshold {
                    affordance: pixel.affordance.clone(),
                    pixel_validation,
                    pixel_f1: pixel_validation.and_then(|chosen| {
                        pixel
                            .f1_by_threshold
                            .iter()
                            .find(|s| s.threshold == chosen.threshold)
                            .map(|s| s.f1)
                    }),
                    object_validation,
                    object: object_validation.map(|chosen| {
                        ObjectRow::at(object.affordance.clone(), &scored, chosen.threshold)
                    }),
                }
            })
            .collect();
    }

    /// This report's scores of checkpoint `step`, for the learner's
    /// background scorer (`evaluate --scores`) and a later `--select`.
    pub fn scores(&self, step: u64, views_per_scene: usize) -> proto::ValidationScores {
        proto::ValidationScores {
            step,
            scenes: self.scenes.clone(),
            views_per_scene,
            threshold: self.threshold,
            affordances: self
                .pixel
                .iter()
                .zip(&self.object)
                .map(|(pixel, object)| proto::AffordanceScores {
                    affordance: pixel.affordance.clone(),
                    pixel_f1: pixel.f1.map(|p| p.median),
                    object_f1: object.f1,
                    object_auc: object.auc,
                })
                .collect(),
        }
    }

    /// Tables 1 and 2 as Markdown, the network's rows beside the
    /// all-positive reference's.
    pub fn to_markdown(&self) -> String {
        let mut out = String::new();
        let rooms = self.scenes.join(", ");
        let _ = writeln!(out, "Evaluation of {} in {rooms}\n", self.model);
        if let Some(selection) = &self.selection {
            let _ = writeln!(out, "{}\n", selection.describe());
        }
        let _ = writeln!(
            out,
            "Table 1: per-frame pixel scores at threshold {} on {} test frames, median [10th, \
             90th percentile] (frames where defined)\n",
            self.threshold, self.frames
        );
        out.push_str(
            "| prediction | affordance | precision | recall | F1 | object accuracy | false positives on floor & walls |\n",
        );
        out.push_str("|---|---|---|---|---|---|---|\n");
        let reference = &self.all_positive;
        for (name, rows) in [
            ("network", &self.pixel),
            (&reference.name, &reference.pixel),
        ] {
            for row in rows {
                let _ = writeln!(
                    out,
                    "| {name} | {} | {} | {} | {} | {} | {} |",
                    row.affordance,
                    cell(row.precision),
                    cell(row.recall),
                    cell(row.f1),
                    cell(row.object_accuracy),
                    number(row.false_positives_on_structure)
                );
            }
        }
        let judged = self
            .trials
            .iter()
            .filter(|t| t.scored_by == ScoredBy::GroundTruth)
            .count();
        let _ = writeln!(
            out,
            "\nTable 2: object-level prediction (mean over the object's pixels ≥ {}) against \
             trying it: {} of {} objects, {} tried, {judged} out of reach from every position and \
             judged by the simulator's ground truth, {} in view from no reachable position\n",
            self.threshold,
            self.trials.len(),
            self.objects,
            self.trials.len() - judged,
            self.objects_unseen.len()
        );
        out.push_str(
            "| prediction | affordance | accuracy | precision | recall | F1 | ROC AUC | succeeded | predicted |\n",
        );
        out.push_str("|---|---|---|---|---|---|---|---|---|\n");
        for (name, rows) in [
            ("network", &self.object),
            (&reference.name, &reference.object),
        ] {
            for row in rows {
                let c = row.confusion;
                let _ = writeln!(
                    out,
                    "| {name} | {} | {} | {} | {} | {} | {} | {} | {} |",
                    row.affordance,
                    number(row.accuracy),
                    number(row.precision),
                    number(row.recall),
                    number(row.f1),
                    number(row.auc),
                    c.true_positives + c.false_negatives,
                    c.true_positives + c.false_positives
                );
            }
        }
        out.push_str(
            "\nThresholds that would do best in these rooms (choose on the validation rooms, \
             then evaluate the test rooms with --threshold):\n\n",
        );
        out.push_str("| affordance | Table 1 median F1: best threshold → F1 | Table 2 F1: best threshold → F1 |\n");
        out.push_str("|---|---|---|\n");
        let best = |b: Option<ThresholdF1>| {
            b.map_or_else(|| "–".into(), |b| format!("{} → {:.2}", b.threshold, b.f1))
        };
        for (pixel, object) in self.pixel.iter().zip(&self.object) {
            let _ = writeln!(
                out,
                "| {} | {} | {} |",
                pixel.affordance,
                best(pixel.best()),
                best(object.best)
            );
        }
        let _ = writeln!(
            out,
            "\nTable 2 by object type (the share of the objects that afforded it, and the \
             network's mean prediction for them):\n\n{}",
            super::by_type::markdown(
                &super::by_type::by_object_type(self.trials.iter().map(|t| (
                    t.object_type.as_str(),
                    t.predicted.as_slice(),
                    t.succeeded.as_slice()
                ))),
                &self
                    .object
                    .iter()
                    .map(|o| o.affordance.clone())
                    .collect::<Vec<_>>()
            )
        );
        if !self.at_validation_thresholds.is_empty() {
            out.push_str(
                "\nAt the thresholds chosen on the validation rooms (the threshold, its F1 \
                 there → the score here):\n\n",
            );
            out.push_str("| affordance | Table 1 median F1 | Table 2 precision / recall / F1 |\n");
            out.push_str("|---|---|---|\n");
            for row in &self.at_validation_thresholds {
                let object = row.object.as_ref().map_or_else(
                    || "–".into(),
                    |o| {
                        format!(
                            "{} / {} / {}",
                            number(o.precision),
                            number(o.recall),
                            number(o.f1)
                        )
                    },
                );
                let _ = writeln!(
                    out,
                    "| {} | {} → {} | {} → {object} |",
                    row.affordance,
                    best(row.pixel_validation),
                    number(row.pixel_f1),
                    best(row.object_validation),
                );
            }
        }
        out
    }
}

fn cell(p: Option<Percentiles>) -> String {
    match p {
        Some(p) => format!(
            "{:.2} [{:.2}, {:.2}] ({})",
            p.median, p.p10, p.p90, p.frames
        ),
        None => "–".into(),
    }
}

fn number(x: Option<f32>) -> String {
    x.map_or_else(|| "–".into(), |x| format!("{x:.2}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_interpolate_between_order_statistics_and_skip_undefined() {
        let values = (0..=10).rev().map(|i| Some(i as f32)).chain([None, None]);
        let p = Percentiles::of(values).unwrap();
        assert_eq!((p.median, p.p10, p.p90, p.frames), (5.0, 1.0, 9.0, 11));
        let p = Percentiles::of([Some(0.0), Some(1.0)]).unwrap();
        assert!((p.median - 0.5).abs() < 1e-6 && (p.p10 - 0.1).abs() < 1e-6);
        assert_eq!(Percentiles::of([None, None]), None);
    }

    #[test]
    fn confusion_gives_the_usual_ratios() {
        let mut c = Confusion::default();
        for (predicted, truth) in [(true, true), (true, true), (true, false), (false, true)] {
            c.add(predicted, truth);
        }
        c.add(false, false);
        assert_eq!(c.accuracy(), Some(3.0 / 5.0));
        assert_eq!(c.precision(), Some(2.0 / 3.0));
        assert_eq!(c.recall(), Some(2.0 / 3.0));
        assert_eq!(c.f1(), Some(4.0 / 6.0));
        let row = ObjectRow::new(
            "push".into(),
            &[(0.9, true), (0.2, true), (0.4, false), (0.1, false)],
        );
        assert_eq!(row.confusion.true_positives, 1);
        assert_eq!(row.confusion.false_negatives, 1);
        assert_eq!(row.auc, Some(0.75), "3 of the 4 pairs ranked right");
        let low = ObjectRow::new(
            "pick_up".into(),
            &[(0.04, true), (0.01, false), (0.04, false)],
        );
        assert_eq!(
            (low.f1, low.auc),
            (Some(0.0), Some(0.75)),
            "ties count half"
        );
        let none = Confusion::default();
        assert_eq!(
            (none.accuracy(), none.precision(), none.f1()),
            (None, None, None)
        );
    }

    /// A one-affordance report whose objects have these (mean probability,
    /// outcome) pairs and whose pixel sweep is `sweep`.
    fn report(objects: &[(f32, bool)], sweep: &[(f32, f32)]) -> Report {
        let trial = |&(p, success): &(f32, bool)| ObjectTrial {
            scene: "FloorPlan221".into(),
            object: "Book|1".into(),
            object_type: "Book".into(),
            pixels: 20,
            distance_m: 1.0,
            predicted: vec![p],
            scored_by: ScoredBy::Trial,
            succeeded: vec![success],
            failure: vec![None],
        };
        let pixel = PixelRow {
            affordance: "pick_up".into(),
            precision: None,
            recall: None,
            f1: None,
            object_accuracy: None,
            false_positives_on_structure: None,
            f1_by_threshold: sweep
                .iter()
                .map(|&(threshold, f1)| ThresholdF1 { threshold, f1 })
                .collect(),
        };
        Report {
            model: "a test".into(),
            checkpoint_step: Some(1),
            selection: None,
            scenes: vec![],
            frames: 0,
            threshold: 0.5,
            pixel: vec![pixel.clone()],
            objects: objects.len(),
            objects_unseen: vec![],
            object: vec![ObjectRow::new("pick_up".into(), objects)],
            trials: objects.iter().map(trial).collect(),
            all_positive: Reference {
                name: "all positive".into(),
                pixel: vec![pixel],
                object: vec![],
            },
            at_validation_thresholds: vec![],
        }
    }

    #[test]
    fn test_scores_are_read_at_the_thresholds_the_validation_rooms_chose() {
        // Validation: pixels do best at 0.7; objects at 0.6 (0.55 is
        // predicted, 0.5 is not).
        let validation = report(
            &[(0.65, true), (0.55, false), (0.2, false)],
            &[(0.5, 0.10), (0.7, 0.30), (0.8, 0.20)],
        );
        // Test rooms: their own best would be 0.8 and 0.5; the validation's
        // thresholds are applied instead.
        let mut test = report(
            &[(0.9, true), (0.55, true), (0.58, false), (0.1, false)],
            &[(0.5, 0.15), (0.7, 0.25), (0.8, 0.40)],
        );
        test.score_at_validation_thresholds(&validation);
        let row = &test.at_validation_thresholds[0];
        assert_eq!(row.pixel_validation.map(|t| t.threshold), Some(0.7));
        assert_eq!(
            row.pixel_f1,
            Some(0.25),
            "the test sweep at 0.7, not its best"
        );
        assert_eq!(row.object_validation.map(|t| t.threshold), Some(0.6));
        let object = row.object.as_ref().unwrap();
        assert_eq!(object.threshold, 0.6);
        assert_eq!(
            (
                object.confusion.true_positives,
                object.confusion.false_negatives
            ),
            (1, 1),
            "0.9 predicted, 0.55 missed at 0.6"
        );
        assert!(test
            .to_markdown()
            .contains("| pick_up | 0.7 → 0.30 → 0.25 |"));
    }
}
