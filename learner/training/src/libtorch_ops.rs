//! Two operations a trainer issues for every parameter at every minibatch,
//! as one libtorch call each where the tensors are libtorch's (`gpu-torch`):
//! the squared norm and the scaling of the global-norm gradient clipping
//! (`training::grad_norm`). In burn's operations they are two each (a
//! square and a sum; a reshape and a product), and on a GPU each libtorch
//! call costs the host its dispatch and a kernel launch, for the policy's 44
//! tensors eight times an update (docs/notebook/2026-11-28-adam-on-libtorch.md).
//!
//! Elsewhere, and in builds without `gpu-torch`, both return `None` and the
//! caller writes them in burn's operations.

// burn 0.22 marks libtorch deprecated; chosen all the same
// (docs/decisions/0010-libtorch-on-a-gpu.md).
#![cfg_attr(feature = "gpu-torch", allow(deprecated))]

use burn::prelude::*;

#[cfg(feature = "gpu-torch")]
use burn::backend::{libtorch::TchTensor, LibTorch};

/// The tensor's libtorch tensor, if it lives on libtorch (also the
/// trainers' Adam's way in, `adam::libtorch`).
#[cfg(feature = "gpu-torch")]
pub(crate) fn on_libtorch<const D: usize>(tensor: &Tensor<D>) -> Option<tch::Tensor> {
    Some(tensor.clone().try_into_primitive::<LibTorch>().ok()?.tensor)
}

/// The sum of the squares of all of `t`'s elements, a one-element tensor on
/// `t`'s device (a dot product of `t` with itself), if `t` is libtorch's.
pub fn squared_norm<const D: usize>(t: &Tensor<D>) -> Option<Tensor<1>> {
    #[cfg(feature = "gpu-torch")]
    {
        let flat = on_libtorch(t)?.f_reshape([-1]).ok()?;
        let dot = flat.f_dot(&flat).ok()?.f_reshape([1]).ok()?;
        Some(Tensor::from_primitive::<LibTorch>(TchTensor::new(dot)))
    }
    #[cfg(not(feature = "gpu-torch"))]
    {
        let _ = t;
        None
    }
}

/// `t` times the one-element `factor` (broadcast, no reshape), if both are
/// libtorch's.
pub fn scaled<const D: usize>(t: &Tensor<D>, factor: &Tensor<1>) -> Option<Tensor<D>> {
    #[cfg(feature = "gpu-torch")]
    {
        let product = on_libtorch(t)?.f_mul(&on_libtorch(factor)?).ok()?;
        Some(Tensor::from_primitive::<LibTorch>(TchTensor::new(product)))
    }
    #[cfg(not(feature = "gpu-torch"))]
    {
        let _ = (t, factor);
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn values() -> Vec<f32> {
        vec![0.5, -1.25, 2.0, 0.0, 3.5, -0.75]
    }

    /// Off libtorch the caller is left to burn's operations.
    #[test]
    fn tensors_off_libtorch_are_declined() {
        let device = Device::flex();
        let t = Tensor::<2>::from_data(TensorData::new(values(), [2, 3]), &device);
        assert!(squared_norm(&t).is_none());
        assert!(scaled(&t, &Tensor::from_floats([2.0], &device)).is_none());
    }

    /// On libtorch both give what burn's operations give.
    #[cfg(feature = "gpu-torch")]
    #[test]
    #[allow(deprecated)]
    fn on_libtorch_they_give_burns_values() {
        let device = Device::libtorch();
        let t = Tensor::<2>::from_data(TensorData::new(values(), [2, 3]), &device);
        let ours = squared_norm(&t).expect("libtorch").into_scalar::<f32>();
        let burns = t.clone().square().sum().into_scalar::<f32>();
        assert!(
            (ours - burns).abs() <= 1e-6 * burns,
            "{ours} against {burns}"
        );
        let factor = Tensor::<1>::from_floats([0.25], &device);
        let ours: Vec<f32> = scaled(&t, &factor)
            .expect("libtorch")
            .into_data()
            .try_to_vec()
            .unwrap();
        let burns: Vec<f32> = (t * factor.reshape([1, 1]))
            .into_data()
            .try_to_vec()
            .unwrap();
        assert_eq!(ours, burns);
    }
}
