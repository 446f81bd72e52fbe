//! The run's history as JSON lines in `RUN_DIR/history.jsonl`: one record
//! per reported episode, policy update, U-Net round and checkpoint scored on
//! the validation rooms, each stamped with
//! the environment steps, the seconds the run has been training
//! (`time_s`, which a resumed run continues rather than restarts) and the
//! wall-clock time (`unix_time_s`). Appended (a resumed run continues the
//! file) and flushed per record, so curves survive a crash; `learner plot`
//! draws them and `/api/history` serves them. The same numbers go to
//! TensorBoard event files beside it (`RUN_DIR/tensorboard/`).

use std::collections::{BTreeMap, VecDeque};
use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use serde::Serialize;
use serde_json::{json, Value};

use crate::tensorboard::EventWriter;

/// File name of the history inside a run directory.
pub const HISTORY_FILE: &str = "history.jsonl";

/// An open history file, with the TensorBoard scalars that mirror it.
pub struct History {
    path: PathBuf,
    file: File,
    started: Instant,
    /// Training seconds of the run before this learner started (its
    /// history's last `time_s`).
    earlier_s: f64,
    /// `None` once writing them failed (the history itself carries on).
    scalars: Option<Scalars>,
}

/// Episodes in each running mean written to TensorBoard.
const EPISODE_WINDOW: usize = 100;

/// The history's records as TensorBoard scalars: every episode metric as
/// its mean over the last 100 episodes (`episode/…`), every PPO update's
/// and U-Net round's numbers (`ppo/…`, `unet/…`), each checkpoint's
/// validation scores (`validation/<affordance>/…`), and environment steps per
/// second between PPO updates (`throughput/env_steps_per_s`).
struct Scalars {
    writer: EventWriter,
    episodes: BTreeMap<String, VecDeque<f64>>,
    last_update: Option<(u64, f64)>,
}

impl Scalars {
    fn add(&mut self, kind: &str, step: u64, record: &Value) -> anyhow::Result<()> {
        let numbers = |object: &Value, prefix: &str| -> Vec<(String, f32)> {
            object
                .as_object()
                .map(|o| {
                    o.iter()
                        .filter_map(|(k, v)| Some((format!("{prefix}/{k}"), v.as_f64()? as f32)))
                        .collect()
                })
                .unwrap_or_default()
        };
        let scalars = match kind {
            "episode" => {
                let mut means = Vec::new();
                for (name, value) in record["stats"].as_object().into_iter().flatten() {
                    let Some(value) = value.as_f64().filter(|v| v.is_finite()) else {
                        continue;
                    };
                    let window = self.episodes.entry(name.clone()).or_default();
                    window.push_back(value);
                    if window.len() > EPISODE_WINDOW {
                        window.pop_front();
                    }
                    let mean = window.iter().sum::<f64>() / window.len() as f64;
                    means.push((format!("episode/{name}"), mean as f32));
                }
                means
            }
            "ppo" => {
                let mut scalars = numbers(&record["stats"], "ppo");
                let time = record["time_s"].as_f64().unwrap_or(0.0);
                if let Some((last_step, last_time)) = self.last_update {
                    if time > last_time && step >= last_step {
                        let rate = (step - last_step) as f64 / (time - last_time);
                        scalars.push(("throughput/env_steps_per_s".into(), rate as f32));
                    }
                }
                self.last_update = Some((step, time));
                scalars
            }
            "unet" => numbers(&record["round"], "unet"),
            "validation" => numbers(&record["validation"], "validation"),
            _ => Vec::new(),
        };
        self.writer.scalars(step, &scalars)
    }
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
        let scalars = match EventWriter::create(run_dir) {
            Ok(writer) => Some(Scalars {
                writer,
                episodes: BTreeMap::new(),
                last_update: None,
            }),
            Err(e) => {
                tracing::warn!("no TensorBoard scalars for this run: {e:#}");
                None
            }
        };
        Ok(Self {
            path,
            file,
            started: Instant::now(),
            earlier_s,
            scalars,
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
            .with_context(|| format!("appending to {} (is the disk full?)", self.path.display()))?;
        if let Some(scalars) = &mut self.scalars {
            if let Err(e) = scalars.add(kind, env_steps, &record) {
                tracing::warn!("stopped writing TensorBoard scalars: {e:#}");
                self.scalars = None;
            }
        }
        Ok(())
    }
}

/// Makes an existing history at `path` safe to append to, and returns its
/// last record's `time_s` (0 without one). A learner killed while writing
/// leaves a torn last line; appending after it would make it a damaged line
/// in the middle, which no reader skips, so it is cut off (one record lost).
fn repair(path: &Path) -> anyhow::Result<f64> {
    // Only a regular file has a last record (a device such as /dev/full
    // would read forever).
    if !std::fs::metadata(path).is_ok_and(|m| m.is_file()) {
        return Ok(0.0);
    }
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
    fn tensorboard_reads_the_scalars_back() {
        let dir = tempfile::tempdir().unwrap();
        let mut history = History::open(dir.path()).unwrap();
        for i in 0..150u64 {
            history
                .record(
                    "episode",
                    (i + 1) * 10,
                    json!({"stats": {"episode_return": i as f64, "interaction_success_rate": 0.5}}),
                )
                .unwrap();
            if i % 50 == 49 {
                history
                    .record(
                        "ppo",
                        (i + 1) * 10,
                        json!({"stats": {"entropy": 1.5, "approx_kl": 0.01}}),
                    )
                    .unwrap();
            }
        }
        history
            .record(
                "unet",
                1500,
                json!({"round": {"train_loss": 0.25, "replaced": true}}),
            )
            .unwrap();
        drop(history);
        // TensorBoard's own reader, independent of the writer.
        let script = "import sys\n\
            from tensorboard.backend.event_processing.event_accumulator import EventAccumulator\n\
            acc = EventAccumulator(sys.argv[1]); acc.Reload()\n\
            r = acc.Scalars('episode/episode_return')\n\
            print(len(r), r[-1].step, r[-1].value)\n\
            print(' '.join(sorted(acc.Tags()['scalars'])))\n";
        let out = std::process::Command::new("python3")
            .args(["-c", script])
            .arg(dir.path().join(crate::tensorboard::TENSORBOARD_DIR))
            .output();
        let required = std::env::var_os("AFX_REQUIRE_PYTHON_CHECKS").is_some();
        let out = match out {
            Ok(out) if out.status.success() => String::from_utf8_lossy(&out.stdout).to_string(),
            Ok(out)
                if !required
                    && String::from_utf8_lossy(&out.stderr).contains("ModuleNotFoundError") =>
            {
                eprintln!(
                    "skipping the TensorBoard read-back: `pip install tensorboard` to run it"
                );
                return;
            }
            Ok(out) => panic!("{}", String::from_utf8_lossy(&out.stderr)),
            Err(e) if !required => {
                eprintln!("skipping the TensorBoard read-back: python3 not runnable ({e})");
                return;
            }
            Err(e) => panic!("python3: {e}"),
        };
        let mut lines = out.lines();
        assert_eq!(
            lines.next(),
            Some("150 1500 99.5"),
            "150 points; the last is the mean of returns 50..=149"
        );
        let tags = lines.next().unwrap_or_default();
        for tag in [
            "episode/episode_return",
            "episode/interaction_success_rate",
            "ppo/entropy",
            "ppo/approx_kl",
            "throughput/env_steps_per_s",
            "unet/train_loss",
        ] {
            assert!(tags.split(' ').any(|t| t == tag), "{tag} in {tags}");
        }
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
