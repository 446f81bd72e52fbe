//! An outside process that publishes garbage on the weights service, the way
//! any process that can open the run's shared memory could, does not take an
//! actor down: the actor counts the message, says why once, keeps its
//! weights and keeps stepping, and takes the learner's next valid weights.

use std::time::{Duration, Instant};

use system_tests::{scratch_dir, start_actor, wait_for, Learner};

/// Environment steps actor 0 has sent, from the learner's view.
fn rollouts_of_actor_0(learner: &Learner) -> u64 {
    learner.status()["actors"]
        .as_array()
        .and_then(|actors| actors.iter().find(|a| a["id"] == 0))
        .and_then(|a| a["received"]["rollout"].as_u64())
        .unwrap_or(0)
}

#[test]
fn garbage_on_the_weights_service_is_skipped_and_the_actor_carries_on() {
    let dir = scratch_dir("bad-weights");
    let prefix = format!("it-badw-{}", std::process::id());
    let (learner, config) = Learner::start_bandit(&dir, &prefix);
    let mut actor = start_actor(0, &prefix, &dir, &["--config", &config]);
    wait_for(
        Duration::from_secs(30),
        "the actor's first rollouts",
        || (rollouts_of_actor_0(&learner) > 0).then_some(()),
    );

    // An outsider: its own node, the weights service opened by name.
    let (_node, service) = system_tests::open_as_outsider(&prefix, proto::service::WEIGHTS);
    let publisher = service
        .publisher_builder()
        .initial_max_slice_len(4096)
        .create()
        .expect("a spare publisher slot");
    // The 104 bytes that used to end every actor ("bad magic"), sent until
    // the actor has seen one: the learner's own weights may overtake any
    // single message (an actor takes only the newest).
    let garbage = [0xABu8; 104];
    let mut sent = 0;
    wait_for(
        Duration::from_secs(20),
        "the actor to report the skip",
        || {
            let mut sample = publisher
                .loan_slice(garbage.len())
                .expect("loaning a sample");
            sample.payload_mut().copy_from_slice(&garbage);
            sample.send().expect("sending garbage");
            sent += 1;
            std::thread::sleep(Duration::from_millis(50));
            std::fs::read_to_string(&actor.log)
                .ok()
                .filter(|log| log.contains("skipped a weights message"))
        },
    );
    // Still alive, still stepping, and still taking the learner's weights.
    let before = rollouts_of_actor_0(&learner);
    let deadline = Instant::now() + Duration::from_secs(20);
    while rollouts_of_actor_0(&learner) <= before + 2 {
        assert!(
            actor.child.try_wait().expect("polling the actor").is_none(),
            "the actor exited on garbage weights:\n{}",
            actor.log_text()
        );
        assert!(
            Instant::now() < deadline,
            "the actor stopped stepping after garbage weights:\n{}",
            actor.log_text()
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    let log = actor.log_text();
    assert_eq!(
        log.matches("skipped a weights message").count(),
        1,
        "one kind of fault, logged once however often it came ({sent} sent): {log}"
    );
    actor.signal(libc::SIGINT);
    assert!(actor
        .wait_exit(Duration::from_secs(20))
        .is_some_and(|s| s.success()));
    let log = actor.log_text();
    let refused: u64 = log
        .lines()
        .find_map(|line| line.strip_suffix(" weights messages refused"))
        .and_then(|line| line.rsplit(' ').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("the summary counts refused weights: {log}"));
    assert!((1..=sent).contains(&refused), "{refused} of {sent}: {log}");
}

/// The policy version actor 0's rollouts carry, from the learner's view.
fn policy_version_of_actor_0(learner: &Learner) -> u64 {
    learner.status()["actors"]
        .as_array()
        .and_then(|actors| actors.iter().find(|a| a["id"] == 0))
        .and_then(|a| a["policy_version"].as_u64())
        .unwrap_or(0)
}

#[test]
fn the_learners_own_weights_relabelled_by_an_outsider_are_refused() {
    let dir = scratch_dir("forged-weights");
    let prefix = format!("it-forgew-{}", std::process::id());
    let (learner, config) = Learner::start_bandit(&dir, &prefix);
    let mut actor = start_actor(0, &prefix, &dir, &["--config", &config]);
    wait_for(
        Duration::from_secs(30),
        "the actor's first rollouts",
        || (rollouts_of_actor_0(&learner) > 0).then_some(()),
    );

    // An outsider takes the learner's newest weights message from the
    // service's history: well formed, checksum right, real tensors.
    let (_node, service) = system_tests::open_as_outsider(&prefix, proto::service::WEIGHTS);
    let subscriber = service
        .subscriber_builder()
        .create()
        .expect("a spare subscriber slot");
    let genuine = wait_for(
        Duration::from_secs(10),
        "the learner's weights from history",
        || {
            subscriber
                .receive()
                .expect("receiving")
                .map(|s| s.payload().to_vec())
        },
    );
    // It claims a far newer policy version (the header is outside the
    // payload checksum) and republishes: before weights were signed, every
    // actor loaded it and reported version 1 000 000.
    const FORGED_VERSION: u64 = 1_000_000;
    let mut forged = genuine;
    forged[16..24].copy_from_slice(&FORGED_VERSION.to_le_bytes());
    let publisher = service
        .publisher_builder()
        .initial_max_slice_len(forged.len())
        .create()
        .expect("a spare publisher slot");
    wait_for(
        Duration::from_secs(20),
        "the actor to refuse the forged weights",
        || {
            let mut sample = publisher
                .loan_slice(forged.len())
                .expect("loaning a sample");
            sample.payload_mut().copy_from_slice(&forged);
            sample.send().expect("sending the forged weights");
            std::thread::sleep(Duration::from_millis(50));
            std::fs::read_to_string(&actor.log)
                .ok()
                .filter(|log| log.contains("not signed with the run's key"))
        },
    );
    let before = rollouts_of_actor_0(&learner);
    let deadline = Instant::now() + Duration::from_secs(20);
    while rollouts_of_actor_0(&learner) <= before + 2 {
        assert!(
            actor.child.try_wait().expect("polling the actor").is_none(),
            "the actor exited on forged weights:\n{}",
            actor.log_text()
        );
        assert!(Instant::now() < deadline, "the actor stopped stepping");
        std::thread::sleep(Duration::from_millis(100));
    }
    let version = policy_version_of_actor_0(&learner);
    assert!(
        (1..FORGED_VERSION).contains(&version),
        "the actor acts on the learner's weights, not the forged ones (version {version}):\n{}",
        actor.log_text()
    );
    actor.signal(libc::SIGINT);
    assert!(actor
        .wait_exit(Duration::from_secs(20))
        .is_some_and(|s| s.success()));
}
