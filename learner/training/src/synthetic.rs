//! Synthetic rollouts: valid messages of a task with random contents, for
//! measuring the learner without actors (`learner bench-capacity`, the
//! `ppo_batches` bench) and for tests.

use proto::{ObsDtype, PolicyLayout, RolloutChunk};
use rand::rngs::StdRng;
use rand::Rng;

/// A valid rollout chunk of `layout`, `steps` steps long, its observations,
/// actions, values and rewards drawn from `rng`: what `learner bench-capacity`'s
/// synthetic actors send and `benches/ppo_batches.rs` gathers.
pub fn rollout(layout: &PolicyLayout, steps: usize, rng: &mut StdRng) -> RolloutChunk {
    let obs_len = layout.obs_len();
    RolloutChunk {
        episode_id: 0,
        first_step: 0,
        n_actions: layout.n_actions as u32,
        obs_dtype: layout.obs_dtype,
        obs_elems: obs_len as u32,
        obs: match layout.obs_dtype {
            ObsDtype::U8 => (0..steps * obs_len).map(|_| rng.random()).collect(),
            ObsDtype::F32 => proto::obs_bytes_from_f32(
                &(0..steps * obs_len)
                    .map(|_| rng.random::<f32>())
                    .collect::<Vec<_>>(),
            ),
        },
        actions: (0..steps)
            .map(|_| rng.random_range(0..layout.n_actions as u32))
            .collect(),
        masks: vec![1; steps * layout.n_actions],
        log_probs: vec![-(layout.n_actions as f32).ln(); steps],
        values: (0..steps).map(|_| rng.random::<f32>()).collect(),
        rewards: (0..steps).map(|_| rng.random::<f32>() - 0.5).collect(),
        dones: vec![0; steps],
        bootstrap_value: 0.0,
        start_hidden: vec![0.0; layout.gru_hidden.unwrap_or(0)],
    }
}
