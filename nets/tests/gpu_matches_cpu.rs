//! The same weights give the same outputs, and one training step the same
//! new weights, on the CPU and the GPU backend (within float tolerance).
//! Built only with `--features gpu` or `--features gpu-torch`; skipped with
//! a message where no GPU is usable. The U-Net's step here is its own
//! forward pass (burn's operations); the trainer's one-operation pass on
//! libtorch (`training::unet_train_torch`) is held to that pass by its unit
//! test.
//!
//! On libtorch run it with `NVIDIA_TF32_OVERRIDE=0` (as `deploy/gpu-check.sh`
//! does): cuDNN convolutions use TF32 by default, as in PyTorch and in the
//! learner, and with TF32 one U-Net step's new weights differ from the CPU's
//! by about 10–20 % of the step's size (a gradient that is a sum with
//! cancellations), against 5e-5 without it, measured on an H200.
#![cfg(any(feature = "gpu", feature = "gpu-torch"))]

use burn::optim::{GradientsParams, ModuleOptimizer, SgdConfig};
use burn::prelude::*;
use nets::device::{open_device, DeviceChoice};
use nets::policy::{ObsDtype, PolicyInput, PolicyLayout, PolicyNet};
use nets::unet::AffordanceUnet;
use nets::unet_inference::UnetInference;
use nets::weights::{load_safetensors, to_safetensors};

fn max_abs_diff(a: Vec<f32>, b: Vec<f32>) -> f32 {
    a.iter()
        .zip(&b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

/// The GPU, or `None` (said on stderr) where this machine has none.
fn gpu_or_skip() -> Option<Device> {
    open_device(DeviceChoice::Gpu)
        .inspect_err(|e| eprintln!("skipping: {e}"))
        .ok()
}

/// Every tensor of a safetensors blob, by name, as f32 values.
fn tensors(bytes: &[u8]) -> Vec<(String, Vec<f32>)> {
    let file = safetensors::SafeTensors::deserialize(bytes).expect("a safetensors blob");
    let mut all: Vec<(String, Vec<f32>)> = file
        .tensors()
        .into_iter()
        .map(|(name, view)| {
            let values = view
                .data()
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect();
            (name, values)
        })
        .collect();
    all.sort_by(|a, b| a.0.cmp(&b.0));
    all
}

/// The largest difference between two networks' parameters after the same
/// step, relative to the largest change the step made on the CPU.
fn relative_step_difference(before: &[u8], cpu_after: &[u8], gpu_after: &[u8]) -> f32 {
    let (before, cpu_after, gpu_after) = (tensors(before), tensors(cpu_after), tensors(gpu_after));
    assert_eq!(cpu_after.len(), gpu_after.len(), "same parameters");
    let mut largest_change = 0f32;
    let mut largest_difference = 0f32;
    for ((b, c), g) in before.iter().zip(&cpu_after).zip(&gpu_after) {
        assert_eq!((&b.0, &c.0), (&g.0, &g.0), "parameters in the same order");
        for ((b, c), g) in b.1.iter().zip(&c.1).zip(&g.1) {
            largest_change = largest_change.max((c - b).abs());
            largest_difference = largest_difference.max((c - g).abs());
        }
    }
    assert!(largest_change > 0.0, "the step changed the weights");
    largest_difference / largest_change
}

/// A fresh U-Net on the CPU and the same weights on `gpu`.
fn unet_on_both(gpu: &Device) -> (AffordanceUnet, AffordanceUnet) {
    let unet_cpu = AffordanceUnet::new(4, 2, &Device::flex());
    let mut unet_gpu = AffordanceUnet::new(4, 2, gpu);
    load_safetensors(&mut unet_gpu, to_safetensors(&unet_cpu).unwrap()).unwrap();
    (unet_cpu, unet_gpu)
}

#[test]
fn cpu_and_gpu_agree_on_the_same_weights() {
    let Some(gpu) = gpu_or_skip() else {
        return;
    };
    let cpu = Device::flex();

    let (unet_cpu, unet_gpu) = unet_on_both(&gpu);
    let x: Vec<f32> = (0..4 * 128 * 128)
        .map(|i| ((i * 7919) % 1000) as f32 / 1000.0)
        .collect();
    let on = |d: &Device| Tensor::<1>::from_floats(x.as_slice(), d).reshape([1, 4, 128, 128]);
    let a: Vec<f32> = unet_cpu.forward(on(&cpu)).into_data().try_to_vec().unwrap();
    let b: Vec<f32> = unet_gpu.forward(on(&gpu)).into_data().try_to_vec().unwrap();
    let unet_diff = max_abs_diff(a, b);

    let config = PolicyLayout {
        image_channels: vec![4],
        image_size: 128,
        vector_dims: vec![15],
        n_actions: 8,
        obs_dtype: ObsDtype::F32,
        gru_hidden: Some(64),
    };
    let policy_cpu = PolicyNet::new(&config, &cpu);
    let mut policy_gpu = PolicyNet::new(&config, &gpu);
    load_safetensors(&mut policy_gpu, to_safetensors(&policy_cpu).unwrap()).unwrap();
    let input = |d: &Device| PolicyInput {
        images: vec![on(d)],
        vectors: vec![Tensor::<1>::from_floats(&x[..15], d).reshape([1, 15])],
        mask: Tensor::<2, Bool>::full([1, 8], true, d),
    };
    let a: Vec<f32> = policy_cpu
        .forward(&input(&cpu), None)
        .log_probs
        .into_data()
        .try_to_vec()
        .unwrap();
    let b: Vec<f32> = policy_gpu
        .forward(&input(&gpu), None)
        .log_probs
        .into_data()
        .try_to_vec()
        .unwrap();
    let policy_diff = max_abs_diff(a, b);
    eprintln!("max |cpu - gpu|: U-Net logits {unet_diff:e}, policy log-probs {policy_diff:e}");
    assert!(unet_diff < 1e-3 && policy_diff < 1e-4);
}

/// The actor's U-Net pass on the GPU gives each image of a batch the
/// logits the CPU's pass gives it alone.
#[test]
fn the_gpus_inference_pass_agrees_with_the_cpus() {
    let Some(gpu) = gpu_or_skip() else {
        return;
    };
    let cpu = Device::flex();
    let (unet_cpu, unet_gpu) = unet_on_both(&gpu);
    let side = 128;
    let images: Vec<Vec<f32>> = (0..3)
        .map(|k| {
            (0..4 * side * side)
                .map(|i| ((i * 7919 + k * 104_729) % 1000) as f32 / 1000.0)
                .collect()
        })
        .collect();
    let refs: Vec<&[f32]> = images.iter().map(Vec::as_slice).collect();
    let expected = UnetInference::new(unet_cpu, &cpu).logits(&refs, side, side);
    let got = UnetInference::new(unet_gpu, &gpu).logits(&refs, side, side);
    assert_eq!(got.len(), expected.len());
    for (k, (g, e)) in got.into_iter().zip(expected).enumerate() {
        let diff = max_abs_diff(g, e);
        eprintln!("U-Net inference, image {k}: max |cpu - gpu| {diff:e}");
        assert!(diff < 1e-3, "image {k}: {diff:e}");
    }
}

/// One plain gradient step (SGD, lr 0.01) of a network on `device` for a
/// fixed loss, from the same weights; the new weights.
fn one_step<M: Module + burn::store::ModuleSnapshot>(
    mut net: M,
    weights: &[u8],
    loss: impl FnOnce(&M) -> Tensor<1>,
) -> Vec<u8> {
    load_safetensors(&mut net, weights.to_vec()).unwrap();
    let grads = GradientsParams::from_grads(loss(&net).backward(), &net);
    let mut optimizer: ModuleOptimizer = SgdConfig::new().init();
    let net = optimizer.step(0.01, net, grads);
    to_safetensors(&net).unwrap()
}

#[test]
fn cpu_and_gpu_agree_after_one_training_step() {
    let Some(gpu) = gpu_or_skip() else {
        return;
    };
    let cpu = Device::flex();
    let side = 64;
    let pixels = 2 * 4 * side * side;
    let x: Vec<f32> = (0..pixels)
        .map(|i| ((i * 7919) % 1000) as f32 / 1000.0)
        .collect();
    let signs: Vec<f32> = (0..pixels)
        .map(|i| if i % 3 == 0 { 1.0 } else { -0.5 })
        .collect();
    let images = |d: &Device| Tensor::<1>::from_floats(x.as_slice(), d).reshape([2, 4, side, side]);

    // The U-Net: a weighted sum of its logits.
    let unet_weights = to_safetensors(&AffordanceUnet::new(4, 2, &cpu)).unwrap();
    let unet_step = |device: &Device| {
        let d = device.clone().autodiff();
        one_step(AffordanceUnet::new(4, 2, &d), &unet_weights, |net| {
            let weights = Tensor::<1>::from_floats(&signs[..2 * 2 * side * side], &d)
                .reshape([2, 2, side, side]);
            (net.forward(images(&d)) * weights).sum()
        })
    };
    let unet_difference =
        relative_step_difference(&unet_weights, &unet_step(&cpu), &unet_step(&gpu));

    // The policy (its encoders take each backend's convolution path): a
    // weighted sum of log-probabilities and values.
    let layout = PolicyLayout {
        image_channels: vec![4],
        image_size: side,
        vector_dims: vec![15],
        n_actions: 8,
        obs_dtype: ObsDtype::F32,
        gru_hidden: None,
    };
    let policy_weights = to_safetensors(&PolicyNet::new(&layout, &cpu)).unwrap();
    let policy_step = |device: &Device| {
        let d = device.clone().autodiff();
        one_step(PolicyNet::new(&layout, &d), &policy_weights, |net| {
            let input = PolicyInput {
                images: vec![images(&d)],
                vectors: vec![Tensor::<1>::from_floats(&x[..30], &d).reshape([2, 15])],
                mask: Tensor::<2, Bool>::full([2, 8], true, &d),
            };
            let out = net.forward(&input, None);
            let weights = Tensor::<1>::from_floats(&signs[..16], &d).reshape([2, 8]);
            (out.log_probs * weights).sum() + out.values.sum()
        })
    };
    let policy_difference =
        relative_step_difference(&policy_weights, &policy_step(&cpu), &policy_step(&gpu));
    eprintln!(
        "after one step, max |cpu - gpu| / max step: U-Net {unet_difference:e}, policy {policy_difference:e}"
    );
    assert!(unet_difference < 1e-2 && policy_difference < 1e-2);
}
