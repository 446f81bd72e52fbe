//! The policy update: rollout chunks from any actors are gathered until a
//! batch is full; advantages are estimated per chunk (GAE, bootstrapped with
//! the critic's value after the chunk's last step); PPO then updates the
//! policy network. Chunks carry the behaviour policy's log-probabilities, so
//! a chunk acted with a slightly older policy is corrected by the ratio.

use crate::gae::gae;
use crate::optimizer_state::{OptimizerState, OptimizerStateError};
use crate::ppo::{Ppo, PpoBatch, PpoStats, Sequences};
use burn::prelude::*;
use nets::policy::{PolicyInput, PolicyNet};
use nets::weights::{load_safetensors, to_safetensors, WeightsError};
use proto::{ObsDtype, PolicyLayout, RolloutView, TaskSpec};
use rand::rngs::StdRng;
use rand::SeedableRng;

use crate::config::PolicyConfig;

/// Why a chunk cannot train the current network.
#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    /// The chunk's shapes do not match the run's task.
    #[error("rollout has obs {obs_elems} x {dtype:?} and {n_actions} actions; this run's task expects obs {obs_len} x {expected_dtype:?} and {expected_actions} actions (is the actor using the learner's config.toml?)")]
    Shape {
        /// Observation elements in the chunk.
        obs_elems: u32,
        /// Observation dtype in the chunk.
        dtype: ObsDtype,
        /// Actions in the chunk.
        n_actions: u32,
        /// The task's observation length.
        obs_len: usize,
        /// The task's dtype.
        expected_dtype: ObsDtype,
        /// The task's action count.
        expected_actions: usize,
    },
    /// The chunk's recurrent state does not fit the policy's GRU.
    #[error("rollout carries a recurrent state of {got} values; this run's policy has {expected} (0 = no GRU; is the actor using the learner's config.toml?)")]
    Hidden {
        /// Values in the chunk.
        got: usize,
        /// The policy's GRU size (0 without one).
        expected: usize,
    },
}

/// Steps gathered for the next update. The buffers keep their capacity
/// from batch to batch: at 128 px a batch's observations are 436 MB, and
/// growing a fresh vector to that size again for every batch copied it
/// about twice more and touched twice as many new pages.
#[derive(Debug, Default)]
struct Gathered {
    /// Observations as they arrived (bytes of the chunk's dtype), turned
    /// into floats only when the batch is full, on every core.
    obs: Vec<u8>,
    masks: Vec<u8>,
    actions: Vec<u32>,
    log_probs: Vec<f32>,
    values: Vec<f32>,
    advantages: Vec<f32>,
    returns: Vec<f32>,
    versions: Vec<u64>,
    /// Steps of each chunk, and its recurrent start state (GRU policies).
    lengths: Vec<usize>,
    start_hidden: Vec<f32>,
}

/// Observation bytes of `dtype` (`rows` flat observations of `layout`) as
/// floats, split by input (the columns of [`PolicyInput::from_columns`]) in
/// the same pass, on rayon's threads: one pass over the batch, which at
/// 128 px and 1 024 steps is 1.7 GB of floats.
fn decode_columns(
    bytes: &[u8],
    dtype: ObsDtype,
    layout: &PolicyLayout,
    rows: usize,
) -> Vec<Vec<f32>> {
    use rayon::prelude::*;
    /// Values per task: large enough that scheduling costs nothing.
    const PER_TASK: usize = 1 << 16;
    let width_bytes = match dtype {
        ObsDtype::U8 => 1,
        ObsDtype::F32 => 4,
    };
    let row_bytes = layout.obs_len() * width_bytes;
    debug_assert_eq!(bytes.len(), rows * row_bytes, "observation bytes");
    let mut start = 0;
    layout
        .input_widths()
        .map(|width| {
            let mut column = vec![0.0f32; rows * width];
            if width == 0 {
                return column; // an empty input: nothing to decode
            }
            let rows_per_task = (PER_TASK / width).max(1);
            column
                .par_chunks_mut(rows_per_task * width)
                .enumerate()
                .for_each(|(task, out)| {
                    for (r, out) in out.chunks_exact_mut(width).enumerate() {
                        let row = task * rows_per_task + r;
                        let at = row * row_bytes + start * width_bytes;
                        decode(&bytes[at..at + width * width_bytes], dtype, out);
                    }
                });
            start += width;
            column
        })
        .collect()
}

/// One input's values of one row, from the wire's bytes.
fn decode(bytes: &[u8], dtype: ObsDtype, out: &mut [f32]) {
    match dtype {
        ObsDtype::U8 => {
            for (o, &b) in out.iter_mut().zip(bytes) {
                *o = proto::byte_to_unit(b);
            }
        }
        ObsDtype::F32 => {
            for (o, b) in out.iter_mut().zip(bytes.chunks_exact(4)) {
                *o = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
            }
        }
    }
}

/// Gathers rollout chunks into PPO batches for [`PolicyTrainer::update`]:
/// advantages per chunk, and when a batch is full its observations built
/// for the device. Separate from the trainer so that the next batch is
/// gathered and built while an update runs.
pub struct BatchBuilder {
    layout: PolicyLayout,
    settings: PolicyConfig,
    device: Device,
    gathered: Gathered,
}

impl BatchBuilder {
    /// Steps waiting for the next update.
    pub fn pending_steps(&self) -> usize {
        self.gathered.actions.len()
    }

    /// Adds a chunk; when the batch is full, returns it built for the
    /// device (observations decoded and handed over), for
    /// [`PolicyTrainer::update`].
    pub fn add_chunk(
        &mut self,
        chunk: &RolloutView<'_>,
        policy_version: u64,
    ) -> Result<Option<PpoBatch>, TrainError> {
        let obs_len = self.layout.obs_len();
        if chunk.obs_dtype != self.layout.obs_dtype
            || chunk.obs_elems as usize != obs_len
            || chunk.n_actions as usize != self.layout.n_actions
        {
            return Err(TrainError::Shape {
                obs_elems: chunk.obs_elems,
                dtype: chunk.obs_dtype,
                n_actions: chunk.n_actions,
                obs_len,
                expected_dtype: self.layout.obs_dtype,
                expected_actions: self.layout.n_actions,
            });
        }
        let hidden = self.layout.gru_hidden.unwrap_or(0);
        if chunk.start_hidden.len() != hidden {
            return Err(TrainError::Hidden {
                got: chunk.start_hidden.len(),
                expected: hidden,
            });
        }
        let steps = chunk.n_steps();
        let batch_steps = self.settings.batch_steps;
        let g = &mut self.gathered;
        if g.actions.is_empty() {
            // The whole batch at once (a batch ends with the chunk that
            // fills it, so it may hold one chunk's steps more).
            let row_bytes = obs_len * self.layout.obs_dtype.size();
            let rows = batch_steps + steps;
            g.obs.reserve(rows * row_bytes);
            g.masks.reserve(rows * self.layout.n_actions);
        }
        g.lengths.push(steps);
        g.start_hidden.extend(chunk.start_hidden.iter());
        for i in 0..steps {
            g.obs.extend_from_slice(chunk.obs(i).unwrap_or_default());
            g.masks.extend_from_slice(chunk.mask(i).unwrap_or_default());
        }
        let values = chunk.values.to_vec();
        let dones: Vec<bool> = chunk.dones.iter().map(|&d| d != 0).collect();
        let (advantages, returns) = gae(
            &chunk.rewards.to_vec(),
            &values,
            &dones,
            chunk.bootstrap_value,
            self.settings.ppo.gamma,
            self.settings.ppo.gae_lambda,
        );
        g.actions.extend(chunk.actions.iter());
        g.log_probs.extend(chunk.log_probs.iter());
        g.values.extend(values);
        g.advantages.extend(advantages);
        g.returns.extend(returns);
        g.versions
            .extend(std::iter::repeat_n(policy_version, steps));
        if g.actions.len() < batch_steps {
            return Ok(None);
        }
        let rows = g.actions.len();
        // Chunks never span episodes: each replays from its start state.
        let sequences = self.layout.gru_hidden.map(|hidden| Sequences {
            lengths: std::mem::take(&mut g.lengths),
            start_hidden: std::mem::take(&mut g.start_hidden),
            hidden,
            episode_starts: vec![0.0; rows],
        });
        // On libtorch the bytes go to the device and become floats there;
        // elsewhere they are decoded here, on every core.
        let input =
            PolicyInput::from_wire_bytes(&self.layout, &g.obs, &g.masks, rows, &self.device)
                .unwrap_or_else(|| {
                    let columns = decode_columns(&g.obs, self.layout.obs_dtype, &self.layout, rows);
                    PolicyInput::from_columns(&self.layout, columns, &g.masks, rows, &self.device)
                });
        // The observations' buffers stay for the next batch; the rest moves
        // into this one.
        g.obs.clear();
        g.masks.clear();
        g.lengths.clear();
        g.start_hidden.clear();
        Ok(Some(PpoBatch {
            input,
            actions: std::mem::take(&mut g.actions),
            behaviour_log_probs: std::mem::take(&mut g.log_probs),
            values: std::mem::take(&mut g.values),
            advantages: std::mem::take(&mut g.advantages),
            returns: std::mem::take(&mut g.returns),
            policy_versions: std::mem::take(&mut g.versions),
            sequences,
        }))
    }
}

/// Why saved weights or optimiser state cannot continue this policy.
#[derive(Debug, thiserror::Error)]
pub enum RestoreError {
    /// The weights do not load into this task's policy.
    #[error("the policy's weights: {0}")]
    Weights(#[from] WeightsError),
    /// The optimiser's state does not fit the policy's parameters.
    #[error("the policy's optimiser state: {0}")]
    Optimizer(#[from] OptimizerStateError),
}

/// The policy network and its optimiser.
pub struct PolicyTrainer {
    layout: PolicyLayout,
    settings: PolicyConfig,
    ppo: Ppo,
    device: Device,
    rng: StdRng,
}

impl PolicyTrainer {
    /// A freshly initialised policy for `task`, trained on `device`.
    pub fn new(task: &TaskSpec, settings: &PolicyConfig, device: &Device) -> Self {
        let layout = task.layout();
        let net = PolicyNet::new(&layout, device);
        let ppo_config = settings.ppo;
        Self {
            layout,
            settings: settings.clone(),
            ppo: Ppo::new(net, ppo_config, device),
            device: device.clone(),
            rng: StdRng::seed_from_u64(settings.seed),
        }
    }

    /// An empty batch for this policy's layout, settings and device.
    pub fn batch_builder(&self) -> BatchBuilder {
        BatchBuilder {
            layout: self.layout.clone(),
            settings: self.settings.clone(),
            device: self.device.clone(),
            gathered: Gathered::default(),
        }
    }

    /// The version of the current weights.
    pub fn version(&self) -> u64 {
        self.ppo.version()
    }

    /// One PPO update on a batch from [`BatchBuilder::add_chunk`]; its statistics
    /// (the version then goes up by one).
    pub fn update(&mut self, batch: &PpoBatch) -> PpoStats {
        self.ppo.update(batch, &mut self.rng)
    }

    /// The current weights as safetensors bytes (PyTorch names, no prefix).
    pub fn weights(&self) -> Result<Vec<u8>, WeightsError> {
        to_safetensors(&self.ppo.inference_net(&self.device))
    }

    /// Adam's state, for a checkpoint.
    pub fn optimizer_state(&self) -> Result<OptimizerState, OptimizerStateError> {
        self.ppo.optimizer_state()
    }

    /// Continues from saved weights and version; the optimiser continues
    /// from `optimizer` when given, else starts afresh.
    pub fn restore(
        &mut self,
        bytes: Vec<u8>,
        version: u64,
        optimizer: Option<&OptimizerState>,
    ) -> Result<(), RestoreError> {
        let mut net = PolicyNet::new(&self.layout, &self.device);
        load_safetensors(&mut net, bytes)?;
        let mut ppo = Ppo::new(net, *self.ppo.config(), &self.device);
        if let Some(state) = optimizer {
            ppo.restore_optimizer(state)?;
        }
        ppo.set_version(version);
        self.ppo = ppo;
        Ok(())
    }

    /// Sets the version the next update counts from.
    pub fn set_version(&mut self, version: u64) {
        self.ppo.set_version(version);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proto::{decode, Limits, Message, MessageHeader};

    /// A valid rollout message of `steps` random steps of `task`.
    fn rollout(task: &TaskSpec, steps: usize, seed: u64) -> Vec<u8> {
        let mut rng = StdRng::seed_from_u64(seed);
        let chunk = crate::synthetic::rollout(&task.layout(), steps, &mut rng);
        proto::encode(&chunk, MessageHeader::default())
    }

    /// Feeds each message to `builder`; the batches it completes.
    fn batches(builder: &mut BatchBuilder, messages: &[Vec<u8>]) -> Vec<PpoBatch> {
        let limits = Limits {
            max_actors: 4,
            max_payload_len: 1 << 30,
        };
        let mut out = Vec::new();
        for bytes in messages {
            let Ok((_, Message::Rollout(view))) = decode(bytes, &limits) else {
                panic!("a valid rollout message");
            };
            out.extend(builder.add_chunk(&view, 7).unwrap());
        }
        out
    }

    fn floats<const D: usize>(tensors: &[Tensor<D>]) -> Vec<Vec<f32>> {
        (tensors.iter())
            .map(|t| t.clone().into_data().try_into_vec::<f32>().unwrap())
            .collect()
    }

    #[test]
    fn a_builder_keeps_its_buffers_and_builds_the_next_batch_as_a_fresh_one_would() {
        let task = TaskSpec {
            image_size: 64,
            ..TaskSpec::default()
        };
        let settings = PolicyConfig {
            batch_steps: 8,
            ..PolicyConfig::default()
        };
        let device = Device::flex();
        let trainer = PolicyTrainer::new(&task, &settings, &device);
        // 5 + 5 steps fill the first batch (10 rows, one chunk beyond 8);
        // 3 + 6 the second.
        let first = [rollout(&task, 5, 1), rollout(&task, 5, 2)];
        let second = [rollout(&task, 3, 3), rollout(&task, 6, 4)];
        let mut reused = trainer.batch_builder();
        let built = batches(&mut reused, &first);
        assert_eq!(built.len(), 1);
        assert_eq!(built[0].len(), 10);
        let capacity = reused.gathered.obs.capacity();
        assert!(
            capacity >= 10 * task.layout().obs_len(),
            "reserved for the batch"
        );
        let again = batches(&mut reused, &second).pop().expect("a second batch");
        assert_eq!(reused.gathered.obs.capacity(), capacity, "the same buffer");
        let fresh = batches(&mut trainer.batch_builder(), &second)
            .pop()
            .expect("the same batch");
        assert_eq!(again.len(), 9);
        assert_eq!(floats(&again.input.images), floats(&fresh.input.images));
        assert_eq!(floats(&again.input.vectors), floats(&fresh.input.vectors));
        assert_eq!(
            (again.actions, again.advantages, again.returns),
            (fresh.actions, fresh.advantages, fresh.returns)
        );
        // And both are the chunks' own bytes, not the first batch's.
        let wire = &second[0];
        let limits = Limits {
            max_actors: 4,
            max_payload_len: 1 << 30,
        };
        let Ok((_, Message::Rollout(view))) = decode(wire, &limits) else {
            panic!("a valid rollout message");
        };
        let first_image = floats(&fresh.input.images).remove(0);
        let first_width = task.layout().input_widths().next().unwrap();
        let expected: Vec<f32> = view.obs(0).unwrap()[..first_width]
            .iter()
            .map(|&b| proto::byte_to_unit(b))
            .collect();
        assert_eq!(&first_image[..first_width], &expected[..]);
    }

    #[test]
    fn observation_bytes_become_each_inputs_floats_across_task_boundaries() {
        // An image of 2 × 64² values (8 rows per task), a second of 1 × 64²,
        // vectors of 3 and 5; 21 rows end inside a task.
        let layout = PolicyLayout {
            image_channels: vec![2, 1],
            image_size: 64,
            vector_dims: vec![3, 5],
            n_actions: 4,
            obs_dtype: ObsDtype::U8,
            gru_hidden: None,
        };
        let rows = 21;
        let len = layout.obs_len();
        let bytes: Vec<u8> = (0..rows * len).map(|i| (i * 7 % 256) as u8).collect();
        let columns = decode_columns(&bytes, ObsDtype::U8, &layout, rows);
        let values: Vec<f32> = (0..rows * len).map(|i| i as f32 * 0.5 - 3.0).collect();
        let encoded: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        let float_columns = decode_columns(&encoded, ObsDtype::F32, &layout, rows);
        // Input i of row r starts at r · len plus the widths before it.
        let widths = [2 * 64 * 64, 64 * 64, 3, 5];
        assert_eq!(columns.len(), widths.len());
        let mut start = 0;
        for (i, &width) in widths.iter().enumerate() {
            assert_eq!(columns[i].len(), rows * width, "input {i}");
            for r in 0..rows {
                for k in 0..width {
                    let at = r * len + start + k;
                    assert_eq!(columns[i][r * width + k], f32::from(bytes[at]) / 255.0);
                    assert_eq!(float_columns[i][r * width + k], values[at]);
                }
            }
            start += width;
        }
    }
}
