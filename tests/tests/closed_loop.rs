//! The closed loop, CI-sized: a learner and two simulator actors (64 × 64
//! images, short episodes), the second running two environments (`--envs
//! 2`, free-running: for `nomap-seg`, whose GRU policy makes recurrent
//! rollouts, each step's task carries the recurrent state on), for `ours`
//! and then `nomap-seg`. Labelled frames reach the learner, the
//! U-Net trains on them and passes its validation gate, the policy updates,
//! and both networks' new weights reach the actors.

use std::time::Duration;

use system_tests::{scratch_dir, shared_data_dir, start_actor, wait_for, Learner, Process};

/// The highest `… version N` an actor's log reports after `marker`.
fn newest_version(actor: &Process, marker: &str) -> Option<u64> {
    actor
        .log_text()
        .lines()
        .filter_map(|l| l.split(marker).nth(1))
        .filter_map(|v| {
            v.split(|c: char| !c.is_ascii_digit())
                .next()
                .and_then(|n| n.parse().ok())
        })
        .max()
}

#[test]
fn frames_train_the_unet_and_new_weights_reach_both_actors() {
    // One method after the other: two loops at once would crowd 2 cores.
    for method in ["ours", "nomap-seg"] {
        closed_loop(method);
    }
}

fn closed_loop(method: &str) {
    eprintln!("closed loop, method {method}");
    let dir = scratch_dir(&format!("closed-loop-{method}"));
    let prefix = format!("it-loop-{method}-{}", std::process::id());
    let run_dir = dir.join("run");
    let config = dir.join("loop.toml");
    std::fs::write(
        &config,
        format!(
            "[task]\nenv = \"sim\"\nmethod = \"{method}\"\naffordances = [\"pick_up\", \"push\"]\nimage_size = 64\nepisode_steps = 16\nbalanced_frames = false\nconfidence_after_steps = 0\nmemory_size = 32\n\
             [policy]\nbatch_steps = 16\nepochs = 2\n\
             [unet]\nsteps_per_episode = 3\nbatch_frames = 4\nvalidation_fraction = 0.5\ntest_fraction = 0.0\nweight_average = 0.9\n\
             [transport]\nservice_prefix = \"{prefix}\"\nmax_actors = 2\n"
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
    let run_config = run_dir.join("config.toml").display().to_string();
    let data = shared_data_dir();
    let mut actors: Vec<Process> = (0..2)
        .map(|id| {
            let envs = (id + 1).to_string();
            start_actor(
                id,
                &prefix,
                &dir,
                &[
                    "--config",
                    &run_config,
                    "--data",
                    &data,
                    "--renderer",
                    "cpu",
                    "--chunk-steps",
                    "8",
                    "--seed",
                    &id.to_string(),
                    "--envs",
                    &envs,
                ],
            )
        })
        .collect();

    // The U-Net trains on the frames and beats the deployed one on validation.
    let status = wait_for(
        Duration::from_secs(240),
        "frames from both actors, a policy update and a U-Net that passed the validation gate",
        || {
            for actor in &mut actors {
                if let Some(exit) = actor.wait_exit(Duration::ZERO) {
                    panic!("actor exited early ({exit}):\n{}", actor.log_text());
                }
            }
            let s = learner.status();
            let both_sent_frames = (0..2).all(|id| {
                s["actors"].as_array().is_some_and(|all| {
                    all.iter()
                        .any(|a| a["id"] == id && a["received"]["frames"].as_u64() > Some(0))
                })
            });
            (s["unet_version"].as_u64() >= Some(1)
                && both_sent_frames
                && s["updates"].as_u64() >= Some(1))
            .then_some(s)
        },
    );
    assert!(status["frames_received"].as_u64() > Some(0), "{status}");
    assert!(status["unet_rounds"].as_u64() >= Some(1), "{status}");
    let unet = &status["last_unet"];
    assert!(
        unet["train_loss"].as_f64().is_some_and(f64::is_finite),
        "{unet}"
    );
    assert!(status["updates"].as_u64() >= Some(1), "{status}");
    // Both actors streamed rollouts and reported ground-truth metrics.
    for id in 0..2 {
        let actor = status["actors"]
            .as_array()
            .unwrap()
            .iter()
            .find(|a| a["id"] == id)
            .unwrap_or_else(|| panic!("actor {id} never reached the learner: {status}"));
        assert!(actor["received"]["rollout"].as_u64() > Some(0), "{actor}");
        assert!(actor["received"]["frames"].as_u64() > Some(0), "{actor}");
    }
    let episode = &status["last_episode"];
    for field in [
        "affordance_iou",
        "object_accuracy",
        "interaction_success_rate",
        "non_interactable_annotation_rate",
    ] {
        let v = episode[field].as_f64();
        assert!(
            v.is_some_and(|v| (0.0..=1.0).contains(&v)),
            "{field}: {episode}"
        );
    }
    // Only a method with a map has map ids to be consistent.
    let consistency = episode["map_id_consistency"].as_f64();
    if method == "ours" {
        assert!(
            consistency.is_some_and(|v| v > 0.5 && v <= 1.0),
            "map_id_consistency: {episode}"
        );
    } else {
        assert_eq!(consistency, None, "{episode}");
    }

    // The history endpoint serves the episodes the status counted.
    let (code, body) = system_tests::http_get(&learner.addr, "/api/history?kind=episode&last=2")
        .expect("/api/history answers");
    assert_eq!(code, 200, "{body}");
    let history: serde_json::Value = serde_json::from_str(&body).expect("JSON history");
    assert!(history["total"].as_u64() >= Some(1), "{history}");
    let records = history["records"].as_array().expect("records");
    assert!(!records.is_empty() && records.len() <= 2, "{history}");
    assert!(
        records
            .iter()
            .all(|r| r["kind"] == "episode" && r["stats"]["episode_return"].is_number()),
        "{history}"
    );
    // Episodes report the rooms they were played in (the seeds are fixed, so
    // which rooms is too): the 20 training rooms are indices 0..20.
    let (_, body) = system_tests::http_get(&learner.addr, "/api/history?kind=episode")
        .expect("/api/history answers");
    let history: serde_json::Value = serde_json::from_str(&body).expect("JSON history");
    let scenes: Vec<u64> = history["records"]
        .as_array()
        .expect("records")
        .iter()
        .filter_map(|r| r["scene"].as_u64())
        .collect();
    assert!(
        scenes.iter().all(|&s| s < 20) && scenes.iter().any(|&s| s > 0),
        "rooms {scenes:?}"
    );
    // Each episode's tries by object type account for its attempts (those
    // aimed at no scene object left out).
    let (mut attempts, mut by_type) = (0.0, 0.0);
    for record in history["records"].as_array().expect("records") {
        let tries = record["tries"].as_array().expect("tries in every episode");
        for affordance in ["pick_up", "push"] {
            let rate = record["stats"][format!("{affordance}_attempt_rate")]
                .as_f64()
                .unwrap_or(0.0);
            let episode_attempts = (rate * record["steps"].as_f64().unwrap_or(0.0)).round();
            let typed: f64 = tries
                .iter()
                .filter(|t| t["affordance"] == affordance)
                .map(|t| t["attempts"].as_f64().expect("attempts"))
                .sum();
            assert!(typed <= episode_attempts, "{record}");
            attempts += episode_attempts;
            by_type += typed;
        }
        assert!(
            tries
                .iter()
                .all(|t| t["type"].as_str().is_some_and(|n| !n.is_empty())),
            "{record}"
        );
    }
    assert!(attempts == 0.0 || by_type > 0.0, "{history}");

    // New weights of both networks reach both actors.
    wait_for(
        Duration::from_secs(120),
        "new weights in both actors",
        || {
            actors
                .iter()
                .all(|a| {
                    newest_version(a, "loaded U-Net version ") >= Some(1)
                        && a.log_text().contains("got policy version")
                })
                .then_some(())
        },
    );

    for actor in &mut actors {
        actor.signal(libc::SIGINT);
        let exit = actor
            .wait_exit(Duration::from_secs(60))
            .expect("actor exits on SIGINT");
        assert!(exit.success(), "actor exit {exit}:\n{}", actor.log_text());
        let log = actor.log_text();
        let final_policy = log
            .lines()
            .find_map(|l| l.split("; policy version ").nth(1))
            .and_then(|v| v.split(',').next())
            .and_then(|v| v.trim().parse::<u64>().ok());
        assert!(
            final_policy > Some(1),
            "the actor acted only with the first policy:\n{log}"
        );
    }
    let mut learner = learner;
    learner.process.signal(libc::SIGINT);
    let exit = learner
        .process
        .wait_exit(Duration::from_secs(60))
        .expect("learner exits on SIGINT");
    assert!(
        exit.success(),
        "learner exit {exit}:\n{}",
        learner.process.log_text()
    );
    drop(learner);
    if method == "ours" {
        resume_continues_unet_training(&config, &run_dir, &dir);
    }
}

/// The final checkpoint holds the U-Net in training, its Adam state and its
/// weight average, and `--resume` continues U-Net training from them.
fn resume_continues_unet_training(
    config: &std::path::Path,
    run_dir: &std::path::Path,
    dir: &std::path::Path,
) {
    let newest = std::fs::read_dir(run_dir.join("checkpoints"))
        .expect("a checkpoint directory")
        .filter_map(|e| e.ok())
        .filter_map(|e| {
            e.file_name()
                .to_str()?
                .parse::<u64>()
                .ok()
                .map(|s| (s, e.path()))
        })
        .max()
        .expect("a final checkpoint")
        .1;
    for file in [
        "unet_candidate.safetensors",
        "unet_optimizer.bpk",
        "unet_optimizer_parameters.json",
        "unet_average.safetensors",
    ] {
        assert!(
            newest.join(file).exists(),
            "{} lacks {file}",
            newest.display()
        );
    }
    let mut learner = Learner::start(
        run_dir,
        &[
            "--config".into(),
            config.display().to_string(),
            "--resume".into(),
            run_dir.display().to_string(),
        ],
        dir.join("learner-resumed.log"),
    );
    let log = learner.process.log_text();
    assert!(
        log.contains("U-Net training state restored, with its weight average"),
        "the U-Net's training state and its weight average were not restored:\n{log}"
    );
    learner.process.signal(libc::SIGINT);
    let exit = learner
        .process
        .wait_exit(Duration::from_secs(60))
        .expect("resumed learner exits on SIGINT");
    assert!(exit.success(), "resumed learner exit {exit}:\n{log}");
}
