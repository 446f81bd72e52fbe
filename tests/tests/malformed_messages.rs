//! Malformed messages on every actor→learner service are counted in /metrics
//! and do not stop the learner.

use std::time::Duration;

use proto::{encode, EpisodeStats, MessageHeader, MessageKind, StatField};
use system_tests::{metric_value, scratch_dir, wait_for, Learner};
use transport::{ActorPorts, TransportConfig};

#[test]
fn malformed_messages_are_counted_and_the_learner_carries_on() {
    let dir = scratch_dir("malformed");
    let prefix = format!("it-bad-{}", std::process::id());
    let run_dir = dir.join("run");
    let learner = Learner::start(
        &run_dir,
        &[
            "--run-dir".into(),
            run_dir.display().to_string(),
            "--service-prefix".into(),
            prefix.clone(),
        ],
        dir.join("learner.log"),
    );
    let config = TransportConfig {
        service_prefix: prefix,
        ..TransportConfig::default()
    };
    let mut ports = ActorPorts::open(&config, 0).expect("open actor ports");

    let valid = encode(
        &EpisodeStats::new(1, 10, 0).with(StatField::EpisodeReturn, 2.0),
        MessageHeader {
            actor_id: 0,
            sequence: 1,
            ..Default::default()
        },
    );
    let mut bad_checksum = valid.clone();
    *bad_checksum.last_mut().unwrap() ^= 1;
    let garbage = vec![0xAB; 100];
    let sends: [(MessageKind, &[u8], &str); 4] = [
        (MessageKind::Rollout, &garbage, "bad_magic"),
        (MessageKind::Frames, &valid[..20], "truncated"),
        (MessageKind::Stats, &bad_checksum, "bad_checksum"),
        (MessageKind::Rollout, &valid, "wrong_kind"),
    ];
    for (kind, bytes, _) in sends {
        ports.publish_raw(kind, bytes).expect("send");
    }
    let metrics = wait_for(Duration::from_secs(10), "rejections in /metrics", || {
        let m = learner.metrics();
        sends
            .iter()
            .all(|(kind, _, reason)| {
                let service = proto::service::for_kind(*kind);
                metric_value(
                    &m,
                    &format!(
                        "afx_messages_rejected_total{{service=\"{service}\",reason=\"{reason}\"}}"
                    ),
                ) == Some(1.0)
            })
            .then_some(m)
    });
    assert_eq!(
        metric_value(&metrics, "afx_episodes_total"),
        Some(0.0),
        "nothing malformed was accepted"
    );

    // The learner still accepts a valid message afterwards.
    ports.publish_raw(MessageKind::Stats, &valid).expect("send");
    wait_for(
        Duration::from_secs(10),
        "the valid stats to be accepted",
        || (learner.status()["episodes"] == 1).then_some(()),
    );
    assert_eq!(
        system_tests::http_get(&learner.addr, "/healthz").map(|r| r.0),
        Some(200)
    );
}
