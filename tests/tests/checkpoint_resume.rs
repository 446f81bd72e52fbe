//! Checkpoints under real crashes: SIGKILL the learner, `--resume` continues
//! counters, versions and the policy optimiser's state from the newest
//! checkpoint; a checkpoint with one flipped byte is refused by checksum and
//! the previous one is used.

use std::path::{Path, PathBuf};
use std::time::Duration;

use system_tests::{scratch_dir, start_actor, wait_for, Learner};

fn checkpoints(run_dir: &Path) -> Vec<(u64, PathBuf)> {
    let mut all: Vec<_> = std::fs::read_dir(run_dir.join("checkpoints"))
        .map(|rd| {
            rd.filter_map(|e| e.ok())
                .filter_map(|e| {
                    e.file_name()
                        .to_str()
                        .and_then(|n| n.parse::<u64>().ok())
                        .map(|s| (s, e.path()))
                })
                .collect()
        })
        .unwrap_or_default();
    all.sort();
    all
}

fn counters(dir: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(dir.join("counters.json")).unwrap()).unwrap()
}

fn assert_resumed_from(learner: &Learner, checkpoint: &Path) {
    let expected = counters(checkpoint);
    let status = learner.status();
    for field in ["env_steps", "updates", "policy_version", "episodes"] {
        assert_eq!(
            status[field],
            expected[field],
            "{field} after resume from {}",
            checkpoint.display()
        );
    }
    let log = learner.process.log_text();
    assert!(
        log.contains(&format!("resumed from checkpoint {}", checkpoint.display())),
        "log does not say which checkpoint:\n{log}"
    );
    assert!(
        checkpoint.join("policy_optimizer.bpk").exists()
            && log.contains("policy optimiser state restored"),
        "Adam's state was not saved and restored:\n{log}"
    );
}

#[test]
fn resume_after_kill_and_fall_back_past_a_corrupt_checkpoint() {
    let dir = scratch_dir("checkpoint");
    let prefix = format!("it-ckpt-{}", std::process::id());
    let run_dir = dir.join("run");
    let config = dir.join("learner.toml");
    std::fs::write(&config, format!("checkpoint_interval_s = 0.3\ncheckpoint_every_updates = 0\nkeep_checkpoints = 3\n[transport]\nservice_prefix = \"{prefix}\"\nmax_actors = 2\n[task]\nenv = \"bandit-fixture\"\n[policy]\nbatch_steps = 32\n")).unwrap();
    let run_args = |resume: bool| {
        let flag = if resume { "--resume" } else { "--run-dir" };
        vec![
            "--config".to_string(),
            config.display().to_string(),
            flag.into(),
            run_dir.display().to_string(),
        ]
    };

    let mut learner = Learner::start(&run_dir, &run_args(false), dir.join("learner-1.log"));
    let mut actor = start_actor(
        0,
        &prefix,
        &dir,
        &[
            "--config",
            &config.display().to_string(),
            "--join-key",
            &run_dir.join("join.key").display().to_string(),
        ],
    );
    wait_for(
        Duration::from_secs(30),
        "two checkpoints with training in them",
        || {
            let all = checkpoints(&run_dir);
            (all.len() >= 2
                && all.iter().all(|(_, d)| {
                    d.join("manifest.json").exists() && counters(d)["updates"].as_u64() > Some(0)
                }))
            .then_some(())
        },
    );
    actor.signal(libc::SIGINT);
    actor
        .wait_exit(Duration::from_secs(10))
        .expect("actor stops");
    learner.process.signal(libc::SIGKILL);
    learner
        .process
        .wait_exit(Duration::from_secs(5))
        .expect("learner dies");
    drop(learner);

    let all = checkpoints(&run_dir);
    let (newest_step, newest) = all.last().cloned().unwrap();
    let (_, previous) = all[all.len() - 2].clone();
    assert!(
        counters(&newest)["policy_version"].as_u64() > Some(1),
        "training advanced the policy version"
    );

    // Resume: counters and versions continue from the newest checkpoint.
    let mut learner = Learner::start(&run_dir, &run_args(true), dir.join("learner-2.log"));
    assert_resumed_from(&learner, &newest);
    learner.process.signal(libc::SIGKILL);
    learner
        .process
        .wait_exit(Duration::from_secs(5))
        .expect("learner dies");
    drop(learner);

    // Flip one byte of the newest checkpoint's weights: refused, previous used.
    let weights = newest.join("weights.safetensors");
    let mut bytes = std::fs::read(&weights).unwrap();
    let last = bytes.len() - 1;
    bytes[last] ^= 0x10;
    std::fs::write(&weights, bytes).unwrap();
    let learner = Learner::start(&run_dir, &run_args(true), dir.join("learner-3.log"));
    assert_resumed_from(&learner, &previous);
    let log = learner.process.log_text();
    assert!(
        log.contains("skipping damaged checkpoint") && log.contains(&newest_step.to_string()),
        "no warning about the damaged checkpoint:\n{log}"
    );
}

/// A learner killed before it wrote any checkpoint leaves a run that
/// `--resume` starts afresh in the same directory (its history set aside);
/// the first checkpoint then comes with the first update, long before the
/// default cadence (120 s), so the next kill loses at most that.
#[test]
fn a_learner_killed_before_its_first_checkpoint_leaves_a_run_to_resume() {
    let dir = scratch_dir("first-checkpoint");
    let prefix = format!("it-first-{}", std::process::id());
    let run_dir = dir.join("run");
    let config = dir.join("learner.toml");
    // The default cadence: by time (120 s) and by count (10 000 updates).
    std::fs::write(&config, format!("[transport]\nservice_prefix = \"{prefix}\"\nmax_actors = 2\n[task]\nenv = \"bandit-fixture\"\n[policy]\nbatch_steps = 32\n")).unwrap();
    let args = |flag: &str| {
        vec![
            "--config".to_string(),
            config.display().to_string(),
            flag.into(),
            run_dir.display().to_string(),
        ]
    };
    let kill = |mut learner: Learner| {
        learner.process.signal(libc::SIGKILL);
        learner
            .process
            .wait_exit(Duration::from_secs(5))
            .expect("learner dies");
    };

    // Killed with episodes in its history but no update yet: no checkpoint.
    let learner = Learner::start(&run_dir, &args("--run-dir"), dir.join("learner-1.log"));
    std::fs::write(
        run_dir.join("history.jsonl"),
        "{\"kind\":\"episode\",\"env_steps\":7,\"time_s\":1.0}\n",
    )
    .unwrap();
    kill(learner);
    assert!(checkpoints(&run_dir).is_empty());

    // Resumed: it starts afresh, says so, and keeps the lost history aside.
    let learner = Learner::start(&run_dir, &args("--resume"), dir.join("learner-2.log"));
    let log = learner.process.log_text();
    assert!(
        log.contains("has no checkpoint") && log.contains("starting the run afresh"),
        "{log}"
    );
    assert_eq!(learner.status()["env_steps"].as_u64(), Some(0));
    let aside: Vec<_> = std::fs::read_dir(&run_dir)
        .unwrap()
        .filter_map(|e| e.ok()?.file_name().into_string().ok())
        .filter(|n| n.starts_with("history.jsonl.before-restart-"))
        .collect();
    assert_eq!(aside.len(), 1, "the lost history is kept");

    // Its first update writes the first checkpoint.
    let join_key = run_dir.join("join.key").display().to_string();
    let config_arg = config.display().to_string();
    let mut actor = start_actor(
        0,
        &prefix,
        &dir,
        &["--config", &config_arg, "--join-key", &join_key],
    );
    let (step, first) = wait_for(Duration::from_secs(60), "the first checkpoint", || {
        checkpoints(&run_dir)
            .into_iter()
            .find(|(_, d)| d.join("manifest.json").exists())
    });
    assert!(counters(&first)["updates"].as_u64() >= Some(1));
    actor.signal(libc::SIGINT);
    actor
        .wait_exit(Duration::from_secs(10))
        .expect("actor stops");
    kill(learner);

    // Killed again: it resumes from that checkpoint.
    let learner = Learner::start(&run_dir, &args("--resume"), dir.join("learner-3.log"));
    let (newest_step, newest) = checkpoints(&run_dir).last().cloned().unwrap();
    assert!(newest_step >= step);
    assert_resumed_from(&learner, &newest);
}
