//! Logs that cannot be written do not stop a run. A learner and an actor
//! whose stderr is `/dev/full` (every write fails with "No space left on
//! device", as a log file on a full disk does) train on, and the learner
//! stops cleanly when asked. Before, a log line that could not be written
//! killed the thread that logged it (the formatter reported the failed
//! write with `eprintln!`, which panics when stderr cannot be written; the
//! actor's own status lines were `eprintln!`s too): a learner's receive loop
//! died at its first "actor joined", and the process went on serving its
//! endpoint without training (a run stalled that way on 2026-11-29).

use std::path::Path;
use std::time::Duration;

use system_tests::{bandit_config, bin, scratch_dir, wait_for, Learner, Process};

#[test]
fn a_run_whose_logs_cannot_be_written_trains_on_and_stops_cleanly() {
    let full = Path::new("/dev/full");
    if !full.exists() {
        eprintln!("skipped: this system has no /dev/full");
        return;
    }
    let dir = scratch_dir("full-disk-logs");
    let prefix = format!("it-full-{}", std::process::id());
    let run_dir = dir.join("run");
    let bandit = bandit_config(&dir, &prefix, "checkpoint_every_updates = 2\n");
    let mut learner = Learner::start(
        &run_dir,
        &[
            "--config".into(),
            bandit.display().to_string(),
            "--run-dir".into(),
            run_dir.display().to_string(),
        ],
        full.to_path_buf(),
    );
    let config = run_dir.join("config.toml").display().to_string();
    let args: Vec<String> = ["--actor-id", "0", "--learner", &prefix, "--config", &config]
        .map(String::from)
        .into();
    let mut actor = Process::start(&bin("actor"), &args, full.to_path_buf());

    // Past the events both sides log: the actor's join and first weights,
    // weights broadcasts, checkpoints.
    wait_for(
        Duration::from_secs(60),
        "ten policy updates with both logs failing",
        || {
            assert!(
                actor.child.try_wait().unwrap().is_none(),
                "the actor died of its log"
            );
            (learner.status()["updates"].as_u64().unwrap_or(0) >= 10).then_some(())
        },
    );
    assert!(
        std::fs::read_dir(run_dir.join("checkpoints"))
            .unwrap()
            .count()
            >= 2,
        "checkpoints are written as usual"
    );

    learner.process.signal(libc::SIGTERM);
    let status = learner
        .process
        .wait_exit(Duration::from_secs(30))
        .expect("the learner stops when asked");
    assert!(status.success(), "the learner stopped with {status}");
    actor.signal(libc::SIGTERM);
    assert!(
        actor.wait_exit(Duration::from_secs(30)).is_some(),
        "the actor stops when asked"
    );
}
