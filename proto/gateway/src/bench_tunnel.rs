//! The upstream bridge as a baseline for `gateway bench`: iceoryx2's own
//! `iox2 link tunnel zenoh` (crate `iceoryx2-integrations-zenoh-link-tunnel-cli`,
//! a prototype; why it is not the product: docs/decisions/0009-zenoh-gateway.md)
//! between two iceoryx2 systems on this machine.
//!
//! The two "hosts" are two iceoryx2 prefixes: each tunnel runs in a
//! directory of its own whose `config/iceoryx2.toml` sets it (iceoryx2 reads
//! that file first), and this process's publisher and subscriber use the
//! same two configs. Tunnel A listens on a loopback TCP port, B connects;
//! both bridge only this benchmark's service. The publisher rings an event
//! service after each message so tunnel A wakes at once (`--listener`);
//! tunnel B wakes on Zenoh data (`--reactive`); the subscriber polls every
//! 100 µs. Zenoh runs with the tunnel's defaults but for congestion
//! control, `Block` instead of `Drop` (through Zenoh's `qos/publication`
//! config, as the gateway pair uses): with `Drop` the tunnel lost a message
//! at every size tried (1 of 21 to 1 of 55), which a windowed sender cannot
//! measure past.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use anyhow::Context;
use iceoryx2::config::Config;
use iceoryx2::prelude::*;
use proto::{encoded_len, Limits, MessageHeader, RolloutChunk};

use crate::measure::{measure, Figures, Received, WINDOW};

/// What the rows of this path are called in the table.
pub const PATH: &str = "upstream iox2 tunnel (Zenoh, loopback TCP)";

/// Messages in flight through the tunnel: the subscriber the tunnel opens
/// on the sending side has iceoryx2's default buffer of 2, and with the
/// other paths' 4 in flight it lost a message now and then (1 of 26 at
/// 0.1 MiB, 1 of 55 at 1 MiB), which stalls a windowed sender.
const TUNNEL_WINDOW: usize = 2;

/// How often the receiving side looks for a sample.
const POLL: Duration = Duration::from_micros(100);

/// The tunnel processes; killed when dropped.
struct Tunnels(Vec<Child>);

impl Drop for Tunnels {
    fn drop(&mut self) {
        for child in &mut self.0 {
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}

/// An iceoryx2 config whose files carry `prefix`: one "host".
fn config_with_prefix(prefix: &str) -> anyhow::Result<Config> {
    let mut config = Config::default();
    config.global.prefix = FileName::new(prefix.as_bytes())
        .map_err(|e| anyhow::anyhow!("iceoryx2 prefix {prefix:?}: {e:?}"))?;
    Ok(config)
}

/// A directory for one tunnel: its iceoryx2 config (the prefix) and its
/// Zenoh config (listen on, or connect to, `endpoint`).
fn tunnel_dir(scratch: &Path, name: &str, prefix: &str, zenoh: &str) -> anyhow::Result<PathBuf> {
    let dir = scratch.join(name);
    std::fs::create_dir_all(dir.join("config"))?;
    std::fs::write(
        dir.join("config/iceoryx2.toml"),
        format!("[global]\nprefix = \"{prefix}\"\n"),
    )?;
    std::fs::write(dir.join("zenoh.json5"), zenoh)?;
    Ok(dir)
}

/// Starts one tunnel in `dir`, bridging services named like `allow`.
fn start_tunnel(binary: &Path, dir: &Path, allow: &str, wake: &[&str]) -> anyhow::Result<Child> {
    let log = std::fs::File::create(dir.join("tunnel.log"))?;
    let mut command = Command::new(binary);
    command
        .current_dir(dir)
        .args(["--zenoh-config", "zenoh.json5", "--allow", allow])
        .args(wake)
        .stdin(Stdio::null())
        .stdout(log.try_clone()?)
        .stderr(log);
    command
        .spawn()
        .with_context(|| format!("starting the upstream tunnel {}", binary.display()))
}

/// Valid rollout messages of each of `sizes` through the upstream tunnel
/// pair; `binary` is `iox2-link-tunnel-zenoh`. Each size gets a service and
/// a tunnel pair of its own: a tunnel that bridged smaller messages of a
/// service drops larger ones (seen: after 0.1 MiB messages, none of 4 MiB
/// arrived; 4 MiB alone crossed). A size whose messages do not all arrive
/// gives an error row, not a failure of the whole benchmark.
pub fn upstream_tunnel(
    binary: &Path,
    sizes: &[usize],
    count: usize,
    scratch: &Path,
) -> anyhow::Result<Vec<Result<Figures, String>>> {
    sizes
        .iter()
        .enumerate()
        .map(|(case, &size)| one_size(binary, size, count, &scratch.join(format!("tunnel-{case}"))))
        .collect()
}

/// One size through a fresh tunnel pair (see [`upstream_tunnel`]).
fn one_size(
    binary: &Path,
    size: usize,
    count: usize,
    scratch: &Path,
) -> anyhow::Result<Result<Figures, String>> {
    // Unique per process and case: the prefixes keep the two "hosts" and
    // earlier cases apart.
    static CASES: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let tag = format!(
        "{}x{}",
        std::process::id(),
        CASES.fetch_add(1, Ordering::Relaxed)
    );
    let (prefix_a, prefix_b) = (format!("afxta{tag}_"), format!("afxtb{tag}_"));
    let service = format!("afx-tunnel-bench-{tag}/rollouts");
    let wake_service = format!("afx-tunnel-bench-{tag}/wake");
    let max = size + 4096;
    let port = std::net::TcpListener::bind("127.0.0.1:0")?
        .local_addr()?
        .port();
    let zenoh = |role: &str| {
        format!(
            r#"{{ mode: "peer", {role}: {{ endpoints: ["tcp/127.0.0.1:{port}"] }}, scouting: {{ multicast: {{ enabled: false }} }}, qos: {{ publication: [{{ key_exprs: ["**"], config: {{ congestion_control: "block" }} }}] }} }}"#
        )
    };
    let dir_a = tunnel_dir(scratch, "a", &prefix_a, &zenoh("listen"))?;
    let dir_b = tunnel_dir(scratch, "b", &prefix_b, &zenoh("connect"))?;

    // The receiving side first, so the tunnel finds the service with its
    // settings (a buffer for the window) instead of mirroring defaults.
    let received = Arc::new(Received::default());
    let stop = Arc::new(AtomicBool::new(false));
    let receiver = {
        let (config, name, received, stop) = (
            config_with_prefix(&prefix_b)?,
            service.clone(),
            received.clone(),
            stop.clone(),
        );
        std::thread::spawn(move || receive(&config, &name, max, &received, &stop))
    };
    let config_a = config_with_prefix(&prefix_a)?;
    let node = NodeBuilder::new()
        .config(&config_a)
        .create::<ipc::Service>()
        .map_err(|e| anyhow::anyhow!("creating the sending node: {e:?}"))?;
    let publisher = node
        .service_builder(&ServiceName::new(&service).map_err(|e| anyhow::anyhow!("{e:?}"))?)
        .publish_subscribe::<[u8]>()
        .subscriber_max_buffer_size(2 * WINDOW)
        .open_or_create()
        .map_err(|e| anyhow::anyhow!("creating the sending service: {e:?}"))?
        .publisher_builder()
        .initial_max_slice_len(max)
        .allocation_strategy(AllocationStrategy::Static)
        .create()
        .map_err(|e| anyhow::anyhow!("creating the publisher: {e:?}"))?;
    let notifier = node
        .service_builder(&ServiceName::new(&wake_service).map_err(|e| anyhow::anyhow!("{e:?}"))?)
        .event()
        .open_or_create()
        .map_err(|e| anyhow::anyhow!("creating the wake event: {e:?}"))?
        .notifier_builder()
        .create()
        .map_err(|e| anyhow::anyhow!("creating the wake notifier: {e:?}"))?;

    let allow = format!("afx-tunnel-bench-{tag}/*");
    let tunnels = Tunnels(vec![
        start_tunnel(
            binary,
            &dir_a,
            &allow,
            &["--listener", &wake_service, "--reactive"],
        )?,
        start_tunnel(binary, &dir_b, &allow, &["--reactive"])?,
    ]);
    let chunk = RolloutChunk::filler(size, 16);
    let mut send = || -> anyhow::Result<()> {
        let len = encoded_len(&chunk);
        let sample = publisher
            .loan_slice_uninit(len)
            .map_err(|e| anyhow::anyhow!("loaning {len} bytes: {e:?}"))?;
        let mut sample = sample.write_from_fn(|_| 0);
        proto::encode_into(&chunk, MessageHeader::default(), sample.payload_mut());
        sample
            .send()
            .map_err(|e| anyhow::anyhow!("sending: {e:?}"))?;
        let _ = notifier.notify();
        Ok(())
    };
    // The first message may go before the tunnels found each other and the
    // service: `measure` sends it again until one arrives.
    let figures = measure(
        PATH,
        encoded_len(&chunk),
        count,
        TUNNEL_WINDOW,
        &received,
        &mut send,
    );
    drop(tunnels);
    stop.store(true, Ordering::Relaxed);
    receiver
        .join()
        .map_err(|_| anyhow::anyhow!("the receiving thread panicked"))??;
    Ok(figures.map_err(|e| {
        format!(
            "{e:#}; tunnel A's log ends: {}; tunnel B's: {}",
            log_tail(&dir_a),
            log_tail(&dir_b)
        )
    }))
}

/// The last lines of a tunnel's log, on one line.
fn log_tail(dir: &Path) -> String {
    let text = std::fs::read_to_string(dir.join("tunnel.log")).unwrap_or_default();
    let lines: Vec<&str> = text.lines().filter(|l| !l.trim().is_empty()).collect();
    let tail = lines[lines.len().saturating_sub(4)..].join(" / ");
    if tail.is_empty() {
        "(empty)".into()
    } else {
        tail
    }
}

/// Receives and validates messages on the other "host" until `stop`.
fn receive(
    config: &Config,
    name: &str,
    max: usize,
    received: &Received,
    stop: &AtomicBool,
) -> anyhow::Result<()> {
    let node = NodeBuilder::new()
        .config(config)
        .create::<ipc::Service>()
        .map_err(|e| anyhow::anyhow!("creating the receiving node: {e:?}"))?;
    let subscriber = node
        .service_builder(&ServiceName::new(name).map_err(|e| anyhow::anyhow!("{e:?}"))?)
        .publish_subscribe::<[u8]>()
        .subscriber_max_buffer_size(2 * WINDOW)
        .open_or_create()
        .map_err(|e| anyhow::anyhow!("creating the receiving service: {e:?}"))?
        .subscriber_builder()
        .buffer_size(2 * WINDOW)
        .create()
        .map_err(|e| anyhow::anyhow!("creating the subscriber: {e:?}"))?;
    let limits = Limits {
        max_actors: 4,
        max_payload_len: max as u64,
    };
    while !stop.load(Ordering::Relaxed) {
        match subscriber.receive() {
            Ok(Some(sample)) => {
                proto::decode(sample.payload(), &limits)?;
                received.add();
            }
            Ok(None) => std::thread::sleep(POLL),
            Err(e) => anyhow::bail!("receiving through the tunnel: {e:?}"),
        }
    }
    Ok(())
}
