//! `actor`: runs episodes with the learner's newest policy and streams
//! rollouts and episode stats to it over shared memory.

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Duration;

use actor::env::{BanditFixture, Environment};
use actor::episode_loop::{run, LoopSettings};
use actor::sim_view::SimViewSettings;
use anyhow::Context;
use clap::{Args, Parser, Subcommand, ValueEnum};
use sim::renderer::RendererChoice;
use transport::TransportConfig;

/// Environments the actor can run.
#[derive(Debug, Clone, Copy, ValueEnum)]
enum EnvKind {
    /// Deterministic contextual bandit: a wiring test fixture, not a simulator.
    BanditFixture,
}

#[derive(Parser)]
#[command(
    version,
    about = "An actor of the affordance-exploration service",
    long_about = None,
    args_conflicts_with_subcommands = true,
    subcommand_negates_reqs = true
)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    #[command(flatten)]
    run: RunArgs,
}

#[derive(Subcommand)]
enum Command {
    /// Walks the agent along a short scripted path through one room and writes
    /// PNGs of what it sees (RGB, colour-mapped depth, instance ids) plus a
    /// top-down map of the room with the path.
    SimView(SimViewArgs),
}

#[derive(Args)]
struct SimViewArgs {
    /// The room: FloorPlan201 … FloorPlan230 (iTHOR) or generated:SEED (procedural).
    #[arg(long, default_value = "FloorPlan227")]
    scene: String,
    /// Directory to write the PNGs to (created).
    #[arg(long)]
    out: PathBuf,
    /// Shared data directory with ithor-livingrooms/ and ithor-object-types.tsv.
    #[arg(long, env = "AFX_DATA", default_value = "../shared/data")]
    data: PathBuf,
    /// Robot profile: a shipped name (default, weak-arm) or a TOML file.
    #[arg(long, default_value = "default")]
    profile: String,
    /// Renderer: gpu (wgpu: a GPU or Mesa lavapipe) or cpu (ray casting).
    #[arg(long, default_value = "gpu")]
    renderer: RendererChoice,
}

#[derive(Args)]
struct RunArgs {
    /// This actor's id, unique in the run, below the transport's max_actors.
    #[arg(long, required = true)]
    actor_id: Option<u32>,
    /// Service-name prefix of the learner to connect to (overrides the config).
    #[arg(long, value_name = "PREFIX")]
    learner: Option<String>,
    /// Run config (the learner's config.toml); only its [transport] table is read.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Environment to run. Only the bandit fixture (a wiring test) exists so far;
    /// the simulator-backed environment with map and networks is the next step.
    #[arg(long, value_enum, required = true)]
    env: Option<EnvKind>,
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
    match cli.command {
        Some(Command::SimView(args)) => sim_view(args),
        None => run_actor(cli.run),
    }
}

fn sim_view(args: SimViewArgs) -> anyhow::Result<()> {
    let settings = SimViewSettings {
        scene: args.scene,
        data_dir: args.data,
        profile: args.profile,
        renderer: args.renderer,
        out: args.out,
    };
    let summary = actor::sim_view::run(&settings)?;
    eprintln!(
        "sim-view: {} ({} of {} walk steps moved the agent), rendered with {}; wrote {} PNGs to {}",
        settings.scene,
        summary.moved,
        actor::sim_view::WALK.len(),
        summary.renderer,
        summary.files.len(),
        settings.out.display()
    );
    Ok(())
}

fn run_actor(cli: RunArgs) -> anyhow::Result<()> {
    let (Some(actor_id), Some(env_kind)) = (cli.actor_id, cli.env) else {
        anyhow::bail!("--actor-id and --env are required (see --help)");
    };
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
    eprintln!("actor {}: {}", actor_id, transport.describe());
    let stop = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, stop.clone()).context("installing signal handlers")?;
    }
    let mut env: Box<dyn Environment> = match env_kind {
        EnvKind::BanditFixture => Box::new(BanditFixture::new()),
    };
    let mut ports = transport::ActorPorts::open(&transport, actor_id).context(
        "opening the shared-memory services (same --learner prefix and config as the learner?)",
    )?;
    let settings = LoopSettings {
        actor_id,
        chunk_steps: cli.chunk_steps,
        seed: cli.seed,
        max_episodes: cli.max_episodes,
        weights_timeout: Duration::from_secs_f64(cli.weights_timeout_s),
    };
    let summary = run(env.as_mut(), &mut ports, &transport, &settings, &stop)?;
    eprintln!(
        "actor {}: stopped after {} episodes, {} steps; {} messages delivered, {} dropped; policy version {}",
        actor_id, summary.episodes, summary.steps, summary.delivered, summary.dropped, summary.policy_version
    );
    Ok(())
}
