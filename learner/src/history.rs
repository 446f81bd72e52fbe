//! The run's history as JSON lines in `RUN_DIR/history.jsonl`: one record
//! per reported episode, policy update and U-Net round, each stamped with
//! the environment steps and seconds since the learner started. Appended
//! (a resumed run continues the file) and flushed per record, so curves
//! survive a crash; `learner plot` draws them and `/api/history` serves them.

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
}

impl History {
    /// Opens (creating or appending to) the history of `run_dir`.
    pub fn open(run_dir: &Path) -> anyhow::Result<Self> {
        let path = run_dir.join(HISTORY_FILE);
        let file = OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
            .with_context(|| format!("opening {}", path.display()))?;
        Ok(Self {
            path,
            file,
            started: Instant::now(),
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
            "time_s": self.started.elapsed().as_secs_f64(),
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
}
