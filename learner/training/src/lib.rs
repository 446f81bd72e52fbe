//! The learner's learning algorithms, on the networks of `nets`: PPO for the
//! exploration policy, and (with the global affordance dataset and
//! temperature scaling) training of the affordance U-Net. Independent of the
//! simulator, the map and the transport; tested on synthetic tasks.

pub mod affordance;
pub mod dataset;
pub mod gae;
pub mod grad_norm;
pub mod optimizer_state;
pub mod ppo;
pub mod temperature;
