//! `docs/results.md`: the comparison `deploy/reproduce.sh` produces, built
//! from its run directories and never edited by hand. Every (method, seed)
//! the manifest lists must have trained and been evaluated; a missing run
//! or a missing field is an error, not a gap in a table.

mod differences;
mod history;
mod page;
mod paper;
mod paper_settings;

pub use history::{HistorySummary, Tenth};
pub use page::render;

use std::path::{Path, PathBuf};

use anyhow::Context;
use serde::Deserialize;

use crate::evaluation::Report;

/// File name of the manifest `deploy/reproduce.sh` writes into its root.
pub(crate) const MANIFEST_FILE: &str = "reproduce.json";

/// What `deploy/reproduce.sh` ran: the comparison's settings.
#[derive(Debug, Clone, PartialEq, Deserialize)]
pub struct Manifest {
    /// The command line that produced the comparison.
    pub command: String,
    /// Methods and variants (`ours`, `ours-paper-labels`, `nomap-seg`, …),
    /// in the order the page shows them.
    pub variants: Vec<String>,
    /// Seeds of every variant.
    pub seeds: Vec<u64>,
    /// Environment steps each run trained for.
    pub steps: u64,
    /// Environment steps after which confidence labels start.
    pub confidence_after_steps: u64,
    /// The `deploy/local.sh` options every run shared.
    pub local_options: String,
    /// Seed of the test and validation views.
    pub views_seed: u64,
    /// Test views per room.
    pub views_per_scene: usize,
    /// Validation views per room.
    pub val_views_per_scene: usize,
    /// The machine, in words.
    pub machine: String,
    /// The commit the binaries were built from.
    pub commit: String,
    /// When the comparison started (UTC).
    pub started: String,
}

/// One (variant, seed) run: its test report and its history.
#[derive(Debug, Clone)]
pub struct RunResult {
    /// The variant.
    pub variant: String,
    /// The seed.
    pub seed: u64,
    /// The test evaluation of the checkpoint validation chose.
    pub report: Report,
    /// What its history says about its course.
    pub history: HistorySummary,
    /// Per affordance of the report, the chosen checkpoint's Table 2 ROC
    /// AUC on the validation rooms, where the run's learner recorded it
    /// (`RUN_DIR/validation/<step>.json`; a checkpoint `--select` scored
    /// itself has none).
    pub chosen_validation_auc: Vec<Option<f32>>,
}

/// Everything the page is made of.
#[derive(Debug, Clone)]
pub struct Comparison {
    /// The manifest.
    pub manifest: Manifest,
    /// Every run, variant by variant in the manifest's order, seeds in order.
    pub runs: Vec<RunResult>,
    /// The untrained network's test report per seed.
    pub untrained: Vec<(u64, Report)>,
    /// The first run's `config.toml` (every setting), when it has one.
    pub first_config: Option<String>,
}

/// A run's directory under the comparison's root.
pub fn run_dir(root: &Path, variant: &str, seed: u64) -> PathBuf {
    root.join(format!("{variant}-seed{seed}"))
}

/// Where a run's test report lives.
pub fn test_report_path(run_dir: &Path) -> PathBuf {
    run_dir.join("eval").join("test.json")
}

/// Where the untrained network's report for `seed` lives.
pub fn untrained_report_path(root: &Path, seed: u64) -> PathBuf {
    root.join("floors")
        .join(format!("untrained-seed{seed}.json"))
}

/// Reads the whole comparison under `root`; an error names the first run
/// or file that is missing or incomplete.
pub fn load(root: &Path) -> anyhow::Result<Comparison> {
    let manifest_path = root.join(MANIFEST_FILE);
    let manifest: Manifest = read_json(&manifest_path)?;
    anyhow::ensure!(
        !manifest.variants.is_empty() && !manifest.seeds.is_empty(),
        "{} lists no variant or no seed",
        manifest_path.display()
    );
    let mut runs = Vec::new();
    for variant in &manifest.variants {
        for &seed in &manifest.seeds {
            let dir = run_dir(root, variant, seed);
            let report: Report = read_report(&test_report_path(&dir)).with_context(|| {
                format!(
                    "run {variant} seed {seed} has not been evaluated (rerun deploy/reproduce.sh \
                     with the same options: it resumes)"
                )
            })?;
            check_complete(&report)
                .with_context(|| format!("the test report of {variant} seed {seed}"))?;
            anyhow::ensure!(
                report.selection.is_some(),
                "the test report of {variant} seed {seed} was not chosen on the validation rooms"
            );
            let history = HistorySummary::read(&dir.join("history.jsonl"))?;
            let chosen_validation_auc = chosen_validation_auc(&dir, &report);
            runs.push(RunResult {
                variant: variant.clone(),
                seed,
                report,
                history,
                chosen_validation_auc,
            });
        }
    }
    let mut untrained = Vec::new();
    for &seed in &manifest.seeds {
        let report: Report = read_report(&untrained_report_path(root, seed))
            .with_context(|| format!("the untrained network's floor for seed {seed}"))?;
        check_complete(&report)
            .with_context(|| format!("the untrained network's report for seed {seed}"))?;
        untrained.push((seed, report));
    }
    let first = &runs[0].report;
    for run in &runs {
        anyhow::ensure!(
            run.report.scenes == first.scenes && run.report.frames == first.frames,
            "{} seed {} was scored on other rooms or views ({} frames in {:?}) than {} seed {} \
             ({} in {:?}): every run must see the same test set",
            run.variant,
            run.seed,
            run.report.frames,
            run.report.scenes,
            runs[0].variant,
            runs[0].seed,
            first.frames,
            first.scenes
        );
    }
    let first_config =
        std::fs::read_to_string(run_dir(root, &runs[0].variant, runs[0].seed).join("config.toml"))
            .ok();
    Ok(Comparison {
        manifest,
        runs,
        untrained,
        first_config,
    })
}

/// Fails unless both tables have a row for each affordance with every
/// count the page shows (a score undefined for lack of positives is not
/// missing: the page says how many runs define it).
fn check_complete(report: &Report) -> anyhow::Result<()> {
    anyhow::ensure!(
        !report.pixel.is_empty() && report.pixel.len() == report.object.len(),
        "Table 1 has {} rows and Table 2 {}",
        report.pixel.len(),
        report.object.len()
    );
    anyhow::ensure!(
        report.frames > 0 && !report.trials.is_empty(),
        "no test frame or no object was scored"
    );
    anyhow::ensure!(
        report.trials.len() + report.objects_unseen.len() == report.objects,
        "{} objects scored and {} unseen, of {}: Table 2 must count every object once",
        report.trials.len(),
        report.objects_unseen.len(),
        report.objects
    );
    for (pixel, object) in report.pixel.iter().zip(&report.object) {
        anyhow::ensure!(
            pixel.affordance == object.affordance,
            "the tables' rows disagree: {} against {}",
            pixel.affordance,
            object.affordance
        );
        let c = object.confusion;
        anyhow::ensure!(
            c.true_positives + c.false_positives + c.true_negatives + c.false_negatives
                == report.trials.len(),
            "Table 2's {} counts {} objects, not the {} scored",
            object.affordance,
            c.true_positives + c.false_positives + c.true_negatives + c.false_negatives,
            report.trials.len()
        );
        anyhow::ensure!(
            pixel.f1.is_some() && pixel.object_accuracy.is_some() && object.accuracy.is_some(),
            "{}: Table 1's F1 or object accuracy, or Table 2's accuracy, is missing",
            pixel.affordance
        );
    }
    Ok(())
}

/// Reads an evaluation report, refusing one that lacks a field (serde
/// would read a missing optional score as undefined).
fn read_report(path: &Path) -> anyhow::Result<Report> {
    let value: serde_json::Value = read_json(path)?;
    let report: Report = serde_json::from_value(value.clone())
        .with_context(|| format!("parsing {}", path.display()))?;
    if let Some(missing) = first_missing(&value, &serde_json::to_value(&report)?, "") {
        anyhow::bail!("{} has no `{missing}`", path.display());
    }
    Ok(report)
}

/// The path of the first key of `complete` that `given` lacks.
fn first_missing(
    given: &serde_json::Value,
    complete: &serde_json::Value,
    at: &str,
) -> Option<String> {
    use serde_json::Value;
    match (given, complete) {
        (Value::Object(given), Value::Object(complete)) => complete.iter().find_map(|(k, v)| {
            let path = if at.is_empty() {
                k.clone()
            } else {
                format!("{at}.{k}")
            };
            match given.get(k) {
                None => Some(path),
                Some(g) => first_missing(g, v, &path),
            }
        }),
        (Value::Array(given), Value::Array(complete)) => given
            .iter()
            .zip(complete)
            .enumerate()
            .find_map(|(i, (g, c))| first_missing(g, c, &format!("{at}[{i}]"))),
        _ => None,
    }
}

/// The ROC AUC per affordance of `report` that the run's learner recorded
/// for the checkpoint validation chose, on as many views as the selection
/// scored (so from the same scoring); `None` where it recorded none.
fn chosen_validation_auc(run_dir: &Path, report: &Report) -> Vec<Option<f32>> {
    let recorded = report.selection.as_ref().and_then(|s| {
        let path = run_dir
            .join(proto::VALIDATION_DIR)
            .join(format!("{}.json", s.chosen_step));
        let scores = read_json::<proto::ValidationScores>(&path).ok()?;
        (scores.views_per_scene == s.views_per_scene).then_some(scores)
    });
    report
        .pixel
        .iter()
        .map(|row| {
            let scores = recorded.as_ref()?;
            let own = scores
                .affordances
                .iter()
                .find(|a| a.affordance == row.affordance)?;
            own.object_auc
        })
        .collect()
}

fn read_json<T: serde::de::DeserializeOwned>(path: &Path) -> anyhow::Result<T> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    serde_json::from_str(&text).with_context(|| format!("parsing {}", path.display()))
}
