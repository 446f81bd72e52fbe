//! The actor's settings: its own flags plus the run's shared transport limits.

use std::path::Path;

use anyhow::Context;
use transport::TransportConfig;

/// Reads the `[transport]` table of a run config (the learner's `config.toml`);
/// other tables belong to the learner and are ignored here.
pub fn transport_from_toml_file(path: &Path) -> anyhow::Result<TransportConfig> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("reading config {}", path.display()))?;
    let table: toml::Table =
        toml::from_str(&text).with_context(|| format!("parsing config {}", path.display()))?;
    match table.get("transport") {
        Some(value) => value.clone().try_into().with_context(|| {
            format!(
                "parsing [transport] in {} (run `learner print-config` for the keys)",
                path.display()
            )
        }),
        None => Ok(TransportConfig::default()),
    }
}
