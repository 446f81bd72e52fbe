//! The state the receive loop, the training threads and the HTTP edge share:
//! the live status, the shutdown flag, the configuration and the run
//! directory. Its own module, so the loop and its workers depend on it
//! rather than on each other.

use std::sync::atomic::AtomicBool;
use std::sync::{Mutex, MutexGuard};

use crate::config::LearnerConfig;
use crate::status::LearnerStatus;

/// State shared between the training loop and the HTTP edge.
pub struct Shared {
    /// The live status.
    pub status: Mutex<LearnerStatus>,
    /// Set on SIGINT/SIGTERM; the loop checkpoints and returns.
    pub shutdown: AtomicBool,
    /// The resolved configuration.
    pub config: LearnerConfig,
    /// The run directory (its `history.jsonl` backs `/api/history`).
    pub run_dir: std::path::PathBuf,
}

impl Shared {
    /// Locks the status; a poisoned lock (a panicked thread) still yields the data.
    pub fn status(&self) -> MutexGuard<'_, LearnerStatus> {
        self.status
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
    }
}
