//! `cargo bench -p nets --bench unet_inference`: one U-Net inference call
//! (`nets::unet_inference::UnetInference::logits`, the actor's batching
//! thread's call: images in, logits out, copies to and from the device
//! included) per batch size at 128 px, for every path the device has: on
//! the CPU the CPU's own pass; on a GPU (`AFX_DEVICE=gpu`, a build with a
//! GPU feature) burn's pass and, with `gpu-torch`, libtorch's own
//! (`nets::unet_torch`). Medians of 30 calls after 5 unmeasured ones.
//! `AFX_BATCHES` lists the batch sizes (default 1,2,4,8,16; 1,2 on the
//! CPU), `AFX_SIDE` the image side (default 128).

use std::time::Instant;

use burn::prelude::Device;
use nets::unet::AffordanceUnet;
use nets::unet_inference::UnetInference;

/// A list of numbers from the variable `name`, else `default`.
fn numbers(name: &str, default: &[usize]) -> Vec<usize> {
    std::env::var(name).map_or(default.to_vec(), |s| {
        s.split(',')
            .map(|v| {
                v.trim()
                    .parse()
                    .unwrap_or_else(|_| panic!("{name}: numbers like 1,2,4"))
            })
            .collect()
    })
}

/// The ways a U-Net pass can run.
#[derive(Clone, Copy)]
enum Path {
    Cpu,
    Burn,
    Torch,
}

impl Path {
    fn name(self) -> &'static str {
        match self {
            Self::Cpu => "CPU",
            Self::Burn => "burn",
            Self::Torch => "libtorch",
        }
    }

    /// A fresh two-affordance U-Net on `device` that runs this way.
    fn make(self, device: &Device) -> UnetInference {
        let net = AffordanceUnet::new(4, 2, device);
        match self {
            Self::Cpu | Self::Torch => UnetInference::new(net, device),
            Self::Burn => UnetInference::Burn {
                net: Box::new(net),
                device: device.clone(),
            },
        }
    }
}

fn main() {
    if std::env::args().any(|a| a == "--list") {
        return; // `cargo test --benches` asks benches to list themselves
    }
    let choice: nets::device::DeviceChoice = std::env::var("AFX_DEVICE")
        .unwrap_or_else(|_| "cpu".into())
        .parse()
        .expect("AFX_DEVICE: cpu or gpu");
    let device = nets::device::open_device(choice).expect("the device (AFX_DEVICE)");
    let on_cpu = nets::device::is_cpu(&device);
    let batches = numbers(
        "AFX_BATCHES",
        if on_cpu { &[1, 2] } else { &[1, 2, 4, 8, 16] },
    );
    let side = numbers("AFX_SIDE", &[128])[0];
    let mut paths = vec![if on_cpu { Path::Cpu } else { Path::Burn }];
    if !on_cpu && cfg!(feature = "gpu-torch") {
        paths.push(Path::Torch);
    }
    println!(
        "U-Net inference, {side} px, {} ({})",
        nets::device::backend_features(),
        if on_cpu { "CPU" } else { "GPU" }
    );
    println!("| path | images | call, median | per image | 10th / 90th percentile |");
    println!("|---|---|---|---|---|");
    for path in paths {
        let name = path.name();
        let net = path.make(&device);
        for &n in &batches {
            let images: Vec<Vec<f32>> = (0..n)
                .map(|k| {
                    (0..4 * side * side)
                        .map(|i| ((i * 31 + k * 7) % 97) as f32 / 97.0)
                        .collect()
                })
                .collect();
            let refs: Vec<&[f32]> = images.iter().map(Vec::as_slice).collect();
            let mut times: Vec<f64> = (0..35)
                .map(|_| {
                    let started = Instant::now();
                    std::hint::black_box(net.logits(&refs, side, side));
                    started.elapsed().as_secs_f64() * 1e3
                })
                .skip(5)
                .collect();
            times.sort_by(f64::total_cmp);
            let median = times[times.len() / 2];
            println!(
                "| {name} | {n} | {median:.2} ms | {:.2} ms | {:.2} / {:.2} ms |",
                median / n as f64,
                times[times.len() / 10],
                times[times.len() * 9 / 10]
            );
        }
    }
}
