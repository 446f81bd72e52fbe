//! `actor evaluate`: a run's U-Net scored as the paper's Tables 1 and 2 in
//! rooms it never trained in (`actor::evaluation` does the scoring; this
//! reads the flags, loads the checkpoints, chooses one on the validation
//! rooms with `--select`, and writes the reports).

use std::path::PathBuf;

use actor::env::affordance_model::{AffordanceModel, CameraFrame};
use anyhow::Context;
use clap::Args;
use proto::EnvKind;
use sim::ithor::SceneSet;
use sim::profile::RobotProfile;
use sim::renderer::Renderer;

use super::sim_args::SimArgs;

/// `actor evaluate`'s flags.
#[derive(Args)]
pub(crate) struct EvaluateArgs {
    /// The run directory: its config.toml gives the image size and the
    /// affordances, its checkpoints/ the network.
    #[arg(long)]
    run_dir: PathBuf,
    /// Checkpoint step to evaluate (default: the newest).
    #[arg(long, conflicts_with_all = ["untrained", "select"])]
    step: Option<u64>,
    /// Choose the checkpoint on the validation rooms (FloorPlan221–225):
    /// score every checkpoint of the run there, then evaluate only the best
    /// on --scenes (test by default). The report says how each scored.
    #[arg(long, conflicts_with = "untrained")]
    select: bool,
    /// Validation views per room when choosing with --select.
    #[arg(long, default_value_t = 120)]
    val_views_per_scene: usize,
    /// With --select, score every checkpoint afresh even where the run's
    /// learner recorded validation scores during training
    /// (RUN_DIR/validation/): by default --select takes those and scores
    /// only the kept checkpoints without them, with as many views per room
    /// as the recorded ones.
    #[arg(long, requires = "select")]
    rescore: bool,
    /// Evaluate a freshly initialised network instead, its weights drawn
    /// from SEED (default: --seed): the floor a trained one must beat.
    #[arg(long, value_name = "SEED", num_args = 0..=1)]
    untrained: Option<Option<u64>>,
    /// Rooms: test (FloorPlan226–230), val (221–225) or train (201–220).
    #[arg(long, default_value = "test")]
    scenes: SceneSet,
    /// Test views per room for Table 1 (the paper had 611 frames over 5 rooms).
    #[arg(long, default_value_t = 120)]
    views_per_scene: usize,
    /// Seed of the test views: the same seed gives the same views (and
    /// objects), whatever network is evaluated.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Predict a pixel, or an object (its mean), positive at or above this
    /// probability. The paper's is 0.5; a threshold chosen on the validation
    /// rooms (the report's "thresholds that would do best") is for the test
    /// rooms, never chosen on them.
    #[arg(long, default_value_t = 0.5, value_parser = parse_threshold)]
    threshold: f32,
    /// Divide the logits by this instead of the checkpoint's calibration
    /// temperature (fitted on a few held-out frames each time the run
    /// deployed a network, so it swings from one to the next): for
    /// measuring how much the scores hang on that fit. A pixel's side of
    /// 0.5 does not move with it; an object's mean probability does.
    #[arg(long, value_parser = parse_temperature, conflicts_with = "untrained")]
    temperature: Option<f32>,
    /// Write the whole report (both tables, the all-positive reference,
    /// the selection and every object's trial) as JSON here.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
    /// Write the checkpoint's scores (per affordance: median pixel F1,
    /// Table 2's F1 and ROC AUC) as JSON here: the learner's background
    /// validation scorer runs `evaluate --step S --scenes val --scores
    /// RUN_DIR/validation/S.json`, and --select reads them back.
    #[arg(long, value_name = "FILE", conflicts_with_all = ["untrained", "select"])]
    scores: Option<PathBuf>,
    /// The robot and renderer: pass the ones the run trained with.
    #[command(flatten)]
    sim: SimArgs,
}

/// Runs `actor evaluate`.
pub(crate) fn evaluate(args: EvaluateArgs) -> anyhow::Result<()> {
    let config_path = args.run_dir.join("config.toml");
    let run_config = actor::config::run_config_from_toml_file(&config_path)?;
    let task = run_config.task;
    let sim = args.sim.resolve(&run_config.actors)?;
    anyhow::ensure!(
        task.env == EnvKind::Sim,
        "{} trains on {:?}, which has no affordance network to evaluate",
        config_path.display(),
        task.env
    );
    anyhow::ensure!(
        args.views_per_scene > 0 && args.val_views_per_scene > 0,
        "--views-per-scene and --val-views-per-scene must be at least 1"
    );
    anyhow::ensure!(
        !(args.select && matches!(args.scenes, SceneSet::Val)),
        "--select chooses the checkpoint on the validation rooms; evaluate it on others \
         (--scenes test, the default)"
    );
    let device = nets::device::open_device(nets::device::DeviceChoice::Cpu)?;
    let mut model = AffordanceModel::new(task.affordances.len(), &device);
    let profile = RobotProfile::load(&sim.profile)?;
    let rooms = sim.data.join("ithor-livingrooms");
    let load_rooms = |set: SceneSet| {
        sim::ithor::load_set(&rooms, set).with_context(|| {
            format!(
                "loading the rooms from {} (set --data or AFX_DATA to the shared data directory)",
                rooms.display()
            )
        })
    };
    let scenes = load_rooms(args.scenes)?;
    let mut renderer = Renderer::open(sim.renderer)?;
    let mut run = |model: &AffordanceModel, scenes: &[sim::scene::Scene], views, name: &str| {
        let predict = |frame: &sim::raycast::Frame| {
            model.predict(&CameraFrame {
                rgb: &frame.rgb,
                depth_m: &frame.depth_m,
                height: frame.height,
                width: frame.width,
            })
        };
        let settings = actor::evaluation::EvaluationSettings {
            model: name.to_string(),
            affordances: task.affordances.clone(),
            image_size: task.image_size,
            views_per_scene: views,
            seed: args.seed,
            threshold: args.threshold,
        };
        eprintln!(
            "evaluate: {name} in {} rooms at {} px with {}",
            scenes.len(),
            task.image_size,
            renderer.describe()
        );
        actor::evaluation::evaluate(
            scenes,
            &profile,
            &mut renderer,
            &predict,
            &settings,
            &mut |line| eprintln!("evaluate: {line}"),
        )
    };
    let load = |model: &mut AffordanceModel, step: Option<u64>| {
        let unet = actor::evaluation::load_checkpoint_unet(&args.run_dir, step)?;
        model.load_weights(unet.weights).with_context(|| {
            format!(
                "loading the U-Net of step {} (made for {:?} at {} px?)",
                unet.step, task.affordances, task.image_size
            )
        })?;
        model.temperature = args.temperature.unwrap_or(unet.temperature);
        let name = format!(
            "the U-Net of {} at step {} (temperature {}{})",
            args.run_dir.display(),
            unet.step,
            model.temperature,
            if args.temperature.is_some() {
                format!(", not its own {}", unet.temperature)
            } else {
                String::new()
            }
        );
        anyhow::Ok((unet.step, name))
    };
    let report = if let Some(seed) = args.untrained {
        // An untrained network's weights follow its seed, so its floor can be repeated.
        let seed = seed.unwrap_or(args.seed);
        device.seed(seed);
        model = AffordanceModel::new(task.affordances.len(), &device);
        let name = format!("an untrained U-Net (seed {seed})");
        run(&model, &scenes, args.views_per_scene, &name)?
    } else if args.select {
        let mut steps = actor::evaluation::checkpoint_steps(&args.run_dir)?;
        anyhow::ensure!(
            !steps.is_empty(),
            "{} has no checkpoint to choose from",
            args.run_dir.display()
        );
        let mut untrained = Vec::new();
        for &step in &steps {
            if !actor::evaluation::unet_has_trained(&args.run_dir, step)? {
                untrained.push(step);
            }
        }
        if !untrained.is_empty() {
            eprintln!(
                "evaluate: passing over checkpoint(s) {untrained:?}: their U-Net has not trained \
                 yet (an untrained network is a floor, scored with --untrained, not a result)"
            );
            steps.retain(|step| !untrained.contains(step));
        }
        anyhow::ensure!(
            !steps.is_empty(),
            "no checkpoint of {} holds a U-Net that has trained: train longer before choosing",
            args.run_dir.display()
        );
        let val = load_rooms(SceneSet::Val)?;
        let recorded = if args.rescore {
            Vec::new()
        } else {
            actor::evaluation::recorded_scores(&args.run_dir, &steps)?
        };
        let mut candidates = Vec::with_capacity(steps.len());
        // The validation reports made here, to read the chosen one's best thresholds.
        let mut validation_reports = std::collections::BTreeMap::new();
        let mut views_per_scene = args.val_views_per_scene;
        if let Some(first) = recorded.first() {
            views_per_scene = first.views_per_scene;
            eprintln!(
                "evaluate: {} of {} kept checkpoints were scored on the validation rooms during \
                 training ({views_per_scene} views per room); scoring the rest the same way \
                 (--rescore scores all afresh)",
                recorded.len(),
                steps.len()
            );
            candidates.extend(
                recorded
                    .iter()
                    .map(actor::evaluation::Candidate::from_scores),
            );
        }
        let to_score: Vec<u64> = steps
            .iter()
            .copied()
            .filter(|step| !recorded.iter().any(|r| r.step == *step))
            .collect();
        for (i, &step) in to_score.iter().enumerate() {
            let (_, name) = load(&mut model, Some(step))?;
            let report = run(&model, &val, views_per_scene, &name)?;
            let candidate = report.candidate(step);
            eprintln!(
                "evaluate: validation {}/{}: step {step} scores {:.3}",
                i + 1,
                to_score.len(),
                candidate.score
            );
            candidates.push(candidate);
            validation_reports.insert(step, report);
        }
        let mut selection = actor::evaluation::Selection::choose(
            val.iter().map(|s| s.name.clone()).collect(),
            views_per_scene,
            candidates,
        )
        .context("no checkpoint was scored")?;
        selection.recorded = recorded.len();
        let (step, name) = load(&mut model, Some(selection.chosen_step))?;
        // Scores recorded in the background hold no threshold sweep: the
        // chosen checkpoint is scored on the validation rooms once more.
        let validation = match validation_reports.remove(&step) {
            Some(report) => report,
            None => run(&model, &val, views_per_scene, &name)?,
        };
        let mut report = run(&model, &scenes, args.views_per_scene, &name)?;
        report.checkpoint_step = Some(step);
        report.selection = Some(selection);
        report.score_at_validation_thresholds(&validation);
        report
    } else {
        let (step, name) = load(&mut model, args.step)?;
        let mut report = run(&model, &scenes, args.views_per_scene, &name)?;
        report.checkpoint_step = Some(step);
        if let Some(path) = &args.scores {
            let scores = report.scores(step, args.views_per_scene);
            write_atomically(path, &serde_json::to_vec_pretty(&scores)?)?;
            eprintln!("evaluate: wrote the scores to {}", path.display());
        }
        report
    };
    print!("{}", report.to_markdown());
    if let Some(path) = &args.json {
        let text = serde_json::to_string_pretty(&report)?;
        std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))?;
        eprintln!("evaluate: wrote {}", path.display());
    }
    Ok(())
}

/// Writes `bytes` to `path` through a temporary file beside it, so that a
/// reader never sees half a file.
fn write_atomically(path: &std::path::Path, bytes: &[u8]) -> anyhow::Result<()> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let partial = path.with_extension("partial");
    std::fs::write(&partial, bytes).with_context(|| format!("writing {}", partial.display()))?;
    std::fs::rename(&partial, path).with_context(|| format!("writing {}", path.display()))
}

/// A probability strictly between 0 and 1.
fn parse_temperature(text: &str) -> Result<f32, String> {
    let value: f32 = text
        .parse()
        .map_err(|_| format!("'{text}' is not a number"))?;
    if value.is_finite() && value > 0.0 {
        Ok(value)
    } else {
        Err(format!(
            "{value} is not a positive temperature (1 leaves the logits as they are)"
        ))
    }
}

fn parse_threshold(text: &str) -> Result<f32, String> {
    let value: f32 = text
        .parse()
        .map_err(|_| format!("'{text}' is not a number"))?;
    if value > 0.0 && value < 1.0 {
        Ok(value)
    } else {
        Err(format!(
            "{value} is not a probability strictly between 0 and 1"
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn temperatures_must_be_positive_and_thresholds_strictly_between_0_and_1() {
        assert_eq!(parse_temperature("2.5"), Ok(2.5));
        for bad in ["0", "-1", "inf", "NaN", "warm"] {
            assert!(parse_temperature(bad).is_err(), "{bad}");
        }
        assert_eq!(parse_threshold("0.5"), Ok(0.5));
        for bad in ["0", "1", "1.5", "x"] {
            assert!(parse_threshold(bad).is_err(), "{bad}");
        }
    }
}
