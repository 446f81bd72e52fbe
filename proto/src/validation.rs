//! Scores of one checkpoint on the validation rooms, as the learner's
//! background scorer hands them over: `actor evaluate --scores FILE`
//! writes them, the learner publishes them (history, `/metrics`,
//! TensorBoard, the live page), and `actor evaluate --select` chooses a
//! checkpoint from them. One type, so that writer and readers agree.

use serde::{Deserialize, Serialize};

/// Directory of a run that holds one scores file per scored checkpoint
/// (`<step>.json`).
pub const VALIDATION_DIR: &str = "validation";

/// One affordance's validation scores.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AffordanceScores {
    /// The affordance's name (`pick_up`, `push`).
    pub affordance: String,
    /// Table 1: median over views of the pixel F1 (`None`: defined in no view).
    pub pixel_f1: Option<f32>,
    /// Table 2: F1 of the object-level predictions.
    pub object_f1: Option<f32>,
    /// Table 2: ROC AUC of the object-level predictions.
    pub object_auc: Option<f32>,
}

/// A checkpoint's scores on the validation rooms.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ValidationScores {
    /// The checkpoint's environment step.
    pub step: u64,
    /// The rooms scored.
    pub scenes: Vec<String>,
    /// Views per room of Table 1.
    pub views_per_scene: usize,
    /// The threshold both tables predicted at.
    pub threshold: f32,
    /// Per affordance of the task, in its order.
    pub affordances: Vec<AffordanceScores>,
}

impl ValidationScores {
    /// The scores as flat `(name, value)` pairs, `<affordance>/<score>`,
    /// the defined ones only: what a history record and TensorBoard show.
    pub fn named_values(&self) -> Vec<(String, f32)> {
        self.affordances
            .iter()
            .flat_map(|a| {
                [
                    ("pixel_f1", a.pixel_f1),
                    ("object_f1", a.object_f1),
                    ("object_auc", a.object_auc),
                ]
                .into_iter()
                .filter_map(move |(name, value)| Some((format!("{}/{name}", a.affordance), value?)))
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn named_values_leave_out_undefined_scores() {
        let scores = ValidationScores {
            step: 10,
            scenes: vec!["FloorPlan221".into()],
            views_per_scene: 20,
            threshold: 0.5,
            affordances: vec![
                AffordanceScores {
                    affordance: "pick_up".into(),
                    pixel_f1: Some(0.25),
                    object_f1: None,
                    object_auc: Some(0.8),
                },
                AffordanceScores {
                    affordance: "push".into(),
                    pixel_f1: None,
                    object_f1: Some(0.5),
                    object_auc: None,
                },
            ],
        };
        assert_eq!(
            scores.named_values(),
            vec![
                ("pick_up/pixel_f1".to_string(), 0.25),
                ("pick_up/object_auc".to_string(), 0.8),
                ("push/object_f1".to_string(), 0.5),
            ]
        );
        let text = serde_json::to_string(&scores).unwrap();
        assert_eq!(
            serde_json::from_str::<ValidationScores>(&text).unwrap(),
            scores
        );
    }
}
