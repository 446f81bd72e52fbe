//! The fixed header that starts every message.

use crate::arrays::{read_u32, read_u64};
use crate::ProtoError;

/// `b"AFX1"` read as a little-endian `u32`: marks our messages.
pub const MAGIC: u32 = u32::from_le_bytes(*b"AFX1");
/// Bumped whenever any layout in this crate changes.
pub const SCHEMA_VERSION: u16 = 10;
/// The `actor_id` the learner writes into the messages it sends.
pub const LEARNER_ID: u32 = u32::MAX;
/// Encoded size of [`MessageHeader`] in bytes.
pub const HEADER_LEN: usize = std::mem::size_of::<MessageHeader>();

/// What a message carries; one kind per service.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u16)]
pub enum MessageKind {
    /// A chunk of consecutive environment steps (actor → learner).
    Rollout = 1,
    /// Labelled frames of a finished episode (actor → learner).
    Frames = 2,
    /// Metrics of a finished episode (actor → learner).
    Stats = 3,
    /// Versioned network parameters (learner → actors).
    Weights = 4,
    /// An actor's proof that it may speak for its id (actor → learner, on
    /// the stats service; see [`crate::Join`]).
    Join = 5,
}

impl MessageKind {
    /// All kinds, in wire order.
    pub const ALL: [MessageKind; 5] = [
        MessageKind::Rollout,
        MessageKind::Frames,
        MessageKind::Stats,
        MessageKind::Weights,
        MessageKind::Join,
    ];

    /// Parses the wire value.
    pub fn from_wire(value: u16) -> Result<Self, ProtoError> {
        match value {
            1 => Ok(Self::Rollout),
            2 => Ok(Self::Frames),
            3 => Ok(Self::Stats),
            4 => Ok(Self::Weights),
            5 => Ok(Self::Join),
            other => Err(ProtoError::UnknownKind(other)),
        }
    }

    /// Lower-case name used in metrics labels and logs.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Rollout => "rollout",
            Self::Frames => "frames",
            Self::Stats => "stats",
            Self::Weights => "weights",
            Self::Join => "join",
        }
    }
}

/// The first [`HEADER_LEN`] bytes of every message, little-endian on the wire.
///
/// `#[repr(C)]` with fields ordered so there is no padding: the in-memory
/// layout and the wire layout coincide on little-endian machines, but encoding
/// and decoding go field by field so nothing depends on alignment.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[repr(C)]
pub struct MessageHeader {
    /// Always [`MAGIC`].
    pub magic: u32,
    /// Always [`SCHEMA_VERSION`] for messages this build accepts.
    pub schema_version: u16,
    /// A [`MessageKind`] wire value.
    pub kind: u16,
    /// Sending actor, or [`LEARNER_ID`] for the learner.
    pub actor_id: u32,
    /// CRC-32 (IEEE) of the payload bytes.
    pub checksum: u32,
    /// Policy version the data was produced with (or is, for weights).
    pub policy_version: u64,
    /// U-Net version the data was produced with (or is, for weights).
    pub unet_version: u64,
    /// Per-sender, per-kind sequence number; gaps reveal dropped messages.
    pub sequence: u64,
    /// Number of payload bytes after the header.
    pub payload_len: u64,
}

impl MessageHeader {
    /// Writes the header into the first [`HEADER_LEN`] bytes of `out`.
    pub(crate) fn write(&self, out: &mut [u8]) {
        out[0..4].copy_from_slice(&self.magic.to_le_bytes());
        out[4..6].copy_from_slice(&self.schema_version.to_le_bytes());
        out[6..8].copy_from_slice(&self.kind.to_le_bytes());
        out[8..12].copy_from_slice(&self.actor_id.to_le_bytes());
        out[12..16].copy_from_slice(&self.checksum.to_le_bytes());
        out[16..24].copy_from_slice(&self.policy_version.to_le_bytes());
        out[24..32].copy_from_slice(&self.unet_version.to_le_bytes());
        out[32..40].copy_from_slice(&self.sequence.to_le_bytes());
        out[40..48].copy_from_slice(&self.payload_len.to_le_bytes());
    }

    /// Reads the header fields without judging them.
    pub(crate) fn read(bytes: &[u8]) -> Result<Self, ProtoError> {
        if bytes.len() < HEADER_LEN {
            return Err(ProtoError::Truncated {
                what: "message header",
                needed: HEADER_LEN,
                got: bytes.len(),
            });
        }
        Ok(Self {
            magic: read_u32(bytes, 0),
            schema_version: u16::from_le_bytes([bytes[4], bytes[5]]),
            kind: u16::from_le_bytes([bytes[6], bytes[7]]),
            actor_id: read_u32(bytes, 8),
            checksum: read_u32(bytes, 12),
            policy_version: read_u64(bytes, 16),
            unet_version: read_u64(bytes, 24),
            sequence: read_u64(bytes, 32),
            payload_len: read_u64(bytes, 40),
        })
    }

    /// The kind, once [`crate::decode`] has accepted the header.
    pub fn message_kind(&self) -> Result<MessageKind, ProtoError> {
        MessageKind::from_wire(self.kind)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_has_no_padding_and_round_trips() {
        assert_eq!(HEADER_LEN, 48);
        let h = MessageHeader {
            magic: MAGIC,
            schema_version: SCHEMA_VERSION,
            kind: 3,
            actor_id: 7,
            checksum: 0xdead_beef,
            policy_version: 11,
            unet_version: 12,
            sequence: 13,
            payload_len: 14,
        };
        let mut buf = [0u8; HEADER_LEN];
        h.write(&mut buf);
        assert_eq!(&buf[0..4], b"AFX1");
        assert_eq!(MessageHeader::read(&buf).unwrap(), h);
    }
}
