//! The U-Net ready for inference on its device: the one place that decides
//! how a forward pass without gradients runs.
//!
//! On the CPU that is [`CpuUnet`] (less than half the time of burn's CPU backend, same
//! results); elsewhere it is burn, with several images in one pass (batches
//! are what keep a GPU busy).

use burn::prelude::*;

use crate::unet::AffordanceUnet;
use crate::unet_cpu::CpuUnet;

/// A U-Net for inference.
#[derive(Debug)]
pub enum UnetInference {
    /// The CPU path, one image at a time.
    Cpu(CpuUnet),
    /// burn on `device`, one batch per call.
    Burn {
        /// The network.
        net: Box<AffordanceUnet>,
        /// Where it runs.
        device: Device,
    },
}

impl UnetInference {
    /// `net` prepared for `device`: the CPU path when `device` is the CPU.
    pub fn new(net: AffordanceUnet, device: &Device) -> Self {
        if crate::device::is_cpu(device) {
            Self::Cpu(CpuUnet::from_network(&net))
        } else {
            Self::Burn {
                net: Box::new(net),
                device: device.clone(),
            }
        }
    }

    /// Logits `[outputs, height, width]` per image; every image is
    /// `[input channels, height, width]`, channels-first, all of one size.
    ///
    /// # Panics
    /// If an image's length does not fit the size, or the sides are not
    /// multiples of 8 (the caller's frame size comes from a validated task).
    pub fn logits(&self, images: &[&[f32]], height: usize, width: usize) -> Vec<Vec<f32>> {
        match self {
            Self::Cpu(net) => images
                .iter()
                .map(|image| net.forward(image, height, width))
                .collect(),
            Self::Burn { net, device } => {
                if images.is_empty() {
                    return Vec::new();
                }
                let input: Vec<f32> = images.iter().flat_map(|i| i.iter().copied()).collect();
                let channels = input.len() / (images.len() * height * width);
                let x = Tensor::<1>::from_floats(input.as_slice(), device).reshape([
                    images.len(),
                    channels,
                    height,
                    width,
                ]);
                let logits: Vec<f32> = net
                    .forward(x)
                    .into_data()
                    .try_to_vec()
                    .expect("the U-Net returns f32 logits");
                logits
                    .chunks(logits.len() / images.len())
                    .map(<[f32]>::to_vec)
                    .collect()
            }
        }
    }
}
