//! Joining a run (actor → learner, on the stats service).
//!
//! Shared memory tells the learner which publisher a message came through,
//! but anything may write any `actor_id` into a header. So an actor first
//! *joins*: it names the three publishers its rollouts, frames and stats will
//! come from, and proves with an HMAC-SHA256 over those ids that it holds the
//! run's join key (a secret the learner writes into the run directory). The
//! learner then accepts an actor id's messages only from the publishers that
//! joined under it; a replayed join is useless, because the learner also
//! checks that the join itself arrived through the stats publisher it names.

use hmac::{Hmac, Mac};
use sha2::Sha256;

use crate::payload::Payload;
use crate::{MessageKind, ProtoError};

/// Bytes in a [`JoinKey`] and in a join's proof.
pub const JOIN_KEY_LEN: usize = 32;
/// Bytes in a [`Join`] payload: three 128-bit publisher ids and the proof.
pub const JOIN_PAYLOAD_LEN: usize = 3 * 16 + JOIN_KEY_LEN;
/// Domain separation: a proof for this schema means nothing elsewhere.
const PROOF_CONTEXT: &[u8] = b"affordance-explorer join v1";

/// The run's shared secret: whoever holds it may join as any actor id, and
/// the learner signs its weights with it (see [`crate::WeightsBlob`]).
#[derive(Clone, PartialEq, Eq)]
pub struct JoinKey([u8; JOIN_KEY_LEN]);

impl std::fmt::Debug for JoinKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("JoinKey(…)")
    }
}

/// Why a join key's text could not be read.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("a join key is {} hexadecimal digits on one line", 2 * JOIN_KEY_LEN)]
pub struct JoinKeyError;

impl JoinKey {
    /// Wraps secret bytes (from the operating system's random source).
    pub fn from_bytes(bytes: [u8; JOIN_KEY_LEN]) -> Self {
        Self(bytes)
    }

    /// The key as the hexadecimal text stored in a key file.
    pub fn to_hex(&self) -> String {
        hex::encode(self.0)
    }

    /// Reads a key file's text (surrounding whitespace allowed).
    pub fn from_hex(text: &str) -> Result<Self, JoinKeyError> {
        let mut bytes = [0u8; JOIN_KEY_LEN];
        hex::decode_to_slice(text.trim(), &mut bytes).map_err(|_| JoinKeyError)?;
        Ok(Self(bytes))
    }

    /// An HMAC-SHA256 keyed with this key, started with `context` (domain
    /// separation: a tag made for one purpose proves nothing for another).
    pub(crate) fn hmac(&self, context: &[u8]) -> Hmac<Sha256> {
        let mut mac =
            Hmac::<Sha256>::new_from_slice(&self.0).expect("HMAC takes a key of any length");
        mac.update(context);
        mac
    }

    fn mac(&self, actor_id: u32, publishers: &[u128; 3]) -> Hmac<Sha256> {
        let mut mac = self.hmac(PROOF_CONTEXT);
        mac.update(&actor_id.to_le_bytes());
        for id in publishers {
            mac.update(&id.to_le_bytes());
        }
        mac
    }
}

/// A join: the publishers an actor sends through, and the proof that it
/// holds the run's [`JoinKey`]. The header's `actor_id` is the id joined.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Join {
    /// iceoryx2 publisher ids of the actor's rollouts, frames and stats
    /// publishers, in that order.
    pub publishers: [u128; 3],
    proof: [u8; JOIN_KEY_LEN],
}

impl Join {
    /// The join of `actor_id` through `publishers` (rollouts, frames, stats).
    pub fn new(key: &JoinKey, actor_id: u32, publishers: [u128; 3]) -> Self {
        let proof = key
            .mac(actor_id, &publishers)
            .finalize()
            .into_bytes()
            .into();
        Self { publishers, proof }
    }

    /// Whether the proof was made with `key` for `actor_id` and these
    /// publishers (compared in constant time).
    pub fn verify(&self, key: &JoinKey, actor_id: u32) -> bool {
        key.mac(actor_id, &self.publishers)
            .verify_slice(&self.proof)
            .is_ok()
    }

    /// The publisher that carries `kind` for the joined actor (none for
    /// weights, which only the learner sends).
    pub fn publisher(&self, kind: MessageKind) -> Option<u128> {
        Self::publisher_for(&self.publishers, kind)
    }

    /// The publisher among a join's `publishers` that carries `kind`.
    pub fn publisher_for(publishers: &[u128; 3], kind: MessageKind) -> Option<u128> {
        match kind {
            MessageKind::Rollout => Some(publishers[0]),
            MessageKind::Frames => Some(publishers[1]),
            MessageKind::Stats | MessageKind::Join => Some(publishers[2]),
            MessageKind::Weights => None,
        }
    }

    pub(crate) fn parse(payload: &[u8]) -> Result<Self, ProtoError> {
        if payload.len() != JOIN_PAYLOAD_LEN {
            return Err(ProtoError::LayoutMismatch {
                what: "join",
                expected: JOIN_PAYLOAD_LEN as u64,
                actual: payload.len() as u64,
            });
        }
        let id = |i: usize| {
            let mut b = [0u8; 16];
            b.copy_from_slice(&payload[i * 16..(i + 1) * 16]);
            u128::from_le_bytes(b)
        };
        let mut proof = [0u8; JOIN_KEY_LEN];
        proof.copy_from_slice(&payload[48..]);
        Ok(Self {
            publishers: [id(0), id(1), id(2)],
            proof,
        })
    }
}

impl Payload for Join {
    const KIND: MessageKind = MessageKind::Join;

    fn payload_len(&self) -> usize {
        JOIN_PAYLOAD_LEN
    }

    fn write_payload(&self, out: &mut [u8]) {
        for (dst, id) in out.chunks_exact_mut(16).zip(&self.publishers) {
            dst.copy_from_slice(&id.to_le_bytes());
        }
        out[48..].copy_from_slice(&self.proof);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{decode, encode, Limits, Message, MessageHeader};

    fn key(byte: u8) -> JoinKey {
        JoinKey::from_bytes([byte; JOIN_KEY_LEN])
    }

    #[test]
    fn a_join_proves_the_key_for_its_actor_and_publishers_only() {
        let join = Join::new(&key(7), 3, [10, 11, 12]);
        assert!(join.verify(&key(7), 3));
        assert!(!join.verify(&key(8), 3), "another key");
        assert!(!join.verify(&key(7), 4), "another actor id");
        let mut moved = join.clone();
        moved.publishers[1] = 99;
        assert!(!moved.verify(&key(7), 3), "other publishers");
    }

    #[test]
    fn the_proof_is_hmac_sha256_of_the_documented_input() {
        // Checked against an independent implementation: Python's
        // hmac.new(bytes([1]*32), b"affordance-explorer join v1"
        //   + (2).to_bytes(4, "little") + b"".join(i.to_bytes(16, "little")
        //   for i in (1, 2, 3)), "sha256").hexdigest()
        let join = Join::new(&key(1), 2, [1, 2, 3]);
        assert_eq!(
            hex::encode(join.proof),
            "556ddb3adb2e081598d45812315d4bc61bcc0db719dd12da437d4c81d93b7701"
        );
    }

    #[test]
    fn a_join_round_trips_through_the_decoder() {
        let join = Join::new(&key(5), 1, [u128::MAX, 0, 42]);
        let header = MessageHeader {
            actor_id: 1,
            ..MessageHeader::default()
        };
        let bytes = encode(&join, header);
        let limits = Limits {
            max_actors: 4,
            max_payload_len: 1024,
        };
        let (header, message) = decode(&bytes, &limits).unwrap();
        assert_eq!(header.actor_id, 1);
        let Message::Join(decoded) = message else {
            panic!("decoded {message:?}")
        };
        assert_eq!(decoded, join);
        assert!(decoded.verify(&key(5), 1));
        assert_eq!(decoded.publisher(MessageKind::Frames), Some(0));
        assert_eq!(decoded.publisher(MessageKind::Weights), None);
    }

    #[test]
    fn a_join_of_the_wrong_length_is_a_layout_error() {
        let err = Join::parse(&[0u8; JOIN_PAYLOAD_LEN - 1]).unwrap_err();
        assert_eq!(err.reason(), "layout_mismatch");
    }

    #[test]
    fn key_text_round_trips_and_bad_text_is_refused() {
        let k = key(0xab);
        assert_eq!(JoinKey::from_hex(&format!("{}\n", k.to_hex())), Ok(k));
        assert_eq!(JoinKey::from_hex("abcd"), Err(JoinKeyError));
        assert_eq!(JoinKey::from_hex(&"zz".repeat(32)), Err(JoinKeyError));
    }
}
