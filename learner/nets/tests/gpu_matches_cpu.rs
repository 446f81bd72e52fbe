//! The same weights give the same outputs on the CPU and the GPU backend
//! (within float tolerance). Built only with `--features gpu`; skipped with a
//! message where no GPU is usable.
#![cfg(feature = "gpu")]

use burn::prelude::*;
use nets::device::{open_device, DeviceChoice};
use nets::policy::{ObsDtype, PolicyInput, PolicyLayout, PolicyNet};
use nets::unet::AffordanceUnet;
use nets::weights::{load_safetensors, to_safetensors};

fn max_abs_diff(a: Vec<f32>, b: Vec<f32>) -> f32 {
    a.iter()
        .zip(&b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

#[test]
fn cpu_and_gpu_agree_on_the_same_weights() {
    let gpu = match open_device(DeviceChoice::Gpu) {
        Ok(d) => d,
        Err(e) => {
            eprintln!("skipping: {e}");
            return;
        }
    };
    let cpu = Device::flex();

    let unet_cpu = AffordanceUnet::new(4, 2, &cpu);
    let mut unet_gpu = AffordanceUnet::new(4, 2, &gpu);
    load_safetensors(&mut unet_gpu, to_safetensors(&unet_cpu).unwrap()).unwrap();
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
