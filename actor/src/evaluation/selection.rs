//! Honest model selection: every kept checkpoint of a run is scored on the
//! validation rooms (FloorPlan221–225), and only the one they choose is
//! scored on the test rooms, once. Choosing among checkpoints by their test
//! scores would report the best of several draws as if it were one.

use std::fmt::Write as _;

use serde::{Deserialize, Serialize};

/// What the selection maximises, in words (every report that used it says so).
pub const RULE: &str = "the mean over affordances of Table 1's median pixel F1 and Table 2's \
                        F1 on the validation rooms (an undefined score counts 0), among the \
                        checkpoints whose U-Net has trained; a tie goes to the later checkpoint";

/// One checkpoint's validation scores.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Candidate {
    /// The checkpoint's environment step.
    pub step: u64,
    /// The score [`RULE`] describes.
    pub score: f32,
    /// Per affordance, Table 1's median pixel F1.
    pub pixel_f1: Vec<Option<f32>>,
    /// Per affordance, Table 2's F1.
    pub object_f1: Vec<Option<f32>>,
}

impl Candidate {
    /// The candidate that recorded validation `scores` make.
    pub fn from_scores(scores: &proto::ValidationScores) -> Self {
        Self::new(
            scores.step,
            scores.affordances.iter().map(|a| a.pixel_f1).collect(),
            scores.affordances.iter().map(|a| a.object_f1).collect(),
        )
    }

    /// The candidate of checkpoint `step` with these validation scores per
    /// affordance (see [`crate::evaluation::Report::candidate`]), scored by [`RULE`].
    pub fn new(step: u64, pixel_f1: Vec<Option<f32>>, object_f1: Vec<Option<f32>>) -> Self {
        let terms: Vec<f32> = pixel_f1
            .iter()
            .chain(&object_f1)
            .map(|f| f.unwrap_or(0.0))
            .collect();
        let score = if terms.is_empty() {
            0.0
        } else {
            terms.iter().sum::<f32>() / terms.len() as f32
        };
        Self {
            step,
            score,
            pixel_f1,
            object_f1,
        }
    }
}

/// How a run's checkpoint was chosen.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Selection {
    /// [`RULE`].
    pub rule: String,
    /// The validation rooms.
    pub scenes: Vec<String>,
    /// Validation views per room (Table 1).
    pub views_per_scene: usize,
    /// Every checkpoint scored, in step order.
    pub candidates: Vec<Candidate>,
    /// The checkpoint chosen.
    pub chosen_step: u64,
    /// How many of the candidates' scores are those the run's learner
    /// recorded during training (`RUN_DIR/validation/`); the others were
    /// scored for this report.
    #[serde(default)]
    pub recorded: usize,
}

impl Selection {
    /// The best of `candidates` by [`RULE`]; `None` without any.
    pub fn choose(
        scenes: Vec<String>,
        views_per_scene: usize,
        mut candidates: Vec<Candidate>,
    ) -> Option<Self> {
        candidates.sort_by_key(|c| c.step);
        // `max_by` keeps the last of equal maxima: the later step.
        let chosen_step = candidates
            .iter()
            .max_by(|a, b| a.score.total_cmp(&b.score))?
            .step;
        Some(Self {
            rule: RULE.to_string(),
            scenes,
            views_per_scene,
            candidates,
            chosen_step,
            recorded: 0,
        })
    }

    /// One paragraph for a report: the rule and each checkpoint's score.
    pub fn describe(&self) -> String {
        let mut out = format!(
            "Checkpoint chosen on the validation rooms ({}, {} views each{}) by {}: step {}. \
             Scores:",
            self.scenes.join(", "),
            self.views_per_scene,
            if self.recorded > 0 {
                format!(
                    "; {} of them scored in the background during training",
                    self.recorded
                )
            } else {
                String::new()
            },
            self.rule,
            self.chosen_step
        );
        for c in &self.candidates {
            let _ = write!(out, " {} → {:.3};", c.step, c.score);
        }
        out.pop();
        out.push('.');
        out
    }
}

/// The validation scores the run's learner recorded for the checkpoints
/// `steps` (`RUN_DIR/validation/<step>.json`, written by `evaluate
/// --scores`), in step order: those of other steps, or of another number
/// of views per room than the first one found, are left out. A file that
/// does not parse is an error that names it.
pub fn recorded_scores(
    run_dir: &std::path::Path,
    steps: &[u64],
) -> anyhow::Result<Vec<proto::ValidationScores>> {
    use anyhow::Context;
    let dir = run_dir.join(proto::VALIDATION_DIR);
    let mut found: Vec<proto::ValidationScores> = Vec::new();
    for &step in steps {
        let path = dir.join(format!("{step}.json"));
        let text = match std::fs::read_to_string(&path) {
            Ok(text) => text,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => continue,
            Err(e) => return Err(e).with_context(|| format!("reading {}", path.display())),
        };
        let scores: proto::ValidationScores = serde_json::from_str(&text).with_context(|| {
            format!(
                "parsing {} (delete it, or pass --rescore, to score the checkpoint afresh)",
                path.display()
            )
        })?;
        if scores.step != step {
            anyhow::bail!(
                "{} holds the scores of step {}, not {step}",
                path.display(),
                scores.step
            );
        }
        if found
            .first()
            .is_none_or(|first| first.views_per_scene == scores.views_per_scene)
        {
            found.push(scores);
        }
    }
    Ok(found)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn candidate(step: u64, score: f32) -> Candidate {
        Candidate {
            step,
            score,
            pixel_f1: vec![Some(score)],
            object_f1: vec![Some(score)],
        }
    }

    #[test]
    fn the_best_score_wins_and_a_tie_goes_to_the_later_checkpoint() {
        let scenes = vec!["FloorPlan221".to_string()];
        let chosen = |c: Vec<Candidate>| Selection::choose(scenes.clone(), 4, c).unwrap();
        let best = chosen(vec![
            candidate(30, 0.2),
            candidate(10, 0.5),
            candidate(20, 0.4),
        ]);
        assert_eq!(best.chosen_step, 10);
        assert_eq!(
            best.candidates.iter().map(|c| c.step).collect::<Vec<_>>(),
            vec![10, 20, 30],
            "in step order"
        );
        let tie = chosen(vec![
            candidate(10, 0.5),
            candidate(30, 0.5),
            candidate(20, 0.1),
        ]);
        assert_eq!(tie.chosen_step, 30);
        assert!(tie.describe().contains("step 30") && tie.describe().contains("20 → 0.100"));
        assert_eq!(Selection::choose(scenes, 4, Vec::new()), None);
    }

    fn scores(step: u64, views: usize, pixel: f32) -> proto::ValidationScores {
        proto::ValidationScores {
            step,
            scenes: vec!["FloorPlan221".into()],
            views_per_scene: views,
            threshold: 0.5,
            affordances: vec![proto::AffordanceScores {
                affordance: "pick_up".into(),
                pixel_f1: Some(pixel),
                object_f1: None,
                object_auc: Some(0.7),
            }],
        }
    }

    #[test]
    fn recorded_scores_are_read_for_kept_checkpoints_of_one_view_count() {
        let run = tempfile::tempdir().unwrap();
        let dir = run.path().join(proto::VALIDATION_DIR);
        std::fs::create_dir_all(&dir).unwrap();
        let write = |name: &str, s: &proto::ValidationScores| {
            std::fs::write(dir.join(name), serde_json::to_string(s).unwrap()).unwrap();
        };
        write("10.json", &scores(10, 20, 0.1));
        write("20.json", &scores(20, 120, 0.9)); // other views: left out
        write("30.json", &scores(30, 20, 0.3));
        write("40.json", &scores(40, 20, 0.4)); // a checkpoint no longer kept
        let found = recorded_scores(run.path(), &[10, 20, 30, 35]).unwrap();
        assert_eq!(
            found.iter().map(|s| s.step).collect::<Vec<_>>(),
            vec![10, 30]
        );
        let candidate = Candidate::from_scores(&found[1]);
        assert_eq!(candidate.step, 30);
        assert_eq!(candidate.pixel_f1, vec![Some(0.3)]);
        assert_eq!(candidate.object_f1, vec![None]);
        assert!(
            (candidate.score - 0.15).abs() < 1e-6,
            "an undefined F1 counts 0"
        );

        write("35.json", &scores(36, 20, 0.3));
        let e = recorded_scores(run.path(), &[35]).unwrap_err().to_string();
        assert!(e.contains("35.json") && e.contains("step 36"), "{e}");
        std::fs::write(dir.join("35.json"), "{").unwrap();
        let e = format!("{:#}", recorded_scores(run.path(), &[35]).unwrap_err());
        assert!(e.contains("--rescore"), "{e}");
    }
}
