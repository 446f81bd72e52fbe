//! The gateway pair under faults, two "hosts" on one machine over loopback
//! TCP: bytes that are not messages, sent straight into the learner host's
//! gateway over Zenoh, are counted and dropped; a learner stopped for 10 s
//! (SIGSTOP) tears no link down and grows neither gateway's memory, and the
//! remote actors' rollouts come back when it continues. Also the closed
//! loop with a simulator actor on the other host: its labelled frames train
//! the U-Net, whose weights reach it.

use std::path::{Path, PathBuf};
use std::time::Duration;

use system_tests::{
    free_port, host_dir, scratch_dir, start_actor, start_host_gateway, start_learner_gateway,
    wait_for, Learner, Process,
};

/// Resident memory of a process, KiB.
fn rss_kib(pid: u32) -> u64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .ok()
        .and_then(|s| {
            s.lines()
                .find_map(|l| l.strip_prefix("VmRSS:"))
                .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        })
        .unwrap_or(0)
}

/// Rollouts the learner received from actor `id`.
fn rollouts(learner: &Learner, id: u64) -> u64 {
    learner.status()["actors"]
        .as_array()
        .and_then(|a| a.iter().find(|x| x["id"] == id).cloned())
        .and_then(|a| a["received"]["rollout"].as_u64())
        .unwrap_or(0)
}

/// The learner host's gateway and an actor host's (host "box-f", service
/// prefix `prefix`, run directory `dir/box-f`), linked over loopback TCP.
struct Pair {
    learner_side: Process,
    host_side: Process,
    endpoint: String,
    host_config: PathBuf,
}

fn start_pair(dir: &Path, run_dir: &Path, prefix: &str) -> Pair {
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let learner_side = start_learner_gateway(
        run_dir,
        &endpoint,
        "faults",
        &[],
        dir.join("gateway-learner.log"),
    );
    let host_dir = host_dir(dir, run_dir, "box-f");
    let mut host_side = start_host_gateway(
        dir,
        &host_dir,
        &endpoint,
        prefix,
        ("faults", "box-f", 1),
        &[],
    );
    let host_config = host_dir.join("config.toml");
    wait_for(
        Duration::from_secs(30),
        "the run's config on the actor host",
        || {
            if let Ok(Some(status)) = host_side.child.try_wait() {
                panic!(
                    "the actor host's gateway exited ({status}):\n{}",
                    host_side.log_text()
                );
            }
            host_config.exists().then_some(())
        },
    );
    Pair {
        learner_side,
        host_side,
        endpoint,
        host_config,
    }
}

#[test]
fn garbage_is_counted_and_a_stalled_learner_tears_no_link_down() {
    use zenoh::Wait;
    let dir = scratch_dir("gateway-faults");
    let pid = std::process::id();
    let (learner, _) = Learner::start_bandit(&dir, &format!("afx_gfl_{pid}"));
    let run_dir = dir.join("run");
    let prefix = format!("afx_gfa_{pid}");
    let pair = start_pair(&dir, &run_dir, &prefix);
    let config = pair.host_config.display().to_string();
    let _actor = start_actor(0, &prefix, &dir, &["--config", &config]);
    wait_for(
        Duration::from_secs(60),
        "the remote actor's rollouts",
        || (rollouts(&learner, 0) > 0).then_some(()),
    );

    // An outside Zenoh client sends bytes that are not messages under the
    // actor host's key, and a valid-looking header with a wrong checksum.
    let mut client = zenoh::Config::default();
    client.insert_json5("mode", "\"client\"").unwrap();
    let endpoints = format!("[\"{}\"]", pair.endpoint);
    client
        .insert_json5("connect/endpoints", &endpoints)
        .unwrap();
    client
        .insert_json5("scouting/multicast/enabled", "false")
        .unwrap();
    let session = zenoh::open(client).wait().expect("an outside Zenoh client");
    for garbage in [b"not a message".to_vec(), vec![0u8; 4096], vec![0xff; 100]] {
        session
            .put("afx/faults/up/box-f/rollout", garbage)
            .wait()
            .unwrap();
    }
    let refused = wait_for(Duration::from_secs(20), "the garbage counted", || {
        let host = learner.status()["remote_hosts"]["box-f"].clone();
        let refused: u64 = host["refused"]
            .as_object()?
            .values()
            .filter_map(serde_json::Value::as_u64)
            .sum();
        (refused >= 3).then_some(host)
    });
    assert!(
        refused["refused"]["truncated"].as_u64() >= Some(1),
        "{refused}"
    );
    assert!(pair.learner_side.log_text().contains("gateway ready"));
    drop(session);

    // The learner stops for 10 s: the gateways neither reconnect nor grow.
    let rss_before = [
        rss_kib(pair.learner_side.child.id()),
        rss_kib(pair.host_side.child.id()),
    ];
    learner.process.signal(libc::SIGSTOP);
    std::thread::sleep(Duration::from_secs(10));
    let rss_stalled = [
        rss_kib(pair.learner_side.child.id()),
        rss_kib(pair.host_side.child.id()),
    ];
    learner.process.signal(libc::SIGCONT);
    let before = rollouts(&learner, 0);
    wait_for(Duration::from_secs(30), "rollouts after the stall", || {
        (rollouts(&learner, 0) > before + 10).then_some(())
    });
    for (side, (b, s)) in ["learner host", "actor host"]
        .iter()
        .zip(rss_before.iter().zip(&rss_stalled))
    {
        assert!(
            *s < b + 64 * 1024,
            "the {side}'s gateway grew from {b} KiB to {s} KiB while the learner stalled"
        );
    }
    let host_log = pair.host_side.log_text();
    assert_eq!(
        host_log.matches("the run's config arrived").count(),
        1,
        "the actor host's gateway reconnected:\n{host_log}"
    );
    assert!(
        !host_log.contains("waiting for the learner host's gateway"),
        "{host_log}"
    );
}

#[test]
fn a_simulator_actor_on_another_host_trains_the_unet_and_gets_its_weights() {
    let dir = scratch_dir("gateway-sim");
    let pid = std::process::id();
    let learner_prefix = format!("afx_gsl_{pid}");
    let run_dir = dir.join("run");
    let config = dir.join("loop.toml");
    std::fs::write(
        &config,
        format!(
            "[task]\nenv = \"sim\"\nmethod = \"ours\"\naffordances = [\"pick_up\", \"push\"]\nimage_size = 64\nepisode_steps = 16\nbalanced_frames = false\nconfidence_after_steps = 0\n\
             [policy]\nbatch_steps = 16\nepochs = 2\n\
             [unet]\nsteps_per_episode = 3\nbatch_frames = 4\nvalidation_fraction = 0.5\ntest_fraction = 0.0\n\
             [transport]\nservice_prefix = \"{learner_prefix}\"\nmax_actors = 2\n"
        ),
    )
    .unwrap();
    let learner = Learner::start(
        &run_dir,
        &[
            "--config".into(),
            config.display().to_string(),
            "--run-dir".into(),
            run_dir.display().to_string(),
        ],
        dir.join("learner.log"),
    );
    let prefix = format!("afx_gsa_{pid}");
    let pair = start_pair(&dir, &run_dir, &prefix);
    let data = system_tests::shared_data_dir();
    let config = pair.host_config.display().to_string();
    let mut actor = start_actor(
        0,
        &prefix,
        &dir,
        &[
            "--config",
            &config,
            "--data",
            &data,
            "--renderer",
            "cpu",
            "--chunk-steps",
            "8",
        ],
    );
    let status = wait_for(
        Duration::from_secs(240),
        "frames from the remote actor and a U-Net that passed its validation gate",
        || {
            if let Some(exit) = actor.wait_exit(Duration::ZERO) {
                panic!("the remote actor exited ({exit}):\n{}", actor.log_text());
            }
            let s = learner.status();
            let frames = s["actors"].as_array().is_some_and(|all| {
                all.iter()
                    .any(|a| a["id"] == 0 && a["received"]["frames"].as_u64() > Some(0))
            });
            (frames && s["unet_version"].as_u64() >= Some(1) && s["updates"].as_u64() >= Some(1))
                .then_some(s)
        },
    );
    assert!(status["frames_received"].as_u64() > Some(0), "{status}");
    wait_for(
        Duration::from_secs(60),
        "a trained U-Net's weights on the remote actor",
        || {
            actor
                .log_text()
                .lines()
                .filter_map(|l| l.split("loaded U-Net version ").nth(1))
                .filter_map(|v| {
                    v.split(|c: char| !c.is_ascii_digit())
                        .next()?
                        .parse::<u64>()
                        .ok()
                })
                .any(|v| v >= 1)
                .then_some(())
        },
    );
}
