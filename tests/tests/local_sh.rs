//! `deploy/local.sh` as a user runs it, with the bandit fixture and the
//! already built binaries (`--bin-dir`): it brings up the learner and two
//! actors, and a stop, whichever processes it reaches, ends every process
//! of the run with a final checkpoint and exit status 0, as does reaching
//! `--max-steps`, printing progress lines meanwhile. Also
//! `deploy/throughput.sh`, which measures runs of `local.sh`.

use std::fs::File;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use system_tests::{bin, free_port, http_get, scratch_dir, wait_for, wait_launch_exit};

/// A running `deploy/local.sh` (killed with its process group on drop),
/// its run directory and service prefix.
struct Launch {
    run: system_tests::Launch,
    run_dir: PathBuf,
    prefix: String,
}

/// The `--seed` every launch gives.
const RUN_SEED: &str = "7";

/// Starts the script with `extra` arguments, without waiting for anything.
fn start(dir: &Path, case: &str, extra: &[&str]) -> (Launch, String) {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let bin_dir = bin("learner").parent().expect("binary dir").to_path_buf();
    let name = format!("ls-{case}-{}", std::process::id());
    let run_dir = dir.join(&name);
    let port = free_port();
    let log = dir.join(format!("{name}.log"));
    let out = File::create(&log).expect("log file");
    let script = Command::new(repo.join("deploy/local.sh"))
        .args(["--actors", "2", "--env", "bandit-fixture", "--bin-dir"])
        .arg(&bin_dir)
        .arg("--run-dir")
        .arg(&run_dir)
        .args(["--port", &port.to_string()])
        .args([
            "--seed",
            RUN_SEED,
            "--envs-per-actor",
            "2",
            "--device",
            "cpu",
        ])
        .args(extra)
        .stdout(Stdio::from(out.try_clone().expect("log handle")))
        .stderr(Stdio::from(out))
        .process_group(0)
        .spawn()
        .expect("starting deploy/local.sh");
    let launch = Launch {
        run: system_tests::Launch { script, log },
        run_dir,
        prefix: format!("afx-{name}"),
    };
    (launch, format!("127.0.0.1:{port}"))
}

/// Starts the script and waits until both actors feed the learner.
fn launch(dir: &Path, case: &str) -> Launch {
    let (launch, addr) = start(dir, case, &[]);
    wait_for(
        Duration::from_secs(90),
        "both actors sending to the learner",
        || {
            let (_, body) = http_get(&addr, "/api/status")?;
            let status: serde_json::Value = serde_json::from_str(&body).ok()?;
            (status["actors_alive"].as_u64()? >= 2 && status["env_steps"].as_u64()? > 0)
                .then_some(())
        },
    );
    launch
}

/// Field `n` of stat(5) for `pid` (1-based, as the manual counts), from
/// /proc; from field 3 on, since the command name (field 2, in
/// parentheses) may hold spaces.
fn stat_field<T: std::str::FromStr>(pid: u32, n: usize) -> Option<T> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    stat.rsplit_once(')')?
        .1
        .split_whitespace()
        .nth(n.checked_sub(3)?)?
        .parse()
        .ok()
}

/// Parent pid of `pid`.
fn parent_of(pid: u32) -> Option<u32> {
    stat_field(pid, 4)
}

/// Niceness of `pid`.
fn niceness(pid: u32) -> Option<i32> {
    stat_field(pid, 19)
}

fn cmdline(pid: u32) -> String {
    std::fs::read(format!("/proc/{pid}/cmdline"))
        .map(|b| String::from_utf8_lossy(&b).replace('\0', " "))
        .unwrap_or_default()
}

fn all_pids() -> Vec<u32> {
    std::fs::read_dir("/proc")
        .map(|rd| {
            rd.filter_map(|e| e.ok()?.file_name().to_str()?.parse().ok())
                .collect()
        })
        .unwrap_or_default()
}

/// Processes of this run still alive (learner and actors name its prefix).
fn survivors(prefix: &str) -> Vec<String> {
    all_pids()
        .into_iter()
        .map(cmdline)
        .filter(|c| c.contains(prefix) && !c.contains("local.sh"))
        .collect()
}

/// Waits for the script's exit and checks that the run ended cleanly.
fn assert_stopped_cleanly(mut launch: Launch) {
    let status = wait_launch_exit(&mut launch.run, 60);
    let log = std::fs::read_to_string(&launch.run.log).unwrap_or_default();
    assert!(
        status.success() && log.contains("stopped (learner exit status 0)"),
        "{status}:\n{log}"
    );
    let learner_log =
        std::fs::read_to_string(launch.run_dir.join("logs/learner.log")).unwrap_or_default();
    assert!(
        learner_log.contains("shutting down: writing a final checkpoint"),
        "no final checkpoint:\n{learner_log}"
    );
    wait_for(Duration::from_secs(5), "no process of the run left", || {
        survivors(&launch.prefix).is_empty().then_some(())
    });
}

#[test]
fn sigterm_to_the_script_stops_actors_then_the_learner() {
    let dir = scratch_dir("local-sh-term");
    let launch = launch(&dir, "term");
    // `--seed`, `--envs-per-actor` and `--device` go into the run's config,
    // and every actor runs as it says, without flags of its own.
    let config = std::fs::read_to_string(launch.run_dir.join("config.toml")).expect("config.toml");
    assert!(
        config.lines().any(|l| l == format!("seed = {RUN_SEED}")),
        "the run's config does not hold seed {RUN_SEED}:\n{config}"
    );
    let actors_table = config.split("[actors]").nth(1).expect("an [actors] table");
    assert!(
        actors_table.contains("envs = 2") && actors_table.contains("device = \"cpu\""),
        "{config}"
    );
    let processes = survivors(&launch.prefix);
    let actors: Vec<String> = processes
        .iter()
        .filter(|c| c.contains("--actor-id"))
        .cloned()
        .collect();
    // `--device` reaches the learner and every actor.
    let learners: Vec<&String> = processes
        .iter()
        .filter(|c| !c.contains("--actor-id"))
        .collect();
    assert!(
        learners.len() == 1 && learners[0].contains("--device cpu"),
        "one learner, with --device cpu: {processes:?}"
    );
    assert_eq!(actors.len(), 2, "two actors: {actors:?}");
    // The actors yield the CPU to the learner (`--actor-nice`, 10 unless
    // given), which runs as the script does.
    let own = niceness(std::process::id()).expect("this test's niceness");
    let nice_of = |is_actor: bool| -> Vec<Option<i32>> {
        all_pids()
            .into_iter()
            .filter(|&pid| {
                let c = cmdline(pid);
                c.contains(&launch.prefix)
                    && !c.contains("local.sh")
                    && c.contains("--actor-id") == is_actor
            })
            .map(niceness)
            .collect()
    };
    assert_eq!(nice_of(true), vec![Some((own + 10).min(19)); 2]);
    assert_eq!(nice_of(false), vec![Some(own)]);
    // Its training threads run before the actors unless --training-nice says otherwise.
    assert!(
        learners[0]
            .split_whitespace()
            .any(|a| a == "training_nice=0"),
        "{}",
        learners[0]
    );
    assert!(
        actors
            .iter()
            .all(|c| c.contains("--config") && !c.contains("--seed") && !c.contains("--envs")),
        "actors take their settings from the run's config: {actors:?}"
    );
    for id in 0..2 {
        let log = launch.run_dir.join(format!("logs/actor-{id}.log"));
        let said = wait_for(Duration::from_secs(10), "the actor's settings line", || {
            std::fs::read_to_string(&log)
                .ok()
                .filter(|l| l.contains("environment(s) on"))
        });
        assert!(
            said.contains(&format!("2 environment(s) on cpu, seed {RUN_SEED}")),
            "{said}"
        );
    }
    // SAFETY: kill(2) on our own child's pid has no memory-safety preconditions.
    unsafe {
        libc::kill(launch.run.script.id() as i32, libc::SIGTERM);
    }
    assert_stopped_cleanly(launch);
}

#[test]
fn sigterm_that_also_kills_the_actor_supervisors_still_stops_the_learner() {
    // What `pkill -f deploy/local.sh` does: the script's supervisor
    // subshells share its command line and die with it.
    let dir = scratch_dir("local-sh-pkill");
    let launch = launch(&dir, "pkill");
    let script = launch.run.script.id();
    let supervisors: Vec<u32> = all_pids()
        .into_iter()
        .filter(|&p| parent_of(p) == Some(script) && cmdline(p).contains("local.sh"))
        .collect();
    assert_eq!(supervisors.len(), 2, "one supervisor per actor");
    for pid in supervisors.into_iter().chain([script]) {
        // SAFETY: kill(2) has no memory-safety preconditions.
        unsafe {
            libc::kill(pid as i32, libc::SIGTERM);
        }
    }
    assert_stopped_cleanly(launch);
}

#[test]
fn max_steps_stops_the_run_cleanly_once_it_has_taken_them() {
    let dir = scratch_dir("local-sh-max-steps");
    let max_steps = 3000;
    let (launch, _) = start(
        &dir,
        "max",
        &[
            "--max-steps",
            &max_steps.to_string(),
            "--progress-every",
            "0",
        ],
    );
    let run_dir = launch.run_dir.clone();
    let log_path = launch.run.log.clone();
    assert_stopped_cleanly(launch);
    let log = std::fs::read_to_string(&log_path).unwrap_or_default();
    assert!(
        log.contains(&format!("(--max-steps {max_steps})")),
        "the script did not say why it stopped:\n{log}"
    );
    // Progress while it ran: one line per poll with every field.
    let progress = log
        .lines()
        .find(|l| l.contains(" steps") && l.contains("| actors "))
        .unwrap_or_else(|| panic!("no progress line:\n{log}"));
    for field in [
        "last ",
        "episodes: return ",
        "success ",
        "U-Net val IoU ",
        "PPO KL ",
        "entropy ",
        "dropped ",
    ] {
        assert!(progress.contains(field), "{field} in {progress}");
    }
    // Logs written to files carry no terminal colour codes.
    for name in ["learner.log", "actor-0.log"] {
        let text = std::fs::read_to_string(run_dir.join("logs").join(name)).unwrap_or_default();
        assert!(!text.is_empty(), "{name} is empty");
        assert!(!text.contains('\x1b'), "colour codes in {name}:\n{text}");
    }
    // Checkpoints are named by the run's environment steps.
    let steps = std::fs::read_dir(run_dir.join("checkpoints"))
        .expect("the run's checkpoints")
        .filter_map(|e| e.ok()?.file_name().to_str()?.parse::<u64>().ok())
        .max()
        .unwrap_or(0);
    assert!(
        steps >= max_steps,
        "final checkpoint at {steps} steps, before --max-steps {max_steps}"
    );
    // Resumed without the flag, the run keeps its limit: it stops at once.
    let (resumed, _) = start(&dir, "max", &["--resume", "--progress-every", "0"]);
    let log_path = resumed.run.log.clone();
    assert_stopped_cleanly(resumed);
    let log = std::fs::read_to_string(&log_path).unwrap_or_default();
    assert!(
        log.contains(&format!("resuming to the run's --max-steps {max_steps}"))
            && log.contains(&format!("(--max-steps {max_steps})")),
        "the resumed run did not keep its --max-steps:\n{log}"
    );
}

#[test]
fn throughput_sh_measures_each_setting_and_stops_its_runs() {
    let dir = scratch_dir("throughput-sh");
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let bin_dir = bin("learner").parent().expect("binary dir").to_path_buf();
    let runs = dir.join(format!("tp-{}", std::process::id()));
    let output = Command::new(repo.join("deploy/throughput.sh"))
        .args(["--settings", "1x1,1x2", "--warmup", "1", "--seconds", "2"])
        .arg("--runs-dir")
        .arg(&runs)
        .args(["--port", &free_port().to_string()])
        .args(["--", "--env", "bandit-fixture", "--bin-dir"])
        .arg(&bin_dir)
        .output()
        .expect("running deploy/throughput.sh");
    let table = String::from_utf8_lossy(&output.stdout);
    assert!(
        output.status.success(),
        "{}\n{table}\n{}",
        output.status,
        String::from_utf8_lossy(&output.stderr)
    );
    // The first table: its header, then a row per setting up to a blank line.
    let first: Vec<&str> = table
        .lines()
        .skip(2)
        .take_while(|l| !l.trim().is_empty())
        .collect();
    let rows: Vec<Vec<f64>> = first
        .iter()
        .map(|l| {
            l.split('|')
                .filter_map(|cell| cell.trim().parse::<f64>().ok())
                .collect()
        })
        .collect();
    assert_eq!(rows.len(), 2, "{table}");
    for (row, (actors, envs)) in rows.iter().zip([(1.0, 1.0), (1.0, 2.0)]) {
        // actors, environments, steps/s, per process, updates/s, steps discarded
        // (frames "taken / skipped", messages lost "n (x %)" and CPU cores
        // busy "learner / actors of cores" are not plain numbers).
        assert_eq!(row.len(), 6, "{table}");
        assert_eq!((row[0], row[1]), (actors, envs), "{table}");
        assert!(row[2] > 0.0 && row[3] > 0.0, "no steps counted:\n{table}");
        assert!(row[4] >= 0.0 && row[5] >= 0.0, "{table}");
    }
    // The learner's receive loop took the messages: busy a share of the
    // window (the cell before the last).
    let receiving: Vec<f64> = first
        .iter()
        .map(|line| {
            let cells: Vec<&str> = line.split('|').map(str::trim).collect();
            let cell = cells[cells.len() - 3];
            cell.split_once(" %")
                .and_then(|(v, _)| v.parse().ok())
                .unwrap_or_else(|| panic!("no 'receive loop busy' share in {line:?}"))
        })
        .collect();
    assert!(
        receiving.iter().all(|&r| (0.0..=100.0).contains(&r)) && receiving.iter().any(|&r| r > 0.0),
        "{table}"
    );
    // The actors stepped, so their processes kept some of a core busy; the
    // learner's figure is a share of the machine too.
    for line in &first {
        let cell = line
            .trim_end_matches(['|', ' '])
            .rsplit('|')
            .next()
            .unwrap_or("");
        let numbers: Vec<f64> = cell
            .split(|c: char| c == '/' || c.is_whitespace())
            .filter_map(|w| w.parse().ok())
            .collect();
        let [learner, actors, cores] = numbers[..] else {
            panic!("no 'learner / actors of cores' cell in {line:?}:\n{table}");
        };
        assert!(cores >= 1.0, "{table}");
        assert!(actors > 0.0 && actors <= cores + 0.5, "{table}");
        assert!(learner >= 0.0 && learner <= cores + 0.5, "{table}");
    }
    // The second table splits those cores by thread name: a learner and an
    // actor row per setting, the learner's naming its receive loop (busy
    // with the fixture's ~40 000 messages a second).
    let threads: Vec<&str> = table
        .lines()
        .skip_while(|l| !l.contains("busiest threads"))
        .skip(2)
        .take_while(|l| l.starts_with('|'))
        .collect();
    assert_eq!(threads.len(), 4, "{table}");
    for (line, (setting, kind)) in threads.iter().zip([
        ("| 1 | 1 |", "learner"),
        ("| 1 | 1 |", "actor"),
        ("| 1 | 2 |", "learner"),
        ("| 1 | 2 |", "actor"),
    ]) {
        assert!(
            line.starts_with(setting) && line.contains(&format!("| {kind} |")),
            "{table}"
        );
        if kind == "learner" {
            assert!(line.contains("receive-loop "), "{table}");
        }
    }
    // Each run was stopped cleanly: a final checkpoint, nothing left running.
    for setting in ["1x1", "1x2"] {
        let log = std::fs::read_to_string(runs.join(format!("{setting}.log"))).unwrap_or_default();
        assert!(
            log.contains("stopped (learner exit status 0)"),
            "{setting}:\n{log}"
        );
        let prefix = format!("afx-{setting}");
        assert!(
            survivors(&prefix)
                .iter()
                .all(|c| !c.contains(&*runs.to_string_lossy())),
            "{setting}: processes left"
        );
    }
}

#[test]
fn an_actor_that_fails_before_its_first_weights_stops_the_run_with_its_log() {
    let dir = scratch_dir("local-sh-setup");
    // The learner trains on the CPU, but the run asks its actors for a GPU
    // this build has not: a setup problem restarts cannot fix.
    let (mut launch, _) = start(&dir, "setup", &["--", "--set", "actors.device=gpu"]);
    let deadline = Instant::now() + Duration::from_secs(60);
    let status = loop {
        if let Some(status) = launch
            .run
            .script
            .try_wait()
            .expect("waiting for the script")
        {
            break status;
        }
        assert!(
            Instant::now() < deadline,
            "deploy/local.sh kept restarting actors that cannot start:\n{}",
            std::fs::read_to_string(&launch.run.log).unwrap_or_default()
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    let log = std::fs::read_to_string(&launch.run.log).unwrap_or_default();
    assert!(!status.success(), "{status}:\n{log}");
    for words in [
        "before it received its first weights",
        "this build has no GPU backend",
        "stopping the run",
    ] {
        assert!(log.contains(words), "{words} in:\n{log}");
    }
    assert!(!log.contains("restart #"), "no restart:\n{log}");
    wait_for(Duration::from_secs(5), "no process of the run left", || {
        survivors(&launch.prefix).is_empty().then_some(())
    });
}

#[test]
fn a_setting_actors_cannot_use_is_refused_before_anything_starts() {
    let dir = scratch_dir("local-sh-bad-setting");
    let (mut launch, _) = start(&dir, "badset", &["--renderer", "bogus"]);
    let status = wait_for(Duration::from_secs(30), "the script to give up", || {
        launch
            .run
            .script
            .try_wait()
            .expect("waiting for the script")
    });
    let log = std::fs::read_to_string(&launch.run.log).unwrap_or_default();
    assert!(!status.success(), "{status}:\n{log}");
    assert!(
        log.contains("actors.renderer") && log.contains("auto, gpu, cpu"),
        "the learner names the setting and its values:\n{log}"
    );
    assert!(!log.contains("actors:   "), "no actor was started:\n{log}");
}

#[test]
fn a_taken_port_is_named_with_the_option_that_changes_it() {
    let dir = scratch_dir("local-sh-port");
    // Another run's learner, as far as the port is concerned.
    let taken = std::net::TcpListener::bind("127.0.0.1:0").expect("a port to hold");
    let port = taken.local_addr().expect("its address").port().to_string();
    let (mut launch, _) = start(&dir, "port", &["--port", &port]);
    let status = wait_for(Duration::from_secs(30), "the script to give up", || {
        launch
            .run
            .script
            .try_wait()
            .expect("waiting for the script")
    });
    let log = std::fs::read_to_string(&launch.run.log).unwrap_or_default();
    assert!(!status.success(), "{status}:\n{log}");
    assert!(
        log.contains(&format!("port {port} is taken")) && log.contains("with --port"),
        "the script names the port and its option:\n{log}"
    );
    drop(taken);
}
