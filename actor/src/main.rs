//! `actor`: runs episodes with the learner's newest policy and streams
//! rollouts and episode stats to it over shared memory.

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Duration;

mod commands;

use actor::config::RunConfig;
use actor::env::affordance_model::AffordanceModel;
use actor::env::sim_env::{SimEnv, SimEnvConfig};
use actor::env::{BanditFixture, Environment, FlatSimEnv};
use actor::episode_loop::{run, LoopSettings};
use actor::sim_view::SimViewSettings;
use anyhow::Context;
use clap::{Args, Parser, Subcommand, ValueEnum};
use proto::{EnvKind, TaskSpec};
use sim::profile::RobotProfile;
use sim::renderer::Renderer;

use commands::evaluate::{evaluate, EvaluateArgs};
use commands::sim_args::{Sim, SimArgs};

/// Where the simulator's rooms come from.
#[derive(Debug, Clone, Copy, ValueEnum)]
enum Scenes {
    /// The 20 iTHOR training living rooms (FloorPlan201–220) under --data.
    Ithor,
    /// Procedurally generated rooms from the object catalogue under --data.
    Generated,
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
    /// Scores a run's affordance U-Net in rooms it never trained in, as the
    /// paper's Tables 1 and 2: pixel precision, recall, F1 and object accuracy
    /// per test view (median [10th, 90th percentile]), and, with the robot
    /// placed in front of every object and each affordance tried there, the
    /// object-level prediction (mean over its pixels) against the outcome.
    Evaluate(EvaluateArgs),
    /// Writes the comparison `deploy/reproduce.sh` ran (its --root) as one
    /// Markdown page: Tables 1 and 2 per method over seeds beside the
    /// floors and the paper's numbers, whether the paper's ordering holds,
    /// and each run's course. Fails if any run is missing or incomplete.
    Results(ResultsArgs),
}

#[derive(Args)]
struct ResultsArgs {
    /// The comparison's root directory (with reproduce.json).
    #[arg(long)]
    root: PathBuf,
    /// The page to write.
    #[arg(long, default_value = "docs/results.md")]
    out: PathBuf,
    /// The training curves' SVG, as the page should link it (relative to
    /// the page).
    #[arg(long)]
    curves: Option<String>,
}

#[derive(Args)]
struct SimViewArgs {
    /// The room: FloorPlan201 … FloorPlan230 (iTHOR) or generated:SEED (procedural).
    #[arg(long, default_value = "FloorPlan227")]
    scene: String,
    /// Directory to write the PNGs to (created).
    #[arg(long)]
    out: PathBuf,
    /// Side of the camera's square images, pixels (a run's is its `[task] image_size`).
    #[arg(long, default_value_t = 128)]
    image_size: usize,
    #[command(flatten)]
    sim: SimArgs,
}

#[derive(Args)]
struct RunArgs {
    /// This actor's id, unique in the run, below the transport's max_actors.
    #[arg(long, required = true)]
    actor_id: Option<u32>,
    /// Service-name prefix of the learner to connect to (overrides the config).
    #[arg(long, value_name = "PREFIX")]
    learner: Option<String>,
    /// Run config (the learner's RUN_DIR/config.toml): its [transport],
    /// [task] and [actors] tables and [policy] seed are read, so the actor
    /// runs what the learner trains, as the run says; the flags below
    /// override [actors].
    #[arg(long)]
    config: Option<PathBuf>,
    /// The run's join key (the learner writes RUN_DIR/join.key when it
    /// starts): the actor proves with it that it belongs to the run, and the
    /// learner refuses messages from actors that do not. Default: join.key
    /// beside --config.
    #[arg(long, value_name = "FILE")]
    join_key: Option<PathBuf>,
    /// Steps per rollout chunk sent to the learner.
    #[arg(long, default_value_t = 16)]
    chunk_steps: usize,
    /// Base random seed: rooms, their randomisation and sampled actions.
    /// Moved on by the run's environment steps when the actor starts, so a
    /// restarted actor, or a resumed run, does not replay its episodes.
    /// Default: the run's seed ([policy] seed), else 0.
    #[arg(long)]
    seed: Option<u64>,
    /// Stop after this many episodes over all environments (default: run
    /// until SIGINT/SIGTERM).
    #[arg(long)]
    max_episodes: Option<u64>,
    /// Environments this actor runs side by side, each on a thread of its
    /// own and none waiting for the others. On a GPU the U-Net sees their
    /// frames in batches: batches are how one actor process keeps it busy.
    /// On a CPU this uses more cores, like more actors would. Default:
    /// [actors] envs, else 1.
    #[arg(long, value_parser = clap::value_parser!(u16).range(1..=256))]
    envs: Option<u16>,
    /// Seconds to wait for the learner's first weights before giving up.
    #[arg(long, default_value_t = 30.0)]
    weights_timeout_s: f64,
    /// Rooms to explore. Default: [actors] scenes, else ithor.
    #[arg(long, value_enum)]
    scenes: Option<Scenes>,
    #[command(flatten)]
    sim: SimArgs,
    /// Where the networks infer: cpu, or gpu in a build with `--features
    /// nets/gpu`. Default: [actors] device, else cpu.
    #[arg(long, value_parser = ["cpu", "gpu"])]
    device: Option<String>,
    /// Record every episode to an MCAP file in this directory (created):
    /// camera images and pose, calibration, instance and map ids, the
    /// U-Net's predictions, labels, the policy's maps, the map's object
    /// meshes, actions and rewards, in Foxglove's schemas (open with
    /// deploy/foxglove-layout.json).
    #[arg(long, value_name = "DIR")]
    record: Option<PathBuf>,
    /// With --record, record only every N-th episode (a recording is tens
    /// of megabytes).
    #[arg(long, default_value_t = 1, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
    record_every: u64,
    /// Write the label ladder's dataset to this directory (created; method
    /// `ours`): episodes' frames, each with the simulator's ground truth
    /// for every object (L0), for the objects the agent tried (L1) and the
    /// run's own labels (L2), for `learner train-unet` (docs/ladder.md).
    /// The run's config.toml is copied beside them.
    #[arg(long, value_name = "DIR", requires = "config")]
    dataset: Option<PathBuf>,
    /// With --dataset, write only every N-th episode.
    #[arg(long, default_value_t = 1, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
    dataset_every: u64,
    /// With --dataset, keep every K-th frame of an episode (a 600-step
    /// episode at 128 px is 128 MB whole).
    #[arg(long, default_value_t = 1, value_name = "K", value_parser = clap::value_parser!(u16).range(1..))]
    dataset_frame_every: u16,
}

fn main() -> anyhow::Result<()> {
    let heap_kept = nets::heap::keep_freed_memory();
    transport::init_logging("info");
    if !heap_kept {
        tracing::warn!(
            "the C allocator refused to keep freed memory: steps may fault pages in afresh"
        );
    }
    let cli = Cli::parse();
    match cli.command {
        Some(Command::SimView(args)) => sim_view(args),
        Some(Command::Evaluate(args)) => evaluate(args),
        Some(Command::Results(args)) => results(args),
        None => run_actor(cli.run).or_else(|e| {
            if !slots_taken(&e) {
                return Err(e);
            }
            // A condition that heals when a holder ends: a distinct status,
            // which deploy/supervise.sh retries with back-off.
            eprintln!("Error: {e:#}");
            eprintln!(
                "actor: exiting with status {} (no free publisher slot yet; a supervisor retries)",
                transport::SLOTS_TAKEN_EXIT
            );
            std::process::exit(transport::SLOTS_TAKEN_EXIT)
        }),
    }
}

/// Whether `error` comes from a service whose every publisher slot was taken.
fn slots_taken(error: &anyhow::Error) -> bool {
    error.chain().any(|cause| {
        cause
            .downcast_ref::<transport::TransportError>()
            .is_some_and(|e| e.slots_taken)
    })
}

fn sim_view(args: SimViewArgs) -> anyhow::Result<()> {
    let sim = args.sim.resolve(&proto::ActorSettings::default())?;
    let settings = SimViewSettings {
        scene: args.scene,
        data_dir: sim.data,
        profile: sim.profile,
        renderer: sim.renderer,
        image_size: args.image_size,
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

fn results(args: ResultsArgs) -> anyhow::Result<()> {
    let comparison = actor::results::load(&args.root)?;
    let page = actor::results::render(&comparison, args.curves.as_deref());
    std::fs::write(&args.out, page).with_context(|| format!("writing {}", args.out.display()))?;
    eprintln!(
        "results: {} runs of {} into {}",
        comparison.runs.len(),
        args.root.display(),
        args.out.display()
    );
    Ok(())
}

/// The simulator environment for `task`, in `scenes`, as `sim` says.
fn flat_sim_env(
    task: &TaskSpec,
    sim: &Sim,
    scenes: Scenes,
    cli: &RunArgs,
) -> anyhow::Result<FlatSimEnv> {
    let profile = RobotProfile::load(&sim.profile)?;
    let source = actor::env::training_rooms(&sim.data, matches!(scenes, Scenes::Ithor), &profile)
        .with_context(|| {
        format!(
            "opening the training rooms under {} (set --data, AFX_DATA or [actors] data \
                     to the shared data directory)",
            sim.data.display()
        )
    })?;
    let renderer = Renderer::open(sim.renderer)?;
    let mut env = SimEnv::new(SimEnvConfig::from_task(task), source, profile, renderer);
    if let Some(dir) = &cli.record {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("creating the --record directory {}", dir.display()))?;
        env.record_to(
            dir.clone(),
            format!("actor{}_", cli.actor_id.unwrap_or(0)),
            cli.record_every,
        );
    }
    if let Some(dir) = &cli.dataset {
        env.dataset_to(
            dir.clone(),
            format!("actor{}_", cli.actor_id.unwrap_or(0)),
            cli.dataset_every,
            usize::from(cli.dataset_frame_every),
        );
    }
    FlatSimEnv::new(env, task)
}

/// Starts the label ladder's dataset in `dir`: the run's config beside the
/// episodes, for the offline trainer to read the task and the U-Net's
/// settings from.
fn start_dataset(
    dir: &std::path::Path,
    config: &std::path::Path,
    task: &TaskSpec,
) -> anyhow::Result<()> {
    anyhow::ensure!(
        task.env == EnvKind::Sim && task.method.spec().map,
        "--dataset records the label ladder of a method with a map (ours); this run's is {}",
        task.method.as_str()
    );
    std::fs::create_dir_all(dir)
        .with_context(|| format!("creating the --dataset directory {}", dir.display()))?;
    let target = dir.join("config.toml");
    let text = std::fs::read(config).with_context(|| format!("reading {}", config.display()))?;
    match std::fs::read(&target) {
        Ok(existing) => anyhow::ensure!(
            existing == text,
            "{} holds a dataset of another run (its config.toml differs from {}): choose another --dataset directory",
            dir.display(),
            config.display()
        ),
        Err(_) => std::fs::write(&target, text)
            .with_context(|| format!("writing {}", target.display()))?,
    }
    Ok(())
}

/// Reads the run's join key (`--join-key`, or join.key beside `--config`),
/// waiting up to `--weights-timeout-s` for a learner that is still starting
/// to write it.
fn read_join_key(cli: &RunArgs) -> anyhow::Result<proto::JoinKey> {
    let path = match (&cli.join_key, &cli.config) {
        (Some(path), _) => path.clone(),
        (None, Some(config)) => config.with_file_name(transport::JOIN_KEY_FILE),
        (None, None) => anyhow::bail!(
            "no join key: pass --config RUN_DIR/config.toml (the key is read from beside it) or \
             --join-key RUN_DIR/{}; the learner writes both when it starts",
            transport::JOIN_KEY_FILE
        ),
    };
    let deadline = std::time::Instant::now() + Duration::from_secs_f64(cli.weights_timeout_s);
    while !path.exists() && std::time::Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(100));
    }
    transport::read_join_key(&path).with_context(|| {
        format!(
            "the actor needs the run's join key (is the learner of this run started? its run \
             directory holds {})",
            transport::JOIN_KEY_FILE
        )
    })
}

fn run_actor(cli: RunArgs) -> anyhow::Result<()> {
    let Some(actor_id) = cli.actor_id else {
        anyhow::bail!("--actor-id is required (see --help)");
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
    let RunConfig {
        mut transport,
        task,
        actors,
        seed: run_seed,
    } = match &cli.config {
        Some(path) => actor::config::run_config_from_toml_file(path)?,
        None => RunConfig::default(),
    };
    let sim = cli.sim.resolve(&actors)?;
    let scenes = match cli.scenes {
        Some(scenes) => scenes,
        None => clap::ValueEnum::from_str(&actors.scenes, true)
            .map_err(|e| anyhow::anyhow!("[actors] scenes: {e}"))?,
    };
    let device_name = cli.device.clone().unwrap_or_else(|| actors.device.clone());
    let envs = cli.envs.unwrap_or(actors.envs);
    let seed = cli.seed.unwrap_or(run_seed);
    if let Some(prefix) = &cli.learner {
        transport.service_prefix = prefix.clone();
    }
    tracing::info!(
        "actor {}: {}; task {:?} {} {:?} at {} px; {} environment(s) on {}, seed {}, rooms {:?}, \
         profile {}, renderer {:?}, data {}",
        actor_id,
        transport.describe(),
        task.env,
        task.method.as_str(),
        task.affordances,
        task.image_size,
        envs,
        device_name,
        seed,
        scenes,
        sim.profile,
        sim.renderer,
        sim.data.display()
    );
    if let (Some(dir), Some(config)) = (&cli.dataset, &cli.config) {
        start_dataset(dir, config, &task)?;
    }
    let choice: nets::device::DeviceChoice = device_name
        .parse()
        .map_err(|e| anyhow::anyhow!("--device: {e}"))?;
    let device = nets::device::open_device(choice).context("opening the inference device")?;
    let stop = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, stop.clone()).context("installing signal handlers")?;
    }
    let envs = (0..envs)
        .map(|_| -> anyhow::Result<Box<dyn Environment>> {
            Ok(match task.env {
                EnvKind::BanditFixture => Box::new(BanditFixture::new()),
                EnvKind::Sim => Box::new(flat_sim_env(&task, &sim, scenes, &cli)?),
            })
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let model =
        (task.env == EnvKind::Sim).then(|| AffordanceModel::new(task.affordances.len(), &device));
    let join_key = read_join_key(&cli)?;
    let mut ports = transport::ActorPorts::open(&transport, actor_id, join_key).context(
        "opening the shared-memory services (same --learner prefix and config as the learner?)",
    )?;
    let settings = LoopSettings {
        actor_id,
        chunk_steps: cli.chunk_steps,
        seed,
        max_episodes: cli.max_episodes,
        weights_timeout: Duration::from_secs_f64(cli.weights_timeout_s),
    };
    let summary = run(
        envs, model, &mut ports, &transport, &settings, &device, &stop,
    )?;
    tracing::info!(
        "actor {}: stopped after {} episodes, {} steps; {} messages delivered, {} dropped; policy version {}, U-Net version {}; {:.0} s waiting for the learner's U-Net; {} weights messages refused",
        actor_id,
        summary.episodes,
        summary.steps,
        summary.delivered,
        summary.dropped,
        summary.policy_version,
        summary.unet_version,
        summary.held_s,
        summary.weights_rejected
    );
    Ok(())
}
