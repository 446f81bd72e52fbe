//! The policy's forward pass on the CPU for one observation, for acting.
//!
//! Why it exists: an actor runs the policy on every step, and on the CPU
//! burn's pass over `ours`' three conv encoders (about 15 MFLOP at 64 px)
//! took a millisecond or more: the time goes to per-operation overhead
//! (tensor allocation, layout copies), not to arithmetic. Here each
//! convolution is a few GEMMs straight over the input's stride phases
//! ([`Conv`]), the rest (dense layers, the GRU of the methods with memory)
//! plain loops over weights copied out once.
//!
//! The arithmetic is the network's own: [`CpuPolicy::forward`] equals
//! [`PolicyNet::forward`] to float rounding (tested below). It reads an
//! observation as floats or as a byte layout's bytes ([`ObservationValue`]),
//! so that an actor need not expand the bytes it sends into a float copy
//! of several hundred thousand values a step only for this pass.

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

/// One value of a flat observation as [`CpuPolicy::forward`] reads it:
/// a float as it is, or a byte layout's byte as the unit value it stands
/// for ([`proto::byte_to_unit`], the learner's reading of it). Zero (the
/// default) reads as 0.
pub trait ObservationValue: Copy + Default {
    /// The value the network sees.
    fn unit(self) -> f32;
}

impl ObservationValue for f32 {
    #[inline]
    fn unit(self) -> f32 {
        self
    }
}

impl ObservationValue for u8 {
    #[inline]
    fn unit(self) -> f32 {
        proto::BYTE_UNITS[usize::from(self)]
    }
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
    /// vectors, [`PolicyLayout::obs_len`] values, floats or bytes) and its
    /// mask (one byte per action, nonzero = allowed); for a policy with a
    /// GRU, `hidden` is its state before this step (`None`: zeros, an
    /// episode's start).
    ///
    /// # Panics
    /// If the lengths do not match the layout: callers validate first.
    pub fn forward<T: ObservationValue>(
        &self,
        observation: &[T],
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
            let input: Vec<f32> = observation[at..at + dim].iter().map(|v| v.unit()).collect();
            let inner = mlp[0].forward(&input, encoder);
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

/// A valid (unpadded), strided, square convolution followed by the
/// encoders' activation.
///
/// Computed without im2col columns: a `k × k` convolution with stride `s`
/// is a `t × t` convolution with stride 1 (`t = ⌈k / s⌉` taps a side) over
/// the input's stride phases ([`split_phases`]: `s²` planes per input
/// channel, `⌈size / s⌉` square), and each tap is one GEMM whose right-hand
/// side is the phase planes themselves, read from the tap's offset: output
/// row `oy` is computed `⌈size / s⌉` wide, so that output pixel
/// `oy · ⌈size / s⌉ + ox` reads phase pixel `(oy + ty) · ⌈size / s⌉ + ox +
/// tx` for every pixel at once. The columns past the output's side read the
/// next row and are dropped. Copying im2col columns (four times the input
/// for an 8 × 8 kernel with stride 4) took a quarter of a 128-px pass.
#[derive(Debug, Clone)]
struct Conv {
    inputs: usize,
    outputs: usize,
    kernel: usize,
    stride: usize,
    /// One block per tap `(ty, tx)`, row-major `outputs × (inputs · s²)`:
    /// row `o`, column `(c, py, px)` holds burn's weight
    /// `[o][c][ty · s + py][tx · s + px]`, zero where that lies past the
    /// kernel (a 3 × 3 kernel with stride 2 fills 9 of 2 × 2 taps' 16).
    taps: Vec<f32>,
    bias: Vec<f32>,
}

impl Conv {
    fn from_layer(layer: &Conv2d) -> Self {
        let [outputs, inputs, kernel, _] = layer.weight.val().dims();
        Self::from_weights(
            &values(&layer.weight),
            bias_values(&layer.bias, outputs),
            [outputs, inputs, kernel],
            layer.stride[0],
        )
    }

    /// From burn's `[output][input][ky][kx]` weights.
    fn from_weights(
        weight: &[f32],
        bias: Vec<f32>,
        [outputs, inputs, kernel]: [usize; 3],
        stride: usize,
    ) -> Self {
        let (k, s) = (kernel, stride);
        let t = k.div_ceil(s);
        let depth = inputs * s * s;
        let mut taps = vec![0.0; t * t * outputs * depth];
        for o in 0..outputs {
            for c in 0..inputs {
                for ky in 0..k {
                    for kx in 0..k {
                        let tap = (ky / s) * t + kx / s;
                        let column = (c * s + ky % s) * s + kx % s;
                        taps[(tap * outputs + o) * depth + column] =
                            weight[((o * inputs + c) * k + ky) * k + kx];
                    }
                }
            }
        }
        Self {
            inputs,
            outputs,
            kernel,
            stride,
            taps,
            bias,
        }
    }

    /// `[inputs][size][size]` → (`[outputs][out][out]`, `out`).
    fn forward<T: ObservationValue>(&self, x: &[T], size: usize) -> (Vec<f32>, usize) {
        let (k, s) = (self.kernel, self.stride);
        let t = k.div_ceil(s);
        let out = (size - k) / s + 1;
        let phase = size.div_ceil(s);
        let wide = out * phase;
        let depth = self.inputs * s * s;
        let mut y = vec![0.0; self.outputs * out * out];
        SCRATCH.with_borrow_mut(|(wide_output, split)| {
            // The last taps' dropped columns read up to (t − 1) · (phase + 1)
            // values past the last plane.
            split_phases(x, self.inputs, size, s, (t - 1) * (phase + 1), split);
            wide_output.resize(self.outputs * wide, 0.0);
            // Output rows in bands whose phase rows stay in the cache while
            // every tap reads them.
            let band = (BAND_BYTES / (depth * phase * 4)).clamp(1, out);
            for first in (0..out).step_by(band) {
                let columns = band.min(out - first) * phase;
                for (tap, weights) in self.taps.chunks_exact(self.outputs * depth).enumerate() {
                    let (ty, tx) = (tap / t, tap % t);
                    matmul_lhs_rows(
                        &mut wide_output[first * phase..],
                        wide,
                        (weights, depth),
                        &split[(first + ty) * phase + tx..],
                        phase_plane_len(phase),
                        (self.outputs, columns, depth),
                        tap > 0,
                    );
                }
            }
            for ((plane, wide), &bias) in y
                .chunks_exact_mut(out * out)
                .zip(wide_output.chunks_exact(wide))
                .zip(&self.bias)
            {
                for (row, wide) in plane.chunks_exact_mut(out).zip(wide.chunks_exact(phase)) {
                    for (v, &w) in row.iter_mut().zip(wide) {
                        *v = ENCODER_ACTIVATION.value(w + bias);
                    }
                }
            }
        });
        (y, out)
    }
}

/// The most bytes of phase rows one band of [`Conv::forward`]'s output rows
/// reads: about what a core's L2 cache holds beside the weights and the
/// output, so that each tap after the first finds them there.
const BAND_BYTES: usize = 128 * 1024;

thread_local! {
    /// Each thread's wide output and stride phases for [`Conv::forward`],
    /// kept from pass to pass: allocated anew on every pass (hundreds of kB)
    /// they cost page faults whenever the allocator had handed the memory
    /// back to the system, which made a 64-px pass more than twice as slow
    /// in one process as in another (`cpu_policy` bench; docs/performance.md).
    static SCRATCH: RefCell<(Vec<f32>, Vec<f32>)> = const { RefCell::new((Vec::new(), Vec::new())) };
}

/// Values from one phase plane to the next in [`split_phases`]' output: the
/// plane and 16 values (a cache line) more. A GEMM reads the planes as the
/// rows of its right-hand side, and at 128 px a plane of 32 × 32 values is
/// 4 KiB: rows a power of two apart fall into the same few cache sets and
/// evict each other.
fn phase_plane_len(phase: usize) -> usize {
    phase * phase + 16
}

/// `[channels][size][size]` split into its stride-`s` phases, into `out`:
/// `[channels][py][px][Y][X] = x[c][Y·s + py][X·s + px]`, each phase
/// `⌈size / s⌉` square and [`phase_plane_len`] values from the next, zeros
/// past the edge, between the planes and in `tail` values after the last.
fn split_phases<T: ObservationValue>(
    x: &[T],
    channels: usize,
    size: usize,
    s: usize,
    tail: usize,
    out: &mut Vec<f32>,
) {
    let phase = size.div_ceil(s);
    let plane_len = phase_plane_len(phase);
    let len = channels * s * s * plane_len;
    out.resize(len + tail, 0.0);
    out[len..].fill(0.0);
    for plane in out[..len].chunks_exact_mut(plane_len) {
        plane[phase * phase..].fill(0.0);
    }
    let past_edge = vec![T::default(); size];
    for (c, input) in x.chunks_exact(size * size).take(channels).enumerate() {
        for y in 0..phase * s {
            let line = input.get(y * size..(y + 1) * size).unwrap_or(&past_edge);
            // Phases (py, 0..s) of channel c lie one after another.
            let planes = &mut out[(c * s + y % s) * s * plane_len..][..s * plane_len];
            match s {
                2 => deinterleave::<2, T>(line, planes, phase, y / s),
                4 => deinterleave::<4, T>(line, planes, phase, y / s),
                _ => {
                    for (px, plane) in planes.chunks_exact_mut(plane_len).enumerate() {
                        let row = &mut plane[y / s * phase..][..phase];
                        let mut values = line.iter().skip(px).step_by(s);
                        for slot in row {
                            *slot = values.next().map_or(0.0, |v| v.unit());
                        }
                    }
                }
            }
        }
    }
}

/// Row `row` of each of the `S` planes of `planes` (each `phase` square,
/// [`phase_plane_len`] apart):
/// plane `px` takes `line[X · S + px]` at column `X`, zeros past the line's
/// end. With the stride a constant, the copy is one pass over the line in
/// vector registers; a strided gather per plane took a quarter of a 128-px
/// pass.
fn deinterleave<const S: usize, T: ObservationValue>(
    line: &[T],
    planes: &mut [f32],
    phase: usize,
    row: usize,
) {
    let mut planes = planes.chunks_exact_mut(phase_plane_len(phase));
    let mut rows: [&mut [f32]; S] =
        std::array::from_fn(|_| &mut planes.next().expect("S planes")[row * phase..][..phase]);
    let whole = line.len() / S;
    for (x, values) in line.chunks_exact(S).enumerate() {
        for (row, &value) in rows.iter_mut().zip(values) {
            row[x] = value.unit();
        }
    }
    for (px, row) in rows.iter_mut().enumerate() {
        for (x, slot) in row.iter_mut().enumerate().skip(whole) {
            *slot = line.get(x * S + px).map_or(0.0, |v| v.unit());
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

    /// The convolution by its definition, one output value at a time.
    fn reference_conv(
        x: &[f32],
        weight: &[f32],
        bias: &[f32],
        [outputs, inputs, k, s, size]: [usize; 5],
    ) -> Vec<f32> {
        let out = (size - k) / s + 1;
        let mut y = Vec::with_capacity(outputs * out * out);
        for o in 0..outputs {
            for oy in 0..out {
                for ox in 0..out {
                    let mut sum = f64::from(bias[o]);
                    for c in 0..inputs {
                        for ky in 0..k {
                            for kx in 0..k {
                                let w = weight[((o * inputs + c) * k + ky) * k + kx];
                                let v = x[(c * size + oy * s + ky) * size + ox * s + kx];
                                sum += f64::from(w) * f64::from(v);
                            }
                        }
                    }
                    y.push(ENCODER_ACTIVATION.value(sum as f32));
                }
            }
        }
        y
    }

    #[test]
    fn convolutions_over_stride_phases_equal_the_definition() {
        // The policy's three layers at 128 px, sides that the stride does
        // not divide, and a stride of 1.
        for [outputs, inputs, k, s, size] in [
            [16, 10, 8, 4, 128],
            [32, 16, 4, 2, 31],
            [32, 32, 3, 2, 14],
            [5, 3, 8, 4, 66],
            [4, 2, 3, 2, 9],
            [3, 2, 3, 1, 7],
        ] {
            let pseudo = |i: usize, m: usize| ((i * 7919 + m) % 211) as f32 / 211.0 - 0.4;
            let weight: Vec<f32> = (0..outputs * inputs * k * k)
                .map(|i| pseudo(i, 1))
                .collect();
            let bias: Vec<f32> = (0..outputs).map(|i| pseudo(i, 5) * 0.1).collect();
            let x: Vec<f32> = (0..inputs * size * size).map(|i| pseudo(i, 3)).collect();
            let conv = Conv::from_weights(&weight, bias.clone(), [outputs, inputs, k], s);
            let (got, out) = conv.forward(&x, size);
            let expected = reference_conv(&x, &weight, &bias, [outputs, inputs, k, s, size]);
            assert_eq!(out, (size - k) / s + 1);
            assert_eq!(got.len(), expected.len());
            for (i, (g, e)) in got.iter().zip(&expected).enumerate() {
                assert!(
                    (g - e).abs() <= 1e-4 * (1.0 + e.abs()),
                    "k {k}, s {s}, side {size}: value {i}: {g} against {e}"
                );
            }
            assert!(expected.iter().any(|&v| v > 0.1), "a test that can see");
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
            // Every value here is a byte level: the same observation as a
            // byte layout's bytes gives the same pass to the bit.
            let bytes: Vec<u8> = observation
                .iter()
                .map(|&v| proto::unit_to_byte(v))
                .collect();
            assert_eq!(cpu.forward(&bytes, &mask, None), got, "read from bytes");
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
