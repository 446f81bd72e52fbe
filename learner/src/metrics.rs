//! Prometheus text rendering of a [`StatusSnapshot`].
//!
//! The registry is built fresh from one snapshot per scrape: nothing is counted
//! twice, and `/metrics` agrees with `/api/status` by construction.

use std::sync::atomic::AtomicU64;

use prometheus_client::encoding::EncodeLabelSet;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::registry::Registry;

use crate::status::StatusSnapshot;

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
struct ActorLabel {
    actor: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct FieldLabel {
    field: String,
}

fn counter(registry: &mut Registry, name: &str, help: &str, value: u64) {
    let c: Counter = Counter::default();
    c.inc_by(value);
    registry.register(name, help, c);
}

fn gauge(registry: &mut Registry, name: &str, help: &str, value: f64) {
    let g: Gauge<f64, AtomicU64> = Gauge::default();
    g.set(value);
    registry.register(name, help, g);
}

/// Renders the snapshot in the Prometheus text exposition format.
pub fn render(s: &StatusSnapshot) -> String {
    let mut r = Registry::with_prefix("afx");
    counter(
        &mut r,
        "env_steps",
        "Environment steps trained on",
        s.env_steps,
    );
    counter(&mut r, "policy_updates", "Policy updates done", s.updates);
    counter(
        &mut r,
        "episodes",
        "Episodes reported by actors",
        s.episodes,
    );
    counter(
        &mut r,
        "weights_published",
        "Weights messages published",
        s.weights_published,
    );
    counter(
        &mut r,
        "checkpoints_written",
        "Checkpoints written by this learner process",
        s.checkpoints_written,
    );
    counter(
        &mut r,
        "untrainable_chunks",
        "Valid rollout chunks whose shapes did not fit the policy",
        s.untrainable_chunks,
    );
    counter(
        &mut r,
        "trained_steps",
        "Environment steps that went into policy updates",
        s.trained_steps,
    );
    counter(
        &mut r,
        "rollout_steps_discarded",
        "Environment steps discarded, oldest first, because the PPO queue was full",
        s.rollout_steps_discarded,
    );
    gauge(
        &mut r,
        "rollout_steps_queued",
        "Environment steps waiting for the PPO thread",
        s.rollout_steps_queued as f64,
    );
    counter(
        &mut r,
        "frames_received",
        "Labelled frames received for U-Net training",
        s.frames_received,
    );
    counter(
        &mut r,
        "frames_skipped",
        "Labelled frames skipped because the U-Net trainer was behind",
        s.frames_skipped,
    );
    counter(
        &mut r,
        "unet_rounds",
        "Rounds of U-Net training (a few steps each, after every episode's frames)",
        s.unet_rounds,
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
        s.policy_version as f64,
    );
    gauge(
        &mut r,
        "unet_version",
        "Current U-Net version",
        s.unet_version as f64,
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
    for a in &s.actors {
        let label = ActorLabel {
            actor: a.id.to_string(),
        };
        lag.get_or_create(&label).set(a.policy_lag as f64);
        last_seen.get_or_create(&label).set(a.last_seen_s);
        actor_steps.get_or_create(&label).inc_by(a.env_steps);
    }
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

    let episode = Family::<FieldLabel, Gauge<f64, AtomicU64>>::default();
    for (field, &v) in &s.last_episode {
        episode
            .get_or_create(&FieldLabel {
                field: field.clone(),
            })
            .set(f64::from(v));
    }
    r.register(
        "last_episode",
        "Metrics of the most recently reported episode",
        episode,
    );

    if let Some(u) = &s.last_update {
        let update = Family::<FieldLabel, Gauge<f64, AtomicU64>>::default();
        for (field, v) in [
            ("policy_loss", u.policy_loss),
            ("value_loss", u.value_loss),
            ("entropy", u.entropy),
            ("approx_kl", u.approx_kl),
            ("clip_fraction", u.clip_fraction),
            ("explained_variance", u.explained_variance),
            ("grad_norm", u.grad_norm),
            ("mean_policy_lag", u.mean_policy_lag),
        ] {
            update
                .get_or_create(&FieldLabel {
                    field: field.into(),
                })
                .set(f64::from(v));
        }
        r.register("ppo", "Statistics of the latest policy update", update);
    }

    if let Some(u) = &s.last_unet {
        let unet = Family::<FieldLabel, Gauge<f64, AtomicU64>>::default();
        for (field, v) in [
            ("train_loss", u.train_loss),
            ("validation_loss", u.candidate_loss),
            ("validation_iou", u.candidate_iou),
            ("deployed_validation_loss", u.deployed_loss),
            ("deployed_validation_iou", u.deployed_iou),
        ] {
            unet.get_or_create(&FieldLabel {
                field: field.into(),
            })
            .set(f64::from(v));
        }
        r.register(
            "unet",
            "Statistics of the latest U-Net training round",
            unet,
        );
    }

    let mut out = String::new();
    // Writing into a String cannot fail.
    let _ = prometheus_client::encoding::text::encode(&mut out, &r);
    out
}
