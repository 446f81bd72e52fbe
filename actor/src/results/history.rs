//! What a run's `history.jsonl` says about its course: how far it went, how
//! long it took, and whether it kept exploring to the end (a run whose
//! policy stops interacting stops producing labels, however long it runs).

use std::path::Path;

use anyhow::Context;
use serde_json::Value;

/// Episode means over one tenth of a run's steps.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Tenth {
    /// Episodes that ended in it.
    pub episodes: usize,
    /// Interaction attempts per step.
    pub attempt_rate: Option<f64>,
    /// Objects interacted with / interactable objects.
    pub interacted_object_rate: Option<f64>,
    /// Successful / attempted interactions.
    pub success_rate: Option<f64>,
    /// Pick-up attempts per step (a policy that gives up picking up stops
    /// producing positive pick-up labels).
    pub pick_up_attempt_rate: Option<f64>,
}

/// A run's course.
#[derive(Debug, Clone, PartialEq)]
pub struct HistorySummary {
    /// Environment steps of the last record.
    pub steps: u64,
    /// Seconds the learner ran, summed over resumed segments.
    pub wall_s: f64,
    /// Episodes reported.
    pub episodes: usize,
    /// Episode means per tenth of `steps`, first to last.
    pub tenths: Vec<Tenth>,
    /// The policy's entropy at the first and the last PPO update.
    pub entropy: Option<(f64, f64)>,
}

impl HistorySummary {
    /// Reads `path`. A torn last line (the learner was killed mid-write)
    /// is skipped; any other unreadable line is an error.
    pub fn read(path: &Path) -> anyhow::Result<Self> {
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        let lines: Vec<&str> = text.lines().filter(|l| !l.trim().is_empty()).collect();
        let mut records = Vec::with_capacity(lines.len());
        for (i, line) in lines.iter().enumerate() {
            match serde_json::from_str::<Value>(line) {
                Ok(record) => records.push(record),
                Err(_) if i + 1 == lines.len() => {}
                Err(e) => anyhow::bail!("{} line {}: {e}", path.display(), i + 1),
            }
        }
        Self::of(&records).with_context(|| format!("summarising {}", path.display()))
    }

    /// The summary of parsed history records.
    pub fn of(records: &[Value]) -> anyhow::Result<Self> {
        let steps = records
            .iter()
            .filter_map(|r| r["env_steps"].as_u64())
            .max()
            .context("no record has env_steps")?;
        // Learners before 2026-11-26 restarted `time_s` at 0 on resume (now it
        // continues): summing each segment's end reads both.
        let (mut wall_s, mut segment_end) = (0.0, 0.0);
        for time in records.iter().filter_map(|r| r["time_s"].as_f64()) {
            if time < segment_end {
                wall_s += segment_end;
            }
            segment_end = time;
        }
        wall_s += segment_end;
        let episodes: Vec<&Value> = records.iter().filter(|r| r["kind"] == "episode").collect();
        let mut sums = vec![[(0.0, 0usize); 4]; 10];
        let mut counts = [0usize; 10];
        for episode in &episodes {
            let at = episode["env_steps"].as_u64().unwrap_or(0);
            let tenth = ((at.saturating_sub(1) * 10) / steps.max(1)).min(9) as usize;
            counts[tenth] += 1;
            let stats = &episode["stats"];
            for (sum, field) in sums[tenth].iter_mut().zip([
                "interaction_attempt_rate",
                "interacted_object_rate",
                "interaction_success_rate",
                "pick_up_attempt_rate",
            ]) {
                if let Some(value) = stats[field].as_f64().filter(|v| v.is_finite()) {
                    sum.0 += value;
                    sum.1 += 1;
                }
            }
        }
        let mean = |(sum, n): (f64, usize)| (n > 0).then(|| sum / n as f64);
        let tenths = sums
            .iter()
            .zip(counts)
            .map(|(s, episodes)| Tenth {
                episodes,
                attempt_rate: mean(s[0]),
                interacted_object_rate: mean(s[1]),
                success_rate: mean(s[2]),
                pick_up_attempt_rate: mean(s[3]),
            })
            .collect();
        let entropies: Vec<f64> = records
            .iter()
            .filter(|r| r["kind"] == "ppo")
            .filter_map(|r| r["stats"]["entropy"].as_f64())
            .collect();
        Ok(Self {
            steps,
            wall_s,
            episodes: episodes.len(),
            tenths,
            entropy: entropies
                .first()
                .zip(entropies.last())
                .map(|(a, b)| (*a, *b)),
        })
    }

    /// True when the last tenth's interacted-object rate fell below half
    /// of the best tenth's: the policy stopped exploring.
    pub(crate) fn collapsed(&self) -> bool {
        let rates: Vec<f64> = self
            .tenths
            .iter()
            .filter_map(|t| t.interacted_object_rate)
            .collect();
        let best = rates.iter().copied().fold(0.0, f64::max);
        self.tenths
            .last()
            .and_then(|t| t.interacted_object_rate)
            .is_some_and(|last| best > 0.0 && last < 0.5 * best)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn episode(steps: u64, time_s: f64, rate: f64) -> Value {
        json!({"kind": "episode", "env_steps": steps, "time_s": time_s,
               "stats": {"interacted_object_rate": rate, "interaction_attempt_rate": rate / 2.0,
                         "interaction_success_rate": 0.5}})
    }

    #[test]
    fn tenths_wall_time_over_resumes_and_a_collapse() {
        let mut records: Vec<Value> = (1..=100)
            .map(|i| episode(i * 10, i as f64, if i <= 90 { 0.4 } else { 0.1 }))
            .collect();
        // Resumed after step 500: time starts again.
        for (i, r) in records.iter_mut().enumerate().skip(50) {
            r["time_s"] = json!((i - 49) as f64);
        }
        records.push(
            json!({"kind": "ppo", "env_steps": 1000, "time_s": 51.0, "stats": {"entropy": 0.2}}),
        );
        records.insert(
            0,
            json!({"kind": "ppo", "env_steps": 0, "time_s": 0.0, "stats": {"entropy": 2.0}}),
        );
        let summary = HistorySummary::of(&records).unwrap();
        assert_eq!(summary.steps, 1000);
        assert_eq!(summary.episodes, 100);
        assert!(
            (summary.wall_s - (50.0 + 51.0)).abs() < 1e-9,
            "{}",
            summary.wall_s
        );
        assert_eq!(summary.tenths.len(), 10);
        assert!(summary.tenths.iter().all(|t| t.episodes == 10));
        let near = |x: Option<f64>, y: f64| x.is_some_and(|x| (x - y).abs() < 1e-9);
        assert!(near(summary.tenths[0].interacted_object_rate, 0.4));
        assert!(near(summary.tenths[9].attempt_rate, 0.05));
        assert_eq!(summary.entropy, Some((2.0, 0.2)));
        assert!(summary.collapsed());
        records.truncate(95);
        assert!(!HistorySummary::of(&records).unwrap().collapsed());
    }
}
