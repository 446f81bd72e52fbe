//! Every piece of the learner's training, on the networks of `nets`: PPO
//! for the exploration policy (batches of rollouts with their advantages,
//! the loss, clipping) and the affordance U-Net's trainer (its global
//! dataset, the step, the validation gate, temperature scaling), with the
//! settings of both. Independent of the simulator, the map and the
//! transport (the learner's service drives it); tested on synthetic tasks.

pub mod adam;
pub mod affordance;
pub mod affordance_learner;
pub mod config;
pub mod dataset;
pub mod gae;
pub mod gate;
pub mod grad_norm;
pub mod libtorch_ops;
pub mod optimizer_state;
pub mod ppo;
pub mod ppo_batcher;
pub mod synthetic;
pub mod temperature;
#[cfg(feature = "gpu-torch")]
mod unet_train_torch;
pub mod weight_average;

// Networks on libtorch train with libtorch's own steps (`adam::libtorch`,
// `libtorch_ops`), which this crate's `gpu-torch` builds: a binary built
// with `nets/gpu-torch` alone would train with burn's slower ones.
const _: () = assert!(
    !nets::device::LIBTORCH || cfg!(feature = "gpu-torch"),
    "nets is built with gpu-torch: build training with it too (--features nets/gpu-torch,training/gpu-torch, as deploy/build-gpu-torch.sh does)"
);
