//! Weights messages the actor refused. Whatever arrives on the weights
//! service may be wrong (a learner of another task, or a process that is not
//! the learner at all): the actor counts it, says why once per kind of
//! fault, and keeps acting with the weights it has, rather than exiting and
//! taking its environments down with it.

use std::collections::BTreeSet;

/// Kinds of fault reported at most, so that a flood of distinct garbage
/// cannot flood the log.
const MAX_REPORTED: usize = 16;

/// The refused weights messages of one actor.
#[derive(Debug, Default)]
pub(super) struct RejectedWeights {
    count: u64,
    reported: BTreeSet<String>,
    last: Option<String>,
}

impl RejectedWeights {
    /// Counts one refused message; logs `error` (with its causes) the first
    /// time its kind (the outermost context) is seen, and returns whether it
    /// did. `kept` is the policy version the actor goes on with.
    pub(super) fn reject(
        &mut self,
        actor_id: u32,
        error: &anyhow::Error,
        kept: Option<u64>,
    ) -> bool {
        self.count += 1;
        self.last = Some(format!("{error:#}"));
        let new = self.reported.len() < MAX_REPORTED && self.reported.insert(error.to_string());
        if new {
            let keeping = kept.map_or_else(
                || "still waiting for valid weights".to_string(),
                |v| format!("keeping policy version {v}"),
            );
            tracing::warn!(
                "actor {actor_id}: skipped a weights message ({error:#}); {keeping}; \
                 further messages of this kind are only counted"
            );
        }
        new
    }

    /// Messages refused so far.
    pub(super) fn count(&self) -> u64 {
        self.count
    }

    /// Why the newest refused message was refused.
    pub(super) fn last(&self) -> Option<&str> {
        self.last.as_deref()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_kind_of_fault_is_logged_once_and_every_message_counted() {
        let mut rejected = RejectedWeights::default();
        let bad_magic = || anyhow::anyhow!("bad magic").context("the learner sent invalid weights");
        assert!(rejected.reject(0, &bad_magic(), Some(3)));
        assert!(!rejected.reject(0, &bad_magic(), Some(3)));
        let misfit = anyhow::anyhow!("shape").context("the policy does not fit");
        assert!(rejected.reject(0, &misfit, None));
        assert_eq!(rejected.count(), 3);
        assert_eq!(rejected.last(), Some("the policy does not fit: shape"));
        for i in 0..100 {
            rejected.reject(0, &anyhow::anyhow!("garbage {i}"), Some(3));
        }
        assert_eq!(rejected.reported.len(), MAX_REPORTED, "the log is bounded");
        assert_eq!(rejected.count(), 103);
    }
}
