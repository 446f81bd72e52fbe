//! What the learner knows about the run: counters, versions, per-actor state.
//! One struct behind a mutex; `/api/status` and `/metrics` both render the same
//! [`StatusSnapshot`], so they always agree.

use std::borrow::Cow;
use std::collections::{BTreeMap, VecDeque};
use std::time::Instant;

use prometheus_client::metrics::histogram::{exponential_buckets, Histogram};
use proto::{EpisodeStats, MessageKind};
use serde::Serialize;

use training::ppo::PpoStats;

use training::affordance_learner::{RoundSeconds, UnetRound};

/// Per-actor book-keeping.
#[derive(Debug, Clone)]
pub struct ActorState {
    last_seen: Instant,
    /// Messages accepted from this actor, per kind.
    pub received: BTreeMap<&'static str, u64>,
    /// Messages this actor sent that never arrived (gaps in its sequence
    /// numbers), per kind: which of the learner's buffers overflowed (or
    /// which of its services a gateway lost messages on).
    pub dropped_by_kind: BTreeMap<&'static str, u64>,
    /// Environment steps in accepted rollout chunks.
    pub env_steps: u64,
    /// Current policy version minus the version its newest chunk was produced with.
    pub policy_lag: u64,
    /// Policy version of its newest chunk.
    pub policy_version: u64,
    next_sequence: BTreeMap<&'static str, u64>,
    /// When its recent chunks arrived, for its steps per second.
    rate: StepRate,
}

/// Steps per second from the arrival times of recent chunks. A chunk
/// carries many steps (1 024 for an actor of 32 environments at the
/// paper's scale), so steps counted between two looks a few seconds apart
/// are often none: the rate is taken from the first to the last chunk of
/// the last [`RATE_WINDOW`] instead.
#[derive(Debug, Clone, Default)]
pub(crate) struct StepRate {
    /// (arrival, steps counted up to and including that chunk), oldest first.
    arrivals: VecDeque<(Instant, u64)>,
}

/// How far back [`StepRate`] looks.
pub(crate) const RATE_WINDOW: std::time::Duration = std::time::Duration::from_secs(60);

impl StepRate {
    /// Books a chunk of `steps` arriving at `at`.
    pub(crate) fn add(&mut self, at: Instant, steps: u64) {
        let total = self.arrivals.back().map_or(0, |&(_, n)| n) + steps;
        self.arrivals.push_back((at, total));
        // Keep one arrival older than the window: the span starts there.
        while self.arrivals.len() > 2
            && self
                .arrivals
                .get(1)
                .is_some_and(|&(t, _)| at.duration_since(t) > RATE_WINDOW)
        {
            self.arrivals.pop_front();
        }
    }

    /// Steps per second over the chunks after the oldest one kept (its
    /// steps were taken before the span began); `None` before two chunks,
    /// and 0 once none has arrived for a whole window before `now`.
    pub(crate) fn per_s(&self, now: Instant) -> Option<f64> {
        let (&(first, first_total), &(last, last_total)) =
            (self.arrivals.front()?, self.arrivals.back()?);
        if now.duration_since(last) > RATE_WINDOW {
            return Some(0.0);
        }
        let span = last.duration_since(first).as_secs_f64();
        (span > 0.0).then(|| (last_total - first_total) as f64 / span)
    }
}

impl ActorState {
    /// Messages this actor sent that never arrived, all kinds.
    pub fn dropped(&self) -> u64 {
        self.dropped_by_kind.values().sum()
    }
}

/// The learner's counters and its latest training results: kept once here,
/// shown as they are by `/api/status` and rendered by `/metrics`.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Counters {
    /// Environment steps trained on.
    pub env_steps: u64,
    /// Policy updates done.
    pub updates: u64,
    /// Episodes reported.
    pub episodes: u64,
    /// Current policy version.
    pub policy_version: u64,
    /// Current U-Net version.
    pub unet_version: u64,
    /// Weights messages published.
    pub weights_published: u64,
    /// Checkpoints written by this process.
    pub checkpoints_written: u64,
    /// Step of the newest checkpoint.
    pub last_checkpoint_step: Option<u64>,
    /// Chunks that were valid but could not train the policy.
    pub untrainable_chunks: u64,
    /// Environment steps that went into policy updates.
    pub trained_steps: u64,
    /// Seconds the PPO batching thread spent gathering chunks into batches
    /// and building them for the device (decoding the observations, or
    /// uploading them), in all; it runs during the updates.
    pub ppo_batch_seconds: f64,
    /// Seconds the PPO training thread spent in updates, in all.
    pub ppo_update_seconds: f64,
    /// Seconds the receive loop spent on its passes (taking, checking and
    /// handing on messages, publishing weights, checkpoints), not waiting
    /// for messages: near the wall time, the loop itself is why an
    /// actor's messages are lost; far below it, the loop was kept from
    /// running (a busy host) or the messages came in bursts.
    pub receive_loop_seconds: f64,
    /// Passes of the receive loop that took longer than
    /// [`LONG_PASS_S`]: a buffer of 8 messages holds a fraction of a
    /// second of a fast actor's output, so such a pass can lose messages
    /// by itself.
    pub receive_loop_long_passes: u64,
    /// The longest pass of the receive loop so far, seconds.
    pub receive_loop_longest_pass_s: f64,
    /// Environment steps received but discarded, oldest first, because the
    /// PPO thread's queue was full (the learner could not keep up).
    pub rollout_steps_discarded: u64,
    /// Environment steps waiting for the PPO thread.
    pub rollout_steps_queued: u64,
    /// Latest update's statistics.
    pub last_update: Option<PpoStats>,
    /// Labelled frames received and queued for the U-Net.
    pub frames_received: u64,
    /// Labelled frames skipped because the U-Net trainer was behind.
    pub frames_skipped: u64,
    /// Rounds of U-Net training.
    pub unet_rounds: u64,
    /// Gradient steps of U-Net training, over all rounds: against the
    /// episodes received, how much the U-Net trains per episode.
    pub unet_steps: u64,
    /// Gradient steps the U-Net owes the episodes that arrived (its debt
    /// after the newest round or arrival).
    pub unet_owed_steps: u64,
    /// Whether the newest weights delivered tell the actors to wait for the
    /// U-Net (`[unet] hold_actors_beyond_episodes`: it owes more than that).
    pub actors_held: bool,
    /// Times the actors were told to wait for the U-Net.
    pub actor_holds: u64,
    /// Latest U-Net round.
    pub last_unet: Option<UnetRound>,
    /// Seconds of the U-Net rounds' parts, summed over all rounds.
    pub unet_round_seconds: RoundSeconds,
}

/// The learner's live state.
#[derive(Debug)]
pub struct LearnerStatus {
    /// Run id (the run directory's name).
    pub run_id: String,
    started: Instant,
    /// Counters and latest results.
    pub counters: Counters,
    /// Accepted messages per kind.
    pub received: BTreeMap<&'static str, u64>,
    /// Rejected messages per (service, reason).
    pub rejected: BTreeMap<(&'static str, &'static str), u64>,
    /// Latest episode's reported metrics.
    pub last_episode: BTreeMap<Cow<'static, str>, f32>,
    /// Each metric of the last [`EPISODE_WINDOW`] episodes that reported it.
    recent_episodes: BTreeMap<Cow<'static, str>, VecDeque<f32>>,
    /// Per-actor state, by actor id.
    pub actors: BTreeMap<u32, ActorState>,
    /// Publishers on each actor→learner service (slots taken).
    pub publishers: BTreeMap<&'static str, usize>,
    /// The services whose every publisher slot is taken.
    pub services_full: Vec<&'static str>,
    /// The background validation scorer.
    pub(crate) validation: ValidationStatus,
    /// How long updates and rounds take (shared handles: `/metrics` registers clones).
    pub timings: Timings,
}

/// What the status shows of the background validation scorer
/// (`crate::validation_scorer`).
#[derive(Debug, Clone, Default, Serialize)]
pub(crate) struct ValidationStatus {
    /// Why no checkpoint is scored, when none is (`None`: the scorer runs).
    pub off: Option<String>,
    /// Checkpoints scored.
    pub scored: u64,
    /// Checkpoints not scored because a newer one was written while they
    /// waited.
    pub skipped: u64,
    /// Scorings that failed (the scorer's log says why).
    pub failed: u64,
    /// The checkpoint being scored now.
    pub scoring_step: Option<u64>,
    /// The newest scores.
    pub last: Option<proto::ValidationScores>,
}

/// Farthest ahead of an actor's next sequence number (per kind) a message
/// may be: a million lost messages is hours of an actor's output, so a
/// larger jump is a forged number, refused rather than counted as losses.
pub(crate) const SEQUENCE_WINDOW: u64 = 1_000_000;

/// A pass of the receive loop longer than this is counted
/// ([`Counters::receive_loop_long_passes`]), seconds.
pub const LONG_PASS_S: f64 = 0.1;

/// Episodes in the means `/metrics` and `/api/status` report.
pub(crate) const EPISODE_WINDOW: usize = 100;

/// Durations of the learner's two kinds of training work, as Prometheus
/// histograms (seconds).
#[derive(Debug, Clone)]
pub struct Timings {
    /// One PPO update (every epoch and minibatch of one batch).
    pub ppo_update: Histogram,
    /// One U-Net round (its training steps, validation and calibration).
    pub unet_round: Histogram,
}

impl Default for Timings {
    fn default() -> Self {
        // 10 ms to about 80 s in factors of 2.
        let buckets = || Histogram::new(exponential_buckets(0.01, 2.0, 14));
        Self {
            ppo_update: buckets(),
            unet_round: buckets(),
        }
    }
}

/// A consistent copy of the status for rendering.
#[derive(Debug, Clone, Serialize)]
pub(crate) struct StatusSnapshot {
    /// Run id.
    pub run_id: String,
    /// Seconds since the learner started.
    pub uptime_s: f64,
    /// Counters and latest results, flattened into the JSON.
    #[serde(flatten)]
    pub counters: Counters,
    /// Actors seen within the timeout.
    pub actors_alive: usize,
    /// Accepted messages per kind.
    pub received: BTreeMap<String, u64>,
    /// Rejected messages per service and reason.
    pub rejected: Vec<RejectedCount>,
    /// Messages lost in transit (sequence gaps), all actors.
    pub dropped: u64,
    /// [`StatusSnapshot::dropped`] per kind (`rollout`, `frames`, `stats`).
    pub dropped_by_kind: BTreeMap<String, u64>,
    /// Latest episode's metrics.
    pub last_episode: BTreeMap<String, f32>,
    /// Each episode metric's mean over the last 100 episodes that reported it.
    pub episode_means: BTreeMap<String, f32>,
    /// Every actor ever seen.
    pub actors: Vec<ActorSnapshot>,
    /// Publishers on each actor→learner service: actors, and anything else
    /// holding one of its `max_actors + spare_ports` slots.
    pub publishers: BTreeMap<String, usize>,
    /// The services whose every publisher slot is taken: an actor that is
    /// not running cannot join them until a holder ends.
    pub services_full: Vec<String>,
    /// The background validation scorer: counts and the newest scores.
    pub validation: ValidationStatus,
}

/// One row of rejected-message counts.
#[derive(Debug, Clone, Serialize)]
pub(crate) struct RejectedCount {
    /// Service the message arrived on.
    pub service: String,
    /// The failed check.
    pub reason: String,
    /// How many.
    pub count: u64,
}

/// One actor in the snapshot.
#[derive(Debug, Clone, Serialize)]
pub(crate) struct ActorSnapshot {
    /// Actor id.
    pub id: u32,
    /// Seen within the timeout.
    pub alive: bool,
    /// Seconds since its last accepted message.
    pub last_seen_s: f64,
    /// Accepted messages per kind.
    pub received: BTreeMap<String, u64>,
    /// Messages lost in transit.
    pub dropped: u64,
    /// Environment steps it contributed.
    pub env_steps: u64,
    /// Policy lag of its newest chunk.
    pub policy_lag: u64,
    /// Policy version its newest chunk was produced with.
    pub policy_version: u64,
    /// Environment steps per second over its chunks of the last minute
    /// (`None` before its second chunk).
    pub steps_per_s: Option<f64>,
}

impl LearnerStatus {
    /// Books one pass of the receive loop that took `seconds`.
    pub(crate) fn add_receive_pass(&mut self, seconds: f64) {
        self.counters.receive_loop_seconds += seconds;
        if seconds > LONG_PASS_S {
            self.counters.receive_loop_long_passes += 1;
        }
        self.counters.receive_loop_longest_pass_s =
            self.counters.receive_loop_longest_pass_s.max(seconds);
    }

    /// A fresh status for `run_id`.
    pub fn new(run_id: String) -> Self {
        Self {
            run_id,
            started: Instant::now(),
            counters: Counters::default(),
            received: BTreeMap::new(),
            rejected: BTreeMap::new(),
            last_episode: BTreeMap::new(),
            recent_episodes: BTreeMap::new(),
            actors: BTreeMap::new(),
            publishers: BTreeMap::new(),
            services_full: Vec::new(),
            validation: ValidationStatus::default(),
            timings: Timings::default(),
        }
    }

    /// Records an accepted message and returns how many of the actor's earlier
    /// messages of this kind were lost (sequence gap); `None`, recording
    /// nothing, for a sequence number more than [`SEQUENCE_WINDOW`] ahead of
    /// the actor's next one, which no loss explains (a forged message).
    pub fn accept(
        &mut self,
        actor_id: u32,
        kind: MessageKind,
        sequence: u64,
        policy_version: u64,
    ) -> Option<u64> {
        let expected = self
            .actors
            .get(&actor_id)
            .and_then(|a| a.next_sequence.get(kind.as_str()).copied());
        if expected.is_some_and(|e| sequence > e.saturating_add(SEQUENCE_WINDOW)) {
            return None;
        }
        let now = Instant::now();
        let current = self.counters.policy_version;
        let actor = self.actors.entry(actor_id).or_insert_with(|| ActorState {
            last_seen: now,
            received: BTreeMap::new(),
            dropped_by_kind: BTreeMap::new(),
            env_steps: 0,
            policy_lag: 0,
            policy_version: 0,
            next_sequence: BTreeMap::new(),
            rate: StepRate::default(),
        });
        actor.last_seen = now;
        *actor.received.entry(kind.as_str()).or_default() += 1;
        *self.received.entry(kind.as_str()).or_default() += 1;
        // A restarted actor starts again at 1: only forward gaps count.
        let expected = actor
            .next_sequence
            .get(kind.as_str())
            .copied()
            .unwrap_or(sequence);
        let lost = sequence.saturating_sub(expected);
        if lost > 0 {
            *actor.dropped_by_kind.entry(kind.as_str()).or_default() += lost;
        }
        actor.next_sequence.insert(kind.as_str(), sequence + 1);
        if kind == MessageKind::Rollout {
            actor.policy_version = policy_version;
            actor.policy_lag = current.saturating_sub(policy_version);
        }
        Some(lost)
    }

    /// Adds environment steps from an accepted chunk.
    pub(crate) fn add_steps(&mut self, actor_id: u32, steps: u64) {
        self.counters.env_steps += steps;
        if let Some(actor) = self.actors.get_mut(&actor_id) {
            actor.env_steps += steps;
            actor.rate.add(Instant::now(), steps);
        }
    }

    /// Records a finished episode's metrics.
    pub(crate) fn add_episode(&mut self, stats: &EpisodeStats) {
        self.counters.episodes += 1;
        for (field, value) in stats.present() {
            self.last_episode.insert(field.name(), value);
            let recent = self.recent_episodes.entry(field.name()).or_default();
            recent.push_back(value);
            if recent.len() > EPISODE_WINDOW {
                recent.pop_front();
            }
        }
    }

    /// Counts a rejected message.
    pub(crate) fn reject(&mut self, kind: MessageKind, reason: &'static str) {
        *self
            .rejected
            .entry((proto::service::for_kind(kind), reason))
            .or_default() += 1;
    }

    /// A consistent copy for rendering.
    pub(crate) fn snapshot(&self, actor_timeout_s: f64) -> StatusSnapshot {
        let actors: Vec<ActorSnapshot> = self
            .actors
            .iter()
            .map(|(&id, a)| {
                let last_seen_s = a.last_seen.elapsed().as_secs_f64();
                ActorSnapshot {
                    id,
                    alive: last_seen_s <= actor_timeout_s,
                    last_seen_s,
                    received: a
                        .received
                        .iter()
                        .map(|(k, v)| (k.to_string(), *v))
                        .collect(),
                    dropped: a.dropped(),
                    env_steps: a.env_steps,
                    policy_lag: a.policy_lag,
                    policy_version: a.policy_version,
                    steps_per_s: a.rate.per_s(Instant::now()),
                }
            })
            .collect();
        StatusSnapshot {
            run_id: self.run_id.clone(),
            uptime_s: self.started.elapsed().as_secs_f64(),
            counters: self.counters.clone(),
            actors_alive: actors.iter().filter(|a| a.alive).count(),
            received: self
                .received
                .iter()
                .map(|(k, v)| (k.to_string(), *v))
                .collect(),
            rejected: self
                .rejected
                .iter()
                .map(|(&(service, reason), &count)| RejectedCount {
                    service: service.into(),
                    reason: reason.into(),
                    count,
                })
                .collect(),
            dropped: actors.iter().map(|a| a.dropped).sum(),
            dropped_by_kind: self.actors.values().fold(BTreeMap::new(), |mut all, a| {
                for (&kind, &n) in &a.dropped_by_kind {
                    *all.entry(kind.to_string()).or_default() += n;
                }
                all
            }),
            last_episode: self
                .last_episode
                .iter()
                .map(|(k, v)| (k.to_string(), *v))
                .collect(),
            publishers: self
                .publishers
                .iter()
                .map(|(k, v)| (k.to_string(), *v))
                .collect(),
            episode_means: self
                .recent_episodes
                .iter()
                .filter(|(_, v)| !v.is_empty())
                .map(|(k, v)| (k.to_string(), v.iter().sum::<f32>() / v.len() as f32))
                .collect(),
            actors,
            services_full: self.services_full.iter().map(|s| s.to_string()).collect(),
            validation: self.validation.clone(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_actor_sending_big_chunks_seldom_has_its_rate_over_the_last_minute() {
        let t0 = Instant::now();
        let at = |s: f64| t0 + std::time::Duration::from_secs_f64(s);
        let mut rate = StepRate::default();
        assert_eq!(rate.per_s(t0), None);
        rate.add(at(0.0), 1024);
        assert_eq!(rate.per_s(at(1.0)), None, "one chunk: no span yet");
        // 1 024 steps every 11.4 s: about 90 steps/s, whatever the moment asked.
        for k in 1..=20 {
            rate.add(at(11.4 * k as f64), 1024);
            let r = rate.per_s(at(11.4 * k as f64 + 5.0)).unwrap();
            assert!((r - 1024.0 / 11.4).abs() < 1e-6, "after chunk {k}: {r}");
        }
        assert!(rate.arrivals.len() <= 7, "a minute's chunks and one before");
        // Twice as fast from now on: within a minute the rate is the new one.
        for k in 1..=12 {
            rate.add(at(228.0 + 5.7 * k as f64), 1024);
        }
        let r = rate.per_s(at(300.0)).unwrap();
        assert!((r - 1024.0 / 5.7).abs() < 1.0, "{r}");
        assert_eq!(rate.per_s(at(400.0)), Some(0.0), "silent for a minute");
    }

    #[test]
    fn gaps_count_as_losses_and_a_jump_beyond_the_window_is_refused() {
        let mut status = LearnerStatus::new("run".into());
        let kind = MessageKind::Rollout;
        assert_eq!(status.accept(0, kind, 1, 0), Some(0));
        assert_eq!(
            status.accept(0, kind, 5, 0),
            Some(3),
            "2, 3 and 4 were lost"
        );
        assert_eq!(status.accept(0, kind, 10_000_000, 0), None, "forged");
        assert_eq!(status.actors[&0].dropped(), 3, "not counted as losses");
        assert_eq!(
            status.accept(0, kind, 6, 0),
            Some(0),
            "the real stream goes on"
        );
        assert_eq!(
            status.accept(0, kind, 1, 0),
            Some(0),
            "a restarted actor starts at 1"
        );
        assert_eq!(
            status.accept(1, kind, 10_000_000, 0),
            Some(0),
            "a first message sets where an actor starts"
        );
    }

    #[test]
    fn receive_passes_add_up_and_the_long_ones_are_counted() {
        let mut status = LearnerStatus::new("run".into());
        for seconds in [0.01, 0.25, 0.05, LONG_PASS_S, 0.5] {
            status.add_receive_pass(seconds);
        }
        assert!((status.counters.receive_loop_seconds - 0.91).abs() < 1e-9);
        assert_eq!(
            status.counters.receive_loop_long_passes, 2,
            "0.25 and 0.5 s"
        );
        assert_eq!(status.counters.receive_loop_longest_pass_s, 0.5);
    }

    #[test]
    fn losses_are_counted_per_kind_and_summed_over_actors() {
        let mut status = LearnerStatus::new("run".into());
        for (actor, kind, sequences) in [
            (0, MessageKind::Rollout, [1, 2, 4]),
            (0, MessageKind::Frames, [1, 5, 6]),
            (1, MessageKind::Frames, [1, 3, 4]),
            (1, MessageKind::Stats, [1, 2, 3]),
        ] {
            for sequence in sequences {
                status.accept(actor, kind, sequence, 0);
            }
        }
        assert_eq!(
            status.actors[&0].dropped_by_kind,
            BTreeMap::from([("frames", 3), ("rollout", 1)])
        );
        let snapshot = status.snapshot(60.0);
        assert_eq!(snapshot.dropped, 5);
        assert_eq!(
            snapshot.dropped_by_kind,
            BTreeMap::from([("frames".to_string(), 4), ("rollout".to_string(), 1)]),
            "no entry for a kind that lost nothing"
        );
    }
}
