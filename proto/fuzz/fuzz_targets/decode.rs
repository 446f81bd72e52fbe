//! Fuzzes the message decoder: any byte string must decode or be rejected, never panic.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let limits = proto::Limits { max_actors: 64, max_payload_len: 1 << 24 };
    if let Ok((header, message)) = proto::decode(data, &limits) {
        // An accepted message must be internally consistent.
        assert_eq!(header.payload_len as usize + proto::HEADER_LEN, data.len());
        assert_eq!(header.message_kind().ok(), Some(message.kind()));
    }
});
