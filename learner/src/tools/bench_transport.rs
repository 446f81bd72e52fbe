//! `learner bench-transport`: the real message path (encode with checksum into
//! the send buffer → transport → validating decode) over iceoryx2 shared
//! memory and over loopback TCP, side by side in one run.

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use proto::{
    decode, encode, encoded_len, Limits, Message, MessageHeader, RolloutChunk, WeightsBlob,
    HEADER_LEN,
};
use transport::{ActorPorts, Delivery, LearnerPorts, TransportConfig};

/// One measured case.
#[derive(Debug, Clone)]
pub struct Measurement {
    /// What was measured.
    pub case: String,
    /// Transport used.
    pub transport: &'static str,
    /// Streaming throughput, GiB/s of message bytes received and validated.
    pub gib_per_s: f64,
    /// Median one-message latency (lock-step), milliseconds.
    pub median_ms: f64,
}

fn weights_of(bytes: usize) -> Vec<u8> {
    let values = bytes / 4;
    let data: Vec<u8> = (0..values)
        .flat_map(|i| ((i % 97) as f32 * 0.01).to_le_bytes())
        .collect();
    let view = safetensors::tensor::TensorView::new(safetensors::Dtype::F32, vec![values], &data)
        .expect("shape and data length agree by construction");
    safetensors::serialize([("policy.bench", view)], None)
        .expect("serialising in-memory f32 tensors cannot fail")
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

fn limits(max: usize) -> Limits {
    Limits {
        max_actors: 16,
        max_payload_len: max as u64,
    }
}

/// The benchmark's actors talk to raw ports, not to a learner that checks
/// joins: any key will do, as long as both sides use it (weights are signed
/// with it).
fn bench_key() -> proto::JoinKey {
    proto::JoinKey::from_bytes([0; proto::JOIN_KEY_LEN])
}

fn config(tag: &str, max: usize) -> TransportConfig {
    TransportConfig {
        service_prefix: format!("afx-bench-{}-{tag}", std::process::id()),
        max_actors: 16,
        max_rollout_bytes: max,
        max_weights_bytes: max,
        learner_buffer: 4,
        ..TransportConfig::default()
    }
}

/// What one upstream measurement saw: when streaming started, when the
/// receiver decoded the last streamed message, and each lock-step round
/// trip (ms).
struct Upstream {
    start: Instant,
    last_received: Instant,
    latencies: Vec<f64>,
}

/// Sends `count` messages back to back, waits for the receiver's ack of the
/// last (`acks` carries when it decoded each message), then `count` more one
/// at a time, each waiting for its ack.
fn stream_then_lock_step(
    count: usize,
    mut send: impl FnMut() -> anyhow::Result<()>,
    acks: &mpsc::Receiver<Instant>,
) -> anyhow::Result<Upstream> {
    let start = Instant::now();
    for _ in 0..count {
        send()?;
    }
    let last_received = acks
        .recv_timeout(Duration::from_secs(30))
        .context("streaming phase")?;
    let mut latencies = Vec::new();
    for _ in 0..count {
        let t = Instant::now();
        send()?;
        acks.recv_timeout(Duration::from_secs(10))
            .context("lock-step ack")?;
        latencies.push(t.elapsed().as_secs_f64() * 1e3);
    }
    Ok(Upstream {
        start,
        last_received,
        latencies,
    })
}

/// Streaming throughput (GiB/s) from the sender's start to the receiver's
/// decode of the last message, and the median lock-step latency (ms).
fn summarise(
    bytes_per_message: usize,
    count: usize,
    start: Instant,
    last_received: Instant,
    latencies: Vec<f64>,
) -> (f64, f64) {
    let seconds = last_received.duration_since(start).as_secs_f64().max(1e-9);
    (
        (bytes_per_message * count) as f64 / seconds / f64::from(1u32 << 30),
        median(latencies),
    )
}

/// Actor → learner over iceoryx2.
fn iceoryx_upstream(size: usize, count: usize) -> anyhow::Result<(f64, f64)> {
    let chunk = RolloutChunk::filler(size, 64);
    let len = encoded_len(&chunk);
    let cfg = config(&format!("up{size}"), len);
    let (ready_tx, ready_rx) = mpsc::channel();
    let (ack_tx, ack_rx) = mpsc::channel::<Instant>();
    let receiver_cfg = cfg.clone();
    let receiver = std::thread::spawn(move || -> anyhow::Result<()> {
        let learner = LearnerPorts::open(&receiver_cfg, bench_key())?;
        ready_tx.send(())?;
        let mut received = 0;
        while received < 2 * count {
            learner.wait(Duration::from_millis(1))?;
            while let Some(m) = learner.receive(proto::MessageKind::Rollout)? {
                let (_, msg) = decode(m.bytes(), &limits(len))?;
                if !matches!(msg, Message::Rollout(_)) {
                    bail!("unexpected kind");
                }
                received += 1;
                if received >= count {
                    ack_tx.send(Instant::now())?;
                }
            }
        }
        Ok(())
    });
    ready_rx.recv()?;
    let mut actor = ActorPorts::open(&cfg, 0, bench_key())?;
    let send = |actor: &mut ActorPorts| -> anyhow::Result<()> {
        while actor.publish(&chunk, 1, 0)? == Delivery::Dropped {
            std::thread::yield_now();
        }
        Ok(())
    };
    let figures = stream_then_lock_step(count, || send(&mut actor), &ack_rx)?;
    receiver
        .join()
        .map_err(|_| anyhow::anyhow!("receiver panicked"))??;
    Ok(summarise(
        len,
        count,
        figures.start,
        figures.last_received,
        figures.latencies,
    ))
}

fn read_message(stream: &mut TcpStream, buf: &mut Vec<u8>) -> anyhow::Result<()> {
    buf.resize(HEADER_LEN, 0);
    stream.read_exact(buf)?;
    let payload_len = u64::from_le_bytes(buf[40..48].try_into()?) as usize;
    buf.resize(HEADER_LEN + payload_len, 0);
    stream.read_exact(&mut buf[HEADER_LEN..])?;
    Ok(())
}

/// Actor → learner over loopback TCP, same encode and decode.
fn tcp_upstream(size: usize, count: usize) -> anyhow::Result<(f64, f64)> {
    let chunk = RolloutChunk::filler(size, 64);
    let len = encoded_len(&chunk);
    let listener = TcpListener::bind("127.0.0.1:0")?;
    let addr = listener.local_addr()?;
    let (ack_tx, ack_rx) = mpsc::channel::<Instant>();
    let receiver = std::thread::spawn(move || -> anyhow::Result<()> {
        let (mut stream, _) = listener.accept()?;
        let mut buf = Vec::new();
        for received in 1..=2 * count {
            read_message(&mut stream, &mut buf)?;
            decode(&buf, &limits(len))?;
            if received >= count {
                ack_tx.send(Instant::now())?;
            }
        }
        Ok(())
    });
    let mut stream = TcpStream::connect(addr)?;
    stream.set_nodelay(true)?;
    let mut out = vec![0u8; len];
    let mut send = |stream: &mut TcpStream| -> anyhow::Result<()> {
        proto::encode_into(
            &chunk,
            MessageHeader {
                policy_version: 1,
                ..Default::default()
            },
            &mut out,
        );
        stream.write_all(&out)?;
        Ok(())
    };
    let figures = stream_then_lock_step(count, || send(&mut stream), &ack_rx)?;
    receiver
        .join()
        .map_err(|_| anyhow::anyhow!("receiver panicked"))??;
    Ok(summarise(
        len,
        count,
        figures.start,
        figures.last_received,
        figures.latencies,
    ))
}

/// Learner → `subscribers` actors over iceoryx2, lock-step: every publish
/// waits until all subscribers decoded it. Throughput counts every copy received.
fn iceoryx_broadcast(size: usize, subscribers: u32, count: usize) -> anyhow::Result<(f64, f64)> {
    let blob = weights_of(size);
    let len = encoded_len(&WeightsBlob::signed(
        &bench_key(),
        &MessageHeader::default(),
        &blob,
    ));
    let cfg = config(&format!("bc{size}"), len);
    let (ready_tx, ready_rx) = mpsc::channel();
    let (ack_tx, ack_rx) = mpsc::channel::<()>();
    let mut learner = LearnerPorts::open(&cfg, bench_key())?;
    let mut threads = Vec::new();
    for id in 0..subscribers {
        let (cfg, ready_tx, ack_tx) = (cfg.clone(), ready_tx.clone(), ack_tx.clone());
        threads.push(std::thread::spawn(move || -> anyhow::Result<()> {
            let actor = ActorPorts::open(&cfg, id, bench_key())?;
            ready_tx.send(())?;
            let mut seen = 0;
            while seen < count {
                if let Some(m) = actor.wait_for_weights(Duration::from_secs(10))? {
                    actor.check_weights(&m)?;
                    seen += 1;
                    ack_tx.send(())?;
                }
            }
            Ok(())
        }));
    }
    for _ in 0..subscribers {
        ready_rx.recv()?;
    }
    let mut latencies = Vec::new();
    let start = Instant::now();
    for version in 1..=count as u64 {
        let t = Instant::now();
        if learner.publish_weights(version, 0, &blob)? == Delivery::Dropped {
            bail!("weights publish dropped");
        }
        for _ in 0..subscribers {
            ack_rx
                .recv_timeout(Duration::from_secs(10))
                .context("broadcast ack")?;
        }
        latencies.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let end = Instant::now();
    for t in threads {
        t.join()
            .map_err(|_| anyhow::anyhow!("subscriber panicked"))??;
    }
    Ok(summarise(
        len * subscribers as usize,
        count,
        start,
        end,
        latencies,
    ))
}

/// Learner → `subscribers` actors over loopback TCP (one connection each), lock-step.
fn tcp_broadcast(size: usize, subscribers: u32, count: usize) -> anyhow::Result<(f64, f64)> {
    let blob = weights_of(size);
    let header = MessageHeader {
        actor_id: proto::LEARNER_ID,
        ..Default::default()
    };
    let message = encode(&WeightsBlob::signed(&bench_key(), &header, &blob), header);
    let len = message.len();
    let listener = TcpListener::bind("127.0.0.1:0")?;
    let addr = listener.local_addr()?;
    let (ack_tx, ack_rx) = mpsc::channel::<()>();
    let mut threads = Vec::new();
    for _ in 0..subscribers {
        let ack_tx = ack_tx.clone();
        threads.push(std::thread::spawn(move || -> anyhow::Result<()> {
            let mut stream = TcpStream::connect(addr)?;
            let mut buf = Vec::new();
            for _ in 0..count {
                read_message(&mut stream, &mut buf)?;
                proto::decode_weights(&buf, &limits(len), &bench_key())?;
                ack_tx.send(())?;
            }
            Ok(())
        }));
    }
    let mut streams = Vec::new();
    for _ in 0..subscribers {
        let (s, _) = listener.accept()?;
        s.set_nodelay(true)?;
        streams.push(s);
    }
    let mut latencies = Vec::new();
    let start = Instant::now();
    for _ in 0..count {
        let t = Instant::now();
        for s in &mut streams {
            s.write_all(&message)?;
        }
        for _ in 0..subscribers {
            ack_rx
                .recv_timeout(Duration::from_secs(10))
                .context("broadcast ack")?;
        }
        latencies.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let end = Instant::now();
    for t in threads {
        t.join()
            .map_err(|_| anyhow::anyhow!("subscriber panicked"))??;
    }
    Ok(summarise(
        len * subscribers as usize,
        count,
        start,
        end,
        latencies,
    ))
}

/// Runs every case and returns the measurements, iceoryx2 then TCP per case.
pub fn run(repeats: usize) -> anyhow::Result<Vec<Measurement>> {
    let mut out = Vec::new();
    let mut push = |case: &str, transport: &'static str, (gib_per_s, median_ms): (f64, f64)| {
        eprintln!("{case:<34} {transport:<9} {gib_per_s:>7.2} GiB/s  median {median_ms:>8.3} ms");
        out.push(Measurement {
            case: case.into(),
            transport,
            gib_per_s,
            median_ms,
        });
    };
    for (size, count) in [(1usize << 20, 100 * repeats), (16 << 20, 10 * repeats)] {
        let case = format!("actor -> learner, {} MiB", size >> 20);
        push(&case, "iceoryx2", iceoryx_upstream(size, count)?);
        push(&case, "tcp", tcp_upstream(size, count)?);
    }
    let case = "weights 8 MiB -> 8 subscribers";
    push(
        case,
        "iceoryx2",
        iceoryx_broadcast(8 << 20, 8, 10 * repeats)?,
    );
    push(case, "tcp", tcp_broadcast(8 << 20, 8, 10 * repeats)?);
    Ok(out)
}

/// A markdown table with iceoryx2 / TCP ratios.
pub fn table(measurements: &[Measurement]) -> String {
    let mut s = String::from("| case | iceoryx2 GiB/s | TCP GiB/s | ratio | iceoryx2 median ms | TCP median ms | ratio |\n|---|---|---|---|---|---|---|\n");
    for pair in measurements.chunks(2) {
        if let [shm, tcp] = pair {
            s += &format!(
                "| {} | {:.2} | {:.2} | {:.1}x | {:.3} | {:.3} | {:.1}x |\n",
                shm.case,
                shm.gib_per_s,
                tcp.gib_per_s,
                shm.gib_per_s / tcp.gib_per_s,
                shm.median_ms,
                tcp.median_ms,
                tcp.median_ms / shm.median_ms
            );
        }
    }
    s
}
