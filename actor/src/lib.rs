//! The actor process as a library: the [`env::Environment`] interface, the
//! episode loop that acts with the broadcast policy and streams rollouts and
//! stats to the learner, and the actor's configuration; and the test
//! evaluation of its networks with the comparison page built from it.
//!
//! It never trains: weights only arrive from the learner.
//!
//! Only the binary, its benches and tests use this library, so items are
//! `pub(crate)` unless those do; its documentation is read with the private
//! items (`cargo doc --document-private-items`, as CI builds it), where
//! links to them resolve.
#![allow(rustdoc::private_intra_doc_links)]

pub mod config;
pub mod env;
pub mod episode_loop;
pub mod evaluation;
pub mod frame_scores;
pub mod labeler;
pub mod ladder_labels;
pub mod mapping;
pub(crate) mod recording;
pub mod results;
pub mod sampling;
pub mod sim_view;
