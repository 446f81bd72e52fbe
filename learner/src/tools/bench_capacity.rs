//! `learner bench-capacity`: how many environment steps a learner can take,
//! with no simulator beside it. A real learner (the same receive loop, PPO
//! and U-Net threads as `learner serve`) runs in this process on its own
//! shared-memory services; synthetic actors publish valid rollout chunks,
//! labelled frames and episode stats of the run's task as fast as the
//! learner takes them: each keeps at most a subscriber buffer's worth of
//! rollout messages ahead of what the learner has accepted, and none while
//! the PPO thread's queue is full, so nothing is lost in transit or
//! discarded and the figure is the learner's, not the actors'.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::Context;
use proto::{EpisodeStats, FrameBatch, StatField};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use transport::ActorPorts;

use crate::config::LearnerConfig;
use crate::service::Trainers;
use crate::shared::Shared;
use crate::status::LearnerStatus;
use training::affordance_learner::RoundSeconds;
use training::synthetic;

/// How the synthetic actors feed the learner.
#[derive(Debug, Clone)]
pub struct FeedSettings {
    /// Synthetic actor threads (each with its own actor id and ports).
    pub actors: u32,
    /// Steps per rollout chunk (the actors' `--chunk-steps`).
    pub chunk_steps: usize,
    /// Share of an episode's steps that come back as labelled frames.
    pub labelled_share: f64,
    /// Seconds before counting (start-up, first updates, kernel compilation).
    pub warmup: Duration,
    /// Seconds counted.
    pub window: Duration,
}

/// What the learner took in the counted window, per second.
#[derive(Debug, Clone, Copy, Default)]
pub struct Capacity {
    /// Environment steps accepted from rollout chunks.
    pub steps_per_s: f64,
    /// Environment steps that went into PPO updates.
    pub trained_steps_per_s: f64,
    /// PPO updates.
    pub updates_per_s: f64,
    /// Labelled frames handed to the U-Net trainer.
    pub frames_per_s: f64,
    /// U-Net rounds.
    pub unet_rounds_per_s: f64,
    /// Mean seconds of a U-Net round's parts (training, gate, temperature).
    pub unet_round_seconds: RoundSeconds,
    /// Labelled frames skipped because the U-Net trainer was a dataset behind.
    pub frames_skipped: u64,
    /// Rollout steps discarded because PPO was behind.
    pub steps_discarded: u64,
    /// Messages lost in transit.
    pub messages_dropped: u64,
    /// Mean policy lag (updates) of the last update's rows.
    pub mean_policy_lag: f32,
    /// Mean seconds per update the PPO batching thread spent gathering and
    /// building its batch (during the update before).
    pub batch_seconds: f64,
    /// Mean seconds per update in the update itself.
    pub update_seconds: f64,
}

/// Counters read at the start and end of the window.
#[derive(Clone, Copy)]
struct Reading {
    at: Instant,
    env_steps: u64,
    trained_steps: u64,
    updates: u64,
    frames: u64,
    rounds: u64,
    skipped: u64,
    discarded: u64,
    dropped: u64,
    batch_seconds: f64,
    update_seconds: f64,
    unet_seconds: RoundSeconds,
}

fn read(shared: &Shared) -> Reading {
    let status = shared.status();
    Reading {
        at: Instant::now(),
        env_steps: status.counters.env_steps,
        trained_steps: status.counters.trained_steps,
        updates: status.counters.updates,
        frames: status.counters.frames_received,
        rounds: status.counters.unet_rounds,
        skipped: status.counters.frames_skipped,
        discarded: status.counters.rollout_steps_discarded,
        dropped: status.actors.values().map(|a| a.dropped()).sum(),
        batch_seconds: status.counters.ppo_batch_seconds,
        update_seconds: status.counters.ppo_update_seconds,
        unet_seconds: status.counters.unet_round_seconds,
    }
}

/// Runs a learner with `config` on `device` (`policy_device` for PPO) and
/// the synthetic actors of `feed`; returns what the learner took in the window.
pub fn run(
    mut config: LearnerConfig,
    device: &burn::prelude::Device,
    policy_device: &burn::prelude::Device,
    feed: &FeedSettings,
) -> anyhow::Result<Capacity> {
    anyhow::ensure!(
        config.task.env == proto::EnvKind::Sim,
        "bench-capacity feeds the simulator's task; [task] env must be sim"
    );
    anyhow::ensure!(
        feed.actors >= 1 && feed.actors <= config.transport.max_actors,
        "--actors must be in 1..={} (transport.max_actors)",
        config.transport.max_actors
    );
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.subsec_nanos());
    let id = format!("{}-{nanos}", std::process::id());
    config.transport.service_prefix = format!("afx_capacity_{id}_");
    // Nothing to checkpoint during the window.
    config.checkpoint_every_updates = 0;
    config.checkpoint_interval_s = 0.0;
    let run_dir = std::env::temp_dir().join(format!("afx-capacity-{id}"));
    std::fs::create_dir_all(&run_dir).with_context(|| format!("creating {}", run_dir.display()))?;
    let result = run_in(config, device, policy_device, feed, run_dir.clone());
    let _ = std::fs::remove_dir_all(&run_dir);
    result
}

fn run_in(
    config: LearnerConfig,
    device: &burn::prelude::Device,
    policy_device: &burn::prelude::Device,
    feed: &FeedSettings,
    run_dir: PathBuf,
) -> anyhow::Result<Capacity> {
    let trainers = Trainers::new(&config, device, policy_device);
    let shared = Arc::new(Shared {
        status: Mutex::new(LearnerStatus::new("capacity".into())),
        shutdown: AtomicBool::new(false),
        config,
        run_dir: run_dir.clone(),
    });
    let learner = crate::service::spawn(shared.clone(), trainers, run_dir.join("checkpoints"))?;

    let stop = Arc::new(AtomicBool::new(false));
    let actors: Vec<_> = (0..feed.actors)
        .map(|actor_id| {
            let (shared, stop, feed) = (shared.clone(), stop.clone(), feed.clone());
            std::thread::Builder::new()
                .name(format!("synthetic-actor-{actor_id}"))
                .spawn(move || synthetic_actor(actor_id, &shared, &stop, &feed))
        })
        .collect::<Result<_, _>>()
        .context("starting the synthetic actors")?;

    let outcome = measure(&shared, feed);
    stop.store(true, Ordering::Relaxed);
    shared.shutdown.store(true, Ordering::Relaxed);
    let mut failures = Vec::new();
    for actor in actors {
        match actor.join() {
            Ok(Ok(())) => {}
            Ok(Err(e)) => failures.push(format!("{e:#}")),
            Err(_) => failures.push("a synthetic actor panicked".into()),
        }
    }
    match learner.join() {
        Ok(result) => result.context("the learner failed")?,
        Err(_) => anyhow::bail!("the learner panicked"),
    }
    anyhow::ensure!(failures.is_empty(), "{}", failures.join("; "));
    outcome
}

/// Waits out the warm-up, then counts over the window, printing progress.
fn measure(shared: &Shared, feed: &FeedSettings) -> anyhow::Result<Capacity> {
    let started = Instant::now();
    let mut progress = Instant::now();
    let mut start = None;
    loop {
        std::thread::sleep(Duration::from_millis(200));
        if shared.shutdown.load(Ordering::Relaxed) {
            anyhow::bail!("the learner stopped during the benchmark (see its log above)");
        }
        let elapsed = started.elapsed();
        if start.is_none() && elapsed >= feed.warmup {
            start = Some(read(shared));
        }
        if progress.elapsed() >= Duration::from_secs(10) {
            progress = Instant::now();
            let status = shared.status();
            eprintln!(
                "  {:>4.0} s: {} steps taken, {} updates, {} frames to the U-Net, {} U-Net rounds",
                elapsed.as_secs_f64(),
                status.counters.env_steps,
                status.counters.updates,
                status.counters.frames_received,
                status.counters.unet_rounds
            );
        }
        if let Some(start) = start {
            if start.at.elapsed() >= feed.window {
                let end = read(shared);
                let seconds = (end.at - start.at).as_secs_f64().max(1e-9);
                let rate = |a: u64, b: u64| b.saturating_sub(a) as f64 / seconds;
                let updates = end.updates.saturating_sub(start.updates).max(1) as f64;
                let per_update = |a: f64, b: f64| (b - a) / updates;
                let lag = shared
                    .status()
                    .counters
                    .last_update
                    .map_or(0.0, |u| u.mean_policy_lag);
                return Ok(Capacity {
                    steps_per_s: rate(start.env_steps, end.env_steps),
                    trained_steps_per_s: rate(start.trained_steps, end.trained_steps),
                    updates_per_s: rate(start.updates, end.updates),
                    frames_per_s: rate(start.frames, end.frames),
                    unet_rounds_per_s: rate(start.rounds, end.rounds),
                    unet_round_seconds: per_round(&start, &end),
                    frames_skipped: end.skipped - start.skipped,
                    steps_discarded: end.discarded - start.discarded,
                    messages_dropped: end.dropped - start.dropped,
                    mean_policy_lag: lag,
                    batch_seconds: per_update(start.batch_seconds, end.batch_seconds),
                    update_seconds: per_update(start.update_seconds, end.update_seconds),
                });
            }
        }
    }
}

/// Mean seconds of each part of the rounds between two readings.
fn per_round(start: &Reading, end: &Reading) -> RoundSeconds {
    let rounds = end.rounds.saturating_sub(start.rounds).max(1) as f64;
    let (a, b) = (start.unet_seconds, end.unet_seconds);
    RoundSeconds {
        training: (b.training - a.training) / rounds,
        gate: (b.gate - a.gate) / rounds,
        temperature: (b.temperature - a.temperature) / rounds,
    }
}

/// Whether the learner takes another rollout message from this actor now:
/// fewer than `window` of its messages wait in transit, and the PPO queue
/// has room for a chunk of every feed.
fn learner_ready(shared: &Shared, actor_id: u32, sent: u64, window: u64, room: u64) -> bool {
    let status = shared.status();
    let accepted = status
        .actors
        .get(&actor_id)
        .and_then(|a| {
            a.received
                .get(proto::MessageKind::Rollout.as_str())
                .copied()
        })
        .unwrap_or(0);
    sent < accepted + window && status.counters.rollout_steps_queued <= room
}

/// One synthetic actor: the task's messages, as fast as the learner takes them.
fn synthetic_actor(
    actor_id: u32,
    shared: &Shared,
    stop: &AtomicBool,
    feed: &FeedSettings,
) -> anyhow::Result<()> {
    let config = &shared.config;
    let task = &config.task;
    let layout = task.layout();
    let key = transport::read_join_key(&shared.run_dir.join(transport::JOIN_KEY_FILE))?;
    let mut ports = ActorPorts::open(&config.transport, actor_id, key)
        .with_context(|| format!("synthetic actor {actor_id}: opening its ports"))?;
    let mut rng = StdRng::seed_from_u64(u64::from(actor_id));
    let steps = feed.chunk_steps.max(1);
    let mut chunk = synthetic::rollout(&layout, steps, &mut rng);
    let side = task.image_size;
    let pixels = side * side;
    let planes = task.affordances.len();
    let frame_bytes = 4 * pixels + 3 * pixels + planes * pixels;
    let per_message = ((config.transport.max_frames_bytes - 4096) / frame_bytes).max(1);
    let labelled = ((task.episode_steps as f64 * feed.labelled_share).round() as usize).max(1);
    let frames = |n: usize, rng: &mut StdRng| FrameBatch {
        episode_id: 0,
        height: side as u32,
        width: side as u32,
        n_affordances: planes as u32,
        depth_m: (0..n * pixels)
            .map(|_| rng.random_range(0.2..5.0))
            .collect(),
        rgb: (0..n * pixels * 3).map(|_| rng.random()).collect(),
        labels: (0..n * pixels * planes)
            .map(|_| {
                [
                    proto::LABEL_NEGATIVE,
                    proto::LABEL_POSITIVE,
                    proto::LABEL_UNKNOWN,
                ][rng.random_range(0..3)]
            })
            .collect(),
    };
    let mut parts: Vec<FrameBatch> = Vec::new();
    let mut left = labelled;
    while left > 0 {
        let n = left.min(per_message);
        parts.push(frames(n, &mut rng));
        left -= n;
    }
    // Two messages in transit per feed keep the receive loop busy; the PPO
    // queue keeps room for all of them and for the one the receive loop may
    // have accepted (counted in `received`) but not yet queued.
    let window = 2u64.min(config.transport.learner_buffer.max(1) as u64);
    let queue = config.policy.queue_batches.max(1) * config.policy.batch_steps.max(1);
    let in_flight = (window as usize * feed.actors as usize + 1) * steps;
    let room = queue.saturating_sub(in_flight) as u64;
    let (mut sent, mut episode, mut step) = (0u64, 0u64, 0usize);
    let version = || shared.status().counters.policy_version;
    while !stop.load(Ordering::Relaxed) {
        if !learner_ready(shared, actor_id, sent, window, room) {
            std::thread::sleep(Duration::from_micros(500));
            continue;
        }
        chunk.episode_id = episode;
        chunk.first_step = step as u32;
        let last = step + steps >= task.episode_steps;
        chunk.dones.iter_mut().for_each(|d| *d = 0);
        if last {
            if let Some(d) = chunk.dones.last_mut() {
                *d = 1;
            }
        }
        ports.publish(&chunk, version(), 0)?;
        sent += 1;
        step += steps;
        if last {
            for part in &mut parts {
                part.episode_id = episode;
                ports.publish(&*part, version(), 0)?;
            }
            let stats =
                EpisodeStats::new(episode, step as u32, 0).with(StatField::EpisodeReturn, 0.0);
            ports.publish(&stats, version(), 0)?;
            episode += 1;
            step = 0;
        }
    }
    Ok(())
}

/// The report's Markdown table: one row per setting.
pub fn table(rows: &[(String, Capacity)]) -> String {
    let mut out = String::from(
        "| setting | steps/s taken | steps/s trained | PPO updates/s | PPO batch / update (ms each) | U-Net frames/s | U-Net rounds/s | U-Net round: training / gate / temperature (ms each) | frames skipped | steps discarded | messages dropped | policy lag |\n|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for (name, c) in rows {
        out.push_str(&format!(
            "| {name} | {:.0} | {:.0} | {:.2} | {:.0} / {:.0} | {:.1} | {:.2} | {:.0} / {:.0} / {:.0} | {} | {} | {} | {:.2} |\n",
            c.steps_per_s,
            c.trained_steps_per_s,
            c.updates_per_s,
            c.batch_seconds * 1e3,
            c.update_seconds * 1e3,
            c.frames_per_s,
            c.unet_rounds_per_s,
            c.unet_round_seconds.training * 1e3,
            c.unet_round_seconds.gate * 1e3,
            c.unet_round_seconds.temperature * 1e3,
            c.frames_skipped,
            c.steps_discarded,
            c.messages_dropped,
            c.mean_policy_lag
        ));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn synthetic_actors_feed_a_learner_that_trains_without_losing_anything() {
        let mut config = LearnerConfig::default();
        config.task.image_size = 48;
        config.task.episode_steps = 16;
        config.policy.batch_steps = 32;
        config.validate().unwrap();
        let device = burn::prelude::Device::flex();
        let feed = FeedSettings {
            actors: 2,
            chunk_steps: 8,
            labelled_share: 0.5,
            warmup: Duration::from_secs(2),
            window: Duration::from_secs(4),
        };
        let taken = run(config, &device, &device, &feed).unwrap();
        assert!(taken.steps_per_s > 0.0, "{taken:?}");
        assert!(taken.updates_per_s > 0.0, "{taken:?}");
        assert!(taken.frames_per_s > 0.0, "{taken:?}");
        // Fed only as fast as PPO takes them: nothing discarded, lost or skipped.
        assert_eq!(taken.steps_discarded, 0, "{taken:?}");
        assert_eq!(taken.messages_dropped, 0, "{taken:?}");
        assert_eq!(taken.frames_skipped, 0, "{taken:?}");
    }
}
