//! The actor process as a library: the [`env::Environment`] interface, the
//! episode loop that acts with the broadcast policy and streams rollouts and
//! stats to the learner, and the actor's configuration; and the test
//! evaluation of its networks with the comparison page built from it.
//!
//! It never trains: weights only arrive from the learner.

pub mod config;
pub mod env;
pub mod episode_loop;
pub mod evaluation;
pub mod frame_scores;
pub mod labeler;
pub mod mapping;
pub(crate) mod recording;
pub mod results;
pub mod sim_view;
