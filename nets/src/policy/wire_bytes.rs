//! A batch of byte observations moved to libtorch's device as bytes and
//! turned into floats there.
//!
//! Why: at 128 px a PPO batch of 1 024 steps of the `ours` state is 436 MB
//! of bytes and 1.7 GB of floats. Decoded on the host and handed to burn,
//! the floats are copied again into a libtorch tensor and then uploaded
//! from pageable memory: on an H200 building the batch took four times as
//! long as the update it fed (docs/notebook/2026-11-27-libtorch-learner.md).
//! Here one upload of the bytes straight from the batch's buffer, then a
//! slice, a cast and a scale per input on the device.

// burn 0.22 marks libtorch deprecated; chosen all the same
// (docs/decisions/0010-libtorch-on-a-gpu.md).
#![allow(deprecated)]

use burn::backend::libtorch::TchTensor;
use burn::backend::LibTorch;
use burn::prelude::*;
use burn::tensor::Bool;
use proto::{ObsDtype, PolicyLayout};

use super::PolicyInput;

/// `rows` observations of `layout` as the wire carries them (`obs` bytes,
/// `masks` one byte per action, nonzero = allowed) as a [`PolicyInput`] on
/// `device`, the bytes converted on the device; `None` unless `device` is
/// libtorch's and the layout's observations are bytes.
///
/// # Panics
/// If the lengths do not match `layout`: callers validate first.
pub(crate) fn upload(
    layout: &PolicyLayout,
    obs: &[u8],
    masks: &[u8],
    rows: usize,
    device: &Device,
) -> Option<PolicyInput> {
    if layout.obs_dtype != ObsDtype::U8 {
        return None;
    }
    let probe = Tensor::<1>::zeros([1], device)
        .try_into_primitive::<LibTorch>()
        .ok()?;
    let on = probe.tensor.device();
    let len = layout.obs_len();
    assert_eq!(obs.len(), rows * len, "observation length");
    assert_eq!(masks.len(), rows * layout.n_actions, "mask length");
    // SAFETY: `host` views `obs`, which outlives it, as bytes; nothing
    // writes through it. A blocking copy to a GPU has read it whole when
    // `to` returns; on the CPU `to` returns `host` itself, but every tensor
    // that outlives this call comes from `to_kind` below, which copies.
    // (A copy into a tensor of its own first cost a fresh 436 MB on the
    // host at 128 px for every batch.)
    let host = unsafe {
        tch::Tensor::from_blob(
            obs.as_ptr(),
            &[obs.len() as i64],
            &[],
            tch::Kind::Uint8,
            tch::Device::Cpu,
        )
    };
    let all = host.to(on).view([rows as i64, len as i64]);
    let mut start = 0i64;
    let mut column = |width: usize, shape: &[i64]| {
        let values = all
            .narrow(1, start, width as i64)
            .to_kind(tch::Kind::Float)
            .g_div_scalar(255.0)
            .reshape(shape);
        start += width as i64;
        TchTensor::new(values)
    };
    let (rows_i, side) = (rows as i64, layout.image_size as i64);
    let pixels = layout.image_size * layout.image_size;
    let images = layout
        .image_channels
        .iter()
        .map(|&c| {
            let values = column(c * pixels, &[rows_i, c as i64, side, side]);
            Tensor::<4>::from_primitive::<LibTorch>(values)
        })
        .collect();
    let vectors = layout
        .vector_dims
        .iter()
        .map(|&d| Tensor::<2>::from_primitive::<LibTorch>(column(d, &[rows_i, d as i64])))
        .collect();
    let mask = Tensor::<2, Bool>::from_data(
        TensorData::new(
            masks.iter().map(|&m| m != 0).collect::<Vec<_>>(),
            [rows, layout.n_actions],
        ),
        device,
    );
    Some(PolicyInput {
        images,
        vectors,
        mask,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each tensor's values, as floats.
    fn values<const D: usize>(tensors: &[Tensor<D>]) -> Vec<Vec<f32>> {
        (tensors.iter())
            .map(|t| t.clone().into_data().to_vec::<f32>().unwrap())
            .collect()
    }

    #[test]
    fn bytes_converted_on_the_device_are_the_hosts_floats() {
        let layout = PolicyLayout {
            image_channels: vec![3, 2],
            image_size: 8,
            vector_dims: vec![5, 1],
            n_actions: 4,
            obs_dtype: ObsDtype::U8,
            gru_hidden: None,
        };
        let rows = 7;
        let masks: Vec<u8> = (0..rows * 4).map(|i| u8::from(i % 3 != 0)).collect();
        let mut devices = vec![Device::libtorch()];
        if tch::Cuda::is_available() {
            devices.push(Device::libtorch_cuda(0));
        }
        for device in devices {
            let mut obs: Vec<u8> = (0..rows * layout.obs_len())
                .map(|i| (i * 37 % 256) as u8)
                .collect();
            let uploaded = upload(&layout, &obs, &masks, rows, &device).expect("libtorch, bytes");
            let floats: Vec<f32> = obs.iter().map(|&b| proto::byte_to_unit(b)).collect();
            let host = PolicyInput::from_flat(&layout, &floats, &masks, rows, &device);
            // The batch's buffer is refilled for the next batch: the
            // uploaded tensors must not be views of it.
            obs.fill(0);
            assert_eq!(values(&uploaded.images), values(&host.images), "{device:?}");
            assert_eq!(
                values(&uploaded.vectors),
                values(&host.vectors),
                "{device:?}"
            );
            let dims = |i: &[Tensor<4>]| i.iter().map(Tensor::dims).collect::<Vec<_>>();
            assert_eq!(dims(&uploaded.images), dims(&host.images));
            assert_eq!(
                uploaded.mask.into_data().to_vec::<bool>().unwrap(),
                host.mask.into_data().to_vec::<bool>().unwrap()
            );
        }
        let obs = vec![0u8; rows * layout.obs_len()];
        let device = Device::libtorch();
        let floats_layout = PolicyLayout {
            obs_dtype: ObsDtype::F32,
            ..layout.clone()
        };
        assert!(upload(&floats_layout, &obs, &masks, rows, &device).is_none());
        assert!(upload(&layout, &obs, &masks, rows, &Device::flex()).is_none());
    }
}
