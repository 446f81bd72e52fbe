//! Simulator step + render throughput: a scripted 1 000-step episode in a
//! test scene (FloorPlan227, randomised), five times per renderer, median
//! steps/s and where the time goes. One core: lavapipe is limited to one
//! rasteriser thread (`LP_NUM_THREADS=1`) unless the caller sets it.
//!
//! `cargo bench -p sim --bench steps`

use std::time::{Duration, Instant};

use rand::rngs::StdRng;
use rand::SeedableRng;
use sim::ithor::load_scene;
use sim::profile::RobotProfile;
use sim::randomise::randomise;
use sim::renderer::{Renderer, RendererChoice};
use sim::script::Script;

const STEPS: usize = 1000;
const RUNS: usize = 5;

/// One episode: total, simulation and rendering time.
fn episode(renderer: &mut Renderer) -> (Duration, Duration, Duration) {
    let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/ithor-livingrooms");
    let scene = load_scene(&dir.join("FloorPlan227.json")).expect("the test scene loads");
    let profile = RobotProfile::load("default").expect("the default profile loads");
    let (mut sim, _) =
        randomise(&scene, &profile, 128, &mut StdRng::seed_from_u64(3)).expect("randomises");
    let mut script = Script::new(7);
    let mut frame = sim.render(renderer).expect("renders");
    let (mut stepping, mut rendering) = (Duration::ZERO, Duration::ZERO);
    let start = Instant::now();
    for _ in 0..STEPS {
        let t0 = Instant::now();
        let action = script.next(&sim, &frame);
        sim.apply(action);
        let t1 = Instant::now();
        frame = sim.render(renderer).expect("renders");
        stepping += t1 - t0;
        rendering += t1.elapsed();
    }
    (start.elapsed(), stepping, rendering)
}

fn median(mut xs: Vec<f64>) -> f64 {
    xs.sort_by(f64::total_cmp);
    xs[xs.len() / 2]
}

fn main() {
    if std::env::var_os("LP_NUM_THREADS").is_none() {
        std::env::set_var("LP_NUM_THREADS", "1");
    }
    for choice in [RendererChoice::Cpu, RendererChoice::Gpu] {
        let mut renderer = match Renderer::open(choice) {
            Ok(r) => r,
            Err(e) => {
                println!("{choice:?}: skipped: {e}");
                continue;
            }
        };
        let runs: Vec<_> = (0..RUNS).map(|_| episode(&mut renderer)).collect();
        let per_step_ms = |d: Duration| d.as_secs_f64() * 1e3 / STEPS as f64;
        println!(
            "{:<40} {STEPS} steps × {RUNS}: median {:>7.1} steps/s (step {:.3} ms, render {:.3} ms per step)",
            renderer.describe(),
            median(runs.iter().map(|r| STEPS as f64 / r.0.as_secs_f64()).collect()),
            median(runs.iter().map(|r| per_step_ms(r.1)).collect()),
            median(runs.iter().map(|r| per_step_ms(r.2)).collect()),
        );
    }
}
