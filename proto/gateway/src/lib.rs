//! Carries a run's messages between hosts over Zenoh, one gateway per host.
//!
//! Actors and the learner speak iceoryx2 shared memory only, within one
//! host. A gateway on each actor host stands in for the learner there, and
//! the gateway on the learner's host stands in for the remote actors; the
//! messages cross unchanged (the same bytes, validated by `proto` on both
//! sides) under the key expressions of [`keys`]. Why Zenoh, and the
//! settings that matter: docs/decisions/0009-zenoh-gateway.md.

pub mod actor_host;
pub mod bench;
mod bench_tunnel;
pub mod keys;
pub mod learner_host;
pub mod link;
mod measure;
pub mod remote;
mod weights_in;

use std::path::Path;
use std::time::Duration;

use anyhow::Context;
use transport::TransportConfig;

/// How often a gateway reports what it has carried.
const STATUS_EVERY: Duration = Duration::from_secs(10);

/// Zenoh's errors as `anyhow` errors (they are boxed trait objects that are
/// not `Sync`).
fn zenoh_error(error: zenoh::Error) -> anyhow::Error {
    anyhow::anyhow!("{error}")
}

/// The `[transport]` table of a run config's text (its defaults if absent).
fn run_transport_config(text: &str, path: &Path) -> anyhow::Result<TransportConfig> {
    let table: toml::Table =
        toml::from_str(text).with_context(|| format!("parsing {}", path.display()))?;
    match table.get("transport") {
        Some(value) => value
            .clone()
            .try_into()
            .with_context(|| format!("parsing [transport] in {}", path.display())),
        None => Ok(TransportConfig::default()),
    }
}

/// Writes a file whole: to a temporary name beside it, then renamed over
/// `path`, so a reader never sees half of it.
fn write_whole(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    let temp = path.with_extension("tmp");
    std::fs::write(&temp, bytes)
        .and_then(|()| std::fs::rename(&temp, path))
        .with_context(|| format!("writing {}", path.display()))
}
