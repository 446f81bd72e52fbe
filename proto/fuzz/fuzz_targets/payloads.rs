//! Fuzzes the payload parsers behind the decoder's checksum: the first byte
//! picks the kind, the rest is the payload, and the header is made valid
//! around it (magic, version, length, the payload's CRC-32), so every input
//! reaches the layout checks of rollouts, frames, stats, weights and joins.
//! Any payload must parse or be refused, never panic.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Some((&selector, payload)) = data.split_first() else {
        return;
    };
    let kind = proto::MessageKind::ALL[usize::from(selector) % proto::MessageKind::ALL.len()];
    let actor_id = if kind == proto::MessageKind::Weights {
        proto::LEARNER_ID
    } else {
        u32::from(selector >> 4)
    };
    let mut bytes = Vec::with_capacity(proto::HEADER_LEN + payload.len());
    bytes.extend_from_slice(&proto::MAGIC.to_le_bytes());
    bytes.extend_from_slice(&proto::SCHEMA_VERSION.to_le_bytes());
    bytes.extend_from_slice(&(kind as u16).to_le_bytes());
    bytes.extend_from_slice(&actor_id.to_le_bytes());
    bytes.extend_from_slice(&crc32fast::hash(payload).to_le_bytes());
    bytes.extend_from_slice(&[0u8; 24]); // versions and sequence
    bytes.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    assert_eq!(bytes.len(), proto::HEADER_LEN);
    bytes.extend_from_slice(payload);
    let limits = proto::Limits {
        max_actors: 64,
        max_payload_len: 1 << 24,
    };
    if let Ok((header, message)) = proto::decode(&bytes, &limits) {
        assert_eq!(message.kind(), kind);
        let key = proto::JoinKey::from_bytes([7; proto::JOIN_KEY_LEN]);
        match message {
            proto::Message::Join(join) => {
                let _ = join.verify(&key, actor_id);
            }
            proto::Message::Weights(weights) => {
                let _ = weights.is_signed_by(&key, &header);
            }
            _ => {}
        }
    }
});
