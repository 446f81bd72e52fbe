//! A running episode's bookkeeping, and how a rollout chunk that goes out
//! closes.

use std::time::Instant;

use proto::RolloutChunk;

use crate::env::Observation;

/// The bookkeeping of one running episode.
pub(super) struct RunningEpisode {
    pub(super) id: u64,
    pub(super) steps: u32,
    pub(super) episode_return: f32,
    pub(super) started: Instant,
    /// The actor's steps (all environments) when the episode started.
    pub(super) actor_steps_at_start: u64,
    pub(super) observation: Observation,
    /// The GRU state before the next step; `None` = zeros (episode start).
    pub(super) hidden: Option<Vec<f32>>,
    pub(super) chunk: RolloutChunk,
}

/// How a rollout chunk that goes out now ends.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum ChunkClose {
    /// With its episode's last step (nothing to bootstrap from).
    EpisodeEnd,
    /// Mid-episode: it bootstraps from the critic's value of the episode's
    /// next observation, given here when the policy's pass that chose the
    /// next action made it already (otherwise the loop runs the critic).
    Cut(Option<f32>),
}

impl ChunkClose {
    /// How a chunk closes after a step that ended its episode or not
    /// (`done`); `next_value` is the critic's value of the observation
    /// that step led to, if known.
    pub(super) fn after(done: bool, next_value: Option<f32>) -> Self {
        if done {
            ChunkClose::EpisodeEnd
        } else {
            ChunkClose::Cut(next_value)
        }
    }
}
