//! The comparison page from a tiny fake comparison: two variants × two
//! seeds of evaluation JSONs and histories. The page shows each variant's
//! mean and range and the floors; a dropped seed, a missing number, or a
//! Table 2 that does not count every object once is an error, not a gap.

use std::path::Path;

use actor::evaluation::{
    AtValidationThreshold, Candidate, ObjectRow, ObjectTrial, Percentiles, PixelRow, Reference,
    Report, ScoredBy, Selection, ThresholdF1,
};
use actor::results::{load, render, run_dir, test_report_path, untrained_report_path};
use serde_json::json;

fn percentiles(median: f32) -> Option<Percentiles> {
    Some(Percentiles {
        median,
        p10: median / 2.0,
        p90: median.max(0.5),
        frames: 10,
    })
}

/// A report whose pick-up pixel F1 median is `f1` and whose two objects
/// are predicted with probability `p`.
fn report(f1: f32, p: f32, selected: bool) -> Report {
    let pixel = |f1: f32| PixelRow {
        affordance: "pick_up".into(),
        precision: percentiles(0.3),
        recall: percentiles(0.6),
        f1: percentiles(f1),
        object_accuracy: percentiles(0.8),
        false_positives_on_structure: Some(0.4),
        f1_by_threshold: Vec::new(),
    };
    let scored = [(p, true), (1.0 - p, false)];
    let trial = |object: &str, p: f32, success: bool, scored_by| ObjectTrial {
        scene: "FloorPlan226".into(),
        object: object.into(),
        object_type: "Book".into(),
        pixels: 20,
        distance_m: 1.0,
        predicted: vec![p],
        scored_by,
        succeeded: vec![success],
        failure: vec![None],
    };
    Report {
        model: "a fake".into(),
        checkpoint_step: Some(2000),
        selection: selected.then(|| {
            Selection::choose(
                vec!["FloorPlan221".into()],
                4,
                vec![Candidate {
                    step: 2000,
                    score: 0.5,
                    pixel_f1: vec![Some(0.5)],
                    object_f1: vec![Some(0.5)],
                }],
            )
            .unwrap()
        }),
        scenes: vec!["FloorPlan226".into()],
        frames: 10,
        threshold: 0.5,
        pixel: vec![pixel(f1)],
        objects: 3,
        objects_unseen: vec!["FloorPlan226/Pen|1".into()],
        object: vec![ObjectRow::new("pick_up".into(), &scored)],
        trials: vec![
            trial("Book|1", p, true, ScoredBy::Trial),
            trial("Vase|2", 1.0 - p, false, ScoredBy::GroundTruth),
        ],
        all_positive: Reference {
            name: "all positive".into(),
            pixel: vec![pixel(0.1)],
            object: vec![ObjectRow::new(
                "pick_up".into(),
                &[(1.0, true), (1.0, false)],
            )],
        },
        // A selected run's scores at the validation rooms' thresholds.
        at_validation_thresholds: if selected {
            vec![AtValidationThreshold {
                affordance: "pick_up".into(),
                pixel_validation: Some(ThresholdF1 {
                    threshold: 0.3,
                    f1: 0.7,
                }),
                pixel_f1: Some(f1 + 0.05),
                object_validation: Some(ThresholdF1 {
                    threshold: 0.3,
                    f1: 0.8,
                }),
                object: Some(ObjectRow::at("pick_up".into(), &scored, 0.3)),
            }]
        } else {
            Vec::new()
        },
    }
}

fn write_json(path: &Path, value: &impl serde::Serialize) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    std::fs::write(path, serde_json::to_string(value).unwrap()).unwrap();
}

fn fake_comparison(root: &Path) {
    write_json(
        &root.join("reproduce.json"),
        &json!({
            "command": "deploy/reproduce.sh --methods ours,nomap-seg,nomap-noseg,intexp --seeds 0,1 --steps 2000",
            "variants": ["ours", "nomap-seg", "nomap-noseg", "intexp"], "seeds": [0, 1], "steps": 2000,
            "confidence_after_steps": 800, "local_options": "--actors 2 --image-size 64",
            "views_seed": 0, "views_per_scene": 4, "val_views_per_scene": 4,
            "machine": "a test", "commit": "abc1234", "started": "2026-11-26T00:00:00Z"
        }),
    );
    for (variant, f1s) in [
        ("ours", [0.4, 0.6]),
        ("nomap-seg", [0.3, 0.36]),
        ("nomap-noseg", [0.1, 0.2]),
        ("intexp", [0.1, 0.2]),
    ] {
        for (seed, f1) in [0u64, 1].into_iter().zip(f1s) {
            let dir = run_dir(root, variant, seed);
            write_json(&test_report_path(&dir), &report(f1, 0.9, true));
            let history: String = (1..=20)
                .map(|i| {
                    format!(
                        "{}\n",
                        json!({"kind": "episode", "env_steps": i * 100, "time_s": i as f64 * 3.0,
                               "stats": {"interacted_object_rate": 0.3, "interaction_attempt_rate": 0.1,
                                         "interaction_success_rate": 0.2}})
                    )
                })
                .collect();
            std::fs::write(dir.join("history.jsonl"), history).unwrap();
            if (variant, seed) == ("ours", 0) {
                // The learner recorded the chosen checkpoint's scores (and
                // so its AUC) for this run only.
                write_json(
                    &dir.join("validation/2000.json"),
                    &json!({"step": 2000, "scenes": ["FloorPlan221"], "views_per_scene": 4,
                            "threshold": 0.5, "affordances": [{"affordance": "pick_up",
                            "pixel_f1": 0.5, "object_f1": 0.5, "object_auc": 0.8}]}),
                );
            }
        }
    }
    for seed in [0, 1] {
        write_json(
            &untrained_report_path(root, seed),
            &report(0.01, 0.5, false),
        );
    }
}

#[test]
fn the_page_shows_every_variant_over_seeds_beside_the_floors() {
    let root = tempfile::tempdir().unwrap();
    fake_comparison(root.path());
    let page = render(&load(root.path()).unwrap(), Some("results-curves.svg"));
    assert!(page.contains("| **ours** | 0.30 [0.30, 0.30] | 0.60 [0.60, 0.60] | 0.50 [0.40, 0.60] | 0.80 [0.80, 0.80] |"), "{page}");
    assert!(
        page.contains("| **intexp** | 0.30 [0.30, 0.30] | 0.60 [0.60, 0.60] | 0.15 [0.10, 0.20] |"),
        "{page}"
    );
    assert!(page.contains("| floor: untrained U-Net | 0.30 [0.30, 0.30] | 0.60 [0.60, 0.60] | 0.01 [0.01, 0.01] |"), "{page}");
    assert!(
        page.contains("| floor: all positive | 0.30 | 0.60 | 0.10 | 0.80 |"),
        "{page}"
    );
    assert!(
        page.contains("| paper: Ours | 0.20 | 0.37 | 0.22 | 0.89 |"),
        "{page}"
    );
    assert!(
        page.contains("| paper: IntExp | 0.72 | 0.75 | 0.12 | 0.21 | – |"),
        "{page}"
    );
    assert!(page.contains("1 tried from the nearest position"), "{page}");
    assert!(page.contains("1 out of reach"), "{page}");
    assert!(
        page.contains(
            "- **Table 1 median pixel F1** — ours 0.50, nomap-seg 0.33, nomap-noseg 0.15, \
             intexp 0.15: the ordering **holds** (ours > nomap-seg (clearly), nomap-seg > \
             nomap-noseg (clearly), nomap-seg > intexp (clearly); nomap-noseg and intexp overlap, \
             ≈ as in the paper). Above the all-positive floor (0.10): ours, nomap-seg, \
             nomap-noseg, intexp."
        ),
        "{page}"
    );
    assert!(
        page.contains("- **Table 2 F1** — ours 1.00, nomap-seg 1.00, nomap-noseg 1.00, intexp 1.00: the ordering **does not hold**"),
        "{page}"
    );
    assert!(
        page.contains("| ours-seed1 | 2000 | 1 min | 2000 of 1 (0.500) |"),
        "{page}"
    );
    assert!(page.contains("![training curves](results-curves.svg)"));
    // The scores at each run's validation-chosen thresholds, in their own table.
    let chosen = &page[page
        .find("## At thresholds chosen on the validation rooms")
        .expect("the section")..];
    assert!(
        chosen.contains(
            "| **ours** | 0.30 [0.30, 0.30] | 0.55 [0.45, 0.65] | 0.30 [0.30, 0.30] | \
             1.00 [1.00, 1.00] | 1.00 [1.00, 1.00] | 1.00 [1.00, 1.00] |"
        ),
        "{chosen}"
    );
    // The chosen checkpoints' own validation scores, the AUC where recorded.
    let validation = &page[page
        .find("## On the validation rooms")
        .expect("the section")..];
    assert!(
        validation.contains(
            "| **ours** | 0.50 [0.50, 0.50] | 0.50 [0.50, 0.50] | 0.80 [0.80, 0.80] (1 of 2) |"
        ),
        "{validation}"
    );
    assert!(
        validation.contains(
            "| **intexp** | 0.50 [0.50, 0.50] | 0.50 [0.50, 0.50] | – (undefined in 2) |"
        ),
        "{validation}"
    );
}

#[test]
fn a_dropped_seed_or_a_missing_number_is_an_error() {
    let root = tempfile::tempdir().unwrap();
    fake_comparison(root.path());
    let dropped = test_report_path(&run_dir(root.path(), "intexp", 1));
    std::fs::remove_file(&dropped).unwrap();
    let error = format!("{:#}", load(root.path()).unwrap_err());
    assert!(error.contains("intexp seed 1"), "{error}");

    write_json(&dropped, &report(0.3, 0.9, true));
    load(root.path()).unwrap();
    let mut value: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&dropped).unwrap()).unwrap();
    value["object"][0].as_object_mut().unwrap().remove("f1");
    write_json(&dropped, &value);
    let error = format!("{:#}", load(root.path()).unwrap_err());
    assert!(error.contains("f1"), "{error}");

    let mut uncounted = report(0.3, 0.9, true);
    uncounted.objects = 4;
    write_json(&dropped, &uncounted);
    let error = format!("{:#}", load(root.path()).unwrap_err());
    assert!(error.contains("every object once"), "{error}");

    let mut unselected = report(0.3, 0.9, false);
    unselected.selection = None;
    write_json(&dropped, &unselected);
    let error = format!("{:#}", load(root.path()).unwrap_err());
    assert!(error.contains("validation"), "{error}");
}
