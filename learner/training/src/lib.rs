//! Every piece of the learner's training, on the networks of `nets`: PPO
//! for the exploration policy (batches of rollouts with their advantages,
//! the loss, clipping) and the affordance U-Net's trainer (its global
//! dataset, the step, the validation gate, temperature scaling), with the
//! settings of both. Independent of the simulator, the map and the
//! transport (the learner's service drives it); tested on synthetic tasks.

pub mod affordance;
pub mod affordance_learner;
pub mod config;
pub mod dataset;
pub mod gae;
pub mod grad_norm;
pub mod optimizer_state;
pub mod ppo;
pub mod ppo_batcher;
pub mod synthetic;
pub mod temperature;
