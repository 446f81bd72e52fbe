//! `learner train-unet`: the affordance U-Net trained offline on the label
//! ladder's dataset (`actor --dataset`) with one of its label sources
//! ([`proto::LabelRung`]), so that the rungs' scores say where the signal
//! is lost (`docs/ladder.md`).
//!
//! It replays the run's U-Net schedule with the rung's labels: episode by
//! episode, the frames join the learner's own dataset (its split, its
//! frame budget and uses), then `[unet] steps_per_episode` gradient steps,
//! the validation gate and the temperature fit, exactly as
//! [`training::affordance_learner::AffordanceLearner`] does in a run. The
//! result is a directory that `actor evaluate --run-dir` scores: the
//! dataset's `config.toml` and `checkpoints/<gradient steps>/` with the
//! deployed U-Net and its temperature.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use anyhow::Context;
use burn::prelude::Device;
use proto::{LabelRung, Limits, Message, DATASET_EPISODES_DIR, DATASET_EPISODE_EXTENSION};
use serde::Serialize;
use training::affordance::{LabelledFrame, UNKNOWN};

use crate::config::LearnerConfig;
use training::affordance_learner::{checked_frames, AffordanceLearner};

/// What to train on and how long.
#[derive(Debug, Clone)]
pub struct TrainUnetSettings {
    /// The dataset directory (`actor --dataset`).
    pub dataset: PathBuf,
    /// Whose labels the network learns.
    pub rung: LabelRung,
    /// The directory written (a run directory `actor evaluate` reads).
    pub out: PathBuf,
    /// Times the episodes are replayed.
    pub passes: usize,
    /// Gradient steps per episode (default: the run's `[unet] steps_per_episode`).
    pub steps_per_episode: Option<usize>,
    /// Checkpoints written, evenly over the training (the last at its end).
    pub checkpoints: usize,
    /// The loss's class balance (default: the run's `[unet] class_balance`).
    pub class_balance: Option<nets::unet::ClassBalance>,
    /// Seed of the split, the batches and the initial weights.
    pub seed: u64,
}

/// Labelled pixels and frames of one affordance plane in what trained.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct PlaneCounts {
    /// Frames with at least one positive pixel in this plane.
    pub frames_with_positives: usize,
    /// Positive pixels.
    pub positive_pixels: u64,
    /// Negative pixels.
    pub negative_pixels: u64,
}

/// What `train-unet` did.
#[derive(Debug, Clone, Serialize)]
pub struct TrainUnetReport {
    /// The rung trained on.
    pub rung: String,
    /// Episode files read.
    pub episodes: usize,
    /// Frames read, and kept (with both classes in some plane, when the
    /// run's `balanced_frames` is on; else with any label).
    pub frames_read: usize,
    /// Frames kept for training.
    pub frames_kept: usize,
    /// Per affordance (task order), the kept frames' labels.
    pub planes: Vec<(String, PlaneCounts)>,
    /// Gradient steps taken.
    pub steps: usize,
    /// Rounds whose network passed the validation gate.
    pub rounds_replaced: usize,
    /// Rounds in all.
    pub rounds: usize,
    /// The checkpoints written (gradient steps).
    pub checkpoints: Vec<u64>,
    /// The deployed network's temperature at the end.
    pub temperature: f32,
}

/// The dataset's episode files, in name order (per actor, the run's order).
fn episode_files(dataset: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let dir = dataset.join(DATASET_EPISODES_DIR);
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .with_context(|| {
            format!(
                "listing {} (is {} a dataset written by `actor --dataset`?)",
                dir.display(),
                dataset.display()
            )
        })?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.extension()
                .is_some_and(|e| e == DATASET_EPISODE_EXTENSION)
        })
        .collect();
    files.sort();
    anyhow::ensure!(
        !files.is_empty(),
        "{} holds no episode yet (*.{DATASET_EPISODE_EXTENSION})",
        dir.display()
    );
    Ok(files)
}

/// One episode file's frames with `rung`'s planes alone (of a task with
/// `affordances` affordances and `image_size` images).
fn read_episode(
    path: &Path,
    rung: LabelRung,
    affordances: usize,
    image_size: usize,
) -> anyhow::Result<Vec<LabelledFrame>> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    let limits = Limits {
        max_actors: u32::MAX,
        max_payload_len: bytes.len() as u64,
    };
    let (_, message) = proto::decode(&bytes, &limits)
        .with_context(|| format!("{} is not a dataset episode", path.display()))?;
    let Message::Frames(view) = message else {
        anyhow::bail!("{} holds no frames", path.display());
    };
    let rungs = LabelRung::ALL.len();
    let frames = checked_frames(&view, rungs * affordances, image_size).with_context(|| {
        format!(
            "{} does not fit the dataset's config.toml ({rungs} label sources × {affordances} affordances)",
            path.display()
        )
    })?;
    let pixels = image_size * image_size;
    let planes = rung.planes(affordances);
    Ok(frames
        .into_iter()
        .map(|mut frame| {
            frame.labels = frame.labels[planes.start * pixels..planes.end * pixels].to_vec();
            frame
        })
        .collect())
}

/// Whether a frame goes to training: with both classes in some plane when
/// `balanced` (the labeler's filter), else with any label.
fn keep(frame: &LabelledFrame, balanced: bool) -> bool {
    let pixels = frame.size[0] * frame.size[1];
    if balanced {
        frame
            .labels
            .chunks(pixels)
            .any(|plane| plane.contains(&1) && plane.contains(&0))
    } else {
        frame.labels.iter().any(|&l| l != UNKNOWN)
    }
}

/// Adds a frame's labels to the per-plane counts.
fn count(counts: &mut [PlaneCounts], frame: &LabelledFrame) {
    let pixels = frame.size[0] * frame.size[1];
    for (plane, counts) in frame.labels.chunks(pixels).zip(counts) {
        let positive = plane.iter().filter(|&&l| l == 1).count() as u64;
        counts.positive_pixels += positive;
        counts.negative_pixels += plane.iter().filter(|&&l| l == 0).count() as u64;
        counts.frames_with_positives += usize::from(positive > 0);
    }
}

/// Writes the deployed network as checkpoint `step` of `out`.
fn write_checkpoint(out: &Path, step: u64, learner: &AffordanceLearner) -> anyhow::Result<()> {
    let unet = learner
        .deployed_weights()
        .context("serialising the U-Net")?;
    let metadata = HashMap::from([(
        proto::WEIGHTS_META_TEMPERATURE.to_string(),
        learner.temperature().to_string(),
    )]);
    let bundled = nets::weights::bundle(&[(proto::WEIGHTS_UNET_PREFIX, &unet)], metadata)
        .context("bundling the U-Net")?;
    crate::checkpoint::write(
        &out.join("checkpoints"),
        step,
        &[("weights.safetensors", &bundled)],
        usize::MAX,
    )?;
    Ok(())
}

/// Trains as `settings` say on `device`, telling `progress` how it goes.
pub fn train_unet(
    settings: &TrainUnetSettings,
    device: &Device,
    progress: &mut dyn FnMut(&str),
) -> anyhow::Result<TrainUnetReport> {
    anyhow::ensure!(settings.passes > 0, "--passes must be at least 1");
    anyhow::ensure!(settings.checkpoints > 0, "--checkpoints must be at least 1");
    let config_path = settings.dataset.join("config.toml");
    let config = LearnerConfig::from_toml_file(&config_path)
        .with_context(|| format!("reading the dataset's run config {}", config_path.display()))?;
    let task = &config.task;
    let affordances = task.affordances.len();
    let mut unet = config.unet.clone();
    if let Some(steps) = settings.steps_per_episode {
        anyhow::ensure!(steps > 0, "--steps-per-episode must be at least 1");
        unet.steps_per_episode = steps;
    }
    if let Some(balance) = settings.class_balance {
        unet.class_balance = balance;
    }
    let files = episode_files(&settings.dataset)?;
    anyhow::ensure!(
        !settings.out.join("checkpoints").exists(),
        "{} already holds checkpoints: choose another --out",
        settings.out.display()
    );
    std::fs::create_dir_all(&settings.out)
        .with_context(|| format!("creating {}", settings.out.display()))?;
    // The run's config with the U-Net settings this training used.
    let mut written = config.clone();
    written.unet = unet.clone();
    let out_config = settings.out.join("config.toml");
    std::fs::write(&out_config, written.to_toml())
        .with_context(|| format!("writing {}", out_config.display()))?;

    let mut learner = AffordanceLearner::new(affordances, &unet, settings.seed, device);
    let rounds = settings.passes * files.len();
    let checkpoint_rounds: Vec<usize> = (1..=settings.checkpoints)
        .map(|i| (i * rounds).div_ceil(settings.checkpoints))
        .collect();
    let mut report = TrainUnetReport {
        rung: settings.rung.name().to_string(),
        episodes: files.len(),
        frames_read: 0,
        frames_kept: 0,
        planes: task
            .affordances
            .iter()
            .map(|a| (a.as_str().to_string(), PlaneCounts::default()))
            .collect(),
        steps: 0,
        rounds_replaced: 0,
        rounds: 0,
        checkpoints: Vec::new(),
        temperature: 1.0,
    };
    let started = std::time::Instant::now();
    for pass in 0..settings.passes {
        for (index, path) in files.iter().enumerate() {
            let frames = read_episode(path, settings.rung, affordances, task.image_size)?;
            let kept: Vec<LabelledFrame> = frames
                .iter()
                .filter(|f| keep(f, task.balanced_frames))
                .cloned()
                .collect();
            if pass == 0 {
                report.frames_read += frames.len();
                report.frames_kept += kept.len();
                let mut counts: Vec<PlaneCounts> = report.planes.iter().map(|p| p.1).collect();
                for frame in &kept {
                    count(&mut counts, frame);
                }
                for (plane, counts) in report.planes.iter_mut().zip(counts) {
                    plane.1 = counts;
                }
            }
            if !kept.is_empty() {
                learner.add_episode((pass * files.len() + index) as u64, kept);
            }
            if let Some(round) = learner.train_round(unet.steps_per_episode) {
                report.rounds += 1;
                report.rounds_replaced += usize::from(round.replaced);
                report.steps += round.steps;
            }
            let done = pass * files.len() + index + 1;
            if checkpoint_rounds.contains(&done) {
                write_checkpoint(&settings.out, report.steps as u64, &learner)?;
                report.checkpoints.push(report.steps as u64);
            }
            if done % 10 == 0 || done == rounds {
                progress(&format!(
                    "{done}/{rounds} episodes, {} steps, {} of {} rounds replaced the network, {:.0} s",
                    report.steps,
                    report.rounds_replaced,
                    report.rounds,
                    started.elapsed().as_secs_f64()
                ));
            }
        }
    }
    report.temperature = learner.temperature();
    let json = serde_json::to_string_pretty(&report)?;
    let path = settings.out.join("train-unet.json");
    std::fs::write(&path, json).with_context(|| format!("writing {}", path.display()))?;
    Ok(report)
}
