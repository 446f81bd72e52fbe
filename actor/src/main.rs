//! `actor`: runs episodes with the learner's newest policy and streams
//! rollouts and episode stats to it over shared memory.

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Duration;

use actor::env::{BanditFixture, Environment};
use actor::episode_loop::{run, LoopSettings};
use anyhow::Context;
use clap::{Parser, ValueEnum};
use transport::TransportConfig;

/// Environments the actor can run.
#[derive(Debug, Clone, Copy, ValueEnum)]
enum EnvKind {
    /// Deterministic contextual bandit: a wiring test fixture, not a simulator.
    BanditFixture,
}

#[derive(Parser)]
#[command(version, about = "An actor of the affordance-exploration service", long_about = None)]
struct Cli {
    /// This actor's id, unique in the run, below the transport's max_actors.
    #[arg(long)]
    actor_id: u32,
    /// Service-name prefix of the learner to connect to (overrides the config).
    #[arg(long, value_name = "PREFIX")]
    learner: Option<String>,
    /// Run config (the learner's config.toml); only its [transport] table is read.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Environment to run. There is no default: the simulator is not built yet,
    /// and the bandit fixture exists only to test the wiring.
    #[arg(long, value_enum)]
    env: EnvKind,
    /// Steps per rollout chunk sent to the learner.
    #[arg(long, default_value_t = 32)]
    chunk_steps: usize,
    /// Base random seed.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Stop after this many episodes (default: run until SIGINT/SIGTERM).
    #[arg(long)]
    max_episodes: Option<u64>,
    /// Seconds to wait for the learner's first weights before giving up.
    #[arg(long, default_value_t = 30.0)]
    weights_timeout_s: f64,
}

fn main() -> anyhow::Result<()> {
    tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .init();
    transport::init_iceoryx_logging();
    let cli = Cli::parse();
    anyhow::ensure!(
        (1..=proto::MAX_STEPS as usize).contains(&cli.chunk_steps),
        "--chunk-steps must be in 1..={}",
        proto::MAX_STEPS
    );
    anyhow::ensure!(
        cli.weights_timeout_s.is_finite() && cli.weights_timeout_s >= 0.0,
        "--weights-timeout-s must be a non-negative number"
    );
    let mut transport = match &cli.config {
        Some(path) => actor::config::transport_from_toml_file(path)?,
        None => TransportConfig::default(),
    };
    if let Some(prefix) = &cli.learner {
        transport.service_prefix = prefix.clone();
    }
    eprintln!("actor {}: {}", cli.actor_id, transport.describe());
    let stop = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, stop.clone()).context("installing signal handlers")?;
    }
    let mut env: Box<dyn Environment> = match cli.env {
        EnvKind::BanditFixture => Box::new(BanditFixture::new()),
    };
    let mut ports = transport::ActorPorts::open(&transport, cli.actor_id).context(
        "opening the shared-memory services (same --learner prefix and config as the learner?)",
    )?;
    let settings = LoopSettings {
        actor_id: cli.actor_id,
        chunk_steps: cli.chunk_steps,
        seed: cli.seed,
        max_episodes: cli.max_episodes,
        weights_timeout: Duration::from_secs_f64(cli.weights_timeout_s),
    };
    let summary = run(env.as_mut(), &mut ports, &transport, &settings, &stop)?;
    eprintln!(
        "actor {}: stopped after {} episodes, {} steps; {} messages delivered, {} dropped; policy version {}",
        cli.actor_id, summary.episodes, summary.steps, summary.delivered, summary.dropped, summary.policy_version
    );
    Ok(())
}
