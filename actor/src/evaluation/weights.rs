//! The deployed U-Net of a run's checkpoint (the one that last passed
//! validation, which the actors used), with its calibration temperature.

use std::path::Path;

use anyhow::Context;
use proto::WEIGHTS_META_TEMPERATURE;

/// A checkpoint's U-Net.
#[derive(Debug, Clone)]
pub struct CheckpointUnet {
    /// The checkpoint's environment step.
    pub step: u64,
    /// The U-Net's safetensors bytes (names without the `unet.` prefix).
    pub weights: Vec<u8>,
    /// Its calibration temperature (1 if the checkpoint has none).
    pub temperature: f32,
}

/// The steps of `run_dir`'s checkpoints, oldest first.
pub fn checkpoint_steps(run_dir: &Path) -> anyhow::Result<Vec<u64>> {
    let root = run_dir.join("checkpoints");
    let entries = std::fs::read_dir(&root).with_context(|| {
        format!(
            "listing {} (is {} a run directory with checkpoints?)",
            root.display(),
            run_dir.display()
        )
    })?;
    let mut steps: Vec<u64> = entries
        .filter_map(|e| e.ok()?.file_name().to_str()?.parse().ok())
        .collect();
    steps.sort_unstable();
    Ok(steps)
}

/// Whether checkpoint `step` of `run_dir` holds a U-Net that has trained:
/// its `counters.json` says `unet_version` ≥ 1. An untrained network is a
/// floor every report gives beside the scores, not a result of the run, and
/// where a method's trained networks score below calling everything
/// afforded, the untrained one (which does just that at 0.5) would win the
/// choice of a checkpoint; so `evaluate --select` passes over it. A
/// checkpoint without counters (older runs) counts as trained.
pub fn unet_has_trained(run_dir: &Path, step: u64) -> anyhow::Result<bool> {
    let path = run_dir
        .join("checkpoints")
        .join(step.to_string())
        .join("counters.json");
    let text = match std::fs::read_to_string(&path) {
        Ok(text) => text,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(true),
        Err(e) => return Err(e).with_context(|| format!("reading {}", path.display())),
    };
    let counters: serde_json::Value = serde_json::from_str(&text)
        .with_context(|| format!("{} is not JSON (a damaged checkpoint?)", path.display()))?;
    Ok(counters
        .get("unet_version")
        .and_then(serde_json::Value::as_u64)
        .is_none_or(|version| version >= 1))
}

/// Reads the U-Net of `run_dir/checkpoints/<step>/weights.safetensors`,
/// the newest step when `step` is `None`.
pub fn load_checkpoint_unet(run_dir: &Path, step: Option<u64>) -> anyhow::Result<CheckpointUnet> {
    let root = run_dir.join("checkpoints");
    let steps = checkpoint_steps(run_dir)?;
    let step = match step {
        Some(s) if steps.contains(&s) => s,
        Some(s) => anyhow::bail!(
            "no checkpoint of step {s} in {}; it has {steps:?}",
            root.display()
        ),
        None => *steps.last().with_context(|| {
            format!(
                "no checkpoint in {} yet (the learner writes them periodically and on Ctrl-C)",
                root.display()
            )
        })?,
    };
    let path = root.join(step.to_string()).join("weights.safetensors");
    let bytes = std::fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
    let temperature = nets::weights::metadata(&bytes)
        .with_context(|| format!("reading the header of {}", path.display()))?
        .get(WEIGHTS_META_TEMPERATURE)
        .and_then(|t| t.parse::<f32>().ok())
        .filter(|t| t.is_finite() && *t > 0.0)
        .unwrap_or(1.0);
    let weights = nets::weights::unbundle(&bytes, "unet.")
        .with_context(|| format!("taking the U-Net out of {}", path.display()))?;
    Ok(CheckpointUnet {
        step,
        weights,
        temperature,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_checkpoint_whose_unet_never_trained_is_told_apart() {
        let run = tempfile::tempdir().unwrap();
        let run = run.path();
        for (step, counters) in [
            (180, Some(r#"{"env_steps": 180, "unet_version": 0}"#)),
            (8996, Some(r#"{"env_steps": 8996, "unet_version": 26}"#)),
            (9000, None),
        ] {
            let dir = run.join("checkpoints").join(step.to_string());
            std::fs::create_dir_all(&dir).unwrap();
            if let Some(text) = counters {
                std::fs::write(dir.join("counters.json"), text).unwrap();
            }
        }
        let trained: Vec<bool> = [180, 8996, 9000]
            .iter()
            .map(|&step| unet_has_trained(run, step).unwrap())
            .collect();
        std::fs::write(run.join("checkpoints/180/counters.json"), "{").unwrap();
        let damaged = unet_has_trained(run, 180);
        assert_eq!(trained, [false, true, true]);
        assert!(
            damaged.is_err(),
            "a damaged checkpoint is an error, not a guess"
        );
    }
}
