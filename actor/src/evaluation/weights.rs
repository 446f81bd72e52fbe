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
