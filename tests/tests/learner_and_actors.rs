//! The real learner with three real actors: weights reach every actor, chunks
//! reach the learner, the HTTP views agree, and the run survives a SIGKILLed
//! actor whose replacement gets the newest weights within 2 s.

use std::process::Command;
use std::time::{Duration, Instant};

use system_tests::{bandit_config, metric_value, scratch_dir, start_actor, wait_for, Learner};

fn rollouts_of(status: &serde_json::Value, id: u64) -> u64 {
    status["actors"]
        .as_array()
        .and_then(|a| a.iter().find(|x| x["id"] == id))
        .and_then(|a| a["received"]["rollout"].as_u64())
        .unwrap_or(0)
}

/// Checks the classic exposition with `promtool check metrics`, Prometheus's
/// own linter. Returns false (and says so) without promtool, unless
/// `AFX_REQUIRE_PROMTOOL` is set (CI installs Debian's `prometheus`).
fn promtool_accepts(metrics: &str) -> bool {
    use std::io::Write;
    let child = Command::new("promtool")
        .args(["check", "metrics"])
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn();
    let mut child = match child {
        Ok(child) => child,
        Err(e) if std::env::var_os("AFX_REQUIRE_PROMTOOL").is_none() => {
            eprintln!("skipping promtool check metrics: {e} (`apt-get install prometheus`)");
            return true;
        }
        Err(e) => panic!("promtool: {e}"),
    };
    child
        .stdin
        .take()
        .expect("stdin")
        .write_all(metrics.as_bytes())
        .expect("feeding promtool");
    let out = child.wait_with_output().expect("promtool");
    assert!(
        out.status.success(),
        "promtool check metrics: {}{}\n---\n{metrics}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    true
}

/// Parses the exposition with the Python `prometheus_client` OpenMetrics
/// parser, an independent reader. Returns false (and says so) when Python or
/// the package is missing, unless the CI demands it.
fn python_parses(metrics: &str) -> bool {
    let script = "import sys\nfrom prometheus_client.openmetrics.parser import text_string_to_metric_families as p\nfams=list(p(sys.stdin.read()))\nprint(len(fams))";
    let output = Command::new("python3")
        .args(["-c", script])
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .and_then(|mut child| {
            use std::io::Write;
            child
                .stdin
                .take()
                .expect("stdin")
                .write_all(metrics.as_bytes())?;
            child.wait_with_output()
        });
    match output {
        Ok(out) if out.status.success() => true,
        Ok(out)
            if String::from_utf8_lossy(&out.stderr).contains("ModuleNotFoundError")
                && std::env::var_os("AFX_REQUIRE_PYTHON_CHECKS").is_none() =>
        {
            eprintln!(
                "skipping the prometheus_client parse: `pip install prometheus_client` to run it"
            );
            true
        }
        Ok(out) => panic!(
            "prometheus_client rejected /metrics:\n{}\n---\n{metrics}",
            String::from_utf8_lossy(&out.stderr)
        ),
        Err(e) if std::env::var_os("AFX_REQUIRE_PYTHON_CHECKS").is_none() => {
            eprintln!("skipping the prometheus_client parse: python3 not runnable ({e})");
            true
        }
        Err(e) => panic!("python3 not runnable: {e}"),
    }
}

#[test]
fn learner_serves_three_actors_and_survives_a_killed_one() {
    let dir = scratch_dir("three-actors");
    let prefix = format!("it-three-{}", std::process::id());
    let run_dir = dir.join("run");
    let bandit = bandit_config(&dir, &prefix, "");
    let learner = Learner::start(
        &run_dir,
        &[
            "--config".into(),
            bandit.display().to_string(),
            "--run-dir".into(),
            run_dir.display().to_string(),
            "--service-prefix".into(),
            prefix.clone(),
            "--max-actors".into(),
            "4".into(),
        ],
        dir.join("learner.log"),
    );
    let config = run_dir.join("config.toml").display().to_string();
    // Actor 2 runs three environments (free-running).
    let mut actors: Vec<_> = (0..3)
        .map(|id| {
            let envs = if id == 2 { "3" } else { "1" };
            start_actor(id, &prefix, &dir, &["--config", &config, "--envs", envs])
        })
        .collect();

    // Every actor streams chunks made with weights version >= 1.
    let all_served = |s: &serde_json::Value| {
        (0..3).all(|id| {
            s["actors"].as_array().unwrap().iter().any(|a| {
                a["id"] == id
                    && a["received"]["rollout"].as_u64() > Some(0)
                    && a["policy_version"].as_u64() >= Some(1)
            })
        })
    };
    let deadline = std::time::Instant::now() + Duration::from_secs(30);
    loop {
        let s = learner.status();
        if all_served(&s) {
            break;
        }
        assert!(
            std::time::Instant::now() < deadline,
            "timed out after 30 s waiting for chunks from all three actors; the learner's view:\n{:#}",
            s["actors"]
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    for actor in &actors {
        let log = actor.log_text();
        assert!(
            log.contains("got policy version"),
            "actor log lacks the weights message:\n{log}"
        );
    }

    // /metrics and /api/status render the same state: counters read from
    // /metrics lie between two status reads taken around it.
    // Per-update and per-episode metrics exist once an update and an episode have.
    wait_for(
        Duration::from_secs(30),
        "a PPO update and an episode",
        || {
            let s = learner.status();
            (s["updates"].as_u64() >= Some(1) && s["episodes"].as_u64() >= Some(1)).then_some(())
        },
    );
    let before = learner.status();
    let metrics = learner.metrics();
    let after = learner.status();
    assert!(python_parses(&learner.openmetrics()));
    assert!(promtool_accepts(&metrics));
    for name in [
        "afx_build_info",
        "afx_episode_return",
        "afx_ppo_entropy",
        "afx_ppo_approx_kl",
        "afx_ppo_update_duration_seconds_count",
    ] {
        assert!(
            metrics.lines().any(|l| l.starts_with(name)),
            "{name} missing from /metrics:\n{metrics}"
        );
    }
    for (metric, field) in [
        ("afx_env_steps_total", "env_steps"),
        ("afx_policy_updates_total", "updates"),
        ("afx_weights_published_total", "weights_published"),
    ] {
        let m = metric_value(&metrics, metric)
            .unwrap_or_else(|| panic!("{metric} missing from /metrics:\n{metrics}"));
        let (lo, hi) = (
            before[field].as_f64().unwrap(),
            after[field].as_f64().unwrap(),
        );
        assert!(
            lo <= m && m <= hi,
            "{metric} = {m}, status {field} went {lo} -> {hi}"
        );
    }
    assert_eq!(metric_value(&metrics, "afx_actors_alive"), Some(3.0));
    assert_eq!(after["actors_alive"], 3);

    // SIGKILL actor 1: the learner keeps serving and the others keep streaming.
    actors[1].signal(libc::SIGKILL);
    assert!(actors[1].wait_exit(Duration::from_secs(5)).is_some());
    let at_kill = learner.status();
    wait_for(
        Duration::from_secs(20),
        "actors 0 and 2 to keep streaming",
        || {
            let s = learner.status();
            (rollouts_of(&s, 0) > rollouts_of(&at_kill, 0)
                && rollouts_of(&s, 2) > rollouts_of(&at_kill, 2))
            .then_some(())
        },
    );
    assert_eq!(
        system_tests::http_get(&learner.addr, "/healthz").map(|r| r.0),
        Some(200)
    );

    // A restarted actor 1 gets the newest weights within 2 s of its start.
    let version_before = learner.status()["policy_version"].as_u64().unwrap();
    let started = Instant::now();
    actors[1] = start_actor(1, &prefix, &dir, &["--config", &config]);
    let got = wait_for(
        Duration::from_secs(10),
        "the restarted actor's weights",
        || {
            let log = actors[1].log_text();
            log.lines().find_map(|l| {
                l.split("got policy version ")
                    .nth(1)
                    .and_then(|v| v.split(',').next())
                    .and_then(|v| v.trim().parse::<u64>().ok())
            })
        },
    );
    let elapsed = started.elapsed();
    assert!(
        got >= version_before,
        "restarted actor got version {got}, learner was at {version_before}"
    );
    assert!(
        elapsed < Duration::from_secs(2),
        "restarted actor took {elapsed:?} to get weights"
    );

    // Clean shutdown: SIGINT to everyone, all exit 0.
    for actor in &mut actors {
        actor.signal(libc::SIGINT);
        let status = actor
            .wait_exit(Duration::from_secs(10))
            .expect("actor exits on SIGINT");
        assert!(
            status.success(),
            "actor exit {status}:\n{}",
            actor.log_text()
        );
    }
    let mut learner = learner;
    learner.process.signal(libc::SIGINT);
    let status = learner
        .process
        .wait_exit(Duration::from_secs(20))
        .expect("learner exits on SIGINT");
    assert!(
        status.success(),
        "learner exit {status}:\n{}",
        learner.process.log_text()
    );
}

#[test]
fn an_actor_with_several_environments_stops_after_max_episodes() {
    let dir = scratch_dir("max-episodes");
    let prefix = format!("it-max-episodes-{}", std::process::id());
    let run_dir = dir.join("run");
    let bandit = bandit_config(&dir, &prefix, "");
    let learner = Learner::start(
        &run_dir,
        &[
            "--config".into(),
            bandit.display().to_string(),
            "--run-dir".into(),
            run_dir.display().to_string(),
        ],
        dir.join("learner.log"),
    );
    let config = run_dir.join("config.toml").display().to_string();
    // Two environments, five episodes: the third pair starts only one.
    let mut actor = start_actor(
        0,
        &prefix,
        &dir,
        &["--config", &config, "--envs", "2", "--max-episodes", "5"],
    );
    let exit = actor
        .wait_exit(Duration::from_secs(60))
        .expect("the actor stops by itself after its episodes");
    let log = actor.log_text();
    assert!(exit.success(), "actor exit {exit}:\n{log}");
    // The bandit's episodes are 64 steps long.
    assert!(log.contains("stopped after 5 episodes, 320 steps"), "{log}");
    // Its environments ran free, and it says how busy its loop was.
    assert!(log.contains("the loop's thread was busy"), "{log}");
    // What reached the learner: all of it unless the actor reports drops
    // (the learner's queue was full), which a quiet machine never sees.
    let complete = log.contains(", 0 dropped");
    let status = wait_for(
        Duration::from_secs(10),
        "the episodes' stats at the learner",
        || {
            // Rollouts and stats travel on services of their own, so the
            // stats may arrive before the last rollouts.
            let s = learner.status();
            let all_in = s["episodes"].as_u64() == Some(5) && s["env_steps"].as_u64() == Some(320);
            (!complete || all_in).then_some(s)
        },
    );
    if complete {
        assert_eq!(status["env_steps"].as_u64(), Some(320), "{status}");
    }
    let (_, body) = system_tests::http_get(&learner.addr, "/api/history?kind=episode")
        .expect("/api/history answers");
    let history: serde_json::Value = serde_json::from_str(&body).expect("JSON history");
    let mut ids: Vec<u64> = history["records"]
        .as_array()
        .expect("records")
        .iter()
        .filter_map(|r| r["episode"].as_u64())
        .collect();
    ids.sort_unstable();
    ids.dedup();
    assert!(ids.iter().all(|&id| id < 5), "{history}");
    if complete {
        assert_eq!(ids, [0, 1, 2, 3, 4], "{history}");
    }
}

#[test]
fn the_shipped_prometheus_config_is_valid() {
    let config = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/prometheus.yml");
    match Command::new("promtool")
        .arg("check")
        .arg("config")
        .arg(&config)
        .output()
    {
        Ok(out) => assert!(
            out.status.success(),
            "promtool check config: {}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        ),
        Err(e) if std::env::var_os("AFX_REQUIRE_PROMTOOL").is_none() => {
            eprintln!("skipping promtool check config: {e} (`apt-get install prometheus`)")
        }
        Err(e) => panic!("promtool: {e}"),
    }
}
