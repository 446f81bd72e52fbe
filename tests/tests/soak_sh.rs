//! `deploy/soak.sh`, short: two minutes of a `deploy/local.sh` run (bandit
//! fixture, two actors) with an actor SIGKILLed every 45 s and the learner
//! once, at 60 s, after which the script resumes the run. Every process is
//! sampled through the run, killed processes come back and count again, the
//! run resumes from a checkpoint and stops cleanly, every kept checkpoint
//! verifies, nothing is left in shared memory, and the verdict matches the
//! exit status.

use std::process::Command;

use system_tests::{bin, scratch_dir};

#[test]
fn soak_samples_every_process_through_kills_and_gives_a_verdict() {
    let dir = scratch_dir("soak");
    let run_dir = dir.join(format!("soak-{}", std::process::id()));
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("a free port")
        .port();
    let repo = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    // Checkpoints every few updates, so that the learner's kill has one to resume from.
    let config = dir.join("often.toml");
    std::fs::write(
        &config,
        "checkpoint_every_updates = 5\nkeep_checkpoints = 3\n",
    )
    .unwrap();
    let output = Command::new(repo.join("deploy/soak.sh"))
        .arg("--run-dir")
        .arg(&run_dir)
        .args([
            "--minutes",
            "2",
            "--every",
            "2",
            "--warmup",
            "0",
            "--window",
            "1",
        ])
        .args(["--kill-every", "45", "--kill-learner-every", "60", "--"])
        .args(["--actors", "2", "--env", "bandit-fixture", "--seed", "4"])
        .arg("--bin-dir")
        .arg(bin("learner").parent().expect("binary dir"))
        .args(["--port", &port.to_string(), "--", "--config"])
        .arg(&config)
        .output()
        .expect("running deploy/soak.sh");
    let said = format!(
        "{}{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
    let code = output.status.code();
    assert!(matches!(code, Some(0 | 2)), "{code:?}:\n{said}");
    assert!(
        said.contains("soak: resumed (resumed from checkpoint"),
        "{said}"
    );

    let csv = std::fs::read_to_string(run_dir.join("soak.csv")).expect("soak.csv");
    let samples: Vec<(u64, String, String)> = csv
        .lines()
        .skip(1)
        .map(|line| {
            let f: Vec<&str> = line.split(',').collect();
            assert_eq!(f.len(), 4, "{line}");
            assert!(f[3].parse::<u64>().expect("RSS in KiB") > 1000, "{line}");
            (f[0].parse().expect("seconds"), f[1].into(), f[2].into())
        })
        .collect();
    for role in ["learner", "actor-0", "actor-1"] {
        let times: Vec<u64> = samples
            .iter()
            .filter(|s| s.1 == role)
            .map(|s| s.0)
            .collect();
        assert!(
            times.first() < Some(&10) && times.last() > Some(&100),
            "{role} sampled through the run: {times:?}"
        );
    }
    // Two actor kills (at 45 and 90 s) and the learner's (at 60 s, which
    // stops both actors before the resume): six actor processes in all,
    // two learners.
    let actor_pids: std::collections::BTreeSet<&str> = samples
        .iter()
        .filter(|s| s.1.starts_with("actor-"))
        .map(|s| s.2.as_str())
        .collect();
    assert_eq!(actor_pids.len(), 6, "{actor_pids:?}\n{said}");
    let learner_pids: std::collections::BTreeSet<&str> = samples
        .iter()
        .filter(|s| s.1 == "learner")
        .map(|s| s.2.as_str())
        .collect();
    assert_eq!(learner_pids.len(), 2, "{learner_pids:?}\n{said}");

    let summary = std::fs::read_to_string(run_dir.join("soak.md")).expect("soak.md");
    assert!(
        summary.contains("2 actors and 1 learners SIGKILLed"),
        "{summary}"
    );
    assert!(
        summary.contains("all verify against their manifests"),
        "{summary}"
    );
    assert!(
        summary.contains("Shared memory left in /dev/shm: none."),
        "{summary}"
    );
    for role in ["learner", "actor-0", "actor-1"] {
        let row = summary
            .lines()
            .find(|l| l.starts_with(&format!("| {role} |")))
            .unwrap_or_else(|| panic!("no row for {role}:\n{summary}"));
        assert!(!row.contains("too short"), "{row}");
    }
    let flat = summary.contains("stayed flat");
    assert_eq!(flat, code == Some(0), "verdict and exit status:\n{summary}");
    let local = std::fs::read_to_string(run_dir.join("soak-local.log")).unwrap_or_default();
    assert!(
        local.contains("stopped (learner exit status 0)"),
        "a clean stop:\n{local}"
    );
}
