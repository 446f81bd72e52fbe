//! `cargo bench -p training --bench adam_steps`: one Adam step of the trainers'
//! optimiser (`training::adam::Adam`) against burn's own Adam, alternated, over
//! the parameters the learner trains: the U-Net's (with its weight decay),
//! the `ours` task's policy at 128 px, and the U-Net's 36 tensors cut to one
//! element each. The last row leaves almost no arithmetic, so it is the
//! host's cost of issuing a step's operations: on a GPU that cost, not the
//! kernels, is what a step of small tensors waits for.
//!
//! The device is `AFX_DEVICE`: `cpu` (burn's CPU backend, where the two
//! are the same code), `gpu` (a `gpu-torch` build: libtorch on CUDA), or
//! `torch-cpu` (a `gpu-torch` build: libtorch's CPU device, the host's
//! cost of a libtorch step measured without a GPU). Each step is timed
//! from a finished GPU to a finished GPU (one value read back); the
//! gradients it takes are made before the clock starts. Medians of
//! `AFX_REPEATS` steps (default 50) after 5 unmeasured ones.

use std::time::Instant;

use burn::module::{Module, ModuleVisitor, Param};
use burn::optim::decay::WeightDecayConfig;
use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use burn::prelude::*;
use nets::policy::PolicyNet;
use nets::unet::AffordanceUnet;
use training::adam::{Adam, AdamSettings};

/// One-element stand-ins for a network's parameters.
#[derive(Module, Debug)]
struct Stand {
    params: Vec<Param<Tensor<1>>>,
}

/// The sum of every parameter, as one tensor: its gradient is 1 everywhere.
struct SumAll(Option<Tensor<1>>);

impl ModuleVisitor for SumAll {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        let sum = param.val().sum();
        self.0 = Some(match self.0.take() {
            Some(total) => total + sum,
            None => sum,
        });
    }
}

/// The sum of the first parameter visited.
struct SumFirst(Option<Tensor<1>>);

impl ModuleVisitor for SumFirst {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if self.0.is_none() {
            self.0 = Some(param.val().sum());
        }
    }
}

/// Counts a module's parameter tensors.
struct Count(usize);

impl ModuleVisitor for Count {
    fn visit_float<const D: usize>(&mut self, _: &Param<Tensor<D>>) {
        self.0 += 1;
    }
}

/// Waits for the device: one value made of the first parameter read back.
fn finish<M: Module>(module: &M) {
    let mut sum = SumFirst(None);
    module.visit(&mut sum);
    let _ = sum.0.expect("a parameter").into_scalar::<f32>();
}

/// Median milliseconds of one step of `optimizer` over `module`.
fn time_steps<M: Module + Clone>(
    mut module: M,
    optimizer: &mut ModuleOptimizer,
    repeats: usize,
) -> f64 {
    let mut times = Vec::new();
    for k in 0..repeats + 5 {
        let mut sum = SumAll(None);
        module.visit(&mut sum);
        let grads = GradientsParams::from_grads(sum.0.expect("a parameter").backward(), &module);
        finish(&module);
        let started = Instant::now();
        module = optimizer.step(1e-3, module, grads);
        finish(&module);
        if k >= 5 {
            times.push(started.elapsed().as_secs_f64() * 1e3);
        }
    }
    times.sort_by(f64::total_cmp);
    times[times.len() / 2]
}

/// One row: burn's Adam and ours over `module`, alternated three times.
fn row<M: Module + Clone>(name: &str, module: M, settings: AdamSettings, repeats: usize) {
    let mut count = Count(0);
    module.visit(&mut count);
    let burns = || {
        ModuleOptimizer::from(
            AdamConfig::new()
                .with_epsilon(settings.epsilon)
                .with_weight_decay(settings.weight_decay.map(WeightDecayConfig::new))
                .build(),
        )
    };
    let (mut burn_ms, mut ours_ms) = (Vec::new(), Vec::new());
    for _ in 0..3 {
        burn_ms.push(time_steps(module.clone(), &mut burns(), repeats));
        ours_ms.push(time_steps(
            module.clone(),
            &mut Adam::for_module(settings),
            repeats,
        ));
    }
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[1]
    };
    let (burn_ms, ours_ms) = (median(burn_ms), median(ours_ms));
    println!(
        "| {name} | {} / {} | {burn_ms:.3} ms | {ours_ms:.3} ms | {:.2} |",
        count.0,
        module.num_params(),
        ours_ms / burn_ms
    );
}

#[allow(deprecated)] // libtorch's CPU device, for `torch-cpu` (decision 0010)
fn device() -> Device {
    match std::env::var("AFX_DEVICE").as_deref() {
        Ok("torch-cpu") => {
            #[cfg(feature = "gpu-torch")]
            return Device::libtorch();
            #[cfg(not(feature = "gpu-torch"))]
            panic!("AFX_DEVICE=torch-cpu needs a build with --features gpu-torch");
        }
        Ok(choice) => {
            nets::device::open_device(choice.parse().expect("AFX_DEVICE: cpu, gpu or torch-cpu"))
                .expect("AFX_DEVICE's device opens")
        }
        Err(_) => Device::flex(),
    }
}

fn main() {
    if std::env::args().any(|a| a == "--list") {
        return; // `cargo test --benches` asks benches to list themselves
    }
    let device = device().autodiff();
    let repeats: usize = std::env::var("AFX_REPEATS")
        .map_or(50, |s| s.parse().expect("AFX_REPEATS: a number of steps"));
    println!("Adam steps on {device:?}, medians of {repeats} (of three alternated runs):");
    println!("| parameters | tensors / floats | burn's Adam | ours | ours / burn's |");
    println!("|---|---|---|---|---|");
    // The trainers' settings: the U-Net's weight decay, PPO's epsilon.
    let unet_settings = AdamSettings {
        weight_decay: Some(1e-4),
        ..AdamSettings::default()
    };
    let unet = AffordanceUnet::new(4, 2, &device);
    row("U-Net", unet.clone(), unet_settings, repeats);
    let layout = proto::TaskSpec {
        image_size: 128,
        ..proto::TaskSpec::default()
    }
    .layout();
    let ppo_settings = AdamSettings {
        epsilon: 1e-5,
        ..AdamSettings::default()
    };
    row(
        "policy, `ours` at 128 px",
        PolicyNet::new(&layout, &device),
        ppo_settings,
        repeats,
    );
    let mut count = Count(0);
    unet.visit(&mut count);
    let stand = Stand {
        params: (0..count.0)
            .map(|_| Param::from_tensor(Tensor::ones([1], &device)))
            .collect(),
    };
    row(
        "the U-Net's, one element each",
        stand,
        unet_settings,
        repeats,
    );
}
