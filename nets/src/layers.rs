//! One description of each network's layers: sizes, kernels, strides and
//! activations, read by both implementations of each network (burn's
//! modules in `policy` and `unet`, which train; the CPU passes in
//! `policy::cpu` and `unet_cpu`, which act). The CPU passes take every shape
//! from the burn layers whose weights they copy and every activation from
//! here, so a layer is changed once, in this file, and the tests that hold
//! the two passes equal catch any drift.

use burn::prelude::*;

/// A nonlinearity between layers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Activation {
    /// `max(x, 0)`.
    Relu,
    /// `tanh(x)`.
    Tanh,
}

impl Activation {
    /// On a tensor (burn's path).
    pub(crate) fn tensor<const D: usize>(self, x: Tensor<D>) -> Tensor<D> {
        match self {
            Activation::Relu => burn::tensor::activation::relu(x),
            Activation::Tanh => burn::tensor::activation::tanh(x),
        }
    }

    /// On one value (the CPU paths).
    pub(crate) fn value(self, x: f32) -> f32 {
        match self {
            Activation::Relu => x.max(0.0),
            Activation::Tanh => x.tanh(),
        }
    }
}

/// A valid (unpadded), square, strided convolution.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct StridedConv {
    /// Output channels.
    pub(crate) outputs: usize,
    /// Kernel side.
    pub(crate) kernel: usize,
    /// Stride in both directions.
    pub(crate) stride: usize,
}

impl StridedConv {
    /// Side of the output for an input `size` pixels across.
    pub(crate) fn output_side(self, size: usize) -> usize {
        (size - self.kernel) / self.stride + 1
    }
}

/// The policy's image encoder: 8 × 8 / 4, 4 × 4 / 2, 3 × 3 / 2
/// convolutions (Nature-DQN-like, as IntExp), then a dense layer to
/// [`ENCODER_FEATURES`].
pub(crate) const ENCODER_CONVS: [StridedConv; 3] = [
    StridedConv {
        outputs: 16,
        kernel: 8,
        stride: 4,
    },
    StridedConv {
        outputs: 32,
        kernel: 4,
        stride: 2,
    },
    StridedConv {
        outputs: 32,
        kernel: 3,
        stride: 2,
    },
];

/// Features out of each of the policy's encoders (image and vector).
pub(crate) const ENCODER_FEATURES: usize = 64;

/// After every layer of the policy's encoders.
pub(crate) const ENCODER_ACTIVATION: Activation = Activation::Relu;

/// Hidden widths of the actor's and the critic's heads.
pub(crate) const HEAD_WIDTHS: [usize; 2] = [64, 32];

/// Between the layers of the heads (none after the last).
pub(crate) const HEAD_ACTIVATION: Activation = Activation::Tanh;

/// The U-Net's encoder channels per level, shallow to deep (the paper's):
/// two 3 × 3 same-padded convolutions with ReLU per level, 2 × 2 max
/// pooling down, 2 × 2 stride-2 transposed convolutions up.
pub const UNET_CHANNELS: [usize; 4] = [24, 48, 92, 164];
