//! Messages that claim to come from an actor are accepted only from the
//! publishers that joined as that actor with the run's key. An outside
//! process that can open the run's shared memory (its own iceoryx2 node and
//! ports, as any process of the same user could) captures a real actor's
//! join, stats and rollouts and sends them, and forged ones, as its own:
//! every one is refused and counted under its reason, the real actor's
//! counters stay right, no ghost actor appears, and the real actor carries on.

use std::time::{Duration, Instant};

use iceoryx2::prelude::*;
use proto::{encode, EpisodeStats, Join, JoinKey, MessageHeader, StatField};
use system_tests::{metric_value, scratch_dir, start_actor, wait_for, Learner};

/// The first message on `service` from anyone that is `wanted`, as bytes.
/// Reads as fast as messages come: the bandit fixture's actor sends
/// thousands of stats a second, and a subscriber's buffer keeps only the
/// newest few, so a reader that slept between reads (20 ms once) saw the
/// actor's join, one message every 2 s, only now and then (14–26 s, or not
/// within 30 s, in three of five runs).
fn capture(
    subscriber: &iceoryx2::port::subscriber::Subscriber<ipc::Service, [u8], ()>,
    what: &str,
    wanted: impl Fn(&[u8]) -> bool,
) -> Vec<u8> {
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        match subscriber.receive().expect("receiving") {
            Some(sample) if wanted(sample.payload()) => return sample.payload().to_vec(),
            Some(_) => {}
            None => {
                assert!(
                    Instant::now() < deadline,
                    "timed out after 30 s waiting for {what}"
                );
                std::thread::sleep(Duration::from_millis(1));
            }
        }
    }
}

fn kind_of(bytes: &[u8]) -> u16 {
    u16::from_le_bytes([bytes[6], bytes[7]])
}

fn send(publisher: &iceoryx2::port::publisher::Publisher<ipc::Service, [u8], ()>, bytes: &[u8]) {
    let mut sample = publisher.loan_slice(bytes.len()).expect("loaning");
    sample.payload_mut().copy_from_slice(bytes);
    sample.send().expect("sending");
}

fn rejected(learner: &Learner, service: &str, reason: &str) -> f64 {
    metric_value(
        &learner.metrics(),
        &format!("afx_messages_rejected_total{{service=\"{service}\",reason=\"{reason}\"}}"),
    )
    .unwrap_or(0.0)
}

fn actor_0(learner: &Learner) -> serde_json::Value {
    learner.status()["actors"]
        .as_array()
        .and_then(|actors| actors.iter().find(|a| a["id"] == 0).cloned())
        .unwrap_or_default()
}

#[test]
fn only_the_publishers_that_joined_speak_for_an_actor() {
    let dir = scratch_dir("spoofing");
    let prefix = format!("it-spoof-{}", std::process::id());
    let (learner, config) = Learner::start_bandit(&dir, &prefix);
    let mut actor = start_actor(0, &prefix, &dir, &["--config", &config]);

    // The outsider listens on the stats and rollouts services (spare
    // subscriber slots) and publishes on them (spare publisher slots).
    let (_stats_node, stats) = system_tests::open_as_outsider(&prefix, proto::service::STATS);
    let (_rollouts_node, rollouts) =
        system_tests::open_as_outsider(&prefix, proto::service::ROLLOUTS);
    let stats_in = stats
        .subscriber_builder()
        .create()
        .expect("a stats subscriber");
    let rollouts_in = rollouts
        .subscriber_builder()
        .create()
        .expect("a rollouts subscriber");
    let stats_out = stats
        .publisher_builder()
        .initial_max_slice_len(4096)
        .create()
        .expect("a stats publisher");
    let rollouts_out = rollouts
        .publisher_builder()
        .initial_max_slice_len(1 << 16)
        .create()
        .expect("a rollouts publisher");
    let join = proto::MessageKind::Join as u16;
    let real_join = capture(&stats_in, "the actor's join (repeated every 2 s)", |b| {
        kind_of(b) == join
    });
    let real_rollout = capture(&rollouts_in, "one of the actor's rollouts", |_| true);
    wait_for(Duration::from_secs(30), "actor 0 at the learner", || {
        (actor_0(&learner)["received"]["rollout"].as_u64() > Some(0)).then_some(())
    });
    let dropped_before = actor_0(&learner)["dropped"].as_u64().expect("dropped");

    // 1. The captured join, replayed: it names the real actor's publishers,
    //    not the outsider's.
    send(&stats_out, &real_join);
    // 2. A join made without the run's key, for a ghost actor 3.
    let forged_join = Join::new(&JoinKey::from_bytes([9; proto::JOIN_KEY_LEN]), 3, [1, 2, 3]);
    let header = |actor_id, sequence| MessageHeader {
        actor_id,
        sequence,
        ..Default::default()
    };
    send(&stats_out, &encode(&forged_join, header(3, 1)));
    // 3. Valid stats in actor 0's name (the attack's return of 1234.5), and
    //    in a ghost actor 3's.
    let stats_of =
        |episode| EpisodeStats::new(episode, 10, 0).with(StatField::EpisodeReturn, 1234.5);
    send(&stats_out, &encode(&stats_of(1), header(0, 1)));
    send(&stats_out, &encode(&stats_of(2), header(3, 1)));
    // 4. The actor's own rollout, replayed, and again with a sequence number
    //    ten million ahead (which used to count ten million drops).
    send(&rollouts_out, &real_rollout);
    // The checksum covers the payload only: the header's sequence (bytes
    // 32..40) can be rewritten and the message stays valid.
    let mut far_ahead = real_rollout.clone();
    let sequence = u64::from_le_bytes(far_ahead[32..40].try_into().unwrap());
    far_ahead[32..40].copy_from_slice(&(sequence + 10_000_000).to_le_bytes());
    send(&rollouts_out, &far_ahead);

    // The joins are read and refused for what they say; the outsider's
    // stats and rollouts, from a publisher that never joined, are refused
    // before the learner reads a byte of them.
    for (service, reason, count) in [
        ("stats", "join_from_another_publisher", 1.0),
        ("stats", "bad_join_proof", 1.0),
        ("stats", "unknown_publisher", 2.0),
        ("rollouts", "unknown_publisher", 2.0),
    ] {
        wait_for(
            Duration::from_secs(10),
            &format!("{service} {reason} counted {count} times"),
            || (rejected(&learner, service, reason) == count).then_some(()),
        );
    }
    let status = learner.status();
    assert_eq!(status["actors_alive"], 1, "no ghost: {status}");
    assert!(
        status["actors"]
            .as_array()
            .expect("actors")
            .iter()
            .all(|a| a["id"] == 0),
        "only actor 0 is known: {status}"
    );
    let dropped_after = actor_0(&learner)["dropped"].as_u64().expect("dropped");
    assert!(
        dropped_after < dropped_before + 1000,
        "the forged sequence counted as drops: {dropped_before} → {dropped_after}"
    );
    // Parsed, not searched as text: a real episode's steps_per_second
    // (51234.59375 once) can hold the digits "1234.5".
    let history = std::fs::read_to_string(dir.join("run/history.jsonl")).expect("history");
    let spoofed = history
        .lines()
        .filter_map(|line| serde_json::from_str::<serde_json::Value>(line).ok())
        .find(|record| record["stats"]["episode_return"].as_f64() == Some(1234.5));
    assert!(
        spoofed.is_none(),
        "a spoofed episode reached the history: {spoofed:?}"
    );

    // The real actor is still heard.
    let before = actor_0(&learner)["received"]["rollout"].as_u64().unwrap();
    wait_for(
        Duration::from_secs(20),
        "more rollouts from actor 0",
        || (actor_0(&learner)["received"]["rollout"].as_u64() > Some(before + 2)).then_some(()),
    );
    assert!(actor.child.try_wait().expect("polling").is_none());
    for reason in ["not_joined", "not_its_publisher"] {
        assert_eq!(rejected(&learner, "rollouts", reason), 0.0);
        assert_eq!(rejected(&learner, "stats", reason), 0.0);
    }
    let log = std::fs::read_to_string(dir.join("learner.log")).expect("learner log");
    assert!(log.contains("actor joined"), "{log}");
}
