//! PPO on threads of its own, so that the receive loop never waits for an
//! update. The loop hands each valid rollout chunk over without blocking;
//! chunks wait in a queue bounded in steps (`[policy] queue_batches` batches)
//! while an update runs. When the queue is full the oldest chunks are discarded and
//! counted (`rollout_steps_discarded`): they are the stalest, so a learner
//! that cannot keep up trains on fresh data with a bounded policy lag instead
//! of falling ever further behind.
//!
//! Two threads, one batch apart: `ppo-batching` gathers the next batch
//! (advantages, observations copied and built for the device) while
//! `ppo-training` runs the update on the one before, and hands it over only
//! when the update is done (so the policy lag grows by one update at most).
//! Gathering and building had run between updates on one thread: with
//! 1 024-step batches on an H200 they took about three quarters of an
//! update's time at 64 px and three times it at 128 px
//! (docs/notebook/2026-11-28-ppo-batches-ahead.md). After each update the training thread
//! hands the new weights back for the next broadcast; on request, between
//! updates, it hands over what a checkpoint needs.

use std::collections::{HashSet, VecDeque};
use std::sync::mpsc::{self, Receiver, Sender, SyncSender};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;

use anyhow::Context;
use proto::{decode, Limits, Message};
use training::optimizer_state::OptimizerState;

use crate::history::History;
use crate::shared::Shared;
use training::ppo_batcher::{BatchBuilder, PolicyTrainer};

/// One rollout message as it arrived, validated by the receive loop.
struct QueuedChunk {
    bytes: Vec<u8>,
    steps: usize,
}

#[derive(Default)]
struct InboxState {
    chunks: VecDeque<QueuedChunk>,
    steps: usize,
    snapshot_requested: bool,
    stop: bool,
}

/// The queue between the receive loop and the PPO thread.
struct Inbox {
    state: Mutex<InboxState>,
    changed: Condvar,
    /// Most steps queued; older chunks are discarded beyond it.
    capacity: usize,
}

impl Inbox {
    fn new(capacity: usize) -> Self {
        Self {
            state: Mutex::new(InboxState::default()),
            changed: Condvar::new(),
            capacity: capacity.max(1),
        }
    }

    fn lock(&self) -> MutexGuard<'_, InboxState> {
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Queues a chunk, discarding the oldest ones beyond the capacity (never
    /// the newest); returns the steps discarded. The status's
    /// discarded and queued counts are written while the queue is still
    /// locked, so a report of the PPO thread's cannot overwrite a newer one.
    fn push(&self, chunk: QueuedChunk, shared: &Shared) -> usize {
        let mut state = self.lock();
        state.steps += chunk.steps;
        state.chunks.push_back(chunk);
        let mut discarded = 0;
        while state.steps > self.capacity && state.chunks.len() > 1 {
            if let Some(old) = state.chunks.pop_front() {
                state.steps -= old.steps;
                discarded += old.steps;
            }
        }
        {
            let mut status = shared.status();
            status.counters.rollout_steps_discarded += discarded as u64;
            status.counters.rollout_steps_queued = state.steps as u64;
        }
        drop(state);
        self.changed.notify_one();
        discarded
    }
}

/// What the PPO thread takes in one go.
struct Taken {
    chunks: Vec<QueuedChunk>,
    snapshot: bool,
    stop: bool,
}

/// The policy after an update, for the next weights broadcast.
pub struct PublishedPolicy {
    /// Its version.
    pub version: u64,
    /// Its weights as safetensors bytes (PyTorch names, no prefix).
    pub weights: Vec<u8>,
}

/// What a checkpoint needs of the policy, taken between two updates.
pub struct PolicySnapshot {
    /// The policy's version.
    pub version: u64,
    /// Updates done when it was taken.
    pub updates: u64,
    /// Its weights as safetensors bytes.
    pub weights: Vec<u8>,
    /// Adam's state.
    pub optimizer: OptimizerState,
}

/// The running PPO thread.
pub struct PolicyWorker {
    inbox: Arc<Inbox>,
    /// Where [`PolicyWorker::offer`] counts queued and discarded steps.
    shared: Arc<Shared>,
    published: Receiver<PublishedPolicy>,
    snapshots: Receiver<PolicySnapshot>,
    /// The training thread; its result is the final snapshot.
    training: Option<JoinHandle<anyhow::Result<PolicySnapshot>>>,
    /// The batching thread.
    batching: Option<JoinHandle<()>>,
}

/// What the batching thread hands the training thread.
enum Work {
    /// A full batch, and the seconds spent gathering and building it.
    Batch(Box<training::ppo::PpoBatch>, f64),
    /// A checkpoint asked for the policy.
    Snapshot,
}

fn snapshot(trainer: &PolicyTrainer, shared: &Shared) -> anyhow::Result<PolicySnapshot> {
    Ok(PolicySnapshot {
        version: trainer.version(),
        updates: shared.status().counters.updates,
        weights: trainer.weights().context("serialising the policy")?,
        optimizer: trainer
            .optimizer_state()
            .context("saving the policy optimiser's state")?,
    })
}

impl PolicyWorker {
    /// Starts training `trainer` on threads of its own, with at most
    /// `queue_steps` steps waiting (at least one chunk always waits).
    pub fn start(
        mut trainer: PolicyTrainer,
        shared: Arc<Shared>,
        history: Arc<Mutex<History>>,
        queue_steps: usize,
    ) -> anyhow::Result<Self> {
        let inbox = Arc::new(Inbox::new(queue_steps));
        let (publish, published) = mpsc::channel();
        let (snapshot_out, snapshots) = mpsc::channel();
        // No room: a built batch waits in the batching thread until the
        // training thread takes it, so at most one is built ahead.
        let (work, work_in) = mpsc::sync_channel(0);
        let nice = shared.config.training_nice;
        let mut builder = trainer.batch_builder();
        let (batch_inbox, batch_shared) = (inbox.clone(), shared.clone());
        let batching = std::thread::Builder::new()
            .name("ppo-batching".into())
            .spawn(move || {
                crate::thread_priority::lower_this_thread(nice);
                gather(&mut builder, &batch_inbox, &batch_shared, &work);
            })
            .context("starting the PPO batching thread")?;
        let (train_inbox, train_shared) = (inbox.clone(), shared.clone());
        let training = std::thread::Builder::new()
            .name("ppo-training".into())
            .spawn(move || {
                crate::thread_priority::lower_this_thread(nice);
                let outlets = Outlets {
                    history: &history,
                    publish: &publish,
                    snapshots: &snapshot_out,
                };
                train(
                    &mut trainer,
                    &work_in,
                    &train_inbox,
                    &train_shared,
                    &outlets,
                )?;
                snapshot(&trainer, &train_shared)
            })
            .context("starting the PPO training thread")?;
        Ok(Self {
            inbox,
            shared,
            published,
            snapshots,
            training: Some(training),
            batching: Some(batching),
        })
    }

    /// Queues a validated rollout message of `steps` steps; never blocks.
    /// Returns the steps discarded to make room (the oldest chunks').
    /// Counts them in the status's `rollout_steps_discarded` and
    /// `rollout_steps_queued`.
    pub fn offer(&self, bytes: Vec<u8>, steps: usize) -> usize {
        self.inbox.push(QueuedChunk { bytes, steps }, &self.shared)
    }

    /// The newest policy published since the last call, if any.
    pub fn take_published(&self) -> Option<PublishedPolicy> {
        self.published.try_iter().last()
    }

    /// Asks for a [`PolicySnapshot`] after the current update; it arrives
    /// through [`PolicyWorker::take_snapshot`].
    pub fn request_snapshot(&self) {
        self.inbox.lock().snapshot_requested = true;
        self.inbox.changed.notify_one();
    }

    /// A snapshot asked for earlier, once it is there.
    pub fn take_snapshot(&self) -> Option<PolicySnapshot> {
        self.snapshots.try_iter().last()
    }

    /// True once either thread has ended, which before
    /// [`PolicyWorker::stop`] means it failed.
    pub fn finished(&self) -> bool {
        let training = self.training.as_ref().is_none_or(JoinHandle::is_finished);
        training || self.batching.as_ref().is_none_or(JoinHandle::is_finished)
    }

    /// Stops the threads after the current update (chunks still queued and
    /// a batch built ahead are dropped) and returns the final snapshot, or
    /// the training thread's error.
    pub fn stop(mut self) -> anyhow::Result<PolicySnapshot> {
        self.inbox.lock().stop = true;
        self.inbox.changed.notify_one();
        let result = match self.training.take().map(JoinHandle::join) {
            Some(Ok(result)) => result,
            Some(Err(_)) => Err(anyhow::anyhow!("the PPO training thread panicked")),
            None => Err(anyhow::anyhow!(
                "the PPO training thread was already stopped"
            )),
        };
        // The training thread has dropped its end, so this one is not
        // waiting to hand over a batch.
        if let Some(Err(_)) = self.batching.take().map(JoinHandle::join) {
            return Err(anyhow::anyhow!("the PPO batching thread panicked"));
        }
        result
    }
}

/// Waits for work, then takes queued chunks up to `need` steps (at least
/// one), and records the steps left in the status before the queue is
/// unlocked.
fn take(inbox: &Inbox, need: usize, shared: &Shared) -> Taken {
    let mut state = inbox.lock();
    while state.chunks.is_empty() && !state.snapshot_requested && !state.stop {
        state = inbox.changed.wait(state).unwrap_or_else(|p| p.into_inner());
    }
    let mut chunks = Vec::new();
    let mut steps = 0;
    if !state.stop {
        while steps < need.max(1) {
            let Some(chunk) = state.chunks.pop_front() else {
                break;
            };
            state.steps -= chunk.steps;
            steps += chunk.steps;
            chunks.push(chunk);
        }
    }
    shared.status().counters.rollout_steps_queued = state.steps as u64;
    Taken {
        chunks,
        snapshot: std::mem::take(&mut state.snapshot_requested),
        stop: state.stop,
    }
}

/// The batching thread's loop: take chunks, gather them into batches, hand
/// each full batch (and each snapshot request) to the training thread.
/// Ends when the learner stops or the training thread has ended.
fn gather(builder: &mut BatchBuilder, inbox: &Inbox, shared: &Shared, work: &SyncSender<Work>) {
    let t = &shared.config.transport;
    let limits = Limits {
        max_actors: t.max_actors,
        max_payload_len: t.max_bytes(proto::MessageKind::Rollout) as u64,
    };
    let batch_steps = shared.config.policy.batch_steps;
    let mut warned = HashSet::new();
    let mut seconds = 0.0;
    loop {
        let taken = take(
            inbox,
            batch_steps.saturating_sub(builder.pending_steps()),
            shared,
        );
        if taken.snapshot && work.send(Work::Snapshot).is_err() {
            return;
        }
        if taken.stop {
            return;
        }
        for chunk in taken.chunks {
            let Ok((header, Message::Rollout(view))) = decode(&chunk.bytes, &limits) else {
                continue; // the receive loop validated it: cannot happen
            };
            let started = std::time::Instant::now();
            let added = builder.add_chunk(&view, header.policy_version);
            seconds += started.elapsed().as_secs_f64();
            match added {
                Ok(Some(batch)) => {
                    if work.send(Work::Batch(Box::new(batch), seconds)).is_err() {
                        return;
                    }
                    seconds = 0.0;
                }
                Ok(None) => {}
                Err(error) => {
                    shared.status().counters.untrainable_chunks += 1;
                    if warned.insert(header.actor_id) {
                        tracing::warn!(
                            "actor {}: {error} (further ones are only counted)",
                            header.actor_id
                        );
                    }
                }
            }
        }
    }
}

/// Where the training thread's results go.
struct Outlets<'a> {
    history: &'a Mutex<History>,
    publish: &'a Sender<PublishedPolicy>,
    snapshots: &'a Sender<PolicySnapshot>,
}

/// The training thread's loop: update on each batch and publish the new
/// weights, or take a snapshot. Ends when the batching thread has ended,
/// or at a batch that comes after the learner was told to stop.
fn train(
    trainer: &mut PolicyTrainer,
    work: &Receiver<Work>,
    inbox: &Inbox,
    shared: &Shared,
    outlets: &Outlets<'_>,
) -> anyhow::Result<()> {
    while let Ok(next) = work.recv() {
        let (batch, built) = match next {
            Work::Snapshot => {
                // The receiver is gone only while the learner shuts down.
                let _ = outlets.snapshots.send(snapshot(trainer, shared)?);
                continue;
            }
            Work::Batch(batch, built) => (batch, built),
        };
        if inbox.lock().stop {
            return Ok(());
        }
        let rows = batch.actions.len();
        let started = std::time::Instant::now();
        let stats = trainer.update(&batch);
        drop(batch);
        let updated = started.elapsed().as_secs_f64();
        let version = trainer.version();
        let env_steps = {
            let mut status = shared.status();
            status.timings.ppo_update.observe(updated);
            status.counters.ppo_batch_seconds += built;
            status.counters.ppo_update_seconds += updated;
            status.counters.updates += 1;
            status.counters.last_update = Some(stats);
            status.counters.policy_version = version;
            status.counters.trained_steps += rows as u64;
            status.counters.env_steps
        };
        outlets
            .history
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .record(
                "ppo",
                env_steps,
                serde_json::json!({ "policy_version": version, "stats": stats }),
            )?;
        let weights = trainer.weights().context("serialising the policy")?;
        if outlets
            .publish
            .send(PublishedPolicy { version, weights })
            .is_err()
        {
            return Ok(());
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use std::sync::atomic::AtomicBool;
    use std::time::{Duration, Instant};

    use proto::{MessageHeader, RolloutChunk};

    use super::*;
    use crate::config::LearnerConfig;
    use crate::status::LearnerStatus;

    fn chunk(tag: u8, steps: usize) -> QueuedChunk {
        QueuedChunk {
            bytes: vec![tag],
            steps,
        }
    }

    /// A learner's shared state for tests, its run directory in `dir`.
    fn shared_state(config: &LearnerConfig, dir: &std::path::Path) -> Arc<Shared> {
        Arc::new(Shared {
            status: Mutex::new(LearnerStatus::new("test".into())),
            shutdown: AtomicBool::new(false),
            config: config.clone(),
            run_dir: dir.into(),
        })
    }

    #[test]
    fn a_full_queue_discards_its_oldest_chunks_but_never_the_newest() {
        let dir = tempfile::tempdir().unwrap();
        let shared = shared_state(&LearnerConfig::default(), dir.path());
        let counts = || {
            let status = shared.status();
            (
                status.counters.rollout_steps_queued,
                status.counters.rollout_steps_discarded,
            )
        };
        let inbox = Inbox::new(10);
        assert_eq!(inbox.push(chunk(1, 4), &shared), 0);
        assert_eq!(inbox.push(chunk(2, 4), &shared), 0);
        assert_eq!(counts(), (8, 0));
        assert_eq!(
            inbox.push(chunk(3, 4), &shared),
            4,
            "12 > 10: the oldest goes"
        );
        assert_eq!(inbox.lock().steps, 8);
        assert_eq!(counts(), (8, 4));
        assert_eq!(
            inbox.push(chunk(4, 30), &shared),
            8,
            "everything older goes"
        );
        assert_eq!(counts(), (30, 12));
        let state = inbox.lock();
        assert_eq!(state.steps, 30);
        assert_eq!(state.chunks.len(), 1);
        assert_eq!(state.chunks[0].bytes, vec![4]);
        drop(state);
        let taken = take(&inbox, 5, &shared);
        assert_eq!(taken.chunks.len(), 1);
        assert_eq!(inbox.lock().steps, 0);
        assert_eq!(counts(), (0, 12));
    }

    /// A bandit-fixture rollout message of `steps` steps from actor 0.
    fn rollout(config: &LearnerConfig, steps: usize, sequence: u64) -> Vec<u8> {
        let layout = config.task.layout();
        let chunk = RolloutChunk {
            episode_id: sequence,
            first_step: 0,
            n_actions: layout.n_actions as u32,
            obs_dtype: layout.obs_dtype,
            obs_elems: layout.obs_len() as u32,
            obs: proto::obs_bytes_from_f32(&vec![0.5; steps * layout.obs_len()]),
            actions: (0..steps).map(|i| (i % layout.n_actions) as u32).collect(),
            masks: vec![1; steps * layout.n_actions],
            log_probs: vec![-(layout.n_actions as f32).ln(); steps],
            values: vec![0.0; steps],
            rewards: (0..steps).map(|i| (i % 2) as f32).collect(),
            dones: vec![0; steps],
            bootstrap_value: 0.0,
            start_hidden: Vec::new(),
        };
        let header = MessageHeader {
            actor_id: 0,
            policy_version: 1,
            sequence,
            ..MessageHeader::default()
        };
        proto::encode(&chunk, header)
    }

    /// A PPO worker for the bandit fixture, at version 1, with its run
    /// directory in `dir`: its config, shared state and the worker.
    fn bandit_worker(
        dir: &std::path::Path,
        batch_steps: usize,
        queue_steps: usize,
    ) -> (LearnerConfig, Arc<Shared>, PolicyWorker) {
        let mut config = LearnerConfig::default();
        config.task.env = proto::EnvKind::BanditFixture;
        config.policy.batch_steps = batch_steps;
        let device = burn::prelude::Device::flex();
        let mut trainer = PolicyTrainer::new(&config.task, &config.policy, &device);
        trainer.set_version(1);
        let shared = shared_state(&config, dir);
        let history = Arc::new(Mutex::new(History::open(dir).unwrap()));
        let worker = PolicyWorker::start(trainer, shared.clone(), history, queue_steps).unwrap();
        (config, shared, worker)
    }

    #[test]
    fn the_next_batch_is_taken_during_an_update_and_stop_returns() {
        let dir = tempfile::tempdir().unwrap();
        let (config, shared, worker) = bandit_worker(dir.path(), 4, 1 << 20);
        let batches = 200;
        for sequence in 1..=batches {
            assert_eq!(worker.offer(rollout(&config, 4, sequence), 4), 0);
        }
        // One thread would take a batch, update, and only then take the
        // next: steps taken from the queue would never lead steps trained
        // by more than the batch in its update. Two lead by two batches
        // while the next waits to be handed over.
        let deadline = Instant::now() + Duration::from_secs(60);
        let mut lead = 0;
        while lead < 8 {
            let status = shared.status();
            assert!(
                Instant::now() < deadline && status.counters.updates < batches,
                "never two batches ahead of training"
            );
            lead = (batches * 4 - status.counters.rollout_steps_queued)
                .saturating_sub(status.counters.trained_steps);
        }
        let last = worker.stop().unwrap();
        let status = shared.status();
        assert_eq!(
            last.version,
            1 + status.counters.updates,
            "one version an update"
        );
        assert_eq!(status.counters.trained_steps, 4 * status.counters.updates);
    }

    #[test]
    fn updates_publish_weights_and_a_snapshot_comes_between_updates() {
        let dir = tempfile::tempdir().unwrap();
        let (config, shared, worker) = bandit_worker(dir.path(), 8, 64);
        for sequence in 1..=4 {
            assert_eq!(worker.offer(rollout(&config, 4, sequence), 4), 0);
        }
        let deadline = Instant::now() + Duration::from_secs(60);
        let mut versions = Vec::new();
        while versions.last() != Some(&3) {
            assert!(
                Instant::now() < deadline,
                "two updates never came: {versions:?}"
            );
            if let Some(published) = worker.take_published() {
                assert!(!published.weights.is_empty());
                versions.push(published.version);
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        worker.request_snapshot();
        let snapshot = loop {
            assert!(Instant::now() < deadline, "no snapshot");
            if let Some(snapshot) = worker.take_snapshot() {
                break snapshot;
            }
            std::thread::sleep(Duration::from_millis(5));
        };
        assert_eq!((snapshot.version, snapshot.updates), (3, 2));
        let status = shared.status();
        assert_eq!(
            (status.counters.updates, status.counters.trained_steps),
            (2, 16)
        );
        assert_eq!(status.counters.policy_version, 3);
        drop(status);
        let last = worker.stop().unwrap();
        assert_eq!(last.version, 3);
    }
}
