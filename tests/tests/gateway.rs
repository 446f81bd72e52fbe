//! Two "hosts" on one machine, linked only by the gateways over loopback
//! TCP: the learner and its gateway on one shared-memory prefix, an actor
//! host's gateway and its actors on another. The remote actors get the
//! run's config and the learner's weights, their rollouts train the
//! learner, and a SIGKILLed actor-host gateway, restarted, reconnects while
//! the actors keep running.

use std::path::Path;
use std::time::Duration;

use system_tests::{
    bin, free_port, host_dir, scratch_dir, start_actor, start_host_gateway, start_learner_gateway,
    wait_for, Learner, Process,
};

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

fn start_actor_host(dir: &Path, host_dir: &Path, endpoint: &str, prefix: &str, n: u32) -> Process {
    start_host_gateway(
        dir,
        host_dir,
        endpoint,
        prefix,
        ("gateway-test", "box-b", n),
        &[],
    )
}

#[test]
fn over_mutual_tls_a_host_publishes_only_under_its_own_name() {
    let dir = scratch_dir("gateway-tls");
    let pid = std::process::id();
    let certs = dir.join("certs");
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let made = std::process::Command::new(repo.join("deploy/make-certs.sh"))
        .args(["--dir", &certs.display().to_string()])
        .args(["--run", "gateway-tls", "--learner", "127.0.0.1"])
        .args(["--hosts", "box-b,box-c"])
        .output()
        .expect("running deploy/make-certs.sh");
    assert!(
        made.status.success(),
        "make-certs.sh: {}",
        String::from_utf8_lossy(&made.stderr)
    );
    let (learner, _) = Learner::start_bandit(&dir, &format!("afx_gtl_{pid}"));
    let run_dir = dir.join("run");
    let endpoint = format!("tls/127.0.0.1:{}", free_port());
    let _learner_gateway = start_learner_gateway(
        &run_dir,
        &endpoint,
        "gateway-tls",
        &[
            "--zenoh-config",
            &certs.join("learner.json5").display().to_string(),
        ],
        dir.join("gateway-learner.log"),
    );
    let config_of = |name: &str| certs.join(format!("{name}.json5")).display().to_string();
    // box-b, with its own certificate, trains the learner with actor 0.
    let b_dir = host_dir(&dir, &run_dir, "box-b");
    let b_prefix = format!("afx_gtb_{pid}");
    let _b = start_host_gateway(
        &dir,
        &b_dir,
        &endpoint,
        &b_prefix,
        ("gateway-tls", "box-b", 1),
        &["--zenoh-config", &config_of("box-b")],
    );
    // box-c holds a valid certificate but claims to be box-b, with actor 1.
    let c_dir = host_dir(&dir, &run_dir, "box-c");
    let c_prefix = format!("afx_gtc_{pid}");
    let impostor = start_host_gateway(
        &dir,
        &c_dir,
        &endpoint,
        &c_prefix,
        ("gateway-tls", "box-b", 2),
        &["--zenoh-config", &config_of("box-c")],
    );
    // A host without a certificate from the run's CA gets nothing.
    let x_dir = host_dir(&dir, &run_dir, "box-x");
    let _outsider = start_host_gateway(
        &dir,
        &x_dir,
        &endpoint,
        &format!("afx_gtx_{pid}"),
        ("gateway-tls", "box-x", 3),
        &[],
    );
    let mut actors = Vec::new();
    for (host_dir, prefix, id) in [(&b_dir, &b_prefix, 0), (&c_dir, &c_prefix, 1)] {
        let config = host_dir.join("config.toml");
        wait_for(Duration::from_secs(30), "the run's config over TLS", || {
            config.exists().then_some(())
        });
        let config = config.display().to_string();
        actors.push(start_actor(id, prefix, &dir, &["--config", &config]));
    }
    wait_for(Duration::from_secs(60), "box-b's actor trained", || {
        let (version, rollouts) = actor(&learner.status(), 0);
        (version >= 2 && rollouts > 0).then_some(())
    });
    // The impostor's gateway got the config and sends, but the learner's
    // side refuses everything it publishes under box-b's name.
    std::thread::sleep(Duration::from_secs(3));
    let status = learner.status();
    assert_eq!(actor(&status, 1), (0, 0), "{status}");
    // The hosts' counts reach the status through a file the gateway
    // rewrites every 2 s: wait for box-b's row rather than read it once.
    wait_for(
        Duration::from_secs(20),
        "box-b's actor in remote_hosts",
        || {
            (learner.status()["remote_hosts"]["box-b"]["actors"] == serde_json::json!([0]))
                .then_some(())
        },
    );
    assert!(
        impostor.log_text().contains("config arrived"),
        "{}",
        impostor.log_text()
    );
    assert!(
        !x_dir.join("config.toml").exists(),
        "a host without a certificate got the run's config"
    );
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
    let learner_gateway = |n: u32| {
        start_learner_gateway(
            &run_dir,
            &endpoint,
            "gateway-test",
            &[],
            dir.join(format!("gateway-learner-{n}.log")),
        )
    };
    let mut learner_gateway_1 = learner_gateway(1);
    // The actor host has its own directory, with a copy of the run's key.
    let host_dir = host_dir(&dir, &run_dir, "box-b");
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
    // The learner's status shows the actor host, from the gateway's counts.
    let hosts = wait_for(
        Duration::from_secs(20),
        "remote hosts in the status",
        || {
            let hosts = learner.status()["remote_hosts"].clone();
            (hosts["box-b"]["actors"] == serde_json::json!([0, 1])).then_some(hosts)
        },
    );
    assert!(hosts["box-b"]["forwarded"].as_u64().unwrap() > 0, "{hosts}");
    assert!(hosts["box-b"]["gaps"].is_u64(), "{hosts}");

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
    // An actor that starts late on the actor host gets the newest weights
    // at once (the local service's history), not the first ones.
    let newest = learner.status()["policy_version"].as_u64().unwrap();
    let mut late = start_actor(2, &actor_prefix, &dir, &["--config", &config]);
    let first = wait_for(
        Duration::from_secs(10),
        "the late actor's first weights",
        || {
            if let Ok(Some(status)) = late.child.try_wait() {
                panic!("the late actor exited ({status}):\n{}", late.log_text());
            }
            late.log_text()
                .lines()
                .filter_map(|l| l.split("got policy version ").nth(1))
                .find_map(|v| {
                    v.split(|c: char| !c.is_ascii_digit())
                        .next()?
                        .parse::<u64>()
                        .ok()
                })
        },
    );
    assert!(
        first + 5 >= newest && first > 1,
        "the late actor started from policy version {first}; the learner was at {newest}"
    );
    // The learner host's gateway dies and comes back: the actor host's
    // reconnects, the remote actors join again through it, rollouts resume.
    learner_gateway_1.signal(libc::SIGKILL);
    learner_gateway_1.wait_exit(Duration::from_secs(5));
    let before: u64 = (0..2).map(|id| actor(&learner.status(), id).1).sum();
    std::thread::sleep(Duration::from_secs(1));
    let _learner_gateway_2 = learner_gateway(2);
    wait_for(
        Duration::from_secs(60),
        "rollouts after the learner host's gateway restarted",
        || {
            let now: u64 = (0..2).map(|id| actor(&learner.status(), id).1).sum();
            (now > before + 4).then_some(())
        },
    );
    assert!(
        actor_gateway.child.try_wait().unwrap().is_none(),
        "{}",
        actor_gateway.log_text()
    );
}

/// A script run as its own process group, killed with it on drop.
struct Script(std::process::Child);

impl Drop for Script {
    fn drop(&mut self) {
        // SAFETY: kill(2) on the process group we created has no memory-safety preconditions.
        unsafe {
            libc::kill(-(self.0.id() as i32), libc::SIGKILL);
        }
        let _ = self.0.wait();
    }
}

fn script(name: &str, args: &[String], log: &Path) -> Script {
    use std::os::unix::process::CommandExt;
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let out = std::fs::File::create(log).expect("log file");
    let child = std::process::Command::new(repo.join("deploy").join(name))
        .args(args)
        .stdout(out.try_clone().expect("log handle"))
        .stderr(out)
        .process_group(0)
        .spawn()
        .unwrap_or_else(|e| panic!("starting deploy/{name}: {e}"));
    Script(child)
}

fn wait_exit(script: &mut Script, timeout: Duration) -> std::process::ExitStatus {
    wait_for(timeout, "the script to end", || {
        script.0.try_wait().ok().flatten()
    })
}

#[test]
fn local_sh_listens_and_actors_sh_on_another_host_trains_the_run_to_its_max_steps() {
    let dir = scratch_dir("gateway-scripts");
    let bin_dir = bin("gateway").parent().unwrap().display().to_string();
    let run_dir = dir.join(format!("gws-{}", std::process::id()));
    let port = free_port();
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let learner_log = dir.join("local.log");
    let mut learner = script(
        "local.sh",
        &[
            "--actors",
            "0",
            "--remote-actors",
            "2",
            "--listen",
            &endpoint,
            "--env",
            "bandit-fixture",
            "--bin-dir",
            &bin_dir,
            "--run-dir",
            &run_dir.display().to_string(),
            "--port",
            &port.to_string(),
            "--max-steps",
            "2000",
            "--progress-every",
            "0",
        ]
        .map(String::from),
        &learner_log,
    );
    let host_dir = dir.join("box-c");
    let key = run_dir.join("join.key");
    wait_for(Duration::from_secs(30), "the run's join key", || {
        std::fs::metadata(&key).ok().filter(|m| m.len() > 0)
    });
    std::fs::create_dir_all(&host_dir).unwrap();
    std::fs::copy(&key, host_dir.join("join.key")).unwrap();
    let actors_log = dir.join("actors.log");
    let mut actors = script(
        "actors.sh",
        &[
            "--learner-at",
            &endpoint,
            "--run",
            &run_dir.file_name().unwrap().to_string_lossy(),
            "--run-dir",
            &host_dir.display().to_string(),
            "--first-actor-id",
            "0",
            "--actors",
            "2",
            "--host",
            "box-c",
            "--service-prefix",
            &format!("afx_gws_{}", std::process::id()),
            "--bin-dir",
            &bin_dir,
        ]
        .map(String::from),
        &actors_log,
    );
    // The learner's run ends at --max-steps on the remote actors' steps alone.
    let status = wait_exit(&mut learner, Duration::from_secs(120));
    let text = std::fs::read_to_string(&learner_log).unwrap_or_default();
    assert!(status.success(), "local.sh: {status}\n{text}");
    assert!(text.contains("(--max-steps 2000)"), "{text}");
    assert!(text.contains("deploy/actors.sh --learner-at"), "{text}");
    // The actor host stops cleanly on SIGTERM.
    // SAFETY: kill(2) on our own child's pid has no memory-safety preconditions.
    unsafe {
        libc::kill(actors.0.id() as i32, libc::SIGTERM);
    }
    let status = wait_exit(&mut actors, Duration::from_secs(60));
    let text = std::fs::read_to_string(&actors_log).unwrap_or_default();
    assert!(status.success(), "actors.sh: {status}\n{text}");
    assert!(text.contains("actors 0..1 started"), "{text}");
}
