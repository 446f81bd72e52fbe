//! The `ours` environment end to end on a generated room: simulator, map,
//! U-Net, state, mask, reward and the labeler at the episode's end.

use actor::env::actions::{random_allowed_action, PolicyAction};
use actor::env::affordance_model::AffordanceModel;
use actor::env::sim_env::{ActionOutcome, SimEnv, SimEnvConfig, SimObservation};
use actor::env::step_phases::step_phases;
use actor::env::{Environment, ObservationValues};
use actor::sampling::env_threads::{Done, EnvThreads, Task};
use actor::sampling::unet_batcher::batch_times;
use actor::sampling::Inference;
use foxglove::messages::{CameraCalibration, FrameTransform, Grid, RawImage, SceneUpdate};
use foxglove::Decode;
use mapper::Affordance;
use proto::{AffordanceStat, Method, StatField, StatKey, LABEL_UNKNOWN};
use rand::rngs::StdRng;
use rand::SeedableRng;
use sim::agent::Failure;
use sim::ithor::SceneSet;
use sim::profile::RobotProfile;
use sim::renderer::{Renderer, RendererChoice};
use sim::scenes::SceneSource;
use std::sync::RwLock;

const AFFORDANCES: [Affordance; 2] = [Affordance::PickUp, Affordance::Push];

fn environment(steps: usize) -> SimEnv {
    environment_for(Method::Ours, steps)
}

/// A freshly initialised U-Net on the CPU.
fn unet() -> AffordanceModel {
    let device = nets::device::open_device(nets::device::DeviceChoice::Cpu).unwrap();
    AffordanceModel::new(AFFORDANCES.len(), &device)
}

fn environment_for(method: Method, steps: usize) -> SimEnv {
    environment_with(method, steps, |_| {})
}

fn environment_with(
    method: Method,
    steps: usize,
    change: impl FnOnce(&mut SimEnvConfig),
) -> SimEnv {
    let data = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data");
    let profile = RobotProfile::load("default").unwrap();
    let source = SceneSource::open(
        Some(&data.join("ithor-livingrooms")),
        SceneSet::Test,
        &data.join("ithor-object-types.tsv"),
        &profile,
    )
    .unwrap();
    let mut config = SimEnvConfig {
        episode_steps: steps,
        balanced_frames: false,
        ..SimEnvConfig::paper(method, &AFFORDANCES)
    };
    change(&mut config);
    SimEnv::new(
        config,
        source,
        profile,
        Renderer::open(RendererChoice::Cpu).unwrap(),
    )
}

fn run(
    env: &mut SimEnv,
    model: &AffordanceModel,
    seed: u64,
    steps: usize,
) -> (
    Vec<(ActionOutcome, Option<Affordance>)>,
    Vec<SimObservation>,
) {
    let mut rng = StdRng::seed_from_u64(seed);
    let mut observation = env.reset(seed, model).unwrap();
    let (mut outcomes, mut observations) = (Vec::new(), vec![observation.clone()]);
    for step in 0..steps {
        let action = random_allowed_action(env.action_space(), &observation.mask, 0.5, &mut rng);
        assert_eq!(observation.mask[action], 1);
        let (outcome, next) = env.step(action, model).unwrap();
        assert!(outcome.reward.is_finite());
        assert_eq!(
            outcome.done,
            step + 1 == steps,
            "done exactly at the budget"
        );
        let tried = match env.action_space().get(action) {
            Some(PolicyAction::Select { affordance, .. }) => Some(affordance),
            _ => None,
        };
        outcomes.push((outcome, tried));
        observation = next;
        observations.push(observation.clone());
    }
    (outcomes, observations)
}

#[test]
fn cell_ratings_in_the_state_follow_the_cells_the_mask_offers() {
    let steps = 12;
    let mut env = environment_with(Method::Ours, steps, |c| {
        c.selection.ratings_in_state = true;
    });
    assert_eq!(env.state_config().ratings_len, 9 * AFFORDANCES.len());
    let (_, observations) = run(&mut env, &unet(), 3, steps);
    let space = env.action_space().actions().to_vec();
    let mut offered = 0;
    for o in &observations {
        assert_eq!(o.state.ratings().len(), 9 * AFFORDANCES.len());
        for (index, action) in space.iter().enumerate() {
            if let PolicyAction::Select {
                affordance: Affordance::Push,
                cell,
            } = *action
            {
                let rating = o.state.ratings()[9 + cell];
                // An untrained sigmoid says about one half, never a byte's 0.
                assert_eq!(o.mask[index] == 1, rating > 0, "cell {cell}");
                offered += usize::from(rating > 0);
            }
        }
    }
    assert!(offered > 0, "some cell offered an object to push");
}

#[test]
fn an_episode_runs_labels_and_repeats_exactly() {
    let steps = 40;
    let mut env = environment(steps);
    let model = unet();
    let n_actions = env.action_space().len();
    assert_eq!(n_actions, 30);
    let (outcomes, observations) = run(&mut env, &model, 2, steps);
    let config = env.state_config().clone();
    for o in &observations {
        assert_eq!(o.mask.len(), n_actions);
        assert_eq!(o.state.camera().len(), config.camera_channels() * 128 * 128);
        assert_eq!(
            o.state.global_map().len(),
            config.map_channels() * 128 * 128
        );
        assert_eq!(o.state.history().len(), config.history_len());
    }
    let interactions = outcomes.iter().filter(|(o, _)| o.reward != 0.0).count();
    let attempts: Vec<&ActionOutcome> = outcomes
        .iter()
        .filter(|(_, tried)| tried.is_some())
        .map(|(o, _)| o)
        .collect();
    println!(
        "{} of {steps} steps succeeded, return {:.1}",
        outcomes.iter().filter(|(o, _)| o.success).count(),
        outcomes.iter().map(|(o, _)| o.reward).sum::<f32>()
    );
    assert!(interactions > 0);
    let timings = env.last_timings();
    println!("last step: {timings:?}");
    let summary = env.finish_episode(9).unwrap();
    let batch = summary.frames;
    assert_eq!(batch.n_affordances, 2);
    let stats: std::collections::HashMap<_, _> = summary.stats.into_iter().collect();
    println!("episode metrics: {stats:?}");
    let per = |affordance, stat| StatKey::Affordance(affordance, stat);
    let wide = StatKey::Episode;
    for field in [
        wide(StatField::InteractionSuccessRate),
        wide(StatField::InteractedObjectRate),
        wide(StatField::InteractableAnnotationRate),
        wide(StatField::NonInteractableAnnotationRate),
        wide(StatField::AffordanceIou),
        wide(StatField::ObjectAccuracy),
        wide(StatField::InteractionAttemptRate),
        wide(StatField::InteractionOutOfReachRate),
        wide(StatField::InteractionUnaffordedRate),
        per(Affordance::PickUp, AffordanceStat::Iou),
        per(Affordance::Push, AffordanceStat::Iou),
        per(Affordance::PickUp, AffordanceStat::ObjectAccuracy),
        per(Affordance::Push, AffordanceStat::ObjectAccuracy),
    ] {
        let v = stats[&field];
        assert!((0.0..=1.0).contains(&v), "{field:?} = {v}");
    }
    for (both, plane) in [
        (wide(StatField::AffordanceIou), AffordanceStat::Iou),
        (
            wide(StatField::ObjectAccuracy),
            AffordanceStat::ObjectAccuracy,
        ),
    ] {
        let (pick_up, push) = (per(Affordance::PickUp, plane), per(Affordance::Push, plane));
        let (lo, hi) = (
            stats[&pick_up].min(stats[&push]),
            stats[&pick_up].max(stats[&push]),
        );
        assert!(
            (lo - 1e-6..=hi + 1e-6).contains(&stats[&both]),
            "{both:?} = {} averages the planes' {lo} and {hi}",
            stats[&both]
        );
    }
    assert!(
        !attempts.is_empty(),
        "a random policy that favours interactions tries some"
    );
    assert_eq!(
        stats[&wide(StatField::InteractionAttemptRate)],
        attempts.len() as f32 / steps as f32,
        "one attempt per pick-up or push selected"
    );
    assert_eq!(
        Some(stats[&wide(StatField::InteractionOutOfReachRate)]),
        failed_share(&attempts, |f| matches!(f, Failure::OutOfReach { .. })),
        "attempts that failed beyond reach"
    );
    assert_eq!(
        Some(stats[&wide(StatField::InteractionUnaffordedRate)]),
        failed_share(&attempts, Failure::object_does_not_afford),
        "attempts on objects that do not afford the action"
    );
    for affordance in [Affordance::PickUp, Affordance::Push] {
        let [attempt_rate, success_rate, out_of_reach_rate, unafforded_rate, no_room_rate] = [
            AffordanceStat::AttemptRate,
            AffordanceStat::SuccessRate,
            AffordanceStat::OutOfReachRate,
            AffordanceStat::UnaffordedRate,
            AffordanceStat::NoRoomRate,
        ]
        .map(|stat| per(affordance, stat));
        let tried: Vec<&ActionOutcome> = outcomes
            .iter()
            .filter(|(_, tried)| *tried == Some(affordance))
            .map(|(o, _)| o)
            .collect();
        assert_eq!(
            stats[&attempt_rate],
            tried.len() as f32 / steps as f32,
            "{affordance:?} attempts per step"
        );
        let succeeded = tried.iter().filter(|o| o.success).count();
        assert_eq!(
            stats.get(&success_rate).copied(),
            (!tried.is_empty()).then(|| succeeded as f32 / tried.len() as f32),
            "{affordance:?} successes per attempt"
        );
        assert_eq!(
            stats.get(&out_of_reach_rate).copied(),
            failed_share(&tried, |f| matches!(f, Failure::OutOfReach { .. })),
            "{affordance:?} attempts beyond reach"
        );
        assert_eq!(
            stats.get(&unafforded_rate).copied(),
            failed_share(&tried, Failure::object_does_not_afford),
            "{affordance:?} attempts on objects that do not afford it"
        );
        assert_eq!(
            stats.get(&no_room_rate).copied(),
            failed_share(&tried, |f| matches!(f, Failure::NoRoom { .. })),
            "{affordance:?} attempts without room"
        );
        // The frames sent are some of the episode's: their labels are a
        // lower bound of the episode's label shares.
        let pixels = 128 * 128;
        let plane = [Affordance::PickUp, Affordance::Push]
            .iter()
            .position(|&a| a == affordance)
            .unwrap();
        let sent = |label: u8| {
            batch
                .labels
                .chunks(pixels)
                .skip(plane)
                .step_by(2)
                .flatten()
                .filter(|&&l| l == label)
                .count() as f32
        };
        let all = ((steps + 1) * pixels) as f32;
        let positive = stats[&per(affordance, AffordanceStat::PositiveLabelShare)];
        let negative = stats[&per(affordance, AffordanceStat::NegativeLabelShare)];
        assert!(
            positive * all + 0.5 >= sent(proto::LABEL_POSITIVE),
            "{affordance:?}"
        );
        assert!(
            negative * all + 0.5 >= sent(proto::LABEL_NEGATIVE),
            "{affordance:?}"
        );
        assert!(positive + negative <= 1.0);
    }
    assert!(batch.n_frames() <= steps + 1);
    println!("labelled frames: {}", batch.n_frames());

    let (again, observations_again) = run(&mut env, &model, 2, steps);
    assert_eq!(outcomes, again, "same seed, same episode");
    assert!(observations == observations_again);
    assert!(
        env.step(99, &model).is_err(),
        "an action outside the space is an error"
    );
}

/// Labelled pixels of a batch.
fn labelled(batch: &proto::FrameBatch) -> usize {
    batch.labels.iter().filter(|&&l| l != LABEL_UNKNOWN).count()
}

#[test]
fn annotation_by_confidence_starts_at_the_configured_global_step() {
    let steps = 12;
    let mut env = environment(steps);
    // A near-zero temperature makes every probability 0 or 1: the U-Net is
    // "sure" about every object, so every untouched object gets a label.
    let mut model = unet();
    model.temperature = 1e-3;
    run(&mut env, &model, 5, steps);
    env.set_global_steps(399_999);
    assert!(!env.annotates_by_confidence());
    let before = labelled(&env.finish_episode(1).unwrap().frames);
    run(&mut env, &model, 5, steps);
    env.set_global_steps(400_000);
    assert!(env.annotates_by_confidence());
    let after = labelled(&env.finish_episode(2).unwrap().frames);
    println!("labelled pixels: {before} by interaction only, {after} with confidence");
    assert!(after > before, "{after} <= {before}");
}

#[test]
fn a_recorded_episode_holds_every_frame_label_and_step() {
    let steps = 6;
    let mut env = environment(steps);
    let dir = std::env::temp_dir().join(format!("afx-record-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    env.record_to(dir.clone(), "test_".into(), 2);
    env.set_global_steps(1234);
    run(&mut env, &unet(), 3, steps);
    env.finish_episode(7).unwrap();
    // Every second episode: 7 is not recorded, 8 is, and 8 again (a
    // restarted actor's) goes beside it instead of over it.
    assert_eq!(
        std::fs::read_dir(&dir).unwrap().count(),
        0,
        "episode 7 skipped"
    );
    for _ in 0..2 {
        run(&mut env, &unet(), 3, steps);
        env.finish_episode(8).unwrap();
    }
    let first = dir.join("test_step000001234_episode000008.mcap");
    assert!(dir.join("test_step000001234_episode000008_2.mcap").exists());
    let plane_names = env.state_config().map_plane_names();
    let bytes = std::fs::read(first).unwrap();
    let mut counts = std::collections::BTreeMap::<String, usize>::new();
    let mut objects = 0;
    for message in mcap::MessageStream::new(&bytes).unwrap() {
        let message = message.unwrap();
        let topic = message.channel.topic.as_str();
        let schema = message.channel.schema.as_ref().unwrap().name.as_str();
        let data = &message.data[..];
        match schema {
            "foxglove.RawImage" => {
                let image = RawImage::decode(data).unwrap();
                assert_eq!((image.width, image.height), (128, 128), "{topic}");
                assert_eq!(image.data.len(), (image.step * image.height) as usize);
                let encoding = match topic {
                    "/camera/depth" => "32FC1",
                    t if t.ends_with("/raw") => "16UC1",
                    t if t.starts_with("/labels/") || t.starts_with("/unet/") => "mono8",
                    _ => "rgb8",
                };
                assert_eq!(image.encoding, encoding, "{topic}");
            }
            "foxglove.FrameTransform" => {
                let tf = FrameTransform::decode(data).unwrap();
                assert_eq!(
                    (tf.parent_frame_id.as_str(), tf.child_frame_id.as_str()),
                    ("world", "camera")
                );
            }
            "foxglove.CameraCalibration" => {
                let calibration = CameraCalibration::decode(data).unwrap();
                assert_eq!(calibration.k[8], 1.0);
                assert!(calibration.k[0] > 10.0, "fx {}", calibration.k[0]);
            }
            "foxglove.Grid" => {
                let grid = Grid::decode(data).unwrap();
                let names: Vec<String> = grid.fields.iter().map(|f| f.name.clone()).collect();
                assert_eq!(names, plane_names, "{topic}");
                assert_eq!(grid.column_count, 128);
                assert_eq!(grid.data.len(), (grid.row_stride * 128) as usize);
            }
            "foxglove.SceneUpdate" => {
                let update = SceneUpdate::decode(data).unwrap();
                objects = update.entities.len();
                for entity in &update.entities {
                    let mesh = &entity.triangles[0];
                    assert!(!mesh.indices.is_empty(), "{} has no triangles", entity.id);
                    assert!(mesh
                        .indices
                        .iter()
                        .all(|&i| (i as usize) < mesh.points.len()));
                    assert!(entity.metadata.iter().any(|kv| kv.key == "pick_up"));
                }
            }
            "afx.PolicyStep" => {
                let value: serde_json::Value = serde_json::from_slice(data).unwrap();
                assert!(value["reward"].is_number() && value["action_name"].is_string());
            }
            other => panic!("{topic}: unexpected schema {other}"),
        }
        *counts.entry(topic.to_owned()).or_default() += 1;
    }
    let frames = steps + 1;
    for topic in [
        "/tf",
        "/camera/calibration",
        "/camera/rgb",
        "/camera/depth",
        "/camera/instance_ids",
        "/camera/instance_ids/raw",
        "/map/object_ids",
        "/map/object_ids/raw",
        "/labels/pick_up",
        "/labels/push",
        "/unet/pick_up",
        "/unet/push",
        "/map/global",
        "/map/local",
    ] {
        assert_eq!(counts.get(topic), Some(&frames), "{topic}: {counts:?}");
    }
    assert_eq!(counts.get("/policy/step"), Some(&steps));
    assert_eq!(counts.get("/map/objects"), Some(&1));
    assert!(objects > 0, "the map's objects are in the recording");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn methods_without_a_map_fit_their_layout_and_label_from_interaction_points() {
    let steps = 40;
    let model = unet();
    for method in [Method::NomapSeg, Method::NomapNoseg, Method::Intexp] {
        let env = environment_for(method, steps);
        let task = proto::TaskSpec {
            method,
            affordances: AFFORDANCES.to_vec(),
            ..proto::TaskSpec::default()
        };
        let layout = task.layout();
        assert_eq!(env.action_space().len(), layout.n_actions);
        // The wrapper checks the state against the task's layout.
        let mut env = actor::env::FlatSimEnv::new(env, &task).unwrap();
        let mut rng = StdRng::seed_from_u64(3);
        let mut observation = env.reset(3, Some(&model)).unwrap();
        let mut interactions = 0;
        for _ in 0..steps {
            // The environment makes the bytes the rollout carries.
            let ObservationValues::Bytes(bytes) = &observation.values else {
                panic!("{method:?}: an environment's observation in floats");
            };
            assert_eq!(bytes.len(), layout.obs_len(), "{method:?}");
            let space = env.inner().action_space();
            let action = random_allowed_action(space, &observation.action_mask, 0.5, &mut rng);
            let is_interaction = matches!(
                space.get(action),
                Some(actor::env::actions::PolicyAction::Select { .. })
            );
            interactions += usize::from(is_interaction);
            observation = env.step(action as u32, Some(&model)).unwrap().1;
        }
        let end = env.finish_episode(1).unwrap();
        let frames = end.frames.unwrap();
        println!(
            "{method:?}: {interactions} interactions, {} labelled frames, {} labelled pixels",
            frames.n_frames(),
            labelled(&frames)
        );
        let stats: std::collections::HashMap<_, _> = end.stats.into_iter().collect();
        for v in stats.values() {
            assert!(v.is_finite());
        }
        if method != Method::Intexp {
            assert!(interactions > 0, "{method:?}");
        }
        if interactions > 0 {
            assert!(
                labelled(&frames) > 0,
                "{method:?}: interactions leave labels"
            );
        }
    }
}

/// `seeds.len()` environments of `task` stepped together for `steps` steps
/// on the actor's threads (random allowed actions, a generator per
/// environment seeded like it): every environment's observations.
fn play_together(
    task: &proto::TaskSpec,
    model: &RwLock<Option<AffordanceModel>>,
    seeds: &[u64],
    steps: usize,
    inference: Inference,
) -> Vec<Vec<actor::env::Observation>> {
    let envs: Vec<actor::env::FlatSimEnv> = seeds
        .iter()
        .map(|_| actor::env::FlatSimEnv::new(environment(steps), task).unwrap())
        .collect();
    let spaces: Vec<_> = envs
        .iter()
        .map(|e| e.inner().action_space().clone())
        .collect();
    let mut rngs: Vec<StdRng> = seeds.iter().map(|&s| StdRng::seed_from_u64(s)).collect();
    let mut traces: Vec<Vec<actor::env::Observation>> = vec![Vec::new(); seeds.len()];
    std::thread::scope(|scope| {
        let boxed = envs
            .into_iter()
            .map(|e| Box::new(e) as Box<dyn Environment>)
            .collect();
        let threads = EnvThreads::start(scope, boxed, model, inference);
        for (index, &seed) in seeds.iter().enumerate() {
            threads.send(index, Task::Reset(seed)).unwrap();
        }
        let mut running = seeds.len();
        while running > 0 {
            let (index, done) = threads.next().unwrap();
            let observation = match done {
                Done::Reset(observation, _) | Done::Step(_, observation, _) => observation,
                Done::Finish { .. } => panic!("no episode was ended"),
            };
            traces[index].push(observation.clone());
            if traces[index].len() > steps {
                running -= 1;
                continue;
            }
            let mask = &observation.action_mask;
            let action = random_allowed_action(&spaces[index], mask, 0.5, &mut rngs[index]);
            threads
                .send(index, Task::Step(action as u32, None))
                .unwrap();
        }
    });
    traces
}

#[test]
fn environments_on_the_actors_threads_play_exactly_the_episodes_they_play_alone() {
    let steps = 10;
    let model = RwLock::new(Some(unet()));
    let task = proto::TaskSpec {
        method: Method::Ours,
        affordances: AFFORDANCES.to_vec(),
        episode_steps: steps,
        ..proto::TaskSpec::default()
    };
    let seeds = [2u64, 3];
    // Each environment alone, its actions drawn from its own generator.
    let mut alone = Vec::new();
    for &seed in &seeds {
        let model = model.read().unwrap();
        let mut env = actor::env::FlatSimEnv::new(environment(steps), &task).unwrap();
        let mut rng = StdRng::seed_from_u64(seed);
        let mut observation = env.reset(seed, model.as_ref()).unwrap();
        let mut trace = vec![observation.clone()];
        for _ in 0..steps {
            let space = env.inner().action_space();
            let action = random_allowed_action(space, &observation.action_mask, 0.5, &mut rng);
            let (outcome, next) = env.step(action as u32, model.as_ref()).unwrap();
            trace.push(next.clone());
            observation = next;
            assert!(outcome.reward.is_finite());
        }
        alone.push(trace);
    }
    assert!(alone[0] != alone[1], "two seeds, two episodes");
    // Together, each with its U-Net pass on its own thread (the CPU's way):
    // exactly the same episodes, each step's phases timed.
    let phases_before = step_phases();
    let threaded = play_together(&task, &model, &seeds, steps, Inference::PerEnvironment);
    for (i, (a, b)) in alone.iter().zip(&threaded).enumerate() {
        assert!(
            a == b,
            "environment {i} played another episode on its thread"
        );
    }
    // (Other tests of this binary may add steps of their own meanwhile.)
    let phases = step_phases().since(&phases_before);
    assert!(phases.steps >= (seeds.len() * steps) as u64, "{phases:?}");
    assert!(
        [phases.acting, phases.unet, phases.state]
            .iter()
            .all(|d| !d.is_zero()),
        "{phases:?}"
    );
    // Together, the frames through the batching thread (the GPU's way): a
    // batch may round differently in the last bits, so the state may differ
    // by a byte level; the masks, and so the actions, are the same.
    let batches_before = batch_times();
    let batched = play_together(&task, &model, &seeds, steps, Inference::Batched);
    let batches = batch_times().since(&batches_before);
    assert!(
        batches.frames >= (seeds.len() * (steps + 1)) as u64,
        "{batches:?}"
    );
    for (i, (a, b)) in alone.iter().zip(&batched).enumerate() {
        for (step, (x, y)) in a.iter().zip(b).enumerate() {
            assert_eq!(x.action_mask, y.action_mask, "environment {i}, step {step}");
            let worst = x
                .values
                .floats()
                .iter()
                .zip(y.values.floats().iter())
                .map(|(p, q)| (p - q).abs())
                .fold(0.0f32, f32::max);
            assert!(
                worst <= 1.5 / 255.0,
                "environment {i}, step {step}: {worst}"
            );
        }
    }
}

/// The share of `tried` that failed for `why`; `None` when nothing was tried.
fn failed_share(tried: &[&ActionOutcome], why: fn(&Failure) -> bool) -> Option<f32> {
    let failed = tried
        .iter()
        .filter(|o| o.failure.as_ref().is_some_and(why))
        .count();
    (!tried.is_empty()).then(|| failed as f32 / tried.len() as f32)
}

/// Runs `actor/tests/read_recording.py` on `file` with the shipped Foxglove
/// layout; `None` (skipped, said) when Python or its `mcap` packages are
/// missing, unless `AFX_REQUIRE_PYTHON_CHECKS` is set (CI sets it).
fn python_reads(file: &std::path::Path) -> Option<serde_json::Value> {
    let required = std::env::var_os("AFX_REQUIRE_PYTHON_CHECKS").is_some();
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let output = match std::process::Command::new("python3")
        .arg(root.join("tests/read_recording.py"))
        .arg(file)
        .arg(root.join("../deploy/foxglove-layout.json"))
        .output()
    {
        Ok(o) => o,
        Err(e) if !required => {
            eprintln!("skipping: python3 not runnable ({e})");
            return None;
        }
        Err(e) => panic!("python3 not runnable: {e}"),
    };
    let stderr = String::from_utf8_lossy(&output.stderr);
    if !output.status.success() {
        if stderr.contains("ModuleNotFoundError") && !required {
            eprintln!("skipping: `pip install mcap mcap-protobuf-support lz4` to run this check");
            return None;
        }
        panic!("Python could not decode the recording:\n{stderr}");
    }
    Some(serde_json::from_slice(&output.stdout).expect("the reader prints JSON"))
}

#[test]
fn python_decodes_every_message_of_a_recording_and_the_layout_finds_its_topics() {
    let steps = 4;
    let mut env = environment(steps);
    let dir = std::env::temp_dir().join(format!("afx-record-py-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    env.record_to(dir.clone(), "py_".into(), 1);
    run(&mut env, &unet(), 5, steps);
    env.finish_episode(1).unwrap();
    let file = std::fs::read_dir(&dir)
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    let Some(seen) = python_reads(&file) else {
        return;
    };
    let _ = std::fs::remove_dir_all(&dir);
    let topics = &seen["topics"];
    println!("{}", serde_json::to_string_pretty(&seen).unwrap());
    assert_eq!(seen["layout_topics_missing"], serde_json::json!([]));
    assert_eq!(topics["/camera/rgb"]["size"], serde_json::json!([128, 128]));
    assert_eq!(topics["/camera/rgb"]["messages"], steps + 1);
    assert_eq!(topics["/camera/depth"]["image_encoding"], "32FC1");
    assert_eq!(
        topics["/tf"]["frames"],
        serde_json::json!(["world", "camera"])
    );
    assert_eq!(topics["/camera/calibration"]["K"][8], 1.0);
    let names = env.state_config().map_plane_names();
    assert_eq!(topics["/map/global"]["fields"], serde_json::json!(names));
    assert_eq!(topics["/map/global"]["rows"], 128);
    assert!(topics["/map/objects"]["entities"].as_u64().unwrap() > 0);
    assert!(topics["/map/objects"]["triangles"].as_u64().unwrap() > 100);
    assert_eq!(
        topics["/map/objects"]["metadata_keys"],
        serde_json::json!(["class", "pick_up", "push"])
    );
    assert_eq!(topics["/policy/step"]["encoding"], "json");
    assert_eq!(topics["/policy/step"]["messages"], steps);
}

#[test]
fn the_ladder_dataset_holds_the_truth_the_tried_objects_and_the_runs_labels() {
    let steps = 30;
    let dir = tempfile::tempdir().unwrap();
    let mut env = environment(steps);
    env.dataset_to(dir.path().to_path_buf(), "t_".into(), 1, 2);
    let model = unet();
    run(&mut env, &model, 2, steps);
    env.finish_episode(4).unwrap();
    let files: Vec<_> = std::fs::read_dir(dir.path().join(proto::DATASET_EPISODES_DIR))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    assert_eq!(files.len(), 1, "{files:?}");
    let bytes = std::fs::read(&files[0]).unwrap();
    let limits = proto::Limits {
        max_actors: 1,
        max_payload_len: bytes.len() as u64,
    };
    let proto::Message::Frames(view) = proto::decode(&bytes, &limits).unwrap().1 else {
        panic!("an episode file holds frames");
    };
    let planes = AFFORDANCES.len();
    assert_eq!(view.n_affordances as usize, 3 * planes);
    // Every 2nd frame, but those no source labels at all (a view of bare
    // walls under the paper's rules): nothing to learn from them.
    let kept = view.n_frames as usize;
    assert!(kept > 0 && kept <= (steps + 1).div_ceil(2), "{kept} frames");
    let pixels = (view.height * view.width) as usize;
    let plane = |frame: usize, rung: proto::LabelRung, a: usize| {
        let p = rung.planes(planes).start + a;
        &view.labels[(frame * 3 * planes + p) * pixels..][..pixels]
    };
    let labelled = |labels: &[u8]| labels.iter().filter(|&&l| l != LABEL_UNKNOWN).count();
    let (mut truth, mut run_labels) = (0, 0);
    for frame in 0..view.n_frames as usize {
        for a in 0..planes {
            let (l0, l1, l2) = (
                plane(frame, proto::LabelRung::GroundTruth, a),
                plane(frame, proto::LabelRung::TriedTruth, a),
                plane(frame, proto::LabelRung::Run, a),
            );
            // The run labels only tried objects (and the background, as
            // every rung does): where it says anything, L1 does too.
            for (&tried, &run) in l1.iter().zip(l2) {
                assert!(run == LABEL_UNKNOWN || tried != LABEL_UNKNOWN);
            }
            truth += labelled(l0);
            run_labels += labelled(l2);
        }
    }
    assert!(
        truth > run_labels,
        "the ground truth labels every object in view"
    );

    let mut baseline = environment_for(Method::NomapNoseg, 5);
    baseline.dataset_to(dir.path().join("baseline"), "b_".into(), 1, 1);
    run(&mut baseline, &model, 2, 5);
    let err = baseline.finish_episode(1).unwrap_err();
    assert!(
        format!("{err:#}").contains("needs a method with a map"),
        "{err:#}"
    );
}
