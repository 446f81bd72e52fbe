//! An outside process that publishes on the weights service, the way any
//! process that can open the run's shared memory could, does not take an
//! actor down and does not steer it: garbage and weights not signed with the
//! run's key are counted, said once, and skipped; the actor keeps its
//! weights, keeps stepping, and takes the learner's next valid weights.

use std::path::Path;
use std::time::{Duration, Instant};

use iceoryx2::port::publisher::Publisher;
use iceoryx2::prelude::ipc;
use system_tests::{scratch_dir, start_actor, wait_for, Learner, Process};

/// A number the learner's status reports for actor 0 (`pointer` into its
/// entry, e.g. `/received/rollout`); 0 while it has none.
fn actor_0(learner: &Learner, pointer: &str) -> u64 {
    learner.status()["actors"]
        .as_array()
        .and_then(|actors| actors.iter().find(|a| a["id"] == 0))
        .and_then(|a| a.pointer(pointer)?.as_u64())
        .unwrap_or(0)
}

/// A bandit learner and actor 0, once the actor's rollouts arrive.
fn learner_and_stepping_actor(dir: &Path, prefix: &str) -> (Learner, Process) {
    let (learner, config) = Learner::start_bandit(dir, prefix);
    let actor = start_actor(0, prefix, dir, &["--config", &config]);
    wait_for(
        Duration::from_secs(30),
        "the actor's first rollouts",
        || (actor_0(&learner, "/received/rollout") > 0).then_some(()),
    );
    (learner, actor)
}

/// Publishes `bytes` every 50 ms until the actor's log holds `words`
/// (the learner's own weights may overtake any single message: an actor
/// takes only the newest); returns how many were sent.
fn send_until_logged(
    publisher: &Publisher<ipc::Service, [u8], ()>,
    bytes: &[u8],
    actor: &Process,
    words: &str,
) -> u64 {
    let mut sent = 0;
    wait_for(
        Duration::from_secs(20),
        &format!("the actor to log {words:?}"),
        || {
            let mut sample = publisher.loan_slice(bytes.len()).expect("loaning a sample");
            sample.payload_mut().copy_from_slice(bytes);
            sample.send().expect("sending");
            sent += 1;
            std::thread::sleep(Duration::from_millis(50));
            std::fs::read_to_string(&actor.log)
                .ok()
                .filter(|log| log.contains(words))
        },
    );
    sent
}

/// Fails unless the actor is alive and sends a few more rollouts.
fn assert_keeps_stepping(learner: &Learner, actor: &mut Process, after: &str) {
    let before = actor_0(learner, "/received/rollout");
    let deadline = Instant::now() + Duration::from_secs(20);
    while actor_0(learner, "/received/rollout") <= before + 2 {
        assert!(
            actor.child.try_wait().expect("polling the actor").is_none(),
            "the actor exited on {after}:\n{}",
            actor.log_text()
        );
        assert!(
            Instant::now() < deadline,
            "the actor stopped stepping after {after}:\n{}",
            actor.log_text()
        );
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// Stops the actor with SIGINT; fails unless it exits cleanly.
fn stop_cleanly(actor: &mut Process) {
    actor.signal(libc::SIGINT);
    assert!(actor
        .wait_exit(Duration::from_secs(20))
        .is_some_and(|s| s.success()));
}

#[test]
fn garbage_on_the_weights_service_is_skipped_and_the_actor_carries_on() {
    let dir = scratch_dir("bad-weights");
    let prefix = format!("it-badw-{}", std::process::id());
    let (learner, mut actor) = learner_and_stepping_actor(&dir, &prefix);

    // An outsider: its own node, the weights service opened by name.
    let (_node, service) = system_tests::open_as_outsider(&prefix, proto::service::WEIGHTS);
    let publisher = service
        .publisher_builder()
        .initial_max_slice_len(4096)
        .create()
        .expect("a spare publisher slot");
    // The 104 bytes that used to end every actor ("bad magic").
    let sent = send_until_logged(
        &publisher,
        &[0xAB; 104],
        &actor,
        "skipped a weights message",
    );
    // Still alive, still stepping, and still taking the learner's weights.
    assert_keeps_stepping(&learner, &mut actor, "garbage weights");
    let log = actor.log_text();
    assert_eq!(
        log.matches("skipped a weights message").count(),
        1,
        "one kind of fault, logged once however often it came ({sent} sent): {log}"
    );
    stop_cleanly(&mut actor);
    let log = actor.log_text();
    let refused: u64 = log
        .lines()
        .find_map(|line| line.strip_suffix(" weights messages refused"))
        .and_then(|line| line.rsplit(' ').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("the summary counts refused weights: {log}"));
    assert!((1..=sent).contains(&refused), "{refused} of {sent}: {log}");
}

#[test]
fn the_learners_own_weights_relabelled_by_an_outsider_are_refused() {
    let dir = scratch_dir("forged-weights");
    let prefix = format!("it-forgew-{}", std::process::id());
    let (learner, mut actor) = learner_and_stepping_actor(&dir, &prefix);

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
    send_until_logged(&publisher, &forged, &actor, "not signed with the run's key");
    assert_keeps_stepping(&learner, &mut actor, "forged weights");
    let version = actor_0(&learner, "/policy_version");
    assert!(
        (1..FORGED_VERSION).contains(&version),
        "the actor acts on the learner's weights, not the forged ones (version {version}):\n{}",
        actor.log_text()
    );
    stop_cleanly(&mut actor);
}
