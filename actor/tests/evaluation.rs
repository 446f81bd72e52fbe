//! The test evaluation (the paper's Tables 1 and 2) on a real test room,
//! with the simulator's ground truth standing in for the network: it must
//! score perfectly on Table 1, its opposite must score nothing, and on
//! Table 2 every object the robot picked up must be one the rules allow;
//! every object is counted once, the same seed gives the same views and
//! objects, and the all-positive reference recalls everything.

use actor::evaluation::{evaluate, EvaluationSettings, Predictor, Report, ScoredBy};
use actor::frame_scores::ground_truth_planes;
use proto::Affordance;
use sim::ithor::load_scene;
use sim::profile::RobotProfile;
use sim::raycast::Frame;
use sim::renderer::{Renderer, RendererChoice};
use sim::scene::Scene;

const AFFORDANCES: [Affordance; 2] = [Affordance::PickUp, Affordance::Push];

fn room() -> (Scene, RobotProfile) {
    let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data/ithor-livingrooms/FloorPlan227.json");
    let profile = RobotProfile::load("default").unwrap();
    (load_scene(&path).unwrap(), profile)
}

fn run(scene: &Scene, profile: &RobotProfile, predict: &Predictor<'_>) -> Report {
    run_at(scene, profile, predict, 0.5)
}

fn run_at(
    scene: &Scene,
    profile: &RobotProfile,
    predict: &Predictor<'_>,
    threshold: f32,
) -> Report {
    let settings = EvaluationSettings {
        model: "the ground truth".into(),
        affordances: AFFORDANCES.to_vec(),
        image_size: 64,
        views_per_scene: 4,
        seed: 3,
        threshold,
    };
    let mut renderer = Renderer::open(RendererChoice::Cpu).unwrap();
    let mut rooms = Vec::new();
    let report = evaluate(
        std::slice::from_ref(scene),
        profile,
        &mut renderer,
        predict,
        &settings,
        &mut |line| rooms.push(line.to_string()),
    )
    .unwrap();
    assert_eq!(rooms.len(), 1, "one progress line per room: {rooms:?}");
    report
}

/// A predictor that says `yes` wherever the ground truth `truth` (per scene
/// object and plane) affords the plane's affordance, and `no` elsewhere.
fn by_truth(truth: Vec<Vec<bool>>, yes: f32, no: f32) -> impl Fn(&Frame) -> Vec<Vec<f32>> {
    move |frame: &Frame| {
        (0..AFFORDANCES.len())
            .map(|plane| {
                frame
                    .ids
                    .iter()
                    .map(|&id| {
                        if id != 0 && truth[id as usize - 1][plane] {
                            yes
                        } else {
                            no
                        }
                    })
                    .collect()
            })
            .collect()
    }
}

#[test]
fn the_ground_truth_scores_perfectly_and_its_opposite_scores_nothing() {
    let (scene, profile) = room();
    let truth = ground_truth_planes(&scene, &profile, &AFFORDANCES);
    let oracle = |value: f32| by_truth(truth.clone(), value, 1.0 - value);
    let right = run(&scene, &profile, &oracle(1.0));
    assert_eq!(right.frames, 4);
    let objects = scene
        .objects
        .iter()
        .filter(|o| o.object_type != "Floor")
        .count();
    assert_eq!(right.objects, objects);
    // Table 2 counts every object exactly once: scored (tried or judged)
    // or in view from nowhere.
    let mut names: Vec<String> = right
        .trials
        .iter()
        .map(|t| format!("{}/{}", t.scene, t.object))
        .chain(right.objects_unseen.iter().cloned())
        .collect();
    names.sort();
    names.dedup();
    assert_eq!(names.len(), objects, "each object once: {names:?}");
    assert_eq!(right.trials.len() + right.objects_unseen.len(), objects);
    let tried = right
        .trials
        .iter()
        .filter(|t| t.scored_by == ScoredBy::Trial)
        .count();
    assert!(
        tried * 10 >= objects * 8,
        "most objects are tried: {tried} of {objects}; unseen: {:?}",
        right.objects_unseen
    );
    for row in &right.all_positive.pixel {
        let recall = row.recall.unwrap();
        assert_eq!((recall.p10, recall.median), (1.0, 1.0), "{row:?}");
    }
    for (reference, row) in right.all_positive.object.iter().zip(&right.object) {
        let c = row.confusion;
        let positives = c.true_positives + c.false_negatives;
        assert_eq!(reference.recall, Some(1.0));
        assert_eq!(reference.confusion.true_positives, positives);
        assert_eq!(reference.auc, Some(0.5), "a constant ranks nothing");
    }
    for row in &right.pixel {
        for p in [row.precision, row.recall, row.f1, row.object_accuracy] {
            let p = p.expect("defined in some view");
            assert_eq!((p.p10, p.median, p.p90), (1.0, 1.0, 1.0), "{row:?}");
        }
        assert_eq!(row.false_positives_on_structure, None, "no false positives");
    }
    let pick_up = &right.object[0];
    assert_eq!(pick_up.affordance, "pick_up");
    assert!(pick_up.confusion.true_positives > 0, "{pick_up:?}");
    assert_eq!(
        pick_up.confusion.false_negatives, 0,
        "only what the rules allow is picked up: {pick_up:?}"
    );
    assert!(pick_up.accuracy.unwrap() >= 0.9, "{pick_up:?}");
    let push = &right.object[1];
    assert!(push.confusion.true_positives > 0 && push.confusion.true_negatives > 0);
    assert!(push.accuracy.unwrap() >= 0.9, "{push:?}");
    for row in &right.object {
        assert!(row.auc.unwrap() >= 0.9, "the truth ranks well: {row:?}");
    }

    let wrong = run(&scene, &profile, &oracle(0.0));
    // The same seed gives the same views and objects, whatever the network.
    assert_eq!(wrong.frames, right.frames);
    assert_eq!(wrong.all_positive, right.all_positive);
    let where_scored = |r: &Report| {
        r.trials
            .iter()
            .map(|t| (t.object.clone(), t.pixels, t.scored_by, t.succeeded.clone()))
            .collect::<Vec<_>>()
    };
    assert_eq!(where_scored(&wrong), where_scored(&right));
    for row in &wrong.pixel {
        let f1 = row.f1.unwrap();
        assert_eq!((f1.p10, f1.median, f1.p90), (0.0, 0.0, 0.0), "{row:?}");
        // Positive on everything that does not afford it: floor, walls and objects.
        let share = row.false_positives_on_structure.unwrap();
        assert!(share > 0.05 && share < 0.95, "{row:?}");
    }
    for (w, r) in wrong.object.iter().zip(&right.object) {
        assert_eq!(w.confusion.true_positives, r.confusion.false_negatives);
        assert_eq!(w.confusion.false_negatives, r.confusion.true_positives);
        assert_eq!(w.f1.unwrap_or(0.0), 0.0);
        let (w_auc, r_auc) = (w.auc.unwrap(), r.auc.unwrap());
        assert!(
            (w_auc - (1.0 - r_auc)).abs() < 1e-6,
            "the opposite ranks oppositely: {w:?}"
        );
    }
}

#[test]
fn a_network_that_ranks_well_below_one_half_is_found_by_the_threshold_sweep() {
    let (scene, profile) = room();
    let truth = ground_truth_planes(&scene, &profile, &AFFORDANCES);
    // The truth's ranking with every probability far too low: 0.3 where an
    // object affords, 0.08 elsewhere.
    let shy = by_truth(truth, 0.3, 0.08);
    let paper = run(&scene, &profile, &shy);
    let pick_up = &paper.object[0];
    assert_eq!(pick_up.threshold, 0.5);
    assert_eq!(
        pick_up.recall,
        Some(0.0),
        "nothing reaches 0.5: {pick_up:?}"
    );
    let best = pick_up.best.expect("some threshold predicts");
    // Not 1: a trial fails where the rules allow a pick-up but there is no
    // room to lift the object.
    assert!(
        best.threshold > 0.08 && best.threshold <= 0.3 && best.f1 >= 0.75,
        "{best:?}"
    );
    let pixel_best = paper.pixel[0].best().expect("a sweep");
    assert!(
        pixel_best.threshold > 0.08 && pixel_best.threshold <= 0.3,
        "{pixel_best:?}"
    );
    assert_eq!(pixel_best.f1, 1.0);
    assert!(paper
        .to_markdown()
        .contains("Thresholds that would do best"));

    let chosen = run_at(&scene, &profile, &shy, best.threshold);
    assert_eq!(chosen.threshold, best.threshold);
    assert_eq!(chosen.object[0].f1, Some(best.f1));
    let f1 = chosen.pixel[0].f1.expect("defined");
    assert_eq!((f1.p10, f1.median), (1.0, 1.0), "{f1:?}");
    assert_eq!(
        chosen.all_positive, paper.all_positive,
        "the floor does not move"
    );
}
