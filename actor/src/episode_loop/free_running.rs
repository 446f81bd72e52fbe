//! The loop over free-running environments ([`EnvThreads`]): this thread
//! keeps the bookkeeping, the policy and the learner's ports, and gives each
//! environment its next task as soon as its last one is done.
//!
//! Unlike lock-step, which environment starts which episode (and so draws
//! which random numbers) depends on timing; each episode's reset seed is
//! still its id's.

use std::sync::atomic::{AtomicBool, Ordering};

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

/// Whether `envs` environments should run free: several of them, a policy
/// pass cheap enough for this thread to run (the CPU's own,
/// `nets::policy::CpuPolicy`), and steps long and uneven enough that waiting
/// at a barrier costs more than this thread's competing with the
/// environments for the cores. That is the methods with a map, whose
/// policies have no GRU (the GRU stands in for the map). Measured on the CPU
/// with 2 environments, 64 px (env bench, both with the CPU pass): `ours`
/// 95–107 steps/s in lock-step, 109–135 free-running on 2026-11-23, 152–158
/// and 144–182 on 2026-11-27; `nomap-seg`, whose short, even steps lose
/// little at the barrier, 202–203 and 184 on 2026-11-23, 226–243 and
/// 225–227 on 2026-11-27. On a GPU the U-Net's frames go to one batching thread
/// (`crate::env::unet_batcher`) instead of a lock-step batch, whose barrier
/// at 16 environments made `ours`' rounds wait for the slowest of them
/// (docs/notebook/2026-11-27-free-running-gpu-actor.md).
pub(super) fn suits(actor: &Actor<'_>, envs: usize) -> bool {
    envs > 1 && actor.policy.cpu.is_some() && actor.policy.layout.gru_hidden.is_none()
}

/// Runs `envs` free-running until `stop` is set or `max_episodes` are done.
pub(super) fn run(
    actor: &mut Actor<'_>,
    envs: Vec<Box<dyn Environment>>,
    stop: &AtomicBool,
) -> anyhow::Result<()> {
    let model = actor.model;
    std::thread::scope(|scope| {
        let threads = EnvThreads::start(scope, envs, model, actor.inference);
        drive(actor, &threads, stop)
        // Dropping `threads` ends them; the scope waits for them.
    })
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
/// runs only those whose policy new weights replaced meanwhile).
fn drive(actor: &mut Actor<'_>, threads: &EnvThreads, stop: &AtomicBool) -> anyhow::Result<()> {
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
        let mut finished = vec![threads.next()?];
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
            threads.send(index, Task::Step(acted.action))?;
            phases[index] = Phase::Stepping(episode, acted);
        }
    }
    Ok(())
}
