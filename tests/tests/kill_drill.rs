//! The kill drill, short: a `deploy/local.sh` run (bandit fixture, two
//! actors) whose actors are SIGKILLed three times and whose learner is
//! SIGKILLed once, then resumed with `--resume`. The supervisor restarts every
//! actor, the resume continues from the newest checkpoint, every kept
//! checkpoint verifies against its manifest with an outside reader
//! (`sha256sum`), the run stops cleanly, and it leaves nothing in /dev/shm.

use std::collections::BTreeSet;
use std::path::Path;
use std::process::Command;
use std::time::Duration;

use system_tests::{
    checkpoint_steps as checkpoints, kill_pid as kill, launch_bandit_run as launch,
    run_status as status, scratch_dir, wait_for, wait_launch_exit as wait_exit,
};

/// Whether every file of checkpoint `step` has the size and SHA-256 its
/// manifest says, by `sha256sum` (not the learner's own code).
fn verifies(run_dir: &Path, step: u64) -> bool {
    let dir = run_dir.join("checkpoints").join(step.to_string());
    let Ok(text) = std::fs::read_to_string(dir.join("manifest.json")) else {
        return false;
    };
    let manifest: serde_json::Value = serde_json::from_str(&text).expect("manifest JSON");
    manifest["files"]
        .as_array()
        .expect("files")
        .iter()
        .all(|file| {
            let out = Command::new("sha256sum")
                .arg(dir.join(file["name"].as_str().unwrap()))
                .output()
                .expect("sha256sum");
            let sum = String::from_utf8_lossy(&out.stdout).to_string();
            out.status.success() && sum.split_whitespace().next() == file["sha256"].as_str()
        })
}

fn shm_files() -> BTreeSet<String> {
    std::fs::read_dir("/dev/shm")
        .map(|d| {
            d.filter_map(|e| Some(e.ok()?.file_name().to_str()?.to_string()))
                .filter(|n| n.starts_with("iox2_"))
                .collect()
        })
        .unwrap_or_default()
}

#[test]
fn a_run_survives_killed_actors_and_a_killed_learner_and_resumes_from_its_newest_checkpoint() {
    let dir = scratch_dir("kill-drill");
    let run_dir = dir.join(format!("drill-{}", std::process::id()));
    let config = dir.join("often.toml");
    std::fs::write(
        &config,
        "checkpoint_every_updates = 5\nkeep_checkpoints = 3\n",
    )
    .unwrap();
    let config = config.display().to_string();
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("a free port")
        .port();
    let shm_before = shm_files();

    let mut first = launch(
        &run_dir,
        port,
        dir.join("first.log"),
        &["--", "--config", &config],
    );
    wait_for(Duration::from_secs(60), "a first checkpoint", || {
        (checkpoints(&run_dir).len() >= 2).then_some(())
    });
    let logs = run_dir.join("logs");
    for round in 0..3 {
        let id = round % 2;
        let pid = std::fs::read_to_string(logs.join(format!("actor-{id}.pid"))).expect("actor pid");
        kill(&pid, libc::SIGKILL);
        wait_for(Duration::from_secs(30), "the supervisor's restart", || {
            let now = std::fs::read_to_string(logs.join(format!("actor-{id}.pid"))).ok()?;
            (now.trim() != pid.trim() && !now.trim().is_empty()).then_some(())
        });
    }
    wait_for(Duration::from_secs(30), "both actors alive again", || {
        (status(port)?["actors_alive"] == 2).then_some(())
    });
    // The learner dies without a final checkpoint.
    let learner = Command::new("pgrep")
        .args([
            "-f",
            &format!(
                "learner serve --service-prefix afx-drill-{}",
                std::process::id()
            ),
        ])
        .output()
        .expect("pgrep");
    let learner = String::from_utf8_lossy(&learner.stdout).to_string();
    let learner = learner
        .lines()
        .next()
        .expect("the learner's pid")
        .to_string();
    kill(&learner, libc::SIGKILL);
    let exit = wait_exit(&mut first, 90);
    assert!(
        !exit.success(),
        "a killed learner ends the script with an error"
    );
    let newest = *checkpoints(&run_dir)
        .iter()
        .rev()
        .find(|&&step| verifies(&run_dir, step))
        .expect("a checkpoint that verifies");

    let mut second = launch(&run_dir, port, dir.join("second.log"), &["--resume"]);
    wait_for(
        Duration::from_secs(60),
        "steps beyond the newest checkpoint",
        || (status(port)?["env_steps"].as_u64()? > newest).then_some(()),
    );
    let learner_log = std::fs::read_to_string(logs.join("learner.log")).unwrap_or_default();
    assert!(
        learner_log.contains(&format!("checkpoints/{newest} (env steps {newest},")),
        "resumed from the newest checkpoint {newest}:\n{learner_log}"
    );
    for id in 0..2 {
        let log = std::fs::read_to_string(logs.join(format!("actor-{id}.log"))).unwrap_or_default();
        assert!(
            log.contains("got policy version"),
            "actor {id} came back:\n{log}"
        );
    }
    kill(&second.script.id().to_string(), libc::SIGTERM);
    let exit = wait_exit(&mut second, 90);
    assert!(
        exit.success(),
        "{exit}:\n{}",
        std::fs::read_to_string(&second.log).unwrap_or_default()
    );

    // Every kept checkpoint verifies with an outside reader.
    let kept = checkpoints(&run_dir);
    assert!(kept.len() >= 2, "{kept:?}");
    for step in kept {
        assert!(
            verifies(&run_dir, step),
            "checkpoint {step} does not verify"
        );
    }
    // Nothing of the run is left in shared memory.
    let left: Vec<String> = shm_files().difference(&shm_before).cloned().collect();
    assert!(left.is_empty(), "left in /dev/shm: {left:?}");
}
