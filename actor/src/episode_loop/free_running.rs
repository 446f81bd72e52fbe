//! The loop over free-running environments ([`EnvThreads`]): this thread
//! keeps the bookkeeping, the policy and the learner's ports, and gives each
//! environment its next task as soon as its last one is done.
//!
//! Unlike lock-step, which environment starts which episode (and so draws
//! which random numbers) depends on timing; each episode's reset seed is
//! still its id's.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use super::{Acted, Actor, RunningEpisode};
use crate::env::threads::{Done, EnvThreads, PolicyPass, Task};
use crate::env::Environment;

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

/// Whether `envs` environments should run free: several of them, and a
/// policy with the CPU's own pass (`nets::policy::CpuPolicy`), which the
/// environments' threads run on their observations (a GRU's state goes
/// with each step's task). Free-running, nobody waits for the slowest
/// environment at a barrier. Measured (env bench, policy included):
/// on the VM's CPU, 2 environments at 64 px, `ours` 121–149 steps/s in
/// lock-step against 115–145 free-running, `nomap-seg` (a GRU) 151–208
/// against 167–235 (five runs each, 2026-11-27); on an H200 at 128 px
/// with 16 environments, the U-Net's frames batched by one thread
/// (`crate::env::unet_batcher`), `ours` 217 against 353 and `nomap-seg`
/// 712 against 970, with 32 environments 287 / 469 and 888 / 1 049
/// (docs/notebook/2026-11-27-gpu-check-free-running.md).
pub(super) fn suits(actor: &Actor<'_>, envs: usize) -> bool {
    envs > 1 && actor.policy.cpu.is_some()
}

/// Runs `envs` free-running until `stop` is set or `max_episodes` are done.
pub(super) fn run(
    actor: &mut Actor<'_>,
    envs: Vec<Box<dyn Environment>>,
    stop: &AtomicBool,
) -> anyhow::Result<()> {
    let model = actor.model;
    let started = Instant::now();
    let waited = std::thread::scope(|scope| {
        let threads = EnvThreads::start(scope, envs, model, actor.inference);
        drive(actor, &threads, stop)
        // Dropping `threads` ends them; the scope waits for them.
    })?;
    // Every environment waits for this thread between its steps, so a
    // loop busy nearly all the time is what holds a process back.
    let all = started.elapsed();
    eprintln!(
        "actor {}: the loop's thread was busy {:.0} % of {:.0} s (waiting for its environments the rest)",
        actor.settings.actor_id,
        100.0 * (1.0 - waited.as_secs_f64() / all.as_secs_f64().max(1e-9)),
        all.as_secs_f64()
    );
    Ok(())
}

/// What comes after an environment's finished task.
enum Next {
    /// This phase.
    Phase(Phase),
    /// An action for this episode, chosen with the others that need one
    /// (from the policy's pass its thread made, if any).
    Act(RunningEpisode, Option<PolicyPass>),
}

/// Hands out tasks and books what comes back: every task finished by the
/// time the last one is booked, then the actions of those that need one,
/// from the policy's passes the environments' threads made (this thread
/// runs only those whose policy new weights replaced meanwhile). Returns
/// how long it waited for its environments.
fn drive(
    actor: &mut Actor<'_>,
    threads: &EnvThreads,
    stop: &AtomicBool,
) -> anyhow::Result<Duration> {
    let mut waited = Duration::ZERO;
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
        let waiting = Instant::now();
        let mut finished = vec![threads.next()?];
        waited += waiting.elapsed();
        finished.extend(threads.finished()?);
        let version = actor.policy.policy_version;
        if let Some(steps) = actor.refresh_weights()? {
            threads.set_global_steps(steps)?;
        }
        if actor.policy.policy_version != version {
            share_policy(actor)?;
        }
        let stopping = stop.load(Ordering::Relaxed);
        let mut acting = Vec::new();
        for (index, done) in finished {
            let phase = std::mem::replace(&mut phases[index], Phase::Idle);
            let next = match (phase, done) {
                (Phase::Resetting(id), Done::Reset(observation, pass)) => {
                    Next::Act(actor.begin_episode(id, observation), pass)
                }
                (Phase::Stepping(mut episode, acted), Done::Step(outcome, observation, pass)) => {
                    let closing =
                        actor.record_step(&mut episode, acted, &outcome, observation, stopping);
                    if let Some(ended) = closing {
                        actor.close_chunks(vec![(&mut episode, ended)])?;
                    }
                    if outcome.done || stopping {
                        threads.send(index, Task::Finish(episode.id))?;
                        Next::Phase(Phase::Finishing(episode))
                    } else {
                        Next::Act(episode, pass)
                    }
                }
                (Phase::Finishing(episode), Done::Finish { end, scene }) => {
                    actor.publish_end(&episode, end, scene)?;
                    Next::Phase(start(actor, index)?)
                }
                _ => anyhow::bail!("environment {index} answered a task it was not given"),
            };
            match next {
                Next::Phase(phase) => phases[index] = phase,
                Next::Act(episode, pass) => acting.push((index, episode, pass)),
            }
        }
        if acting.is_empty() {
            continue;
        }
        let passes = acting.iter_mut().map(|(_, _, pass)| pass.take()).collect();
        let inputs: Vec<_> = acting
            .iter()
            .map(|(_, e, _)| (&e.observation, e.hidden.as_deref()))
            .collect();
        let acted = actor.act_with_passes(&inputs, passes)?;
        anyhow::ensure!(acted.len() == acting.len(), "the policy acted for each");
        for ((index, episode, _), acted) in acting.into_iter().zip(acted) {
            threads.send(index, Task::Step(acted.action, acted.hidden.clone()))?;
            phases[index] = Phase::Stepping(episode, acted);
        }
    }
    Ok(waited)
}
