//! The contract between the actor and learner processes.
//!
//! Every message that crosses a process boundary is one byte buffer: a fixed
//! [`MessageHeader`] followed by a kind-specific payload. This crate defines the
//! layouts, writes them, and — most importantly — validates untrusted bytes before
//! anything reads them: [`decode`] returns a typed view or a typed [`ProtoError`],
//! never panics, and never trusts a length it has not checked.
//!
//! This crate must stay small: it knows nothing of shared memory, networks,
//! simulators or neural networks, so that every other crate can depend on it.

mod actors;
mod arrays;
mod error;
mod frames;
mod header;
mod join;
mod ladder;
mod message;
mod method;
mod payload;
mod rollout;
mod rules;
pub mod service;
mod stats;
pub mod task;
#[cfg(test)]
mod third_affordance;
mod type_tries;
mod validation;
mod weights;

pub use actors::{ActorSettings, ActorSettingsError, ACTOR_DEVICES, RENDERERS, TRAINING_SCENES};
pub use arrays::{F32Array, U32Array};
pub use error::ProtoError;
pub use frames::{
    FrameBatch, FrameBatchView, FrameSlices, LABEL_NEGATIVE, LABEL_POSITIVE, LABEL_UNKNOWN,
};
pub use header::{MessageHeader, MessageKind, HEADER_LEN, LEARNER_ID, MAGIC, SCHEMA_VERSION};
pub use join::{Join, JoinKey, JoinKeyError, JOIN_KEY_LEN, JOIN_PAYLOAD_LEN};
pub use ladder::{LabelRung, DATASET_EPISODES_DIR, DATASET_EPISODE_EXTENSION};
pub use message::{
    decode, decode_header, decode_weights, encode, encode_into, encoded_len, Limits, Message,
};
pub use method::{LabelSource, Method, MethodSpec, Selection, GRID_CELLS, HISTORY_STEPS};
pub use payload::Payload;
pub use rollout::{
    byte_to_unit, obs_bytes_from_f32, unit_to_byte, ObsDtype, RolloutChunk, RolloutView,
    BYTE_UNITS, MAX_ACTIONS, MAX_STEPS,
};
pub use rules::{
    CellPreference, ConfidenceRule, MapSegmentation, MapSettings, SelectionRule, SphereRule,
};
pub use stats::{AffordanceStat, EpisodeStats, StatField, StatKey};
pub use task::{Affordance, EnvKind, PolicyLayout, RewardWeights, TaskError, TaskSpec};
pub use type_tries::{TypeTries, MAX_TYPE_NAME, MAX_TYPE_TRIES};
pub use validation::{AffordanceScores, ValidationScores, VALIDATION_DIR};
pub use weights::{
    WeightsBlob, WeightsView, WEIGHTS_META_ENV_STEPS, WEIGHTS_META_HOLD, WEIGHTS_META_TEMPERATURE,
    WEIGHTS_POLICY_PREFIX, WEIGHTS_TAG_LEN, WEIGHTS_UNET_PREFIX,
};
