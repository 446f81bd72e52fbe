//! The Zenoh key expressions of one run: every message of run `R` lives
//! under `afx/R/`, so gateways of different runs on one network never mix.
//!
//! - `afx/R/up/HOST/KIND`: what the actors of host `HOST` send to the
//!   learner (`rollout`, `frames`, `stats`; joins travel with the stats, as
//!   they do in shared memory). One host publishes only under its own name,
//!   which an access-control list can enforce (docs/many-hosts.md).
//! - `afx/R/weights`: the learner's weights, to every actor host.
//! - `afx/R/config`: the run's `config.toml`, answered on request.

use proto::MessageKind;

/// A name that cannot be one chunk of a key expression.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{what} {name:?} must be 1 to 64 characters from A-Z, a-z, 0-9, '.', '_' and '-'")]
pub struct NameError {
    what: &'static str,
    name: String,
}

/// Checks that `name` is safe as one key chunk: no `/`, no wildcard or
/// special characters of Zenoh's key syntax.
pub fn check_name(what: &'static str, name: &str) -> Result<(), NameError> {
    let ok = (1..=64).contains(&name.len())
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'.' | b'_' | b'-'));
    if ok {
        Ok(())
    } else {
        Err(NameError {
            what,
            name: name.to_string(),
        })
    }
}

/// The kinds that travel from actor hosts to the learner's host, each under
/// its own key (joins ride with the stats), in the order a gateway reads
/// them: stats first, so that a new actor's join is seen before the
/// rollouts it sent after it (as the learner reads them).
pub const UPSTREAM: [MessageKind; 3] = [
    MessageKind::Stats,
    MessageKind::Rollout,
    MessageKind::Frames,
];

/// The key expressions of one run.
#[derive(Debug, Clone)]
pub struct RunKeys {
    root: String,
}

impl RunKeys {
    /// The keys of run `run` (checked with [`check_name`]).
    pub fn new(run: &str) -> Result<Self, NameError> {
        check_name("run name", run)?;
        Ok(Self {
            root: format!("afx/{run}"),
        })
    }

    /// Where host `host` publishes messages of `kind` (a join: under stats).
    pub fn upstream(&self, host: &str, kind: MessageKind) -> String {
        let kind = match kind {
            MessageKind::Join => MessageKind::Stats,
            other => other,
        };
        format!("{}/up/{host}/{}", self.root, kind.as_str())
    }

    /// Every host's upstream messages, for the learner's gateway.
    pub fn all_upstream(&self) -> String {
        format!("{}/up/*/*", self.root)
    }

    /// The host and kind of an upstream key, or `None` for any other key.
    pub fn parse_upstream<'k>(&self, key: &'k str) -> Option<(&'k str, MessageKind)> {
        let rest = key.strip_prefix(&self.root)?.strip_prefix("/up/")?;
        let (host, kind) = rest.split_once('/')?;
        check_name("host name", host).ok()?;
        let kind = UPSTREAM.into_iter().find(|k| k.as_str() == kind)?;
        Some((host, kind))
    }

    /// The learner's weights.
    pub fn weights(&self) -> String {
        format!("{}/weights", self.root)
    }

    /// The run's configuration.
    pub fn config(&self) -> String {
        format!("{}/config", self.root)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_with_key_syntax_are_refused() {
        for bad in ["", "a/b", "a*", "$x", "a b", "#", "?", &"x".repeat(65)] {
            assert!(check_name("host name", bad).is_err(), "{bad:?}");
        }
        for good in ["host-1", "gpu_box.03", "A"] {
            check_name("host name", good).unwrap();
        }
    }

    #[test]
    fn upstream_keys_name_their_host_and_kind_and_joins_ride_with_stats() {
        let keys = RunKeys::new("run-7").unwrap();
        assert_eq!(
            keys.upstream("box-2", MessageKind::Rollout),
            "afx/run-7/up/box-2/rollout"
        );
        assert_eq!(
            keys.upstream("box-2", MessageKind::Join),
            "afx/run-7/up/box-2/stats"
        );
        for kind in UPSTREAM {
            let key = keys.upstream("box-2", kind);
            assert_eq!(keys.parse_upstream(&key), Some(("box-2", kind)));
        }
        for foreign in [
            "afx/run-8/up/box-2/rollout",
            "afx/run-7/up/box-2/weights",
            "afx/run-7/up/box-2/rollout/extra",
            "afx/run-7/weights",
            "afx/run-77/up/box-2/rollout",
        ] {
            assert_eq!(keys.parse_upstream(foreign), None, "{foreign}");
        }
    }
}
