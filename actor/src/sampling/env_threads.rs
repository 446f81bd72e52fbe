//! Environments on threads of their own, none waiting for the others.
//!
//! [`EnvThreads`] hands each environment its next reset, step or episode end
//! as soon as its last one is done, and the caller books whichever finishes
//! first: no step waits for the slowest environment's, and an episode's end
//! (labelling, tens of milliseconds) holds up no other environment.
//!
//! Each environment's thread runs in a rayon pool of one thread, so that the
//! map's parallel loops inside a step stay on that thread instead of handing
//! work to a pool whose threads compete with the environments.
//!
//! The U-Net sees each camera frame on its environment's thread
//! ([`Inference::PerEnvironment`], the CPU) or in the batches of one thread
//! that all environments hand their frames to ([`Inference::Batched`], a
//! GPU: [`super::unet_batcher`]).
//!
//! Once given a policy ([`EnvThreads::set_policy`]), each thread also runs
//! the policy's CPU pass on every observation it makes, so the caller finds
//! it done ([`PolicyPass`]) and only draws the action: the passes run in
//! parallel on the environments' own threads instead of one after another
//! on the caller's, which at 128 px made the caller the wall
//! (docs/notebook/2026-11-27-free-running-gpu-actor.md).

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::mpsc::{channel, Receiver, Sender};
use std::sync::{Arc, PoisonError, RwLock};
use std::thread::Scope;
use std::time::Instant;

use anyhow::{anyhow, Context};
use nets::policy::{CpuPolicy, CpuPolicyStep};

use super::named_thread::spawn_named;
use super::unet_batcher::{self, UnetClient};
use super::Inference;
use crate::env::affordance_model::{planes_for, AffordanceModel};
use crate::env::step_phases::{self, StepPhases};
use crate::env::{Environment, EpisodeEnd, Observation, StepOutcome};

/// Work for an environment.
#[derive(Debug, Clone, PartialEq)]
pub enum Task {
    /// Start an episode with this reset seed (the policy's pass over its
    /// first observation, if any, starts from a recurrent state of zeros).
    Reset(u64),
    /// Take this action; the policy's pass over the next observation, if
    /// any, starts from this recurrent state (`None`: zeros, or a policy
    /// without a GRU).
    Step(u32, Option<Vec<f32>>),
    /// End the episode with this id.
    Finish(u64),
}

/// The policy's CPU pass over an observation, made on its environment's
/// thread with the policy of `version` (see [`EnvThreads::set_policy`]).
#[derive(Debug, Clone, PartialEq)]
pub struct PolicyPass {
    /// The version of the policy that made it.
    pub version: u64,
    /// What the policy said, with the recurrent state after it (policies
    /// with a GRU).
    pub step: CpuPolicyStep,
}

/// What an environment did for its [`Task`].
#[derive(Debug)]
pub enum Done {
    /// The first observation of the episode, and the policy's pass over it
    /// once the threads have a policy.
    Reset(Observation, Option<PolicyPass>),
    /// The step's outcome and the next observation, with the policy's pass
    /// as for a reset.
    Step(StepOutcome, Observation, Option<PolicyPass>),
    /// The episode's labelled frames and metrics, and the scene it ran in.
    Finish {
        /// What the episode left behind.
        end: EpisodeEnd,
        /// Index of its scene.
        scene: u32,
    },
}

/// What the caller sends an environment's thread.
enum Job {
    Do(Task),
    GlobalSteps(u64),
    Policy(u64, Arc<CpuPolicy>),
}

/// The environments' threads, within a [`std::thread::scope`]; they end
/// when this is dropped (after the task each is doing).
pub struct EnvThreads {
    jobs: Vec<Sender<Job>>,
    done: Receiver<(usize, anyhow::Result<Done>)>,
}

impl EnvThreads {
    /// Starts a thread for each of `envs` in `scope`; `model` is the U-Net
    /// for their camera frames, which the caller may replace between tasks
    /// (a task or a batch holds it for reading while it runs), seen as
    /// `inference` says.
    pub fn start<'scope, 'env>(
        scope: &'scope Scope<'scope, 'env>,
        envs: Vec<Box<dyn Environment + 'env>>,
        model: &'env RwLock<Option<AffordanceModel>>,
        inference: Inference,
    ) -> Self {
        let (done_tx, done) = channel();
        let batcher = (inference == Inference::Batched)
            .then(|| unet_batcher::start(scope, model, unet_batcher::batching_threads()));
        let jobs = envs
            .into_iter()
            .enumerate()
            .map(|(index, env)| {
                let (job_tx, job_rx) = channel();
                let done_tx = done_tx.clone();
                let unet = match &batcher {
                    Some(clients) => Unet::Batched(clients.client()),
                    None => Unet::OnThisThread(model),
                };
                spawn_named(scope, format!("env-{index}"), move || {
                    serve(index, env, job_rx, done_tx, unet)
                });
                job_tx
            })
            .collect();
        Self { jobs, done }
    }

    /// How many environments there are.
    pub fn len(&self) -> usize {
        self.jobs.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.jobs.is_empty()
    }

    /// Queues `task` for environment `index`.
    pub fn send(&self, index: usize, task: Task) -> anyhow::Result<()> {
        self.job(index, Job::Do(task))
    }

    /// Tells every environment the run's environment steps (before its next task).
    pub fn set_global_steps(&self, steps: u64) -> anyhow::Result<()> {
        (0..self.len()).try_for_each(|index| self.job(index, Job::GlobalSteps(steps)))
    }

    /// From each environment's next task on, its observations come with
    /// the pass of `policy` (of `version`) over them.
    pub fn set_policy(&self, version: u64, policy: &Arc<CpuPolicy>) -> anyhow::Result<()> {
        (0..self.len())
            .try_for_each(|index| self.job(index, Job::Policy(version, Arc::clone(policy))))
    }

    /// Waits for the next task to finish: which environment, and what it did.
    pub fn next(&self) -> anyhow::Result<(usize, Done)> {
        let (index, done) = self
            .done
            .recv()
            .context("every environment's thread ended early")?;
        Ok((index, done.with_context(|| format!("environment {index}"))?))
    }

    /// The tasks finished since the last look, without waiting: the caller
    /// can act on several environments at once.
    pub fn finished(&self) -> anyhow::Result<Vec<(usize, Done)>> {
        self.done
            .try_iter()
            .map(|(index, done)| Ok((index, done.with_context(|| format!("environment {index}"))?)))
            .collect()
    }

    fn job(&self, index: usize, job: Job) -> anyhow::Result<()> {
        self.jobs
            .get(index)
            .context("no such environment")?
            .send(job)
            .map_err(|_| anyhow!("environment {index}'s thread ended early"))
    }
}

/// Where an environment's thread gets the U-Net's planes for its frames.
enum Unet<'env> {
    /// From the model, on this thread.
    OnThisThread(&'env RwLock<Option<AffordanceModel>>),
    /// From the batching thread.
    Batched(UnetClient),
}

impl Unet<'_> {
    /// The planes for `env`'s camera frame (none without a camera).
    fn planes_for(&self, env: &dyn Environment) -> anyhow::Result<Vec<Vec<f32>>> {
        match (self, env.camera_frame()) {
            (_, None) => Ok(Vec::new()),
            (Unet::OnThisThread(model), frame) => planes_for(
                frame,
                model
                    .read()
                    .unwrap_or_else(PoisonError::into_inner)
                    .as_ref(),
            ),
            (Unet::Batched(client), Some(frame)) => client.predict(&frame),
        }
    }
}

/// An environment's thread: does its jobs in order until the caller hangs up.
fn serve(
    index: usize,
    mut env: Box<dyn Environment + '_>,
    jobs: Receiver<Job>,
    done: Sender<(usize, anyhow::Result<Done>)>,
    unet: Unet<'_>,
) {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .thread_name(move |_| format!("env-{index}"))
        .build();
    let pool = match pool {
        Ok(pool) => pool,
        Err(e) => {
            let _ = done.send((index, Err(anyhow!("starting its thread pool: {e}"))));
            return;
        }
    };
    pool.install(move || {
        let mut policy = None;
        for job in jobs.iter() {
            let result = match job {
                Job::GlobalSteps(steps) => {
                    env.set_global_steps(steps);
                    continue;
                }
                Job::Policy(version, net) => {
                    policy = Some((version, net));
                    continue;
                }
                Job::Do(task) => catch_unwind(AssertUnwindSafe(|| {
                    work(env.as_mut(), task, &unet, policy.as_ref())
                }))
                .unwrap_or_else(|_| Err(anyhow!("the environment panicked"))),
            };
            if done.send((index, result)).is_err() {
                return;
            }
        }
    });
}

/// One task of an environment, with `policy`'s pass over its observation.
fn work(
    env: &mut dyn Environment,
    task: Task,
    unet: &Unet<'_>,
    policy: Option<&(u64, Arc<CpuPolicy>)>,
) -> anyhow::Result<Done> {
    let pass = |observation: &Observation, hidden: Option<&[f32]>| {
        policy.map(|(version, net)| PolicyPass {
            version: *version,
            step: observation.cpu_pass(net, hidden),
        })
    };
    Ok(match task {
        Task::Reset(seed) => {
            env.begin_reset(seed)?;
            let planes = unet.planes_for(env)?;
            let observation = env.observe(planes)?;
            let pass = pass(&observation, None);
            Done::Reset(observation, pass)
        }
        Task::Step(action, hidden) => {
            let started = Instant::now();
            let outcome = env.begin_step(action)?;
            let acted = Instant::now();
            let planes = unet.planes_for(env)?;
            let planned = Instant::now();
            let observation = env.observe(planes)?;
            let observed = Instant::now();
            let pass = pass(&observation, hidden.as_deref());
            step_phases::record(&StepPhases {
                steps: 1,
                acting: acted - started,
                rendering: env.last_render_time(),
                unet: planned - acted,
                state: observed - planned,
                policy: observed.elapsed(),
            });
            Done::Step(outcome, observation, pass)
        }
        Task::Finish(id) => {
            let scene = env.scene_index();
            Done::Finish {
                end: env.finish_episode(id)?,
                scene,
            }
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::env::affordance_model::CameraFrame;
    use crate::env::BanditFixture;
    use crate::env::ObservationValues;
    use proto::PolicyLayout;

    /// Bandits have no camera, so no U-Net.
    static NO_MODEL: RwLock<Option<AffordanceModel>> = RwLock::new(None);

    /// `n` bandit environments.
    fn bandits(n: usize) -> Vec<Box<dyn Environment>> {
        (0..n)
            .map(|_| Box::new(BanditFixture::new()) as Box<dyn Environment>)
            .collect()
    }

    /// Stands for a reset in the lists of outcomes.
    const RESET: StepOutcome = StepOutcome {
        reward: 0.0,
        done: false,
        success: false,
    };

    /// The action for step `k` of the environment reset with `seed`.
    fn action(seed: u64, k: u32) -> u32 {
        (seed as u32 + 3 * k) % 4
    }

    #[test]
    fn each_environment_does_what_it_does_alone_whatever_the_interleaving() {
        let seeds = [3u64, 5, 8];
        let model = &NO_MODEL;
        let mut seen: Vec<Vec<(StepOutcome, Observation)>> = vec![Vec::new(); seeds.len()];
        let mut ends = vec![None; seeds.len()];
        std::thread::scope(|scope| {
            let envs = bandits(seeds.len());
            let threads = EnvThreads::start(scope, envs, model, Inference::PerEnvironment);
            assert_eq!(threads.len(), 3);
            for (index, &seed) in seeds.iter().enumerate() {
                threads.send(index, Task::Reset(seed)).unwrap();
            }
            let mut finished = 0;
            while finished < seeds.len() {
                let (index, done) = threads.next().unwrap();
                let steps = seen[index].len() as u32;
                match done {
                    Done::Reset(observation, None) => {
                        seen[index].push((RESET, observation));
                        threads
                            .send(index, Task::Step(action(seeds[index], 0), None))
                            .unwrap();
                    }
                    Done::Step(outcome, observation, None) => {
                        seen[index].push((outcome, observation));
                        let task = if outcome.done {
                            Task::Finish(index as u64)
                        } else {
                            Task::Step(action(seeds[index], steps), None)
                        };
                        threads.send(index, task).unwrap();
                    }
                    Done::Finish { end, scene } => {
                        assert_eq!(scene, 0);
                        ends[index] = Some(end);
                        finished += 1;
                    }
                    _ => panic!("a pass without a policy"),
                }
            }
        });
        for (index, &seed) in seeds.iter().enumerate() {
            let mut alone = BanditFixture::new();
            let mut expected = vec![(RESET, alone.reset(seed, None).unwrap())];
            for k in 0..64 {
                expected.push(alone.step(action(seed, k), None).unwrap());
            }
            assert_eq!(seen[index], expected, "environment {index}");
            assert_eq!(
                ends[index].as_ref(),
                Some(&alone.finish_episode(index as u64).unwrap())
            );
        }
    }

    /// Steps panic; everything else is a bandit's.
    struct Panicking(BanditFixture);

    impl Environment for Panicking {
        fn layout(&self) -> &PolicyLayout {
            self.0.layout()
        }
        fn scene_index(&self) -> u32 {
            0
        }
        fn begin_reset(&mut self, seed: u64) -> anyhow::Result<()> {
            self.0.begin_reset(seed)
        }
        fn begin_step(&mut self, _action: u32) -> anyhow::Result<StepOutcome> {
            panic!("a bug in the environment")
        }
        fn camera_frame(&self) -> Option<CameraFrame<'_>> {
            None
        }
        fn observe(&mut self, affordances: Vec<Vec<f32>>) -> anyhow::Result<Observation> {
            self.0.observe(affordances)
        }
        fn finish_episode(&mut self, id: u64) -> anyhow::Result<EpisodeEnd> {
            self.0.finish_episode(id)
        }
        fn set_global_steps(&mut self, _steps: u64) {}
    }

    /// A bandit with a camera, which its reset seed shades: its
    /// observation's features are the U-Net's first plane for its frame.
    struct Seeing {
        bandit: BanditFixture,
        rgb: Vec<u8>,
        depth_m: Vec<f32>,
    }

    const SEEING_SIDE: usize = 8;

    impl Seeing {
        fn frame(&self) -> CameraFrame<'_> {
            CameraFrame {
                rgb: &self.rgb,
                depth_m: &self.depth_m,
                height: SEEING_SIDE,
                width: SEEING_SIDE,
            }
        }
    }

    impl Environment for Seeing {
        fn layout(&self) -> &PolicyLayout {
            self.bandit.layout()
        }
        fn scene_index(&self) -> u32 {
            0
        }
        fn begin_reset(&mut self, seed: u64) -> anyhow::Result<()> {
            let pixels = SEEING_SIDE * SEEING_SIDE;
            self.rgb = (0..3 * pixels).map(|i| (i as u64 * seed) as u8).collect();
            self.depth_m = (0..pixels)
                .map(|i| 0.3 + (i as u64 % seed) as f32)
                .collect();
            self.bandit.begin_reset(seed)
        }
        fn begin_step(&mut self, action: u32) -> anyhow::Result<StepOutcome> {
            self.bandit.begin_step(action)
        }
        fn camera_frame(&self) -> Option<CameraFrame<'_>> {
            Some(self.frame())
        }
        fn observe(&mut self, affordances: Vec<Vec<f32>>) -> anyhow::Result<Observation> {
            let mut observation = self.bandit.observe(Vec::new())?;
            observation.values = ObservationValues::Floats(affordances[0].clone());
            Ok(observation)
        }
        fn finish_episode(&mut self, id: u64) -> anyhow::Result<EpisodeEnd> {
            self.bandit.finish_episode(id)
        }
        fn set_global_steps(&mut self, _steps: u64) {}
    }

    #[test]
    fn each_environment_gets_the_planes_of_its_own_frame_on_its_thread_or_batched() {
        let device = nets::device::open_device(nets::device::DeviceChoice::Cpu).unwrap();
        let model = RwLock::new(Some(AffordanceModel::new(2, &device)));
        let seeds = [3u64, 5, 8, 13];
        let seeing = || Seeing {
            bandit: BanditFixture::new(),
            rgb: Vec::new(),
            depth_m: Vec::new(),
        };
        let mut expected = Vec::new();
        for &seed in &seeds {
            let mut env = seeing();
            env.begin_reset(seed).unwrap();
            let planes = model
                .read()
                .unwrap()
                .as_ref()
                .unwrap()
                .predict(&env.frame());
            expected.push(planes[0].clone());
        }
        for (k, a) in expected.iter().enumerate() {
            for b in &expected[k + 1..] {
                assert_ne!(a, b, "the frames tell the environments apart");
            }
        }
        for inference in [Inference::PerEnvironment, Inference::Batched] {
            let mut got = vec![Vec::new(); seeds.len()];
            std::thread::scope(|scope| {
                let envs = seeds
                    .iter()
                    .map(|_| Box::new(seeing()) as Box<dyn Environment>)
                    .collect();
                let threads = EnvThreads::start(scope, envs, &model, inference);
                for (index, &seed) in seeds.iter().enumerate() {
                    threads.send(index, Task::Reset(seed)).unwrap();
                }
                for _ in 0..seeds.len() {
                    let (index, Done::Reset(observation, None)) = threads.next().unwrap() else {
                        panic!("a reset answered");
                    };
                    got[index] = observation.values.floats().into_owned();
                }
            });
            for (k, (g, e)) in got.iter().zip(&expected).enumerate() {
                assert_eq!(g.len(), e.len(), "{inference:?}, environment {k}");
                let worst = g
                    .iter()
                    .zip(e)
                    .map(|(x, y)| (x - y).abs())
                    .fold(0.0, f32::max);
                assert!(worst < 1e-6, "{inference:?}, environment {k}: {worst}");
            }
        }
    }

    #[test]
    fn with_a_policy_each_observation_comes_with_that_policys_pass_from_the_state_given() {
        let device = nets::device::open_device(nets::device::DeviceChoice::Cpu).unwrap();
        // A GRU, so that the recurrent state the caller sends matters.
        let layout = PolicyLayout {
            gru_hidden: Some(8),
            ..BanditFixture::new().layout().clone()
        };
        let policy = || {
            let net = nets::policy::PolicyNet::new(&layout, &device);
            Arc::new(CpuPolicy::from_network(&net, &layout).expect("a CPU pass"))
        };
        let (first, second) = (policy(), policy());
        let seeds = [3u64, 5];
        let model = &NO_MODEL;
        std::thread::scope(|scope| {
            let envs = bandits(seeds.len());
            let threads = EnvThreads::start(scope, envs, model, Inference::PerEnvironment);
            threads.set_policy(1, &first).unwrap();
            for (index, &seed) in seeds.iter().enumerate() {
                threads.send(index, Task::Reset(seed)).unwrap();
            }
            for _ in 0..seeds.len() {
                let (index, Done::Reset(observation, Some(pass))) = threads.next().unwrap() else {
                    panic!("a reset with its pass answered");
                };
                let by = |p: &CpuPolicy| observation.cpu_pass(p, None);
                assert_eq!(
                    pass,
                    PolicyPass {
                        version: 1,
                        step: by(&first)
                    },
                    "environment {index}"
                );
                assert_ne!(by(&first), by(&second), "the two policies tell apart");
            }
            threads.set_policy(2, &second).unwrap();
            let state = |index: usize| -> Vec<f32> {
                (0..8).map(|i| (i + index) as f32 / 8.0 - 0.5).collect()
            };
            for index in 0..seeds.len() {
                threads
                    .send(index, Task::Step(0, Some(state(index))))
                    .unwrap();
            }
            for _ in 0..seeds.len() {
                let (index, Done::Step(_, observation, Some(pass))) = threads.next().unwrap()
                else {
                    panic!("a step with its pass answered");
                };
                let from = |h: Option<&[f32]>| observation.cpu_pass(&second, h);
                let step = from(Some(&state(index)));
                assert_ne!(step, from(None), "the state tells apart");
                assert_eq!(pass, PolicyPass { version: 2, step }, "environment {index}");
            }
        });
    }

    #[test]
    fn a_panicking_environment_is_an_error_for_the_caller_not_a_hang() {
        let model = &NO_MODEL;
        std::thread::scope(|scope| {
            let envs: Vec<Box<dyn Environment>> = vec![
                Box::new(BanditFixture::new()),
                Box::new(Panicking(BanditFixture::new())),
            ];
            let threads = EnvThreads::start(scope, envs, model, Inference::PerEnvironment);
            threads.send(1, Task::Reset(1)).unwrap();
            assert!(matches!(threads.next().unwrap(), (1, Done::Reset(..))));
            threads.send(1, Task::Step(0, None)).unwrap();
            let error = threads.next().unwrap_err();
            assert!(
                format!("{error:#}").contains("environment 1: the environment panicked"),
                "{error:#}"
            );
            assert!(
                threads.send(7, Task::Step(0, None)).is_err(),
                "no environment 7"
            );
        });
    }
}
