//! Network definitions shared by the actor (inference) and the learner (training).
//!
//! One crate, so the two processes can never disagree about a layer. Weights
//! travel as safetensors with PyTorch-style names (`actor.fc1.weight`, bundled under `policy.` / `unet.`).
//! This crate holds no training loop and knows nothing of transport or simulation.
//!
//! - [`policy`]: the exploration policy (conv encoders, MLPs, optional GRU,
//!   actor and critic heads with masked logits), on burn;
//! - [`unet`]: the affordance U-Net and its labelled-pixels-only loss;
//! - `layers`: one description of each network's layers (sizes, kernels,
//!   strides, activations) that both implementations read;
//! - `kernels`: the CPU convolution kernels (Winograd, nine taps, GEMM) the
//!   two CPU paths below share;
//! - [`unet_cpu`]: the same U-Net's forward pass for CPU inference, without
//!   burn's copies, with Winograd convolutions (the actor's per-frame pass);
//! - `unet_conv_cpu`: the U-Net's 3 × 3 convolutions with their ReLU as
//!   one differentiable operation on the CPU (its training step);
//! - `unet_torch` (`gpu-torch`): the U-Net's inference pass straight on
//!   libtorch (which `training::unet_train_torch` trains through);
//! - [`unet_inference`]: which of these a device gets;
//! - [`weights`]: either network to and from safetensors bytes;
//! - [`device`]: `--device cpu|gpu` at run time;
//! - [`heap`]: the C allocator kept from returning each step's memory;
//! - [`sample`]: the masked categorical draw the actor acts with;

mod conv_matmul;
#[cfg(feature = "gpu-torch")]
pub mod cuda_wait;
pub mod device;
pub mod heap;
mod kernels;
mod layers;
mod masked_categorical;
pub mod policy;
pub mod unet;
mod unet_conv_cpu;
pub mod unet_cpu;
pub mod unet_inference;
#[cfg(feature = "gpu-torch")]
pub mod unet_torch;
pub mod weights;

pub use masked_categorical::sample;

/// What the crate's tests share.
#[cfg(test)]
mod test_support {
    use burn::nn::conv::Conv2d;
    use burn::prelude::*;

    /// The largest absolute difference between two equally long runs of values.
    pub(crate) fn largest_difference(a: &[f32], b: &[f32]) -> f32 {
        assert_eq!(a.len(), b.len());
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f32::max)
    }

    /// Asserts that two computations of the same convolution layers (each
    /// with its ReLU, or the last without) from the same input agree: their
    /// outputs `ours` and `burns`, and, from losses weighing the outputs by
    /// `weights`, the gradients of their inputs `x_ours` and `x_burn` and of
    /// each of `layers`' weights and bias. Some outputs must be at or below
    /// zero (cut by a ReLU, negative without one), or the activation would
    /// go untested.
    pub(crate) fn assert_same_values_and_gradients(
        (ours, x_ours): (Tensor<4>, &Tensor<4>),
        (burns, x_burn): (Tensor<4>, &Tensor<4>),
        weights: Tensor<4>,
        layers: &[(&str, &Conv2d)],
        what: &str,
    ) {
        let ours_grads = (ours.clone() * weights.clone()).sum().backward();
        let burn_grads = (burns.clone() * weights).sum().backward();
        let cut = burns
            .clone()
            .lower_equal_elem(0.0)
            .int()
            .sum()
            .into_scalar::<i64>();
        assert!(cut > 0, "{what}: some outputs must be at or below zero");
        assert_close(ours, burns, &format!("outputs, {what}"));
        assert_close(
            x_ours.grad(&ours_grads).expect("gradient"),
            x_burn.grad(&burn_grads).expect("gradient"),
            &format!("input gradients, {what}"),
        );
        for (name, layer) in layers {
            assert_close(
                layer.weight.grad(&ours_grads).expect("gradient"),
                layer.weight.grad(&burn_grads).expect("gradient"),
                &format!("{name} layer's weight gradients, {what}"),
            );
            let bias = layer.bias.as_ref().expect("bias");
            assert_close(
                bias.grad(&ours_grads).expect("gradient"),
                bias.grad(&burn_grads).expect("gradient"),
                &format!("{name} layer's bias gradients, {what}"),
            );
        }
    }

    /// Asserts that `ours` is within 1e-5 of `burns`' largest value.
    pub(crate) fn assert_close<const D: usize>(ours: Tensor<D>, burns: Tensor<D>, what: &str) {
        let scale = burns.clone().abs().max().into_scalar::<f32>();
        let difference = (ours - burns).abs().max().into_scalar::<f32>();
        assert!(
            difference <= 1e-5 * scale,
            "{what} differ: {difference} of {scale}"
        );
    }
}
