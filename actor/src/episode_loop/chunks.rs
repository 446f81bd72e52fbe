//! Building what an actor sends: rollout chunks in the policy's layout, and
//! an episode's labelled frames split into messages that fit the transport.

use nets::policy::PolicyLayout;
use proto::{FrameBatch, FrameSlices, ObsDtype, RolloutChunk};

use crate::env::{Observation, ObservationValues};

/// Most steps a new chunk reserves room for: chunks may be set to thousands
/// of steps (`proto::MAX_STEPS`), which at 128 px would reserve gigabytes
/// per environment up front, for episodes that may end far sooner.
const MAX_RESERVED_STEPS: usize = 64;

/// An empty chunk in `layout`, starting from recurrent state `start_hidden`,
/// with room for `steps` steps (up to [`MAX_RESERVED_STEPS`]), so that
/// booking a step does not reallocate.
pub(super) fn new_chunk(
    episode_id: u64,
    first_step: u32,
    layout: &PolicyLayout,
    start_hidden: Vec<f32>,
    steps: usize,
) -> RolloutChunk {
    let steps = steps.min(MAX_RESERVED_STEPS);
    let obs_bytes = layout.obs_len() * layout.obs_dtype.size();
    RolloutChunk {
        episode_id,
        first_step,
        n_actions: layout.n_actions as u32,
        obs_dtype: layout.obs_dtype,
        obs_elems: layout.obs_len() as u32,
        obs: Vec::with_capacity(steps * obs_bytes),
        actions: Vec::with_capacity(steps),
        masks: Vec::with_capacity(steps * layout.n_actions),
        log_probs: Vec::with_capacity(steps),
        values: Vec::with_capacity(steps),
        rewards: Vec::with_capacity(steps),
        dones: Vec::with_capacity(steps),
        bootstrap_value: 0.0,
        start_hidden,
    }
}

/// Empties a sent `chunk` for its episode's next steps, from step
/// `first_step` and recurrent state `start_hidden`, keeping its buffers:
/// at 128 px a chunk of 16 steps holds 6.8 MB of observations, and fresh
/// buffers cost the loop's thread their page faults every chunk.
pub(super) fn restart_chunk(chunk: &mut RolloutChunk, first_step: u32, start_hidden: Vec<f32>) {
    chunk.first_step = first_step;
    chunk.start_hidden = start_hidden;
    chunk.bootstrap_value = 0.0;
    chunk.obs.clear();
    chunk.actions.clear();
    chunk.masks.clear();
    chunk.log_probs.clear();
    chunk.values.clear();
    chunk.rewards.clear();
    chunk.dones.clear();
}

/// Appends an observation in the chunk's element type (a byte layout's
/// bytes as the environment made them, if it did).
pub(super) fn push_obs(chunk: &mut RolloutChunk, observation: &Observation) {
    match (chunk.obs_dtype, &observation.values) {
        (ObsDtype::U8, ObservationValues::Bytes(bytes)) => chunk.obs.extend_from_slice(bytes),
        (ObsDtype::U8, ObservationValues::Floats(features)) => chunk
            .obs
            .extend(features.iter().map(|&v| proto::unit_to_byte(v))),
        (ObsDtype::F32, values) => chunk
            .obs
            .extend(values.floats().iter().flat_map(|v| v.to_le_bytes())),
    }
}

/// Splits an episode's frames into messages of at most `max_bytes` payload,
/// each borrowing its frames from `batch`.
pub(super) fn split_frames(batch: &FrameBatch, max_bytes: usize) -> Vec<FrameSlices<'_>> {
    let pixels = (batch.height * batch.width) as usize;
    let planes = batch.n_affordances as usize;
    let per_frame = pixels * (4 + 3 + planes);
    let per_message = (max_bytes.saturating_sub(64) / per_frame.max(1)).max(1);
    let n = batch.n_frames();
    (0..n)
        .step_by(per_message)
        .map(|start| batch.frames(start..(start + per_message).min(n)))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_byte_chunk_takes_the_environments_bytes_else_converts_the_features() {
        let layout = PolicyLayout {
            image_channels: vec![],
            image_size: 8,
            vector_dims: vec![3],
            n_actions: 2,
            obs_dtype: ObsDtype::U8,
            gru_hidden: None,
        };
        let features = vec![0.0, 0.5, 1.0];
        let mut chunk = new_chunk(1, 0, &layout, Vec::new(), 2);
        let converted = Observation::of_floats(features.clone(), vec![1, 1]);
        push_obs(&mut chunk, &converted);
        assert_eq!(chunk.obs, [0, 128, 255]);
        // Bytes from the environment go in as they are.
        let made = Observation {
            values: ObservationValues::Bytes(vec![7, 8, 255]),
            ..converted.clone()
        };
        push_obs(&mut chunk, &made);
        assert_eq!(chunk.obs, [0, 128, 255, 7, 8, 255]);
        // A float layout carries the values the network reads.
        chunk.obs_dtype = ObsDtype::F32;
        chunk.obs.clear();
        push_obs(&mut chunk, &converted);
        assert_eq!(chunk.obs, proto::obs_bytes_from_f32(&features));
        chunk.obs.clear();
        push_obs(&mut chunk, &made);
        let units = [7, 8, 255].map(proto::byte_to_unit);
        assert_eq!(chunk.obs, proto::obs_bytes_from_f32(&units));
    }

    #[test]
    fn frames_split_into_messages_that_fit_and_lose_nothing() {
        let (h, w, a, n) = (4u32, 5u32, 2u32, 7usize);
        let pixels = (h * w) as usize;
        let batch = FrameBatch {
            episode_id: 3,
            height: h,
            width: w,
            n_affordances: a,
            depth_m: (0..n * pixels).map(|i| i as f32).collect(),
            rgb: (0..3 * n * pixels).map(|i| i as u8).collect(),
            labels: (0..2 * n * pixels).map(|i| (i % 2) as u8).collect(),
        };
        let per_frame = pixels * 9;
        let parts = split_frames(&batch, 64 + 3 * per_frame);
        assert_eq!(parts.len(), 3);
        assert_eq!(
            parts.iter().map(|p| p.n_frames()).collect::<Vec<_>>(),
            [3, 3, 1]
        );
        let joined: Vec<f32> = parts.iter().flat_map(|p| p.depth_m.to_vec()).collect();
        assert_eq!(joined, batch.depth_m);
        let labels: Vec<u8> = parts.iter().flat_map(|p| p.labels.to_vec()).collect();
        assert_eq!(labels, batch.labels);
        let rgb: Vec<u8> = parts.iter().flat_map(|p| p.rgb.to_vec()).collect();
        assert_eq!(rgb, batch.rgb);
        assert!(parts.iter().all(|p| p.episode_id == 3));
    }
}
