//! The policy's forward pass on the CPU for one observation, for acting.
//!
//! Why it exists: an actor runs the policy on every step, and on the CPU
//! burn's pass over `ours`' three conv encoders (about 15 MFLOP at 64 px)
//! took a millisecond or more: the time goes to per-operation overhead
//! (tensor allocation, layout copies), not to arithmetic. Here each
//! convolution is a few GEMMs straight over the input's stride phases
//! ([`Conv`]), except that the first layers add the observation's
//! mostly-zero planes (the state's masks) pixel by pixel ([`InputConv`]);
//! the rest (dense layers, the GRU of the methods with memory) are plain
//! loops over weights copied out once.
//!
//! The arithmetic is the network's own: [`CpuPolicy::forward`] equals
//! [`PolicyNet::forward`] to float rounding (tested below). It reads an
//! observation as floats or as a byte layout's bytes ([`ObservationValue`]),
//! so that an actor need not expand the bytes it sends into a float copy
//! of several hundred thousand values a step only for this pass.

mod input_conv;
mod strided_conv;

use burn::nn::gru::Gru;
use burn::nn::Linear;

use self::input_conv::InputConv;
pub use self::input_conv::SPARSE_PLANES_BELOW;
use self::strided_conv::Conv;
use super::{ConvEncoder, Head, PolicyLayout, PolicyNet, VectorEncoder, MASKED_LOGIT};
use crate::kernels::{bias_values, values};
use crate::layers::{ENCODER_ACTIVATION, HEAD_ACTIVATION};

/// The policy's weights, laid out for [`CpuPolicy::forward`].
#[derive(Debug, Clone)]
pub struct CpuPolicy {
    layout: PolicyLayout,
    /// Each image encoder's first layer (which reads the observation) and
    /// the two after it.
    images: Vec<(InputConv, [Conv; 2])>,
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

    /// Whether the network sees 0 (the first layers skip such values).
    fn is_zero(self) -> bool;
}

impl ObservationValue for f32 {
    #[inline]
    fn unit(self) -> f32 {
        self
    }

    #[inline]
    fn is_zero(self) -> bool {
        self == 0.0
    }
}

impl ObservationValue for u8 {
    #[inline]
    fn unit(self) -> f32 {
        proto::BYTE_UNITS[usize::from(self)]
    }

    #[inline]
    fn is_zero(self) -> bool {
        self == 0
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
                .map(|e: &ConvEncoder| {
                    let rest = [&e.conv2, &e.conv3].map(Conv::from_layer);
                    (InputConv::from_layer(&e.conv1), rest)
                })
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

    /// The same policy, its first layers adding the observation's planes
    /// with fewer than `share` of their values nonzero pixel by pixel
    /// instead of through their GEMMs ([`SPARSE_PLANES_BELOW`] unless
    /// said; 0: every plane through the GEMMs). The values are the same
    /// to float rounding; the `cpu_policy` bench compares the times.
    pub fn with_sparse_planes_below(self, share: f32) -> Self {
        Self {
            images: (self.images.into_iter())
                .map(|(first, rest)| (first.with_sparse_below(share), rest))
                .collect(),
            ..self
        }
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
            let (first, rest) = convs;
            let (mut x, mut size) = first.forward(&observation[at..at + len], side);
            for conv in rest {
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
        // Seeds 3 to 5 are mostly zeros, as the state's masks are: their
        // planes go pixel by pixel.
        for seed in 0..6u32 {
            let observation: Vec<f32> = (0..layout.obs_len() as u32)
                .map(|i| {
                    let value = ((i * 7919 + seed * 104_729) % 255) as f32 / 255.0;
                    let kept = seed < 3 || i.wrapping_mul(2_654_435_761) % 100 < 4;
                    if kept {
                        value
                    } else {
                        0.0
                    }
                })
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
            let through_gemms = cpu.clone().with_sparse_planes_below(0.0);
            let dense = through_gemms.forward(&observation, &mask, None);
            for (g, d) in got.log_probs.iter().zip(&dense.log_probs) {
                assert!(
                    (g - d).abs() < 1e-5,
                    "pixel by pixel {g}, through the GEMMs {d}"
                );
            }
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
