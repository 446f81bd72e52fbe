//! Weight blobs (learner → actors): a safetensors file as the payload.
//!
//! Tensor names carry the network as a prefix (`policy.actor.0.weight`,
//! `unet.down.0.conv.weight`) so one blob can hold both networks and loads in
//! PyTorch as a `state_dict`. The header's `policy_version` / `unet_version`
//! say which versions the blob holds.

use safetensors::{Dtype, SafeTensors};

use crate::payload::Payload;
use crate::{MessageKind, ProtoError};

/// Name prefix of policy tensors.
pub const WEIGHTS_POLICY_PREFIX: &str = "policy.";
/// Name prefix of U-Net tensors.
pub const WEIGHTS_UNET_PREFIX: &str = "unet.";
/// Header metadata key: environment steps the learner had received when it sent the blob.
pub const WEIGHTS_META_ENV_STEPS: &str = "env_steps";
/// Header metadata key: temperature calibrating the U-Net's logits (`sigmoid(logit / T)`).
pub const WEIGHTS_META_TEMPERATURE: &str = "unet_temperature";

/// A validated safetensors blob.
pub struct WeightsView<'a> {
    bytes: &'a [u8],
    tensors: SafeTensors<'a>,
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

    pub(crate) fn parse(payload: &'a [u8]) -> Result<Self, ProtoError> {
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
        })
    }
}

/// A safetensors blob to send (already serialised by the learner).
#[derive(Debug, Clone, Copy)]
pub struct WeightsBlob<'a>(pub &'a [u8]);

impl Payload for WeightsBlob<'_> {
    const KIND: MessageKind = MessageKind::Weights;

    fn payload_len(&self) -> usize {
        self.0.len()
    }

    fn write_payload(&self, out: &mut [u8]) {
        out.copy_from_slice(self.0);
    }
}
