//! Actors wait for a U-Net that owes too many episodes, and go on once it
//! has caught up: with `[unet] hold_actors_beyond_episodes = 1` and rounds
//! that pay one episode's steps at a time, two episodes arriving together
//! (an actor's two environments) put the U-Net past its allowance. The
//! learner then tells the actors to wait through its weights, counts the
//! hold, and releases them when its debt is paid: the run goes on making
//! episodes.

use std::time::Duration;

use system_tests::{scratch_dir, shared_data_dir, start_actor, wait_for, Learner, Process};

#[test]
fn actors_wait_for_a_unet_that_owes_too_much_and_go_on_when_it_has_caught_up() {
    let dir = scratch_dir("actor-hold");
    let prefix = format!("it-hold-{}", std::process::id());
    let run_dir = dir.join("run");
    let config = dir.join("hold.toml");
    std::fs::write(
        &config,
        format!(
            "[task]\nenv = \"sim\"\nmethod = \"nomap-noseg\"\naffordances = [\"pick_up\", \"push\"]\nimage_size = 48\nepisode_steps = 8\nbalanced_frames = false\n\
             [policy]\nbatch_steps = 16\nepochs = 1\n\
             [unet]\nsteps_per_episode = 4\nhold_actors_beyond_episodes = 1\nbatch_frames = 2\nvalidation_fraction = 0.5\ntest_fraction = 0.0\n\
             [validation]\nviews_per_room = 0\n\
             [transport]\nservice_prefix = \"{prefix}\"\nmax_actors = 1\n"
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
    let mut actor: Process = start_actor(
        0,
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
            "--envs",
            "2",
        ],
    );

    // Held at least twice, and episodes kept coming after the first hold.
    let status = wait_for(
        Duration::from_secs(300),
        "two holds of the actor and episodes after them",
        || {
            if let Some(exit) = actor.wait_exit(Duration::ZERO) {
                panic!("actor exited early ({exit}):\n{}", actor.log_text());
            }
            let s = learner.status();
            (s["actor_holds"].as_u64() >= Some(2) && s["episodes"].as_u64() >= Some(8)).then_some(s)
        },
    );
    assert!(
        actor
            .log_text()
            .contains("waiting for the learner's U-Net to catch up"),
        "{}",
        actor.log_text()
    );
    // The U-Net trained while the actor waited.
    assert!(status["unet_steps"].as_u64() >= Some(8), "{status}");

    actor.signal(libc::SIGINT);
    let exit = actor
        .wait_exit(Duration::from_secs(60))
        .expect("actor exits on SIGINT");
    assert!(exit.success(), "actor exit {exit}:\n{}", actor.log_text());
    assert!(
        actor
            .log_text()
            .contains("s waiting for the learner's U-Net"),
        "{}",
        actor.log_text()
    );
}
