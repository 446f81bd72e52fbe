//! When other processes hold every publisher slot of a service, an actor
//! that cannot join says which service, how many slots it has and which
//! settings raise them, instead of iceoryx2's bare error name; the learner
//! reports how many publishers each service has.

use std::time::Duration;

use system_tests::{scratch_dir, start_actor, Learner};

#[test]
fn an_actor_without_a_publisher_slot_says_what_holds_them_and_what_to_raise() {
    let dir = scratch_dir("slots");
    let prefix = format!("it-slots-{}", std::process::id());
    let (learner, config) = Learner::start_bandit(&dir, &prefix);
    // An outsider takes every slot of the rollouts service: max_actors 4 + 2 spares.
    let (_node, service) = system_tests::open_as_outsider(&prefix, proto::service::ROLLOUTS);
    let mut held = Vec::new();
    while let Ok(publisher) = service
        .publisher_builder()
        .initial_max_slice_len(64)
        .create()
    {
        held.push(publisher);
        assert!(
            held.len() <= 64,
            "the service should have a publisher limit"
        );
    }
    assert_eq!(held.len(), 6, "max_actors 4 + spare_ports 2");
    // The learner reports who holds the slots.
    system_tests::wait_for(Duration::from_secs(10), "the publisher count", || {
        (learner.status()["publishers"]["rollouts"] == 6).then_some(())
    });
    assert_eq!(
        system_tests::metric_value(
            &learner.metrics(),
            "afx_service_publishers{service=\"rollouts\"}"
        ),
        Some(6.0)
    );

    let mut actor = start_actor(0, &prefix, &dir, &["--config", &config]);
    let status = actor
        .wait_exit(Duration::from_secs(30))
        .expect("the actor gives up at once");
    assert_eq!(
        status.code(),
        Some(transport::SLOTS_TAKEN_EXIT),
        "a distinct status, which a supervisor retries"
    );
    let log = actor.log_text();
    for words in [
        "\"rollouts\"",
        "all 6 publisher slots",
        "max_actors 4 + spare_ports 2",
        "learner clean",
    ] {
        assert!(log.contains(words), "{words} in:\n{log}");
    }
}
