//! Weight blobs (learner → actors): a signature, then a safetensors file.
//!
//! The payload starts with an HMAC-SHA256 tag made with the run's
//! [`JoinKey`] over the header's versions and sequence and the safetensors
//! bytes. Anything that can open the weights service can publish on it (the
//! service has spare publisher slots), so an actor loads weights only when
//! [`crate::decode_weights`] finds the tag right: a foreign publisher without the
//! run's key cannot make actors act on its weights. A replay of an earlier
//! weights message of the same run still verifies (a resumed learner
//! legitimately sends older versions than actors have seen), so the worst
//! a replay does is hand actors an earlier policy of this run.
//!
//! Tensor names carry the network as a prefix (`policy.actor.0.weight`,
//! `unet.down.0.conv.weight`) so one blob can hold both networks and loads in
//! PyTorch as a `state_dict`. The header's `policy_version` / `unet_version`
//! say which versions the blob holds.

use hmac::Mac;
use safetensors::{Dtype, SafeTensors};

use crate::header::MessageHeader;
use crate::join::JoinKey;
use crate::payload::Payload;
use crate::{MessageKind, ProtoError};

/// Bytes of the signature at the start of a weights payload.
pub const WEIGHTS_TAG_LEN: usize = 32;
/// Domain separation: a weights tag proves nothing as a join proof.
const SIGNATURE_CONTEXT: &[u8] = b"affordance-explorer weights v1";

/// Name prefix of policy tensors.
pub const WEIGHTS_POLICY_PREFIX: &str = "policy.";
/// Name prefix of U-Net tensors.
pub const WEIGHTS_UNET_PREFIX: &str = "unet.";
/// Header metadata key: environment steps the learner had received when it sent the blob.
pub const WEIGHTS_META_ENV_STEPS: &str = "env_steps";
/// Header metadata key: temperature calibrating the U-Net's logits (`sigmoid(logit / T)`).
pub const WEIGHTS_META_TEMPERATURE: &str = "unet_temperature";
/// Header metadata key, present ("1") while the learner's U-Net owes more
/// gradient steps than its `[unet] hold_actors_beyond_episodes` allow: the
/// actors wait, starting and stepping nothing, until weights without it
/// arrive.
pub const WEIGHTS_META_HOLD: &str = "hold";

/// The signature of `safetensors` sent under a header with these versions
/// and sequence.
fn signature(key: &JoinKey, header: &MessageHeader, safetensors: &[u8]) -> [u8; WEIGHTS_TAG_LEN] {
    signing_mac(key, header, safetensors)
        .finalize()
        .into_bytes()
        .into()
}

fn signing_mac(
    key: &JoinKey,
    header: &MessageHeader,
    safetensors: &[u8],
) -> hmac::Hmac<sha2::Sha256> {
    let mut mac = key.hmac(SIGNATURE_CONTEXT);
    mac.update(&header.policy_version.to_le_bytes());
    mac.update(&header.unet_version.to_le_bytes());
    mac.update(&header.sequence.to_le_bytes());
    mac.update(safetensors);
    mac
}

/// A structurally valid safetensors blob and the signature it came with
/// (checked by [`crate::decode_weights`], not by [`crate::decode`]).
pub struct WeightsView<'a> {
    bytes: &'a [u8],
    tensors: SafeTensors<'a>,
    tag: &'a [u8],
}

impl std::fmt::Debug for WeightsView<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("WeightsView")
            .field("bytes", &self.bytes.len())
            .field("tensors", &self.tensors.len())
            .finish()
    }
}

impl<'a> WeightsView<'a> {
    /// The raw safetensors bytes.
    pub fn bytes(&self) -> &'a [u8] {
        self.bytes
    }

    /// The parsed tensors.
    pub fn tensors(&self) -> &SafeTensors<'a> {
        &self.tensors
    }

    /// Whether the blob was signed with `key` for a message with `header`'s
    /// versions and sequence (compared in constant time).
    pub fn is_signed_by(&self, key: &JoinKey, header: &MessageHeader) -> bool {
        signing_mac(key, header, self.bytes)
            .verify_slice(self.tag)
            .is_ok()
    }

    pub(crate) fn parse(payload: &'a [u8]) -> Result<Self, ProtoError> {
        if payload.len() < WEIGHTS_TAG_LEN {
            return Err(ProtoError::Truncated {
                what: "weights signature",
                needed: WEIGHTS_TAG_LEN,
                got: payload.len(),
            });
        }
        let (tag, payload) = payload.split_at(WEIGHTS_TAG_LEN);
        let tensors =
            SafeTensors::deserialize(payload).map_err(|e| ProtoError::BadWeights(e.to_string()))?;
        for (name, view) in tensors.iter() {
            if !name.starts_with(WEIGHTS_POLICY_PREFIX) && !name.starts_with(WEIGHTS_UNET_PREFIX) {
                return Err(ProtoError::BadWeights(format!(
                    "tensor {name:?} has neither the {WEIGHTS_POLICY_PREFIX:?} nor the {WEIGHTS_UNET_PREFIX:?} prefix"
                )));
            }
            if view.dtype() == Dtype::F32 {
                for (index, b) in view.data().chunks_exact(4).enumerate() {
                    let value = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
                    if !value.is_finite() {
                        return Err(ProtoError::BadFloat {
                            field: "weights",
                            index,
                            value,
                            extra: "",
                        });
                    }
                }
            }
        }
        Ok(Self {
            bytes: payload,
            tensors,
            tag,
        })
    }
}

/// A safetensors blob to send (already serialised by the learner), signed
/// for the header it will be sent with.
#[derive(Debug, Clone, Copy)]
pub struct WeightsBlob<'a> {
    safetensors: &'a [u8],
    tag: [u8; WEIGHTS_TAG_LEN],
}

impl<'a> WeightsBlob<'a> {
    /// Signs `safetensors` with the run's `key` for a message sent under
    /// `header` (its versions and sequence are signed; pass the same header
    /// to [`crate::encode_into`]).
    pub fn signed(key: &JoinKey, header: &MessageHeader, safetensors: &'a [u8]) -> Self {
        Self {
            safetensors,
            tag: signature(key, header, safetensors),
        }
    }
}

impl Payload for WeightsBlob<'_> {
    const KIND: MessageKind = MessageKind::Weights;

    fn payload_len(&self) -> usize {
        WEIGHTS_TAG_LEN + self.safetensors.len()
    }

    fn write_payload(&self, out: &mut [u8]) {
        let (tag, rest) = out.split_at_mut(WEIGHTS_TAG_LEN);
        tag.copy_from_slice(&self.tag);
        rest.copy_from_slice(self.safetensors);
    }
}
