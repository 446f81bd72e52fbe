//! Network definitions shared by the actor (inference) and the learner (training).
//!
//! One crate, so the two processes can never disagree about a layer. Weights
//! travel as safetensors with PyTorch-style names (`policy.actor.weight`).
//! This crate holds no training loop and knows nothing of transport or simulation.
//!
//! Today it holds a linear actor-critic over flat observations: the model the
//! foundation's learner trains end to end. The convolutional policy and the
//! affordance U-Net join it here.

mod linear;
mod masked_categorical;
pub mod policy;
mod tensors;
pub mod unet;
pub mod weights;

pub use linear::LinearActorCritic;
pub use masked_categorical::{entropy, log_softmax_masked, sample};
pub use tensors::{NamedTensors, NetsError};
