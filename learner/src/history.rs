//! The run's history as JSON lines in `RUN_DIR/history.jsonl`: one record
//! per reported episode, policy update and U-Net round, each stamped with
//! the environment steps, the seconds the run has been training
//! (`time_s`, which a resumed run continues rather than restarts) and the
//! wall-clock time (`unix_time_s`). Appended (a resumed run continues the
//! file) and flushed per record, so curves survive a crash; `learner plot`
//! draws them and `/api/history` serves them.

use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use serde::Serialize;
use serde_json::{json, Value};

/// File name of the history inside a run directory.
pub const HISTORY_FILE: &str = "history.jsonl";

/// An open history file.
pub struct History {
    path: PathBuf,
    file: File,
    started: Instant,
    /// Training seconds of the run before this learner started (its
    /// history's last `time_s`).
    earlier_s: f64,
}

impl History {
    /// Opens (creating or appending to) the history of `run_dir`.
    pub fn open(run_dir: &Path) -> anyhow::Result<Self> {
        let path = run_dir.join(HISTORY_FILE);
        let earlier_s = repair(&path)?;
        let file = OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
            .with_context(|| format!("opening {}", path.display()))?;
        Ok(Self {
            path,
            file,
            started: Instant::now(),
            earlier_s,
        })
    }

    /// Appends one record of `kind` with the fields of `fields` (an object).
    pub fn record(
        &mut self,
        kind: &str,
        env_steps: u64,
        fields: impl Serialize,
    ) -> anyhow::Result<()> {
        let mut record = json!({
            "kind": kind,
            "env_steps": env_steps,
            "time_s": self.earlier_s + self.started.elapsed().as_secs_f64(),
            "unix_time_s": std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0.0, |d| d.as_secs_f64()),
        });
        if let (Value::Object(out), Ok(Value::Object(more))) =
            (&mut record, serde_json::to_value(fields))
        {
            out.extend(more);
        }
        let mut line = serde_json::to_vec(&record)?;
        line.push(b'\n');
        self.file
            .write_all(&line)
            .with_context(|| format!("appending to {} (is the disk full?)", self.path.display()))
    }
}

/// Makes an existing history at `path` safe to append to, and returns its
/// last record's `time_s` (0 without one). A learner killed while writing
/// leaves a torn last line; appending after it would make it a damaged line
/// in the middle, which no reader skips, so it is cut off (one record lost).
fn repair(path: &Path) -> anyhow::Result<f64> {
    let text = match std::fs::read(path) {
        Ok(text) => text,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(0.0),
        Err(e) => return Err(e).with_context(|| format!("reading {}", path.display())),
    };
    let whole = text.iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1);
    if whole < text.len() {
        OpenOptions::new()
            .write(true)
            .open(path)
            .and_then(|f| f.set_len(whole as u64))
            .with_context(|| format!("cutting a torn last record off {}", path.display()))?;
        tracing::warn!(
            "{}: cut off a torn last record ({} bytes) left by a learner that was killed while writing",
            path.display(),
            text.len() - whole
        );
    }
    let last_time = String::from_utf8_lossy(&text[..whole])
        .lines()
        .rev()
        .find_map(|line| serde_json::from_str::<Value>(line).ok()?["time_s"].as_f64())
        .unwrap_or(0.0);
    Ok(last_time)
}

/// The records of `run_dir`'s history in file order, only those of `kind`
/// when given. An unreadable last line is a record still being written and
/// is skipped; an unreadable line elsewhere is an error.
pub fn read_records(run_dir: &Path, kind: Option<&str>) -> anyhow::Result<Vec<Value>> {
    let path = run_dir.join(HISTORY_FILE);
    let text = std::fs::read_to_string(&path).with_context(|| {
        format!(
            "reading {} (is this a run directory of the learner?)",
            path.display()
        )
    })?;
    let lines: Vec<&str> = text.lines().collect();
    let mut records = Vec::new();
    for (number, line) in lines.iter().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        let record: Value = match serde_json::from_str(line) {
            Ok(record) => record,
            Err(_) if number + 1 == lines.len() && !text.ends_with('\n') => break,
            Err(e) => {
                return Err(e)
                    .with_context(|| format!("{} line {}: not JSON", path.display(), number + 1))
            }
        };
        if kind.is_none_or(|k| record["kind"] == k) {
            records.push(record);
        }
    }
    Ok(records)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_read_back_by_kind_and_a_torn_last_line_is_skipped() {
        let dir = tempfile::tempdir().unwrap();
        let mut history = History::open(dir.path()).unwrap();
        history
            .record("episode", 10, json!({"stats": {"episode_return": 1.5}}))
            .unwrap();
        history
            .record("ppo", 20, json!({"policy_version": 2}))
            .unwrap();
        drop(history);
        let all = read_records(dir.path(), None).unwrap();
        assert_eq!(all.len(), 2);
        assert_eq!(all[0]["stats"]["episode_return"], 1.5);
        assert_eq!(all[1]["env_steps"], 20);
        let ppo = read_records(dir.path(), Some("ppo")).unwrap();
        assert_eq!(ppo.len(), 1);
        // A record being appended right now.
        let path = dir.path().join(HISTORY_FILE);
        let mut text = std::fs::read_to_string(&path).unwrap();
        text.push_str("{\"kind\":\"epi");
        std::fs::write(&path, &text).unwrap();
        assert_eq!(read_records(dir.path(), None).unwrap().len(), 2);
        // Damage in the middle is reported.
        std::fs::write(&path, format!("nonsense\n{text}\n")).unwrap();
        let err = read_records(dir.path(), None).unwrap_err().to_string();
        assert!(err.contains("line 1"), "{err}");
    }

    #[test]
    fn a_resumed_history_continues_its_time_and_cuts_a_torn_record() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(HISTORY_FILE);
        std::fs::write(
            &path,
            "{\"kind\":\"ppo\",\"env_steps\":5,\"time_s\":100.5}\n{\"kind\":\"epi",
        )
        .unwrap();
        let mut history = History::open(dir.path()).unwrap();
        history.record("ppo", 10, json!({})).unwrap();
        drop(history);
        let records = read_records(dir.path(), None).unwrap();
        assert_eq!(records.len(), 2, "the torn record is gone, the rest reads");
        let time = records[1]["time_s"].as_f64().unwrap();
        assert!((100.5..101.5).contains(&time), "continues at {time}");
        let unix = records[1]["unix_time_s"].as_f64().unwrap();
        assert!(unix > 1.7e9, "wall-clock time: {unix}");
    }
}
