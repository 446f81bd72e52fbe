//! The actor's settings: its own flags plus what it reads from the run's
//! `config.toml` (written by the learner): the transport limits, the task,
//! how actors run (`[actors]`) and the run's seed (`[policy] seed`).

use std::path::Path;

use anyhow::Context;
use proto::{ActorSettings, TaskSpec};
use transport::TransportConfig;

/// What an actor takes from the run config.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RunConfig {
    /// Shared-memory limits and service prefix.
    pub transport: TransportConfig,
    /// What to run.
    pub task: TaskSpec,
    /// How actors run: renderer, rooms, robot, device, environments, data.
    pub actors: ActorSettings,
    /// The run's seed (`[policy] seed`), which actors start their random
    /// choices from.
    pub seed: u64,
}

/// The table `name` of a run config read as `T`, or `T`'s default when
/// the config has no such table.
fn table_or_default<T: serde::de::DeserializeOwned + Default>(
    table: &toml::Table,
    name: &str,
    path: &Path,
) -> anyhow::Result<T> {
    match table.get(name) {
        Some(value) => value.clone().try_into().with_context(|| {
            format!(
                "parsing [{name}] in {} (run `learner print-config` for the keys)",
                path.display()
            )
        }),
        None => Ok(T::default()),
    }
}

/// Reads the `[transport]`, `[task]` and `[actors]` tables and `[policy]
/// seed` of a run config (the learner's `config.toml`); the rest belongs to
/// the learner and is ignored here. Missing tables take their defaults.
pub fn run_config_from_toml_file(path: &Path) -> anyhow::Result<RunConfig> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("reading config {}", path.display()))?;
    let table: toml::Table =
        toml::from_str(&text).with_context(|| format!("parsing config {}", path.display()))?;
    let transport: TransportConfig = table_or_default(&table, "transport", path)?;
    let task: TaskSpec = table_or_default(&table, "task", path)?;
    task.validate()
        .with_context(|| format!("[task] in {}", path.display()))?;
    let actors: ActorSettings = table_or_default(&table, "actors", path)?;
    actors
        .validate()
        .with_context(|| format!("[actors] in {}", path.display()))?;
    let seed = match table.get("policy").and_then(|p| p.get("seed")) {
        None => 0,
        Some(value) => value
            .as_integer()
            .and_then(|s| u64::try_from(s).ok())
            .with_context(|| {
                format!(
                    "[policy] seed in {} must be a non-negative integer",
                    path.display()
                )
            })?,
    };
    Ok(RunConfig {
        transport,
        task,
        actors,
        seed,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read(text: &str) -> anyhow::Result<RunConfig> {
        // A file of its own per call: the tests run in parallel.
        static CALLS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
        let call = CALLS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let path =
            std::env::temp_dir().join(format!("afx-run-config-{}-{call}.toml", std::process::id()));
        std::fs::write(&path, text).unwrap();
        let config = run_config_from_toml_file(&path);
        std::fs::remove_file(&path).ok();
        config
    }

    #[test]
    fn the_actors_table_and_the_runs_seed_are_read_and_checked() {
        let config = read(
            "[actors]\nrenderer = \"cpu\"\nscenes = \"generated\"\nenvs = 4\n\
             data = \"/data\"\n[policy]\nseed = 7\nlearning_rate = 0.1\n",
        )
        .unwrap();
        assert_eq!(config.actors.renderer, "cpu");
        assert_eq!(config.actors.scenes, "generated");
        assert_eq!(config.actors.envs, 4);
        assert_eq!(config.actors.data.as_deref(), Some("/data"));
        assert_eq!(
            config.actors.profile, "default",
            "unset keys keep their defaults"
        );
        assert_eq!(config.seed, 7);

        let plain = read("[task]\nimage_size = 64\n").unwrap();
        assert_eq!(plain.actors, ActorSettings::default());
        assert_eq!(plain.seed, 0);

        for (text, says) in [
            ("[actors]\nrenderer = \"vulkan\"\n", "actors.renderer"),
            ("[actors]\nrender = \"cpu\"\n", "render"),
            ("[policy]\nseed = -1\n", "seed"),
        ] {
            let err = format!("{:#}", read(text).unwrap_err());
            assert!(err.contains(says), "{text}: {err}");
        }
    }

    #[test]
    fn the_tasks_rules_are_read_and_a_bad_one_is_named() {
        let config = read(
            "[task.sphere]\nradius_m = 0.3\n[task.map]\nvoxel_size_m = 0.05\n\
             segmentation = \"geometric\"\n[task.selection]\nmin_pixels = 4\n",
        )
        .unwrap();
        assert_eq!(config.task.sphere.radius_m, 0.3);
        assert_eq!(config.task.map.voxel_size_m, 0.05);
        assert_eq!(
            config.task.map.segmentation,
            proto::MapSegmentation::Geometric
        );
        assert_eq!(config.task.selection.min_pixels, 4);
        assert_eq!(
            config.task.confidence,
            proto::ConfidenceRule::default(),
            "unset tables keep their defaults"
        );
        for (text, says) in [
            (
                "[task.map]\nvoxel_size_m = 0.0\n",
                "task.map.voxel_size_m = 0 must be above 0",
            ),
            (
                "[task.confidence]\nnegative_below = 0.95\n",
                "task.confidence.negative_below",
            ),
            ("[task.sphere]\nradius = 0.3\n", "radius"),
            ("[task.map]\nsegmentation = \"paint\"\n", "segmentation"),
        ] {
            let err = format!("{:#}", read(text).unwrap_err());
            assert!(err.contains(says), "{text}: {err}");
        }
    }
}
