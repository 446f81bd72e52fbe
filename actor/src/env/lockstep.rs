//! Several environments stepped as one, a thread each (the actor's way for
//! policies with a GRU; the others' environments run free,
//! [`super::threads`]).
//!
//! [`Inference::Batched`] (for a U-Net on a GPU): the first halves of their
//! resets or steps run in parallel, the U-Net sees all their camera frames in
//! one batch, then the second halves run in parallel: batches of frames
//! rather than one frame at a time. [`Inference::PerEnvironment`] (for the
//! CPU, where a batch costs the same per frame): each environment runs its
//! whole reset or step, U-Net pass included, on its thread, and none waits
//! for the others halfway.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use rayon::prelude::*;

use super::affordance_model::{AffordanceModel, CameraFrame};
use super::time_tally::TimeTally;
use super::{Environment, Observation, StepOutcome};

/// How the networks see several environments' inputs (the U-Net their
/// frames, the actor's policy their observations).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Inference {
    /// All inputs in one forward pass; the U-Net's between the halves of
    /// every environment's reset or step (for a GPU).
    Batched,
    /// Each input on a thread of its own; the U-Net's on its environment's
    /// thread, inside its reset or step (for the CPU, where a batch costs
    /// the same per input, on one thread).
    PerEnvironment,
}

impl Inference {
    /// The way that suits networks on `device`.
    pub fn for_device(device: &burn::prelude::Device) -> Self {
        if nets::device::is_cpu(device) {
            Self::PerEnvironment
        } else {
            Self::Batched
        }
    }
}

/// Where [`Inference::Batched`] resets and steps spent their time in this
/// process, in all: what a profiler would say of a lock-step round (which
/// half waits for the slowest environment, how long the U-Net's batch
/// takes), read by benchmarks as the difference of two readings.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PhaseTimes {
    /// Batched resets and steps.
    pub rounds: u64,
    /// The first halves, in parallel (simulation, rendering, and what an
    /// environment does before it needs the U-Net).
    pub first_halves: Duration,
    /// The slowest environment's first half of each round, in all: what
    /// the rounds' first halves would take if nothing but the barrier
    /// held them up.
    pub slowest_first_halves: Duration,
    /// Every environment's first half, in all (divided by the rounds and
    /// the environments: the mean, which grows over one environment's
    /// alone when the environments compete for something).
    pub each_first_half: Duration,
    /// The U-Net's batches.
    pub unet: Duration,
    /// The second halves, in parallel (the observation: map, state).
    pub second_halves: Duration,
}

impl PhaseTimes {
    /// The time from `earlier` to this reading.
    pub fn since(&self, earlier: &PhaseTimes) -> PhaseTimes {
        PhaseTimes {
            rounds: self.rounds - earlier.rounds,
            first_halves: self.first_halves - earlier.first_halves,
            slowest_first_halves: self.slowest_first_halves - earlier.slowest_first_halves,
            each_first_half: self.each_first_half - earlier.each_first_half,
            unet: self.unet - earlier.unet,
            second_halves: self.second_halves - earlier.second_halves,
        }
    }
}

/// Each phase's time and the rounds, process-wide.
static ROUNDS: AtomicU64 = AtomicU64::new(0);
static FIRST_HALVES: TimeTally = TimeTally::new();
static SLOWEST_FIRST_HALVES: TimeTally = TimeTally::new();
static EACH_FIRST_HALF: TimeTally = TimeTally::new();
static UNET: TimeTally = TimeTally::new();
static SECOND_HALVES: TimeTally = TimeTally::new();

/// This process's [`PhaseTimes`] so far.
pub fn phase_times() -> PhaseTimes {
    PhaseTimes {
        rounds: ROUNDS.load(Ordering::Relaxed),
        first_halves: FIRST_HALVES.total(),
        slowest_first_halves: SLOWEST_FIRST_HALVES.total(),
        each_first_half: EACH_FIRST_HALF.total(),
        unet: UNET.total(),
        second_halves: SECOND_HALVES.total(),
    }
}

/// Adds the time since `started` to `phase`; the time now.
fn lap(phase: &TimeTally, started: Instant) -> Instant {
    let now = Instant::now();
    phase.add(now - started);
    now
}

/// `first_half` of every environment of `envs` with its argument in
/// `args`, in parallel; each one's time is booked in [`PhaseTimes`].
fn first_halves<E: Environment + ?Sized, A: Sync, R: Send>(
    envs: &mut [&mut E],
    args: &[A],
    first_half: impl Fn(&mut E, &A) -> anyhow::Result<R> + Sync,
) -> anyhow::Result<Vec<R>> {
    let timed: Vec<(R, Duration)> = envs
        .par_iter_mut()
        .zip(args)
        .map(|(env, arg)| {
            let started = Instant::now();
            let result = first_half(&mut **env, arg)?;
            Ok((result, started.elapsed()))
        })
        .collect::<anyhow::Result<_>>()?;
    let times = timed.iter().map(|(_, t)| *t);
    SLOWEST_FIRST_HALVES.add(times.clone().max().unwrap_or_default());
    EACH_FIRST_HALF.add(times.sum());
    Ok(timed.into_iter().map(|(r, _)| r).collect())
}

/// Resets every environment of `envs` with its seed in `seeds`.
pub fn reset_all<E: Environment + ?Sized>(
    envs: &mut [&mut E],
    seeds: &[u64],
    model: Option<&AffordanceModel>,
    inference: Inference,
) -> anyhow::Result<Vec<Observation>> {
    anyhow::ensure!(envs.len() == seeds.len(), "one seed per environment");
    if inference == Inference::PerEnvironment {
        return envs
            .par_iter_mut()
            .zip(seeds)
            .map(|(env, &seed)| {
                env.begin_reset(seed)?;
                observe_alone(&mut **env, model)
            })
            .collect();
    }
    let started = Instant::now();
    first_halves(envs, seeds, |env, &seed| env.begin_reset(seed))?;
    observe_batched(envs, model, lap(&FIRST_HALVES, started))
}

/// Steps every environment of `envs` with its action in `actions`.
pub fn step_all<E: Environment + ?Sized>(
    envs: &mut [&mut E],
    actions: &[u32],
    model: Option<&AffordanceModel>,
    inference: Inference,
) -> anyhow::Result<Vec<(StepOutcome, Observation)>> {
    anyhow::ensure!(envs.len() == actions.len(), "one action per environment");
    if inference == Inference::PerEnvironment {
        return envs
            .par_iter_mut()
            .zip(actions)
            .map(|(env, &action)| {
                let outcome = env.begin_step(action)?;
                Ok((outcome, observe_alone(&mut **env, model)?))
            })
            .collect();
    }
    let started = Instant::now();
    let outcomes = first_halves(envs, actions, |env, &action| env.begin_step(action))?;
    let halfway = lap(&FIRST_HALVES, started);
    Ok(outcomes
        .into_iter()
        .zip(observe_batched(envs, model, halfway)?)
        .collect())
}

/// The U-Net's planes for `frames` (`None`: an environment without a camera).
fn predict<'f>(
    frames: impl IntoIterator<Item = Option<CameraFrame<'f>>>,
    model: Option<&AffordanceModel>,
) -> anyhow::Result<Vec<Vec<Vec<f32>>>> {
    let frames: Vec<_> = frames.into_iter().collect();
    let batch: Vec<_> = frames.iter().flatten().copied().collect();
    let mut predicted = match (batch.is_empty(), model) {
        (true, _) => Vec::new(),
        (false, Some(model)) => model.predict_batch(&batch),
        (false, None) => anyhow::bail!("this environment's camera frames need the U-Net"),
    }
    .into_iter();
    Ok(frames
        .iter()
        .map(|f| match f {
            Some(_) => predicted.next().unwrap_or_default(),
            None => Vec::new(),
        })
        .collect())
}

/// The second half of one environment's reset or step.
fn observe_alone<E: Environment + ?Sized>(
    env: &mut E,
    model: Option<&AffordanceModel>,
) -> anyhow::Result<Observation> {
    let affordances = predict([env.camera_frame()], model)?;
    env.observe(affordances.into_iter().next().unwrap_or_default())
}

/// The second halves: the U-Net over every camera frame in one batch, then
/// each environment's observation; `halfway` is when the first halves ended.
fn observe_batched<E: Environment + ?Sized>(
    envs: &mut [&mut E],
    model: Option<&AffordanceModel>,
    halfway: Instant,
) -> anyhow::Result<Vec<Observation>> {
    let affordances = predict(envs.iter().map(|e| e.camera_frame()), model)?;
    let predicted = lap(&UNET, halfway);
    let observations = envs
        .par_iter_mut()
        .zip(affordances)
        .map(|(env, a)| env.observe(a))
        .collect();
    lap(&SECOND_HALVES, predicted);
    ROUNDS.fetch_add(1, Ordering::Relaxed);
    observations
}
