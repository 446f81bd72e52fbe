//! Every way a message can be malformed, as one typed error.

use crate::header::MessageKind;

/// Why a message was rejected. The variant names the first check that failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ProtoError {
    /// Fewer bytes than the fixed header or a fixed sub-header needs.
    #[error("message truncated: need {needed} bytes for the {what}, got {got}")]
    Truncated {
        /// Which part could not be read.
        what: &'static str,
        /// Bytes that part needs.
        needed: usize,
        /// Bytes available.
        got: usize,
    },
    /// The first four bytes are not [`crate::MAGIC`].
    #[error("bad magic 0x{0:08x}: not an affordance-explorer message")]
    BadMagic(u32),
    /// Written by a different schema version of this crate.
    #[error("schema version {got} not supported (this build speaks {expected})")]
    BadVersion {
        /// Version in the header.
        got: u16,
        /// Version this build writes.
        expected: u16,
    },
    /// The kind field names no known message kind.
    #[error("unknown message kind {0}")]
    UnknownKind(u16),
    /// A valid kind arrived on a service that carries another kind.
    #[error("expected a {expected:?} message, got {got:?}")]
    WrongKind {
        /// Kind the service carries.
        expected: MessageKind,
        /// Kind in the header.
        got: MessageKind,
    },
    /// The header's payload length disagrees with the bytes that follow it.
    #[error("payload length {declared} in the header, but {actual} bytes follow it")]
    PayloadLengthMismatch {
        /// Length in the header.
        declared: u64,
        /// Bytes after the header.
        actual: usize,
    },
    /// The payload is larger than this receiver accepts.
    #[error("payload of {len} bytes exceeds the limit of {limit}")]
    PayloadTooLarge {
        /// Payload length.
        len: u64,
        /// Configured limit.
        limit: u64,
    },
    /// CRC-32 of the payload disagrees with the header.
    #[error("payload checksum 0x{actual:08x} does not match header 0x{declared:08x}")]
    BadChecksum {
        /// Checksum in the header.
        declared: u32,
        /// Checksum of the bytes received.
        actual: u32,
    },
    /// The payload's own sub-header declares sizes that do not add up to its length.
    #[error("{what}: layout needs {expected} bytes, payload has {actual}")]
    LayoutMismatch {
        /// Which payload.
        what: &'static str,
        /// Bytes the declared sizes need.
        expected: u64,
        /// Bytes present.
        actual: u64,
    },
    /// A count, id or enum value lies outside its allowed range.
    #[error("{field} = {value} out of range ({allowed})")]
    OutOfRange {
        /// Field name.
        field: &'static str,
        /// Value found.
        value: u64,
        /// Human-readable allowed range.
        allowed: &'static str,
    },
    /// A float that must be finite (or within a range) is not.
    #[error("{field}[{index}] = {value} is not allowed (must be finite{extra})")]
    BadFloat {
        /// Field name.
        field: &'static str,
        /// Element index.
        index: usize,
        /// Value found.
        value: f32,
        /// Extra constraint, e.g. ", in [0, 1]".
        extra: &'static str,
    },
    /// An action was taken that its own action mask forbids.
    #[error("step {step}: action {action} is masked out")]
    MaskedAction {
        /// Step index in the chunk.
        step: usize,
        /// Action index.
        action: u32,
    },
    /// The weights payload is not a valid safetensors file.
    #[error("weights blob is not valid safetensors: {0}")]
    BadWeights(String),
    /// The weights' signature was not made with the run's key for this
    /// header: a publisher other than the run's learner sent them.
    #[error("the weights are not signed with the run's key (sent by something other than this run's learner)")]
    BadSignature,
}

impl ProtoError {
    /// A short stable name for the failed check, for metrics labels.
    pub fn reason(&self) -> &'static str {
        match self {
            ProtoError::Truncated { .. } => "truncated",
            ProtoError::BadMagic(_) => "bad_magic",
            ProtoError::BadVersion { .. } => "bad_version",
            ProtoError::UnknownKind(_) => "unknown_kind",
            ProtoError::WrongKind { .. } => "wrong_kind",
            ProtoError::PayloadLengthMismatch { .. } => "length_mismatch",
            ProtoError::PayloadTooLarge { .. } => "too_large",
            ProtoError::BadChecksum { .. } => "bad_checksum",
            ProtoError::LayoutMismatch { .. } => "layout_mismatch",
            ProtoError::OutOfRange { .. } => "out_of_range",
            ProtoError::BadFloat { .. } => "bad_float",
            ProtoError::MaskedAction { .. } => "masked_action",
            ProtoError::BadWeights(_) => "bad_weights",
            ProtoError::BadSignature => "bad_signature",
        }
    }
}
