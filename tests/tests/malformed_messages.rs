//! Malformed messages on every actor→learner service are counted in /metrics
//! and do not stop the learner; so are valid ones with a forged sequence
//! number, and oversized ones, which are refused before they are copied, and
//! lengths that lie beyond a stranger's segment, refused before they are read.

use std::path::PathBuf;
use std::time::Duration;

use proto::{encode, EpisodeStats, MessageHeader, MessageKind, StatField};
use system_tests::{metric_value, scratch_dir, wait_for, Learner};
use transport::{ActorPorts, TransportConfig};

/// A learner on a service prefix of its own, in a scratch directory named
/// after `case`; returns the prefix, its run directory and the learner.
fn start_learner(case: &str, prefix: &str) -> (String, PathBuf, Learner) {
    let dir = scratch_dir(case);
    let prefix = format!("{prefix}-{}", std::process::id());
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
    (prefix, run_dir, learner)
}

#[test]
fn malformed_messages_are_counted_and_the_learner_carries_on() {
    let (prefix, run_dir, learner) = start_learner("malformed", "it-bad");
    let config = TransportConfig {
        service_prefix: prefix,
        ..TransportConfig::default()
    };
    // A process of the run: it holds the join key the learner wrote.
    let key = transport::read_join_key(&run_dir.join(transport::JOIN_KEY_FILE)).expect("the key");
    let mut ports = ActorPorts::open(&config, 0, key).expect("open actor ports");

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

    // A valid message whose sequence number jumps ten million ahead is a
    // forgery, not ten million losses: refused, and nothing counted as lost.
    let forged = encode(
        &EpisodeStats::new(2, 10, 0).with(StatField::EpisodeReturn, 1234.5),
        MessageHeader {
            actor_id: 0,
            sequence: 10_000_000,
            ..Default::default()
        },
    );
    ports
        .publish_raw(MessageKind::Stats, &forged)
        .expect("send");
    let reason = "afx_messages_rejected_total{service=\"stats\",reason=\"sequence_out_of_window\"}";
    let metrics = wait_for(
        Duration::from_secs(10),
        "the forged sequence refused",
        || {
            let m = learner.metrics();
            (metric_value(&m, reason) == Some(1.0)).then_some(m)
        },
    );
    assert_eq!(
        metric_value(&metrics, "afx_messages_dropped_total"),
        Some(0.0)
    );
    assert_eq!(
        learner.status()["episodes"],
        1,
        "the forged episode is not counted"
    );

    // A gap in the sequence numbers is a loss, counted under its kind.
    let after_a_gap = encode(
        &EpisodeStats::new(3, 10, 0).with(StatField::EpisodeReturn, 3.0),
        MessageHeader {
            actor_id: 0,
            sequence: 4,
            ..Default::default()
        },
    );
    ports
        .publish_raw(MessageKind::Stats, &after_a_gap)
        .expect("send");
    let metrics = wait_for(Duration::from_secs(10), "the loss counted", || {
        let m = learner.metrics();
        (metric_value(&m, "afx_messages_dropped_total") == Some(2.0)).then_some(m)
    });
    assert_eq!(
        metric_value(
            &metrics,
            "afx_messages_dropped_by_kind_total{kind=\"stats\"}"
        ),
        Some(2.0),
        "sequences 2 and 3 of the stats were lost"
    );
    assert_eq!(learner.status()["dropped_by_kind"]["stats"], 2);
    assert_eq!(
        system_tests::http_get(&learner.addr, "/healthz").map(|r| r.0),
        Some(200)
    );
}

/// The learner's peak resident memory (`VmHWM`), in bytes.
fn peak_rss(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).expect("/proc status");
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.trim().strip_suffix("kB"))
        .and_then(|kb| kb.trim().parse::<u64>().ok())
        .expect("VmHWM in /proc status")
        * 1024
}

#[test]
fn oversized_messages_are_refused_before_the_learner_copies_them() {
    let (prefix, _, learner) = start_learner("oversized", "it-big");
    let pid = learner.process.child.id();
    // An outsider with its own node and a publisher on the rollouts service
    // that sends four times the service's largest message (16 MiB), four times.
    let (_node, service) = system_tests::open_as_outsider(&prefix, proto::service::ROLLOUTS);
    let size = 4 * TransportConfig::default().max_rollout_bytes;
    let publisher = service
        .publisher_builder()
        .initial_max_slice_len(size)
        .max_loaned_samples(1)
        .create()
        .expect("a publisher slot");
    let before = peak_rss(pid);
    let sends = 4;
    for _ in 0..sends {
        let mut sample = publisher.loan_slice(size).expect("loaning 64 MiB");
        sample.payload_mut()[..4].copy_from_slice(b"AFX1");
        sample.send().expect("sending");
        std::thread::sleep(Duration::from_millis(100));
    }
    // Rejected for whatever reason first, so that a learner that copies
    // before it checks fails on its memory, not on a label.
    let rejected = |metrics: &str| -> f64 {
        metrics
            .lines()
            .filter(|l| l.starts_with("afx_messages_rejected_total{service=\"rollouts\""))
            .filter_map(|l| l.rsplit(' ').next()?.parse::<f64>().ok())
            .sum()
    };
    let deadline = std::time::Instant::now() + Duration::from_secs(20);
    let metrics = loop {
        let metrics = learner.metrics();
        if rejected(&metrics) == sends as f64 {
            break metrics;
        }
        assert!(
            std::time::Instant::now() < deadline,
            "{sends} oversized messages not all refused after 20 s:\n{}",
            metrics
                .lines()
                .filter(|l| l.starts_with("afx_messages_rejected"))
                .collect::<Vec<_>>()
                .join("\n")
        );
        std::thread::sleep(Duration::from_millis(100));
    };
    let grown = peak_rss(pid).saturating_sub(before);
    assert!(
        grown < size as u64,
        "the learner's peak memory grew by {grown} bytes for {sends} messages of {size}: \
         it copied what it should have refused"
    );
    let reason = "afx_messages_rejected_total{service=\"rollouts\",reason=\"too_large\"}";
    assert_eq!(
        metric_value(&metrics, reason),
        Some(sends as f64),
        "{metrics}"
    );
    assert_eq!(
        system_tests::http_get(&learner.addr, "/healthz").map(|r| r.0),
        Some(200)
    );
}

/// The attack iceoryx2 itself does not stop: a foreign publisher with a
/// small segment rewrites its sample's element count (in its own shared
/// memory, after loaning) to a length within the service's maximum but far
/// beyond the segment. A subscriber that reads the payload reads past the
/// mapping: before publishers were screened this made the learner segfault.
#[test]
fn a_length_beyond_a_strangers_segment_is_refused_unread() {
    use iceoryx2::service::header::publish_subscribe::Header;

    let (prefix, _, mut learner) = start_learner("lying-length", "it-lie");
    let (_node, service) = system_tests::open_as_outsider(&prefix, proto::service::ROLLOUTS);
    let publisher = service
        .publisher_builder()
        .initial_max_slice_len(64)
        .max_loaned_samples(1)
        .create()
        .expect("a publisher slot");
    let lie = (TransportConfig::default().max_rollout_bytes / 2) as u64;
    let sends = 3;
    for _ in 0..sends {
        let mut sample = publisher.loan_slice(64).expect("loaning 64 bytes");
        sample.payload_mut()[..4].copy_from_slice(b"AFX1");
        // The element count sits in iceoryx2's sample header after the
        // publisher id; find the u64 that holds the loaned 64 and write the
        // lie there, as any process that maps its own segment can.
        let header = sample.header() as *const Header;
        let words = std::mem::size_of::<Header>() / 8;
        let count = (1..words)
            .map(|i| header.cast::<u64>().wrapping_add(i))
            .find(|&word| {
                // SAFETY: `word` lies inside the header iceoryx2 just wrote.
                let value = unsafe { std::ptr::read_volatile(word) };
                value == 64
            })
            .expect("the element count in the sample header");
        // SAFETY: the header is in this process's writable shared-memory
        // segment and no reference to it is alive; an attacker writes it.
        unsafe { std::ptr::write_volatile(count.cast_mut(), lie) };
        assert_eq!(sample.payload().len() as u64, lie, "the lie took");
        sample.send().expect("sending");
        std::thread::sleep(Duration::from_millis(100));
    }
    let reason = "afx_messages_rejected_total{service=\"rollouts\",reason=\"unknown_publisher\"}";
    let metrics = wait_for(Duration::from_secs(20), "the lies refused", || {
        assert!(
            learner
                .process
                .child
                .try_wait()
                .expect("polling the learner")
                .is_none(),
            "the learner died reading past a foreign segment"
        );
        let m = learner.metrics();
        (metric_value(&m, reason) == Some(sends as f64)).then_some(m)
    });
    assert_eq!(
        metric_value(&metrics, "afx_env_steps_total"),
        Some(0.0),
        "{metrics}"
    );
    assert_eq!(
        system_tests::http_get(&learner.addr, "/healthz").map(|r| r.0),
        Some(200)
    );
}
