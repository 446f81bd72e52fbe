//! A held publisher slot is a condition to wait out, not the end of a run:
//! a `deploy/local.sh` run of two actors (bandit fixture) whose rollouts
//! service has every spare slot held by a foreign process; actor 0 is
//! killed and the foreign process takes its freed slot too. The restarted
//! actor cannot join: the supervisor says why and retries it with back-off
//! while actor 1 keeps training, the learner's status names the full
//! service, and once the foreign process lets go, actor 0 joins again.

use std::time::Duration;

use system_tests::{
    kill_pid, launch_bandit_run, open_as_outsider, run_status, scratch_dir, wait_for,
    wait_launch_exit,
};

#[test]
fn a_run_waits_out_a_held_slot_and_gets_its_actor_back() {
    let dir = scratch_dir("held-slot");
    let name = format!("held-{}", std::process::id());
    let run_dir = dir.join(&name);
    let port = system_tests::free_port();
    let mut launch = launch_bandit_run(&run_dir, port, dir.join("local.log"), &[]);
    wait_for(Duration::from_secs(60), "both actors training", || {
        (run_status(port)?["actors_alive"] == 2).then_some(())
    });

    // The outsider takes both spare slots of the rollouts service (2 actors + 2 spares).
    let (_node, rollouts) = open_as_outsider(&format!("afx-{name}"), proto::service::ROLLOUTS);
    let take = || {
        rollouts
            .publisher_builder()
            .initial_max_slice_len(64)
            .create()
            .ok()
    };
    let mut held: Vec<_> = (0..2).map(|_| take().expect("a spare slot")).collect();
    assert!(take().is_none(), "the actors hold the other two");

    // Actor 0 dies; the outsider takes its slot once its dead node is cleaned up.
    let logs = run_dir.join("logs");
    let pid = std::fs::read_to_string(logs.join("actor-0.pid")).expect("actor 0's pid");
    kill_pid(&pid, libc::SIGKILL);
    held.push(wait_for(Duration::from_secs(10), "actor 0's slot", || {
        transport::remove_dead_nodes().expect("cleaning dead nodes");
        take()
    }));

    // Actor 0 is retried, not given up on, and the run goes on with actor 1.
    let local_log = || std::fs::read_to_string(dir.join("local.log")).unwrap_or_default();
    wait_for(Duration::from_secs(60), "the supervisor's retry", || {
        local_log()
            .contains("actor 0 could not join: every publisher slot of a service is taken")
            .then_some(())
    });
    let s = run_status(port).expect("the learner answers");
    assert_eq!(s["services_full"][0], "rollouts", "{s}");
    let steps = |s: &serde_json::Value, id: u64| {
        s["actors"]
            .as_array()
            .and_then(|a| a.iter().find(|a| a["id"].as_u64() == Some(id)))
            .and_then(|a| a["env_steps"].as_u64())
            .unwrap_or(0)
    };
    let (actor0, actor1) = (steps(&s, 0), steps(&s, 1));
    wait_for(Duration::from_secs(30), "actor 1 training on", || {
        (steps(&run_status(port)?, 1) > actor1).then_some(())
    });
    assert!(
        launch.script.try_wait().expect("local.sh").is_none(),
        "the run stopped:\n{}",
        local_log()
    );
    assert_eq!(
        steps(&run_status(port).unwrap(), 0),
        actor0,
        "actor 0 is out"
    );

    // The outsider lets go: actor 0 joins at a retry and trains again.
    held.clear();
    wait_for(Duration::from_secs(90), "actor 0 training again", || {
        (steps(&run_status(port)?, 0) > actor0).then_some(())
    });
    wait_for(Duration::from_secs(10), "no full service", || {
        run_status(port)?["services_full"]
            .as_array()?
            .is_empty()
            .then_some(())
    });

    // SIGTERM, which the script traps as it traps Ctrl-C: a SIGINT to the
    // script alone is lost when the tests run as a background job (which
    // starts with SIGINT ignored, and bash cannot trap an ignored signal).
    kill_pid(&launch.script.id().to_string(), libc::SIGTERM);
    let exit = wait_launch_exit(&mut launch, 60);
    assert!(exit.success(), "{}", local_log());
}
