//! The affordance U-Net: RGB-D in, one sigmoid map per affordance out.
//!
//! Four resolution levels on each path (128, 64, 32, 16 pixels for a 128 × 128
//! input) with encoder channels (24, 48, 92, 164): two 3 × 3 convolutions per
//! level, 2 × 2 max pooling down, 2 × 2 transposed convolutions up, skip
//! connections by concatenation, and a 1 × 1 output convolution. About
//! 0.92 M parameters. Inputs must have sides divisible by 8.
//!
//! A network in training may hold a batch normalisation after each 3 × 3
//! convolution (`[unet] batch_norm`; [`AffordanceUnet::with_batch_norm`]);
//! what leaves training is [`AffordanceUnet::folded`], the same function in
//! plain convolutions, so that every inference path (`unet_cpu`,
//! `unet_torch`) and the weights the actors get stay as they are.

use burn::module::Param;
use burn::nn::conv::{Conv2d, Conv2dConfig, ConvTranspose2d, ConvTranspose2dConfig};
use burn::nn::pool::{MaxPool2d, MaxPool2dConfig};
use burn::nn::{BatchNorm, BatchNormConfig, PaddingConfig2d};
use burn::prelude::*;
use burn::tensor::activation::relu;

use crate::unet_conv_cpu::{conv3x3, Activation};

pub use crate::layers::UNET_CHANNELS;

/// Two 3 × 3 same-padded convolutions with ReLU, each optionally batch
/// normalised before its ReLU.
#[derive(Module, Debug)]
pub struct DoubleConv {
    pub(crate) first: Conv2d,
    pub(crate) second: Conv2d,
    /// The normalisation of `first`'s output (a network in training only).
    first_norm: Option<BatchNorm>,
    /// The normalisation of `second`'s output.
    second_norm: Option<BatchNorm>,
}

impl DoubleConv {
    fn new(input: usize, output: usize, device: &Device) -> Self {
        let conv = |i, o| {
            Conv2dConfig::new([i, o], [3, 3])
                .with_padding(PaddingConfig2d::Same)
                .init(device)
        };
        Self {
            first: conv(input, output),
            second: conv(output, output),
            first_norm: None,
            second_norm: None,
        }
    }

    fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let x = conv_norm_relu(&self.first, self.first_norm.as_ref(), x);
        conv_norm_relu(&self.second, self.second_norm.as_ref(), x)
    }

    /// With a fresh normalisation after each convolution.
    fn with_batch_norm(self) -> Self {
        let norm = |conv: &Conv2d| {
            let [outputs, ..] = conv.weight.dims();
            BatchNormConfig::new(outputs).init(&conv.weight.device())
        };
        Self {
            first_norm: Some(norm(&self.first)),
            second_norm: Some(norm(&self.second)),
            ..self
        }
    }

    /// The same function (normalisations at their running statistics) in
    /// plain convolutions.
    fn folded(&self) -> Self {
        Self {
            first: fold(&self.first, self.first_norm.as_ref()),
            second: fold(&self.second, self.second_norm.as_ref()),
            first_norm: None,
            second_norm: None,
        }
    }
}

/// `relu(norm(conv(x)))`, or `relu(conv(x))` without a normalisation. In
/// training (tracked tensors) the normalisation uses the batch's statistics
/// and updates its running ones; otherwise it uses the running ones.
fn conv_norm_relu(conv: &Conv2d, norm: Option<&BatchNorm>, x: Tensor<4>) -> Tensor<4> {
    match norm {
        None => conv3x3(conv, x, Activation::Relu),
        Some(norm) => relu(norm.forward(conv3x3(conv, x, Activation::Identity))),
    }
}

/// `conv` followed by `norm` at its running statistics as one convolution:
/// `norm(W x + b) = s (W x + b − μ) + β` with `s = γ / √(σ² + ε)` per
/// output, so the weight is `s W` and the bias `s (b − μ) + β`. The
/// statistics are read synchronised (burn keeps a training pass's update
/// aside until then).
fn fold(conv: &Conv2d, norm: Option<&BatchNorm>) -> Conv2d {
    let Some(norm) = norm else {
        return conv.clone();
    };
    let [outputs, inputs, kh, kw] = conv.weight.dims();
    let scale = norm.gamma.val() / (norm.running_var.value_sync() + norm.epsilon).sqrt();
    let bias = match &conv.bias {
        Some(bias) => bias.val(),
        None => Tensor::zeros([outputs], &conv.weight.device()),
    };
    let weight = conv.weight.val().reshape([outputs, inputs * kh * kw])
        * scale.clone().reshape([outputs, 1]);
    let mut folded = conv.clone();
    folded.weight = Param::from_tensor(weight.reshape([outputs, inputs, kh, kw]));
    folded.bias = Some(Param::from_tensor(
        (bias - norm.running_mean.value_sync()) * scale + norm.beta.val(),
    ));
    folded
}

/// One decoder level: upsample, concatenate the skip, two convolutions.
#[derive(Module, Debug)]
pub struct UpLevel {
    pub(crate) up: ConvTranspose2d,
    pub(crate) conv: DoubleConv,
}

impl UpLevel {
    fn new(deep: usize, skip: usize, device: &Device) -> Self {
        Self {
            up: ConvTranspose2dConfig::new([deep, skip], [2, 2])
                .with_stride([2, 2])
                .init(device),
            conv: DoubleConv::new(2 * skip, skip, device),
        }
    }

    fn forward(&self, deep: Tensor<4>, skip: Tensor<4>) -> Tensor<4> {
        let up = self.up.forward(deep);
        self.conv.forward(Tensor::cat(vec![up, skip], 1))
    }
}

/// The U-Net.
#[derive(Module, Debug)]
pub struct AffordanceUnet {
    pub(crate) down: Vec<DoubleConv>,
    pool: MaxPool2d,
    pub(crate) up: Vec<UpLevel>,
    pub(crate) head: Conv2d,
}

impl AffordanceUnet {
    /// A freshly initialised network for `input_channels` (4 for RGB-D) and
    /// one output per affordance.
    pub fn new(input_channels: usize, affordances: usize, device: &Device) -> Self {
        let c = UNET_CHANNELS;
        let inputs = std::iter::once(input_channels).chain(c);
        Self {
            down: inputs
                .zip(c)
                .map(|(i, o)| DoubleConv::new(i, o, device))
                .collect(),
            pool: MaxPool2dConfig::new([2, 2]).init(),
            // Deep to shallow, as the decoder runs.
            up: c
                .windows(2)
                .rev()
                .map(|pair| UpLevel::new(pair[1], pair[0], device))
                .collect(),
            head: Conv2dConfig::new([c[0], affordances], [1, 1]).init(device),
        }
    }

    /// The network with a fresh batch normalisation between each 3 × 3
    /// convolution and its ReLU, for training (`[unet] batch_norm`): with
    /// its running statistics at their start (mean 0, variance 1) it is the
    /// same function as `self` outside training, up to the normalisation's ε.
    pub fn with_batch_norm(self) -> Self {
        Self {
            down: self
                .down
                .into_iter()
                .map(DoubleConv::with_batch_norm)
                .collect(),
            up: self
                .up
                .into_iter()
                .map(|level| UpLevel {
                    up: level.up,
                    conv: level.conv.with_batch_norm(),
                })
                .collect(),
            ..self
        }
    }

    /// Whether the network holds batch normalisations (a network in
    /// training with `[unet] batch_norm`).
    pub fn has_batch_norm(&self) -> bool {
        self.down
            .iter()
            .chain(self.up.iter().map(|level| &level.conv))
            .any(|conv| conv.first_norm.is_some() || conv.second_norm.is_some())
    }

    /// The function this network computes outside training, in plain
    /// convolutions: each batch normalisation, at its running statistics,
    /// folded into the convolution before it. Every inference path and the
    /// weights the actors get take this form; a network without
    /// normalisations comes back as it is.
    pub fn folded(&self) -> Self {
        Self {
            down: self.down.iter().map(DoubleConv::folded).collect(),
            pool: self.pool.clone(),
            up: self
                .up
                .iter()
                .map(|level| UpLevel {
                    up: level.up.clone(),
                    conv: level.conv.folded(),
                })
                .collect(),
            head: self.head.clone(),
        }
    }

    /// Each layer's weight and bias, in the order the forward pass uses
    /// them: the encoder's convolutions shallow to deep (two per level),
    /// then per decoder level, deep to shallow, the transposed convolution
    /// and its two convolutions, then the head. Of a network without batch
    /// normalisations (a [`AffordanceUnet::folded`] one).
    #[cfg(feature = "gpu-torch")]
    pub fn layers(&self) -> Vec<(Tensor<4>, Option<Tensor<1>>)> {
        let params = |layer: &Conv2d| (layer.weight.val(), layer.bias.as_ref().map(|b| b.val()));
        let mut layers = Vec::new();
        for level in &self.down {
            layers.extend([params(&level.first), params(&level.second)]);
        }
        for level in &self.up {
            let up = &level.up;
            layers.push((up.weight.val(), up.bias.as_ref().map(|b| b.val())));
            layers.extend([params(&level.conv.first), params(&level.conv.second)]);
        }
        layers.push(params(&self.head));
        layers
    }

    /// `[batch, channels, h, w]` → logits `[batch, affordances, h, w]`
    /// (apply a sigmoid, after the learner's temperature scaling, for
    /// probabilities), one layer after another, each the backend's
    /// operations (on the CPU the 3 × 3 convolutions `unet_conv_cpu`'s).
    /// Training on libtorch takes the whole pass as one operation instead
    /// (`training::unet_train_torch`).
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let mut skips = Vec::with_capacity(3);
        let mut x = self.down[0].forward(x);
        for level in &self.down[1..] {
            skips.push(x.clone());
            x = level.forward(self.pool.forward(x));
        }
        for level in &self.up {
            x = level.forward(x, skips.pop().expect("one skip per up level"));
        }
        self.head.forward(x)
    }
}

/// How a plane's BCE weighs its positive labelled pixels against its
/// negative ones (`[unet] class_balance`; docs/ladder.md).
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ClassBalance {
    /// Every labelled pixel alike (the mean over the labelled pixels), the
    /// paper's: probabilities follow the labels' share of positives, which
    /// for pick up, with the floor and walls labelled negative in every
    /// frame, is two to five pixels in a thousand.
    Pixels,
    /// Positives and negatives each half of the plane's BCE where the batch
    /// has both (each class's mean): the network's odds are those of a
    /// plane with as many positive as negative labels, so 0.5 is where a
    /// pixel is as likely to afford the affordance as not, whatever the
    /// share of positives the run happened to label (the default;
    /// docs/decisions/0011-class-balanced-loss.md).
    #[default]
    Classes,
    /// As `Classes`, with the positives' mean carrying this share of the
    /// plane's BCE and the negatives' the rest (the α of an α-balanced
    /// loss): below one half it moves the network's odds from even towards
    /// the rarer positives that rooms hold (`{ positive-share = 0.25 }`).
    PositiveShare(f32),
}

impl ClassBalance {
    /// The share of a plane's BCE its positive pixels carry when the batch
    /// has both classes; `None` for [`ClassBalance::Pixels`].
    pub fn positive_share(self) -> Option<f32> {
        match self {
            Self::Pixels => None,
            Self::Classes => Some(0.5),
            Self::PositiveShare(share) => Some(share),
        }
    }
}

impl std::str::FromStr for ClassBalance {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let share = |v: &str| -> Result<Self, String> {
            let share: f32 = v
                .parse()
                .map_err(|_| format!("positive-share={v}: not a number"))?;
            if share > 0.0 && share < 1.0 {
                Ok(Self::PositiveShare(share))
            } else {
                Err(format!("positive-share={v}: must be above 0 and below 1"))
            }
        };
        match s {
            "pixels" => Ok(Self::Pixels),
            "classes" => Ok(Self::Classes),
            other => match other.strip_prefix("positive-share=") {
                Some(v) => share(v),
                None => Err(format!(
                    "unknown class balance '{other}': pixels, classes or positive-share=A (0 < A < 1)"
                )),
            },
        }
    }
}

/// Loss over labelled pixels only: binary cross-entropy (from logits,
/// weighed by `balance`) plus soft Dice (on planes whose batch has positive
/// labels). `labels` holds 1 / 0 where `known` is 1; pixels with `known` 0
/// contribute nothing (neither value nor gradient). All `[b, a, h, w]`.
///
/// Each affordance plane gets its own BCE and its own Dice, and the loss is
/// their mean over the planes that have labels: every affordance is learnt
/// as if it were the network's only one (the paper trained one network per
/// affordance), so one with few labels (successful pick-ups are rare) is
/// not drowned by another's.
pub fn masked_bce_dice(
    logits: Tensor<4>,
    labels: Tensor<4>,
    known: Tensor<4>,
    balance: ClassBalance,
) -> Tensor<1> {
    let per_plane = |t: Tensor<4>| t.sum_dim(0).sum_dim(2).sum_dim(3).flatten::<1>(0, 3);
    let labelled = per_plane(known.clone());
    // softplus(x) - y x, written stably as max(x, 0) - y x + ln(1 + e^{-|x|}).
    let bce = logits.clone().clamp_min(0.0) - logits.clone() * labels.clone()
        + (logits.clone().abs().neg().exp() + 1.0).log();
    let bce = match balance {
        ClassBalance::Pixels => per_plane(bce * known.clone()) / labelled.clone().clamp_min(1.0),
        ClassBalance::Classes | ClassBalance::PositiveShare(_) => {
            let share = balance.positive_share().unwrap_or(0.5);
            let positive = labels.clone() * known.clone();
            let negative = known.clone() - positive.clone();
            let (n_pos, n_neg) = (per_plane(positive.clone()), per_plane(negative.clone()));
            let mean_pos = per_plane(bce.clone() * positive) / n_pos.clone().clamp_min(1.0);
            let mean_neg = per_plane(bce * negative) / n_neg.clone().clamp_min(1.0);
            // `share` and the rest where the plane has both classes; else
            // the one it has, whole.
            let has_pos = n_pos.greater_elem(0.0).float();
            let has_neg = n_neg.greater_elem(0.0).float();
            let both = has_pos.clone() * has_neg.clone();
            let w_pos = has_pos.clone() - both.clone() * (1.0 - share);
            let w_neg = has_neg.clone() - both * share;
            mean_pos * w_pos + mean_neg * w_neg
        }
    };
    let p = burn::tensor::activation::sigmoid(logits) * known.clone();
    let y = labels * known;
    let intersection = per_plane(p.clone() * y.clone());
    let positives = per_plane(y.clone());
    let dice = (intersection * 2.0 + 1.0) / (per_plane(p) + positives.clone() + 1.0);
    // Dice only where the batch has positives: on a plane with negatives
    // alone its loss is about the *sum* of the predicted probabilities, a
    // push to zero thousands of times stronger than the BCE's mean, which
    // for a rare affordance (most batches hold no successful pick-up)
    // drives every probability to ~0.001 however well the network ranks.
    let dice_loss = (dice.neg() + 1.0) * positives.greater_elem(0.0).float();
    // A plane without labels has BCE 0 and no Dice: it adds nothing.
    let planes = labelled.greater_elem(0.0).float().sum().clamp_min(1.0);
    (bce + dice_loss).sum() / planes
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::module::Module;
    use burn::tensor::Distribution;

    #[test]
    fn shapes_and_parameter_count() {
        let device = Device::flex();
        let net = AffordanceUnet::new(4, 2, &device);
        let out = net.forward(Tensor::zeros([2, 4, 128, 128], &device));
        assert_eq!(out.dims(), [2, 2, 128, 128]);
        let params = net.num_params();
        assert!((880_000..960_000).contains(&params), "{params} parameters");
    }

    /// A normalised network after three training passes (running
    /// statistics moved from their start) with random γ and β.
    fn normalised_net_in_use(device: &Device) -> AffordanceUnet {
        let tracked = device.clone().autodiff();
        let net = AffordanceUnet::new(4, 2, &tracked).with_batch_norm();
        assert!(net.has_batch_norm());
        for shift in [0.0, 0.3, -0.2] {
            let x = Tensor::<4>::random([3, 4, 16, 16], Distribution::Default, &tracked)
                .add_scalar(shift);
            let _ = net.forward(x);
        }
        let mut net = net.valid().to_device(device);
        let random = |n: usize, mean: f64| {
            Param::from_tensor(Tensor::<1>::random(
                [n],
                Distribution::Normal(mean, 0.3),
                device,
            ))
        };
        for conv in net
            .down
            .iter_mut()
            .chain(net.up.iter_mut().map(|l| &mut l.conv))
        {
            for norm in [&mut conv.first_norm, &mut conv.second_norm] {
                let norm = norm.as_mut().expect("normalised");
                let [n] = norm.gamma.dims();
                norm.gamma = random(n, 1.0);
                norm.beta = random(n, 0.0);
            }
        }
        net
    }

    #[test]
    fn a_normalised_network_folds_into_plain_convolutions_computing_the_same() {
        let device = Device::flex();
        let net = normalised_net_in_use(&device);
        // The running statistics moved, so a fold that ignored them differs.
        let norm = net.down[0].first_norm.as_ref().expect("normalised");
        let mean: Vec<f32> = norm
            .running_mean
            .value()
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        assert!(mean.iter().any(|m| m.abs() > 1e-3), "{mean:?}");
        let x = Tensor::<4>::random([2, 4, 16, 16], Distribution::Default, &device);
        let folded = net.folded();
        assert!(!folded.has_batch_norm());
        let expected = net.forward(x.clone());
        crate::test_support::assert_close(folded.forward(x.clone()), expected.clone(), "folded");
        // The inference path folds on its own, and the folded weights load
        // into a plain network (the actors').
        let images: Vec<f32> = x.into_data().try_to_vec::<f32>().unwrap();
        let [c, h, w] = [4, 16, 16];
        let inference = crate::unet_inference::UnetInference::new(net, &device);
        let logits = inference.logits(&[&images[..c * h * w], &images[c * h * w..]], h, w);
        let logits = Tensor::<1>::from_floats(logits.concat().as_slice(), &device);
        crate::test_support::assert_close(logits, expected.flatten(0, 3), "inference path");
        let mut plain = AffordanceUnet::new(4, 2, &device);
        crate::weights::load_safetensors(
            &mut plain,
            crate::weights::to_safetensors(&folded).unwrap(),
        )
        .expect("the folded weights fit a plain network");
    }

    #[test]
    fn a_normalised_network_keeps_its_running_statistics_through_its_weights() {
        let device = Device::flex();
        let net = normalised_net_in_use(&device);
        let bytes = crate::weights::to_safetensors(&net).unwrap();
        let mut plain = AffordanceUnet::new(4, 2, &device);
        assert!(crate::weights::load_safetensors(&mut plain, bytes.clone()).is_err());
        let mut loaded = AffordanceUnet::new(4, 2, &device).with_batch_norm();
        crate::weights::load_safetensors(&mut loaded, bytes).unwrap();
        let x = Tensor::<4>::random([1, 4, 16, 16], Distribution::Default, &device);
        crate::test_support::assert_close(loaded.forward(x.clone()), net.forward(x), "reloaded");
    }

    #[test]
    fn a_plane_with_negatives_only_costs_its_mean_bce_and_no_dice() {
        let device = Device::flex();
        let shape = [2, 2, 16, 16];
        // Plane 0: all negative; plane 1: half positive. Logits 0 (p = ½).
        let logits = Tensor::<4>::zeros(shape, &device);
        let mut labels = vec![0.0f32; 2 * 2 * 16 * 16];
        for b in 0..2 {
            let plane1 = &mut labels[(b * 2 + 1) * 256..][..256];
            plane1[..128].fill(1.0);
        }
        let labels = Tensor::<4>::from_data(burn::tensor::TensorData::new(labels, shape), &device);
        let known = Tensor::<4>::ones(shape, &device);
        let loss =
            masked_bce_dice(logits, labels, known, ClassBalance::Pixels).into_scalar::<f32>();
        let ln2 = std::f32::consts::LN_2;
        // Plane 1's Dice: (2·128 + 1) / (256 + 256 + 1) with p = ½ over 512 pixels.
        let dice1 = 1.0 - (2.0 * 128.0 + 1.0) / (256.0 + 256.0 + 1.0);
        let expected = (ln2 + (ln2 + dice1)) / 2.0;
        assert!((loss - expected).abs() < 1e-4, "{loss} vs {expected}");
    }

    #[test]
    fn balanced_classes_weigh_a_rare_positive_as_much_as_all_negatives() {
        let device = Device::flex();
        let shape = [1, 1, 1, 100];
        // One positive and 99 negatives; the positive's logit is -2 (missed),
        // the negatives' -4 (right).
        let mut logits = vec![-4.0f32; 100];
        logits[0] = -2.0;
        let mut labels = vec![0.0f32; 100];
        labels[0] = 1.0;
        let tensor =
            |v: Vec<f32>| Tensor::<4>::from_data(burn::tensor::TensorData::new(v, shape), &device);
        let known = Tensor::<4>::ones(shape, &device);
        let softplus = |x: f32| x.max(0.0) + (-x.abs()).exp().ln_1p();
        let (bce_pos, bce_neg) = (softplus(2.0), softplus(-4.0));
        let p = [1.0 / (1.0 + 2f32.exp()), 1.0 / (1.0 + 4f32.exp())];
        let dice = 1.0 - (2.0 * p[0] + 1.0) / (p[0] + 99.0 * p[1] + 1.0 + 1.0);
        let pixels = masked_bce_dice(
            tensor(logits.clone()),
            tensor(labels.clone()),
            known.clone(),
            ClassBalance::Pixels,
        )
        .into_scalar::<f32>();
        let expected = (bce_pos + 99.0 * bce_neg) / 100.0 + dice;
        assert!((pixels - expected).abs() < 1e-4, "{pixels} vs {expected}");
        let classes = masked_bce_dice(
            tensor(logits.clone()),
            tensor(labels.clone()),
            known.clone(),
            ClassBalance::Classes,
        )
        .into_scalar::<f32>();
        let expected = (bce_pos + bce_neg) / 2.0 + dice;
        assert!((classes - expected).abs() < 1e-4, "{classes} vs {expected}");
        // A quarter for the positives, three quarters for the negatives.
        let quarter = masked_bce_dice(
            tensor(logits),
            tensor(labels),
            known,
            ClassBalance::PositiveShare(0.25),
        )
        .into_scalar::<f32>();
        let expected = 0.25 * bce_pos + 0.75 * bce_neg + dice;
        assert!((quarter - expected).abs() < 1e-4, "{quarter} vs {expected}");
        // Negatives only: both are the negatives' mean.
        let negatives = masked_bce_dice(
            tensor(vec![-4.0; 100]),
            tensor(vec![0.0; 100]),
            Tensor::<4>::ones(shape, &device),
            ClassBalance::Classes,
        )
        .into_scalar::<f32>();
        assert!((negatives - bce_neg).abs() < 1e-5, "{negatives}");
    }

    #[test]
    fn a_class_balance_reads_from_its_name() {
        assert_eq!("pixels".parse(), Ok(ClassBalance::Pixels));
        assert_eq!("classes".parse(), Ok(ClassBalance::Classes));
        assert_eq!(
            "positive-share=0.25".parse(),
            Ok(ClassBalance::PositiveShare(0.25))
        );
        for bad in [
            "positive-share=1",
            "positive-share=0",
            "positive-share=x",
            "share",
        ] {
            assert!(bad.parse::<ClassBalance>().is_err(), "{bad}");
        }
        assert_eq!(ClassBalance::Classes.positive_share(), Some(0.5));
        assert_eq!(ClassBalance::Pixels.positive_share(), None);
    }
}
