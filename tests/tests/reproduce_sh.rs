//! `deploy/reproduce.sh` as a user runs it, on a tiny budget (one method,
//! one seed, 640 steps at 64 px, the built binaries): it trains
//! to the budget, chooses the checkpoint on the validation rooms, scores
//! the test rooms and the untrained floor, and writes the page; run again,
//! it skips what is done; asked for other settings in the same root, it
//! refuses.

use std::path::Path;
use std::process::{Command, Output};

use system_tests::{bin, scratch_dir};

fn reproduce(root: &Path, report: &Path, steps: &str, port: u16) -> Output {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let data = repo.join("../shared/data");
    let bin_dir = bin("actor").parent().expect("binary dir").to_path_buf();
    Command::new(repo.join("deploy/reproduce.sh"))
        .args(["--methods", "ours", "--seeds", "3", "--steps", steps])
        .args(["--checkpoints", "5", "--views-per-scene", "2"])
        .args(["--val-views-per-scene", "2", "--root"])
        .arg(root)
        .arg("--report")
        .arg(report)
        .arg("--bin-dir")
        .arg(&bin_dir)
        .arg("--data")
        .arg(&data)
        .args([
            "--",
            "--actors",
            "1",
            "--image-size",
            "64",
            "--episode-steps",
            "16",
        ])
        .args(["--port", &port.to_string()])
        .output()
        .expect("running deploy/reproduce.sh")
}

fn text(output: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    )
}

#[test]
fn a_tiny_comparison_trains_chooses_on_validation_and_writes_the_page() {
    let dir = scratch_dir("reproduce-sh");
    let root = dir.join("root");
    let report = dir.join("docs/results.md");
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("a free port")
        .port();
    // 640 steps in 5 checkpoints is a checkpoint after every PPO update
    // (128 steps): the run takes several before the budget is reached even
    // where the actor outpaces the learner (steps count when they arrive).
    let first = reproduce(&root, &report, "640", port);
    let log = text(&first);
    assert!(first.status.success(), "{log}");
    let run = root.join("ours-seed3");
    assert!(run.join("trained").exists(), "{log}");
    let test: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(run.join("eval/test.json")).expect("the test report"),
    )
    .expect("JSON");
    let selection = &test["selection"];
    let candidates = selection["candidates"].as_array().expect("candidates");
    // A checkpoint whose U-Net has not yet trained (`unet_version` 0) is a
    // floor, not a candidate; every other checkpoint is one.
    let trained = std::fs::read_dir(run.join("checkpoints"))
        .expect("the checkpoints")
        .filter_map(|e| e.ok()?.file_name().to_str()?.parse::<u64>().ok())
        .filter(|step| {
            let counters = run.join(format!("checkpoints/{step}/counters.json"));
            let counters: serde_json::Value =
                serde_json::from_str(&std::fs::read_to_string(counters).expect("counters"))
                    .expect("JSON");
            counters["unet_version"].as_u64().expect("unet_version") >= 1
        })
        .count();
    assert_eq!(
        candidates.len(),
        trained,
        "every checkpoint whose U-Net trained is a candidate: {selection}"
    );
    assert!(trained >= 2, "validation chose among several: {selection}");
    assert_eq!(
        selection["scenes"][0], "FloorPlan221",
        "chosen on validation"
    );
    assert_eq!(
        test["scenes"][0], "FloorPlan226",
        "scored on the test rooms"
    );
    assert_eq!(test["checkpoint_step"], selection["chosen_step"]);
    assert!(test["checkpoint_step"].as_u64().unwrap() > 0);
    assert!(root.join("floors/untrained-seed3.json").exists());
    let page = std::fs::read_to_string(&report).expect("the results page");
    for expected in [
        "| **ours** |",
        "| floor: untrained U-Net |",
        "| floor: all positive |",
        "| paper: Ours |",
        "Not tested: `nomap-seg` was not among the methods run",
        "| ours-seed3 |",
        "![training curves](results-curves.svg)",
        "## Settings",
        "## On the validation rooms",
        "- **Confidence labels**: off",
        "`unet.class_balance = \"classes\"` (the paper's: \"pixels\")",
    ] {
        assert!(page.contains(expected), "{expected} in:\n{page}");
    }
    assert!(dir.join("docs/results-curves.svg").exists());

    let again = reproduce(&root, &report, "640", port);
    let log = text(&again);
    assert!(again.status.success(), "{log}");
    assert!(
        log.contains("ours seed 3: trained") && log.contains("ours seed 3: evaluated"),
        "a finished run is skipped: {log}"
    );

    // The run's config says where the data is and how to render: `actor
    // evaluate` needs no flag repeated, from anywhere.
    let again_json = dir.join("again.json");
    let evaluated = Command::new(bin("actor"))
        .args(["evaluate", "--views-per-scene", "1", "--run-dir"])
        .arg(&run)
        .arg("--json")
        .arg(&again_json)
        .current_dir(&dir)
        .env_remove("AFX_DATA")
        .output()
        .expect("running actor evaluate");
    assert!(evaluated.status.success(), "{}", text(&evaluated));
    assert!(again_json.exists());

    let other = reproduce(&root, &report, "800", port);
    assert!(!other.status.success());
    assert!(text(&other).contains("other settings"), "{}", text(&other));
}
