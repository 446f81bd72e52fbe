//! Fuzzes the message decoder: any byte string must decode or be rejected, never panic.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let limits = proto::Limits {
        max_actors: 64,
        max_payload_len: 1 << 24,
    };
    if let Ok((header, message)) = proto::decode(data, &limits) {
        // An accepted message must be internally consistent.
        assert_eq!(header.payload_len as usize + proto::HEADER_LEN, data.len());
        assert_eq!(header.message_kind().ok(), Some(message.kind()));
        if let proto::Message::Join(join) = message {
            // Checking a join's proof takes any bytes as well.
            let key = proto::JoinKey::from_bytes([7; proto::JOIN_KEY_LEN]);
            let _ = join.verify(&key, header.actor_id);
        }
    }
});
