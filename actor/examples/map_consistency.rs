//! How well the map keeps its objects' ids, episode by episode: the check
//! to run before and after any change to tracking or re-identification
//! (`mapper::icp`, `mapper::map::track`, `mapper::map::reidentify`).
//!
//! Runs one `ours` episode per seed in the training rooms (FloorPlan201–220:
//! mapper settings are never chosen on validation or test rooms), acting
//! with random allowed actions (interactions at `--interact-bias`), and
//! prints per episode the map id consistency (the share of the objects'
//! pixels that carry their object's most common map id,
//! [`actor::frame_scores::map_id_consistency`]), the share of actions that
//! interacted, and the map's mean and longest time per step. A change that
//! finds fewer lost objects again, or hands one object's id to another,
//! lowers the consistency; single seeds are noisy (an episode parts from
//! its old course at its first different decision), so compare the mean
//! over several seeds.
//!
//! ```text
//! cargo run --release -p actor --example map_consistency -- --seeds 1-6
//! ```

use std::path::PathBuf;
use std::time::{Duration, Instant};

use actor::env::actions::{random_allowed_action, PolicyAction};
use actor::env::affordance_model::AffordanceModel;
use actor::env::sim_env::{SimEnv, SimEnvConfig};
use anyhow::{bail, Context};
use clap::Parser;
use mapper::Affordance;
use proto::{Method, StatField, StatKey};
use rand::rngs::StdRng;
use rand::SeedableRng;
use sim::ithor::SceneSet;
use sim::profile::RobotProfile;
use sim::renderer::{Renderer, RendererChoice};
use sim::scenes::SceneSource;

/// The affordances the paper's `ours` learns.
const AFFORDANCES: [Affordance; 2] = [Affordance::PickUp, Affordance::Push];

#[derive(Parser)]
#[command(about = "Map id consistency of `ours` episodes in the training rooms, one per seed")]
struct Args {
    /// Seeds, one episode each: a range (`1-6`) or a comma-separated list.
    #[arg(long, default_value = "1-6")]
    seeds: String,
    /// Steps per episode.
    #[arg(long, default_value_t = 600)]
    steps: usize,
    /// Image side in pixels (a multiple of 8).
    #[arg(long, default_value_t = 128)]
    image_size: usize,
    /// Probability that a random action is an interaction where one is allowed.
    #[arg(long, default_value_t = 0.5)]
    interact_bias: f64,
    /// Shared data directory with ithor-livingrooms/ and ithor-object-types.tsv.
    #[arg(long, env = "AFX_DATA", default_value = "../shared/data")]
    data: PathBuf,
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    let seeds = parse_seeds(&args.seeds)?;
    if args.steps < 2 {
        bail!("--steps {}: an episode needs at least 2 steps", args.steps);
    }
    if args.image_size == 0 || !args.image_size.is_multiple_of(8) {
        bail!("--image-size {}: a positive multiple of 8", args.image_size);
    }
    let device = nets::device::open_device(nets::device::DeviceChoice::Cpu)
        .context("opening the CPU device for the U-Net")?;
    let model = AffordanceModel::new(AFFORDANCES.len(), &device);
    println!("| seed | room | map id consistency | interactions | map, mean | map, longest |");
    println!("|---|---|---|---|---|---|");
    let mut consistencies = Vec::new();
    let mut env = sim_env(&args)?;
    for seed in seeds {
        let mut rng = StdRng::seed_from_u64(seed);
        let mut observation = env
            .reset(seed, &model)
            .with_context(|| format!("starting seed {seed}'s episode"))?;
        let room = env
            .simulator()
            .map_or_else(|| "?".to_owned(), |s| s.scene().name.clone());
        let (mut map_time, mut longest, mut interactions) = (Duration::ZERO, Duration::ZERO, 0);
        let started = Instant::now();
        for _ in 1..args.steps {
            let action = random_allowed_action(
                env.action_space(),
                &observation.mask,
                args.interact_bias,
                &mut rng,
            );
            interactions += usize::from(!matches!(
                env.action_space().get(action),
                Some(PolicyAction::Nav(_))
            ));
            observation = env.step(action, &model)?.1;
            let map = env.last_timings().map;
            map_time += map;
            longest = longest.max(map);
        }
        let summary = env.finish_episode(seed)?;
        let consistency = summary
            .stats
            .iter()
            .find(|(key, _)| *key == StatKey::Episode(StatField::MapIdConsistency))
            .map(|&(_, v)| v);
        consistencies.extend(consistency);
        println!(
            "| {seed} | {room} | {} | {interactions} of {} | {:.2} ms | {:.0} ms |",
            consistency.map_or_else(|| "none".to_owned(), |c| format!("{c:.4}")),
            args.steps - 1,
            map_time.as_secs_f64() * 1e3 / (args.steps - 1) as f64,
            longest.as_secs_f64() * 1e3,
        );
        eprintln!("seed {seed}: {:.0} s", started.elapsed().as_secs_f64());
    }
    if !consistencies.is_empty() {
        let mean = consistencies.iter().sum::<f32>() / consistencies.len() as f32;
        println!(
            "\nmean map id consistency over {} episodes: {mean:.4}",
            consistencies.len()
        );
    }
    Ok(())
}

/// An `ours` environment of `args` in the training rooms, CPU renderer.
fn sim_env(args: &Args) -> anyhow::Result<SimEnv> {
    let profile = RobotProfile::load("default").context("loading the default robot profile")?;
    let source = SceneSource::open(
        Some(&args.data.join("ithor-livingrooms")),
        SceneSet::Train,
        &args.data.join("ithor-object-types.tsv"),
        &profile,
    )
    .with_context(|| format!("reading the rooms under --data {}", args.data.display()))?;
    let config = SimEnvConfig {
        episode_steps: args.steps,
        image_size: args.image_size,
        ..SimEnvConfig::paper(Method::Ours, &AFFORDANCES)
    };
    let renderer = Renderer::open(RendererChoice::Cpu).context("opening the CPU renderer")?;
    Ok(SimEnv::new(config, source, profile, renderer))
}

/// `1-6` or `1,3,5`.
fn parse_seeds(text: &str) -> anyhow::Result<Vec<u64>> {
    let bad = || format!("--seeds {text:?}: a range like 1-6 or a list like 1,3,5");
    if let Some((first, last)) = text.split_once('-') {
        let first: u64 = first.trim().parse().with_context(bad)?;
        let last: u64 = last.trim().parse().with_context(bad)?;
        if last < first {
            bail!("{}", bad());
        }
        return Ok((first..=last).collect());
    }
    text.split(',')
        .map(|s| s.trim().parse().with_context(bad))
        .collect()
}
