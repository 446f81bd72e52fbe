//! Two "hosts" on one machine, linked only by the gateways over loopback
//! TCP: the learner and its gateway on one shared-memory prefix, an actor
//! host's gateway and its actors on another. The remote actors get the
//! run's config and the learner's weights, their rollouts train the
//! learner, and a SIGKILLed actor-host gateway, restarted, reconnects while
//! the actors keep running.

use std::net::TcpListener;
use std::path::Path;
use std::time::Duration;

use system_tests::{bin, scratch_dir, start_actor, wait_for, Learner, Process};

/// Policy version and rollouts received of actor `id` in the learner's status.
fn actor(status: &serde_json::Value, id: u64) -> (u64, u64) {
    let entry = status["actors"]
        .as_array()
        .and_then(|a| a.iter().find(|x| x["id"] == id).cloned())
        .unwrap_or_default();
    (
        entry["policy_version"].as_u64().unwrap_or(0),
        entry["received"]["rollout"].as_u64().unwrap_or(0),
    )
}

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("a free loopback port")
}

fn start_actor_host(dir: &Path, host_dir: &Path, endpoint: &str, prefix: &str, n: u32) -> Process {
    let args = [
        "actor-host",
        "--learner-at",
        endpoint,
        "--run-dir",
        &host_dir.display().to_string(),
        "--run",
        "gateway-test",
        "--host",
        "box-b",
        "--service-prefix",
        prefix,
    ]
    .map(String::from);
    Process::start(
        &bin("gateway"),
        &args,
        dir.join(format!("gateway-box-b-{n}.log")),
    )
}

#[test]
fn remote_actors_train_through_the_gateways_and_survive_a_gateway_restart() {
    let dir = scratch_dir("gateway");
    let pid = std::process::id();
    let learner_prefix = format!("afx_gwl_{pid}");
    let actor_prefix = format!("afx_gwa_{pid}");
    let (learner, _) = Learner::start_bandit(&dir, &learner_prefix);
    let run_dir = dir.join("run");
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let learner_gateway = Process::start(
        &bin("gateway"),
        &[
            "learner-host",
            "--run-dir",
            &run_dir.display().to_string(),
            "--listen",
            &endpoint,
            "--run",
            "gateway-test",
        ]
        .map(String::from),
        dir.join("gateway-learner.log"),
    );
    // The actor host has its own directory, with a copy of the run's key.
    let host_dir = dir.join("box-b");
    std::fs::create_dir_all(&host_dir).unwrap();
    std::fs::copy(run_dir.join("join.key"), host_dir.join("join.key")).unwrap();
    let mut actor_gateway = start_actor_host(&dir, &host_dir, &endpoint, &actor_prefix, 1);
    let host_config = host_dir.join("config.toml");
    wait_for(
        Duration::from_secs(30),
        "the run's config on the actor host",
        || {
            if let Ok(Some(status)) = actor_gateway.child.try_wait() {
                panic!(
                    "the actor host's gateway exited ({status}):\n{}",
                    actor_gateway.log_text()
                );
            }
            std::fs::read_to_string(&host_config).ok()
        },
    );
    let config_text = std::fs::read_to_string(&host_config).unwrap();
    assert!(config_text.contains("bandit-fixture"), "{config_text}");
    assert!(config_text.contains(&actor_prefix), "{config_text}");
    let config = host_config.display().to_string();
    let mut actors: Vec<Process> = (0..2)
        .map(|id| start_actor(id, &actor_prefix, &dir, &["--config", &config]))
        .collect();

    // Rollouts of both remote actors train the learner, and the weights of
    // its updates reach them (their rollouts carry a version past the first).
    wait_for(Duration::from_secs(60), "trained remote actors", || {
        for a in &mut actors {
            if let Ok(Some(status)) = a.child.try_wait() {
                panic!("a remote actor exited ({status}):\n{}", a.log_text());
            }
        }
        let status = learner.status();
        let both = (0..2).all(|id| {
            let (version, rollouts) = actor(&status, id);
            version >= 2 && rollouts > 0
        });
        both.then_some(())
    });
    let hosts = wait_for(Duration::from_secs(20), "remote-hosts.json", || {
        let text = std::fs::read_to_string(run_dir.join("remote-hosts.json")).ok()?;
        let hosts: serde_json::Value = serde_json::from_str(&text).ok()?;
        (hosts["box-b"]["actors"] == serde_json::json!([0, 1])).then_some(hosts)
    });
    assert!(hosts["box-b"]["forwarded"].as_u64().unwrap() > 0, "{hosts}");

    // The actor host's gateway dies; the actors keep running, and a new
    // gateway brings their rollouts back.
    actor_gateway.signal(libc::SIGKILL);
    actor_gateway.wait_exit(Duration::from_secs(5));
    let before: u64 = (0..2).map(|id| actor(&learner.status(), id).1).sum();
    std::thread::sleep(Duration::from_secs(1));
    let mut actor_gateway = start_actor_host(&dir, &host_dir, &endpoint, &actor_prefix, 2);
    wait_for(
        Duration::from_secs(60),
        "rollouts after the restart",
        || {
            if let Ok(Some(status)) = actor_gateway.child.try_wait() {
                panic!(
                    "the restarted gateway exited ({status}):\n{}",
                    actor_gateway.log_text()
                );
            }
            let now: u64 = (0..2).map(|id| actor(&learner.status(), id).1).sum();
            (now > before + 4).then_some(())
        },
    );
    for a in &mut actors {
        assert!(a.child.try_wait().unwrap().is_none(), "{}", a.log_text());
    }
    drop(learner_gateway);
}
