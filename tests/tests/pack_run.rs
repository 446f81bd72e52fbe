//! A run moves between machines as a user on time-limited machines moves it:
//! `deploy/local.sh --max-seconds` stops it on its deadline with a final
//! checkpoint, `deploy/pack-run.sh` packs it into parts no larger than asked,
//! `deploy/unpack-run.sh` puts it back elsewhere (refusing damaged or
//! missing parts without writing anything), and `--resume` there continues
//! from the packed checkpoint.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use system_tests::{
    checkpoint_steps as checkpoints, free_port, launch_bandit_run as launch, scratch_dir,
    wait_launch_exit as wait_exit,
};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn script(name: &str, args: &[&Path]) -> Output {
    Command::new(repo().join("deploy").join(name))
        .args(args)
        .output()
        .unwrap_or_else(|e| panic!("running {name}: {e}"))
}

fn text(out: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

fn parts(pack: &Path) -> Vec<PathBuf> {
    let mut parts: Vec<PathBuf> = std::fs::read_dir(pack)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.to_string_lossy().contains(".tar.part-"))
        .collect();
    parts.sort();
    parts
}

#[test]
fn a_run_stopped_on_its_deadline_is_packed_carried_and_resumed() {
    let dir = scratch_dir("pack-run");
    let name = format!("moving-{}", std::process::id());
    let here = dir.join("here").join(&name);
    std::fs::create_dir_all(here.parent().unwrap()).unwrap();

    // A deadline stops the run as Ctrl-C would: a final checkpoint.
    let mut first = launch(
        &here,
        free_port(),
        dir.join("first.log"),
        &["--max-seconds", "12"],
    );
    let exit = wait_exit(&mut first, 120);
    let log = std::fs::read_to_string(&first.log).unwrap_or_default();
    assert!(exit.success(), "{exit}:\n{log}");
    assert!(log.contains("--max-seconds 12"), "{log}");
    let newest = *checkpoints(&here).last().expect("a final checkpoint");
    assert!(newest > 0, "the run took steps before its deadline");

    // Packed into parts no larger than asked.
    let pack = dir.join("pack");
    let out = Command::new(repo().join("deploy/pack-run.sh"))
        .arg("--run-dir")
        .arg(&here)
        .arg("--out")
        .arg(&pack)
        .args(["--part-size", "8K"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", text(&out));
    let packed = parts(&pack);
    assert!(packed.len() > 1, "{packed:?}");
    for part in &packed {
        assert!(
            std::fs::metadata(part).unwrap().len() <= 8 * 1024,
            "{part:?}"
        );
    }

    // A damaged part, then a missing one, is refused and nothing is written.
    let there = dir.join("there");
    let middle = &packed[packed.len() / 2];
    let good = std::fs::read(middle).unwrap();
    let mut bad = good.clone();
    bad[10] ^= 0xff;
    std::fs::write(middle, &bad).unwrap();
    let out = script(
        "unpack-run.sh",
        &[Path::new("--pack"), &pack, Path::new("--into"), &there],
    );
    assert_eq!(out.status.code(), Some(4), "{}", text(&out));
    assert!(text(&out).contains("damaged"), "{}", text(&out));
    std::fs::remove_file(middle).unwrap();
    let out = script(
        "unpack-run.sh",
        &[Path::new("--pack"), &pack, Path::new("--into"), &there],
    );
    assert_eq!(out.status.code(), Some(4), "{}", text(&out));
    assert!(text(&out).contains("missing"), "{}", text(&out));
    assert!(
        !there.join(&name).exists(),
        "nothing unpacked from a bad pack"
    );

    // Whole again: it unpacks byte for byte.
    std::fs::write(middle, &good).unwrap();
    let out = script(
        "unpack-run.sh",
        &[Path::new("--pack"), &pack, Path::new("--into"), &there],
    );
    assert!(out.status.success(), "{}", text(&out));
    let moved = there.join(&name);
    assert_eq!(
        checkpoints(&moved),
        [newest],
        "the newest checkpoint travels"
    );
    let checkpoint = |run: &Path| run.join("checkpoints").join(newest.to_string());
    for file in std::fs::read_dir(checkpoint(&here)).unwrap().flatten() {
        let name = file.file_name();
        assert_eq!(
            std::fs::read(file.path()).unwrap(),
            std::fs::read(checkpoint(&moved).join(&name)).unwrap(),
            "{name:?}"
        );
    }
    for file in ["config.toml", "join.key", "history.jsonl"] {
        assert_eq!(
            std::fs::read(here.join(file)).unwrap(),
            std::fs::read(moved.join(file)).unwrap(),
            "{file}"
        );
    }

    // Resumed there, it continues from the packed checkpoint.
    let mut second = launch(
        &moved,
        free_port(),
        dir.join("second.log"),
        &["--resume", "--max-seconds", "12"],
    );
    let exit = wait_exit(&mut second, 120);
    let log = std::fs::read_to_string(&second.log).unwrap_or_default();
    assert!(exit.success(), "{exit}:\n{log}");
    let learner_log = std::fs::read_to_string(moved.join("logs/learner.log")).unwrap_or_default();
    assert!(
        learner_log.contains(&format!("checkpoints/{newest} (env steps {newest},")),
        "resumed from the packed checkpoint {newest}:\n{learner_log}"
    );
    assert!(
        checkpoints(&moved).last().is_some_and(|&s| s > newest),
        "it went on past {newest}: {:?}",
        checkpoints(&moved)
    );

    // Unpacking over an existing copy needs --replace, which keeps the old aside.
    let out = script(
        "unpack-run.sh",
        &[Path::new("--pack"), &pack, Path::new("--into"), &there],
    );
    assert_eq!(out.status.code(), Some(2), "{}", text(&out));
    let out = script(
        "unpack-run.sh",
        &[
            Path::new("--pack"),
            &pack,
            Path::new("--into"),
            &there,
            Path::new("--replace"),
        ],
    );
    assert!(out.status.success(), "{}", text(&out));
    let aside = std::fs::read_dir(&there)
        .unwrap()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().contains(".before-unpack-"))
        .count();
    assert_eq!(aside, 1, "the resumed copy is kept aside");
}
