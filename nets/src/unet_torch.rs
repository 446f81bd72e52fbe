//! The U-Net's forward pass for inference straight on libtorch, without
//! burn between the layers: its weights copied once into libtorch tensors,
//! each image copied from the caller's buffer to the device and each
//! image's logits from the device into the buffer returned, with no copy
//! in between.
//!
//! Why it exists: an actor on a GPU sends every camera frame through the
//! U-Net, in batches of one thread (`actor::sampling::unet_batcher`), which
//! bounds the process's steps per second. On an H200 at 128 px a call
//! through libtorch's own calls is faster than burn's at every batch size
//! (`cargo bench -p nets --bench unet_inference`; docs/performance.md,
//! "One actor"); half precision
//! with channels-last tensors was tried and made actors slower
//! (docs/notebook/2026-11-27-actor-unet-on-libtorch.md).

// burn 0.22 marks libtorch deprecated; chosen all the same
// (docs/decisions/0010-libtorch-on-a-gpu.md).
#![allow(deprecated)]

use std::borrow::Borrow;

use burn::backend::libtorch::TchTensor;
use burn::backend::LibTorch;
use burn::prelude::*;
use tch::Kind;

/// The U-Net's layers on libtorch.
#[derive(Debug)]
pub struct TorchUnet {
    /// Each layer's weight and bias in [`forward`]'s order, in burn's
    /// wrapper, which lets threads share them (actors' environments share
    /// one U-Net; a pass only reads its weights).
    layers: Vec<TchTensor>,
    device: tch::Device,
}

impl TorchUnet {
    /// The U-Net whose layers' weights and biases are `layers` (in
    /// `AffordanceUnet::layers`' order), copied into libtorch tensors on the
    /// device they live on; `None` when they are not on libtorch.
    pub fn from_layers(layers: Vec<(Tensor<4>, Option<Tensor<1>>)>) -> Option<Self> {
        let mut copies = Vec::with_capacity(LAYER_TENSORS);
        for (weight, bias) in layers {
            copies.extend([torch_copy(weight)?, torch_copy(bias?)?]);
        }
        let device = copies.first()?.tensor.device();
        (copies.len() == LAYER_TENSORS).then_some(Self {
            layers: copies,
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
            let layers: Vec<&tch::Tensor> = self.layers.iter().map(|t| &t.tensor).collect();
            let logits = forward(&layers, &x).contiguous();
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
}

/// How many tensors [`forward`] takes for the U-Net's layers: a weight and
/// a bias for each of its 8 encoder and 6 decoder 3 × 3 convolutions, 3
/// transposed convolutions and the 1 × 1 head.
pub const LAYER_TENSORS: usize = 2 * (8 + 6 + 3 + 1);

/// The U-Net's forward pass on libtorch, `[n, channels, h, w]` → logits
/// `[n, outputs, h, w]`, from its layers' weights and biases in
/// `AffordanceUnet::layers`' order, each weight followed by its bias.
///
/// # Panics
/// If `layers` is not [`LAYER_TENSORS`] long.
pub fn forward<T: Borrow<tch::Tensor>>(layers: &[T], x: &tch::Tensor) -> tch::Tensor {
    assert_eq!(layers.len(), LAYER_TENSORS, "the U-Net's layer tensors");
    let mut next = 0;
    let mut layer = || {
        next += 2;
        (layers[next - 2].borrow(), layers[next - 1].borrow())
    };
    let conv_relu = |x: &tch::Tensor, (weight, bias): (&tch::Tensor, &tch::Tensor)| {
        x.conv2d(weight, Some(bias), [1, 1], [1, 1], [1, 1], 1)
            .relu()
    };
    let mut skips = Vec::with_capacity(3);
    let mut x = x.shallow_clone();
    for level in 0..4 {
        if level > 0 {
            let pooled = x.max_pool2d([2, 2], [2, 2], [0, 0], [1, 1], false);
            skips.push(std::mem::replace(&mut x, pooled));
        }
        for _ in 0..2 {
            x = conv_relu(&x, layer());
        }
    }
    while let Some(skip) = skips.pop() {
        let (weight, bias) = layer();
        let upsampled = x.conv_transpose2d(weight, Some(bias), [2, 2], [0, 0], [0, 0], 1, [1, 1]);
        x = tch::Tensor::cat(&[upsampled, skip], 1);
        for _ in 0..2 {
            x = conv_relu(&x, layer());
        }
    }
    let (weight, bias) = layer();
    x.conv2d(weight, Some(bias), [1, 1], [0, 0], [1, 1], 1)
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
    use crate::test_support::largest_difference;
    use crate::unet::AffordanceUnet;
    use burn::tensor::Distribution;

    /// The libtorch pass against burn's on libtorch's CPU device: each
    /// image of a batch gets the logits burn's batch gives it, for several
    /// batch sizes and image sizes.
    #[test]
    fn each_image_gets_burns_logits() {
        let device = Device::libtorch();
        let net = AffordanceUnet::new(4, 2, &device);
        let ours = TorchUnet::from_layers(net.layers()).expect("on libtorch");
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
                let diff = largest_difference(got, expected);
                // The same libtorch kernels in the same order.
                assert!(diff <= 1e-6 * scale, "{n} × {h} × {w}, image {k}: {diff}");
            }
        }
    }

    #[test]
    fn a_network_off_libtorch_has_no_libtorch_pass() {
        let net = AffordanceUnet::new(4, 2, &Device::flex());
        assert!(TorchUnet::from_layers(net.layers()).is_none());
    }
}
