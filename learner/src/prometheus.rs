//! Prometheus text rendering of a [`StatusSnapshot`], one metric per
//! quantity with its unit in the name (`afx_episode_return`,
//! `afx_ppo_approx_kl`, `afx_ppo_update_duration_seconds`, …).
//!
//! The registry is built fresh from one snapshot per scrape: nothing is counted
//! twice, and `/metrics` agrees with `/api/status` by construction. It is
//! served as OpenMetrics to a scraper that asks for it and in the classic
//! text format otherwise ([`to_classic`]), which is what `promtool` and
//! older scrapers read.

use std::sync::atomic::AtomicU64;

use prometheus_client::encoding::EncodeLabelSet;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::registry::{Registry, Unit};

use crate::status::{StatusSnapshot, Timings, EPISODE_WINDOW};

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct KindLabel {
    kind: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct RejectLabel {
    service: String,
    reason: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct ServiceLabel {
    service: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct ActorLabel {
    actor: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct AffordanceLabel {
    affordance: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct BuildLabel {
    version: String,
    backend: String,
}

fn counter(registry: &mut Registry, name: &str, help: &str, value: u64) {
    let c: Counter = Counter::default();
    c.inc_by(value);
    registry.register(name, help, c);
}

fn seconds_counter(registry: &mut Registry, name: &str, help: &str, value: f64) {
    let c: Counter<f64, AtomicU64> = Counter::default();
    c.inc_by(value);
    registry.register_with_unit(name, help, Unit::Seconds, c);
}

fn gauge(registry: &mut Registry, name: &str, help: &str, value: f64) {
    let g: Gauge<f64, AtomicU64> = Gauge::default();
    g.set(value);
    registry.register(name, help, g);
}

/// Renders the snapshot and the timing histograms as OpenMetrics text.
pub fn render(s: &StatusSnapshot, timings: &Timings) -> String {
    let mut r = Registry::with_prefix("afx");
    let build = Family::<BuildLabel, Gauge<f64, AtomicU64>>::default();
    build
        .get_or_create(&BuildLabel {
            version: env!("CARGO_PKG_VERSION").into(),
            backend: nets::device::backend_features(),
        })
        .set(1.0);
    r.register(
        "build_info",
        "The learner's version and network backend (always 1)",
        build,
    );
    counter(
        &mut r,
        "env_steps",
        "Environment steps trained on",
        s.counters.env_steps,
    );
    counter(
        &mut r,
        "policy_updates",
        "Policy updates done",
        s.counters.updates,
    );
    counter(
        &mut r,
        "episodes",
        "Episodes reported by actors",
        s.counters.episodes,
    );
    counter(
        &mut r,
        "weights_published",
        "Weights messages published",
        s.counters.weights_published,
    );
    counter(
        &mut r,
        "checkpoints_written",
        "Checkpoints written by this learner process",
        s.counters.checkpoints_written,
    );
    counter(
        &mut r,
        "untrainable_chunks",
        "Valid rollout chunks whose shapes did not fit the policy",
        s.counters.untrainable_chunks,
    );
    counter(
        &mut r,
        "trained_steps",
        "Environment steps that went into policy updates",
        s.counters.trained_steps,
    );
    seconds_counter(
        &mut r,
        "ppo_thread_batch",
        "Time the PPO batching thread spent gathering and building batches (during the updates)",
        s.counters.ppo_batch_seconds,
    );
    seconds_counter(
        &mut r,
        "ppo_thread_update",
        "Time the PPO training thread spent in updates",
        s.counters.ppo_update_seconds,
    );
    seconds_counter(
        &mut r,
        "receive_loop_busy",
        "Time the receive loop spent on its passes, not waiting for messages",
        s.counters.receive_loop_seconds,
    );
    counter(
        &mut r,
        "receive_loop_long_passes",
        "Passes of the receive loop longer than 0.1 s (each may lose messages)",
        s.counters.receive_loop_long_passes,
    );
    gauge(
        &mut r,
        "receive_loop_longest_pass_seconds",
        "The receive loop's longest pass so far",
        s.counters.receive_loop_longest_pass_s,
    );
    counter(
        &mut r,
        "rollout_steps_discarded",
        "Environment steps discarded, oldest first, because the PPO queue was full",
        s.counters.rollout_steps_discarded,
    );
    gauge(
        &mut r,
        "rollout_steps_queued",
        "Environment steps waiting for the PPO thread",
        s.counters.rollout_steps_queued as f64,
    );
    counter(
        &mut r,
        "frames_received",
        "Labelled frames received for U-Net training",
        s.counters.frames_received,
    );
    counter(
        &mut r,
        "frames_skipped",
        "Labelled frames skipped because the U-Net trainer was behind",
        s.counters.frames_skipped,
    );
    counter(
        &mut r,
        "unet_rounds",
        "Rounds of U-Net training (a few steps each, after the episodes that arrived since the last round)",
        s.counters.unet_rounds,
    );
    counter(
        &mut r,
        "unet_steps",
        "Gradient steps of U-Net training",
        s.counters.unet_steps,
    );
    gauge(
        &mut r,
        "unet_owed_steps",
        "Gradient steps the U-Net owes the episodes that arrived",
        s.counters.unet_owed_steps as f64,
    );
    gauge(
        &mut r,
        "actors_held",
        "1 while the actors are told to wait for the U-Net to catch up",
        if s.counters.actors_held { 1.0 } else { 0.0 },
    );
    counter(
        &mut r,
        "actor_holds",
        "Times the actors were told to wait for the U-Net",
        s.counters.actor_holds,
    );
    counter(
        &mut r,
        "messages_dropped",
        "Actor messages lost in transit (sequence gaps)",
        s.dropped,
    );
    gauge(
        &mut r,
        "policy_version",
        "Current policy version",
        s.counters.policy_version as f64,
    );
    gauge(
        &mut r,
        "unet_version",
        "Current U-Net version",
        s.counters.unet_version as f64,
    );
    gauge(
        &mut r,
        "actors_alive",
        "Actors heard from within the timeout",
        s.actors_alive as f64,
    );
    gauge(
        &mut r,
        "uptime_seconds",
        "Seconds since the learner started",
        s.uptime_s,
    );

    let received = Family::<KindLabel, Counter>::default();
    for (kind, &n) in &s.received {
        received
            .get_or_create(&KindLabel { kind: kind.clone() })
            .inc_by(n);
    }
    r.register(
        "messages_received",
        "Valid messages accepted, per kind",
        received,
    );

    let dropped = Family::<KindLabel, Counter>::default();
    for (kind, &n) in &s.dropped_by_kind {
        dropped
            .get_or_create(&KindLabel { kind: kind.clone() })
            .inc_by(n);
    }
    r.register(
        "messages_dropped_by_kind",
        "Actor messages lost in transit (sequence gaps), per kind: which buffer overflowed",
        dropped,
    );

    let publishers = Family::<ServiceLabel, Gauge<f64, AtomicU64>>::default();
    for (service, &n) in &s.publishers {
        publishers
            .get_or_create(&ServiceLabel {
                service: service.clone(),
            })
            .set(n as f64);
    }
    r.register(
        "service_publishers",
        "Publishers on each actor-to-learner service (slots taken of max_actors + spare_ports)",
        publishers,
    );

    let rejected = Family::<RejectLabel, Counter>::default();
    for row in &s.rejected {
        rejected
            .get_or_create(&RejectLabel {
                service: row.service.clone(),
                reason: row.reason.clone(),
            })
            .inc_by(row.count);
    }
    r.register(
        "messages_rejected",
        "Malformed messages rejected, per service and failed check",
        rejected,
    );

    let lag = Family::<ActorLabel, Gauge<f64, AtomicU64>>::default();
    let last_seen = Family::<ActorLabel, Gauge<f64, AtomicU64>>::default();
    let actor_steps = Family::<ActorLabel, Counter>::default();
    let actor_rate = Family::<ActorLabel, Gauge<f64, AtomicU64>>::default();
    for a in &s.actors {
        let label = ActorLabel {
            actor: a.id.to_string(),
        };
        lag.get_or_create(&label).set(a.policy_lag as f64);
        last_seen.get_or_create(&label).set(a.last_seen_s);
        actor_steps.get_or_create(&label).inc_by(a.env_steps);
        if let Some(rate) = a.steps_per_s {
            actor_rate.get_or_create(&label).set(rate);
        }
    }
    r.register(
        "actor_env_steps_per_second",
        "Environment steps per second per actor, over its chunks of the last minute",
        actor_rate,
    );
    r.register(
        "actor_policy_lag",
        "Policy versions between the learner and the actor's newest chunk",
        lag,
    );
    r.register(
        "actor_last_seen_seconds",
        "Seconds since the actor's last accepted message",
        last_seen,
    );
    r.register(
        "actor_env_steps",
        "Environment steps contributed per actor",
        actor_steps,
    );

    for (field, &mean) in &s.episode_means {
        let name = field.strip_prefix("episode_").unwrap_or(field);
        gauge(
            &mut r,
            &format!("episode_{name}"),
            &format!(
                "Mean of the episodes' {field} over the last {EPISODE_WINDOW} that reported it"
            ),
            f64::from(mean),
        );
    }
    if let Some(u) = &s.counters.last_update {
        for (field, v, help) in [
            ("policy_loss", u.policy_loss, "PPO's clipped policy loss"),
            ("value_loss", u.value_loss, "PPO's value loss"),
            ("entropy", u.entropy, "the policy's entropy (nats)"),
            (
                "approx_kl",
                u.approx_kl,
                "approximate KL divergence from the acting policy",
            ),
            (
                "clip_fraction",
                u.clip_fraction,
                "share of samples whose ratio was clipped",
            ),
            (
                "explained_variance",
                u.explained_variance,
                "variance of the returns the critic explains",
            ),
            (
                "grad_norm",
                u.grad_norm,
                "global gradient norm before clipping",
            ),
            (
                "mean_policy_lag",
                u.mean_policy_lag,
                "mean policy versions between acting and training",
            ),
        ] {
            gauge(
                &mut r,
                &format!("ppo_{field}"),
                &format!("Latest policy update: {help}"),
                f64::from(v),
            );
        }
    }
    if let Some(u) = &s.counters.last_unet {
        for (field, v, help) in [
            ("train_loss", u.train_loss, "training loss"),
            (
                "validation_loss",
                u.candidate_loss,
                "the candidate's validation loss",
            ),
            (
                "validation_iou",
                u.candidate_iou,
                "the candidate's validation IoU",
            ),
            (
                "deployed_validation_loss",
                u.deployed_loss,
                "the deployed network's validation loss",
            ),
            (
                "deployed_validation_iou",
                u.deployed_iou,
                "the deployed network's validation IoU",
            ),
        ] {
            gauge(
                &mut r,
                &format!("unet_{field}"),
                &format!("Latest U-Net round: {help}"),
                f64::from(v),
            );
        }
    }
    validation_families(&mut r, s);
    r.register(
        "ppo_update_duration_seconds",
        "Time one PPO update took (every epoch and minibatch of one batch)",
        timings.ppo_update.clone(),
    );
    r.register(
        "unet_round_duration_seconds",
        "Time one U-Net round took (training steps, validation, calibration)",
        timings.unet_round.clone(),
    );

    let mut out = String::new();
    // Writing into a String cannot fail.
    let _ = prometheus_client::encoding::text::encode(&mut out, &r);
    out
}

/// The background validation scorer's counts and the newest checkpoint's
/// scores on the validation rooms, per affordance.
fn validation_families(r: &mut Registry, s: &StatusSnapshot) {
    let v = &s.validation;
    counter(
        r,
        "validation_checkpoints_scored",
        "Checkpoints scored on the validation rooms in the background",
        v.scored,
    );
    counter(
        r,
        "validation_checkpoints_skipped",
        "Checkpoints not scored because a newer one came while they waited",
        v.skipped,
    );
    counter(
        r,
        "validation_failures",
        "Background scorings that failed (logs/validation-scorer.log says why)",
        v.failed,
    );
    let Some(last) = &v.last else {
        return;
    };
    gauge(
        r,
        "validation_step",
        "Environment step of the newest checkpoint scored on the validation rooms",
        last.step as f64,
    );
    for (name, help, value) in [
        (
            "validation_pixel_f1",
            "Newest scored checkpoint, validation rooms: median pixel F1 (Table 1)",
            (|a: &proto::AffordanceScores| a.pixel_f1) as fn(&proto::AffordanceScores) -> _,
        ),
        (
            "validation_object_f1",
            "Newest scored checkpoint, validation rooms: object-level F1 (Table 2)",
            |a| a.object_f1,
        ),
        (
            "validation_object_auc",
            "Newest scored checkpoint, validation rooms: object-level ROC AUC (Table 2)",
            |a| a.object_auc,
        ),
    ] {
        let family = Family::<AffordanceLabel, Gauge<f64, AtomicU64>>::default();
        for a in &last.affordances {
            if let Some(x) = value(a) {
                family
                    .get_or_create(&AffordanceLabel {
                        affordance: a.affordance.clone(),
                    })
                    .set(f64::from(x));
            }
        }
        r.register(name, help, family);
    }
}

/// The classic Prometheus text format (0.0.4) of OpenMetrics text from
/// [`render`]: a counter's `# HELP` and `# TYPE` name its `_total` sample,
/// `# UNIT` and `# EOF` go, and so do `_created` samples.
pub fn to_classic(openmetrics: &str) -> String {
    let mut counters = std::collections::HashSet::new();
    for line in openmetrics.lines() {
        if let Some(name) = line
            .strip_prefix("# TYPE ")
            .and_then(|rest| rest.strip_suffix(" counter"))
        {
            counters.insert(name.to_string());
        }
    }
    let mut out = String::with_capacity(openmetrics.len());
    for line in openmetrics.lines() {
        if line == "# EOF" || line.starts_with("# UNIT ") {
            continue;
        }
        let renamed = ["# HELP ", "# TYPE "].iter().find_map(|prefix| {
            let rest = line.strip_prefix(prefix)?;
            let (name, tail) = rest.split_once(' ')?;
            counters
                .contains(name)
                .then(|| format!("{prefix}{name}_total {tail}"))
        });
        match renamed {
            Some(line) => out.push_str(&line),
            None if counters.iter().any(|c| {
                line.strip_prefix(c.as_str())
                    .is_some_and(|rest| rest.starts_with("_created"))
            }) =>
            {
                continue
            }
            None => out.push_str(line),
        }
        out.push('\n');
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::status::LearnerStatus;

    #[test]
    fn every_metric_the_grafana_dashboard_plots_is_served() {
        let mut status = LearnerStatus::new("run".into());
        let mut stats = proto::EpisodeStats::new(1, 100, 0);
        for field in proto::StatKey::all() {
            stats = stats.with(field, 0.5);
        }
        status.add_episode(&stats);
        let _ = status.accept(0, proto::MessageKind::Rollout, 1, 0);
        status.reject(proto::MessageKind::Rollout, "bad_magic");
        status.counters.last_update = Some(Default::default());
        status.counters.last_unet = Some(training::affordance_learner::UnetRound {
            steps: 8,
            train_loss: 0.5,
            candidate_loss: 0.5,
            candidate_iou: 0.5,
            deployed_loss: 0.5,
            deployed_iou: 0.5,
            replaced: true,
            temperature: 1.0,
            frames: (1, 1, 1),
            positive_frames: vec![1],
            seconds: Default::default(),
        });
        status.timings.ppo_update.observe(0.2);
        let served = to_classic(&render(&status.snapshot(10.0), &status.timings));
        let dashboard = std::fs::read_to_string(
            std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("../deploy/grafana-dashboard.json"),
        )
        .unwrap();
        let dashboard: serde_json::Value = serde_json::from_str(&dashboard).unwrap();
        let mut names = Vec::new();
        for panel in dashboard["panels"].as_array().unwrap() {
            for target in panel["targets"].as_array().unwrap() {
                let expr = target["expr"].as_str().unwrap();
                let mut rest = expr;
                while let Some(at) = rest.find("afx_") {
                    let name: String = rest[at..]
                        .chars()
                        .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                        .collect();
                    rest = &rest[at + name.len()..];
                    names.push(name);
                }
            }
        }
        assert!(names.len() >= 15, "{names:?}");
        for name in names {
            assert!(
                served
                    .lines()
                    .any(|l| l.starts_with(&format!("{name} "))
                        || l.starts_with(&format!("{name}{{"))),
                "the dashboard plots {name}, which /metrics does not serve:\n{served}"
            );
        }
    }

    #[test]
    fn the_classic_format_names_each_counters_total_and_drops_openmetrics_lines() {
        let openmetrics = "# HELP afx_env_steps Environment steps.\n\
                           # TYPE afx_env_steps counter\n\
                           afx_env_steps_total 12\n\
                           afx_env_steps_created 1.7e9\n\
                           # HELP afx_uptime_seconds Seconds.\n\
                           # TYPE afx_uptime_seconds gauge\n\
                           # UNIT afx_uptime_seconds seconds\n\
                           afx_uptime_seconds 3.5\n\
                           # EOF\n";
        assert_eq!(
            to_classic(openmetrics),
            "# HELP afx_env_steps_total Environment steps.\n\
             # TYPE afx_env_steps_total counter\n\
             afx_env_steps_total 12\n\
             # HELP afx_uptime_seconds Seconds.\n\
             # TYPE afx_uptime_seconds gauge\n\
             afx_uptime_seconds 3.5\n"
        );
    }
}
