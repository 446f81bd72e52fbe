//! How an actor steps its environments: one way, with the U-Net's
//! inference as the one choice a machine makes.
//!
//! Every environment runs on a thread of its own ([`env_threads`]) and gets
//! its next reset, step or episode end as soon as its last one is done; the
//! episode loop's scheduler (`crate::episode_loop`) books whichever finishes
//! first. With one environment that is lock-step; with several, none waits
//! for the slowest at a barrier. Until 2026-11-29 the actor also stepped
//! several environments in lock-step (for policies without the CPU's own
//! pass); measured side by side, it never made more steps than running
//! free (on the VM's 2 cores about the same, on an H200 with 16
//! environments clearly fewer: docs/performance.md, "One actor"), so it
//! went.
//!
//! What a machine chooses is where the U-Net sees the frames
//! ([`Inference`], from the device): on each environment's thread (the
//! CPU, where a batch costs the same per frame), or in the batches of a
//! batching thread ([`unet_batcher`], a GPU, where a batch of 16 frames
//! costs a few single frames: docs/performance.md, "one U-Net inference
//! call at 128 px").

pub mod env_threads;
mod named_thread;
pub mod unet_batcher;

/// Where the networks see several environments' inputs (the U-Net their
/// frames; where the policy has no CPU pass of its own, its observations).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Inference {
    /// In batches: the U-Net's in a batching thread's, over every frame
    /// waiting for it (for a GPU).
    Batched,
    /// Each input on its environment's thread, inside its reset or step
    /// (for the CPU, where a batch costs the same per input).
    PerEnvironment,
}

impl Inference {
    /// The way that suits networks on `device`.
    pub fn for_device(device: &burn::prelude::Device) -> Self {
        if nets::device::is_cpu(device) {
            Self::PerEnvironment
        } else {
            Self::Batched
        }
    }
}
