//! Several environments stepped as one: the first halves of their resets or
//! steps run in parallel (a thread each), the affordance U-Net sees all
//! their camera frames in one batch, then the second halves run in parallel.
//! This is how one actor process keeps a GPU busy: a batch of frames costs
//! it little more than one.

use rayon::prelude::*;

use super::affordance_model::AffordanceModel;
use super::{Environment, Observation, StepOutcome};

/// Resets every environment of `envs` with its seed in `seeds`.
pub fn reset_all<E: Environment + ?Sized>(
    envs: &mut [&mut E],
    seeds: &[u64],
    model: Option<&AffordanceModel>,
) -> anyhow::Result<Vec<Observation>> {
    anyhow::ensure!(envs.len() == seeds.len(), "one seed per environment");
    envs.par_iter_mut()
        .zip(seeds)
        .map(|(env, &seed)| env.begin_reset(seed))
        .collect::<anyhow::Result<()>>()?;
    observe_all(envs, model)
}

/// Steps every environment of `envs` with its action in `actions`.
pub fn step_all<E: Environment + ?Sized>(
    envs: &mut [&mut E],
    actions: &[u32],
    model: Option<&AffordanceModel>,
) -> anyhow::Result<Vec<(StepOutcome, Observation)>> {
    anyhow::ensure!(envs.len() == actions.len(), "one action per environment");
    let outcomes: Vec<StepOutcome> = envs
        .par_iter_mut()
        .zip(actions)
        .map(|(env, &action)| env.begin_step(action))
        .collect::<anyhow::Result<_>>()?;
    Ok(outcomes
        .into_iter()
        .zip(observe_all(envs, model)?)
        .collect())
}

/// The second halves: the U-Net over every camera frame in one batch, then
/// each environment's observation.
fn observe_all<E: Environment + ?Sized>(
    envs: &mut [&mut E],
    model: Option<&AffordanceModel>,
) -> anyhow::Result<Vec<Observation>> {
    let affordances = {
        let frames: Vec<_> = envs.iter().map(|e| e.camera_frame()).collect();
        let batch: Vec<_> = frames.iter().flatten().copied().collect();
        let mut predicted = match (batch.is_empty(), model) {
            (true, _) => Vec::new(),
            (false, Some(model)) => model.predict_batch(&batch),
            (false, None) => anyhow::bail!("this environment's camera frames need the U-Net"),
        }
        .into_iter();
        frames
            .iter()
            .map(|f| match f {
                Some(_) => predicted.next().unwrap_or_default(),
                None => Vec::new(),
            })
            .collect::<Vec<_>>()
    };
    envs.par_iter_mut()
        .zip(affordances)
        .map(|(env, a)| env.observe(a))
        .collect()
}
