//! The U-Net's whole forward pass as one differentiable operation on
//! libtorch, whose backward step is libtorch's own.
//!
//! Why it exists: a U-Net training step (batch 8, 128 px) took over twice
//! PyTorch's time on an H200 with the same network (docs/performance.md,
//! "The learner"), with only its 3 × 3 convolutions through libtorch's
//! autograd (one operation each): every pooling, transposed convolution, concatenation and ReLU was
//! still a burn operation with burn's backward, and the U-Net trainer's
//! kernels delay the PPO update's on the GPU they share
//! (docs/notebook/2026-11-27-gpu-check-free-running.md). Here the forward
//! pass (`unet_torch::forward`, the actor's inference pass) records
//! libtorch's autograd graph on leaves of its own, and the backward step
//! asks libtorch for the gradients of `sum(output · output gradient)` with
//! respect to those leaves, which is exactly the operation's
//! vector-Jacobian product, computed by the kernels PyTorch itself trains
//! with. Only the loss and the optimiser stay burn's.
//!
//! It lives with the trainer, not with the network: only a training step
//! takes it (`UnetTrainer::step`, through [`logits`]);
//! inference and everything else run `AffordanceUnet::forward`.

// burn 0.22 marks libtorch deprecated; chosen all the same
// (docs/decisions/0010-libtorch-on-a-gpu.md).
#![allow(deprecated)]

use std::sync::OnceLock;

use burn::backend::libtorch::TchTensor;
use burn::backend::{Autodiff, LibTorch};
use burn::prelude::*;
use burn_autodiff::checkpoint::base::Checkpointer;
use burn_autodiff::checkpoint::strategy::NoCheckpointing;
use burn_autodiff::grads::Gradients;
use burn_autodiff::ops::{Backward, Ops, OpsKind};

use nets::unet::AffordanceUnet;
use nets::unet_torch::{forward as unet_forward, LAYER_TENSORS};

/// The autodiff backend a training step's tensors live on with libtorch.
type Tracked = Autodiff<LibTorch>;

/// The operation's inputs: the images, then every layer's weight and bias.
const INPUTS: usize = 1 + LAYER_TENSORS;

/// Whether this operation serves the U-Net: unless `AFX_UNET_CONV=burn`
/// (burn's own operations, for measuring against), read once.
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

/// `net`'s logits for `x`: as one operation where `x` and the network are
/// tracked on libtorch, else `AffordanceUnet::forward`. A network with batch
/// normalisations (`[unet] batch_norm`) always takes burn's operations: the
/// operation here has no normalisation in it.
pub(crate) fn logits(net: &AffordanceUnet, x: Tensor<4>) -> Tensor<4> {
    if net.has_batch_norm() {
        return net.forward(x);
    }
    match forward(|| net.layers(), &x) {
        Some(out) => out,
        None => net.forward(x),
    }
}

/// The U-Net's logits for `x` as one operation, from its layers' weights
/// and biases (`layers` gives them, `AffordanceUnet::layers`; asked only
/// once `x` is known to be tracked on libtorch), when `x` and the layers are
/// tracked on libtorch; `None` otherwise.
fn forward(
    layers: impl FnOnce() -> Vec<(Tensor<4>, Option<Tensor<1>>)>,
    x: &Tensor<4>,
) -> Option<Tensor<4>> {
    if !chosen() {
        return None;
    }
    let mut inputs = vec![x.clone().try_into_primitive::<Tracked>().ok()?];
    for (weight, bias) in layers() {
        inputs.push(weight.try_into_primitive::<Tracked>().ok()?);
        inputs.push(bias?.try_into_primitive::<Tracked>().ok()?);
    }
    let nodes: [_; INPUTS] = inputs
        .iter()
        .map(|t| t.node())
        .collect::<Vec<_>>()
        .try_into()
        .ok()?;
    let tensors: Vec<&tch::Tensor> = inputs.iter().map(|t| &t.primitive().tensor).collect();
    let out = match WholeUnet
        .prepare::<NoCheckpointing>(nodes)
        .compute_bound()
        .stateful()
    {
        OpsKind::Tracked(prep) => {
            let leaves: Vec<tch::Tensor> = tensors
                .iter()
                .map(|t| t.detach().set_requires_grad(true))
                .collect();
            let output = unet_forward(&leaves[1..], &leaves[0]);
            let detached = TchTensor::new(output.detach());
            let state = WholeUnetState {
                output: TchTensor::new(output),
                leaves: leaves.into_iter().map(TchTensor::new).collect(),
            };
            prep.finish(state, detached)
        }
        OpsKind::UnTracked(prep) => {
            let output = tch::no_grad(|| unet_forward(&tensors[1..], tensors[0]));
            prep.finish(TchTensor::new(output))
        }
    };
    Some(Tensor::from_primitive::<Tracked>(out))
}

#[derive(Debug)]
struct WholeUnet;

/// What the backward step needs of the forward pass: the output with
/// libtorch's graph behind it, and the leaves (images, weights and biases)
/// it grew from.
#[derive(Clone, Debug)]
struct WholeUnetState {
    output: TchTensor,
    leaves: Vec<TchTensor>,
}

impl Backward<LibTorch, INPUTS> for WholeUnet {
    type State = WholeUnetState;

    fn backward(self, ops: Ops<Self::State, INPUTS>, grads: &mut Gradients, _: &mut Checkpointer) {
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
    use burn::tensor::Distribution;

    /// The largest difference between two tensors, and the second's scale.
    fn difference<const D: usize>(a: Tensor<D>, b: Tensor<D>) -> (f32, f32) {
        let a: Vec<f32> = a.into_data().try_to_vec().unwrap();
        let b: Vec<f32> = b.into_data().try_to_vec().unwrap();
        let scale = b.iter().fold(0f32, |m, v| m.max(v.abs()));
        let largest = a
            .iter()
            .zip(&b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f32::max);
        (largest, scale)
    }

    /// Values, and the gradients of the images and of every layer's weight
    /// and bias, against burn's layer-by-layer pass on libtorch's CPU
    /// device, from a loss that weighs every logit differently.
    #[test]
    fn gives_the_values_and_gradients_of_burns_layer_by_layer_pass() {
        let device = Device::libtorch().autodiff();
        let net = AffordanceUnet::new(4, 2, &device);
        let input = Tensor::<4>::random([2, 4, 16, 24], Distribution::Uniform(0.0, 1.0), &device);
        let weights = Tensor::<4>::random([2, 2, 16, 24], Distribution::Normal(0.0, 1.0), &device);
        let x_ours = input.clone().detach().require_grad();
        let ours = forward(|| net.layers(), &x_ours).expect("tracked on libtorch");
        let x_burn = input.detach().require_grad();
        let burns = net.forward(x_burn.clone());
        let (diff, scale) = difference(ours.clone(), burns.clone());
        assert!(
            scale > 0.01 && diff <= 1e-5 * scale,
            "logits: {diff} of {scale}"
        );
        let ours_grads = (ours * weights.clone()).sum().backward();
        let burn_grads = (burns * weights).sum().backward();
        let (diff, scale) = difference(
            x_ours.grad(&ours_grads).expect("the images' gradient"),
            x_burn.grad(&burn_grads).expect("burn's"),
        );
        assert!(
            scale > 0.0 && diff <= 1e-4 * scale,
            "images: {diff} of {scale}"
        );
        let mut compared = 0;
        for (weight, bias) in net.layers() {
            let (diff, scale) = difference(
                weight.grad(&ours_grads).expect("a weight's gradient"),
                weight.grad(&burn_grads).expect("burn's"),
            );
            assert!(
                scale > 0.0 && diff <= 1e-4 * scale,
                "weight {compared}: {diff} of {scale}"
            );
            let bias = bias.expect("every layer has a bias");
            let (diff, scale) = difference(
                bias.grad(&ours_grads).expect("a bias's gradient"),
                bias.grad(&burn_grads).expect("burn's"),
            );
            assert!(
                diff <= 1e-4 * scale.max(1e-3),
                "bias {compared}: {diff} of {scale}"
            );
            compared += 1;
        }
        assert_eq!(compared, LAYER_TENSORS / 2);
    }

    #[test]
    fn without_autodiff_it_leaves_the_pass_to_the_network() {
        let net = AffordanceUnet::new(4, 2, &Device::libtorch());
        let x = Tensor::<4>::zeros([1, 4, 8, 8], &Device::libtorch());
        assert!(forward(|| net.layers(), &x).is_none());
    }
}
