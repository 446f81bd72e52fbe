//! U-Net training on its own thread, so the policy loop keeps taking
//! rollouts while the U-Net trains: episodes' frames go in through a queue
//! bounded by as many frames as the dataset holds (only beyond that is an
//! episode skipped and counted, never queued without bound: anything more
//! would push out of the dataset frames not yet trained on anyway), the
//! thread adds everything queued before each round, and each network that
//! passes the validation gate comes
//! back as safetensors bytes for the next weights broadcast. After every
//! round the thread also leaves its training state (the network in training
//! and Adam's moments) where checkpoints can take it without waiting.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc::{self, Receiver, Sender};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use anyhow::Context;
use training::affordance::LabelledFrame;

use crate::history::History;
use crate::shared::Shared;
use training::affordance_learner::{AffordanceLearner, UnetTrainingState};
use training::config::MAX_OWED_EPISODES;

/// One episode's frames, keyed uniquely over actors.
type Episode = (u64, Vec<LabelledFrame>);

/// The running U-Net thread.
pub struct UnetWorker {
    frames: Option<Sender<Episode>>,
    /// Frames sent and not yet taken by the thread.
    queued: Arc<AtomicUsize>,
    /// Most frames that may wait.
    capacity: usize,
    deployed: Receiver<DeployedUnet>,
    training: Arc<Mutex<Option<UnetTrainingState>>>,
    thread: Option<JoinHandle<anyhow::Result<()>>>,
}

/// What a stopped U-Net thread leaves.
pub struct StoppedUnet {
    /// A network that passed the gate after the last [`UnetWorker::take_deployed`].
    pub deployed: Option<DeployedUnet>,
    /// The training state after the last round.
    pub training: Option<UnetTrainingState>,
}

/// A U-Net that passed the gate: what actors are sent, with the version it
/// is (the status's version may already be a newer network's, still on its
/// way).
#[derive(Debug, Clone)]
pub struct DeployedUnet {
    /// Its version.
    pub version: u64,
    /// Its weights (safetensors).
    pub weights: Vec<u8>,
    /// The temperature that calibrates its logits.
    pub temperature: f32,
}

/// Stores `learner`'s training state in `slot`; on failure (logged) the
/// slot keeps the previous state, which is still consistent in itself.
fn capture(learner: &AffordanceLearner, slot: &Mutex<Option<UnetTrainingState>>) {
    match learner.training_state() {
        Ok(state) => *slot.lock().unwrap_or_else(|p| p.into_inner()) = Some(state),
        Err(e) => tracing::warn!("cannot capture the U-Net's training state for checkpoints: {e}"),
    }
}

/// Adds an arrived episode's frames to `learner`'s dataset, counting the
/// episode and taking its frames off the `queued` count.
fn take_in(
    learner: &mut AffordanceLearner,
    episodes: &mut EpisodeCounter,
    queued: &AtomicUsize,
    (episode, batch): Episode,
) {
    queued.fetch_sub(batch.len(), Ordering::Relaxed);
    episodes.arrived(episode);
    learner.add_episode(episode, batch);
}

/// Counts the episodes whose frames arrived since the last round. An
/// episode too large for one message comes in parts, one after another
/// from its actor (`[transport] max_frames_bytes`; at 128 px a 600-step
/// episode is about three), so a part counts only when its episode is not
/// the one its actor sent last.
#[derive(Debug, Default)]
struct EpisodeCounter {
    /// Per actor (the key's upper bits), the episode of its last part.
    last: std::collections::HashMap<u64, u64>,
    new: usize,
}

impl EpisodeCounter {
    /// A part of episode `key` (`actor << 40 | episode`) arrived.
    fn arrived(&mut self, key: u64) {
        if self.last.insert(key >> 40, key) != Some(key) {
            self.new += 1;
        }
    }

    /// The episodes counted since the last call.
    fn take(&mut self) -> usize {
        std::mem::take(&mut self.new)
    }
}

impl UnetWorker {
    /// Starts training `learner` on a thread of its own, with at most
    /// `capacity` frames waiting (at least one episode always may).
    pub fn start(
        mut learner: AffordanceLearner,
        shared: Arc<Shared>,
        history: Arc<Mutex<History>>,
        capacity: usize,
    ) -> anyhow::Result<Self> {
        let (frames, inbox) = mpsc::channel::<Episode>();
        let queued = Arc::new(AtomicUsize::new(0));
        let taken = queued.clone();
        let (outbox, deployed) = mpsc::channel();
        let training = Arc::new(Mutex::new(None));
        capture(&learner, &training);
        let slot = training.clone();
        let nice = shared.config.training_nice;
        let thread = std::thread::Builder::new()
            .name("unet-training".into())
            .spawn(move || -> anyhow::Result<()> {
                crate::thread_priority::lower_this_thread(nice);
                // Every episode that arrives is owed `steps_per_episode`
                // steps, however many arrive together (an actor's
                // environments end theirs at once); they are paid in rounds
                // of that many steps, each gated, taking in new frames
                // between rounds. A trainer that cannot keep up trains all
                // the time and forgets debt beyond `MAX_OWED_EPISODES`.
                let per_episode = learner.steps_per_episode();
                let mut episodes = EpisodeCounter::default();
                let mut owed = 0;
                loop {
                    // Ends when the loop drops its sender.
                    if owed == 0 {
                        let Ok(arrived) = inbox.recv() else {
                            break;
                        };
                        take_in(&mut learner, &mut episodes, &taken, arrived);
                    }
                    loop {
                        match inbox.try_recv() {
                            Ok(arrived) => take_in(&mut learner, &mut episodes, &taken, arrived),
                            Err(mpsc::TryRecvError::Empty) => break,
                            Err(mpsc::TryRecvError::Disconnected) => return Ok(()),
                        }
                    }
                    owed =
                        (owed + per_episode * episodes.take()).min(per_episode * MAX_OWED_EPISODES);
                    shared.status().counters.unet_owed_steps = owed as u64;
                    let started = std::time::Instant::now();
                    let Some(round) = learner.train_round(owed.min(per_episode)) else {
                        owed = 0;
                        shared.status().counters.unet_owed_steps = 0;
                        continue;
                    };
                    owed = owed.saturating_sub(round.steps);
                    shared.status().counters.unet_owed_steps = owed as u64;
                    let seconds = started.elapsed().as_secs_f64();
                    capture(&learner, &slot);
                    let (env_steps, unet_version) = {
                        let mut status = shared.status();
                        status.timings.unet_round.observe(seconds);
                        status.counters.unet_rounds += 1;
                        status.counters.unet_steps += round.steps as u64;
                        status.counters.unet_round_seconds.add(&round.seconds);
                        status.counters.last_unet = Some(round.clone());
                        if round.replaced {
                            status.counters.unet_version += 1;
                        }
                        (status.counters.env_steps, status.counters.unet_version)
                    };
                    history.lock().unwrap_or_else(|p| p.into_inner()).record(
                        "unet",
                        env_steps,
                        serde_json::json!({ "unet_version": unet_version, "round": round }),
                    )?;
                    if round.replaced {
                        let weights = learner
                            .deployed_weights()
                            .context("serialising the U-Net")?;
                        let deployed = DeployedUnet {
                            version: unet_version,
                            weights,
                            temperature: learner.temperature(),
                        };
                        if outbox.send(deployed).is_err() {
                            break;
                        }
                    }
                }
                Ok(())
            })
            .context("starting the U-Net training thread")?;
        Ok(Self {
            frames: Some(frames),
            queued,
            capacity,
            deployed,
            training,
            thread: Some(thread),
        })
    }

    /// Hands an episode's frames to the thread; false (and nothing queued)
    /// when a dataset's worth of frames is already waiting.
    pub fn offer(&self, episode: u64, frames: Vec<LabelledFrame>) -> bool {
        let n = frames.len();
        let waiting = self.queued.load(Ordering::Relaxed);
        if waiting > 0 && waiting + n > self.capacity {
            return false;
        }
        let Some(sender) = self.frames.as_ref() else {
            return false;
        };
        self.queued.fetch_add(n, Ordering::Relaxed);
        if sender.send((episode, frames)).is_err() {
            self.queued.fetch_sub(n, Ordering::Relaxed);
            return false;
        }
        true
    }

    /// The newest network that passed the gate since the last call, if any,
    /// with its calibration temperature.
    pub fn take_deployed(&self) -> Option<DeployedUnet> {
        self.deployed.try_iter().last()
    }

    /// True once the thread has ended, which before [`UnetWorker::stop`]
    /// means it failed.
    pub fn finished(&self) -> bool {
        self.thread.as_ref().is_none_or(JoinHandle::is_finished)
    }

    /// The training state after the newest round (for a checkpoint).
    pub fn training_state(&self) -> Option<UnetTrainingState> {
        self.training
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }

    /// Stops the thread after its current round. Returns what it left (after
    /// a failure, the state of its last good round) and its error, if it failed.
    pub fn stop(mut self) -> (StoppedUnet, anyhow::Result<()>) {
        self.frames = None;
        let outcome = match self.thread.take().map(JoinHandle::join) {
            Some(Ok(result)) => result,
            Some(Err(_)) => Err(anyhow::anyhow!("the U-Net training thread panicked")),
            None => Ok(()),
        };
        let stopped = StoppedUnet {
            deployed: self.take_deployed(),
            training: self.training_state(),
        };
        (stopped, outcome)
    }
}

#[cfg(test)]
mod tests {
    use std::sync::atomic::AtomicBool;
    use std::time::{Duration, Instant};

    use training::affordance::LabelledFrame;

    use super::*;
    use crate::config::{LearnerConfig, UnetConfig};
    use crate::status::LearnerStatus;

    #[test]
    fn parts_of_one_episode_count_once_across_rounds() {
        let mut counter = EpisodeCounter::default();
        let key = |actor: u64, episode: u64| actor << 40 | episode;
        counter.arrived(key(0, 5));
        counter.arrived(key(1, 5));
        counter.arrived(key(0, 5));
        assert_eq!(counter.take(), 2, "two actors' episodes 5");
        counter.arrived(key(0, 5));
        counter.arrived(key(0, 6));
        assert_eq!(counter.take(), 1, "the rest of an episode counted before");
        assert_eq!(counter.take(), 0);
    }

    #[test]
    fn a_failed_thread_is_seen_and_stop_returns_its_error() {
        // A history that cannot be written: every record fails as on a full disk.
        let dir = tempfile::tempdir().unwrap();
        std::os::unix::fs::symlink("/dev/full", dir.path().join("history.jsonl")).unwrap();
        let history = History::open(dir.path()).unwrap();
        let settings = UnetConfig {
            steps_per_episode: 1,
            batch_frames: 1,
            validation_fraction: 0.0,
            test_fraction: 0.0,
            ..UnetConfig::default()
        };
        let device = burn::prelude::Device::flex();
        let shared = Arc::new(Shared {
            status: Mutex::new(LearnerStatus::new("test".into())),
            shutdown: AtomicBool::new(false),
            config: LearnerConfig::default(),
            run_dir: dir.path().into(),
        });
        let worker = UnetWorker::start(
            AffordanceLearner::new(1, &settings, 1, &device),
            shared,
            Arc::new(Mutex::new(history)),
            16,
        )
        .unwrap();
        assert!(!worker.finished());
        assert!(
            worker.training_state().is_some(),
            "the state is there before any round"
        );
        let frame = LabelledFrame {
            size: [16, 16],
            rgbd: vec![0.5; 4 * 256],
            labels: vec![1; 256],
        };
        assert!(worker.offer(1, vec![frame.clone(), frame]));
        let deadline = Instant::now() + Duration::from_secs(60);
        while !worker.finished() {
            assert!(Instant::now() < deadline, "the round never ended");
            std::thread::sleep(Duration::from_millis(10));
        }
        let (_, outcome) = worker.stop();
        let err = outcome.expect_err("the thread's error");
        assert!(format!("{err:#}").contains("is the disk full?"), "{err:#}");
    }
}
