//! The U-Net's forward pass for inference straight on libtorch, without
//! burn between the layers: its weights copied once into libtorch tensors
//! of the precision and memory layout chosen ([`TorchPrecision`]).
//!
//! Why it exists: an actor on a GPU sends every camera frame through the
//! U-Net, in batches of one thread (`actor::env::unet_batcher`); through
//! burn a 128-px batch cost about 1.0 ms + 0.85 ms a frame on an H200,
//! which capped a process near 1 100 frames a second
//! (docs/notebook/2026-11-27-gpu-check-free-running.md). Here the layers
//! are libtorch's own calls, and the pass can run in half precision with
//! channels-last tensors (cuDNN's tensor-core convolutions), which burn's
//! float type and layout rule out; which is faster is measured in
//! docs/notebook/2026-11-28-unet-inference-on-libtorch.md.

// burn 0.22 marks libtorch deprecated; chosen all the same
// (docs/decisions/0010-libtorch-on-a-gpu.md).
#![allow(deprecated)]

use burn::backend::libtorch::TchTensor;
use burn::backend::LibTorch;
use burn::nn::conv::{Conv2d, ConvTranspose2d};
use burn::prelude::*;
use tch::Kind;

use crate::unet::{AffordanceUnet, DoubleConv};

/// The number type and memory layout of a libtorch pass.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TorchPrecision {
    /// 32-bit floats, channels-first: the numbers burn's pass gives.
    Full,
    /// 16-bit floats, channels-last (inputs and outputs stay 32-bit):
    /// tensor-core convolutions on CUDA; logits differ from the full
    /// pass's by about 1e-3 of their scale.
    Half,
}

impl TorchPrecision {
    fn kind(self) -> Kind {
        match self {
            Self::Full => Kind::Float,
            Self::Half => Kind::Half,
        }
    }
}

/// A convolution's weight and bias as libtorch tensors, in burn's wrapper,
/// which lets threads share them (actors' environments share one U-Net; a
/// pass only reads its weights).
#[derive(Debug)]
struct Layer {
    weight: TchTensor,
    bias: Option<TchTensor>,
}

impl Layer {
    fn weight(&self) -> &tch::Tensor {
        &self.weight.tensor
    }

    fn bias(&self) -> Option<&tch::Tensor> {
        self.bias.as_ref().map(|b| &b.tensor)
    }
}

/// The U-Net's layers on libtorch.
#[derive(Debug)]
pub struct TorchUnet {
    /// Encoder levels, shallow to deep: two 3 × 3 convolutions each.
    down: Vec<[Layer; 2]>,
    /// Decoder levels, deep to shallow: the transposed convolution up, then
    /// two 3 × 3 convolutions.
    up: Vec<(Layer, [Layer; 2])>,
    /// The 1 × 1 output convolution.
    head: Layer,
    device: tch::Device,
    precision: TorchPrecision,
}

impl TorchUnet {
    /// `net`'s weights copied into libtorch tensors of `precision`, on the
    /// device they live on; `None` when `net` is not on libtorch.
    pub fn from_network(net: &AffordanceUnet, precision: TorchPrecision) -> Option<Self> {
        let head = Layer::from_conv(&net.head, precision)?;
        let device = head.weight().device();
        let down = net
            .down
            .iter()
            .map(|level| Layer::double(level, precision))
            .collect::<Option<_>>()?;
        let up = net
            .up
            .iter()
            .map(|level| {
                Some((
                    Layer::from_transposed(&level.up, precision)?,
                    Layer::double(&level.conv, precision)?,
                ))
            })
            .collect::<Option<_>>()?;
        Some(Self {
            down,
            up,
            head,
            device,
            precision,
        })
    }

    /// Logits `[images, outputs, height, width]`, 32-bit and channels-first,
    /// for `input` holding `images` images `[channels, height, width]` one
    /// after another.
    pub fn logits(&self, input: &[f32], images: usize, height: usize, width: usize) -> Vec<f32> {
        let channels = input.len() / (images * height * width);
        let dims = [images, channels, height, width].map(|d| d as i64);
        tch::no_grad(|| {
            let x = tch::Tensor::from_slice(input)
                .view(dims)
                .to_device(self.device);
            let x = self.layout(x.to_kind(self.precision.kind()));
            let mut skips = Vec::with_capacity(self.down.len());
            let mut x = double_conv(&self.down[0], &x);
            for level in &self.down[1..] {
                let pooled = x.max_pool2d([2, 2], [2, 2], [0, 0], [1, 1], false);
                skips.push(x);
                x = double_conv(level, &pooled);
            }
            for (up, convs) in &self.up {
                let skip = skips.pop().expect("one skip per decoder level");
                let upsampled =
                    x.conv_transpose2d(up.weight(), up.bias(), [2, 2], [0, 0], [0, 0], 1, [1, 1]);
                x = double_conv(convs, &tch::Tensor::cat(&[upsampled, skip], 1));
            }
            let logits = x
                .conv2d(
                    self.head.weight(),
                    self.head.bias(),
                    [1, 1],
                    [0, 0],
                    [1, 1],
                    1,
                )
                .to_kind(Kind::Float)
                .contiguous()
                .to_device(tch::Device::Cpu);
            Vec::<f32>::try_from(logits.view([-1])).expect("32-bit logits")
        })
    }

    /// `x` in the pass's memory layout: channels-last for half precision
    /// (same shape, NHWC strides, which libtorch's convolutions keep).
    fn layout(&self, x: tch::Tensor) -> tch::Tensor {
        match self.precision {
            TorchPrecision::Full => x,
            TorchPrecision::Half => channels_last(&x),
        }
    }
}

/// `x` `[n, c, h, w]` with channels-last strides (PyTorch's
/// `memory_format=torch.channels_last`, which tch does not name).
fn channels_last(x: &tch::Tensor) -> tch::Tensor {
    x.permute([0, 2, 3, 1]).contiguous().permute([0, 3, 1, 2])
}

/// Two 3 × 3 same-padded convolutions, each with its ReLU.
fn double_conv(layers: &[Layer; 2], x: &tch::Tensor) -> tch::Tensor {
    let conv = |layer: &Layer, x: &tch::Tensor| {
        x.conv2d(layer.weight(), layer.bias(), [1, 1], [1, 1], [1, 1], 1)
            .relu()
    };
    conv(&layers[1], &conv(&layers[0], x))
}

impl Layer {
    fn double(level: &DoubleConv, precision: TorchPrecision) -> Option<[Self; 2]> {
        Some([
            Self::from_conv(&level.first, precision)?,
            Self::from_conv(&level.second, precision)?,
        ])
    }

    fn from_conv(layer: &Conv2d, precision: TorchPrecision) -> Option<Self> {
        Self::from_params(
            layer.weight.val(),
            layer.bias.as_ref().map(|b| b.val()),
            precision,
        )
    }

    fn from_transposed(layer: &ConvTranspose2d, precision: TorchPrecision) -> Option<Self> {
        Self::from_params(
            layer.weight.val(),
            layer.bias.as_ref().map(|b| b.val()),
            precision,
        )
    }

    /// Copies of `weight` and `bias` in `precision` (weights in its layout).
    fn from_params(
        weight: Tensor<4>,
        bias: Option<Tensor<1>>,
        precision: TorchPrecision,
    ) -> Option<Self> {
        let weight = torch_copy(weight, precision)?;
        let weight = match precision {
            TorchPrecision::Full => weight,
            TorchPrecision::Half => channels_last(&weight),
        };
        let bias = match bias {
            Some(bias) => Some(torch_copy(bias, precision)?),
            None => None,
        };
        Some(Self {
            weight: TchTensor::new(weight),
            bias: bias.map(TchTensor::new),
        })
    }
}

/// A libtorch copy of `tensor` in `precision`'s number type, detached from
/// burn's; `None` when `tensor` is not on libtorch.
fn torch_copy<const D: usize>(tensor: Tensor<D>, precision: TorchPrecision) -> Option<tch::Tensor> {
    let primitive = tensor.try_into_primitive::<LibTorch>().ok()?;
    Some(tch::no_grad(|| {
        primitive.tensor.to_kind(precision.kind()).copy()
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::Distribution;

    /// The libtorch pass against burn's on libtorch's CPU device: the same
    /// numbers in full precision, for several batch sizes and image sizes.
    #[test]
    fn full_precision_gives_burns_logits() {
        let device = Device::libtorch();
        let net = AffordanceUnet::new(4, 2, &device);
        let ours = TorchUnet::from_network(&net, TorchPrecision::Full).expect("on libtorch");
        for (images, h, w) in [(1, 16, 16), (3, 32, 24)] {
            let x =
                Tensor::<4>::random([images, 4, h, w], Distribution::Uniform(0.0, 3.0), &device);
            let input: Vec<f32> = x.clone().into_data().try_to_vec().unwrap();
            let expected: Vec<f32> = net.forward(x).into_data().try_to_vec().unwrap();
            let got = ours.logits(&input, images, h, w);
            assert_eq!(got.len(), expected.len());
            let scale = expected.iter().fold(0.0f32, |m, v| m.max(v.abs()));
            assert!(scale > 0.01, "a fresh network gives logits up to {scale}");
            let diff = got
                .iter()
                .zip(&expected)
                .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
            // The same libtorch kernels in the same order.
            assert!(
                diff <= 1e-6 * scale.max(1.0),
                "{images} × {h} × {w}: {diff}"
            );
        }
    }

    #[test]
    fn a_network_off_libtorch_has_no_libtorch_pass() {
        let net = AffordanceUnet::new(4, 2, &Device::flex());
        assert!(TorchUnet::from_network(&net, TorchPrecision::Full).is_none());
    }
}
