//! The transport's one error type.

/// A failure to open or use a shared-memory port, with what was being done.
#[derive(Debug, thiserror::Error)]
#[error("iceoryx2: {action} {subject:?} failed: {detail}. If an earlier run crashed, run `learner clean` (or start the learner, which cleans up) and check that all processes use the same transport settings")]
pub struct TransportError {
    /// What was being done.
    pub action: &'static str,
    /// The service, node or port concerned.
    pub subject: String,
    /// iceoryx2's error, formatted.
    pub detail: String,
    /// Whether every publisher slot of the service was taken: a condition
    /// that heals when a holder ends (a supervisor retries), not a setup error.
    pub slots_taken: bool,
}

/// Exit status of an actor that could not join because every publisher
/// slot of a service was taken (EX_TEMPFAIL): `deploy/supervise.sh`
/// retries it with back-off rather than stopping the run.
pub const SLOTS_TAKEN_EXIT: i32 = 75;

impl TransportError {
    pub(crate) fn new(action: &'static str, subject: &str, detail: impl std::fmt::Debug) -> Self {
        Self {
            action,
            subject: subject.to_string(),
            detail: format!("{detail:?}"),
            slots_taken: false,
        }
    }

    /// A failure whose `detail` is already an explanation in words.
    pub(crate) fn explained(action: &'static str, subject: &str, detail: String) -> Self {
        Self {
            action,
            subject: subject.to_string(),
            detail,
            slots_taken: false,
        }
    }
}
