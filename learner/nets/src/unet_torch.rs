//! The U-Net's forward pass for inference straight on libtorch, without
//! burn between the layers: its weights copied once into libtorch tensors,
//! each image copied from the caller's buffer to the device and each
//! image's logits from the device into the buffer returned, with no copy
//! in between.
//!
//! Why it exists: an actor on a GPU sends every camera frame through the
//! U-Net, in batches of one thread (`actor::env::unet_batcher`), which
//! bounds the process's steps per second. On an H200 at 128 px a call
//! through libtorch's own calls took 0.98 / 1.71 / 2.95 ms for 1 / 4 / 8
//! frames against burn's 1.28 / 2.05 / 4.75 ms (`cargo bench -p nets
//! --bench unet_inference`, before the copies were cut); half precision
//! with channels-last tensors was tried and made actors slower
//! (docs/notebook/2026-11-27-actor-unet-on-libtorch.md).

// burn 0.22 marks libtorch deprecated; chosen all the same
// (docs/decisions/0010-libtorch-on-a-gpu.md).
#![allow(deprecated)]

use burn::backend::libtorch::TchTensor;
use burn::backend::LibTorch;
use burn::nn::conv::{Conv2d, ConvTranspose2d};
use burn::prelude::*;
use tch::Kind;

use crate::unet::{AffordanceUnet, DoubleConv};

/// A convolution's weight and bias as libtorch tensors, in burn's wrapper,
/// which lets threads share them (actors' environments share one U-Net; a
/// pass only reads its weights).
#[derive(Debug)]
struct Layer {
    weight: TchTensor,
    bias: Option<TchTensor>,
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
}

impl TorchUnet {
    /// `net`'s weights copied into libtorch tensors on the device they live
    /// on; `None` when `net` is not on libtorch.
    pub fn from_network(net: &AffordanceUnet) -> Option<Self> {
        let head = Layer::from_conv(&net.head)?;
        let device = head.weight().device();
        let down = net.down.iter().map(Layer::double).collect::<Option<_>>()?;
        let up = net
            .up
            .iter()
            .map(|level| {
                Some((
                    Layer::from_transposed(&level.up)?,
                    Layer::double(&level.conv)?,
                ))
            })
            .collect::<Option<_>>()?;
        Some(Self {
            down,
            up,
            head,
            device,
        })
    }

    /// Logits `[outputs, height, width]` per image; every image is
    /// `[channels, height, width]`, channels-first, all of one size.
    ///
    /// # Panics
    /// If the images differ in length or do not fit the size (the caller's
    /// frames come from a validated task).
    pub fn logits(&self, images: &[&[f32]], height: usize, width: usize) -> Vec<Vec<f32>> {
        let Some(first) = images.first() else {
            return Vec::new();
        };
        let channels = first.len() / (height * width);
        assert!(
            channels > 0 && images.iter().all(|i| i.len() == channels * height * width),
            "U-Net images of {channels} × {height} × {width} floats"
        );
        let image_dims = [channels, height, width].map(|d| d as i64);
        tch::no_grad(|| {
            let x = tch::Tensor::empty(
                [
                    images.len() as i64,
                    image_dims[0],
                    image_dims[1],
                    image_dims[2],
                ],
                (Kind::Float, self.device),
            );
            for (k, image) in images.iter().enumerate() {
                // SAFETY: `host` views `image`'s floats, which outlive it, in
                // their own layout; nothing writes through it, and a blocking
                // copy from the host has read it whole when `copy_` returns.
                let host = unsafe {
                    tch::Tensor::from_blob(
                        image.as_ptr().cast(),
                        &image_dims,
                        &[],
                        Kind::Float,
                        tch::Device::Cpu,
                    )
                };
                x.get(k as i64).copy_(&host);
            }
            let logits = self.forward(&x).contiguous();
            let per_image = logits.numel() / images.len();
            (0..images.len())
                .map(|k| {
                    let mut out = vec![0f32; per_image];
                    // SAFETY: `host` views `out`, which outlives it, as
                    // `per_image` floats; a blocking copy to the host has
                    // written them all when `copy_` returns.
                    let mut host = unsafe {
                        tch::Tensor::from_blob(
                            out.as_mut_ptr().cast::<u8>(),
                            &[per_image as i64],
                            &[],
                            Kind::Float,
                            tch::Device::Cpu,
                        )
                    };
                    host.copy_(&logits.get(k as i64).view([-1]));
                    out
                })
                .collect()
        })
    }

    /// `[n, channels, h, w]` → logits `[n, outputs, h, w]` on the device.
    fn forward(&self, x: &tch::Tensor) -> tch::Tensor {
        let mut skips = Vec::with_capacity(self.down.len());
        let mut x = double_conv(&self.down[0], x);
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
        x.conv2d(
            self.head.weight(),
            self.head.bias(),
            [1, 1],
            [0, 0],
            [1, 1],
            1,
        )
    }
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
    fn weight(&self) -> &tch::Tensor {
        &self.weight.tensor
    }

    fn bias(&self) -> Option<&tch::Tensor> {
        self.bias.as_ref().map(|b| &b.tensor)
    }

    fn double(level: &DoubleConv) -> Option<[Self; 2]> {
        Some([
            Self::from_conv(&level.first)?,
            Self::from_conv(&level.second)?,
        ])
    }

    fn from_conv(layer: &Conv2d) -> Option<Self> {
        Self::from_params(layer.weight.val(), layer.bias.as_ref().map(|b| b.val()))
    }

    fn from_transposed(layer: &ConvTranspose2d) -> Option<Self> {
        Self::from_params(layer.weight.val(), layer.bias.as_ref().map(|b| b.val()))
    }

    fn from_params(weight: Tensor<4>, bias: Option<Tensor<1>>) -> Option<Self> {
        let weight = torch_copy(weight)?;
        let bias = match bias {
            Some(bias) => Some(torch_copy(bias)?),
            None => None,
        };
        Some(Self { weight, bias })
    }
}

/// A libtorch copy of `tensor`, detached from burn's; `None` when `tensor`
/// is not on libtorch.
fn torch_copy<const D: usize>(tensor: Tensor<D>) -> Option<TchTensor> {
    let primitive = tensor.try_into_primitive::<LibTorch>().ok()?;
    Some(TchTensor::new(tch::no_grad(|| primitive.tensor.copy())))
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::Distribution;

    /// The libtorch pass against burn's on libtorch's CPU device: each
    /// image of a batch gets the logits burn's batch gives it, for several
    /// batch sizes and image sizes.
    #[test]
    fn each_image_gets_burns_logits() {
        let device = Device::libtorch();
        let net = AffordanceUnet::new(4, 2, &device);
        let ours = TorchUnet::from_network(&net).expect("on libtorch");
        for (n, h, w) in [(1, 16, 16), (3, 32, 24)] {
            let x = Tensor::<4>::random([n, 4, h, w], Distribution::Uniform(0.0, 3.0), &device);
            let input: Vec<f32> = x.clone().into_data().try_to_vec().unwrap();
            let expected: Vec<f32> = net.forward(x).into_data().try_to_vec().unwrap();
            let images: Vec<&[f32]> = input.chunks(input.len() / n).collect();
            let got = ours.logits(&images, h, w);
            assert_eq!(got.len(), n);
            let scale = expected.iter().fold(0.0f32, |m, v| m.max(v.abs()));
            assert!(scale > 0.01, "a fresh network gives logits up to {scale}");
            for (k, (got, expected)) in got.iter().zip(expected.chunks(2 * h * w)).enumerate() {
                assert_eq!(got.len(), expected.len());
                let diff = got
                    .iter()
                    .zip(expected)
                    .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
                // The same libtorch kernels in the same order.
                assert!(diff <= 1e-6 * scale, "{n} × {h} × {w}, image {k}: {diff}");
            }
        }
    }

    #[test]
    fn a_network_off_libtorch_has_no_libtorch_pass() {
        let net = AffordanceUnet::new(4, 2, &Device::flex());
        assert!(TorchUnet::from_network(&net).is_none());
    }
}
