//! Network definitions shared by the actor (inference) and the learner (training).
//!
//! One crate, so the two processes can never disagree about a layer. Weights
//! travel as safetensors with PyTorch-style names (`policy.actor.weight`).
//! This crate holds no training loop and knows nothing of transport or simulation.
//!
//! - [`policy`]: the exploration policy (conv encoders, MLPs, optional GRU,
//!   actor and critic heads with masked logits), on burn;
//! - [`unet`]: the affordance U-Net and its labelled-pixels-only loss;
//! - [`weights`]: either network to and from safetensors bytes;
//! - [`device`]: `--device cpu|gpu` at run time;
//! - a linear actor-critic over flat observations, which the foundation's
//!   learner still trains until the loop is closed (issue 6), and the masked
//!   categorical helpers the actor samples with.

pub mod device;
mod linear;
mod masked_categorical;
pub mod policy;
mod tensors;
pub mod unet;
pub mod weights;

pub use linear::LinearActorCritic;
pub use masked_categorical::{entropy, log_softmax_masked, sample};
pub use tensors::{NamedTensors, NetsError};
