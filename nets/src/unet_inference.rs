//! The U-Net ready for inference on its device: the one place that decides
//! how a forward pass without gradients runs.
//!
//! On the CPU that is [`CpuUnet`] (less than half the time of burn's CPU backend, same
//! results); on libtorch (`gpu-torch`) it is libtorch's own calls
//! (`nets::unet_torch`) unless `AFX_UNET_INFERENCE=burn`; elsewhere it is
//! burn. Off the CPU several images go in one pass (batches are what keep a
//! GPU busy).

use burn::prelude::*;

use crate::unet::AffordanceUnet;
use crate::unet_cpu::CpuUnet;
#[cfg(feature = "gpu-torch")]
use crate::unet_torch::TorchUnet;

/// A U-Net for inference.
#[derive(Debug)]
pub enum UnetInference {
    /// The CPU path, one image at a time.
    Cpu(CpuUnet),
    /// libtorch's own calls, one batch per call.
    #[cfg(feature = "gpu-torch")]
    Torch(TorchUnet),
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
    /// A network with batch normalisations runs folded
    /// ([`AffordanceUnet::folded`]).
    pub fn new(net: AffordanceUnet, device: &Device) -> Self {
        let net = if net.has_batch_norm() {
            net.folded()
        } else {
            net
        };
        if crate::device::is_cpu(device) {
            return Self::Cpu(CpuUnet::from_network(&net));
        }
        #[cfg(feature = "gpu-torch")]
        if let Some(torch) = torch_path(&net) {
            return Self::Torch(torch);
        }
        Self::Burn {
            net: Box::new(net),
            device: device.clone(),
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
            #[cfg(feature = "gpu-torch")]
            Self::Torch(net) => net.logits(images, height, width),
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

/// libtorch's own pass of `net`, unless `AFX_UNET_INFERENCE=burn` asks for
/// burn's (for measuring against) or `net` is not on libtorch.
#[cfg(feature = "gpu-torch")]
fn torch_path(net: &AffordanceUnet) -> Option<TorchUnet> {
    match std::env::var("AFX_UNET_INFERENCE").as_deref() {
        Ok("burn") => return None,
        Err(_) | Ok("torch") => {}
        Ok(other) => {
            eprintln!("AFX_UNET_INFERENCE takes torch or burn, not {other:?}; using torch")
        }
    }
    TorchUnet::from_layers(net.layers())
}
