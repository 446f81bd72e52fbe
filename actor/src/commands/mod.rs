//! The actor binary's subcommands that are more than a call into the
//! library (`main.rs` declares this module; the library does not).

pub(crate) mod evaluate;
pub(crate) mod sim_args;
