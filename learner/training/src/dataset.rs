//! The global affordance dataset: labelled frames of every episode, split into
//! train / validation / test, used for training until each frame's 35th use,
//! with a bound on memory. Each held-out split keeps only its newest frames:
//! older ones move to training, so held-out data stays recent and bounded
//! while training frames, which leave after their uses, keep coming.
//!
//! The cap can spare the frames that show an affordance's rare positives
//! (`rare_positive_share`): a pick-up succeeds a few dozen times in 10 k
//! steps, and the newest frames alone (dropped oldest first) hold only the
//! last few successes, fewer as the policy tries less. Keeping them did not
//! stop the network's ranking from falling late in a run, and ranked objects
//! worse (docs/ladder.md, "Rare positives kept"); off by default.

use std::collections::VecDeque;
use std::sync::Arc;

use rand::Rng;

use crate::affordance::LabelledFrame;

/// Settings of the dataset.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DatasetConfig {
    /// A training frame leaves the pool after this many uses (the paper's 35).
    pub max_uses: u32,
    /// Frames held at most, all splits together; beyond it the oldest go.
    pub max_frames: usize,
    /// Probability that a new frame goes to validation.
    pub validation_fraction: f64,
    /// Probability that a new frame goes to test.
    pub test_fraction: f64,
    /// Frames each held-out split keeps; beyond it the oldest move to training.
    pub max_held_out: usize,
    /// The cap spares training frames with positive labels of an affordance
    /// that has positives in fewer than this share of the training frames
    /// (they still leave after their uses); 0 spares none. Self-limiting:
    /// once an affordance's positive frames reach the share, the cap drops
    /// them oldest first like any other.
    pub rare_positive_share: f64,
    /// Every frame of an episode goes to the split its episode draws, so
    /// that held-out frames come from episodes the network never trained
    /// on; otherwise each frame draws its own, and a validation frame's
    /// neighbours in its episode, nearly the same picture, are training
    /// frames.
    pub split_by_episode: bool,
}

impl Default for DatasetConfig {
    fn default() -> Self {
        Self {
            max_uses: 35,
            max_frames: 20_000,
            validation_fraction: 0.15,
            test_fraction: 0.15,
            max_held_out: 512,
            rare_positive_share: 0.0,
            split_by_episode: false,
        }
    }
}

/// Which part of the dataset a frame is in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Split {
    /// Used for gradient steps.
    Train,
    /// Used to decide whether a new network replaces the deployed one.
    Validation,
    /// Held out for reporting.
    Test,
}

/// A frame in the pool.
#[derive(Debug, Clone)]
struct Entry {
    episode: u64,
    frame: Arc<LabelledFrame>,
    uses: u32,
    /// Bit `a` set: the frame has a positive label for affordance `a`.
    positives: u64,
}

/// A number in `[0, 1)` fixed by `episode` (splitmix64's finaliser): the
/// split draw of every frame of the episode, in whichever part it arrives.
fn unit_of(episode: u64) -> f64 {
    let mut z = episode.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 53) as f64
}

/// The affordances (as bits, the first 64) with a positive label in `frame`.
fn positive_planes(frame: &LabelledFrame) -> u64 {
    let pixels = frame.size[0] * frame.size[1];
    frame
        .labels
        .chunks(pixels.max(1))
        .take(64)
        .enumerate()
        .filter(|(_, plane)| plane.contains(&1))
        .fold(0, |bits, (a, _)| bits | 1 << a)
}

/// Counters a user would watch.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DatasetCounters {
    /// Frames ever added.
    pub added: u64,
    /// Training frames that left after `max_uses` uses.
    pub evicted_after_uses: u64,
    /// Frames dropped (oldest first) to stay under `max_frames`.
    pub evicted_by_cap: u64,
    /// Times the cap passed over a frame with rare positives to drop a
    /// newer one (`rare_positive_share`).
    pub spared_by_cap: u64,
    /// Held-out frames moved to training when their split was full.
    pub moved_to_train: u64,
}

/// The global dataset.
#[derive(Debug, Clone)]
pub struct AffordanceDataset {
    config: DatasetConfig,
    train: VecDeque<Entry>,
    validation: VecDeque<Entry>,
    test: VecDeque<Entry>,
    counters: DatasetCounters,
}

impl AffordanceDataset {
    /// An empty dataset.
    pub fn new(config: DatasetConfig) -> Self {
        Self {
            config,
            train: VecDeque::new(),
            validation: VecDeque::new(),
            test: VecDeque::new(),
            counters: DatasetCounters::default(),
        }
    }

    /// Frames per split: (train, validation, test).
    pub fn sizes(&self) -> (usize, usize, usize) {
        (self.train.len(), self.validation.len(), self.test.len())
    }

    /// Eviction and addition counters.
    pub fn counters(&self) -> DatasetCounters {
        self.counters
    }

    /// Adds an episode's labelled frames, each drawn into a split with the
    /// configured probabilities; returns the split of each frame, in order.
    pub fn add_episode(
        &mut self,
        episode: u64,
        frames: Vec<LabelledFrame>,
        rng: &mut impl Rng,
    ) -> Vec<Split> {
        let mut splits = Vec::with_capacity(frames.len());
        // An episode sent in parts draws the same for each part.
        let episode_draw = self.config.split_by_episode.then(|| unit_of(episode));
        for frame in frames {
            let u: f64 = episode_draw.unwrap_or_else(|| rng.random());
            let split = if u < self.config.validation_fraction {
                Split::Validation
            } else if u < self.config.validation_fraction + self.config.test_fraction {
                Split::Test
            } else {
                Split::Train
            };
            let entry = Entry {
                episode,
                positives: positive_planes(&frame),
                frame: Arc::new(frame),
                uses: 0,
            };
            match split {
                Split::Train => self.train.push_back(entry),
                Split::Validation => self.validation.push_back(entry),
                Split::Test => self.test.push_back(entry),
            }
            self.counters.added += 1;
            splits.push(split);
        }
        for held_out in [&mut self.validation, &mut self.test] {
            while held_out.len() > self.config.max_held_out {
                let Some(oldest) = held_out.pop_front() else {
                    break;
                };
                self.train.push_back(oldest);
                self.counters.moved_to_train += 1;
            }
        }
        self.enforce_cap();
        splits
    }

    /// Drops the oldest frames (training first, then validation, then test)
    /// until the total fits `max_frames`; training frames with rare
    /// positives go after every other training frame.
    fn enforce_cap(&mut self) {
        while self.train.len() + self.validation.len() + self.test.len() > self.config.max_frames {
            let rare = self.rare_affordances();
            let dropped = match self.train.iter().position(|e| e.positives & rare == 0) {
                Some(i) => {
                    self.counters.spared_by_cap += u64::from(i > 0);
                    self.train.remove(i)
                }
                None => self.train.pop_front(),
            }
            .or_else(|| self.validation.pop_front())
            .or_else(|| self.test.pop_front());
            if dropped.is_none() {
                break;
            }
            self.counters.evicted_by_cap += 1;
        }
    }

    /// Training frames with a positive label, per affordance (the first
    /// `affordances`): how many of its rare positives the U-Net trains on.
    pub fn positive_frames(&self, affordances: usize) -> Vec<usize> {
        (0..affordances.min(64))
            .map(|a| {
                self.train
                    .iter()
                    .filter(|e| e.positives >> a & 1 == 1)
                    .count()
            })
            .collect()
    }

    /// The affordances (as bits) whose positive labels are in fewer than
    /// `rare_positive_share` of the training frames, among those that have
    /// any.
    fn rare_affordances(&self) -> u64 {
        if self.config.rare_positive_share <= 0.0 {
            return 0;
        }
        let mut counts = [0usize; 64];
        for entry in &self.train {
            let mut bits = entry.positives;
            while bits != 0 {
                counts[bits.trailing_zeros() as usize] += 1;
                bits &= bits - 1;
            }
        }
        let limit = self.config.rare_positive_share * self.train.len() as f64;
        counts
            .iter()
            .enumerate()
            .filter(|&(_, &c)| c > 0 && (c as f64) < limit)
            .fold(0, |bits, (a, _)| bits | 1 << a)
    }

    /// Draws up to `n` distinct training frames uniformly, counts one use for
    /// each, and removes those that reached `max_uses`. Empty if there is no
    /// training data.
    pub fn sample_train(&mut self, n: usize, rng: &mut impl Rng) -> Vec<Arc<LabelledFrame>> {
        let picked = rand::seq::index::sample(rng, self.train.len(), n.min(self.train.len()));
        let mut out = Vec::with_capacity(picked.len());
        for i in picked.iter() {
            let entry = &mut self.train[i];
            entry.uses += 1;
            out.push(entry.frame.clone());
        }
        let max_uses = self.config.max_uses;
        let before = self.train.len();
        self.train.retain(|e| e.uses < max_uses);
        self.counters.evicted_after_uses += (before - self.train.len()) as u64;
        out
    }

    /// Up to `n` validation frames for the gate and the temperature: the
    /// newest, or, when whole episodes are held out, frames spread evenly
    /// over the split (the newest `n` would be one or two episodes, one or
    /// two rooms).
    pub fn gate_frames(&self, n: usize) -> Vec<Arc<LabelledFrame>> {
        let frames = &self.validation;
        let len = frames.len();
        if !self.config.split_by_episode || len <= n {
            return frames
                .iter()
                .skip(len.saturating_sub(n))
                .map(|e| e.frame.clone())
                .collect();
        }
        // The i-th of n evenly spaced, the newest last.
        (0..n)
            .map(|i| {
                frames[len - 1 - (n - 1 - i) * (len - 1) / (n - 1).max(1)]
                    .frame
                    .clone()
            })
            .collect()
    }

    /// Frames of one split.
    pub fn frames(&self, split: Split) -> Vec<Arc<LabelledFrame>> {
        let part = match split {
            Split::Train => &self.train,
            Split::Validation => &self.validation,
            Split::Test => &self.test,
        };
        part.iter().map(|e| e.frame.clone()).collect()
    }

    /// Episodes that still have frames in the training split.
    pub fn training_episodes(&self) -> Vec<u64> {
        let mut v: Vec<u64> = self.train.iter().map(|e| e.episode).collect();
        v.sort_unstable();
        v.dedup();
        v
    }
}
