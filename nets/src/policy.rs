//! The exploration policy: conv encoders for image-like inputs, MLPs for 1-D
//! inputs, concatenation, an optional GRU, and actor (64, 32, n_actions) and
//! critic (64, 32, 1) heads with invalid actions masked in the logits.

use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::gru::{Gru, GruConfig};
use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::Bool;
pub use proto::{ObsDtype, PolicyLayout};
use std::sync::atomic::{AtomicU8, Ordering};

use crate::layers::{
    ENCODER_ACTIVATION, ENCODER_CONVS, ENCODER_FEATURES, HEAD_ACTIVATION, HEAD_WIDTHS,
};

mod cpu;
#[cfg(feature = "gpu-torch")]
mod wire_bytes;

pub use cpu::{CpuPolicy, CpuPolicyStep, ObservationValue, SPARSE_PLANES_BELOW};

impl PolicyInput {
    /// Splits `rows` flat observations (`rows · obs_len` values, each row
    /// images then vectors, as [`PolicyLayout::obs_len`] counts them) and
    /// their masks (`rows · n_actions` bytes, nonzero = allowed) into tensors.
    ///
    /// # Panics
    /// If the lengths do not match `config`: callers validate first.
    pub fn from_flat(
        config: &PolicyLayout,
        obs: &[f32],
        masks: &[u8],
        rows: usize,
        device: &Device,
    ) -> Self {
        let len = config.obs_len();
        assert_eq!(obs.len(), rows * len, "observation length");
        let mut start = 0;
        let columns = config
            .input_widths()
            .map(|width| {
                let mut column = Vec::with_capacity(rows * width);
                for r in 0..rows {
                    column.extend_from_slice(&obs[r * len + start..r * len + start + width]);
                }
                start += width;
                column
            })
            .collect();
        Self::from_columns(config, columns, masks, rows, device)
    }

    /// The same from the wire's byte observations (`obs`, `rows · obs_len`
    /// bytes), moved to the device as bytes and converted there: on
    /// libtorch, where this spares a learner's batch two host copies of its
    /// floats. `None` on other backends and for float layouts: decode on
    /// the host and use [`PolicyInput::from_columns`].
    ///
    /// # Panics
    /// If the lengths do not match `config`: callers validate first.
    pub fn from_wire_bytes(
        config: &PolicyLayout,
        obs: &[u8],
        masks: &[u8],
        rows: usize,
        device: &Device,
    ) -> Option<Self> {
        #[cfg(feature = "gpu-torch")]
        return wire_bytes::upload(config, obs, masks, rows, device);
        #[cfg(not(feature = "gpu-torch"))]
        {
            let _ = (config, obs, masks, rows, device);
            None
        }
    }

    /// The same from the observations already split by input: `columns[i]`
    /// holds input `i`'s values of every row, row after row, in
    /// [`PolicyLayout::input_widths`]' order. The values move into the
    /// tensors without another copy (a learner's batch is hundreds of MB).
    ///
    /// # Panics
    /// If the lengths do not match `config`: callers validate first.
    pub fn from_columns(
        config: &PolicyLayout,
        columns: Vec<Vec<f32>>,
        masks: &[u8],
        rows: usize,
        device: &Device,
    ) -> Self {
        assert_eq!(masks.len(), rows * config.n_actions, "mask length");
        assert_eq!(
            columns.len(),
            config.image_channels.len() + config.vector_dims.len(),
            "one column per input"
        );
        let side = config.image_size;
        let mut columns = columns.into_iter();
        // The length check is TensorData's: it asserts values = shape's product.
        let mut next = |shape: Vec<usize>| TensorData::new(columns.next().unwrap(), shape);
        let images = config
            .image_channels
            .iter()
            .map(|&c| Tensor::<4>::from_data(next(vec![rows, c, side, side]), device))
            .collect();
        let vectors = config
            .vector_dims
            .iter()
            .map(|&d| Tensor::<2>::from_data(next(vec![rows, d]), device))
            .collect();
        let mask = Tensor::<2, Bool>::from_data(
            TensorData::new(
                masks.iter().map(|&m| m != 0).collect::<Vec<_>>(),
                [rows, config.n_actions],
            ),
            device,
        );
        Self {
            images,
            vectors,
            mask,
        }
    }
}

/// A small conv encoder: the strided convolutions `layers::ENCODER_CONVS`
/// describes, then a linear layer.
#[derive(Module, Debug)]
pub struct ConvEncoder {
    conv1: Conv2d,
    conv2: Conv2d,
    conv3: Conv2d,
    fc: Linear,
}

impl ConvEncoder {
    fn new(channels: usize, size: usize, device: &Device) -> Self {
        let conv = |inputs: usize, layer: crate::layers::StridedConv| {
            Conv2dConfig::new([inputs, layer.outputs], [layer.kernel, layer.kernel])
                .with_stride([layer.stride, layer.stride])
                .init(device)
        };
        let [first, second, third] = ENCODER_CONVS;
        let side = ENCODER_CONVS
            .iter()
            .fold(size, |side, layer| layer.output_side(side));
        Self {
            conv1: conv(channels, first),
            conv2: conv(first.outputs, second),
            conv3: conv(second.outputs, third),
            fc: LinearConfig::new(third.outputs * side * side, ENCODER_FEATURES).init(device),
        }
    }

    /// `[batch, channels, size, size]` → `[batch, 64]`.
    ///
    /// The convolutions run as the process-wide [`ConvPath`] says: by
    /// default as matrix products, channels-last after the first
    /// (`conv_matmul`). Either way the features are flattened channels
    /// first, as burn's convolutions give them, so the weights are the same.
    pub fn forward(&self, x: Tensor<4>) -> Tensor<2> {
        use crate::conv_matmul::Product;
        let product = match conv_path() {
            ConvPath::Burn => None,
            ConvPath::BatchProducts => Some(Product::Batch),
            ConvPath::ImageProducts => Some(Product::PerImage),
            ConvPath::Auto => Some(Product::for_device(&x.device())),
        };
        self.forward_with(x, product)
    }

    /// The forward pass with burn's convolutions (`None`) or as products.
    fn forward_with(
        &self,
        x: Tensor<4>,
        product: Option<crate::conv_matmul::Product>,
    ) -> Tensor<2> {
        let act = |x| ENCODER_ACTIVATION.tensor(x);
        let Some(product) = product else {
            let x = act(self.conv1.forward(x));
            let x = act(self.conv2.forward(x));
            let x = act(self.conv3.forward(x));
            return ENCODER_ACTIVATION.tensor(self.fc.forward(x.flatten(1, 3)));
        };
        use crate::conv_matmul::{conv, Layout};
        let x = act(conv(x, Layout::ChannelsFirst, &self.conv1, product));
        let x = act(conv(x, Layout::ChannelsLast, &self.conv2, product));
        let x = act(conv(x, Layout::ChannelsLast, &self.conv3, product));
        ENCODER_ACTIVATION.tensor(self.fc.forward(x.permute([0, 3, 1, 2]).flatten(1, 3)))
    }
}

/// How the policy encoders compute their strided convolutions. Every form
/// gives the same values and gradients (tests `encoder_paths_agree`,
/// `conv_matmul`'s); benchmarks and learners on a new GPU compare their
/// speed with `AFX_POLICY_CONV` (`auto`, `burn`, `batch`, `image`) or
/// [`set_conv_path`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ConvPath {
    /// The device's best as measured (docs/decisions/0006-cpu-kernels.md,
    /// 0010): one product per image on wgpu; one over the batch on the CPU
    /// and on libtorch.
    Auto,
    /// burn's `Conv2d`.
    Burn,
    /// One matrix product over every image of the batch.
    BatchProducts,
    /// One matrix product per image, the weights broadcast.
    ImageProducts,
}

impl std::str::FromStr for ConvPath {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim() {
            "auto" => Ok(Self::Auto),
            "burn" => Ok(Self::Burn),
            "batch" => Ok(Self::BatchProducts),
            "image" => Ok(Self::ImageProducts),
            other => Err(format!(
                "AFX_POLICY_CONV takes auto, burn, batch or image, not {other:?}"
            )),
        }
    }
}

/// The process-wide [`ConvPath`]: `0` not chosen yet, else its index + 1.
static CONV_PATH: AtomicU8 = AtomicU8::new(0);
const PATHS: [ConvPath; 4] = [
    ConvPath::Auto,
    ConvPath::Burn,
    ConvPath::BatchProducts,
    ConvPath::ImageProducts,
];

/// Chooses how every policy encoder in this process computes its
/// convolutions from now on.
pub fn set_conv_path(path: ConvPath) {
    let index = PATHS.iter().position(|&p| p == path).unwrap_or(0);
    CONV_PATH.store(index as u8 + 1, Ordering::Relaxed);
}

/// The process-wide [`ConvPath`]: as set, else `AFX_POLICY_CONV` (read
/// once; a value it does not take is said on stderr and ignored), else
/// `Auto`.
fn conv_path() -> ConvPath {
    match CONV_PATH.load(Ordering::Relaxed) {
        0 => {
            let path = std::env::var("AFX_POLICY_CONV").map_or(ConvPath::Auto, |v| {
                v.parse().unwrap_or_else(|e| {
                    eprintln!("{e}; using auto");
                    ConvPath::Auto
                })
            });
            set_conv_path(path);
            path
        }
        chosen => PATHS[usize::from(chosen - 1).min(PATHS.len() - 1)],
    }
}

/// Two-layer MLP for a 1-D input.
#[derive(Module, Debug)]
pub struct VectorEncoder {
    fc1: Linear,
    fc2: Linear,
}

impl VectorEncoder {
    fn new(dim: usize, device: &Device) -> Self {
        Self {
            fc1: LinearConfig::new(dim, ENCODER_FEATURES).init(device),
            fc2: LinearConfig::new(ENCODER_FEATURES, ENCODER_FEATURES).init(device),
        }
    }

    /// `[batch, dim]` → `[batch, 64]`.
    pub fn forward(&self, x: Tensor<2>) -> Tensor<2> {
        let act = |x| ENCODER_ACTIVATION.tensor(x);
        act(self.fc2.forward(act(self.fc1.forward(x))))
    }
}

/// Three-layer MLP head: `layers::HEAD_WIDTHS`, then the output, with
/// `layers::HEAD_ACTIVATION` between layers.
#[derive(Module, Debug)]
pub struct Head {
    fc1: Linear,
    fc2: Linear,
    out: Linear,
}

impl Head {
    fn new(input: usize, output: usize, device: &Device) -> Self {
        let [first, second] = HEAD_WIDTHS;
        Self {
            fc1: LinearConfig::new(input, first).init(device),
            fc2: LinearConfig::new(first, second).init(device),
            out: LinearConfig::new(second, output).init(device),
        }
    }

    /// `[batch, input]` → `[batch, output]`.
    pub fn forward(&self, x: Tensor<2>) -> Tensor<2> {
        let act = |x| HEAD_ACTIVATION.tensor(x);
        self.out
            .forward(act(self.fc2.forward(act(self.fc1.forward(x)))))
    }
}

/// The policy network.
#[derive(Module, Debug)]
pub struct PolicyNet {
    images: Vec<ConvEncoder>,
    vectors: Vec<VectorEncoder>,
    gru: Option<Gru>,
    actor: Head,
    critic: Head,
}

/// One batch of observations.
#[derive(Debug, Clone)]
pub struct PolicyInput {
    /// One `[batch, channels, size, size]` tensor per image-like input.
    pub images: Vec<Tensor<4>>,
    /// One `[batch, dim]` tensor per 1-D input.
    pub vectors: Vec<Tensor<2>>,
    /// `[batch, n_actions]`, true where the action is allowed.
    pub mask: Tensor<2, Bool>,
}

/// What the policy says for a batch.
#[derive(Debug, Clone)]
pub struct PolicyOutput {
    /// `[batch, n_actions]` log-probabilities; masked actions hold a very
    /// negative number (−1e9 before normalisation), so `exp` gives 0.
    pub log_probs: Tensor<2>,
    /// `[batch]` state values.
    pub values: Tensor<1>,
    /// `[batch, hidden]` GRU state after this step (GRU variant only).
    pub hidden: Option<Tensor<2>>,
}

/// Logit given to masked actions: far below any real logit, yet finite so
/// that `0 · logit` terms stay 0 in gradients and entropies.
pub const MASKED_LOGIT: f32 = -1e9;

impl PolicyNet {
    /// A freshly initialised network.
    pub fn new(config: &PolicyLayout, device: &Device) -> Self {
        let fused = ENCODER_FEATURES * (config.image_channels.len() + config.vector_dims.len());
        let gru = config
            .gru_hidden
            .map(|h| GruConfig::new(fused, h, true).init(device));
        let trunk = config.gru_hidden.unwrap_or(fused);
        Self {
            images: config
                .image_channels
                .iter()
                .map(|&c| ConvEncoder::new(c, config.image_size, device))
                .collect(),
            vectors: config
                .vector_dims
                .iter()
                .map(|&d| VectorEncoder::new(d, device))
                .collect(),
            gru,
            actor: Head::new(trunk, config.n_actions, device),
            critic: Head::new(trunk, 1, device),
        }
    }

    /// Encoders only: `[batch, 64 · inputs]`.
    fn features(&self, input: &PolicyInput) -> Tensor<2> {
        let mut parts: Vec<Tensor<2>> = self
            .images
            .iter()
            .zip(&input.images)
            .map(|(e, x)| e.forward(x.clone()))
            .collect();
        parts.extend(
            self.vectors
                .iter()
                .zip(&input.vectors)
                .map(|(e, x)| e.forward(x.clone())),
        );
        Tensor::cat(parts, 1)
    }

    fn heads(&self, trunk: Tensor<2>, mask: Tensor<2, Bool>) -> (Tensor<2>, Tensor<1>) {
        let logits = self
            .actor
            .forward(trunk.clone())
            .mask_fill(mask.bool_not(), MASKED_LOGIT);
        let log_probs = burn::tensor::activation::log_softmax(logits, 1);
        let values = self.critic.forward(trunk).squeeze_dim(1);
        (log_probs, values)
    }

    /// One step for a batch of independent observations. `hidden` is the
    /// `[batch, gru_hidden]` state for the GRU variant (zeros at episode
    /// start; ignored without a GRU).
    pub fn forward(&self, input: &PolicyInput, hidden: Option<Tensor<2>>) -> PolicyOutput {
        let features = self.features(input);
        let (trunk, hidden) = match &self.gru {
            Some(gru) => {
                let out = gru.forward(features.unsqueeze_dim(1), hidden);
                let h: Tensor<2> = out.squeeze_dim(1);
                (h.clone(), Some(h))
            }
            None => (features, None),
        };
        let (log_probs, values) = self.heads(trunk, input.mask.clone());
        PolicyOutput {
            log_probs,
            values,
            hidden,
        }
    }

    /// GRU variant over sequences: inputs are `[batch · steps, …]` in
    /// batch-major order (sequence `b` occupies rows `b·steps .. (b+1)·steps`),
    /// `start_hidden` is `[batch, gru_hidden]`, and `episode_starts` is
    /// `[batch · steps]` with 1 where an episode begins (the state is reset to
    /// zero before that step). Outputs are `[batch · steps, …]` in the same order.
    /// Without a GRU this is [`PolicyNet::forward`].
    pub fn forward_sequences(
        &self,
        input: &PolicyInput,
        start_hidden: Tensor<2>,
        episode_starts: Tensor<1>,
        steps: usize,
    ) -> PolicyOutput {
        let Some(gru) = &self.gru else {
            return self.forward(input, None);
        };
        let features = self.features(input);
        let [rows, width] = features.dims();
        let batch = rows / steps;
        let features: Tensor<3> = features.reshape([batch, steps, width]);
        let keep: Tensor<2> = (episode_starts.neg() + 1.0).reshape([batch, steps]);
        let mut h = start_hidden;
        let mut outs = Vec::with_capacity(steps);
        for t in 0..steps {
            let x = features.clone().narrow(1, t, 1);
            let k: Tensor<2> = keep.clone().narrow(1, t, 1);
            h = h * k;
            let out: Tensor<3> = gru.forward(x, Some(h));
            h = out.clone().squeeze_dim(1);
            outs.push(out);
        }
        let trunk: Tensor<2> = Tensor::cat(outs, 1).reshape([rows, h.dims()[1]]);
        let (log_probs, values) = self.heads(trunk, input.mask.clone());
        PolicyOutput {
            log_probs,
            values,
            hidden: Some(h),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config(gru: Option<usize>) -> PolicyLayout {
        PolicyLayout {
            image_channels: vec![4, 2],
            image_size: 128,
            vector_dims: vec![15],
            n_actions: 6,
            obs_dtype: ObsDtype::F32,
            gru_hidden: gru,
        }
    }

    fn input(batch: usize, device: &Device) -> PolicyInput {
        let mask = Tensor::<2, Bool>::from_data(
            TensorData::new(
                (0..batch * 6)
                    .map(|i| i % 6 != 2 && i % 6 != 5)
                    .collect::<Vec<_>>(),
                [batch, 6],
            ),
            device,
        );
        PolicyInput {
            images: vec![
                Tensor::random(
                    [batch, 4, 128, 128],
                    burn::tensor::Distribution::Default,
                    device,
                ),
                Tensor::random(
                    [batch, 2, 128, 128],
                    burn::tensor::Distribution::Default,
                    device,
                ),
            ],
            vectors: vec![Tensor::random(
                [batch, 15],
                burn::tensor::Distribution::Default,
                device,
            )],
            mask,
        }
    }

    #[test]
    fn outputs_have_documented_shapes_and_masked_actions_get_no_mass() {
        let device = Device::flex();
        let net = PolicyNet::new(&config(None), &device);
        let out = net.forward(&input(3, &device), None);
        assert_eq!(out.log_probs.dims(), [3, 6]);
        assert_eq!(out.values.dims(), [3]);
        let p: Vec<f32> = out.log_probs.exp().into_data().try_to_vec::<f32>().unwrap();
        for row in p.chunks(6) {
            assert!((row.iter().sum::<f32>() - 1.0).abs() < 1e-5);
            assert_eq!(row[2], 0.0);
            assert_eq!(row[5], 0.0);
        }
    }

    #[test]
    fn flat_observations_split_into_the_inputs_in_order() {
        let device = Device::flex();
        let config = PolicyLayout {
            image_channels: vec![2],
            image_size: 2,
            vector_dims: vec![3, 1],
            n_actions: 2,
            obs_dtype: ObsDtype::F32,
            gru_hidden: None,
        };
        assert_eq!(config.obs_len(), 12);
        let obs: Vec<f32> = (0..24).map(|i| i as f32).collect();
        let input = PolicyInput::from_flat(&config, &obs, &[1, 0, 0, 1], 2, &device);
        let image: Vec<f32> = input.images[0].clone().into_data().try_to_vec().unwrap();
        assert_eq!(image[..8], obs[..8]);
        assert_eq!(image[8..], obs[12..20]);
        let v0: Vec<f32> = input.vectors[0].clone().into_data().try_to_vec().unwrap();
        assert_eq!(v0, vec![8.0, 9.0, 10.0, 20.0, 21.0, 22.0]);
        let v1: Vec<f32> = input.vectors[1].clone().into_data().try_to_vec().unwrap();
        assert_eq!(v1, vec![11.0, 23.0]);
        let mask: Vec<bool> = input.mask.into_data().try_to_vec().unwrap();
        assert_eq!(mask, vec![true, false, false, true]);
    }

    #[test]
    fn the_gru_variant_steps_and_runs_sequences_consistently() {
        let device = Device::flex();
        let net = PolicyNet::new(&config(Some(32)), &device);
        let batch_input = input(4, &device);
        let out = net.forward(&batch_input, None);
        assert_eq!(out.hidden.as_ref().unwrap().dims(), [4, 32]);
        // As one sequence of 4 steps with no resets, the last hidden state
        // equals stepping one observation at a time.
        let zeros = Tensor::<2>::zeros([1, 32], &device);
        let seq =
            net.forward_sequences(&batch_input, zeros.clone(), Tensor::zeros([4], &device), 4);
        let mut h = zeros;
        for t in 0..4 {
            let one = PolicyInput {
                images: batch_input
                    .images
                    .iter()
                    .map(|x| x.clone().narrow(0, t, 1))
                    .collect(),
                vectors: batch_input
                    .vectors
                    .iter()
                    .map(|x| x.clone().narrow(0, t, 1))
                    .collect(),
                mask: batch_input.mask.clone().narrow(0, t, 1),
            };
            h = net.forward(&one, Some(h)).hidden.unwrap();
        }
        let diff: f32 = (seq.hidden.unwrap() - h).abs().max().into_scalar();
        assert!(diff < 1e-5, "{diff}");
    }

    #[test]
    fn encoder_paths_agree() {
        // Values and first-layer weight gradients of every convolution path.
        use crate::conv_matmul::Product;
        let device = Device::flex().autodiff();
        let encoder = ConvEncoder::new(5, 64, &device);
        let x = Tensor::<4>::random([3, 5, 64, 64], burn::tensor::Distribution::Default, &device);
        let run = |product: Option<Product>| {
            let out = encoder.forward_with(x.clone(), product);
            let grads = (out.clone() * out.clone()).sum().backward();
            let grad = encoder.conv1.weight.grad(&grads).expect("a gradient");
            (out.inner(), grad)
        };
        let (burn_out, burn_grad) = run(None);
        assert!(burn_grad.clone().abs().max().into_scalar::<f32>() > 0.0);
        for product in [Product::Batch, Product::PerImage] {
            let (mm_out, mm_grad) = run(Some(product));
            crate::test_support::assert_close(mm_out, burn_out.clone(), "encoder outputs");
            crate::test_support::assert_close(mm_grad, burn_grad.clone(), "conv1 weight gradients");
        }
    }

    #[test]
    fn conv_paths_parse_by_name() {
        assert_eq!("batch".parse::<ConvPath>(), Ok(ConvPath::BatchProducts));
        assert_eq!(" image".parse::<ConvPath>(), Ok(ConvPath::ImageProducts));
        assert_eq!("burn".parse::<ConvPath>(), Ok(ConvPath::Burn));
        assert_eq!("auto".parse::<ConvPath>(), Ok(ConvPath::Auto));
        assert!("cudnn"
            .parse::<ConvPath>()
            .unwrap_err()
            .contains("auto, burn, batch or image"));
    }
}
