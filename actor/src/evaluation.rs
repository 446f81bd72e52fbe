//! The paper's test evaluation of an affordance network in rooms it never
//! trained in (FloorPlan226–230 by default). Table 1 scores its pixels on a
//! fixed set of views against the simulator's ground truth (precision,
//! recall, F1 and object accuracy per frame, as median and 10th / 90th
//! percentile). Table 2 places the robot in front of every object, tries
//! each affordance there, and scores the network's object-level prediction
//! (the mean of its pixels) against what happened. Both tables also score
//! predicting everything positive on the same views and objects, the floor
//! a network must beat.

mod by_type;
mod object_trials;
mod report;
mod selection;
mod test_views;
mod weights;

pub use object_trials::{sight_object, try_affordance, ObjectView, Sighting, SEARCH_RADIUS_M};
pub use report::{
    AtValidationThreshold, Confusion, ObjectRow, ObjectTrial, Percentiles, PixelRow, Reference,
    Report, ScoredBy, ThresholdF1, THRESHOLDS,
};
pub use selection::{recorded_scores, Candidate, Selection, RULE as SELECTION_RULE};
pub(crate) use test_views::test_views;
pub use weights::{checkpoint_steps, load_checkpoint_unet, unet_has_trained, CheckpointUnet};

use anyhow::Context;
use proto::Affordance;
use sim::profile::RobotProfile;
use sim::randomise::reachable_grid;
use sim::raycast::Frame;
use sim::renderer::Renderer;
use sim::scene::Scene;

use crate::frame_scores::{ground_truth_planes, pixel_scores, score_frame, PixelScores};

/// What to evaluate and how much.
#[derive(Debug, Clone)]
pub struct EvaluationSettings {
    /// What the report calls the network.
    pub model: String,
    /// Affordances, in the network's plane order.
    pub affordances: Vec<Affordance>,
    /// Side of the camera's square images, pixels (the run's
    /// `[task] image_size`, what the network takes).
    pub image_size: usize,
    /// Test views per room (Table 1).
    pub views_per_scene: usize,
    /// Seed of the test views.
    pub seed: u64,
    /// A pixel, or an object's mean, at or above it is predicted positive
    /// (the paper's 0.5, or one chosen on the validation rooms).
    pub threshold: f32,
}

/// The network under evaluation (or a stand-in in tests): per affordance,
/// the probability plane of one frame.
pub type Predictor<'a> = dyn Fn(&Frame) -> Vec<Vec<f32>> + 'a;

/// Runs both tables over `scenes` (as loaded, not randomised), telling
/// `progress` about each room as it finishes.
pub fn evaluate(
    scenes: &[Scene],
    profile: &RobotProfile,
    renderer: &mut Renderer,
    predict: &Predictor<'_>,
    settings: &EvaluationSettings,
    progress: &mut dyn FnMut(&str),
) -> anyhow::Result<Report> {
    let planes = settings.affordances.len();
    let mut frame_scores: Vec<Vec<(PixelScores, Option<f32>)>> = vec![Vec::new(); planes];
    // Per plane and threshold of THRESHOLDS, each view's pixel F1.
    let mut f1_by_threshold: Vec<Vec<Vec<Option<f32>>>> =
        vec![vec![Vec::new(); THRESHOLDS.len()]; planes];
    let mut false_positives = vec![FalsePositives::default(); planes];
    let mut all_positive_scores: Vec<Vec<(PixelScores, Option<f32>)>> = vec![Vec::new(); planes];
    let mut all_positive_false = vec![FalsePositives::default(); planes];
    let mut trials = Vec::new();
    let mut objects_unseen = Vec::new();
    let mut scored: Vec<Vec<(f32, bool)>> = vec![Vec::new(); planes];
    let mut frames = 0;
    for (room, scene) in scenes.iter().enumerate() {
        let truth = ground_truth_planes(scene, profile, &settings.affordances);
        let affords = |plane: usize| {
            let truth = &truth;
            move |id: u32| truth.get(id as usize - 1).is_some_and(|t| t[plane])
        };
        let is_structure = |id: u32| {
            id == 0
                || scene
                    .objects
                    .get(id as usize - 1)
                    .is_some_and(|o| o.is_floor())
        };
        let reachable = reachable_grid(scene, profile)
            .with_context(|| format!("finding where the agent fits in {}", scene.name))?;
        let seed = settings
            .seed
            .wrapping_add((room as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
        let views = test_views(
            scene,
            profile,
            settings.image_size,
            &reachable,
            renderer,
            settings.views_per_scene,
            seed,
        )?;
        for view in &views {
            let probabilities = predict(view);
            let everything = vec![1.0; view.ids.len()];
            for plane in 0..planes {
                let p = probabilities
                    .get(plane)
                    .context("the network has too few planes")?;
                let affords = affords(plane);
                for (threshold, f1s) in THRESHOLDS.iter().zip(&mut f1_by_threshold[plane]) {
                    f1s.push(pixel_scores(p, &view.ids, &affords, *threshold).f1);
                }
                for (p, scores, false_positives) in [
                    (p, &mut frame_scores[plane], &mut false_positives[plane]),
                    (
                        &everything,
                        &mut all_positive_scores[plane],
                        &mut all_positive_false[plane],
                    ),
                ] {
                    let threshold = settings.threshold;
                    let object_accuracy =
                        score_frame(p, &view.ids, &affords, threshold).object_accuracy;
                    false_positives.add(p, &view.ids, &affords, &is_structure, threshold);
                    scores.push((
                        pixel_scores(p, &view.ids, &affords, threshold),
                        object_accuracy,
                    ));
                }
            }
        }
        frames += views.len();
        let mut tried = 0;
        let mut judged = 0;
        for (index, object) in scene.objects.iter().enumerate() {
            if object.is_floor() {
                continue;
            }
            let sighting = sight_object(
                scene,
                profile,
                settings.image_size,
                &reachable,
                index,
                renderer,
            )?;
            let (view, scored_by) = match sighting {
                Sighting::Reachable(view) => (view, ScoredBy::Trial),
                Sighting::OutOfReach(view) => (view, ScoredBy::GroundTruth),
                Sighting::Unseen => {
                    objects_unseen.push(format!("{}/{}", scene.name, object.id));
                    continue;
                }
            };
            let probabilities = predict(&view.frame);
            let mut trial = ObjectTrial {
                scene: scene.name.clone(),
                object: object.id.clone(),
                object_type: object.object_type.clone(),
                pixels: view.pixels.len(),
                distance_m: view.distance_m,
                predicted: Vec::with_capacity(planes),
                scored_by,
                succeeded: Vec::with_capacity(planes),
                failure: Vec::with_capacity(planes),
            };
            for (plane, &affordance) in settings.affordances.iter().enumerate() {
                let p = probabilities
                    .get(plane)
                    .context("the network has too few planes")?;
                let mean =
                    view.pixels.iter().map(|&i| p[i]).sum::<f32>() / view.pixels.len() as f32;
                let (success, failure) = match scored_by {
                    ScoredBy::Trial => try_affordance(&view, affordance),
                    ScoredBy::GroundTruth => (truth[index][plane], None),
                };
                scored[plane].push((mean, success));
                trial.predicted.push(mean);
                trial.succeeded.push(success);
                trial.failure.push(failure.map(|f| format!("{f:?}")));
            }
            trials.push(trial);
            match scored_by {
                ScoredBy::Trial => tried += 1,
                ScoredBy::GroundTruth => judged += 1,
            }
        }
        progress(&format!(
            "{}: {} test views, {tried} objects tried, {judged} judged by the ground truth (out of reach)",
            scene.name,
            views.len()
        ));
    }
    let names: Vec<String> = settings
        .affordances
        .iter()
        .map(|a| a.as_str().to_string())
        .collect();
    // The median F1 at each threshold, per plane (none for a reference).
    let sweeps: Vec<Vec<ThresholdF1>> = f1_by_threshold
        .iter()
        .map(|per_threshold| {
            THRESHOLDS
                .iter()
                .zip(per_threshold)
                .filter_map(|(&threshold, f1s)| {
                    let f1 = Percentiles::of(f1s.iter().copied())?.median;
                    Some(ThresholdF1 { threshold, f1 })
                })
                .collect()
        })
        .collect();
    let pixel_rows = |scores: &[Vec<(PixelScores, Option<f32>)>],
                      false_positives: &[FalsePositives],
                      sweeps: &[Vec<ThresholdF1>]| {
        names
            .iter()
            .zip(scores.iter().zip(false_positives))
            .enumerate()
            .map(
                |(plane, (affordance, (scores, false_positives)))| PixelRow {
                    affordance: affordance.clone(),
                    precision: Percentiles::of(scores.iter().map(|s| s.0.precision)),
                    recall: Percentiles::of(scores.iter().map(|s| s.0.recall)),
                    f1: Percentiles::of(scores.iter().map(|s| s.0.f1)),
                    object_accuracy: Percentiles::of(scores.iter().map(|s| s.1)),
                    false_positives_on_structure: false_positives.on_structure_share(),
                    f1_by_threshold: sweeps.get(plane).cloned().unwrap_or_default(),
                },
            )
            .collect::<Vec<_>>()
    };
    let object_rows = |scored: &[Vec<(f32, bool)>], threshold: f32| {
        names
            .iter()
            .zip(scored)
            .map(|(affordance, scored)| ObjectRow::at(affordance.clone(), scored, threshold))
            .collect::<Vec<_>>()
    };
    let everything: Vec<Vec<(f32, bool)>> = scored
        .iter()
        .map(|s| s.iter().map(|&(_, truth)| (1.0, truth)).collect())
        .collect();
    Ok(Report {
        model: settings.model.clone(),
        checkpoint_step: None,
        selection: None,
        scenes: scenes.iter().map(|s| s.name.clone()).collect(),
        frames,
        threshold: settings.threshold,
        pixel: pixel_rows(&frame_scores, &false_positives, &sweeps),
        objects: trials.len() + objects_unseen.len(),
        objects_unseen,
        object: object_rows(&scored, settings.threshold),
        trials,
        all_positive: Reference {
            name: "all positive".into(),
            pixel: pixel_rows(&all_positive_scores, &all_positive_false, &[]),
            object: object_rows(&everything, crate::frame_scores::PAPER_THRESHOLD),
        },
        at_validation_thresholds: Vec::new(),
    })
}

/// Pixels wrongly predicted positive, and how many of them lie on the
/// floor and walls.
#[derive(Debug, Clone, Copy, Default)]
struct FalsePositives {
    all: usize,
    on_structure: usize,
}

impl FalsePositives {
    fn add(
        &mut self,
        probabilities: &[f32],
        ids: &[u32],
        affords: &dyn Fn(u32) -> bool,
        is_structure: &dyn Fn(u32) -> bool,
        threshold: f32,
    ) {
        for (&p, &id) in probabilities.iter().zip(ids) {
            if p >= threshold && (id == 0 || !affords(id)) {
                self.all += 1;
                self.on_structure += usize::from(is_structure(id));
            }
        }
    }

    fn on_structure_share(&self) -> Option<f32> {
        (self.all > 0).then(|| self.on_structure as f32 / self.all as f32)
    }
}
