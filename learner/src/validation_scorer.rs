//! The background validation scorer: each checkpoint the learner writes is
//! scored on the validation rooms (FloorPlan221–225) by a process of its
//! own (`actor evaluate --scores`, few views, one thread, lowest priority),
//! so that a run shows how its U-Net does in rooms it never trained in
//! while it trains, and `actor evaluate --select` can choose a checkpoint
//! without scoring them all again. Training never waits for it: the
//! receive loop only hands over a step; while one scoring runs, the newest
//! checkpoint waits and older waiting ones are skipped (counted). The
//! scores go to the history (kind `validation`, so also TensorBoard and the
//! live page) and to the status (`/api/status`, `/metrics`).

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use anyhow::Context;

use crate::history::History;
use crate::shared::Shared;

/// File in the run's `logs/` that the scorer's output is appended to.
pub(crate) const SCORER_LOG: &str = "validation-scorer.log";

/// Steps waiting for the scorer thread.
#[derive(Debug, Default)]
struct Waiting {
    /// The newest checkpoint not yet scored.
    next: Option<u64>,
    stop: bool,
}

/// The scorer thread and its hand-over slot.
pub(crate) struct ValidationScorer {
    waiting: Arc<(Mutex<Waiting>, Condvar)>,
    shared: Arc<Shared>,
    thread: Option<JoinHandle<()>>,
}

impl ValidationScorer {
    /// Starts the scorer for the run in `shared`, or returns `None` and
    /// says why in the status when it is off (`[validation] views_per_room
    /// = 0`, a task without a U-Net and no scorer named, no `actor` binary
    /// beside the learner's).
    pub fn start(shared: Arc<Shared>, history: Arc<Mutex<History>>) -> Option<Self> {
        let program = match scorer_program(&shared) {
            Ok(program) => program,
            Err(why) => {
                tracing::info!("validation scorer off: {why}");
                shared.status().validation.off = Some(why);
                return None;
            }
        };
        tracing::info!(
            program = %program.display(),
            "scoring each checkpoint on the validation rooms in the background"
        );
        let waiting = Arc::new((Mutex::new(Waiting::default()), Condvar::new()));
        let thread = {
            let (waiting, shared) = (waiting.clone(), shared.clone());
            std::thread::Builder::new()
                .name("validation-scorer".into())
                .spawn(move || score_until_stopped(&program, &waiting, &shared, &history))
        };
        match thread {
            Ok(thread) => Some(Self {
                waiting,
                shared,
                thread: Some(thread),
            }),
            Err(e) => {
                let why = format!("cannot start its thread: {e}");
                tracing::warn!("validation scorer off: {why}");
                shared.status().validation.off = Some(why);
                None
            }
        }
    }

    /// Hands checkpoint `step` over for scoring, without waiting; a step
    /// still waiting is skipped for it. Locks the status: never call it
    /// with the status locked.
    pub fn submit(&self, step: u64) {
        let (lock, ready) = &*self.waiting;
        let skipped = {
            let mut waiting = lock.lock().unwrap_or_else(|p| p.into_inner());
            waiting.next.replace(step).is_some()
        };
        ready.notify_one();
        if skipped {
            self.shared.status().validation.skipped += 1;
        }
    }

    /// Stops the thread: a scoring in progress is killed, nothing waiting
    /// is scored.
    pub fn stop(mut self) {
        self.stop_thread();
    }

    fn stop_thread(&mut self) {
        {
            let (lock, ready) = &*self.waiting;
            lock.lock().unwrap_or_else(|p| p.into_inner()).stop = true;
            ready.notify_one();
        }
        if let Some(thread) = self.thread.take() {
            if thread.join().is_err() {
                tracing::warn!("the validation scorer's thread panicked");
            }
        }
    }
}

impl Drop for ValidationScorer {
    fn drop(&mut self) {
        self.stop_thread();
    }
}

/// The program that scores, or why there is none.
fn scorer_program(shared: &Shared) -> Result<PathBuf, String> {
    let config = &shared.config.validation;
    if config.views_per_room == 0 {
        return Err("[validation] views_per_room = 0".into());
    }
    if !config.scorer.is_empty() {
        return Ok(PathBuf::from(&config.scorer));
    }
    if shared.config.task.env != proto::EnvKind::Sim {
        return Err("the task has no U-Net to score".into());
    }
    let beside = std::env::current_exe()
        .ok()
        .and_then(|exe| Some(exe.parent()?.join("actor")));
    match beside {
        Some(actor) if actor.is_file() => Ok(actor),
        _ => Err(
            "no `actor` binary beside the learner's (build both, or name one in [validation] \
             scorer)"
                .into(),
        ),
    }
}

/// The scorer thread: waits for a step, scores it, publishes the scores.
fn score_until_stopped(
    program: &Path,
    waiting: &(Mutex<Waiting>, Condvar),
    shared: &Shared,
    history: &Mutex<History>,
) {
    let (lock, ready) = waiting;
    loop {
        let step = {
            let mut waiting = lock.lock().unwrap_or_else(|p| p.into_inner());
            loop {
                if waiting.stop {
                    return;
                }
                if let Some(step) = waiting.next.take() {
                    break step;
                }
                waiting = ready.wait(waiting).unwrap_or_else(|p| p.into_inner());
            }
        };
        shared.status().validation.scoring_step = Some(step);
        let stopped = || lock.lock().unwrap_or_else(|p| p.into_inner()).stop;
        let outcome = score(program, step, shared, &stopped);
        let mut status = shared.status();
        status.validation.scoring_step = None;
        match outcome {
            Ok(Some(scores)) => {
                status.validation.scored += 1;
                status.validation.last = Some(scores.clone());
                drop(status);
                record(history, &scores);
            }
            Ok(None) => return, // stopped mid-scoring
            Err(e) => {
                status.validation.failed += 1;
                drop(status);
                tracing::warn!(
                    "scoring checkpoint {step} on the validation rooms failed: {e:#} (see logs/{SCORER_LOG})"
                );
            }
        }
    }
}

/// Runs the scorer on checkpoint `step`; `None` when `stopped` said to stop
/// before it finished (the process is killed).
fn score(
    program: &Path,
    step: u64,
    shared: &Shared,
    stopped: &dyn Fn() -> bool,
) -> anyhow::Result<Option<proto::ValidationScores>> {
    let run_dir = &shared.run_dir;
    let out = run_dir
        .join(proto::VALIDATION_DIR)
        .join(format!("{step}.json"));
    let logs = run_dir.join("logs");
    std::fs::create_dir_all(&logs).with_context(|| format!("creating {}", logs.display()))?;
    let log = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(logs.join(SCORER_LOG))
        .with_context(|| format!("opening logs/{SCORER_LOG}"))?;
    let mut command = Command::new(program);
    command
        .arg("evaluate")
        .arg("--run-dir")
        .arg(run_dir)
        .args(["--step", &step.to_string(), "--scenes", "val"])
        .args([
            "--views-per-scene",
            &shared.config.validation.views_per_room.to_string(),
            "--seed",
            &shared.config.validation.seed.to_string(),
        ])
        .arg("--scores")
        .arg(&out)
        // One thread: the scorer takes a core at most, and only an idle one.
        .env("RAYON_NUM_THREADS", "1")
        .env("OMP_NUM_THREADS", "1")
        .stdin(Stdio::null())
        .stdout(log.try_clone()?)
        .stderr(log);
    lower_priority(&mut command, shared.config.validation.nice);
    let mut child = command
        .spawn()
        .with_context(|| format!("starting {}", program.display()))?;
    let Some(status) = wait_unless_stopped(&mut child, stopped)? else {
        return Ok(None);
    };
    anyhow::ensure!(
        status.success(),
        "{} ended with {status}",
        program.display()
    );
    let text =
        std::fs::read_to_string(&out).with_context(|| format!("reading {}", out.display()))?;
    let scores: proto::ValidationScores =
        serde_json::from_str(&text).with_context(|| format!("parsing {}", out.display()))?;
    anyhow::ensure!(
        scores.step == step,
        "{} holds the scores of step {}, not {step}",
        out.display(),
        scores.step
    );
    Ok(Some(scores))
}

/// Waits for `child`, polling `stopped`: when it says stop, kills the
/// child and returns `None`.
fn wait_unless_stopped(
    child: &mut Child,
    stopped: &dyn Fn() -> bool,
) -> anyhow::Result<Option<std::process::ExitStatus>> {
    loop {
        if let Some(status) = child.try_wait()? {
            return Ok(Some(status));
        }
        if stopped() {
            let _ = child.kill();
            let _ = child.wait();
            return Ok(None);
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// Makes `command`'s process start at niceness `nice`.
fn lower_priority(command: &mut Command, nice: i32) {
    use std::os::unix::process::CommandExt;
    // SAFETY: the closure runs in the child between fork and exec and only
    // makes one system call on plain integers (async-signal-safe). It
    // fails, harmlessly, only where the learner already runs nicer.
    unsafe {
        command.pre_exec(move || {
            libc::setpriority(libc::PRIO_PROCESS, 0, nice);
            Ok(())
        });
    }
}

/// Appends `scores` to the history as a `validation` record.
fn record(history: &Mutex<History>, scores: &proto::ValidationScores) {
    let values: serde_json::Map<String, serde_json::Value> = scores
        .named_values()
        .into_iter()
        .map(|(name, value)| (name, serde_json::Value::from(value)))
        .collect();
    let fields = serde_json::json!({
        "validation": values,
        "views_per_scene": scores.views_per_scene,
        "threshold": scores.threshold,
    });
    let written =
        history
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .record("validation", scores.step, fields);
    if let Err(e) = written {
        tracing::warn!(
            "the history lacks checkpoint {}'s validation scores: {e:#}",
            scores.step
        );
    }
}
