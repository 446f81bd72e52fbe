//! The U-Net's 3 × 3 convolutions with their ReLU as one differentiable
//! operation on libtorch, whose backward step is libtorch's own.
//!
//! Why it exists: burn's autodiff computes a convolution's gradients from
//! the backend's generic operations, the weight gradient as a convolution
//! of the input (batch and channels swapped) with the output gradient as a
//! dilated kernel. cuDNN runs that shape slowly: a U-Net training step
//! (batch 8, 128 px) took 40.0 ms on an H200 against PyTorch's 9.2 ms with
//! the same network (docs/notebook/2026-11-27-libtorch-learner.md). Here the
//! forward pass records libtorch's autograd graph of `relu(conv2d(x))` on
//! leaves of its own; the backward step asks libtorch for the gradients of
//! `sum(output · output gradient)` with respect to those leaves, which is
//! exactly the operation's vector-Jacobian product, computed by the kernels
//! PyTorch itself trains with (cuDNN's data and weight gradients).

// burn 0.22 marks libtorch deprecated; chosen all the same
// (docs/decisions/0010-libtorch-on-a-gpu.md).
#![allow(deprecated)]

use std::sync::OnceLock;

use burn::backend::libtorch::TchTensor;
use burn::backend::{Autodiff, LibTorch};
use burn::nn::conv::Conv2d;
use burn::prelude::*;
use burn_autodiff::checkpoint::base::Checkpointer;
use burn_autodiff::checkpoint::strategy::NoCheckpointing;
use burn_autodiff::grads::Gradients;
use burn_autodiff::ops::{Backward, Ops, OpsKind};

/// The autodiff backend a training step's tensors live on with libtorch.
type Tracked = Autodiff<LibTorch>;

/// Whether this operation serves the U-Net: unless `AFX_UNET_CONV=burn`
/// (burn's own convolution, for measuring against), read once.
fn chosen() -> bool {
    static CHOSEN: OnceLock<bool> = OnceLock::new();
    *CHOSEN.get_or_init(|| match std::env::var("AFX_UNET_CONV").as_deref() {
        Err(_) | Ok("torch") => true,
        Ok("burn") => false,
        Ok(other) => {
            eprintln!("AFX_UNET_CONV takes torch or burn, not {other:?}; using torch");
            true
        }
    })
}

/// `relu(layer(x))` for a 3 × 3, same-padded, stride-1 convolution with a
/// bias, when `x` and the layer are tracked on libtorch; `None` otherwise.
pub(crate) fn conv3x3_relu(layer: &Conv2d, x: &Tensor<4>) -> Option<Tensor<4>> {
    let bias = layer.bias.as_ref()?;
    if !chosen() {
        return None;
    }
    let x = x.clone().try_into_primitive::<Tracked>().ok()?;
    let weight = layer.weight.val().try_into_primitive::<Tracked>().ok()?;
    let bias = bias.val().try_into_primitive::<Tracked>().ok()?;
    let nodes = [x.node(), weight.node(), bias.node()];
    let (x, weight, bias) = (
        &x.primitive().tensor,
        &weight.primitive().tensor,
        &bias.primitive().tensor,
    );
    let out = match ConvRelu
        .prepare::<NoCheckpointing>(nodes)
        .compute_bound()
        .stateful()
    {
        OpsKind::Tracked(prep) => {
            let leaf = |t: &tch::Tensor| t.detach().set_requires_grad(true);
            let leaves = [leaf(x), leaf(weight), leaf(bias)];
            let output = forward(&leaves[0], &leaves[1], &leaves[2]);
            let detached = TchTensor::new(output.detach());
            let state = ConvReluState {
                output: TchTensor::new(output),
                leaves: leaves.map(TchTensor::new),
            };
            prep.finish(state, detached)
        }
        OpsKind::UnTracked(prep) => {
            let output = tch::no_grad(|| forward(x, weight, bias));
            prep.finish(TchTensor::new(output))
        }
    };
    Some(Tensor::from_primitive::<Tracked>(out))
}

/// `relu(conv2d(x, weight) + bias)`, same-padded, stride 1.
fn forward(x: &tch::Tensor, weight: &tch::Tensor, bias: &tch::Tensor) -> tch::Tensor {
    x.conv2d(weight, Some(bias), [1, 1], [1, 1], [1, 1], 1)
        .relu()
}

#[derive(Debug)]
struct ConvRelu;

/// What the backward step needs of the forward pass: the output with
/// libtorch's graph behind it, and the leaves (input, weight, bias) it
/// grew from.
#[derive(Clone, Debug)]
struct ConvReluState {
    output: TchTensor,
    leaves: [TchTensor; 3],
}

impl Backward<LibTorch, 3> for ConvRelu {
    type State = ConvReluState;

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        let grad = grads.consume::<LibTorch>(&ops.node);
        let state = ops.state;
        let wanted: Vec<_> = ops
            .parents
            .iter()
            .zip(&state.leaves)
            .filter_map(|(node, leaf)| node.as_ref().map(|n| (n.id, &leaf.tensor)))
            .collect();
        if wanted.is_empty() {
            return;
        }
        let product = (&state.output.tensor * &grad.tensor).sum(tch::Kind::Float);
        let leaves: Vec<&tch::Tensor> = wanted.iter().map(|(_, leaf)| *leaf).collect();
        let gradients = tch::Tensor::run_backward(&[product], &leaves, false, false);
        for ((id, _), gradient) in wanted.into_iter().zip(gradients) {
            grads.register::<LibTorch>(id, TchTensor::new(gradient));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::assert_same_values_and_gradients;
    use burn::nn::conv::Conv2dConfig;
    use burn::nn::PaddingConfig2d;
    use burn::tensor::activation::relu;
    use burn::tensor::Distribution;

    /// Values and the gradients of input, weight and bias against burn's
    /// convolution and ReLU on libtorch's CPU device, for `batch` images of
    /// `inputs` channels; then two such layers in a row (a `DoubleConv`), so
    /// that a gradient passes from one operation into the other.
    fn check(batch: usize, inputs: usize, outputs: usize, side: usize) {
        let device = Device::libtorch().autodiff();
        let layer = |i, o| {
            Conv2dConfig::new([i, o], [3, 3])
                .with_padding(PaddingConfig2d::Same)
                .init(&device)
        };
        let (first, second) = (layer(inputs, outputs), layer(outputs, outputs));
        let input =
            Tensor::<4>::random([batch, inputs, side, side], Distribution::Default, &device)
                .sub_scalar(0.5);
        // A loss that weighs every output differently, so a shifted or
        // transposed output cannot give the same gradients.
        let weights = Tensor::<4>::random(
            [batch, outputs, side, side],
            Distribution::Normal(0.0, 1.0),
            &device,
        );
        let x_ours = input.clone().detach().require_grad();
        let ours = |l: &Conv2d, x: &Tensor<4>| conv3x3_relu(l, x).expect("the libtorch path");
        let ours = ours(&second, &ours(&first, &x_ours));
        let x_burn = input.detach().require_grad();
        let burns = relu(second.forward(relu(first.forward(x_burn.clone()))));
        assert_same_values_and_gradients(
            (ours, &x_ours),
            (burns, &x_burn),
            weights,
            &[("first", &first), ("second", &second)],
            &format!("{batch} x {inputs} -> {outputs} at {side} px"),
        );
    }

    #[test]
    fn libtorchs_backward_gives_burns_gradients() {
        check(2, 4, 6, 16);
        check(3, 5, 3, 10);
    }

    #[test]
    fn without_autodiff_it_leaves_the_convolution_to_burn() {
        let device = Device::libtorch();
        let layer = Conv2dConfig::new([2, 3], [3, 3])
            .with_padding(PaddingConfig2d::Same)
            .init(&device);
        let x = Tensor::<4>::zeros([1, 2, 8, 8], &device);
        assert!(conv3x3_relu(&layer, &x).is_none());
    }
}
