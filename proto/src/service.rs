//! Service names shared by every process.
//!
//! A run uses one prefix (e.g. `afx/run-2026-11-22`) so two runs on one host
//! never see each other's messages.

use crate::MessageKind;

/// Actor → learner: rollout chunks.
pub const ROLLOUTS: &str = "rollouts";
/// Actor → learner: labelled frames of finished episodes.
pub const FRAMES: &str = "frames";
/// Actor → learner: per-episode metrics.
pub const STATS: &str = "stats";
/// Learner → actors: versioned weights (history 1).
pub const WEIGHTS: &str = "weights";
/// Event: an actor published something (wakes the learner).
pub const LEARNER_WAKEUP: &str = "learner-wakeup";
/// Event: the learner published new weights (wakes waiting actors).
pub const WEIGHTS_READY: &str = "weights-ready";

/// The default prefix when none is configured.
pub const DEFAULT_PREFIX: &str = "afx";

/// Full service name for `suffix` under `prefix`.
pub fn name(prefix: &str, suffix: &str) -> String {
    format!("{prefix}/{suffix}")
}

/// The publish-subscribe service that carries `kind` (joins travel with
/// the stats, the service every actor publishes on least often).
pub fn for_kind(kind: MessageKind) -> &'static str {
    match kind {
        MessageKind::Rollout => ROLLOUTS,
        MessageKind::Frames => FRAMES,
        MessageKind::Stats | MessageKind::Join => STATS,
        MessageKind::Weights => WEIGHTS,
    }
}
