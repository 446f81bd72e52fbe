//! The run's history as JSON lines in `RUN_DIR/history.jsonl`: one record
//! per reported episode, policy update and U-Net round, each stamped with
//! the environment steps and seconds since the learner started. Appended
//! (a resumed run continues the file) and flushed per record, so curves
//! survive a crash; `learner plot` draws them.

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
