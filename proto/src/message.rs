//! Encoding whole messages and the one validating decoder.

use crate::frames::FrameBatchView;
use crate::header::{MessageHeader, MessageKind, HEADER_LEN, LEARNER_ID, MAGIC, SCHEMA_VERSION};
use crate::join::{Join, JoinKey};
use crate::payload::Payload;
use crate::rollout::RolloutView;
use crate::stats::EpisodeStats;
use crate::weights::WeightsView;
use crate::ProtoError;

/// Receiver-side limits that [`decode`] enforces on top of the layout rules.
#[derive(Debug, Clone, Copy)]
pub struct Limits {
    /// Actor ids must be `< max_actors`.
    pub max_actors: u32,
    /// Largest payload accepted, in bytes.
    pub max_payload_len: u64,
}

/// A validated message, borrowing the buffer it was decoded from.
#[derive(Debug)]
pub enum Message<'a> {
    /// See [`RolloutView`].
    Rollout(RolloutView<'a>),
    /// See [`FrameBatchView`].
    Frames(FrameBatchView<'a>),
    /// See [`EpisodeStats`] (boxed: it is the largest by far, and the
    /// rarest).
    Stats(Box<EpisodeStats>),
    /// See [`WeightsView`].
    Weights(WeightsView<'a>),
    /// See [`Join`].
    Join(Join),
}

impl Message<'_> {
    /// The kind of this message.
    pub fn kind(&self) -> MessageKind {
        match self {
            Message::Rollout(_) => MessageKind::Rollout,
            Message::Frames(_) => MessageKind::Frames,
            Message::Stats(_) => MessageKind::Stats,
            Message::Weights(_) => MessageKind::Weights,
            Message::Join(_) => MessageKind::Join,
        }
    }
}

/// Total encoded size of a message carrying `payload`.
pub fn encoded_len<P: Payload>(payload: &P) -> usize {
    HEADER_LEN + payload.payload_len()
}

/// Writes header and payload into `out` (at least [`encoded_len`] bytes, e.g. a
/// loaned shared-memory buffer). The caller's `header` supplies actor id,
/// versions and sequence; magic, schema version, kind, length and checksum are
/// filled in here. Returns the number of bytes written.
///
/// # Panics
/// If `out` is shorter than [`encoded_len`]: a programming error on the sender.
pub fn encode_into<P: Payload>(payload: &P, header: MessageHeader, out: &mut [u8]) -> usize {
    let len = payload.payload_len();
    let (head, rest) = out.split_at_mut(HEADER_LEN);
    let body = &mut rest[..len];
    payload.write_payload(body);
    MessageHeader {
        magic: MAGIC,
        schema_version: SCHEMA_VERSION,
        kind: P::KIND as u16,
        checksum: crc32fast::hash(body),
        payload_len: len as u64,
        ..header
    }
    .write(head);
    HEADER_LEN + len
}

/// Encodes into a new buffer; see [`encode_into`].
pub fn encode<P: Payload>(payload: &P, header: MessageHeader) -> Vec<u8> {
    let mut out = vec![0u8; encoded_len(payload)];
    encode_into(payload, header, &mut out);
    out
}

/// Validates everything about `bytes` that does not need the payload read:
/// header length, magic, schema version, kind, sender id, payload length
/// against the header and the limit. Returns the header and its kind.
///
/// For a relay that passes messages on to a receiver which [`decode`]s
/// them (a gateway between hosts): it routes by the header and leaves the
/// checksum and the payload's layout to the receiver, instead of reading
/// every byte once more. Never panics on any input.
pub fn decode_header(
    bytes: &[u8],
    limits: &Limits,
) -> Result<(MessageHeader, MessageKind), ProtoError> {
    let header = MessageHeader::read(bytes)?;
    if header.magic != MAGIC {
        return Err(ProtoError::BadMagic(header.magic));
    }
    if header.schema_version != SCHEMA_VERSION {
        return Err(ProtoError::BadVersion {
            got: header.schema_version,
            expected: SCHEMA_VERSION,
        });
    }
    let kind = MessageKind::from_wire(header.kind)?;
    check_sender(kind, header.actor_id, limits)?;
    let payload_len = bytes.len() - HEADER_LEN;
    if header.payload_len != payload_len as u64 {
        return Err(ProtoError::PayloadLengthMismatch {
            declared: header.payload_len,
            actual: payload_len,
        });
    }
    if header.payload_len > limits.max_payload_len {
        return Err(ProtoError::PayloadTooLarge {
            len: header.payload_len,
            limit: limits.max_payload_len,
        });
    }
    Ok((header, kind))
}

/// Validates `bytes` completely and returns a typed view.
///
/// Checks, in order: what [`decode_header`] checks, then the checksum, then
/// the kind-specific layout and values. Never panics on any input.
pub fn decode<'a>(
    bytes: &'a [u8],
    limits: &Limits,
) -> Result<(MessageHeader, Message<'a>), ProtoError> {
    let (header, kind) = decode_header(bytes, limits)?;
    let payload = &bytes[HEADER_LEN..];
    let actual = crc32fast::hash(payload);
    if actual != header.checksum {
        return Err(ProtoError::BadChecksum {
            declared: header.checksum,
            actual,
        });
    }
    let message = match kind {
        MessageKind::Rollout => Message::Rollout(RolloutView::parse(payload)?),
        MessageKind::Frames => Message::Frames(FrameBatchView::parse(payload)?),
        MessageKind::Stats => Message::Stats(Box::new(EpisodeStats::parse(payload)?)),
        MessageKind::Weights => Message::Weights(WeightsView::parse(payload)?),
        MessageKind::Join => Message::Join(Join::parse(payload)?),
    };
    Ok((header, message))
}

/// Validates a weights message like [`decode`] and then its signature: the
/// only way an actor should read weights.
pub fn decode_weights<'a>(
    bytes: &'a [u8],
    limits: &Limits,
    key: &JoinKey,
) -> Result<(MessageHeader, WeightsView<'a>), ProtoError> {
    let (header, message) = decode(bytes, limits)?;
    let Message::Weights(weights) = message else {
        return Err(ProtoError::WrongKind {
            expected: MessageKind::Weights,
            got: message.kind(),
        });
    };
    if !weights.is_signed_by(key, &header) {
        return Err(ProtoError::BadSignature);
    }
    Ok((header, weights))
}

fn check_sender(kind: MessageKind, actor_id: u32, limits: &Limits) -> Result<(), ProtoError> {
    match kind {
        MessageKind::Weights if actor_id != LEARNER_ID => Err(ProtoError::OutOfRange {
            field: "actor_id",
            value: actor_id.into(),
            allowed: "weights come only from the learner (u32::MAX)",
        }),
        MessageKind::Weights => Ok(()),
        _ if actor_id >= limits.max_actors => Err(ProtoError::OutOfRange {
            field: "actor_id",
            value: actor_id.into(),
            allowed: "below the configured max_actors",
        }),
        _ => Ok(()),
    }
}
