//! Helpers for system tests: start the real `learner` and `actor` binaries,
//! talk HTTP to the learner, and clean up every process on drop.
//!
//! The binaries must be built first (`cargo build --workspace --bins`, as the
//! README's test command does); nothing here mocks a component.

use std::fs::File;
use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// Path of a workspace binary next to the running test executable.
pub fn bin(name: &str) -> PathBuf {
    let exe = std::env::current_exe().expect("test executable path");
    let dir = exe
        .parent()
        .and_then(Path::parent)
        .expect("target/<profile> directory");
    let path = dir.join(name);
    assert!(
        path.exists(),
        "{} not found: build the binaries first with `cargo build --workspace --bins`",
        path.display()
    );
    path
}

/// The shared data directory (iTHOR rooms and the object catalogue) beside
/// the repository, as the simulator actors of these tests read it.
pub fn shared_data_dir() -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data")
        .display()
        .to_string()
}

/// A unique scratch directory under the target directory.
pub fn scratch_dir(test: &str) -> PathBuf {
    let exe = std::env::current_exe().expect("test executable path");
    let dir = exe
        .parent()
        .and_then(Path::parent)
        .expect("target dir")
        .join("system-tests")
        .join(format!("{test}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("creating scratch dir");
    dir
}

/// Polls `f` every 50 ms until it returns `Some` or `timeout` passes.
pub fn wait_for<T>(timeout: Duration, what: &str, mut f: impl FnMut() -> Option<T>) -> T {
    let deadline = Instant::now() + timeout;
    loop {
        if let Some(v) = f() {
            return v;
        }
        assert!(
            Instant::now() < deadline,
            "timed out after {timeout:?} waiting for {what}"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// A child process whose stderr goes to a log file; killed on drop.
pub struct Process {
    /// The child.
    pub child: Child,
    /// Its combined stdout/stderr log.
    pub log: PathBuf,
}

impl Process {
    /// Starts `program args…`, logging to `log`.
    pub fn start(program: &Path, args: &[String], log: PathBuf) -> Self {
        let out = File::create(&log).expect("creating log file");
        let err = out.try_clone().expect("cloning log handle");
        let child = Command::new(program)
            .args(args)
            .env("RUST_BACKTRACE", "0")
            .stdout(Stdio::from(out))
            .stderr(Stdio::from(err))
            .spawn()
            .unwrap_or_else(|e| panic!("starting {}: {e}", program.display()));
        Self { child, log }
    }

    /// The log so far (empty when the log is no regular file, e.g.
    /// `/dev/full`, whose reads never end).
    pub fn log_text(&self) -> String {
        if !std::fs::metadata(&self.log).is_ok_and(|m| m.is_file()) {
            return String::new();
        }
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    /// Sends a signal (e.g. `libc::SIGKILL`).
    pub fn signal(&self, signal: i32) {
        // SAFETY: kill(2) on our own child's pid has no memory-safety preconditions.
        unsafe {
            libc::kill(self.child.id() as i32, signal);
        }
    }

    /// Waits for exit up to `timeout`; returns the exit status if it exited.
    pub fn wait_exit(&mut self, timeout: Duration) -> Option<std::process::ExitStatus> {
        let deadline = Instant::now() + timeout;
        while Instant::now() < deadline {
            if let Ok(Some(status)) = self.child.try_wait() {
                return Some(status);
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        None
    }
}

impl Drop for Process {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A running learner and where its HTTP endpoint is.
pub struct Learner {
    /// The process.
    pub process: Process,
    /// `host:port` of the HTTP endpoint.
    pub addr: String,
}

impl Learner {
    /// Starts `learner serve` with `args` (which must name a run directory via
    /// `--run-dir` or `--resume`) and waits until `/healthz` answers.
    pub fn start(run_dir: &Path, args: &[String], log: PathBuf) -> Self {
        let addr_file = run_dir.join("http.addr");
        let _ = std::fs::remove_file(&addr_file);
        let mut full = vec![
            "serve".to_string(),
            "--http-addr".into(),
            "127.0.0.1:0".into(),
        ];
        full.extend_from_slice(args);
        let mut process = Process::start(&bin("learner"), &full, log);
        let addr = wait_for(Duration::from_secs(20), "the learner's http.addr", || {
            if let Ok(Some(status)) = process.child.try_wait() {
                panic!("learner exited early ({status}):\n{}", process.log_text());
            }
            std::fs::read_to_string(&addr_file)
                .ok()
                .filter(|a| !a.is_empty())
        });
        wait_for(Duration::from_secs(10), "/healthz", || {
            http_get(&addr, "/healthz").filter(|(code, _)| *code == 200)
        });
        Self { process, addr }
    }

    /// `/api/status` as JSON.
    pub fn status(&self) -> serde_json::Value {
        let (code, body) =
            http_get(&self.addr, "/api/status").expect("learner answers /api/status");
        assert_eq!(code, 200, "{body}");
        serde_json::from_str(&body).expect("status is JSON")
    }

    /// `/metrics` text in the classic Prometheus format (what a client
    /// that does not ask for OpenMetrics gets).
    pub fn metrics(&self) -> String {
        let (code, body) = http_get(&self.addr, "/metrics").expect("learner answers /metrics");
        assert_eq!(code, 200);
        body
    }

    /// `/metrics` as OpenMetrics, asked for the way Prometheus asks.
    pub fn openmetrics(&self) -> String {
        let (code, body) = http_get_accepting(
            &self.addr,
            "/metrics",
            "application/openmetrics-text;version=1.0.0,text/plain;version=0.0.4;q=0.5",
        )
        .expect("learner answers /metrics");
        assert_eq!(code, 200);
        body
    }
}

/// Writes a run config for the bandit fixture (a wiring test environment)
/// with service prefix `prefix`, plus `extra` TOML lines at the top level.
pub fn bandit_config(dir: &Path, prefix: &str, extra: &str) -> PathBuf {
    let path = dir.join("bandit.toml");
    std::fs::write(
        &path,
        format!("{extra}\n[task]\nenv = \"bandit-fixture\"\n[transport]\nservice_prefix = \"{prefix}\"\nmax_actors = 4\n"),
    )
    .expect("writing the test config");
    path
}

/// Starts an actor of the learner on `prefix`; `extra` should name the run
/// config (`--config`), which says what environment to run.
pub fn start_actor(id: u32, prefix: &str, dir: &Path, extra: &[&str]) -> Process {
    let mut args = vec![
        "--actor-id".to_string(),
        id.to_string(),
        "--learner".into(),
        prefix.into(),
    ];
    args.extend(extra.iter().map(|s| s.to_string()));
    Process::start(
        &bin("actor"),
        &args,
        dir.join(format!("actor-{id}-{}.log", now_ms())),
    )
}

fn now_ms() -> u128 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_millis())
        .unwrap_or(0)
}

/// A plain HTTP/1.0 GET; `None` if the connection fails.
pub fn http_get(addr: &str, path: &str) -> Option<(u16, String)> {
    http_get_accepting(addr, path, "*/*")
}

/// [`http_get`] with an `Accept` header.
pub fn http_get_accepting(addr: &str, path: &str, accept: &str) -> Option<(u16, String)> {
    let mut stream = TcpStream::connect(addr).ok()?;
    stream.set_read_timeout(Some(Duration::from_secs(5))).ok()?;
    write!(
        stream,
        "GET {path} HTTP/1.0\r\nHost: {addr}\r\nAccept: {accept}\r\n\r\n"
    )
    .ok()?;
    let mut response = String::new();
    stream.read_to_string(&mut response).ok()?;
    let (head, body) = response.split_once("\r\n\r\n")?;
    let code = head.split_whitespace().nth(1)?.parse().ok()?;
    Some((code, body.to_string()))
}

/// Reads one sample's value from Prometheus text (`name` with exact labels, e.g. `afx_actors_alive`).
pub fn metric_value(text: &str, name_and_labels: &str) -> Option<f64> {
    text.lines().filter(|l| !l.starts_with('#')).find_map(|l| {
        l.strip_prefix(name_and_labels)
            .and_then(|rest| rest.strip_prefix(' '))
            .and_then(|v| v.trim().parse().ok())
    })
}

impl Learner {
    /// Starts a learner of the bandit fixture on services `prefix`, its run
    /// in `dir/run` and its log in `dir/learner.log`; returns it with the
    /// run's `config.toml`, which actors are started with.
    pub fn start_bandit(dir: &Path, prefix: &str) -> (Self, String) {
        let run_dir = dir.join("run");
        let bandit = bandit_config(dir, prefix, "");
        let learner = Self::start(
            &run_dir,
            &[
                "--config".into(),
                bandit.display().to_string(),
                "--run-dir".into(),
                run_dir.display().to_string(),
                "--service-prefix".into(),
                prefix.into(),
            ],
            dir.join("learner.log"),
        );
        (learner, run_dir.join("config.toml").display().to_string())
    }
}

/// A publish-subscribe service of the run on `prefix`, opened by name the
/// way any process of the same user could (its own iceoryx2 node, which
/// must live as long as the service).
pub fn open_as_outsider(
    prefix: &str,
    service: &str,
) -> (
    iceoryx2::prelude::Node<iceoryx2::prelude::ipc::Service>,
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<
        iceoryx2::prelude::ipc::Service,
        [u8],
        (),
    >,
) {
    use iceoryx2::prelude::*;
    let node = NodeBuilder::new()
        .create::<ipc::Service>()
        .expect("an iceoryx2 node");
    let name: ServiceName = proto::service::name(prefix, service)
        .as_str()
        .try_into()
        .expect("service name");
    let factory = node
        .service_builder(&name)
        .publish_subscribe::<[u8]>()
        .open()
        .unwrap_or_else(|e| panic!("opening the {service} service: {e:?}"));
    (node, factory)
}

/// The steps of a run's checkpoints (`RUN_DIR/checkpoints/<step>/`), oldest first.
pub fn checkpoint_steps(run_dir: &Path) -> Vec<u64> {
    let mut steps: Vec<u64> = std::fs::read_dir(run_dir.join("checkpoints"))
        .map(|d| {
            d.filter_map(|e| e.ok()?.file_name().to_str()?.parse().ok())
                .collect()
        })
        .unwrap_or_default();
    steps.sort_unstable();
    steps
}

/// A loopback TCP port nobody listens on now.
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("a free loopback port")
}

/// Starts `gateway learner-host` for the learner in `run_dir`, listening
/// on `endpoint` as run `run`, with `extra` arguments; logs to `log`.
pub fn start_learner_gateway(
    run_dir: &Path,
    endpoint: &str,
    run: &str,
    extra: &[&str],
    log: PathBuf,
) -> Process {
    let mut args = [
        "learner-host",
        "--run-dir",
        &run_dir.display().to_string(),
        "--listen",
        endpoint,
        "--run",
        run,
    ]
    .map(String::from)
    .to_vec();
    args.extend(extra.iter().map(|s| s.to_string()));
    Process::start(&bin("gateway"), &args, log)
}

/// Starts `gateway actor-host` for run `run` as host `host` on service
/// prefix `prefix`, its run directory `host_dir`, with `extra` arguments;
/// its log is `dir/gateway-<host>-<n>.log`.
pub fn start_host_gateway(
    dir: &Path,
    host_dir: &Path,
    endpoint: &str,
    prefix: &str,
    (run, host, n): (&str, &str, u32),
    extra: &[&str],
) -> Process {
    let mut args = [
        "actor-host",
        "--learner-at",
        endpoint,
        "--run-dir",
        &host_dir.display().to_string(),
        "--run",
        run,
        "--host",
        host,
        "--service-prefix",
        prefix,
    ]
    .map(String::from)
    .to_vec();
    args.extend(extra.iter().map(|s| s.to_string()));
    Process::start(
        &bin("gateway"),
        &args,
        dir.join(format!("gateway-{host}-{n}.log")),
    )
}

/// `dir/name`, an actor host's run directory, with a copy of the run's key
/// from `run_dir`.
pub fn host_dir(dir: &Path, run_dir: &Path, name: &str) -> PathBuf {
    let host_dir = dir.join(name);
    std::fs::create_dir_all(&host_dir).expect("creating the host's directory");
    std::fs::copy(run_dir.join("join.key"), host_dir.join("join.key"))
        .expect("copying the run's key");
    host_dir
}

/// A running `deploy/local.sh`, killed with its process group on drop.
pub struct Launch {
    /// The script's process (the leader of its process group).
    pub script: Child,
    /// Where its output goes.
    pub log: PathBuf,
}

impl Drop for Launch {
    fn drop(&mut self) {
        // SAFETY: kill(2) on the process group we created has no memory-safety preconditions.
        unsafe {
            libc::kill(-(self.script.id() as i32), libc::SIGKILL);
        }
        let _ = self.script.wait();
    }
}

/// Starts `deploy/local.sh` with two actors of the bandit fixture (seed 3,
/// the built binaries) on `run_dir`, its endpoint on `port`, its output in
/// `log`, with `extra` options after the others.
pub fn launch_bandit_run(run_dir: &Path, port: u16, log: PathBuf, extra: &[&str]) -> Launch {
    use std::os::unix::process::CommandExt;
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let out = File::create(&log).expect("log file");
    let script = Command::new(repo.join("deploy/local.sh"))
        .args(["--actors", "2", "--env", "bandit-fixture", "--seed", "3"])
        .arg("--bin-dir")
        .arg(bin("learner").parent().expect("binary dir"))
        .arg("--run-dir")
        .arg(run_dir)
        .args(["--port", &port.to_string()])
        .args(extra)
        .stdout(Stdio::from(out.try_clone().expect("log handle")))
        .stderr(Stdio::from(out))
        .process_group(0)
        .spawn()
        .expect("starting deploy/local.sh");
    Launch { script, log }
}

/// `/api/status` of the learner on local port `port`, when it answers.
pub fn run_status(port: u16) -> Option<serde_json::Value> {
    let (code, body) = http_get(&format!("127.0.0.1:{port}"), "/api/status")?;
    (code == 200).then(|| serde_json::from_str(&body).ok())?
}

/// Sends `signal` to the process whose id is `pid` (as a pid file holds it).
pub fn kill_pid(pid: &str, signal: i32) {
    let pid: i32 = pid.trim().parse().expect("a pid");
    // SAFETY: kill(2) has no memory-safety preconditions.
    unsafe {
        libc::kill(pid, signal);
    }
}

/// Waits at most `seconds` for `launch`'s script to exit; fails with its
/// output otherwise.
pub fn wait_launch_exit(launch: &mut Launch, seconds: u64) -> std::process::ExitStatus {
    let deadline = Instant::now() + Duration::from_secs(seconds);
    loop {
        if let Some(status) = launch.script.try_wait().expect("waiting for local.sh") {
            return status;
        }
        assert!(
            Instant::now() < deadline,
            "local.sh did not exit:\n{}",
            std::fs::read_to_string(&launch.log).unwrap_or_default()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}
