//! Gradient clipping by the global norm over all parameters (as PyTorch's
//! `clip_grad_norm_`, which CleanRL's PPO uses). Burn's own clipping works
//! per tensor, which changes the update's direction.
//!
//! The norm stays a tensor on the device: reading it back (once per
//! parameter, as this module first did) made every minibatch wait for the
//! GPU some fifty times; now the caller reads it when it wants the figure.
//! On libtorch each tensor's squared norm and scaling are one libtorch call
//! each (`training::libtorch_ops`), not burn's two.

use burn::module::{Module, ModuleVisitor, Param};
use burn::optim::GradientsParams;
use burn::prelude::*;

/// Collects each parameter's squared gradient norm, as a one-element tensor.
struct SquaredNorms<'a> {
    grads: &'a GradientsParams,
    parts: Vec<Tensor<1>>,
}

impl ModuleVisitor for SquaredNorms<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if let Some(g) = self.grads.get::<D>(param.id) {
            let squared = crate::libtorch_ops::squared_norm(&g);
            self.parts.push(squared.unwrap_or_else(|| g.square().sum()));
        }
    }
}

/// Multiplies every gradient by a one-element tensor.
struct Scale<'a> {
    grads: &'a mut GradientsParams,
    factor: Tensor<1>,
}

impl ModuleVisitor for Scale<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if let Some(g) = self.grads.remove::<D>(param.id) {
            let scaled = crate::libtorch_ops::scaled(&g, &self.factor)
                .unwrap_or_else(|| g * self.factor.clone().reshape([1; D]));
            self.grads.register(param.id, scaled);
        }
    }
}

/// Scales `grads` so that their global L2 norm is at most `max_norm` and
/// returns the norm before scaling, as a one-element tensor on the
/// gradients' device (no read-back). Gradients already within the limit are
/// multiplied by exactly 1.
pub fn clip_global_norm<M: Module>(
    module: &M,
    grads: &mut GradientsParams,
    max_norm: f32,
) -> Option<Tensor<1>> {
    let mut norms = SquaredNorms {
        grads,
        parts: Vec::new(),
    };
    module.visit(&mut norms);
    if norms.parts.is_empty() {
        return None;
    }
    let total = Tensor::cat(norms.parts, 0).sum().sqrt();
    // min(1, max / (norm + 1e-6)), computed on the device.
    let factor = (total.clone() + 1e-6)
        .recip()
        .mul_scalar(max_norm)
        .clamp_max(1.0);
    let mut scale = Scale { grads, factor };
    module.visit(&mut scale);
    Some(total)
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::nn::{Linear, LinearConfig};

    /// Gradients of `sum(w · x) · k` for a small linear layer, with their
    /// expected norm computed on the host.
    fn grads(k: f32, device: &Device) -> (Linear, GradientsParams, f64) {
        let device = device.clone().autodiff();
        let layer = LinearConfig::new(3, 2).init(&device);
        let x = Tensor::<2>::from_floats([[1.0, -2.0, 0.5]], &device);
        let loss = layer.forward(x).sum() * k;
        let grads = GradientsParams::from_grads(loss.backward(), &layer);
        // d/dW = k · x per output (2 × 3), d/db = k per output.
        let expected = (2.0 * (1.0 + 4.0 + 0.25) + 2.0) * f64::from(k * k);
        (layer, grads, expected.sqrt())
    }

    /// The gradients' global norm, summed on the host.
    fn norm_after(layer: &Linear, grads: &GradientsParams) -> f64 {
        let weight: Vec<f32> = grads
            .get::<2>(layer.weight.id)
            .expect("weight gradient")
            .into_data()
            .try_to_vec()
            .unwrap();
        let bias_id = layer.bias.as_ref().expect("a bias").id;
        let bias: Vec<f32> = grads
            .get::<1>(bias_id)
            .expect("bias gradient")
            .into_data()
            .try_to_vec()
            .unwrap();
        (weight.iter().chain(&bias))
            .map(|&g| f64::from(g) * f64::from(g))
            .sum::<f64>()
            .sqrt()
    }

    #[test]
    fn large_gradients_are_scaled_to_the_limit_and_small_ones_kept() {
        clips_on(&Device::flex());
    }

    /// The same through libtorch's calls (`training::libtorch_ops`).
    #[cfg(feature = "gpu-torch")]
    #[test]
    #[allow(deprecated)]
    fn on_libtorch_too() {
        clips_on(&Device::libtorch());
    }

    fn clips_on(device: &Device) {
        let (layer, mut g, expected) = grads(10.0, device);
        let before = clip_global_norm(&layer, &mut g, 0.5).unwrap();
        let before = f64::from(before.into_scalar::<f32>());
        assert!(
            (before - expected).abs() < 1e-4 * expected,
            "{before} vs {expected}"
        );
        assert!((norm_after(&layer, &g) - 0.5).abs() < 1e-5);

        let (layer, mut g, expected) = grads(0.01, device);
        let before = clip_global_norm(&layer, &mut g, 0.5).unwrap();
        assert!((f64::from(before.into_scalar::<f32>()) - expected).abs() < 1e-6);
        assert!(
            (norm_after(&layer, &g) - expected).abs() < 1e-7,
            "unchanged"
        );
    }
}
