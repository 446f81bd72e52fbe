//! Adam's update of one parameter as a handful of libtorch operations, for
//! the learner's trainers on libtorch ([`super::Adam`]).
//!
//! Why it exists: burn's Adam spends 13 tensor operations (15 with weight
//! decay) on each parameter at each step (both moments, bias correction,
//! the update), each through burn's dispatch into libtorch and, on a GPU,
//! each a kernel launch. The PPO update takes eight optimiser steps over the
//! policy's 44 tensors and the U-Net's step one over its 36: thousands of
//! small kernels an update, where the host issuing them rather than the GPU
//! may set the pace (PyTorch, against which the trainers are measured,
//! updates all parameters at once; what this saves on a GPU is the next GPU
//! check's `adam_steps` figure). Here the same arithmetic is 8 libtorch operations a
//! parameter (10 with weight decay), called on libtorch's tensors directly.
//! `cargo bench -p training --bench adam_steps` measures a step against burn's
//! (docs/performance.md, "The learner"; on libtorch's CPU device ours takes
//! less of the host's time to issue a step).
//!
//! The arithmetic is burn's `Adam` with optional weight decay (L2, added to
//! the gradient): the moments of a parameter, their step count and the new
//! parameter come out as burn's do, to float rounding, so an optimiser
//! state saved by either continues in the other.

// burn 0.22 marks libtorch deprecated; chosen all the same
// (docs/decisions/0010-libtorch-on-a-gpu.md).
#![allow(deprecated)]

use burn::backend::libtorch::TchTensor;
use burn::backend::LibTorch;
use burn::optim::{AdamState, AdaptiveMomentumState};
use burn::prelude::*;

use super::settings::AdamSettings;
use crate::libtorch_ops::on_libtorch;

/// Adam's step of `param` with `grad` at learning rate `lr`, after
/// `previous` (none before the first step): the new parameter and state.
/// `None` when the tensors are not libtorch's (the caller then takes
/// burn's step). Every result is a new tensor: nothing passed in is
/// written, so tensors that share a parameter's storage keep their values.
pub(crate) fn adam_step<const D: usize>(
    settings: &AdamSettings,
    lr: f64,
    param: &Tensor<D>,
    grad: &Tensor<D>,
    previous: Option<&AdamState<D>>,
) -> Option<(Tensor<D>, AdamState<D>)> {
    let p = on_libtorch(param)?;
    let g = on_libtorch(grad)?;
    let previous = match previous {
        Some(s) => Some((
            s.momentum.time,
            on_libtorch(&s.momentum.moment_1)?,
            on_libtorch(&s.momentum.moment_2)?,
        )),
        None => None,
    };
    let AdamSettings {
        beta_1,
        beta_2,
        epsilon,
        weight_decay,
    } = *settings;
    let g = match weight_decay {
        Some(penalty) => {
            let mut decayed = p.f_mul_scalar(f64::from(penalty)).ok()?;
            let _ = decayed.f_add_(&g).ok()?;
            decayed
        }
        None => g,
    };
    let scaled = g.f_mul_scalar(f64::from(1.0 - beta_2)).ok()?;
    let (time, first, second) = match previous {
        Some((time, first, second)) => {
            let first = first.f_lerp(&g, f64::from(1.0 - beta_1)).ok()?;
            let mut second = second.f_mul_scalar(f64::from(beta_2)).ok()?;
            let _ = second.f_addcmul_(&scaled, &g).ok()?;
            (time + 1, first, second)
        }
        None => {
            let first = g.f_mul_scalar(f64::from(1.0 - beta_1)).ok()?;
            let second = scaled.f_mul(&g).ok()?;
            (1, first, second)
        }
    };
    // burn's bias correction, in f32 as it computes it.
    let t = i32::try_from(time).unwrap_or(i32::MAX);
    let correction_2 = (1.0 - beta_2.powi(t)).sqrt();
    let combined = correction_2 / (1.0 - beta_1.powi(t));
    let mut denominator = second.f_sqrt().ok()?;
    let _ = denominator
        .f_add_scalar_(f64::from(epsilon * correction_2))
        .ok()?;
    let step = first.f_mul_scalar(-(lr * f64::from(combined))).ok()?;
    let updated = p.f_addcdiv(&step, &denominator).ok()?;
    let wrap = |t: tch::Tensor| Tensor::<D>::from_primitive::<LibTorch>(TchTensor::new(t));
    let momentum = AdaptiveMomentumState::new(time, wrap(first), wrap(second));
    Some((wrap(updated), AdamState::new(momentum)))
}

#[cfg(test)]
mod tests {
    use burn::optim::Optimizer;

    use super::*;
    use crate::adam::settings::burns_adam;

    fn floats<const D: usize>(t: &Tensor<D>) -> Vec<f32> {
        t.clone().into_data().try_to_vec().unwrap()
    }

    /// Within float rounding of each other (the two compute the moments'
    /// blend in a different order).
    fn assert_near<const D: usize>(ours: &Tensor<D>, burns: &Tensor<D>, what: &str) {
        for (a, b) in floats(ours).iter().zip(floats(burns)) {
            assert!(
                (a - b).abs() <= 2e-6 * b.abs().max(1e-2),
                "{what}: {a} against burn's {b}"
            );
        }
    }

    /// Four steps of growing gradients, with and without weight decay,
    /// against burn's own Adam on libtorch's CPU device; the parameter
    /// passed in keeps its values.
    #[test]
    fn four_steps_as_burns_adam_takes_them() {
        let device = Device::libtorch();
        for weight_decay in [None, Some(1e-2)] {
            let settings = AdamSettings {
                beta_1: 0.9,
                beta_2: 0.999,
                epsilon: 1e-5,
                weight_decay,
            };
            let burn = burns_adam(&settings);
            let start = vec![0.5f32, -1.25, 2.0, 0.0, 3.5, -0.75];
            let start = Tensor::<2>::from_data(TensorData::new(start, [2, 3]), &device);
            let (mut ours, mut theirs) = ((start.clone(), None), (start, None));
            for k in 0..4 {
                let g: Vec<f32> = (0..6)
                    .map(|i| (i as f32 - 2.5) * (k as f32 + 1.0) * 0.3)
                    .collect();
                let g = Tensor::<2>::from_data(TensorData::new(g, [2, 3]), &device);
                let before = floats(&ours.0);
                let (p, s) = adam_step(&settings, 1e-2, &ours.0, &g, ours.1.as_ref())
                    .expect("tensors on libtorch");
                assert_eq!(
                    floats(&ours.0),
                    before,
                    "the parameter passed in is not written"
                );
                let (bp, bs) = burn.step(1e-2, theirs.0, g, theirs.1);
                let bs = bs.expect("burn's state");
                assert_eq!(s.momentum.time, bs.momentum.time);
                assert_near(&p, &bp, "parameter");
                assert_near(&s.momentum.moment_1, &bs.momentum.moment_1, "first moment");
                assert_near(&s.momentum.moment_2, &bs.momentum.moment_2, "second moment");
                (ours, theirs) = ((p, Some(s)), (bp, Some(bs)));
            }
        }
    }
}
