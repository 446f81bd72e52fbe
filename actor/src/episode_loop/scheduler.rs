//! The actor's one scheduler: its environments run on threads of their own
//! ([`EnvThreads`], `crate::sampling`); this thread keeps the bookkeeping,
//! the policy and the learner's ports, and gives each environment its next
//! task as soon as its last one is done.
//!
//! With several environments, which one starts which episode (and so draws
//! which random numbers) depends on timing; each episode's reset seed is
//! still its id's, and with one environment a run is what its seeds make.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use super::loop_clock::{Chore, LoopClock};
use super::{Acted, Actor, ChunkClose, RunningEpisode};
use crate::env::step_phases::step_phases;
use crate::env::{Environment, Observation, StepOutcome};
use crate::sampling::env_threads::{Done, EnvThreads, PolicyPass, Task};
use crate::sampling::unet_batcher::batch_times;

/// Where an environment is, as the loop sees it.
enum Phase {
    /// Nothing to do (no more episodes here).
    Idle,
    /// Resetting into episode `id`.
    Resetting(u64),
    /// Stepping its episode with an action the policy chose.
    Stepping(RunningEpisode, Acted),
    /// Ending its episode.
    Finishing(RunningEpisode),
}

/// Runs `envs` until `stop` is set or `max_episodes` are done.
pub(super) fn run(
    actor: &mut Actor<'_>,
    envs: Vec<Box<dyn Environment>>,
    stop: &AtomicBool,
) -> anyhow::Result<()> {
    let model = actor.model;
    let started = Instant::now();
    let steps_before = actor.summary.steps;
    let batches_before = batch_times();
    let phases_before = step_phases();
    let clock = std::thread::scope(|scope| {
        let threads = EnvThreads::start(scope, envs, model, actor.inference);
        drive(actor, &threads, stop)
        // Dropping `threads` ends them; the scope waits for them.
    })?;
    tracing::info!(
        "actor {}: {}",
        actor.settings.actor_id,
        clock.report(started.elapsed(), actor.summary.steps - steps_before)
    );
    // Whether the U-Net's batching threads, which every environment also
    // waits for, were the wall instead.
    if let Some(unet) = batch_times()
        .since(&batches_before)
        .describe(started.elapsed())
    {
        tracing::info!("actor {}: {unet}", actor.settings.actor_id);
    }
    // And what its environments' steps were made of: their own work, or
    // waiting (for a render's read-back, for their frame's U-Net batch).
    if let Some(phases) = step_phases().since(&phases_before).describe() {
        tracing::info!("actor {}: {phases}", actor.settings.actor_id);
    }
    Ok(())
}

/// An environment waiting for its next action, chosen with the others
/// that need one (from the policy's pass its thread made, if any).
struct Waiting {
    index: usize,
    episode: RunningEpisode,
    pass: Option<PolicyPass>,
    /// After a step: the action taken, its outcome and the observation it
    /// led to, booked into the episode once every action has gone out.
    unbooked: Option<(Acted, StepOutcome, Observation)>,
}

impl Waiting {
    /// What the policy acts on: the newest observation and the recurrent
    /// state after the last action.
    fn input(&self) -> (&Observation, Option<&[f32]>) {
        match &self.unbooked {
            Some((acted, _, observation)) => (observation, acted.hidden.as_deref()),
            None => (&self.episode.observation, self.episode.hidden.as_deref()),
        }
    }
}

/// Hands out tasks and books what comes back: of every task finished by the
/// time it looks, the episodes' ends and the resets that follow go out
/// first, then the actions of those that need one, from the policy's
/// passes the environments' threads made (this thread runs only those
/// whose policy new weights replaced meanwhile); what the steps and ends
/// leave to book (rollout chunks, labelled frames) it does after, while
/// the environments work. Returns where its time went.
fn drive(
    actor: &mut Actor<'_>,
    threads: &EnvThreads,
    stop: &AtomicBool,
) -> anyhow::Result<LoopClock> {
    let mut clock = LoopClock::default();
    let share_policy = |actor: &Actor<'_>| match &actor.policy.cpu {
        Some(cpu) => threads.set_policy(actor.policy.policy_version, cpu),
        None => Ok(()),
    };
    share_policy(actor)?;
    let start = |actor: &mut Actor<'_>, index: usize| -> anyhow::Result<Phase> {
        if stop.load(Ordering::Relaxed) {
            return Ok(Phase::Idle);
        }
        Ok(match actor.next_episode_id() {
            Some(id) => {
                threads.send(index, Task::Reset(actor.seed_of(id)))?;
                Phase::Resetting(id)
            }
            None => Phase::Idle,
        })
    };
    let mut phases = Vec::with_capacity(threads.len());
    for index in 0..threads.len() {
        phases.push(start(actor, index)?);
    }
    while phases.iter().any(|p| !matches!(p, Phase::Idle)) {
        let asleep = Instant::now();
        let mut finished = vec![threads.next()?];
        clock.waited += asleep.elapsed();
        finished.extend(threads.finished()?);
        let version = actor.policy.policy_version;
        let taken = clock.time(Chore::Weights, || actor.refresh_weights())?;
        if let Some(steps) = actor.wait_while_held(stop)?.or(taken) {
            threads.set_global_steps(steps)?;
        }
        if actor.policy.policy_version != version {
            share_policy(actor)?;
        }
        let stopping = stop.load(Ordering::Relaxed);
        let mut waiting = Vec::new();
        let mut ended = Vec::new();
        for (index, done) in finished {
            let phase = std::mem::replace(&mut phases[index], Phase::Idle);
            match (phase, done) {
                (Phase::Resetting(id), Done::Reset(observation, pass)) => waiting.push(Waiting {
                    index,
                    episode: actor.begin_episode(id, observation),
                    pass,
                    unbooked: None,
                }),
                (Phase::Stepping(mut episode, acted), Done::Step(outcome, observation, pass)) => {
                    if outcome.done || stopping {
                        let booking = (acted, &outcome, observation);
                        book_step(actor, &mut clock, &mut episode, booking, stopping, None)?;
                        threads.send(index, Task::Finish(episode.id))?;
                        phases[index] = Phase::Finishing(episode);
                    } else {
                        waiting.push(Waiting {
                            index,
                            episode,
                            pass,
                            unbooked: Some((acted, outcome, observation)),
                        });
                    }
                }
                (Phase::Finishing(episode), Done::Finish { end, scene }) => {
                    phases[index] = start(actor, index)?;
                    ended.push((episode, end, scene));
                }
                _ => anyhow::bail!("environment {index} answered a task it was not given"),
            }
        }
        if !waiting.is_empty() {
            let passes = waiting.iter_mut().map(|w| w.pass.take()).collect();
            let inputs: Vec<_> = waiting.iter().map(Waiting::input).collect();
            let acted = clock.time(Chore::Actions, || -> anyhow::Result<_> {
                let acted = actor.act(&inputs, passes)?;
                anyhow::ensure!(acted.len() == waiting.len(), "the policy acted for each");
                for (w, acted) in waiting.iter().zip(&acted) {
                    threads.send(w.index, Task::Step(acted.action, acted.hidden.clone()))?;
                }
                Ok(acted)
            })?;
            for (mut w, acted) in waiting.into_iter().zip(acted) {
                if let Some((taken, outcome, observation)) = w.unbooked {
                    // The pass that chose the next action valued the
                    // observation this step led to: the bootstrap value of
                    // a chunk this step fills.
                    let booking = (taken, &outcome, observation);
                    let next_value = Some(acted.value);
                    book_step(
                        actor,
                        &mut clock,
                        &mut w.episode,
                        booking,
                        stopping,
                        next_value,
                    )?;
                }
                phases[w.index] = Phase::Stepping(w.episode, acted);
            }
        }
        clock.time(Chore::Ends, || -> anyhow::Result<()> {
            for (episode, end, scene) in ended {
                actor.publish_end(&episode, end, scene)?;
            }
            Ok(())
        })?;
    }
    Ok(clock)
}

/// Books a step (the action taken, its outcome and the observation it led
/// to) into `episode` (`Actor::record_step`) and sends its chunk to the
/// learner if that closed it (`next_value`: the critic's value of that
/// observation, if known).
fn book_step(
    actor: &mut Actor<'_>,
    clock: &mut LoopClock,
    episode: &mut RunningEpisode,
    (acted, outcome, observation): (Acted, &StepOutcome, Observation),
    stopping: bool,
    next_value: Option<f32>,
) -> anyhow::Result<()> {
    let closed = clock.time(Chore::Booking, || {
        actor.record_step(episode, acted, outcome, observation, stopping)
    });
    if let Some(done) = closed {
        let close = ChunkClose::after(done, next_value);
        clock.time(Chore::Chunks, || actor.close_chunks(vec![(episode, close)]))?;
    }
    Ok(())
}
