//! End-to-end environment steps/s on one actor, state building included,
//! and where the time goes (simulator, render, map, U-Net, state), per
//! method, image size and renderer; the episode's reset (room randomised,
//! ground truth decided with push physics) is timed apart. A 120-step
//! episode in FloorPlan227 with random allowed actions (half of them
//! interactions when any is allowed).
//! The policy's forward pass is not part of the environment; its time is
//! measured by `cargo bench -p training` (policy inference, one step).
//!
//! `cargo bench -p actor --bench env_steps`
//!
//! `AFX_DEVICE=gpu` runs the U-Net on the GPU (a build with
//! `--features nets/gpu`); `AFX_DATA` points at the shared data directory
//! (default `../shared/data` beside the repository), for running the bench
//! binary on another machine.

use std::time::{Duration, Instant};

use actor::env::actions::random_allowed_action;
use actor::env::affordance_model::AffordanceModel;
use actor::env::sim_env::{SimEnv, SimEnvConfig, StepTimings};
use mapper::Affordance;
use proto::Method;
use rand::rngs::StdRng;
use rand::SeedableRng;
use sim::ithor::SceneSet;
use sim::profile::RobotProfile;
use sim::renderer::{Renderer, RendererChoice};
use sim::scenes::SceneSource;

const STEPS: usize = 120;
const AFFORDANCES: [Affordance; 2] = [Affordance::PickUp, Affordance::Push];

fn median(mut xs: Vec<Duration>) -> Duration {
    xs.sort();
    xs[xs.len() / 2]
}

/// One configuration of the table.
struct Case {
    method: Method,
    image_size: usize,
    renderer: RendererChoice,
}

fn main() {
    if std::env::var_os("LP_NUM_THREADS").is_none() {
        std::env::set_var("LP_NUM_THREADS", "1");
    }
    let data = std::env::var_os("AFX_DATA").map_or_else(
        || std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data"),
        std::path::PathBuf::from,
    );
    let choice: nets::device::DeviceChoice = std::env::var("AFX_DEVICE")
        .unwrap_or_else(|_| "cpu".into())
        .parse()
        .expect("AFX_DEVICE: cpu or gpu");
    let device = nets::device::open_device(choice).expect("the U-Net's device (AFX_DEVICE)");
    println!("U-Net on {choice:?}; data from {}", data.display());
    let case = |method, image_size, renderer| Case {
        method,
        image_size,
        renderer,
    };
    let cases = [
        case(Method::Ours, 128, RendererChoice::Gpu),
        case(Method::Ours, 128, RendererChoice::Cpu),
        case(Method::Ours, 64, RendererChoice::Cpu),
        case(Method::NomapSeg, 128, RendererChoice::Cpu),
        case(Method::NomapSeg, 64, RendererChoice::Cpu),
        case(Method::Intexp, 64, RendererChoice::Cpu),
    ];
    println!("| method | px | renderer | steps/s | reset | sim | render | map | U-Net | state |");
    println!("|---|---|---|---|---|---|---|---|---|---|");
    for Case {
        method,
        image_size,
        renderer: choice,
    } in cases
    {
        let renderer = match Renderer::open(choice) {
            Ok(r) => r,
            Err(e) => {
                println!("{choice:?}: skipped: {e}");
                continue;
            }
        };
        let name = renderer.describe();
        let mut profile = RobotProfile::load("default").expect("profile");
        profile.image_size = image_size;
        let source = SceneSource::open(
            Some(&data.join("ithor-livingrooms")),
            SceneSet::Test,
            &data.join("ithor-object-types.tsv"),
            &profile,
        )
        .expect("scenes");
        let config = SimEnvConfig {
            episode_steps: STEPS,
            ..SimEnvConfig::paper(method, &AFFORDANCES)
        };
        let model = AffordanceModel::new(AFFORDANCES.len(), &device);
        let mut env = SimEnv::new(config, source, profile, renderer);
        let mut rng = StdRng::seed_from_u64(1);
        let reset_started = Instant::now();
        let mut observation = env.reset(1, &model).expect("reset");
        let reset = reset_started.elapsed();
        let mut stages: Vec<StepTimings> = Vec::with_capacity(STEPS);
        let start = Instant::now();
        for _ in 0..STEPS {
            let action =
                random_allowed_action(env.action_space(), &observation.mask, 0.5, &mut rng);
            observation = env.step(action, &model).expect("step").observation;
            stages.push(env.last_timings());
        }
        let elapsed = start.elapsed();
        let ms = |f: fn(&StepTimings) -> Duration| {
            median(stages.iter().map(f).collect()).as_secs_f64() * 1e3
        };
        println!(
            "| {} | {image_size} | {name} | {:.1} | {:.0} ms | {:.2} ms | {:.2} ms | {:.2} ms | {:.1} ms | {:.2} ms |",
            method.as_str(),
            STEPS as f64 / elapsed.as_secs_f64(),
            reset.as_secs_f64() * 1e3,
            ms(|t| t.sim),
            ms(|t| t.render),
            ms(|t| t.map),
            ms(|t| t.unet),
            ms(|t| t.state),
        );
    }
}
