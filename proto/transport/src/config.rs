//! Every transport limit, with defaults, in one serde struct.

use serde::{Deserialize, Serialize};

/// Limits of the shared-memory services. Learner and actors must use the same
/// values (the learner prints them at start; `deploy/local.sh` passes one
/// config to all processes).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, documented::DocumentedFields)]
#[serde(default, deny_unknown_fields)]
pub struct TransportConfig {
    /// Prefix of every service name; one per run so runs never mix.
    pub service_prefix: String,
    /// Most actors that may connect; actor ids are `0..max_actors`.
    pub max_actors: u32,
    /// Extra ports per service beyond the actors and the learner (recorders, CLI tools).
    pub spare_ports: u32,
    /// Largest rollout message in bytes (header included); sizes the pools.
    pub max_rollout_bytes: usize,
    /// Largest labelled-frames message in bytes.
    pub max_frames_bytes: usize,
    /// Largest episode-stats message in bytes.
    pub max_stats_bytes: usize,
    /// Largest weights message in bytes.
    pub max_weights_bytes: usize,
    /// Messages the learner buffers per actor→learner service before newer ones are dropped.
    pub learner_buffer: usize,
}

impl Default for TransportConfig {
    fn default() -> Self {
        Self {
            service_prefix: proto::service::DEFAULT_PREFIX.to_string(),
            max_actors: 16,
            spare_ports: 2,
            max_rollout_bytes: 16 << 20,
            max_frames_bytes: 32 << 20,
            // The largest stats message (every metric, the most tries by
            // object type with the longest names) is ~12 KiB.
            max_stats_bytes: 16 << 10,
            max_weights_bytes: 16 << 20,
            learner_buffer: 8,
        }
    }
}

impl TransportConfig {
    /// Largest message on the service that carries `kind`.
    pub fn max_bytes(&self, kind: proto::MessageKind) -> usize {
        match kind {
            proto::MessageKind::Rollout => self.max_rollout_bytes,
            proto::MessageKind::Frames => self.max_frames_bytes,
            proto::MessageKind::Stats | proto::MessageKind::Join => self.max_stats_bytes,
            proto::MessageKind::Weights => self.max_weights_bytes,
        }
    }

    /// Nodes that may attach to one service: the actors, the learner, spares.
    pub(crate) fn max_nodes(&self) -> usize {
        self.max_actors as usize + 1 + self.spare_ports as usize
    }

    /// Subscribers on an actor→learner service: the learner plus spares.
    pub(crate) fn upstream_subscribers(&self) -> usize {
        1 + self.spare_ports as usize
    }

    /// One line per limit, for the start-up banner.
    pub fn describe(&self) -> String {
        format!(
            "transport: prefix {:?}, max_actors {}, spare_ports {}, max message bytes rollout {} / frames {} / stats {} / weights {}, learner buffer {} per service, weights history 1",
            self.service_prefix,
            self.max_actors,
            self.spare_ports,
            self.max_rollout_bytes,
            self.max_frames_bytes,
            self.max_stats_bytes,
            self.max_weights_bytes,
            self.learner_buffer
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proto::{
        Affordance, AffordanceStat, EpisodeStats, StatKey, TypeTries, MAX_TYPE_NAME, MAX_TYPE_TRIES,
    };

    #[test]
    fn the_largest_stats_message_fits_the_default_limit() {
        let every_metric =
            StatKey::all().fold(EpisodeStats::new(1, 600, 0), |s, key| s.with(key, 0.5));
        assert!(matches!(
            StatKey::all().last(),
            Some(StatKey::Affordance(_, AffordanceStat::NegativeLabelRecall))
        ));
        let longest = (0..MAX_TYPE_TRIES).map(|i| TypeTries {
            affordance: Affordance::ALL[i % Affordance::COUNT],
            object_type: format!("{i:0width$}", width = MAX_TYPE_NAME),
            attempts: 1,
            successes: 1,
            objects: 1,
        });
        let largest = every_metric.with_tries(longest);
        assert_eq!(largest.tries().len(), MAX_TYPE_TRIES);
        let len = proto::encoded_len(&largest);
        let limit = TransportConfig::default().max_stats_bytes;
        assert!(len <= limit, "{len} bytes against a limit of {limit}");
    }
}
