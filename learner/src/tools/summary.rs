//! `learner summary`: a run's history as a table of means per span of
//! environment steps (every episode metric, successes per thousand steps
//! per affordance, the policy's entropy, the U-Net's gradient steps per
//! episode and what its dataset held: training frames, and those with
//! positives per affordance) and the background scorer's validation
//! scores (each score's median over the checkpoints scored in the span: one
//! checkpoint's score on few views swings by more than most settings move
//! it, docs/ladder.md), so
//! that a long run, or two runs side by side, can be read without plotting:
//! where the success rate peaked, when the policy stopped trying. Repeats of
//! one setting (seeds) summarise as the runs' mean with their range. A
//! second table counts the interactions by the type of the object tried,
//! per span: which objects the labels come from.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use std::collections::BTreeMap;

use proto::{Affordance, AffordanceStat, StatKey};
use serde_json::{json, Value};

use crate::history::read_records;
use crate::tools::tries_table::{self, TriedType, Tries};

/// One metric over one span: the mean, and over repeats the lowest and the
/// highest of the runs' means (one run: all three are its mean).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Spread {
    /// Mean of the runs' means (one run: its mean).
    pub mean: f64,
    /// Lowest of the runs' means.
    pub min: f64,
    /// Highest of the runs' means.
    pub max: f64,
}

impl Spread {
    /// The spread of one run's mean.
    fn one(mean: f64) -> Self {
        Self {
            mean,
            min: mean,
            max: mean,
        }
    }

    /// The spread of several runs' values; `None` without any.
    pub fn of(values: impl IntoIterator<Item = f64>) -> Option<Self> {
        let values: Vec<f64> = values.into_iter().collect();
        (!values.is_empty()).then(|| Self {
            mean: values.iter().sum::<f64>() / values.len() as f64,
            min: values.iter().copied().fold(f64::INFINITY, f64::min),
            max: values.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        })
    }
}

/// Means over one span of environment steps.
#[derive(Debug, Clone, PartialEq)]
pub struct SummaryRow {
    /// First environment step of the span.
    pub from_steps: u64,
    /// End of the span: the next span's first step, or the last step seen
    /// (over repeats: by the shortest run).
    pub to_steps: u64,
    /// Episodes that ended in the span (over repeats: in all runs).
    pub episodes: usize,
    /// Mean of each of [`Summary::fields`] over the span's episodes that
    /// reported it.
    pub means: Vec<Option<Spread>>,
    /// Successful attempts per thousand steps of the span's episodes, per
    /// affordance in [`Affordance::ALL`] order (each success labels an
    /// object positive: how fast positives enter the data); none without
    /// an episode that reported the affordance's attempts.
    pub successes_per_kilostep: Vec<Option<Spread>>,
    /// Mean entropy of the policy updates in the span.
    pub entropy: Option<Spread>,
    /// The U-Net's gradient steps in the span per episode that ended in it
    /// (histories written before rounds recorded their steps: none).
    pub unet_steps_per_episode: Option<Spread>,
    /// The share of the U-Net rounds' time in the span spent outside their
    /// gradient steps (the validation gate and the temperature refit; on 2
    /// cores every run waits for that thread; histories written before
    /// rounds recorded their seconds: none).
    pub unet_time_outside_steps: Option<Spread>,
    /// The U-Net's training frames at the span's last round (histories
    /// written before rounds recorded their frames: none).
    pub unet_training_frames: Option<Spread>,
    /// Of those, the frames with positives, per affordance in
    /// [`Affordance::ALL`] order (histories written before rounds recorded
    /// them: none).
    pub unet_positive_frames: Vec<Option<Spread>>,
    /// Checkpoints the background scorer scored in the span (none: it
    /// scored none there).
    pub validation_checkpoints: Option<Spread>,
    /// Per score of [`Summary::validation_scores`], its median over the
    /// span's scored checkpoints.
    pub validation: Vec<Option<Spread>>,
    /// Interactions by (affordance, object type) in the span's episodes:
    /// attempts and successes (over repeats: all runs together).
    pub tries: Tries,
}

/// A run's history, or repeats' histories, span by span.
#[derive(Debug, Clone, PartialEq)]
pub struct Summary {
    /// Runs summarised: one, or repeats of one setting.
    pub runs: usize,
    /// The episode metrics some episode reported, in wire order.
    pub fields: Vec<StatKey>,
    /// The background scorer's scores some span recorded (`pick_up/pixel_f1`,
    /// …), in name order.
    pub validation_scores: Vec<String>,
    /// One row per span that ended an episode (in every run), in step order.
    pub rows: Vec<SummaryRow>,
}

impl Summary {
    /// Every (affordance, object type) some span tried: by affordance, then
    /// the most attempts first.
    pub fn tried_types(&self) -> Vec<TriedType> {
        tries_table::tried_types(self.rows.iter().map(|row| &row.tries))
    }
}

/// Sums over one span, as the history is read.
#[derive(Default)]
struct SpanSums {
    episodes: usize,
    /// Sum and count per metric.
    fields: BTreeMap<StatKey, (f64, usize)>,
    /// Per affordance: successes and steps of the episodes that reported
    /// its attempts.
    successes: [(f64, f64); Affordance::COUNT],
    entropy: (f64, usize),
    /// Gradient steps of the U-Net rounds that recorded them, and whether any did.
    unet_steps: Option<u64>,
    /// Seconds of the U-Net rounds that recorded them: in their gradient
    /// steps, and outside them.
    unet_seconds: Option<(f64, f64)>,
    /// The last round's training frames and its frames with positives per
    /// affordance, where recorded.
    unet_training_frames: Option<u64>,
    unet_positive_frames: Option<Vec<u64>>,
    /// Checkpoints scored on the validation rooms, and each score's values.
    validated: usize,
    validation: BTreeMap<String, Vec<f64>>,
    /// Attempts and successes by (affordance, object type).
    tries: Tries,
}

/// Each of `names` once, in name order.
fn distinct_names(names: impl Iterator<Item = String>) -> Vec<String> {
    names
        .collect::<std::collections::BTreeSet<_>>()
        .into_iter()
        .collect()
}

/// The median of `values` (the mean of the middle two for an even count);
/// `None` for none.
fn median(values: &[f64]) -> Option<f64> {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    let n = sorted.len();
    (n > 0).then(|| (sorted[(n - 1) / 2] + sorted[n / 2]) / 2.0)
}

/// Means of `run_dir`'s history per `every` environment steps.
pub(crate) fn summarize(run_dir: &Path, every: u64) -> anyhow::Result<Summary> {
    anyhow::ensure!(every > 0, "the span must be at least one step");
    // Only spans that hold a record are kept, so a small `every` on a long
    // run costs what its records cost.
    let mut spans = std::collections::BTreeMap::<u64, SpanSums>::new();
    let mut last_step = 0;
    for record in read_records(run_dir, None)? {
        let step = record["env_steps"].as_u64().unwrap_or(0);
        last_step = last_step.max(step);
        let span = spans.entry(step / every).or_default();
        match record["kind"].as_str() {
            Some("episode") => {
                span.episodes += 1;
                let steps = record["steps"].as_f64().unwrap_or(0.0);
                let stats = &record["stats"];
                for (a, sums) in Affordance::ALL.iter().zip(&mut span.successes) {
                    let rate = |stat| stats[StatKey::Affordance(*a, stat).name().as_ref()].as_f64();
                    if let Some(attempts) = rate(AffordanceStat::AttemptRate) {
                        // An episode without attempts reports no success rate.
                        let success = rate(AffordanceStat::SuccessRate).unwrap_or(0.0);
                        sums.0 += attempts * steps * success;
                        sums.1 += steps;
                    }
                }
                tries_table::add_episode(&mut span.tries, &record);
                for key in StatKey::all() {
                    if let Some(v) = record["stats"][key.name().as_ref()].as_f64() {
                        let (sum, n) = span.fields.entry(key).or_default();
                        *sum += v;
                        *n += 1;
                    }
                }
            }
            Some("ppo") => {
                if let Some(v) = record["stats"]["entropy"].as_f64() {
                    span.entropy.0 += v;
                    span.entropy.1 += 1;
                }
            }
            Some("unet") => {
                let round = &record["round"];
                if let Some(steps) = round["steps"].as_u64() {
                    *span.unet_steps.get_or_insert(0) += steps;
                }
                let seconds = &round["seconds"];
                if let Some(training) = seconds["training"].as_f64() {
                    let outside = ["gate", "temperature"]
                        .iter()
                        .filter_map(|part| seconds[part].as_f64())
                        .sum::<f64>();
                    let sums = span.unet_seconds.get_or_insert((0.0, 0.0));
                    sums.0 += training;
                    sums.1 += outside;
                }
                if let Some(training) = round["frames"][0].as_u64() {
                    span.unet_training_frames = Some(training);
                }
                if let Some(positives) = round["positive_frames"].as_array() {
                    span.unet_positive_frames =
                        Some(positives.iter().filter_map(Value::as_u64).collect());
                }
            }
            Some("validation") => {
                span.validated += 1;
                if let Some(scores) = record["validation"].as_object() {
                    for (name, value) in scores {
                        if let Some(v) = value.as_f64() {
                            span.validation.entry(name.clone()).or_default().push(v);
                        }
                    }
                }
            }
            _ => {}
        }
    }
    spans.retain(|_, span| span.episodes > 0);
    anyhow::ensure!(
        !spans.is_empty(),
        "{} holds no finished episode yet: let the run go on",
        run_dir.display()
    );
    let mean = |(sum, n): (f64, usize)| (n > 0).then(|| Spread::one(sum / n as f64));
    let fields: Vec<StatKey> = StatKey::all()
        .filter(|f| spans.values().any(|span| span.fields.contains_key(f)))
        .collect();
    let validation_scores = distinct_names(
        spans
            .values()
            .flat_map(|span| span.validation.keys().cloned()),
    );
    let rows = spans
        .iter()
        .map(|(&index, span)| SummaryRow {
            from_steps: index * every,
            to_steps: ((index + 1) * every).min(last_step),
            episodes: span.episodes,
            means: fields
                .iter()
                .map(|f| span.fields.get(f).and_then(|&sums| mean(sums)))
                .collect(),
            successes_per_kilostep: span
                .successes
                .iter()
                .map(|&(successes, steps)| {
                    (steps > 0.0).then(|| Spread::one(1000.0 * successes / steps))
                })
                .collect(),
            entropy: mean(span.entropy),
            unet_steps_per_episode: span
                .unet_steps
                .map(|steps| Spread::one(steps as f64 / span.episodes as f64)),
            unet_time_outside_steps: span.unet_seconds.and_then(|(training, outside)| {
                (training + outside > 0.0).then(|| Spread::one(outside / (training + outside)))
            }),
            unet_training_frames: span.unet_training_frames.map(|n| Spread::one(n as f64)),
            unet_positive_frames: Affordance::ALL
                .iter()
                .map(|a| {
                    let counts = span.unet_positive_frames.as_ref()?;
                    counts
                        .get(a.code() as usize)
                        .map(|&n| Spread::one(n as f64))
                })
                .collect(),
            validation_checkpoints: (span.validated > 0)
                .then(|| Spread::one(span.validated as f64)),
            validation: validation_scores
                .iter()
                .map(|name| {
                    let values = span.validation.get(name)?;
                    median(values).map(Spread::one)
                })
                .collect(),
            tries: span.tries.clone(),
        })
        .collect();
    Ok(Summary {
        runs: 1,
        fields,
        validation_scores,
        rows,
    })
}

/// Repeats of one setting (seeds), span by span: each metric's mean over
/// the runs' means with their range. Only spans in which every run ended an
/// episode are kept, so a shorter run cuts the table.
pub fn summarize_repeats(run_dirs: &[PathBuf], every: u64) -> anyhow::Result<Summary> {
    let summaries = run_dirs
        .iter()
        .map(|dir| summarize(dir, every))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let Some(first) = summaries.first() else {
        anyhow::bail!("no run directory to summarise");
    };
    let fields: Vec<StatKey> = StatKey::all()
        .filter(|f| summaries.iter().any(|s| s.fields.contains(f)))
        .collect();
    let validation_scores = distinct_names(
        summaries
            .iter()
            .flat_map(|s| s.validation_scores.iter().cloned()),
    );
    let mut rows = Vec::new();
    for row in &first.rows {
        let Some(span): Option<Vec<(&Summary, &SummaryRow)>> = summaries
            .iter()
            .map(|s| {
                s.rows
                    .iter()
                    .find(|r| r.from_steps == row.from_steps)
                    .map(|r| (s, r))
            })
            .collect()
        else {
            continue;
        };
        let field_mean = |summary: &Summary, row: &SummaryRow, field: StatKey| {
            let column = summary.fields.iter().position(|&f| f == field)?;
            row.means[column].map(|spread| spread.mean)
        };
        let score_median = |summary: &Summary, row: &SummaryRow, name: &String| {
            let column = summary.validation_scores.iter().position(|n| n == name)?;
            row.validation[column].map(|spread| spread.mean)
        };
        // One column over the runs: the spread of their means.
        let over_runs = |column: &dyn Fn(&SummaryRow) -> Option<Spread>| {
            Spread::of(span.iter().filter_map(|(_, r)| column(r).map(|s| s.mean)))
        };
        let per_affordance = |columns: &dyn Fn(&SummaryRow) -> &Vec<Option<Spread>>| {
            (0..Affordance::COUNT)
                .map(|a| over_runs(&|r| columns(r)[a]))
                .collect()
        };
        rows.push(SummaryRow {
            from_steps: row.from_steps,
            to_steps: span.iter().map(|(_, r)| r.to_steps).min().unwrap_or(0),
            episodes: span.iter().map(|(_, r)| r.episodes).sum(),
            means: fields
                .iter()
                .map(|&f| Spread::of(span.iter().filter_map(|&(s, r)| field_mean(s, r, f))))
                .collect(),
            successes_per_kilostep: per_affordance(&|r: &SummaryRow| &r.successes_per_kilostep),
            entropy: over_runs(&|r| r.entropy),
            unet_steps_per_episode: over_runs(&|r| r.unet_steps_per_episode),
            unet_time_outside_steps: over_runs(&|r| r.unet_time_outside_steps),
            unet_training_frames: over_runs(&|r| r.unet_training_frames),
            unet_positive_frames: per_affordance(&|r: &SummaryRow| &r.unet_positive_frames),
            validation_checkpoints: over_runs(&|r| r.validation_checkpoints),
            validation: validation_scores
                .iter()
                .map(|name| Spread::of(span.iter().filter_map(|&(s, r)| score_median(s, r, name))))
                .collect(),
            tries: tries_table::total(span.iter().map(|(_, r)| &r.tries)),
        });
    }
    anyhow::ensure!(
        !rows.is_empty(),
        "the runs share no span of {every} steps in which each ended an episode"
    );
    Ok(Summary {
        runs: summaries.len(),
        fields,
        validation_scores,
        rows,
    })
}

impl Summary {
    /// The table in Markdown: one row per span, one column per metric;
    /// over repeats each cell is `mean (lowest–highest)`. The validation
    /// columns come only when some span recorded scores.
    pub fn markdown(&self) -> String {
        let mut out = String::from("| steps | episodes |");
        for field in &self.fields {
            let _ = write!(out, " {} |", field.name());
        }
        for affordance in Affordance::ALL {
            let _ = write!(out, " {} successes per 1 k steps |", affordance.as_str());
        }
        out.push_str(
            " ppo entropy | U-Net steps per episode | U-Net time outside its steps | U-Net training frames |",
        );
        for affordance in Affordance::ALL {
            let _ = write!(out, " … with {} positives |", affordance.as_str());
        }
        let validated = !self.validation_scores.is_empty();
        if validated {
            out.push_str(" checkpoints scored on the validation rooms |");
            for name in &self.validation_scores {
                let _ = write!(out, " validation {name} (median) |");
            }
        }
        let validation_columns = if validated {
            1 + self.validation_scores.len()
        } else {
            0
        };
        out.push_str("\n|---|---|");
        out.push_str(
            &"---|".repeat(self.fields.len() + 4 + 2 * Affordance::COUNT + validation_columns),
        );
        out.push('\n');
        let repeats = self.runs > 1;
        let cell = |v: Option<Spread>| match v {
            None => "–".to_string(),
            Some(s) if repeats => format!("{:.3} ({:.3}–{:.3})", s.mean, s.min, s.max),
            Some(s) => format!("{:.3}", s.mean),
        };
        for row in &self.rows {
            let _ = write!(
                out,
                "| {}–{} | {} |",
                steps(row.from_steps),
                steps(row.to_steps),
                row.episodes
            );
            for &v in row.means.iter().chain(&row.successes_per_kilostep) {
                let _ = write!(out, " {} |", cell(v));
            }
            let _ = write!(
                out,
                " {} | {} | {} | {} |",
                cell(row.entropy),
                cell(row.unet_steps_per_episode),
                cell(row.unet_time_outside_steps),
                cell(row.unet_training_frames)
            );
            for &v in &row.unet_positive_frames {
                let _ = write!(out, " {} |", cell(v));
            }
            if validated {
                let checkpoints = row.validation_checkpoints.or(Some(Spread::one(0.0)));
                for &v in std::iter::once(&checkpoints).chain(&row.validation) {
                    let _ = write!(out, " {} |", cell(v));
                }
            }
            out.push('\n');
        }
        let spans: Vec<(String, &Tries)> = self
            .rows
            .iter()
            .map(|row| {
                let heading = format!("{}–{}", steps(row.from_steps), steps(row.to_steps));
                (heading, &row.tries)
            })
            .collect();
        tries_table::markdown(&mut out, &spans, self.runs > 1);
        out
    }
}

/// Steps as people write them: `40 k` for whole thousands.
fn steps(n: u64) -> String {
    if n > 0 && n.is_multiple_of(1000) {
        format!("{} k", n / 1000)
    } else {
        n.to_string()
    }
}

impl From<&Summary> for Value {
    /// One object per span: `means` per metric, `successes_per_kilostep`
    /// (by affordance), `ppo_entropy`, `unet_steps_per_episode`,
    /// `unet_time_outside_steps`, `unet_training_frames`, `unet_positive_frames` (by affordance),
    /// `validation_checkpoints`, `validation` (each score's median, by
    /// name) and `tries` (by affordance and object type: `[attempts,
    /// successes]`, over repeats all runs together); over repeats also `ranges`, each of these' `[lowest, highest]`
    /// run value.
    fn from(summary: &Summary) -> Value {
        let mean = |spread: &Option<Spread>| json!(spread.map(|s| s.mean));
        let range = |spread: &Option<Spread>| json!(spread.map(|s| [s.min, s.max]));
        let rows: Vec<Value> = summary
            .rows
            .iter()
            .map(|row| {
                let mut means = serde_json::Map::new();
                let mut ranges = serde_json::Map::new();
                for (name, spread) in summary.fields.iter().map(|f| f.name()).zip(&row.means) {
                    means.insert(name.to_string(), mean(spread));
                    ranges.insert(name.into_owned(), range(spread));
                }
                let by_score =
                    |spreads: &[Option<Spread>], value: &dyn Fn(&Option<Spread>) -> Value| {
                        let pairs = summary.validation_scores.iter().zip(spreads);
                        Value::Object(pairs.map(|(n, s)| (n.clone(), value(s))).collect())
                    };
                let by_affordance =
                    |spreads: &[Option<Spread>], value: &dyn Fn(&Option<Spread>) -> Value| {
                        let pairs = Affordance::ALL.iter().zip(spreads);
                        Value::Object(pairs.map(|(a, s)| (a.as_str().into(), value(s))).collect())
                    };
                let mut object = json!({
                    "from_steps": row.from_steps,
                    "to_steps": row.to_steps,
                    "episodes": row.episodes,
                    "means": means,
                    "successes_per_kilostep": by_affordance(&row.successes_per_kilostep, &mean),
                    "ppo_entropy": mean(&row.entropy),
                    "unet_steps_per_episode": mean(&row.unet_steps_per_episode),
                    "unet_time_outside_steps": mean(&row.unet_time_outside_steps),
                    "unet_training_frames": mean(&row.unet_training_frames),
                    "unet_positive_frames": by_affordance(&row.unet_positive_frames, &mean),
                    "validation_checkpoints": mean(&row.validation_checkpoints),
                    "validation": by_score(&row.validation, &mean),
                    "tries": tries_table::json(&row.tries),
                });
                if summary.runs > 1 {
                    ranges.insert("ppo_entropy".into(), range(&row.entropy));
                    ranges.insert(
                        "unet_steps_per_episode".into(),
                        range(&row.unet_steps_per_episode),
                    );
                    ranges.insert(
                        "unet_time_outside_steps".into(),
                        range(&row.unet_time_outside_steps),
                    );
                    ranges.insert(
                        "unet_training_frames".into(),
                        range(&row.unet_training_frames),
                    );
                    ranges.insert(
                        "unet_positive_frames".into(),
                        by_affordance(&row.unet_positive_frames, &range),
                    );
                    ranges.insert(
                        "successes_per_kilostep".into(),
                        by_affordance(&row.successes_per_kilostep, &range),
                    );
                    ranges.insert(
                        "validation_checkpoints".into(),
                        range(&row.validation_checkpoints),
                    );
                    ranges.insert("validation".into(), by_score(&row.validation, &range));
                    object["runs"] = json!(summary.runs);
                    object["ranges"] = Value::Object(ranges);
                }
                object
            })
            .collect();
        Value::Array(rows)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::history::History;
    use proto::StatField;

    fn episode(history: &mut History, steps: u64, success: f64, attempts: Option<f64>) {
        let mut stats = json!({"interaction_success_rate": success});
        if let Some(a) = attempts {
            stats["interaction_attempt_rate"] = json!(a);
        }
        history
            .record("episode", steps, json!({"stats": stats}))
            .unwrap();
    }

    /// An episode at `steps` that tried `tries` (affordance, type,
    /// attempts, successes).
    fn episode_with_tries(history: &mut History, steps: u64, tries: &[(&str, &str, u64, u64)]) {
        let tries: Vec<Value> = tries
            .iter()
            .map(|(a, t, n, s)| json!({"affordance": a, "type": t, "attempts": n, "successes": s, "objects": 1}))
            .collect();
        history
            .record("episode", steps, json!({"stats": {}, "tries": tries}))
            .unwrap();
    }

    #[test]
    fn tries_by_object_type_add_up_per_span_and_over_repeats() {
        let dirs = [tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap()];
        for dir in &dirs {
            let mut history = History::open(dir.path()).unwrap();
            episode_with_tries(
                &mut history,
                100,
                &[("pick_up", "Drawer", 2, 0), ("pick_up", "KeyChain", 1, 1)],
            );
            episode_with_tries(&mut history, 900, &[("pick_up", "Drawer", 1, 0)]);
            episode_with_tries(
                &mut history,
                1500,
                &[("push", "Chair", 2, 1), ("pick_up", "KeyChain", 4, 3)],
            );
            // Histories written before tries were recorded have none.
            episode(&mut history, 1600, 0.5, None);
        }
        let one = summarize(dirs[0].path(), 1000).unwrap();
        let key = |a: &str, t: &str| (a.to_string(), t.to_string());
        assert_eq!(one.rows[0].tries[&key("pick_up", "Drawer")], (3, 0));
        assert_eq!(one.rows[0].tries[&key("pick_up", "KeyChain")], (1, 1));
        assert_eq!(one.rows[1].tries.get(&key("pick_up", "Drawer")), None);
        assert_eq!(one.rows[1].tries[&key("pick_up", "KeyChain")], (4, 3));
        // By affordance, the most tried first.
        assert_eq!(
            one.tried_types(),
            [
                key("pick_up", "KeyChain"),
                key("pick_up", "Drawer"),
                key("push", "Chair")
            ]
        );
        let table = one.markdown();
        assert!(
            table.contains("| pick_up | KeyChain | 1 (1) | 4 (3) | 5 (4) |"),
            "{table}"
        );
        assert!(table.contains("| pick_up | Drawer | 3 (0) | 0 (0) | 3 (0) |"));
        let paths: Vec<PathBuf> = dirs.iter().map(|d| d.path().to_path_buf()).collect();
        let both = summarize_repeats(&paths, 1000).unwrap();
        assert_eq!(both.rows[1].tries[&key("push", "Chair")], (4, 2));
        assert!(both.markdown().contains("all runs together"));
        let json = Value::from(&both);
        assert_eq!(json[0]["tries"]["pick_up"]["Drawer"], json!([6, 0]));
    }

    #[test]
    fn spans_average_the_episodes_and_updates_that_ended_in_them() {
        let dir = tempfile::tempdir().unwrap();
        let mut history = History::open(dir.path()).unwrap();
        episode(&mut history, 100, 0.1, Some(0.2));
        episode(&mut history, 900, 0.3, None);
        history
            .record("ppo", 950, json!({"stats": {"entropy": 2.0}}))
            .unwrap();
        history
            .record("ppo", 990, json!({"stats": {"entropy": 1.0}}))
            .unwrap();
        history
            .record(
                "unet",
                500,
                json!({"round": {"steps": 8, "seconds": {"training": 3.0, "gate": 0.75, "temperature": 0.25}}}),
            )
            .unwrap();
        // The span's last round says what the dataset held at its end.
        let round = json!({"steps": 2, "frames": [40, 5, 5], "positive_frames": [3, 30],
            "seconds": {"training": 1.0, "gate": 0.0, "temperature": 0.0}});
        history
            .record("unet", 600, json!({"round": round}))
            .unwrap();
        let round = json!({"frames": [50, 5, 5], "positive_frames": [4, 35]});
        history
            .record("unet", 800, json!({"round": round}))
            .unwrap();
        history.record("unet", 1500, json!({"round": {}})).unwrap();
        episode(&mut history, 2500, 0.5, Some(0.1));
        drop(history);

        let summary = summarize(dir.path(), 1000).unwrap();
        assert_eq!(
            summary.fields,
            [
                StatKey::Episode(StatField::InteractionSuccessRate),
                StatKey::Episode(StatField::InteractionAttemptRate)
            ]
        );
        assert_eq!(
            summary.rows.len(),
            2,
            "the span without episodes is left out"
        );
        let first = &summary.rows[0];
        assert_eq!(
            (first.from_steps, first.to_steps, first.episodes),
            (0, 1000, 2)
        );
        assert!((first.means[0].unwrap().mean - 0.2).abs() < 1e-9);
        assert!(
            (first.means[1].unwrap().mean - 0.2).abs() < 1e-9,
            "only episodes that reported it"
        );
        assert_eq!(first.entropy, Some(Spread::one(1.5)));
        assert_eq!(first.unet_steps_per_episode, Some(Spread::one(5.0)));
        // 1 s of 5 outside the gradient steps.
        assert_eq!(first.unet_time_outside_steps, Some(Spread::one(0.2)));
        assert_eq!(first.unet_training_frames, Some(Spread::one(50.0)));
        assert_eq!(
            first.unet_positive_frames,
            [Some(Spread::one(4.0)), Some(Spread::one(35.0))]
        );
        let last = &summary.rows[1];
        assert_eq!((last.from_steps, last.to_steps), (2000, 2500));
        assert_eq!(last.entropy, None);
        assert_eq!(last.unet_positive_frames, [None, None]);

        let table = summary.markdown();
        assert!(table.starts_with(
            "| steps | episodes | interaction_success_rate | interaction_attempt_rate \
             | pick_up successes per 1 k steps | push successes per 1 k steps | ppo entropy \
             | U-Net steps per episode | U-Net time outside its steps | U-Net training frames \
             | … with pick_up positives | … with push positives \
             |\n|---|---|---|---|---|---|---|---|---|---|---|---|\n"
        ));
        assert!(
            table.contains(
                "| 0–1 k | 2 | 0.200 | 0.200 | – | – | 1.500 | 5.000 | 0.200 | 50.000 | 4.000 | 35.000 |"
            ),
            "{table}"
        );
        assert!(
            table.contains("| 2 k–2500 | 1 | 0.500 | 0.100 | – | – | – | – | – | – | – | – |"),
            "{table}"
        );
        let json = Value::from(&summary);
        assert_eq!(json[1]["means"]["interaction_success_rate"], 0.5);
        assert_eq!(json[0]["ppo_entropy"], 1.5);
        assert_eq!(json[0]["unet_steps_per_episode"], 5.0);
        assert_eq!(json[0]["unet_time_outside_steps"], 0.2);
        assert_eq!(json[0]["unet_training_frames"], 50.0);
        assert_eq!(
            json[0]["unet_positive_frames"],
            json!({"pick_up": 4.0, "push": 35.0})
        );
        assert!(json[0].get("ranges").is_none(), "one run has no range");
    }

    #[test]
    fn repeats_give_the_mean_and_range_of_their_means_where_all_ran() {
        let root = tempfile::tempdir().unwrap();
        // Seed A: two spans; seed B: success 0.3 in the first span only and
        // attempts in neither; seed C: no episode in the first span.
        type Episode = (u64, f64, Option<f64>);
        let runs: [(&[Episode], &str); 3] = [
            (&[(500, 0.1, Some(0.2)), (1500, 0.2, Some(0.4))], "a"),
            (&[(700, 0.3, None)], "b"),
            (&[(1200, 0.9, None)], "c"),
        ];
        let dirs: Vec<PathBuf> = runs
            .iter()
            .map(|(episodes, name)| {
                let dir = root.path().join(name);
                std::fs::create_dir(&dir).unwrap();
                let mut history = History::open(&dir).unwrap();
                for &(steps, success, attempts) in *episodes {
                    episode(&mut history, steps, success, attempts);
                }
                // Datasets of 10 and 20 training frames, 1 and 3 of them
                // with pick-up positives (seed C: none recorded).
                if let Some(k) = ["a", "b"].iter().position(|n| n == name) {
                    let k = k as u64;
                    let round =
                        json!({"frames": [10 + 10 * k, 1, 1], "positive_frames": [1 + 2 * k, 5]});
                    history
                        .record("unet", 100, json!({"round": round}))
                        .unwrap();
                }
                dir
            })
            .collect();

        let summary = summarize_repeats(&dirs[..2], 1000).unwrap();
        assert_eq!(summary.runs, 2);
        assert_eq!(summary.rows.len(), 1, "only the span both runs reached");
        let row = &summary.rows[0];
        assert_eq!((row.from_steps, row.to_steps, row.episodes), (0, 700, 2));
        let success = row.means[0].unwrap();
        assert!((success.mean - 0.2).abs() < 1e-9);
        assert_eq!((success.min, success.max), (0.1, 0.3));
        assert_eq!(
            row.means[1],
            Some(Spread::one(0.2)),
            "attempts: only the run that reported them"
        );
        let table = summary.markdown();
        assert!(
            table.contains(
                "| 0–700 | 2 | 0.200 (0.100–0.300) | 0.200 (0.200–0.200) | – | – | – | – | – \
                 | 15.000 (10.000–20.000) | 2.000 (1.000–3.000) | 5.000 (5.000–5.000) |"
            ),
            "{table}"
        );
        let json = Value::from(&summary);
        assert_eq!(json[0]["runs"], 2);
        assert_eq!(
            json[0]["ranges"]["interaction_success_rate"],
            json!([0.1, 0.3])
        );
        assert_eq!(
            json[0]["ranges"]["unet_positive_frames"]["pick_up"],
            json!([1.0, 3.0])
        );
        assert_eq!(
            json[0]["ranges"]["unet_training_frames"],
            json!([10.0, 20.0])
        );

        assert_eq!(
            summarize_repeats(&dirs[..1], 1000).unwrap(),
            summarize(&dirs[0], 1000).unwrap()
        );
        let error = summarize_repeats(&dirs[1..], 1000).unwrap_err().to_string();
        assert!(error.contains("share no span"), "{error}");
        assert!(summarize_repeats(&[], 1000).is_err());
    }

    #[test]
    fn successes_per_thousand_steps_count_each_episodes_attempts_that_succeeded() {
        let dir = tempfile::tempdir().unwrap();
        let mut history = History::open(dir.path()).unwrap();
        // 0.2 attempts a step over 100 steps, a quarter of them successes: 5.
        let tried = json!({"pick_up_attempt_rate": 0.2, "pick_up_success_rate": 0.25});
        history
            .record("episode", 100, json!({"steps": 100, "stats": tried}))
            .unwrap();
        // No attempt, so no success rate: 0 successes in 100 more steps.
        let idle = json!({"pick_up_attempt_rate": 0.0});
        history
            .record("episode", 200, json!({"steps": 100, "stats": idle}))
            .unwrap();
        drop(history);

        let summary = summarize(dir.path(), 1000).unwrap();
        let row = &summary.rows[0];
        assert_eq!(
            row.successes_per_kilostep,
            [Some(Spread::one(25.0)), None],
            "5 successes in 200 steps; push never reported"
        );
        let json = Value::from(&summary);
        assert_eq!(
            json[0]["successes_per_kilostep"],
            json!({"pick_up": 25.0, "push": null})
        );
    }

    #[test]
    fn validation_scores_are_each_spans_median_and_repeats_average_them() {
        let root = tempfile::tempdir().unwrap();
        let scored = |name: &str, pixels: &[(u64, f64)]| {
            let dir = root.path().join(name);
            std::fs::create_dir(&dir).unwrap();
            let mut history = History::open(&dir).unwrap();
            episode(&mut history, 100, 0.1, None);
            episode(&mut history, 1100, 0.1, None);
            for &(step, f1) in pixels {
                let scores = json!({"pick_up/pixel_f1": f1, "push/pixel_f1": 0.5});
                history
                    .record("validation", step, json!({"validation": scores}))
                    .unwrap();
            }
            dir
        };
        // Run a: three checkpoints in the first span (median 0.2, mean 0.3),
        // none in the second; run b: one in each.
        let a = scored("a", &[(200, 0.1), (500, 0.6), (900, 0.2)]);
        let b = scored("b", &[(300, 0.4), (1500, 0.3)]);

        let summary = summarize(&a, 1000).unwrap();
        assert_eq!(
            summary.validation_scores,
            ["pick_up/pixel_f1", "push/pixel_f1"]
        );
        let first = &summary.rows[0];
        assert_eq!(first.validation_checkpoints, Some(Spread::one(3.0)));
        assert_eq!(
            first.validation,
            [Some(Spread::one(0.2)), Some(Spread::one(0.5))]
        );
        assert_eq!(summary.rows[1].validation, [None, None]);
        let table = summary.markdown();
        assert!(
            table.contains(
                "| checkpoints scored on the validation rooms \
                 | validation pick_up/pixel_f1 (median) | validation push/pixel_f1 (median) |\n"
            ),
            "{table}"
        );
        assert!(table.contains("| 3.000 | 0.200 | 0.500 |\n"), "{table}");
        assert!(table.contains("| 0.000 | – | – |\n"), "{table}");
        let json = Value::from(&summary);
        assert_eq!(json[0]["validation"]["pick_up/pixel_f1"], 0.2);
        assert_eq!(json[0]["validation_checkpoints"], 3.0);

        let repeats = summarize_repeats(&[a, b], 1000).unwrap();
        let first = &repeats.rows[0];
        let pixels = first.validation[0].unwrap();
        assert!(
            (pixels.mean - 0.3).abs() < 1e-9,
            "the runs' medians 0.2 and 0.4"
        );
        assert_eq!((pixels.min, pixels.max), (0.2, 0.4));
        assert_eq!(
            repeats.rows[1].validation[0],
            Some(Spread::one(0.3)),
            "only the run that scored a checkpoint there"
        );
        let json = Value::from(&repeats);
        assert_eq!(
            json[0]["ranges"]["validation"]["pick_up/pixel_f1"],
            json!([0.2, 0.4])
        );
    }

    #[test]
    fn a_history_without_episodes_says_so() {
        let dir = tempfile::tempdir().unwrap();
        let mut history = History::open(dir.path()).unwrap();
        history.record("ppo", 10, json!({"stats": {}})).unwrap();
        drop(history);
        let error = summarize(dir.path(), 1000).unwrap_err().to_string();
        assert!(error.contains("no finished episode"), "{error}");
        assert!(summarize(Path::new("/nonexistent"), 1000).is_err());
    }
}
