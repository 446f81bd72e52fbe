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
//! A second table steps several environments in one process (`actor --envs
//! N`) through a whole episode, each step with the policy's forward pass as
//! the actor runs it (the actions themselves stay random): as the actor runs
//! them (`actor::sampling`: each environment on its own thread, running the
//! policy's pass on its own observations; on a GPU the U-Net in one
//! batching thread's batches, `actor::sampling::unet_batcher`), and for
//! comparison with the policy's passes on the caller's thread. It reports
//! steps/s per process and per environment, then the episode's end
//! (labelling, in parallel) and steps/s per process with that end included,
//! and how many cores the process kept busy while stepping (its CPU time
//! over the wall time): near the machine's count, the run is bound by the
//! CPU and only less work per step makes it faster. The rows also say what
//! the environments' steps were made of (`actor::env::step_phases`), as an
//! actor's last lines do beside the learner.
//!
//! `AFX_DEVICE=gpu` runs the U-Net on the GPU (a build with
//! `--features nets/gpu`); `AFX_DATA` points at the shared data directory
//! (default `../shared/data` beside the repository), for running the bench
//! binary on another machine; `AFX_ENVS` lists the environment counts of the
//! second table (default `1,2`; `none` skips it). `AFX_CASES` keeps only the first table's
//! rows whose name (`method-px-renderer`, e.g. `ours-64-cpu`) contains one of
//! its comma-separated parts (`none` skips the table); `AFX_STEPS` sets the
//! episode length of both tables (default 120; the paper's is 600: the map,
//! and with it the map's and the state's time, grows over an episode).
//! The second table runs at 64 px with the CPU renderer unless `AFX_ENVS_PX`
//! (image side) and `AFX_ENVS_RENDERER` (`cpu` or `gpu`) say otherwise: the
//! paper's 128 px on a GPU machine is `AFX_ENVS_PX=128 AFX_ENVS_RENDERER=gpu`.
//! `AFX_ENVS_INFERENCE=batched` runs the second table as on a GPU (the
//! U-Net's frames in batches) with the U-Net on the CPU; `AFX_UNET_BATCHERS=2`
//! gives the rows two batching threads (their "busy" share is
//! then the two threads' time added up). `AFX_SPARSE_PLANES_BELOW` sets the
//! policy's CPU pass's share below which a plane skips its GEMM (0: none
//! does), to compare the two ways in one binary.

use std::sync::{Arc, RwLock};
use std::time::{Duration, Instant};

use actor::env::actions::random_allowed_action;
use actor::env::actions::ActionSpace;
use actor::env::affordance_model::AffordanceModel;
use actor::env::sim_env::{SimEnv, SimEnvConfig, StepTimings};
use actor::env::step_phases::{step_phases, StepPhases};
use actor::env::{Environment, FlatSimEnv, Observation};
use actor::sampling::env_threads::{Done, EnvThreads, PolicyPass, Task};
use actor::sampling::unet_batcher::{batch_times, BatchTimes};
use actor::sampling::Inference;
use burn::prelude::*;
use mapper::Affordance;
use nets::policy::{CpuPolicy, PolicyInput, PolicyLayout, PolicyNet};
use proto::{Method, TaskSpec};
use rand::rngs::StdRng;
use rand::SeedableRng;
use rayon::prelude::*;
use sim::ithor::SceneSet;
use sim::profile::RobotProfile;
use sim::renderer::{Renderer, RendererChoice};
use sim::scenes::SceneSource;

/// Episode length unless `AFX_STEPS` says otherwise.
const DEFAULT_STEPS: usize = 120;
const AFFORDANCES: [Affordance; 2] = [Affordance::PickUp, Affordance::Push];

/// The episode length: `AFX_STEPS`, else [`DEFAULT_STEPS`].
fn episode_steps() -> usize {
    std::env::var("AFX_STEPS").map_or(DEFAULT_STEPS, |s| {
        s.trim()
            .parse()
            .ok()
            .filter(|&n: &usize| n >= 2)
            .expect("AFX_STEPS: an episode length of at least 2 steps")
    })
}

/// The second table's image side (`AFX_ENVS_PX`, default 64) and renderer
/// (`AFX_ENVS_RENDERER`, default the CPU's).
fn several_envs_setting() -> (usize, RendererChoice) {
    let side = std::env::var("AFX_ENVS_PX").map_or(64, |s| {
        s.trim()
            .parse()
            .ok()
            .filter(|&n: &usize| n >= 8 && n % 8 == 0)
            .expect("AFX_ENVS_PX: an image side, a multiple of 8")
    });
    let renderer =
        std::env::var("AFX_ENVS_RENDERER").map_or(RendererChoice::Cpu, |s| match s.trim() {
            "cpu" => RendererChoice::Cpu,
            "gpu" => RendererChoice::Gpu,
            other => panic!("AFX_ENVS_RENDERER takes cpu or gpu, not {other:?}"),
        });
    (side, renderer)
}

/// How the second table's networks see the environments: as the actor on
/// `device` does, unless `AFX_ENVS_INFERENCE` (`batched` or
/// `per-environment`) says otherwise (to run a GPU's way on a CPU).
fn several_envs_inference(device: &Device) -> Inference {
    std::env::var("AFX_ENVS_INFERENCE").map_or(Inference::for_device(device), |s| match s.trim() {
        "batched" => Inference::Batched,
        "per-environment" => Inference::PerEnvironment,
        other => panic!("AFX_ENVS_INFERENCE takes batched or per-environment, not {other:?}"),
    })
}

/// The policy's CPU pass adds planes under this share of nonzero values
/// pixel by pixel: `AFX_SPARSE_PLANES_BELOW`, else the pass's default (0
/// sends every plane through the GEMMs, to compare the two in one binary).
fn sparse_planes_below() -> f32 {
    std::env::var("AFX_SPARSE_PLANES_BELOW").map_or(nets::policy::SPARSE_PLANES_BELOW, |s| {
        s.trim()
            .parse()
            .expect("AFX_SPARSE_PLANES_BELOW: a share such as 0.2")
    })
}

/// True if the first table's row `name` is selected by `AFX_CASES`.
fn selected(name: &str) -> bool {
    match std::env::var("AFX_CASES") {
        Ok(cases) => cases.split(',').any(|part| name.contains(part.trim())),
        Err(_) => true,
    }
}

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
    // As the actor binary does: freed memory stays in the process.
    assert!(
        nets::heap::keep_freed_memory(),
        "the allocator refused the actor's settings"
    );
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
    let mut map_splits = Vec::new();
    let mut work_rows = Vec::new();
    let mut share_rows = Vec::new();
    let steps = episode_steps();
    for Case {
        method,
        image_size,
        renderer: choice,
    } in cases
    {
        let renderer_name = format!("{choice:?}").to_lowercase();
        let row = format!("{}-{image_size}-{renderer_name}", method.as_str());
        if !selected(&row) {
            continue;
        }
        let renderer = match Renderer::open(choice) {
            Ok(r) => r,
            Err(e) => {
                println!("{choice:?}: skipped: {e}");
                continue;
            }
        };
        let name = renderer.describe();
        let mut env = sim_env(&data, method, image_size, renderer);
        let model = AffordanceModel::new(AFFORDANCES.len(), &device);
        let mut rng = StdRng::seed_from_u64(1);
        let reset_started = Instant::now();
        let mut observation = env.reset(1, &model).expect("reset");
        let reset = reset_started.elapsed();
        let mut stages: Vec<StepTimings> = Vec::with_capacity(steps);
        let mut walls: Vec<Duration> = Vec::with_capacity(steps);
        let mut shares = PlaneShares::new(method);
        let start = Instant::now();
        for _ in 0..steps {
            let action =
                random_allowed_action(env.action_space(), &observation.mask, 0.5, &mut rng);
            let step_started = Instant::now();
            observation = env.step(action, &model).expect("step").1;
            walls.push(step_started.elapsed());
            stages.push(env.last_timings());
            shares.add(&observation.state);
        }
        let elapsed = start.elapsed();
        share_rows.extend(shares.rows(&row));
        work_rows.push(work_row(&row, &stages, &walls));
        let ms = |f: fn(&StepTimings) -> Duration| {
            median(stages.iter().map(f).collect()).as_secs_f64() * 1e3
        };
        println!(
            "| {} | {image_size} | {name} | {:.1} | {:.0} ms | {:.2} ms | {:.2} ms | {:.2} ms | {:.1} ms | {:.2} ms |",
            method.as_str(),
            steps as f64 / elapsed.as_secs_f64(),
            reset.as_secs_f64() * 1e3,
            ms(|t| t.sim),
            ms(|t| t.render),
            ms(|t| t.map),
            ms(|t| t.unet),
            ms(|t| t.state),
        );
        if method == Method::Ours {
            let stage = |f: fn(&mapper::IntegrateTimings) -> f64| {
                let times: Vec<f64> = stages.iter().map(|t| f(&t.map_stages)).collect();
                let mean = times.iter().sum::<f64>() / times.len() as f64;
                let times = times.into_iter().map(Duration::from_secs_f64);
                let median = median(times.collect()).as_secs_f64();
                format!("{:.2} / {:.2}", median * 1e3, mean * 1e3)
            };
            map_splits.push(format!(
                "| {} | {image_size} | {} ms | {} ms | {} ms | {} ms | {} ms | {} ms |",
                method.as_str(),
                stage(|m| m.render_s),
                stage(|m| m.associate_s),
                stage(|m| m.tracking_s),
                stage(|m| m.integrate_s),
                stage(|m| m.background_s),
                stage(|m| m.book_keeping_s),
            ));
        }
    }
    println!();
    println!("The map's own split of its column (median / mean per stage):");
    println!(
        "| method | px | render | association | tracking | objects | background | book-keeping |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for line in map_splits {
        println!("{line}");
    }
    println!();
    println!(
        "The state's image planes, each plane's share of nonzero values (mean over the \
         episode, planes in the state's order; the policy's first layers add a plane under \
         {} pixel by pixel):",
        nets::policy::SPARSE_PLANES_BELOW
    );
    println!("| case | input | shares |");
    println!("|---|---|---|");
    for line in share_rows {
        println!("{line}");
    }
    println!();
    println!(
        "The environment's work a step outside the U-Net and the render, means over the \
         episode (re-identification's bursts and the map's growth count in a mean, not in a \
         median; \"rest\" is the step's time outside its timed parts; with RAYON_NUM_THREADS=1 \
         the map's time is its CPU time):"
    );
    println!("| case | sim | map | state | rest | outside U-Net and render |");
    println!("|---|---|---|---|---|---|");
    for line in work_rows {
        println!("{line}");
    }
    several_envs_table(&data, &device);
}

/// A row of the work table: the means over an episode of each timed part
/// of a step and of what its wall time holds besides them.
fn work_row(case: &str, stages: &[StepTimings], walls: &[Duration]) -> String {
    let mean_ms = |total: Duration| total.as_secs_f64() * 1e3 / stages.len().max(1) as f64;
    let part = |f: fn(&StepTimings) -> Duration| mean_ms(stages.iter().map(f).sum());
    let (sim, map, state) = (part(|t| t.sim), part(|t| t.map), part(|t| t.state));
    let outside = mean_ms(
        stages
            .iter()
            .zip(walls)
            .map(|(t, wall)| wall.saturating_sub(t.unet + t.render))
            .sum(),
    );
    let rest = outside - sim - map - state;
    format!("| {case} | {sim:.2} ms | {map:.2} ms | {state:.2} ms | {rest:.2} ms | **{outside:.2} ms** |")
}

/// An environment of `method` at `image_size` px in the test rooms.
/// Each image plane's share of nonzero values, summed over the states seen.
struct PlaneShares {
    /// Planes of the camera, global and local map inputs.
    channels: [usize; 3],
    sums: [Vec<f64>; 3],
    states: usize,
}

impl PlaneShares {
    fn new(method: Method) -> Self {
        let spec = method.spec();
        let map = spec.map_channels(AFFORDANCES.len());
        let channels = [spec.camera_channels(AFFORDANCES.len()), map, map];
        Self {
            channels,
            sums: channels.map(|c| vec![0.0; c]),
            states: 0,
        }
    }

    fn add(&mut self, state: &actor::env::state::State) {
        let inputs = [state.camera(), state.global_map(), state.local_map()];
        for ((values, &channels), sums) in inputs.iter().zip(&self.channels).zip(&mut self.sums) {
            if channels == 0 || values.is_empty() {
                continue;
            }
            for (plane, sum) in values.chunks_exact(values.len() / channels).zip(sums) {
                let nonzero = plane.iter().filter(|&&v| v != 0).count();
                *sum += nonzero as f64 / plane.len() as f64;
            }
        }
        self.states += 1;
    }

    fn rows(&self, case: &str) -> Vec<String> {
        let names = ["camera", "global map", "local map"];
        (names.iter().zip(&self.sums))
            .filter(|(_, sums)| !sums.is_empty())
            .map(|(name, sums)| {
                let shares: Vec<String> = (sums.iter())
                    .map(|s| format!("{:.3}", s / self.states.max(1) as f64))
                    .collect();
                format!("| {case} | {name} | {} |", shares.join(" "))
            })
            .collect()
    }
}

fn sim_env(
    data: &std::path::Path,
    method: Method,
    image_size: usize,
    renderer: Renderer,
) -> SimEnv {
    let profile = RobotProfile::load("default").expect("profile");
    let source = SceneSource::open(
        Some(&data.join("ithor-livingrooms")),
        SceneSet::Test,
        &data.join("ithor-object-types.tsv"),
        &profile,
    )
    .expect("scenes");
    let config = SimEnvConfig {
        episode_steps: episode_steps(),
        image_size,
        ..SimEnvConfig::paper(method, &AFFORDANCES)
    };
    SimEnv::new(config, source, profile, renderer)
}

/// Several environments per process (CPU renderer and 64 px unless
/// [`several_envs_setting`] says otherwise), one whole episode with the
/// policy's forward pass every step, as the actor runs them: steps/s of the
/// process and of each environment, the episode's end, and steps/s of the
/// process with the end included.
fn several_envs_table(data: &std::path::Path, device: &burn::prelude::Device) {
    let counts = std::env::var("AFX_ENVS").unwrap_or_else(|_| "1,2".into());
    if counts.trim() == "none" {
        return;
    }
    let counts: Vec<usize> = counts
        .split(',')
        .map(|n| {
            n.trim()
                .parse()
                .expect("AFX_ENVS: environment counts, e.g. 1,2,4")
        })
        .collect();
    let (side, renderer_choice) = several_envs_setting();
    let model = RwLock::new(Some(AffordanceModel::new(AFFORDANCES.len(), device)));
    let inference = several_envs_inference(device);
    println!();
    println!("Several environments per process, {renderer_choice:?} renderer, U-Net inference {inference:?}:");
    println!("| method | px | environments | stepped | steps/s per process | steps/s per environment | episode end | steps/s per process, end included | CPU cores busy (of {}) | the U-Net's batches (on a GPU); what the steps were made of |", cores());
    println!("|---|---|---|---|---|---|---|---|---|---|");
    for method in [Method::Ours, Method::NomapSeg] {
        for &n in &counts {
            let task = TaskSpec {
                method,
                affordances: AFFORDANCES.to_vec(),
                image_size: side,
                episode_steps: episode_steps(),
                ..TaskSpec::default()
            };
            let new_envs = || -> Vec<FlatSimEnv> {
                (0..n)
                    .map(|_| {
                        let renderer = Renderer::open(renderer_choice).expect("the renderer");
                        FlatSimEnv::new(sim_env(data, method, side, renderer), &task)
                            .expect("the environment fits its task")
                    })
                    .collect()
            };
            let envs = new_envs();
            let layout = envs[0].layout().clone();
            let space = envs[0].inner().action_space().clone();
            let mut unused = Some(envs);
            let net = PolicyNet::new(&layout, device);
            // As the actor: the CPU's own pass on every device.
            let cpu = CpuPolicy::from_network(&net, &layout)
                .map(|cpu| cpu.with_sparse_planes_below(sparse_planes_below()))
                .map(Arc::new);
            let policy = (net, cpu);
            let bench = SeveralEnvs {
                layout: &layout,
                space: &space,
                policy: &policy,
                model: &model,
                device,
                inference,
            };
            let row = |stepped: &str, timed: Timed, phases: String| {
                let steps = episode_steps();
                let per_process = (n * steps) as f64 / timed.stepping.as_secs_f64();
                let busy = timed.cpu.map_or("—".to_string(), |cpu| {
                    format!("{:.1}", cpu.as_secs_f64() / timed.stepping.as_secs_f64())
                });
                println!(
                    "| {} | {side} | {n} | {stepped} | {per_process:.1} | {:.1} | {:.0} ms | {:.1} | {busy} | {phases} |",
                    method.as_str(),
                    per_process / n as f64,
                    timed.end.as_secs_f64() * 1e3,
                    (n * steps) as f64 / (timed.stepping + timed.end).as_secs_f64(),
                );
            };
            // As the actor runs them (the policy's passes on the
            // environments' threads), and with the passes on this thread as
            // before 2026-11-27's second change, for comparison.
            for (passes_on_threads, stepped) in [
                (true, "as the actor"),
                (false, "the policy on the loop's thread"),
            ] {
                if n == 1 && !passes_on_threads {
                    break;
                }
                let envs = unused.take().unwrap_or_else(new_envs);
                let (timed, batches, phases) = bench.free_running(envs, passes_on_threads);
                // The U-Net's batches ("—": on each environment's thread),
                // then what the steps were made of, as an actor's last
                // lines say it beside the learner.
                let unet = batches
                    .describe(timed.stepping)
                    .unwrap_or_else(|| "—".to_string());
                let phases = phases.describe().unwrap_or_default();
                row(stepped, timed, format!("{unet}; {phases}"));
            }
        }
    }
}

/// What [`several_envs_table`]'s runs share.
struct SeveralEnvs<'a> {
    layout: &'a PolicyLayout,
    space: &'a ActionSpace,
    policy: &'a (PolicyNet, Option<Arc<CpuPolicy>>),
    model: &'a RwLock<Option<AffordanceModel>>,
    device: &'a Device,
    inference: Inference,
}

impl SeveralEnvs<'_> {
    /// One episode of each of `envs`, free-running as the actor runs them:
    /// the policy's CPU pass on the environments' threads when
    /// `passes_on_threads` (and the policy has one), else on this thread over
    /// every observation that came in since its last pass (on the CPU one
    /// at a time); on a GPU the U-Net in the batching thread's batches.
    /// The stepping, the episode's end, what the batching thread did, and
    /// what the environments' steps were made of.
    fn free_running(
        &self,
        envs: Vec<FlatSimEnv>,
        passes_on_threads: bool,
    ) -> (Timed, BatchTimes, StepPhases) {
        let n = envs.len();
        std::thread::scope(|scope| {
            let boxed = envs
                .into_iter()
                .map(|env| Box::new(env) as Box<dyn Environment>)
                .collect();
            let threads = EnvThreads::start(scope, boxed, self.model, self.inference);
            if let (true, Some(cpu)) = (passes_on_threads, &self.policy.1) {
                threads.set_policy(1, cpu).expect("the policy");
            }
            for index in 0..n {
                threads
                    .send(index, Task::Reset(index as u64 + 1))
                    .expect("reset");
            }
            let mut rng = StdRng::seed_from_u64(1);
            let mut act = |ready: &[(usize, Observation, Option<PolicyPass>)]| {
                // As the actor: the passes not made on the environments'
                // threads one at a time on the CPU, else all at once.
                let observations: Vec<Observation> = ready
                    .iter()
                    .filter(|(_, _, pass)| pass.is_none())
                    .map(|(_, o, _)| o.clone())
                    .collect();
                let batches: Vec<&[Observation]> = match self.inference {
                    Inference::PerEnvironment => observations.chunks(1).collect(),
                    Inference::Batched => vec![&observations],
                };
                for batch in batches.into_iter().filter(|b| !b.is_empty()) {
                    policy_pass(self.policy, self.layout, batch, self.device, self.inference);
                }
                for (index, observation, pass) in ready {
                    let action =
                        random_allowed_action(self.space, &observation.action_mask, 0.5, &mut rng);
                    // The recurrent state on, as the actor sends it.
                    let hidden = pass.as_ref().and_then(|p| p.step.hidden.clone());
                    threads
                        .send(*index, Task::Step(action as u32, hidden))
                        .expect("step");
                }
            };
            let mut first = Vec::new();
            for _ in 0..n {
                match threads.next().expect("reset") {
                    (index, Done::Reset(observation, pass)) => {
                        first.push((index, observation, pass))
                    }
                    _ => panic!("a reset answered"),
                }
            }
            let start = Instant::now();
            let cpu_before = process_cpu_time();
            let before = batch_times();
            let phases_before = step_phases();
            act(&first);
            let mut stepped = vec![0; n];
            let mut running = n;
            while running > 0 {
                let mut finished = vec![threads.next().expect("step")];
                finished.extend(threads.finished().expect("steps"));
                let mut ready = Vec::new();
                for (index, done) in finished {
                    let Done::Step(_, observation, pass) = done else {
                        panic!("a step answered");
                    };
                    stepped[index] += 1;
                    if stepped[index] < episode_steps() {
                        ready.push((index, observation, pass));
                    } else {
                        running -= 1;
                    }
                }
                if !ready.is_empty() {
                    act(&ready);
                }
            }
            let stepping = start.elapsed();
            let cpu = cpu_since(cpu_before);
            let batches = batch_times().since(&before);
            let phases = step_phases().since(&phases_before);
            let end_started = Instant::now();
            for index in 0..n {
                threads
                    .send(index, Task::Finish(index as u64))
                    .expect("the episode's end");
            }
            for _ in 0..n {
                threads.next().expect("the episode's end");
            }
            let end = end_started.elapsed();
            (Timed { stepping, cpu, end }, batches, phases)
        })
    }
}

/// One episode of several environments: its stepping (wall and the
/// process's CPU time) and its end.
struct Timed {
    stepping: Duration,
    /// CPU time of every thread of the process while stepping: over the
    /// wall time, how many cores the environments kept busy (so whether a
    /// run is bound by the CPU). `None` where it could not be read.
    cpu: Option<Duration>,
    end: Duration,
}

/// This process's CPU time so far, all threads, user and system.
fn process_cpu_time() -> Option<Duration> {
    // SAFETY: getrusage only writes the `rusage` it is given, which is
    // ours, and all-zero bytes are a valid `rusage`.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: as above; RUSAGE_SELF names this process.
    if unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut usage) } != 0 {
        return None;
    }
    let time = |t: libc::timeval| {
        Duration::from_secs(t.tv_sec.max(0) as u64) + Duration::from_micros(t.tv_usec.max(0) as u64)
    };
    Some(time(usage.ru_utime) + time(usage.ru_stime))
}

/// The CPU time this process used since `before` ([`process_cpu_time`]).
fn cpu_since(before: Option<Duration>) -> Option<Duration> {
    Some(process_cpu_time()?.saturating_sub(before?))
}

/// Cores this process may run on (for the CPU column's heading).
fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// The policy's forward pass over `observations`, as the actor's loop runs
/// the passes its environments' threads did not make: one pass over all of
/// them, or one per observation and thread on the CPU (its own pass where
/// it has one, burn's otherwise). A fresh
/// episode's recurrent state (zeros) for GRU policies.
fn policy_pass(
    (policy, cpu): &(PolicyNet, Option<Arc<CpuPolicy>>),
    layout: &PolicyLayout,
    observations: &[Observation],
    device: &Device,
    inference: Inference,
) {
    if let Some(cpu) = cpu {
        let pass = |o: &Observation| {
            std::hint::black_box(o.cpu_pass(cpu, None));
        };
        // One observation stays on this thread, as in the actor's `forward_batch`.
        match observations {
            [alone] => pass(alone),
            several => several.par_iter().for_each(pass),
        }
        return;
    }
    let pass = |batch: &[&Observation]| {
        let n = batch.len();
        let features: Vec<f32> = batch
            .iter()
            .flat_map(|o| o.values.floats().into_owned())
            .collect();
        let masks: Vec<u8> = batch
            .iter()
            .flat_map(|o| o.action_mask.iter().copied())
            .collect();
        let hidden = layout
            .gru_hidden
            .map(|size| Tensor::<2>::zeros([n, size], device));
        let input = PolicyInput::from_flat(layout, &features, &masks, n, device);
        let out = policy.forward(&input, hidden);
        let log_probs: Vec<f32> = out
            .log_probs
            .into_data()
            .try_to_vec()
            .expect("the policy's log-probabilities");
        std::hint::black_box(log_probs);
    };
    match inference {
        Inference::PerEnvironment => observations.par_iter().for_each(|o| pass(&[o])),
        Inference::Batched => pass(&observations.iter().collect::<Vec<_>>()),
    }
}
