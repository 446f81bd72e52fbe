//! `gateway bench`: what crossing hosts through the gateway pair costs,
//! side by side in one run with the same messages over local iceoryx2 (one
//! host, no gateway) and over one plain loopback TCP stream.
//!
//! Every case sends valid rollout messages of a given size from an actor's
//! ports and validates them where the learner would read them; a sender
//! keeps at most four messages unreceived, so no buffer on the way
//! overflows and nothing is lost. Streaming throughput is message bytes
//! over the time to receive `count` of them; latency is lock-step, one
//! message at a time. Both gateways run in this process on their own
//! threads, as `gateway learner-host` and `gateway actor-host` would,
//! linked by Zenoh over 127.0.0.1.

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use proto::{encoded_len, JoinKey, Limits, MessageHeader, MessageKind, RolloutChunk, HEADER_LEN};
use transport::{ActorPorts, Delivery, LearnerPorts, TransportConfig};

use crate::actor_host::{self, ActorHost};
use crate::learner_host::{self, LearnerHost};
pub use crate::measure::Figures;
use crate::measure::{measure, percentile, Received, WINDOW};

/// Time for new weights to reach a remote actor.
#[derive(Debug, Clone)]
pub struct WeightsFigure {
    /// Safetensors bytes.
    pub bytes: usize,
    /// From the learner's publish to the remote actor's signature check,
    /// median ms.
    pub median_ms: f64,
}

/// Everything one benchmark run measured.
#[derive(Debug, Clone)]
pub struct Report {
    /// Per path and message size.
    pub paths: Vec<Figures>,
    /// Per weights size, through the gateway pair.
    pub weights: Vec<WeightsFigure>,
    /// Cases that could not be measured, and why.
    pub failed: Vec<String>,
}

/// A safetensors file of one `size`-byte tensor: what a weights message
/// must carry to be forwarded.
fn safetensors_of(size: usize) -> Vec<u8> {
    let header = format!(
        r#"{{"policy.bench":{{"dtype":"U8","shape":[{size}],"data_offsets":[0,{size}]}}}}"#
    );
    let mut out = (header.len() as u64).to_le_bytes().to_vec();
    out.extend_from_slice(header.as_bytes());
    out.extend((0..size).map(|i| i as u8));
    out
}

/// A thread that receives and validates rollouts from `ports` (a learner's)
/// and counts them, until `stop`.
fn learner_thread(
    config: TransportConfig,
    key: JoinKey,
    received: Arc<Received>,
    stop: Arc<AtomicBool>,
) -> std::thread::JoinHandle<anyhow::Result<()>> {
    std::thread::spawn(move || {
        let ports = LearnerPorts::open(&config, key)?;
        let limits = Limits {
            max_actors: config.max_actors,
            max_payload_len: config.max_rollout_bytes as u64,
        };
        while !stop.load(Ordering::Relaxed) {
            ports.wait(Duration::from_millis(1))?;
            while let Some(message) = ports.receive(MessageKind::Rollout)? {
                proto::decode(message.bytes(), &limits)?;
                received.add();
            }
        }
        Ok(())
    })
}

/// Publishes `chunk` until a subscriber takes it.
fn publish(actor: &mut ActorPorts, chunk: &RolloutChunk) -> anyhow::Result<()> {
    while actor.publish(chunk, 1, 0)? == Delivery::Dropped {
        std::thread::sleep(Duration::from_micros(100));
    }
    Ok(())
}

fn transport_config(prefix: &str, max: usize) -> TransportConfig {
    TransportConfig {
        service_prefix: prefix.to_string(),
        max_actors: 4,
        max_rollout_bytes: max,
        max_weights_bytes: max,
        learner_buffer: WINDOW,
        ..TransportConfig::default()
    }
}

/// Local iceoryx2: an actor's ports to a learner's, one host.
fn local(sizes: &[usize], count: usize, key: &JoinKey, tag: &str) -> anyhow::Result<Vec<Figures>> {
    let max = sizes.iter().max().copied().unwrap_or(0) + 4096;
    let config = transport_config(&format!("afx-gwbench-local-{tag}"), max);
    let received = Arc::new(Received::default());
    let stop = Arc::new(AtomicBool::new(false));
    let learner = learner_thread(config.clone(), key.clone(), received.clone(), stop.clone());
    std::thread::sleep(Duration::from_millis(200));
    let mut actor = ActorPorts::open(&config, 0, key.clone())?;
    let mut figures = Vec::new();
    for &size in sizes {
        let chunk = RolloutChunk::filler(size, 16);
        figures.push(measure(
            "iceoryx2, one host",
            encoded_len(&chunk),
            count,
            WINDOW,
            &received,
            &mut || publish(&mut actor, &chunk),
        )?);
    }
    stop.store(true, Ordering::Relaxed);
    learner
        .join()
        .map_err(|_| anyhow::anyhow!("receiver panicked"))??;
    Ok(figures)
}

/// One loopback TCP stream, the same encoding and validation.
fn tcp(sizes: &[usize], count: usize) -> anyhow::Result<Vec<Figures>> {
    let listener = TcpListener::bind("127.0.0.1:0")?;
    let addr = listener.local_addr()?;
    let received = Arc::new(Received::default());
    let counter = received.clone();
    let max = sizes.iter().max().copied().unwrap_or(0) + 4096;
    let reader = std::thread::spawn(move || -> anyhow::Result<()> {
        let (mut stream, _) = listener.accept()?;
        let limits = Limits {
            max_actors: 4,
            max_payload_len: max as u64,
        };
        let mut buf = vec![0u8; HEADER_LEN];
        loop {
            buf.truncate(HEADER_LEN);
            if stream.read_exact(&mut buf).is_err() {
                return Ok(());
            }
            // The header's payload length (bytes 40..48, little-endian).
            let payload_len = u64::from_le_bytes(buf[40..48].try_into()?) as usize;
            buf.resize(HEADER_LEN + payload_len.min(max), 0);
            stream.read_exact(&mut buf[HEADER_LEN..])?;
            proto::decode(&buf, &limits)?;
            counter.add();
        }
    });
    let mut stream = TcpStream::connect(addr)?;
    stream.set_nodelay(true)?;
    let mut figures = Vec::new();
    for &size in sizes {
        let chunk = RolloutChunk::filler(size, 16);
        let mut out = vec![0u8; encoded_len(&chunk)];
        figures.push(measure(
            "loopback TCP",
            out.len(),
            count,
            WINDOW,
            &received,
            &mut || {
                proto::encode_into(&chunk, MessageHeader::default(), &mut out);
                stream.write_all(&out)?;
                Ok(())
            },
        )?);
    }
    drop(stream);
    reader
        .join()
        .map_err(|_| anyhow::anyhow!("reader panicked"))??;
    Ok(figures)
}

/// Writes a run directory for one side of the gateway pair.
fn run_dir(dir: &Path, config: &TransportConfig, key: &JoinKey) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir)?;
    let text = toml::to_string(&toml::Table::from_iter([(
        "transport".to_string(),
        toml::Value::try_from(config)?,
    )]))?;
    std::fs::write(dir.join("config.toml"), text)?;
    std::fs::write(dir.join(transport::JOIN_KEY_FILE), key.to_hex())?;
    Ok(())
}

/// Through the gateway pair: an actor on one "host" (prefix), its host's
/// gateway, Zenoh over loopback TCP, the learner host's gateway, a learner
/// on the other prefix. Also the time new weights take to reach the actor.
fn gateways(
    sizes: &[usize],
    count: usize,
    key: &JoinKey,
    tag: &str,
    scratch: &Path,
) -> anyhow::Result<Report> {
    let max = sizes.iter().max().copied().unwrap_or(0) + 4096;
    let learner_config = transport_config(&format!("afx-gwbench-learner-{tag}"), max);
    let learner_dir = scratch.join("learner");
    let host_dir = scratch.join("host");
    run_dir(&learner_dir, &learner_config, key)?;
    std::fs::create_dir_all(&host_dir)?;
    std::fs::write(host_dir.join(transport::JOIN_KEY_FILE), key.to_hex())?;
    let port = TcpListener::bind("127.0.0.1:0")?.local_addr()?.port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let stop = Arc::new(AtomicBool::new(false));
    let received = Arc::new(Received::default());
    let learner = learner_thread(
        learner_config.clone(),
        key.clone(),
        received.clone(),
        stop.clone(),
    );
    let learner_side = LearnerHost {
        run_dir: learner_dir,
        run: "bench".into(),
        listen: endpoint.clone(),
        zenoh_config: None,
    };
    let host_prefix = format!("afx-gwbench-host-{tag}");
    let host_side = ActorHost {
        run_dir: host_dir.clone(),
        run: "bench".into(),
        host: "bench-host".into(),
        learner_at: endpoint,
        service_prefix: Some(host_prefix.clone()),
        join_key: None,
        zenoh_config: None,
    };
    let (stop_l, stop_h) = (stop.clone(), stop.clone());
    let learner_gateway = std::thread::spawn(move || learner_host::run(&learner_side, &stop_l));
    let host_gateway = std::thread::spawn(move || actor_host::run(&host_side, &stop_h));
    let deadline = Instant::now() + Duration::from_secs(30);
    while !host_dir.join("config.toml").exists() {
        if Instant::now() > deadline {
            bail!("the actor host's gateway never got the run's config");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let host_config = TransportConfig {
        service_prefix: host_prefix,
        ..learner_config.clone()
    };
    let mut actor = ActorPorts::open(&host_config, 0, key.clone())?;
    let mut figures = Vec::new();
    for &size in sizes {
        let chunk = RolloutChunk::filler(size, 16);
        figures.push(measure(
            "gateway pair (Zenoh, loopback TCP)",
            encoded_len(&chunk),
            count,
            WINDOW,
            &received,
            &mut || publish(&mut actor, &chunk),
        )?);
    }
    // Weights: from the learner's publish to the remote actor's check.
    let mut weights_ports = LearnerPorts::open(&learner_config, key.clone())?;
    let mut weights = Vec::new();
    let mut version = 1;
    for &size in sizes.iter().filter(|&&s| s + 1024 < max) {
        let blob = safetensors_of(size);
        let mut times = Vec::new();
        for _ in 0..count.clamp(1, 5) {
            version += 1;
            let t = Instant::now();
            weights_ports.publish_weights(version, 0, &blob)?;
            loop {
                let Some(message) = actor.wait_for_weights(Duration::from_secs(10))? else {
                    bail!("weights of {size} bytes did not reach the remote actor within 10 s");
                };
                let (header, _) = actor.check_weights(&message).context("remote weights")?;
                if header.policy_version == version {
                    break;
                }
            }
            times.push(t.elapsed().as_secs_f64() * 1e3);
        }
        times.sort_by(f64::total_cmp);
        weights.push(WeightsFigure {
            bytes: size,
            median_ms: percentile(&times, 0.5),
        });
    }
    stop.store(true, Ordering::Relaxed);
    for (name, thread) in [
        ("learner host's gateway", learner_gateway),
        ("actor host's gateway", host_gateway),
    ] {
        thread
            .join()
            .map_err(|_| anyhow::anyhow!("the {name} panicked"))?
            .with_context(|| format!("the {name}"))?;
    }
    learner
        .join()
        .map_err(|_| anyhow::anyhow!("receiver panicked"))??;
    Ok(Report {
        paths: figures,
        weights,
        failed: Vec::new(),
    })
}

/// Runs every case for message sizes `sizes` (bytes), `count` messages
/// each; scratch files go to `scratch`; with `upstream_tunnel` (the path of
/// `iox2-link-tunnel-zenoh`) also through iceoryx2's own bridge. Returns
/// the figures and, per size, the median time (ms) new weights took to
/// reach the remote actor.
pub fn run(
    sizes: &[usize],
    count: usize,
    scratch: &Path,
    upstream_tunnel: Option<&Path>,
) -> anyhow::Result<Report> {
    let key = JoinKey::from_bytes([9; proto::JOIN_KEY_LEN]);
    let tag = std::process::id().to_string();
    let mut figures = local(sizes, count, &key, &tag)?;
    figures.extend(tcp(sizes, count)?);
    let through = gateways(sizes, count, &key, &tag, scratch)?;
    figures.extend(through.paths);
    let mut failed = Vec::new();
    if let Some(binary) = upstream_tunnel {
        for row in crate::bench_tunnel::upstream_tunnel(binary, sizes, count, scratch)? {
            match row {
                Ok(f) => figures.push(f),
                Err(why) => failed.push(why),
            }
        }
    }
    Ok(Report {
        paths: figures,
        weights: through.weights,
        failed,
    })
}

/// The figures as a Markdown table, one row per size, a column group per path.
pub fn table(report: &Report) -> String {
    let figures = &report.paths;
    let mut out = String::from(
        "| message | path | MiB/s | p50 ms | p99 ms | gateway ÷ TCP (MiB/s) |\n|---|---|---|---|---|---|\n",
    );
    for f in figures {
        let tcp = figures
            .iter()
            .find(|t| t.path == "loopback TCP" && t.bytes == f.bytes)
            .map(|t| t.mib_per_s);
        let ratio = match tcp {
            Some(tcp) if f.path != "loopback TCP" && f.path != "iceoryx2, one host" => {
                format!("{:.2}", f.mib_per_s / tcp)
            }
            _ => String::new(),
        };
        out.push_str(&format!(
            "| {:.2} MiB | {} | {:.0} | {:.2} | {:.2} | {ratio} |\n",
            f.bytes as f64 / f64::from(1u32 << 20),
            f.path,
            f.mib_per_s,
            f.p50_ms,
            f.p99_ms
        ));
    }
    for why in &report.failed {
        out.push_str(&format!("\nNot measured: {why}\n"));
    }
    out.push_str("\n| weights | publish → checked by the remote actor, median ms |\n|---|---|\n");
    for WeightsFigure {
        bytes: size,
        median_ms: ms,
    } in &report.weights
    {
        out.push_str(&format!(
            "| {:.2} MiB | {ms:.1} |\n",
            *size as f64 / f64::from(1u32 << 20)
        ));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_path_carries_small_messages_and_weights_reach_the_remote_actor() {
        let dir = tempfile::tempdir().unwrap();
        let report = run(&[64 << 10], 3, dir.path(), None).unwrap();
        let paths: Vec<_> = report.paths.iter().map(|f| f.path).collect();
        assert_eq!(
            paths,
            [
                "iceoryx2, one host",
                "loopback TCP",
                "gateway pair (Zenoh, loopback TCP)"
            ]
        );
        for f in &report.paths {
            assert!(
                f.mib_per_s > 0.0 && f.p50_ms > 0.0 && f.p99_ms >= f.p50_ms,
                "{f:?}"
            );
        }
        assert_eq!(report.weights.len(), 1);
        assert!(report.weights[0].median_ms > 0.0);
        let table = table(&report);
        assert!(table.contains("gateway ÷ TCP"), "{table}");
    }
}
