//! The actor's settings: its own flags plus the run's shared transport limits
//! and task, read from the learner's `config.toml`.

use std::path::Path;

use anyhow::Context;
use proto::TaskSpec;
use transport::TransportConfig;

/// What an actor takes from the run config.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RunConfig {
    /// Shared-memory limits and service prefix.
    pub transport: TransportConfig,
    /// What to run.
    pub task: TaskSpec,
}

/// Reads the `[transport]` and `[task]` tables of a run config (the
/// learner's `config.toml`); other tables belong to the learner and are
/// ignored here. Missing tables take their defaults.
pub fn run_config_from_toml_file(path: &Path) -> anyhow::Result<RunConfig> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("reading config {}", path.display()))?;
    let table: toml::Table =
        toml::from_str(&text).with_context(|| format!("parsing config {}", path.display()))?;
    let transport = match table.get("transport") {
        Some(value) => value.clone().try_into().with_context(|| {
            format!(
                "parsing [transport] in {} (run `learner print-config` for the keys)",
                path.display()
            )
        })?,
        None => TransportConfig::default(),
    };
    let task: TaskSpec = match table.get("task") {
        Some(value) => value.clone().try_into().with_context(|| {
            format!(
                "parsing [task] in {} (run `learner print-config` for the keys)",
                path.display()
            )
        })?,
        None => TaskSpec::default(),
    };
    task.validate()
        .with_context(|| format!("[task] in {}", path.display()))?;
    Ok(RunConfig { transport, task })
}
