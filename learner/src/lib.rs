//! The learner process as a library: the service around the `training`
//! crate: configuration, validation of incoming messages, the receive loop
//! and the threads that train the policy and the U-Net, checkpoints, the
//! run's history (JSON lines and TensorBoard scalars), checkpoints scored on
//! the validation rooms in the background, and the HTTP edge (live page,
//! metrics, status).
//!
//! It never runs a simulator or a map; it only sees what actors send through
//! the `transport` crate, in the layouts of `proto`.
//!
//! Only the binary, its benches and tests use this library, so items are
//! `pub(crate)` unless those do; its documentation is read with the private
//! items (`cargo doc --document-private-items`, as CI builds it), where
//! links to them resolve.
#![allow(rustdoc::private_intra_doc_links)]

pub(crate) mod checkpoint;
pub mod config;
pub mod config_docs;
pub(crate) mod history;
pub mod http;
pub(crate) mod policy_worker;
pub(crate) mod prometheus;
pub mod service;
pub mod shared;
pub mod status;
pub(crate) mod tensorboard;
pub(crate) mod thread_priority;
pub mod tools;
pub(crate) mod unet_worker;
pub(crate) mod validation_scorer;
