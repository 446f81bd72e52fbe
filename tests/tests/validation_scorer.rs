//! The background validation scorer never holds up training: a learner of
//! the bandit fixture that writes a checkpoint every two updates, with a
//! scorer that takes seconds per checkpoint, keeps taking and training on
//! its actors' steps while a scoring runs; checkpoints that come while one
//! waits are skipped and counted; the scores reach `/api/status`,
//! `/metrics`, the history and the run's `validation/` directory; and the
//! learner stops promptly with a scoring in progress.

use std::os::unix::fs::PermissionsExt;
use std::time::Duration;

use system_tests::{
    bandit_config, http_get, metric_value, scratch_dir, start_actor, wait_for, Learner,
};

/// A scorer that takes `seconds` per checkpoint and then writes fixed
/// scores for the step it was asked about, as `actor evaluate --scores`
/// would.
fn slow_scorer(dir: &std::path::Path, seconds: u32) -> std::path::PathBuf {
    let path = dir.join("slow-scorer.sh");
    std::fs::write(
        &path,
        format!(
            r#"#!/bin/sh
# Arguments: evaluate --run-dir DIR --step S --scenes val --views-per-scene N --scores FILE
while [ $# -gt 0 ]; do
  case "$1" in
    --step) step="$2"; shift ;;
    --scores) out="$2"; shift ;;
    --views-per-scene) views="$2"; shift ;;
  esac
  shift
done
sleep {seconds}
mkdir -p "$(dirname "$out")"
printf '{{"step": %s, "scenes": ["FloorPlan221"], "views_per_scene": %s, "threshold": 0.5, "affordances": [{{"affordance": "pick_up", "pixel_f1": 0.25, "object_f1": 0.5, "object_auc": null}}]}}' "$step" "$views" > "$out"
"#
        ),
    )
    .expect("writing the scorer");
    std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o755)).expect("chmod");
    path
}

#[test]
fn a_slow_scorer_never_holds_up_training() {
    let dir = scratch_dir("validation-scorer");
    let prefix = format!("it-val-{}", std::process::id());
    let scorer = slow_scorer(&dir, 3);
    let config = bandit_config(
        &dir,
        &prefix,
        &format!(
            "checkpoint_every_updates = 2\n[validation]\nviews_per_room = 7\nscorer = \"{}\"\n",
            scorer.display()
        ),
    );
    let run_dir = dir.join("run");
    let mut learner = Learner::start(
        &run_dir,
        &[
            "--config".into(),
            config.display().to_string(),
            "--run-dir".into(),
            run_dir.display().to_string(),
            "--service-prefix".into(),
            prefix.clone(),
        ],
        dir.join("learner.log"),
    );
    let run_config = run_dir.join("config.toml").display().to_string();
    let _actors: Vec<_> = (0..2)
        .map(|id| start_actor(id, &prefix, &dir, &["--config", &run_config]))
        .collect();

    // A scoring runs: for the seconds it takes, steps and updates go on.
    let (scoring, steps_before, updates_before) =
        wait_for(Duration::from_secs(60), "a scoring in progress", || {
            let s = learner.status();
            let step = s["validation"]["scoring_step"].as_u64()?;
            Some((step, s["env_steps"].as_u64()?, s["updates"].as_u64()?))
        });
    std::thread::sleep(Duration::from_millis(1500));
    let s = learner.status();
    assert_eq!(
        s["validation"]["scoring_step"].as_u64(),
        Some(scoring),
        "the 3-s scoring still runs: {s}"
    );
    assert!(
        s["env_steps"].as_u64().unwrap() > steps_before
            && s["updates"].as_u64().unwrap() > updates_before,
        "training went on while step {scoring} was scored: {steps_before} steps and \
         {updates_before} updates then, now {s}"
    );

    // Scores arrive; checkpoints written during a scoring wait, the newest only.
    let s = wait_for(Duration::from_secs(60), "two scorings and a skip", || {
        let s = learner.status();
        let v = &s["validation"];
        (v["scored"].as_u64()? >= 2 && v["skipped"].as_u64()? >= 1).then_some(s)
    });
    let v = &s["validation"];
    assert_eq!(v["failed"].as_u64(), Some(0), "{s}");
    assert!(v["off"].is_null(), "{s}");
    let last = &v["last"];
    assert_eq!(last["views_per_scene"].as_u64(), Some(7), "{s}");
    let scored_step = last["step"].as_u64().unwrap();
    assert!(
        run_dir
            .join("validation")
            .join(format!("{scored_step}.json"))
            .is_file(),
        "the scores file of step {scored_step}"
    );
    let metrics = learner.metrics();
    assert_eq!(
        metric_value(&metrics, "afx_validation_pixel_f1{affordance=\"pick_up\"}"),
        Some(0.25)
    );
    assert_eq!(
        metric_value(&metrics, "afx_validation_object_f1{affordance=\"pick_up\"}"),
        Some(0.5)
    );
    assert!(
        !metrics.contains("afx_validation_object_auc{"),
        "an undefined score is left out"
    );
    assert!(
        metric_value(&metrics, "afx_validation_checkpoints_skipped_total")
            .is_some_and(|n| n >= 1.0)
    );
    let (code, body) = http_get(&learner.addr, "/api/history?kind=validation").unwrap();
    assert_eq!(code, 200);
    let history: serde_json::Value = serde_json::from_str(&body).unwrap();
    let records = history["records"].as_array().unwrap();
    assert!(records.len() >= 2, "{body}");
    assert_eq!(
        records[0]["validation"]["pick_up/pixel_f1"].as_f64(),
        Some(0.25)
    );
    // The actors' rates come from their chunks of the last minute.
    for a in s["actors"].as_array().unwrap() {
        assert!(a["steps_per_s"].as_f64().is_some_and(|r| r > 0.0), "{a}");
    }

    // Stopping does not wait for a scoring in progress: it is killed
    // before it writes its scores.
    let in_progress = wait_for(
        Duration::from_secs(30),
        "another scoring in progress",
        || learner.status()["validation"]["scoring_step"].as_u64(),
    );
    learner.process.signal(libc::SIGINT);
    let exit = learner
        .process
        .wait_exit(Duration::from_secs(20))
        .expect("the learner stops");
    assert!(exit.success(), "{}", learner.process.log_text());
    std::thread::sleep(Duration::from_secs(4));
    assert!(
        !run_dir
            .join("validation")
            .join(format!("{in_progress}.json"))
            .exists(),
        "the scoring of step {in_progress} was left to finish"
    );
}
