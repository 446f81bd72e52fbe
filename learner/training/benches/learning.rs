//! `cargo bench -p training`: the learning core's costs on this machine, side
//! by side with the same networks in PyTorch (`benches/torch_reference.py`)
//! when `python3` has `torch`.
//!
//! - U-Net training step, batch 8 of 128 × 128 RGB-D, and single-frame
//!   inference, with burn and through the actor's CPU path (`nets::unet_cpu`,
//!   one thread, against PyTorch on one thread);
//! - one PPO update on 8 × 600 steps (4 epochs × 2 minibatches), and one at
//!   the learner's defaults: 128 steps of 64 × 64 observations;
//! - policy inference for one step.
//!
//! Medians over a few repeats (these steps take seconds on a CPU, so this is
//! a plain timing harness rather than criterion). `AFX_BENCH_QUICK=1` runs
//! one repeat and a 2 × 600-step PPO batch, for a smoke test;
//! `AFX_BENCH_ONLY=ppo-default` runs only the PPO update at the learner's
//! defaults (128 steps of 64 × 64 observations; `AFX_BENCH_PPO_STEPS=N` for
//! another `[policy] batch_steps`), `AFX_BENCH_ONLY=unet-train` only the
//! U-Net training step.
//!
//! `AFX_DEVICE=gpu` (a build with `--features nets/gpu`) runs everything on
//! the GPU and the PyTorch reference with `--device cuda`.
//! `AFX_BENCH_ONLY=temperature` times refitting a replaced U-Net's temperature
//! on a 128-px gate's pixels, binned as the learner fits it and over every
//! pixel. `AFX_BENCH_ONLY=gpu-check` runs the learner's real training shapes side by
//! side with PyTorch: one PPO update of 1 024 steps (`AFX_BENCH_PPO_STEPS`) of
//! the default `ours` task's observations at 64 and 128 px, 4 epochs × 2
//! minibatches, and the U-Net training step (batch 8, 128 px).
//! `AFX_BENCH_SIDES=64` limits the PPO update to the sides listed. It times
//! 15 repeats of each (5 in the quick mode; `AFX_BENCH_REPEATS=N`) and prints
//! each figure's median with its 10th and 90th percentiles, and each ratio to
//! PyTorch with the range the two spreads allow: a range that holds 1.0 does
//! not tell the two apart.
//! `AFX_POLICY_CONV` (`auto`, `burn`, `batch`, `image`) chooses how the
//! policy's encoders compute their convolutions (`nets::policy::ConvPath`);
//! `AFX_TORCH_REFERENCE=none` skips PyTorch.

use std::time::Instant;

use burn::prelude::*;
use nets::policy::{CpuPolicy, ObsDtype, PolicyInput, PolicyLayout, PolicyNet};
use nets::unet::AffordanceUnet;
use nets::unet_cpu::CpuUnet;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use training::affordance::{LabelledFrame, UnetTrainer, UnetTrainingConfig};
use training::ppo::{Ppo, PpoBatch, PpoConfig};

/// The policy of the benchmark: three image-like inputs (RGB-D, a 4-channel
/// map projection, 2 affordance maps), an action history of 5 × (8 + 2) and an
/// inventory flag; 8 actions.
fn policy_config() -> PolicyLayout {
    policy_config_at(128)
}

/// [`policy_config`] with images of `side` × `side`.
fn policy_config_at(side: usize) -> PolicyLayout {
    PolicyLayout {
        image_channels: vec![4, 4, 2],
        image_size: side,
        vector_dims: vec![50, 1],
        n_actions: 8,
        obs_dtype: ObsDtype::F32,
        gru_hidden: None,
    }
}

/// Whether `AFX_BENCH_QUICK` asks for the quick mode (set and not empty).
fn quick_mode() -> bool {
    std::env::var("AFX_BENCH_QUICK").is_ok_and(|v| !v.is_empty())
}

/// One measurement's repeats, milliseconds, sorted: its median and the
/// spread between its 10th and 90th percentiles (the extremes for fewer than
/// ten repeats), so that two figures can be told apart or not.
#[derive(Debug, Clone)]
struct Timing(Vec<f64>);

impl Timing {
    fn quantile(&self, q: f64) -> f64 {
        let i = (q * (self.0.len() - 1) as f64).round() as usize;
        self.0[i]
    }

    fn median(&self) -> f64 {
        self.quantile(0.5)
    }

    /// The 10th and 90th percentiles.
    fn spread(&self) -> (f64, f64) {
        (self.quantile(0.1), self.quantile(0.9))
    }
}

/// Times `f` `repeats` times after a warm-up call.
fn time(repeats: usize, mut f: impl FnMut()) -> Timing {
    f();
    let mut samples: Vec<f64> = (0..repeats.max(1))
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    samples.sort_by(f64::total_cmp);
    Timing(samples)
}

fn random_input(rows: usize, rng: &mut StdRng, device: &Device) -> PolicyInput {
    random_input_at(&policy_config(), rows, rng, device)
}

fn random_input_at(
    c: &PolicyLayout,
    rows: usize,
    rng: &mut StdRng,
    device: &Device,
) -> PolicyInput {
    let side = c.image_size;
    let mut floats = |n: usize| -> Vec<f32> { (0..n).map(|_| rng.random::<f32>()).collect() };
    PolicyInput {
        images: c
            .image_channels
            .iter()
            .map(|&ch| {
                Tensor::<1>::from_floats(floats(rows * ch * side * side).as_slice(), device)
                    .reshape([rows, ch, side, side])
            })
            .collect(),
        vectors: c
            .vector_dims
            .iter()
            .map(|&d| {
                Tensor::<1>::from_floats(floats(rows * d).as_slice(), device).reshape([rows, d])
            })
            .collect(),
        mask: Tensor::<2, Bool>::full([rows, c.n_actions], true, device),
    }
}

/// `rows` steps of random observations, actions and returns.
fn ppo_batch(layout: &PolicyLayout, rows: usize, rng: &mut StdRng, device: &Device) -> PpoBatch {
    PpoBatch {
        input: random_input_at(layout, rows, rng, device),
        actions: (0..rows).map(|_| rng.random_range(0..8)).collect(),
        behaviour_log_probs: vec![-(8f32.ln()); rows],
        values: (0..rows).map(|_| rng.random::<f32>()).collect(),
        advantages: (0..rows).map(|_| rng.random::<f32>() - 0.5).collect(),
        returns: (0..rows).map(|_| rng.random::<f32>()).collect(),
        policy_versions: vec![0; rows],
        sequences: None,
    }
}

/// Steps of the PPO update at the learner's defaults: `AFX_BENCH_PPO_STEPS`,
/// else the learner's `[policy] batch_steps` (128).
fn learner_batch_steps() -> usize {
    std::env::var("AFX_BENCH_PPO_STEPS").map_or(128, |s| {
        s.trim()
            .parse()
            .ok()
            .filter(|&n: &usize| n >= 2)
            .expect("AFX_BENCH_PPO_STEPS: at least 2 steps")
    })
}

/// One PPO update at the learner's defaults (`[policy]`: 128 steps an
/// update unless `AFX_BENCH_PPO_STEPS` says otherwise, 4 epochs × 2
/// minibatches) on 64 × 64 images, the size a 2-core machine trains at
/// (`deploy/local.sh --image-size 64`).
fn ppo_update_at_learner_defaults(repeats: usize, rng: &mut StdRng, device: &Device) -> Timing {
    let layout = policy_config_at(64);
    let batch = ppo_batch(&layout, learner_batch_steps(), rng, device);
    let mut ppo = Ppo::new(
        PolicyNet::new(&layout, device),
        PpoConfig::default(),
        device,
    );
    time(repeats, || {
        ppo.update(&batch, rng);
    })
}

/// The device `AFX_DEVICE` names (`cpu` unless it says `gpu`).
fn bench_device() -> (Device, bool) {
    let choice = std::env::var("AFX_DEVICE").unwrap_or_else(|_| "cpu".into());
    let choice: nets::device::DeviceChoice = choice.parse().unwrap_or_else(|e| {
        eprintln!("AFX_DEVICE: {e}");
        std::process::exit(2);
    });
    let device = nets::device::open_device(choice).unwrap_or_else(|e| {
        eprintln!("AFX_DEVICE: {e}");
        std::process::exit(2);
    });
    (device, choice == nets::device::DeviceChoice::Gpu)
}

/// The policy of the default `ours` task (both affordances) at `side` px.
fn ours_layout(side: usize) -> PolicyLayout {
    proto::TaskSpec {
        image_size: side,
        ..proto::TaskSpec::default()
    }
    .layout()
}

/// The learner's training shapes (see the module's doc), with PyTorch's
/// figures beside them.
fn gpu_check(device: &Device, gpu: bool, rng: &mut StdRng) {
    let quick = quick_mode();
    // Enough repeats that the spread says whether two figures differ (two
    // repeats swung 1.7x between calls of one binary on an H200).
    let repeats = std::env::var("AFX_BENCH_REPEATS")
        .ok()
        .and_then(|s| s.trim().parse::<usize>().ok())
        .filter(|&n| n >= 1)
        .unwrap_or(if quick { 5 } else { 15 });
    let steps = std::env::var("AFX_BENCH_PPO_STEPS")
        .ok()
        .and_then(|s| s.trim().parse::<usize>().ok())
        .filter(|&n| n >= 2)
        .unwrap_or(1024);
    let sides: Vec<usize> = std::env::var("AFX_BENCH_SIDES").map_or(vec![64, 128], |s| {
        s.split(',')
            .map(|v| {
                v.trim()
                    .parse()
                    .expect("AFX_BENCH_SIDES: sides like 64,128")
            })
            .collect()
    });
    let mut results: Vec<(String, Timing)> = Vec::new();
    for side in sides {
        let layout = ours_layout(side);
        let batch = ppo_batch(&layout, steps, rng, device);
        let mut ppo = Ppo::new(
            PolicyNet::new(&layout, device),
            PpoConfig::default(),
            device,
        );
        let ms = time(repeats, || {
            ppo.update(&batch, rng);
        });
        eprintln!(
            "  ppo_update_{steps}_{side}px_ms: median {:.1} ms",
            ms.median()
        );
        results.push((format!("ppo_update_{steps}_{side}px_ms"), ms));
    }
    let frames = unet_frames(rng);
    let refs: Vec<&LabelledFrame> = frames.iter().collect();
    let mut trainer = UnetTrainer::new(
        AffordanceUnet::new(4, 2, device),
        // The PyTorch reference computes the paper's loss (every labelled
        // pixel alike): the same work on both sides.
        UnetTrainingConfig {
            class_balance: nets::unet::ClassBalance::Pixels,
            ..UnetTrainingConfig::default()
        },
        device,
    );
    results.push((
        "unet_train_step_batch8_ms".into(),
        time(repeats.max(5), || {
            trainer.step(&refs);
        }),
    ));
    let named: Vec<(&str, Timing)> = results
        .iter()
        .map(|(n, v)| (n.as_str(), v.clone()))
        .collect();
    print_results(&named, gpu);
    let layout = ours_layout(64);
    let list = |v: &[usize]| v.iter().map(usize::to_string).collect::<Vec<_>>().join(",");
    compare_with_torch(
        &named,
        &[
            "--gpu-check".into(),
            "--ppo-steps".into(),
            steps.to_string(),
            "--image-channels".into(),
            list(&layout.image_channels),
            "--vector-dims".into(),
            list(&layout.vector_dims),
            "--actions".into(),
            layout.n_actions.to_string(),
            "--repeats".into(),
            repeats.to_string(),
            "--device".into(),
            if gpu { "cuda" } else { "cpu" }.into(),
        ],
    );
}

/// Eight labelled 128 × 128 frames of random RGB-D and labels.
fn unet_frames(rng: &mut StdRng) -> Vec<LabelledFrame> {
    (0..8)
        .map(|_| LabelledFrame {
            size: [128, 128],
            rgbd: (0..4 * 128 * 128).map(|_| rng.random::<f32>()).collect(),
            labels: (0..2 * 128 * 128)
                .map(|_| [0u8, 1, 255][rng.random_range(0..3)])
                .collect(),
        })
        .collect()
}

fn main() {
    if std::env::args().any(|a| a == "--list") {
        return; // `cargo test --benches` asks benches to list themselves
    }
    let quick = quick_mode();
    let repeats = if quick { 1 } else { 5 };
    let (device, gpu) = bench_device();
    let mut rng = StdRng::seed_from_u64(1);
    let mut results: Vec<(&str, Timing)> = Vec::new();

    let only = std::env::var("AFX_BENCH_ONLY").ok();
    if only.as_deref() == Some("temperature") {
        temperature_fit(&mut rng);
        return;
    }
    if only.as_deref() == Some("gpu-check") {
        gpu_check(&device, gpu, &mut rng);
        return;
    }
    if only
        .as_deref()
        .is_some_and(|o| o != "ppo-default" && o != "unet-train")
    {
        eprintln!("AFX_BENCH_ONLY takes ppo-default, unet-train, gpu-check or temperature");
        std::process::exit(2);
    }
    if only.as_deref() != Some("unet-train") {
        results.push((
            "ppo_update_learner_batch_64px_ms",
            ppo_update_at_learner_defaults(repeats.max(5), &mut rng, &device),
        ));
    }
    if only.as_deref() == Some("ppo-default") {
        print_results(&results, gpu);
        return;
    }

    // U-Net.
    let frames = unet_frames(&mut rng);
    let refs: Vec<&LabelledFrame> = frames.iter().collect();
    // The PyTorch reference computes the paper's loss (every labelled pixel
    // alike): the same work on both sides.
    let settings = UnetTrainingConfig {
        class_balance: nets::unet::ClassBalance::Pixels,
        ..UnetTrainingConfig::default()
    };
    let mut trainer = UnetTrainer::new(AffordanceUnet::new(4, 2, &device), settings, &device);
    results.push((
        "unet_train_step_batch8_ms",
        time(repeats, || {
            trainer.step(&refs);
        }),
    ));
    // The same step with a batch normalisation after each 3 × 3
    // convolution (`[unet] batch_norm`), in the same run.
    let mut normalised = UnetTrainer::new(
        AffordanceUnet::new(4, 2, &device).with_batch_norm(),
        settings,
        &device,
    );
    results.push((
        "unet_train_step_batch_norm_batch8_ms",
        time(repeats, || {
            normalised.step(&refs);
        }),
    ));
    if only.is_some() {
        print_results(&results, gpu);
        return;
    }
    let unet = trainer.inference_net(&device);
    let one =
        Tensor::<1>::from_floats(frames[0].rgbd.as_slice(), &device).reshape([1, 4, 128, 128]);
    results.push((
        "unet_inference_1frame_ms",
        time(repeats.max(5), || {
            let _: Vec<f32> = unet.forward(one.clone()).into_data().try_to_vec().unwrap();
        }),
    ));
    // The same network through the actor's CPU path (`nets::unet_cpu`).
    let cpu_path = CpuUnet::from_network(&unet);
    results.push((
        "unet_inference_1frame_cpu_path_ms",
        time(repeats.max(5), || {
            cpu_path.forward(&frames[0].rgbd, 128, 128);
        }),
    ));

    // Policy inference, one step.
    let policy = PolicyNet::new(&policy_config(), &device);
    let step_input = random_input(1, &mut rng, &device);
    results.push((
        "policy_inference_1step_ms",
        time(repeats.max(5), || {
            let _: Vec<f32> = policy
                .forward(&step_input, None)
                .log_probs
                .into_data()
                .try_to_vec()
                .unwrap();
        }),
    ));

    // The same policy through the actor's CPU path (`nets::policy::CpuPolicy`).
    let layout = policy_config();
    let cpu_policy = CpuPolicy::from_network(&policy, &layout).expect("a policy without a GRU");
    let observation: Vec<f32> = (0..layout.obs_len()).map(|_| rng.random::<f32>()).collect();
    let mask = vec![1u8; layout.n_actions];
    results.push((
        "policy_inference_1step_cpu_path_ms",
        time(repeats.max(5), || {
            std::hint::black_box(cpu_policy.forward(&observation, &mask, None));
        }),
    ));

    // The methods without a map: the same inputs into a GRU of the default
    // `task.memory_size`, both passes, from a running state.
    let memory = 512;
    let gru_layout = PolicyLayout {
        gru_hidden: Some(memory),
        ..policy_config()
    };
    let gru_policy = PolicyNet::new(&gru_layout, &device);
    let state: Vec<f32> = (0..memory).map(|_| rng.random::<f32>() - 0.5).collect();
    let state_tensor = Tensor::<1>::from_floats(state.as_slice(), &device).reshape([1, memory]);
    results.push((
        "policy_gru_inference_1step_ms",
        time(repeats.max(5), || {
            let _: Vec<f32> = gru_policy
                .forward(&step_input, Some(state_tensor.clone()))
                .log_probs
                .into_data()
                .try_to_vec()
                .unwrap();
        }),
    ));
    let cpu_gru_policy =
        CpuPolicy::from_network(&gru_policy, &gru_layout).expect("burn's GRU as built");
    results.push((
        "policy_gru_inference_1step_cpu_path_ms",
        time(repeats.max(5), || {
            std::hint::black_box(cpu_gru_policy.forward(&observation, &mask, Some(&state)));
        }),
    ));

    // PPO update on envs × 600 steps.
    let envs = if quick { 2 } else { 8 };
    let rows = envs * 600;
    let batch = ppo_batch(&policy_config(), rows, &mut rng, &device);
    let mut ppo = Ppo::new(policy, PpoConfig::default(), &device);
    let ppo_repeats = 1; // one warm-up, one timed: an update takes minutes on a CPU
    let name = if quick {
        "ppo_update_2x600_ms"
    } else {
        "ppo_update_8x600_ms"
    };
    results.push((
        name,
        time(ppo_repeats, || {
            ppo.update(&batch, &mut rng);
        }),
    ));

    print_results(&results, gpu);
    compare_with_torch(
        &results,
        &[
            "--envs".into(),
            envs.to_string(),
            "--repeats".into(),
            repeats.to_string(),
            "--device".into(),
            if gpu { "cuda" } else { "cpu" }.into(),
        ],
    );
}

/// Refitting a replaced U-Net's temperature on a gate's labelled pixels at
/// 128 px (64 frames × 2 planes, every pixel labelled, 1 % positive, the
/// classes weighing half each): the learner's binned fit beside the search
/// over every pixel, alternated, with the two temperatures.
fn temperature_fit(rng: &mut StdRng) {
    use training::temperature::{fit_weighted_temperature, fit_weighted_temperature_exact};
    let n = 64 * 2 * 128 * 128;
    let labels: Vec<bool> = (0..n).map(|_| rng.random::<f32>() < 0.01).collect();
    let logits: Vec<f32> = labels
        .iter()
        .map(|&y| rng.random_range(-12.0..4.0) + if y { 5.0 } else { 0.0 })
        .collect();
    let positives = labels.iter().filter(|&&y| y).count() as f32;
    let weights: Vec<f32> = labels
        .iter()
        .map(|&y| {
            if y {
                0.5 / positives
            } else {
                0.5 / (n as f32 - positives)
            }
        })
        .collect();
    let repeats = if quick_mode() { 1 } else { 5 };
    let (mut binned, mut exact) = (Vec::new(), Vec::new());
    let (mut t_binned, mut t_exact) = (0.0, 0.0);
    for _ in 0..repeats {
        let started = Instant::now();
        t_binned = fit_weighted_temperature(&logits, &labels, &weights);
        binned.push(started.elapsed().as_secs_f64() * 1e3);
        let started = Instant::now();
        t_exact = fit_weighted_temperature_exact(&logits, &labels, &weights);
        exact.push(started.elapsed().as_secs_f64() * 1e3);
    }
    binned.sort_by(f64::total_cmp);
    exact.sort_by(f64::total_cmp);
    let (binned, exact) = (Timing(binned), Timing(exact));
    println!(
        "temperature fit, {n} labelled pixels: binned {:.1} ms (T {t_binned:.4}), every pixel {:.1} ms (T {t_exact:.4}), medians of {repeats}; ratio {:.4}",
        binned.median(),
        exact.median(),
        binned.median() / exact.median()
    );
}

/// Prints each measurement's median and spread.
fn print_results(results: &[(&str, Timing)], gpu: bool) {
    let backend = if gpu { "wgpu (GPU)" } else { "flex (CPU)" };
    println!(
        "burn 0.22.1 {backend}, {} CPU threads available, features: {}:",
        std::thread::available_parallelism().map_or(1, |n| n.get()),
        nets::device::backend_features()
    );
    for (name, timing) in results {
        let (low, high) = timing.spread();
        println!(
            "  {name}: median {:.1} ms [p10 {low:.1}, p90 {high:.1}] of {}",
            timing.median(),
            timing.0.len()
        );
    }
}

/// A reference line's median and spread: `name: median M ms [p10 L, p90 H] of N`
/// (or without the spread, as older references print).
fn reference(text: &str, name: &str) -> Option<(f64, f64, f64)> {
    let line = text
        .lines()
        .find(|l| l.trim_start().starts_with(&format!("{name}:")))?;
    let number = |after: &str| -> Option<f64> {
        line.split(after)
            .nth(1)?
            .split([' ', ',', ']'])
            .next()?
            .parse()
            .ok()
    };
    let median = number("median ")?;
    Some((
        median,
        number("p10 ").unwrap_or(median),
        number("p90 ").unwrap_or(median),
    ))
}

/// Runs the PyTorch reference with `args` and prints ours / theirs per
/// measurement: the ratio of the medians, and the range of ratios the two
/// spreads allow (ours at its 10th percentile against theirs at its 90th, and
/// the other way): a ratio whose range holds 1.0 does not tell the two apart.
/// `AFX_TORCH_REFERENCE` names the script where the bench runs away from its
/// source tree (a GPU machine with the binary alone).
fn compare_with_torch(ours: &[(&str, Timing)], args: &[String]) {
    if std::env::var_os("AFX_TORCH_REFERENCE").is_some_and(|v| v == "none") {
        return;
    }
    let script = std::env::var_os("AFX_TORCH_REFERENCE").map_or_else(
        || std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/torch_reference.py"),
        std::path::PathBuf::from,
    );
    let output = std::process::Command::new("python3")
        .arg(&script)
        .args(args)
        .output();
    let text = match output {
        Ok(o) if o.status.success() => String::from_utf8_lossy(&o.stdout).into_owned(),
        Ok(o) => {
            println!(
                "pytorch comparison skipped: {}",
                String::from_utf8_lossy(&o.stderr).trim()
            );
            return;
        }
        Err(e) => {
            println!("pytorch comparison skipped: cannot run python3: {e}");
            return;
        }
    };
    print!("{text}");
    for (name, timing) in ours {
        // The CPU path runs on one thread: PyTorch on one thread is its peer.
        let Some((theirs, their_low, their_high)) =
            reference(&text, &name.replace("_cpu_path", "_1thread"))
        else {
            continue;
        };
        let ms = timing.median();
        let (low, high) = timing.spread();
        println!(
            "  ours / pytorch, {name}: {ms:.1} / {theirs:.1} = {:.2} [{:.2}, {:.2}]",
            ms / theirs,
            low / their_high,
            high / their_low
        );
    }
}
