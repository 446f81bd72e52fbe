//! `learner summary`: a run's history as a table of means per span of
//! environment steps (every episode metric, and the policy's entropy), so
//! that a long run, or two runs side by side, can be read without plotting:
//! where the success rate peaked, when the policy stopped trying.

use std::fmt::Write as _;
use std::path::Path;

use proto::StatField;
use serde_json::Value;

use crate::history::read_records;

/// Means over one span of environment steps.
#[derive(Debug, Clone, PartialEq)]
pub struct SummaryRow {
    /// First environment step of the span.
    pub from_steps: u64,
    /// End of the span: the next span's first step, or the last step seen.
    pub to_steps: u64,
    /// Episodes that ended in the span.
    pub episodes: usize,
    /// Mean of each of [`Summary::fields`] over the span's episodes that
    /// reported it.
    pub means: Vec<Option<f64>>,
    /// Mean entropy of the policy updates in the span.
    pub entropy: Option<f64>,
}

/// A run's history, span by span.
#[derive(Debug, Clone, PartialEq)]
pub struct Summary {
    /// The episode metrics some episode reported, in wire order.
    pub fields: Vec<StatField>,
    /// One row per span that ended an episode, in step order.
    pub rows: Vec<SummaryRow>,
}

/// Sums over one span, as the history is read.
#[derive(Default)]
struct SpanSums {
    episodes: usize,
    /// Sum and count per [`StatField`], in wire order.
    fields: [(f64, usize); StatField::COUNT],
    entropy: (f64, usize),
}

/// Means of `run_dir`'s history per `every` environment steps.
pub fn summarize(run_dir: &Path, every: u64) -> anyhow::Result<Summary> {
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
                for field in StatField::ALL {
                    if let Some(v) = record["stats"][field.as_str()].as_f64() {
                        let (sum, n) = &mut span.fields[field as usize];
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
            _ => {}
        }
    }
    spans.retain(|_, span| span.episodes > 0);
    anyhow::ensure!(
        !spans.is_empty(),
        "{} holds no finished episode yet: let the run go on",
        run_dir.display()
    );
    let mean = |(sum, n): (f64, usize)| (n > 0).then(|| sum / n as f64);
    let fields: Vec<StatField> = StatField::ALL
        .into_iter()
        .filter(|&f| spans.values().any(|span| span.fields[f as usize].1 > 0))
        .collect();
    let rows = spans
        .iter()
        .map(|(&index, span)| SummaryRow {
            from_steps: index * every,
            to_steps: ((index + 1) * every).min(last_step),
            episodes: span.episodes,
            means: fields
                .iter()
                .map(|&f| mean(span.fields[f as usize]))
                .collect(),
            entropy: mean(span.entropy),
        })
        .collect();
    Ok(Summary { fields, rows })
}

impl Summary {
    /// The table in Markdown: one row per span, one column per metric.
    pub fn markdown(&self) -> String {
        let mut out = String::from("| steps | episodes |");
        for field in &self.fields {
            let _ = write!(out, " {} |", field.as_str());
        }
        out.push_str(" ppo entropy |\n|---|---|");
        out.push_str(&"---|".repeat(self.fields.len() + 1));
        out.push('\n');
        let cell = |v: Option<f64>| v.map_or("–".to_string(), |v| format!("{v:.3}"));
        for row in &self.rows {
            let _ = write!(
                out,
                "| {}–{} | {} |",
                steps(row.from_steps),
                steps(row.to_steps),
                row.episodes
            );
            for &v in &row.means {
                let _ = write!(out, " {} |", cell(v));
            }
            let _ = writeln!(out, " {} |", cell(row.entropy));
        }
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
    fn from(summary: &Summary) -> Value {
        let rows: Vec<Value> = summary
            .rows
            .iter()
            .map(|row| {
                let mut means = serde_json::Map::new();
                for (field, v) in summary.fields.iter().zip(&row.means) {
                    means.insert(field.as_str().into(), serde_json::json!(v));
                }
                serde_json::json!({
                    "from_steps": row.from_steps,
                    "to_steps": row.to_steps,
                    "episodes": row.episodes,
                    "means": means,
                    "ppo_entropy": row.entropy,
                })
            })
            .collect();
        Value::Array(rows)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::history::History;
    use serde_json::json;

    fn episode(history: &mut History, steps: u64, success: f64, attempts: Option<f64>) {
        let mut stats = json!({"interaction_success_rate": success});
        if let Some(a) = attempts {
            stats["interaction_attempt_rate"] = json!(a);
        }
        history
            .record("episode", steps, json!({"stats": stats}))
            .unwrap();
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
        history.record("unet", 1500, json!({"round": {}})).unwrap();
        episode(&mut history, 2500, 0.5, Some(0.1));
        drop(history);

        let summary = summarize(dir.path(), 1000).unwrap();
        assert_eq!(
            summary.fields,
            [
                StatField::InteractionSuccessRate,
                StatField::InteractionAttemptRate
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
        assert!((first.means[0].unwrap() - 0.2).abs() < 1e-9);
        assert!(
            (first.means[1].unwrap() - 0.2).abs() < 1e-9,
            "only episodes that reported it"
        );
        assert_eq!(first.entropy, Some(1.5));
        let last = &summary.rows[1];
        assert_eq!((last.from_steps, last.to_steps), (2000, 2500));
        assert_eq!(last.entropy, None);

        let table = summary.markdown();
        assert!(table.starts_with(
            "| steps | episodes | interaction_success_rate | interaction_attempt_rate | ppo entropy |"
        ));
        assert!(
            table.contains("| 0–1 k | 2 | 0.200 | 0.200 | 1.500 |"),
            "{table}"
        );
        assert!(
            table.contains("| 2 k–2500 | 1 | 0.500 | 0.100 | – |"),
            "{table}"
        );
        let json = Value::from(&summary);
        assert_eq!(json[1]["means"]["interaction_success_rate"], 0.5);
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
