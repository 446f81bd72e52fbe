//! `learner`: receives rollouts, labelled frames and stats from actors over
//! shared memory, trains, broadcasts weights, checkpoints, and serves metrics.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};

use anyhow::{bail, Context};
use clap::{Parser, Subcommand};
use learner::config::LearnerConfig;
use learner::service::{resume, Trainers};
use learner::shared::Shared;
use learner::status::LearnerStatus;

#[derive(Parser)]
#[command(version, about = "The learner of the affordance-exploration service", long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run the learner: receive from actors, train, publish weights, serve metrics.
    Serve(ServeArgs),
    /// Print every setting with its default as TOML, each under its
    /// explanation (a starting config file).
    PrintConfig,
    /// Remove shared-memory resources left by crashed learner or actor processes.
    Clean,
    /// Draw the paper's six training curves, the episode return, the
    /// interaction attempt rate, why attempts fail (beyond reach, not
    /// afforded) and the U-Net's IoU and object-level accuracy per
    /// affordance from a run's history.jsonl into an SVG; with several
    /// --run-dir, one line per run to compare them.
    Plot {
        /// A run directory (holds history.jsonl); repeat to compare runs.
        /// Several directories joined by commas are repeats of one setting
        /// (seeds), drawn as their mean in a band from their lowest to their
        /// highest value; `LABEL=` in front names the line:
        /// `--run-dir ours=runs/a,runs/b`.
        #[arg(long, required = true, value_name = "[LABEL=]DIR[,DIR...]")]
        run_dir: Vec<learner::tools::plot::RunGroup>,
        /// SVG file to write (default RUN_DIR/training_curves.svg for one run;
        /// required for several).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Episodes in the moving average.
        #[arg(long, default_value_t = 20)]
        window: usize,
    },
    /// Print a run's history as a table: the mean of every episode metric,
    /// successes per thousand steps per affordance, the policy's entropy,
    /// the U-Net's gradient steps per episode and what
    /// its dataset held (training frames, and those with positives per
    /// affordance) per span of environment steps (Markdown, or JSON).
    Summary {
        /// A run directory (holds history.jsonl). Repeat it for repeats of
        /// one setting (seeds): each cell is then the runs' mean with their
        /// lowest and highest in brackets, over the spans every run reached.
        #[arg(long, required = true)]
        run_dir: Vec<PathBuf>,
        /// Environment steps per row.
        #[arg(long, default_value_t = 20_000, value_parser = clap::value_parser!(u64).range(1..))]
        every: u64,
        /// Print JSON (one object per row) instead of a Markdown table.
        #[arg(long)]
        json: bool,
    },
    /// Train the affordance U-Net offline on the label ladder's dataset
    /// (`actor --dataset`) with one of its label sources, replaying the
    /// run's U-Net schedule (split, gate, temperature); writes a directory
    /// that `actor evaluate --run-dir` scores (docs/ladder.md).
    TrainUnet(TrainUnetArgs),
    /// Measure how many environment steps this learner takes: a real learner
    /// fed by synthetic actors (valid rollouts, labelled frames and stats of
    /// the task, as fast as it takes them; no simulator), printed as a
    /// Markdown row.
    BenchCapacity(CapacityArgs),
    /// Measure the message path over iceoryx2 and over loopback TCP, side by side.
    BenchTransport {
        /// Scale of the run (1 = 100 x 1 MiB, 10 x 16 MiB, 10 broadcasts per transport).
        #[arg(long, default_value_t = 3)]
        repeats: usize,
    },
}

#[derive(clap::Args)]
struct ServeArgs {
    /// TOML config file; missing keys take their defaults (see `learner print-config`).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Directory of this run (config, checkpoints). Default: runs/<UTC timestamp>.
    #[arg(long, conflicts_with = "resume")]
    run_dir: Option<PathBuf>,
    /// Resume the run in this directory from its newest checkpoint that verifies.
    #[arg(long, value_name = "RUN_DIR")]
    resume: Option<PathBuf>,
    /// HTTP address for /metrics, /api/status, /healthz (overrides the config; port 0 = any free port).
    #[arg(long)]
    http_addr: Option<String>,
    /// Service-name prefix shared with the actors (overrides the config).
    #[arg(long)]
    service_prefix: Option<String>,
    /// Most actors that may connect (overrides the config).
    #[arg(long)]
    max_actors: Option<u32>,
    /// Where the networks train: cpu, or gpu in a build with `--features nets/gpu` (overrides the config).
    #[arg(long, value_parser = ["cpu", "gpu"])]
    device: Option<String>,
    /// Method: ours, nomap-seg, nomap-noseg or intexp (overrides [task] method).
    #[arg(long, conflicts_with = "resume", value_parser = ["ours", "nomap-seg", "nomap-noseg", "intexp"])]
    method: Option<String>,
    /// Actors' environment: sim, or bandit-fixture (a wiring test) (overrides [task] env).
    #[arg(long, conflicts_with = "resume", value_parser = ["sim", "bandit-fixture"])]
    env: Option<String>,
    /// Side of the camera images and maps in pixels, a multiple of 16 (overrides [task] image_size).
    #[arg(long, conflicts_with = "resume")]
    image_size: Option<usize>,
    /// Steps per episode (overrides [task] episode_steps).
    #[arg(long, conflicts_with = "resume")]
    episode_steps: Option<usize>,
    /// The run's seed: initial weights of both networks, minibatch shuffling
    /// and the dataset split (overrides [policy] seed); the run's actors
    /// take it from the run's config too.
    #[arg(long, conflicts_with = "resume")]
    seed: Option<u64>,
    /// Any setting, as `KEY=VALUE` with a dotted key (repeat it):
    /// `--set policy.batch_steps=1024 --set actors.renderer=cpu`. Applied
    /// on top of --config (or, resuming, the run's saved config) and before
    /// the flags above; a value is TOML, and what is not TOML is a string.
    /// `learner print-config` lists every key.
    #[arg(long, value_name = "KEY=VALUE")]
    set: Vec<String>,
}

#[derive(clap::Args)]
struct TrainUnetArgs {
    /// The dataset directory (`actor --dataset`; holds config.toml and episodes/).
    #[arg(long)]
    dataset: PathBuf,
    /// Whose labels to learn: ground-truth (L0: every object in view),
    /// tried-truth (L1: the objects the agent tried, spread by the map,
    /// perfect outcomes) or run (L2: the run's own labels).
    #[arg(long)]
    labels: proto::LabelRung,
    /// The directory to write (config.toml, checkpoints/, train-unet.json).
    #[arg(long)]
    out: PathBuf,
    /// Times the episodes are replayed.
    #[arg(long, default_value_t = 1)]
    passes: usize,
    /// Gradient steps per episode (default: the run's [unet] steps_per_episode;
    /// raise it for a dataset of every N-th episode).
    #[arg(long)]
    steps_per_episode: Option<usize>,
    /// Checkpoints written, evenly over the training (the last at its end).
    #[arg(long, default_value_t = 1)]
    checkpoints: usize,
    /// How the loss weighs positive labels against negative ones: pixels,
    /// classes or positive-share=A (0 < A < 1: positives A of each plane's
    /// BCE) (default: the run's [unet] class_balance).
    #[arg(long)]
    class_balance: Option<nets::unet::ClassBalance>,
    /// Seed of the split, the batches and the initial weights.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Where the U-Net trains: cpu, or gpu in a GPU build.
    #[arg(long, default_value = "cpu", value_parser = ["cpu", "gpu"])]
    device: String,
}

#[derive(clap::Args)]
struct CapacityArgs {
    /// Synthetic actor processes' worth of feeds (threads, one actor id each).
    #[arg(long, default_value_t = 4)]
    actors: u32,
    /// Seconds before counting (start-up, first updates, kernel compilation).
    #[arg(long, default_value_t = 20)]
    warmup: u64,
    /// Seconds counted.
    #[arg(long, default_value_t = 60, value_parser = clap::value_parser!(u64).range(1..))]
    seconds: u64,
    /// Steps per rollout chunk (as the actors' --chunk-steps).
    #[arg(long, default_value_t = 16)]
    chunk_steps: usize,
    /// Share of each episode's steps sent back as labelled frames.
    #[arg(long, default_value_t = 0.5)]
    labelled_share: f64,
    /// TOML config file, as for `serve` (its [task], [policy] and [unet] apply).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Where the networks train: cpu, or gpu (overrides the config).
    #[arg(long, value_parser = ["cpu", "gpu"])]
    device: Option<String>,
    /// Side of the images in pixels (overrides [task] image_size).
    #[arg(long)]
    image_size: Option<usize>,
    /// Steps per episode (overrides [task] episode_steps).
    #[arg(long)]
    episode_steps: Option<usize>,
    /// Method: ours, nomap-seg, nomap-noseg or intexp (overrides [task] method).
    #[arg(long, value_parser = ["ours", "nomap-seg", "nomap-noseg", "intexp"])]
    method: Option<String>,
    /// Steps per PPO update (overrides [policy] batch_steps).
    #[arg(long)]
    batch_steps: Option<usize>,
}

/// Runs `learner bench-capacity` and prints its row.
fn bench_capacity(args: CapacityArgs) -> anyhow::Result<()> {
    let mut config = match &args.config {
        Some(path) => LearnerConfig::from_toml_file(path)?,
        None => LearnerConfig::default(),
    };
    if let Some(device) = &args.device {
        config.device = device.clone();
    }
    if let Some(size) = args.image_size {
        config.task.image_size = size;
    }
    if let Some(steps) = args.episode_steps {
        config.task.episode_steps = steps;
    }
    if let Some(method) = &args.method {
        config.task.method = parse_value("--method", method)?;
    }
    if let Some(steps) = args.batch_steps {
        config.policy.batch_steps = steps;
    }
    anyhow::ensure!(
        (0.0..=1.0).contains(&args.labelled_share),
        "--labelled-share must be in 0..=1"
    );
    config.validate()?;
    let device = open_named_device(&config.device, "--device")?;
    let policy_device = match config.policy.device.as_deref() {
        None => device.clone(),
        Some(name) => open_named_device(name, "[policy] device")?,
    };
    let setting = format!(
        "{} {} px, {}-step episodes, {} feeds, PPO {} steps on {}, U-Net on {} ({})",
        serde_json::to_value(config.task.method)?
            .as_str()
            .unwrap_or("?"),
        config.task.image_size,
        config.task.episode_steps,
        args.actors,
        config.policy.batch_steps,
        config.policy.device.as_deref().unwrap_or(&config.device),
        config.device,
        nets::device::backend_features()
    );
    eprintln!(
        "bench-capacity: {setting}; {} s warm-up, {} s counted",
        args.warmup, args.seconds
    );
    let feed = learner::tools::bench_capacity::FeedSettings {
        actors: args.actors,
        chunk_steps: args.chunk_steps,
        labelled_share: args.labelled_share,
        warmup: std::time::Duration::from_secs(args.warmup),
        window: std::time::Duration::from_secs(args.seconds),
    };
    let capacity = learner::tools::bench_capacity::run(config, &device, &policy_device, &feed)?;
    print!(
        "{}",
        learner::tools::bench_capacity::table(&[(setting, capacity)])
    );
    Ok(())
}

/// Parses a kebab-case enum value the way the config file spells it.
fn parse_value<T: serde::de::DeserializeOwned>(flag: &str, value: &str) -> anyhow::Result<T> {
    T::deserialize(serde::de::value::StrDeserializer::<serde::de::value::Error>::new(value))
        .map_err(|e| anyhow::anyhow!("{flag} {value:?}: {e}"))
}

fn main() -> anyhow::Result<()> {
    let heap_kept = nets::heap::keep_freed_memory();
    transport::init_logging("info");
    if !heap_kept {
        tracing::warn!(
            "the C allocator refused to keep freed memory: training steps may fault pages in afresh"
        );
    }
    match Cli::parse().command {
        Command::Serve(args) => serve(args),
        Command::PrintConfig => {
            print!(
                "{}",
                learner::config_docs::documented_toml(&LearnerConfig::default())
            );
            Ok(())
        }
        Command::BenchCapacity(args) => bench_capacity(args),
        Command::BenchTransport { repeats } => {
            let measurements = learner::tools::bench_transport::run(repeats.max(1))?;
            print!("{}", learner::tools::bench_transport::table(&measurements));
            Ok(())
        }
        Command::Plot {
            run_dir,
            out,
            window,
        } => {
            let out = match (out, run_dir.as_slice()) {
                (Some(out), _) => out,
                (None, [one]) if one.dirs.len() == 1 => one.dirs[0].join("training_curves.svg"),
                (None, _) => anyhow::bail!(
                    "several runs given: say where the comparison goes with --out FILE.svg"
                ),
            };
            let episodes = learner::tools::plot::plot(&run_dir, &out, window)?;
            let runs: usize = run_dir.iter().map(|g| g.dirs.len()).sum();
            if runs == 1 {
                println!("plotted {episodes} episodes into {}", out.display());
            } else {
                println!(
                    "plotted {runs} runs as {} lines (the longest run has {episodes} episodes) into {}",
                    run_dir.len(),
                    out.display()
                );
            }
            Ok(())
        }
        Command::Summary {
            run_dir,
            every,
            json,
        } => {
            let summary = learner::tools::summary::summarize_repeats(&run_dir, every)?;
            if json {
                println!("{}", serde_json::Value::from(&summary));
            } else {
                print!("{}", summary.markdown());
            }
            Ok(())
        }
        Command::TrainUnet(args) => {
            let device = open_named_device(&args.device, "--device")?;
            let settings = learner::tools::train_unet::TrainUnetSettings {
                dataset: args.dataset,
                rung: args.labels,
                out: args.out,
                passes: args.passes,
                steps_per_episode: args.steps_per_episode,
                checkpoints: args.checkpoints,
                class_balance: args.class_balance,
                seed: args.seed,
            };
            let report = learner::tools::train_unet::train_unet(&settings, &device, &mut |line| {
                eprintln!("train-unet: {line}")
            })?;
            println!("{}", serde_json::to_string_pretty(&report)?);
            Ok(())
        }
        Command::Clean => {
            let removed = transport::remove_dead_nodes()?;
            println!("removed the resources of {removed} dead node(s)");
            Ok(())
        }
    }
}

fn default_run_dir() -> PathBuf {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0);
    PathBuf::from("runs").join(format!("run-{secs}"))
}

fn load_config(args: &ServeArgs, run_dir: &Path) -> anyhow::Result<LearnerConfig> {
    let saved = run_dir.join("config.toml");
    let base = match (&args.config, &args.resume) {
        (Some(path), _) => Some(path.as_path()),
        (None, Some(_)) if saved.exists() => Some(saved.as_path()),
        _ => None,
    };
    let mut config = LearnerConfig::from_toml_file_with(base, &args.set)?;
    if let Some(addr) = &args.http_addr {
        config.http_addr = addr.clone();
    }
    if let Some(prefix) = &args.service_prefix {
        config.transport.service_prefix = prefix.clone();
    }
    if let Some(n) = args.max_actors {
        config.transport.max_actors = n;
    }
    if let Some(device) = &args.device {
        config.device = device.clone();
    }
    if let Some(method) = &args.method {
        config.task.method = parse_value("--method", method)?;
    }
    if let Some(env) = &args.env {
        config.task.env = parse_value("--env", env)?;
    }
    if let Some(size) = args.image_size {
        config.task.image_size = size;
    }
    if let Some(steps) = args.episode_steps {
        config.task.episode_steps = steps;
    }
    if let Some(seed) = args.seed {
        config.policy.seed = seed;
    }
    if args.resume.is_some() && saved.exists() {
        let (resumed, ignored) = config.for_resume(&LearnerConfig::from_toml_file(&saved)?);
        for what in ignored {
            tracing::warn!(
                "resuming keeps the run's {what} from {} (its checkpoints were made \
                 for it); the one given is ignored",
                saved.display()
            );
        }
        config = resumed;
    }
    config.validate()?;
    Ok(config)
}

/// Moves a run's history (`history.jsonl`, `tensorboard/`) aside, to
/// `<name>.before-restart-<unix time>`, for a run that starts afresh in its
/// directory: the new history counts steps from 0 again. Returns where the
/// history went, `None` when there was none.
fn set_aside_history(run_dir: &Path) -> anyhow::Result<Option<PathBuf>> {
    let stamp = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    let mut history_to = None;
    for name in ["history.jsonl", "tensorboard"] {
        let from = run_dir.join(name);
        if !from.exists() {
            continue;
        }
        let to = run_dir.join(format!("{name}.before-restart-{stamp}"));
        std::fs::rename(&from, &to)
            .with_context(|| format!("moving {} aside to {}", from.display(), to.display()))?;
        if name == "history.jsonl" {
            history_to = Some(to);
        }
    }
    Ok(history_to)
}

/// Opens the device `name` (`cpu` or `gpu`) names; `setting` says where the
/// name came from in the error.
fn open_named_device(name: &str, setting: &str) -> anyhow::Result<burn::prelude::Device> {
    let choice: nets::device::DeviceChoice = name
        .parse()
        .map_err(|e| anyhow::anyhow!("{setting}: {e}"))?;
    nets::device::open_device(choice).with_context(|| format!("opening the device of {setting}"))
}

fn serve(args: ServeArgs) -> anyhow::Result<()> {
    let run_dir = match (&args.resume, &args.run_dir) {
        (Some(dir), _) => {
            if !dir.is_dir() {
                bail!("--resume {}: no such run directory", dir.display());
            }
            dir.clone()
        }
        (None, Some(dir)) => dir.clone(),
        (None, None) => default_run_dir(),
    };
    let config = load_config(&args, &run_dir)?;
    std::fs::create_dir_all(&run_dir)
        .with_context(|| format!("creating run directory {}", run_dir.display()))?;
    std::fs::write(run_dir.join("config.toml"), config.to_toml())
        .context("saving config.toml in the run directory")?;
    let run_id = run_dir
        .file_name()
        .and_then(|n| n.to_str())
        .unwrap_or("run")
        .to_string();
    tracing::info!("learner config (run {run_id}):\n{}", config.to_toml());
    tracing::info!("{}", config.transport.describe());

    let checkpoint_dir = run_dir.join("checkpoints");
    let device = open_named_device(&config.device, "--device")?;
    let policy_device = match config.policy.device.as_deref() {
        None => device.clone(),
        Some(name) => open_named_device(name, "[policy] device")?,
    };
    let mut trainers = Trainers::new(&config, &device, &policy_device);
    let mut status = LearnerStatus::new(run_id);
    if args.resume.is_some() && !resume(&checkpoint_dir, &mut trainers, &mut status)? {
        let aside = set_aside_history(&run_dir)?;
        tracing::warn!(
            "{} has no checkpoint (its learner stopped before writing one): starting \
             the run afresh in the same directory, with its config.toml{}",
            run_dir.display(),
            aside.map_or(String::new(), |to| format!(
                "; the steps it lost are in {}",
                to.display()
            ))
        );
    }

    let shared = Arc::new(Shared {
        status: Mutex::new(status),
        shutdown: Default::default(),
        config: config.clone(),
        run_dir: run_dir.clone(),
    });

    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    let listener = runtime
        .block_on(tokio::net::TcpListener::bind(&config.http_addr))
        .with_context(|| {
            format!(
                "binding the metrics endpoint to {} (in use? pick another with --http-addr)",
                config.http_addr
            )
        })?;
    let addr: SocketAddr = listener.local_addr()?;

    let training = learner::service::spawn(shared.clone(), trainers, checkpoint_dir)?;
    std::fs::write(run_dir.join("http.addr"), addr.to_string()).context("writing http.addr")?;
    tracing::info!("metrics: http://{addr}/metrics  status: http://{addr}/api/status");

    let http_shared = shared.clone();
    runtime.block_on(async move {
        let shutdown = async move {
            use tokio::signal::unix::{signal, SignalKind};
            let (Ok(mut int), Ok(mut term)) = (
                signal(SignalKind::interrupt()),
                signal(SignalKind::terminate()),
            ) else {
                tracing::error!("cannot install signal handlers");
                return;
            };
            let watch = http_shared.clone();
            let stopped = async move {
                while !watch.shutdown.load(Ordering::Relaxed) {
                    tokio::time::sleep(std::time::Duration::from_millis(100)).await;
                }
            };
            tokio::select! {
                _ = int.recv() => tracing::info!("SIGINT received"),
                _ = term.recv() => tracing::info!("SIGTERM received"),
                _ = stopped => {}
            }
            http_shared.shutdown.store(true, Ordering::Relaxed);
        };
        axum::serve(listener, learner::http::router(shared))
            .with_graceful_shutdown(shutdown)
            .await
    })?;
    match training.join() {
        Ok(result) => result.context("the training loop failed"),
        Err(_) => bail!(
            "the training loop panicked (its message is in the log above, unless the log \
             could not be written: is the disk full?); continue the run from its newest \
             checkpoint with --resume"
        ),
    }
}
