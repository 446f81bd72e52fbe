//! The transport between real iceoryx2 nodes in one process: joins and
//! the publisher a message came through, delivery, late-joiner weights, and
//! bounded, counted drops under backpressure.

use std::time::Duration;

use proto::{decode, EpisodeStats, JoinKey, Limits, Message, MessageKind, StatField};
use transport::{ActorPorts, Delivery, LearnerPorts, TransportConfig};

fn config(test: &str) -> TransportConfig {
    TransportConfig {
        service_prefix: format!("afx-test-{}-{test}", std::process::id()),
        max_actors: 4,
        learner_buffer: 4,
        max_rollout_bytes: 1 << 16,
        max_frames_bytes: 1 << 16,
        max_weights_bytes: 1 << 16,
        ..TransportConfig::default()
    }
}

fn key() -> JoinKey {
    JoinKey::from_bytes([3; proto::JOIN_KEY_LEN])
}

const LIMITS: Limits = Limits {
    max_actors: 4,
    max_payload_len: 1 << 20,
};

fn weights_blob(value: f32) -> Vec<u8> {
    let data = value.to_le_bytes().to_vec();
    let view =
        safetensors::tensor::TensorView::new(safetensors::Dtype::F32, vec![1], &data).unwrap();
    safetensors::serialize([("policy.w", view)], None).unwrap()
}

/// The join an actor sends when it opens its ports, as the learner reads it.
fn take_join(learner: &LearnerPorts, actor: &ActorPorts) {
    let msg = learner
        .receive(MessageKind::Stats)
        .unwrap()
        .expect("the actor's join");
    let ids = actor.publisher_ids();
    assert_eq!(
        msg.origin(),
        ids[2],
        "the join came through the stats publisher"
    );
    let (header, decoded) = decode(msg.bytes(), &LIMITS).unwrap();
    let Message::Join(join) = decoded else {
        panic!("got {:?}", decoded.kind())
    };
    assert_eq!(join.publishers, ids);
    assert!(join.verify(&key(), header.actor_id));
}

#[test]
fn stats_reach_the_learner_and_wake_it() {
    let cfg = config("stats");
    let learner = LearnerPorts::open(&cfg, key()).unwrap();
    let mut actor = ActorPorts::open(&cfg, 2, key()).unwrap();
    take_join(&learner, &actor);
    let ids = actor.publisher_ids();
    assert_eq!(
        ids.iter().collect::<std::collections::HashSet<_>>().len(),
        3,
        "one publisher per service"
    );
    let stats = EpisodeStats::new(9, 600, 1).with(StatField::EpisodeReturn, 3.5);
    assert_eq!(actor.publish(&stats, 1, 1).unwrap(), Delivery::Delivered(1));
    assert!(
        learner.wait(Duration::from_secs(2)).unwrap(),
        "the actor's notification must wake the learner"
    );
    let msg = learner
        .receive(MessageKind::Stats)
        .unwrap()
        .expect("a stats message");
    assert_eq!(msg.origin(), ids[2]);
    let (header, decoded) = decode(msg.bytes(), &LIMITS).unwrap();
    assert_eq!((header.actor_id, header.sequence), (2, 1));
    match decoded {
        Message::Stats(got) => assert_eq!(*got, stats),
        other => panic!("got {:?}", other.kind()),
    }
    assert!(learner.receive(MessageKind::Stats).unwrap().is_none());
}

#[test]
fn a_late_actor_gets_the_newest_weights_at_once() {
    let cfg = config("late");
    let mut learner = LearnerPorts::open(&cfg, key()).unwrap();
    learner.publish_weights(1, 1, &weights_blob(1.0)).unwrap();
    learner.publish_weights(2, 1, &weights_blob(2.0)).unwrap();
    let actor = ActorPorts::open(&cfg, 0, key()).unwrap();
    learner.maintain();
    let msg = actor
        .wait_for_weights(Duration::from_secs(2))
        .unwrap()
        .expect("weights from history");
    let (header, weights) = actor.check_weights(&msg).unwrap();
    assert_eq!(header.policy_version, 2);
    assert_eq!(weights.bytes(), &weights_blob(2.0)[..]);
}

#[test]
fn weights_from_a_learner_with_another_key_are_refused() {
    let cfg = config("foreign");
    let mut foreign = LearnerPorts::open(
        &cfg,
        proto::JoinKey::from_bytes([0xee; proto::JOIN_KEY_LEN]),
    )
    .unwrap();
    let actor = ActorPorts::open(&cfg, 0, key()).unwrap();
    foreign.publish_weights(1, 1, &weights_blob(1.0)).unwrap();
    let msg = actor
        .wait_for_weights(Duration::from_secs(2))
        .unwrap()
        .expect("the foreign weights arrive");
    assert!(matches!(
        actor.check_weights(&msg),
        Err(proto::ProtoError::BadSignature)
    ));
}

#[test]
fn a_slow_learner_makes_actors_drop_and_count_not_grow() {
    let cfg = config("slow");
    let learner = LearnerPorts::open(&cfg, key()).unwrap();
    let mut actor = ActorPorts::open(&cfg, 1, key()).unwrap();
    take_join(&learner, &actor);
    let stats = EpisodeStats::new(0, 1, 0);
    let mut delivered = 0;
    let mut dropped = 0;
    for _ in 0..50 {
        match actor.publish(&stats, 0, 0).unwrap() {
            Delivery::Delivered(_) => delivered += 1,
            Delivery::Dropped => dropped += 1,
        }
    }
    assert_eq!(
        delivered, cfg.learner_buffer,
        "exactly the learner's buffer is delivered"
    );
    assert_eq!(dropped, 50 - cfg.learner_buffer);
    // The learner sees the first messages, and the gap in sequence numbers afterwards.
    let mut sequences = Vec::new();
    while let Some(msg) = learner.receive(MessageKind::Stats).unwrap() {
        sequences.push(decode(msg.bytes(), &LIMITS).unwrap().0.sequence);
    }
    assert_eq!(sequences, vec![1, 2, 3, 4]);
    assert_eq!(actor.publish(&stats, 0, 0).unwrap(), Delivery::Delivered(1));
    let msg = learner.receive(MessageKind::Stats).unwrap().unwrap();
    assert_eq!(decode(msg.bytes(), &LIMITS).unwrap().0.sequence, 51);
}

#[test]
fn oversized_messages_are_refused_with_a_hint() {
    let cfg = config("big");
    let _learner = LearnerPorts::open(&cfg, key()).unwrap();
    let mut actor = ActorPorts::open(&cfg, 0, key()).unwrap();
    let batch = proto::FrameBatch {
        episode_id: 0,
        height: 128,
        width: 128,
        n_affordances: 2,
        depth_m: vec![1.0; 128 * 128],
        rgb: vec![0; 3 * 128 * 128],
        labels: vec![255; 2 * 128 * 128],
    };
    let err = actor.publish(&batch, 0, 0).unwrap_err().to_string();
    assert!(err.contains("max_frames_bytes"), "{err}");
    assert!(
        ActorPorts::open(&cfg, 4, key()).is_err(),
        "actor ids at or above max_actors are refused"
    );
}
