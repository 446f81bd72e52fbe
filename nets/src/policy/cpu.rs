//! The policy's forward pass on the CPU for one observation, for acting.
//!
//! Why it exists: an actor runs the policy on every step, and on the CPU
//! burn's pass over `ours`' three conv encoders (about 15 MFLOP at 64 px)
//! took a millisecond or more: the time goes to per-operation overhead (tensor allocation, layout copies), not to
//! arithmetic. Here each convolution is one im2col copy and one GEMM, the
//! rest (dense layers, the GRU of the methods with memory) plain loops over
//! weights copied out once.
//!
//! The arithmetic is the network's own: [`CpuPolicy::forward`] equals
//! [`PolicyNet::forward`] to float rounding (tested below).

use std::cell::RefCell;

use burn::nn::conv::Conv2d;
use burn::nn::gru::Gru;
use burn::nn::Linear;

use super::{ConvEncoder, Head, PolicyLayout, PolicyNet, VectorEncoder, MASKED_LOGIT};
use crate::kernels::{bias_values, matmul_lhs_rows, values};
use crate::layers::{ENCODER_ACTIVATION, HEAD_ACTIVATION};

/// The policy's weights, laid out for [`CpuPolicy::forward`].
#[derive(Debug, Clone)]
pub struct CpuPolicy {
    layout: PolicyLayout,
    images: Vec<[Conv; 3]>,
    image_fcs: Vec<Dense>,
    vectors: Vec<[Dense; 2]>,
    gru: Option<CpuGru>,
    actor: [Dense; 3],
    critic: [Dense; 3],
}

/// What the policy says for one observation.
#[derive(Debug, Clone, PartialEq)]
pub struct CpuPolicyStep {
    /// Log-probabilities of the actions (masked ones hold what
    /// [`PolicyNet::forward`] gives them: very negative).
    pub log_probs: Vec<f32>,
    /// The critic's value.
    pub value: f32,
    /// The GRU state after this step (policies with memory).
    pub hidden: Option<Vec<f32>>,
}

impl CpuPolicy {
    /// Copies the weights of `net` (built for `layout`), or `None` where
    /// the network is not what this pass computes: a GRU other than the one
    /// [`PolicyNet::new`] builds (gates applied after the reset, no
    /// clipping), or one that disagrees with the layout.
    pub fn from_network(net: &PolicyNet, layout: &PolicyLayout) -> Option<Self> {
        let gru = match (&net.gru, layout.gru_hidden) {
            (None, None) => None,
            (Some(gru), Some(hidden)) if gru.d_hidden == hidden => Some(CpuGru::from_layer(gru)?),
            _ => return None,
        };
        let head = |h: &Head| [&h.fc1, &h.fc2, &h.out].map(Dense::from_layer);
        Some(Self {
            layout: layout.clone(),
            images: net
                .images
                .iter()
                .map(|e: &ConvEncoder| [&e.conv1, &e.conv2, &e.conv3].map(Conv::from_layer))
                .collect(),
            image_fcs: net
                .images
                .iter()
                .map(|e| Dense::from_layer(&e.fc))
                .collect(),
            vectors: net
                .vectors
                .iter()
                .map(|e: &VectorEncoder| [&e.fc1, &e.fc2].map(Dense::from_layer))
                .collect(),
            gru,
            actor: head(&net.actor),
            critic: head(&net.critic),
        })
    }

    /// Log-probabilities and value for one flat observation (images then
    /// vectors, [`PolicyLayout::obs_len`] values) and its mask (one byte
    /// per action, nonzero = allowed); for a policy with a GRU, `hidden` is
    /// its state before this step (`None`: zeros, an episode's start).
    ///
    /// # Panics
    /// If the lengths do not match the layout: callers validate first.
    pub fn forward(
        &self,
        observation: &[f32],
        mask: &[u8],
        hidden: Option<&[f32]>,
    ) -> CpuPolicyStep {
        let layout = &self.layout;
        assert_eq!(observation.len(), layout.obs_len(), "observation length");
        assert_eq!(mask.len(), layout.n_actions, "mask length");
        let side = layout.image_size;
        let encoder = |v| ENCODER_ACTIVATION.value(v);
        let mut features = Vec::new();
        let mut at = 0;
        for ((convs, fc), &channels) in self
            .images
            .iter()
            .zip(&self.image_fcs)
            .zip(&layout.image_channels)
        {
            let len = channels * side * side;
            let (mut x, mut size) = convs[0].forward(&observation[at..at + len], side);
            for conv in &convs[1..] {
                (x, size) = conv.forward(&x, size);
            }
            features.extend(fc.forward(&x, encoder));
            at += len;
        }
        for (mlp, &dim) in self.vectors.iter().zip(&layout.vector_dims) {
            let inner = mlp[0].forward(&observation[at..at + dim], encoder);
            features.extend(mlp[1].forward(&inner, encoder));
            at += dim;
        }
        let hidden = self.gru.as_ref().map(|gru| {
            let zeros = vec![0.0; gru.size()];
            let before = hidden.unwrap_or(&zeros);
            assert_eq!(before.len(), gru.size(), "GRU state length");
            gru.step(&features, before)
        });
        let trunk = hidden.as_deref().unwrap_or(&features);
        let head = |h: &[Dense; 3]| {
            let hidden = |v| HEAD_ACTIVATION.value(v);
            let x = h[0].forward(trunk, hidden);
            let x = h[1].forward(&x, hidden);
            h[2].forward(&x, |v| v)
        };
        let mut logits = head(&self.actor);
        for (logit, &allowed) in logits.iter_mut().zip(mask) {
            if allowed == 0 {
                *logit = MASKED_LOGIT;
            }
        }
        let max = logits.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        let log_sum = logits.iter().map(|l| (l - max).exp()).sum::<f32>().ln();
        CpuPolicyStep {
            log_probs: logits.iter().map(|l| l - max - log_sum).collect(),
            value: head(&self.critic)[0],
            hidden,
        }
    }
}

fn sigmoid(v: f32) -> f32 {
    1.0 / (1.0 + (-v).exp())
}

/// burn's GRU with the new gate's reset applied after its hidden product
/// (`reset_after`, [`PolicyNet::new`]'s choice):
/// `z = σ(x Wz + h Uz)`, `r = σ(x Wr + h Ur)`, `n = tanh(x Wn + r ⊙ (h Un))`,
/// `h' = (1 − z) ⊙ n + z ⊙ h` (each product with its bias).
#[derive(Debug, Clone)]
struct CpuGru {
    /// Input and hidden transforms of the update, reset and new gates.
    gates: [[Dense; 2]; 3],
}

impl CpuGru {
    /// `None` for a GRU this pass does not compute (see
    /// [`CpuPolicy::from_network`]).
    fn from_layer(gru: &Gru) -> Option<Self> {
        let standard = gru.reset_after
            && gru.clip.is_none()
            && matches!(
                gru.gate_activation,
                burn::nn::activation::Activation::Sigmoid(_)
            )
            && matches!(
                gru.hidden_activation,
                burn::nn::activation::Activation::Tanh(_)
            );
        standard.then(|| Self {
            gates: [&gru.update_gate, &gru.reset_gate, &gru.new_gate].map(|g| {
                [
                    Dense::from_layer(&g.input_transform),
                    Dense::from_layer(&g.hidden_transform),
                ]
            }),
        })
    }

    /// The state's length.
    fn size(&self) -> usize {
        self.gates[0][1].outputs
    }

    /// The state after input `x`, from state `h`.
    fn step(&self, x: &[f32], h: &[f32]) -> Vec<f32> {
        let [update, reset, new] = &self.gates;
        let gate = |g: &[Dense; 2]| {
            let mut v = g[0].forward(x, |v| v);
            for (v, u) in v.iter_mut().zip(g[1].forward(h, |v| v)) {
                *v = sigmoid(*v + u);
            }
            v
        };
        let (z, r) = (gate(update), gate(reset));
        let candidate = new[0].forward(x, |v| v);
        let recurrent = new[1].forward(h, |v| v);
        (0..h.len())
            .map(|i| {
                let n = (candidate[i] + r[i] * recurrent[i]).tanh();
                (1.0 - z[i]) * n + z[i] * h[i]
            })
            .collect()
    }
}

/// The most bytes of im2col columns one GEMM of [`Conv::forward`] takes:
/// about what a core's L2 cache holds beside the weights and the output.
const IM2COL_BYTES: usize = 256 * 1024;

/// A valid (unpadded), strided, square convolution followed by the
/// encoders' activation.
#[derive(Debug, Clone)]
struct Conv {
    inputs: usize,
    outputs: usize,
    kernel: usize,
    stride: usize,
    /// `[output][input][ky][kx]`, burn's own layout: row-major
    /// `outputs × (inputs · kernel²)` for the GEMM.
    weight: Vec<f32>,
    bias: Vec<f32>,
}

impl Conv {
    fn from_layer(layer: &Conv2d) -> Self {
        let [outputs, inputs, kernel, _] = layer.weight.val().dims();
        let stride = layer.stride[0];
        Self {
            inputs,
            outputs,
            kernel,
            stride,
            weight: values(&layer.weight),
            bias: bias_values(&layer.bias, outputs),
        }
    }

    /// `[inputs][size][size]` → (`[outputs][out][out]`, `out`).
    ///
    /// One GEMM per group of input channels, each over the im2col columns
    /// of its group only, accumulated into the output: the columns of all
    /// channels at once (2.5 MB for the 10 camera planes at 128 px, four
    /// times the input) would leave the cache before the GEMM reads them.
    /// With a stride, the input is first split into its stride phases
    /// ([`split_phases`]), so that every row of the columns is one
    /// contiguous copy instead of a strided gather (which took half of a
    /// 128-px pass).
    fn forward(&self, x: &[f32], size: usize) -> (Vec<f32>, usize) {
        let (k, s) = (self.kernel, self.stride);
        let out = (size - k) / s + 1;
        let pixels = out * out;
        let per_channel = k * k * pixels;
        let group = (IM2COL_BYTES / (per_channel * 4)).clamp(1, self.inputs);
        let mut y: Vec<f32> = self
            .bias
            .iter()
            .flat_map(|&b| std::iter::repeat_n(b, pixels))
            .collect();
        SCRATCH.with_borrow_mut(|(columns, split)| {
            if columns.len() < group * per_channel {
                columns.resize(group * per_channel, 0.0);
            }
            let planes = if s == 1 {
                x
            } else {
                split_phases(x, self.inputs, size, s, split);
                &split[..]
            };
            self.accumulate(&mut y, planes, columns, (size, group));
        });
        for v in &mut y {
            *v = ENCODER_ACTIVATION.value(*v);
        }
        (y, out)
    }

    /// Adds the convolution of `planes` (the input, split into its stride
    /// phases) to `y`, `group` input channels per GEMM, im2col in `columns`.
    fn accumulate(
        &self,
        y: &mut [f32],
        planes: &[f32],
        columns: &mut [f32],
        (size, group): (usize, usize),
    ) {
        let (k, s) = (self.kernel, self.stride);
        let out = (size - k) / s + 1;
        let pixels = out * out;
        let phase = size.div_ceil(s);
        for first in (0..self.inputs).step_by(group) {
            let channels = group.min(self.inputs - first);
            // im2col: row (c, ky, kx), column (oy, ox); tap (ky, kx) reads
            // phase (ky mod s, kx mod s) from (oy + ky / s, ox + kx / s).
            for c in 0..channels {
                for ky in 0..k {
                    for kx in 0..k {
                        let row = &mut columns[((c * k + ky) * k + kx) * pixels..][..pixels];
                        let plane = ((first + c) * s + ky % s) * s + kx % s;
                        let plane = &planes[plane * phase * phase..][..phase * phase];
                        for (oy, row) in row.chunks_exact_mut(out).enumerate() {
                            row.copy_from_slice(&plane[(oy + ky / s) * phase + kx / s..][..out]);
                        }
                    }
                }
            }
            // The weights' columns of these channels: row stride inputs · k².
            let weight = &self.weight[first * k * k..];
            matmul_lhs_rows(
                y,
                pixels,
                (weight, self.inputs * k * k),
                columns,
                pixels,
                (self.outputs, pixels, channels * k * k),
                true,
            );
        }
    }
}

thread_local! {
    /// Each thread's im2col columns and stride phases for [`Conv::forward`],
    /// kept from pass to pass: allocated anew on every pass (hundreds of kB)
    /// they cost page faults whenever the allocator had handed the memory
    /// back to the system, which made a 64-px pass more than twice as slow
    /// in one process as in another (`cpu_policy` bench; docs/performance.md).
    static SCRATCH: RefCell<(Vec<f32>, Vec<f32>)> = const { RefCell::new((Vec::new(), Vec::new())) };
}

/// `[channels][size][size]` split into its stride-`s` phases, into `out`:
/// `[channels][py][px][Y][X] = x[c][Y·s + py][X·s + px]`, each phase
/// `⌈size / s⌉` square, zeros past the edge.
fn split_phases(x: &[f32], channels: usize, size: usize, s: usize, out: &mut Vec<f32>) {
    let phase = size.div_ceil(s);
    out.clear();
    out.resize(channels * s * s * phase * phase, 0.0);
    for c in 0..channels {
        for y in 0..size {
            let line = &x[(c * size + y) * size..][..size];
            for px in 0..s {
                let plane = (c * s + y % s) * s + px;
                let row = &mut out[(plane * phase + y / s) * phase..][..phase];
                for (slot, &value) in row.iter_mut().zip(line[px..].iter().step_by(s)) {
                    *slot = value;
                }
            }
        }
    }
}

/// A linear layer (`y = x W + b`, burn's `[inputs, outputs]` weight).
#[derive(Debug, Clone)]
struct Dense {
    outputs: usize,
    weight: Vec<f32>,
    bias: Vec<f32>,
}

impl Dense {
    fn from_layer(layer: &Linear) -> Self {
        let [_, outputs] = layer.weight.val().dims();
        Self {
            outputs,
            weight: values(&layer.weight),
            bias: bias_values(&layer.bias, outputs),
        }
    }

    /// `activation(x W + b)`.
    fn forward(&self, x: &[f32], activation: impl Fn(f32) -> f32) -> Vec<f32> {
        let mut y = self.bias.clone();
        for (&xi, row) in x.iter().zip(self.weight.chunks_exact(self.outputs)) {
            for (yj, &w) in y.iter_mut().zip(row) {
                *yj += xi * w;
            }
        }
        for v in &mut y {
            *v = activation(*v);
        }
        y
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::policy::PolicyInput;
    use burn::prelude::*;
    use proto::ObsDtype;

    fn layout() -> PolicyLayout {
        PolicyLayout {
            image_channels: vec![9, 8, 8],
            image_size: 64,
            vector_dims: vec![15, 1],
            n_actions: 24,
            obs_dtype: ObsDtype::U8,
            gru_hidden: None,
        }
    }

    #[test]
    fn gives_what_burn_gives() {
        let device = Device::flex();
        let layout = layout();
        let net = PolicyNet::new(&layout, &device);
        let cpu = CpuPolicy::from_network(&net, &layout).expect("no GRU");
        for seed in 0..3u32 {
            let observation: Vec<f32> = (0..layout.obs_len() as u32)
                .map(|i| ((i * 7919 + seed * 104_729) % 255) as f32 / 255.0)
                .collect();
            let mask: Vec<u8> = (0..24).map(|a| u8::from((a + seed) % 3 != 0)).collect();
            let input = PolicyInput::from_flat(&layout, &observation, &mask, 1, &device);
            let expected = net.forward(&input, None);
            let log_probs: Vec<f32> = expected.log_probs.into_data().try_to_vec().unwrap();
            let value: Vec<f32> = expected.values.into_data().try_to_vec().unwrap();
            let got = cpu.forward(&observation, &mask, None);
            assert!(got.hidden.is_none());
            for (a, (g, e)) in got.log_probs.iter().zip(&log_probs).enumerate() {
                if mask[a] == 0 {
                    assert!(*g < -1e8 && *e < -1e8, "masked action {a}: {g} vs {e}");
                } else {
                    assert!((g - e).abs() < 1e-5, "action {a}: {g} vs {e}");
                }
            }
            assert!(
                (got.value - value[0]).abs() < 1e-5,
                "{} vs {}",
                got.value,
                value[0]
            );
        }
    }

    #[test]
    fn a_policy_with_memory_steps_as_burns_does() {
        let device = Device::flex();
        let layout = PolicyLayout {
            gru_hidden: Some(32),
            ..layout()
        };
        let net = PolicyNet::new(&layout, &device);
        let cpu = CpuPolicy::from_network(&net, &layout).expect("burn's GRU as built");
        let mask = vec![1u8; layout.n_actions];
        // Three steps of one episode: each step's state comes from the last,
        // so a wrong gate shows in the log-probabilities and in the state.
        let (mut burn_state, mut cpu_state): (Option<Tensor<2>>, Option<Vec<f32>>) = (None, None);
        for step in 0..3u32 {
            let observation: Vec<f32> = (0..layout.obs_len() as u32)
                .map(|i| ((i * 31 + step * 7_001) % 251) as f32 / 251.0)
                .collect();
            let input = PolicyInput::from_flat(&layout, &observation, &mask, 1, &device);
            let expected = net.forward(&input, burn_state);
            let got = cpu.forward(&observation, &mask, cpu_state.as_deref());
            let log_probs: Vec<f32> = expected.log_probs.into_data().try_to_vec().unwrap();
            let hidden = expected.hidden.expect("a GRU state");
            let state: Vec<f32> = hidden.clone().into_data().try_to_vec().unwrap();
            let got_state = got.hidden.expect("a GRU state");
            assert_eq!(got_state.len(), 32);
            for (g, e) in got_state.iter().zip(&state) {
                assert!((g - e).abs() < 1e-5, "step {step}: state {g} vs {e}");
            }
            for (g, e) in got.log_probs.iter().zip(&log_probs) {
                assert!((g - e).abs() < 1e-5, "step {step}: {g} vs {e}");
            }
            assert!(state.iter().any(|v| v.abs() > 1e-3), "a state that moved");
            burn_state = Some(hidden);
            cpu_state = Some(got_state);
        }
    }
}
