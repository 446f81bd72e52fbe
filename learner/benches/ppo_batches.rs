//! `cargo bench -p learner --bench ppo_batches`: what gathering rollout
//! chunks into a PPO batch and building it for the device costs, per batch,
//! with the batch's buffers kept from the batch before (the learner's way)
//! and with a fresh builder for every batch (how it was until the buffers
//! were kept), alternated in one run.
//!
//! The chunks are the default `ours` task's (byte observations of the
//! camera and both maps, 16 steps each, as actors send them), 1 024 steps a
//! batch (`AFX_BATCH_STEPS`), at 64 and 128 px (`AFX_BENCH_SIDES=64`).
//! Gathering is every chunk but the last (advantages, observations
//! copied); building is the last chunk's, which turns the batch into the
//! device's tensors: decoded to floats on every core for the CPU, or the
//! bytes uploaded and converted there on libtorch (`AFX_DEVICE=gpu`, a
//! build with `nets/gpu-torch`). Medians over `AFX_REPEATS` (default 5)
//! batches each.

use std::time::Instant;

use learner::config::PolicyConfig;
use proto::{decode, Limits, Message, MessageHeader, TaskSpec};
use rand::rngs::StdRng;
use rand::SeedableRng;
use training::ppo_batcher::{BatchBuilder, PolicyTrainer};
use training::synthetic;

const CHUNK_STEPS: usize = 16;

fn env_usize(name: &str, default: usize) -> usize {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// Seconds gathering and building one batch from `messages`, round and round.
fn one_batch(builder: &mut BatchBuilder, messages: &[Vec<u8>]) -> (f64, f64) {
    let limits = Limits {
        max_actors: 1,
        max_payload_len: u64::MAX,
    };
    let mut gathered = 0.0;
    for bytes in messages.iter().cycle() {
        let Ok((_, Message::Rollout(view))) = decode(bytes, &limits) else {
            panic!("a valid rollout message");
        };
        let started = Instant::now();
        let batch = builder.add_chunk(&view, 1).expect("the task's chunk");
        let seconds = started.elapsed().as_secs_f64();
        match batch {
            Some(batch) => {
                drop(batch);
                return (gathered, seconds);
            }
            None => gathered += seconds,
        }
    }
    unreachable!("a cycle over messages never ends")
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    if std::env::args().any(|a| a == "--list") {
        return; // `cargo test --benches` asks for a list; there is none
    }
    let choice = std::env::var("AFX_DEVICE").unwrap_or_else(|_| "cpu".into());
    let device = (choice.parse().map_err(|e| format!("{e}")))
        .and_then(|c| nets::device::open_device(c).map_err(|e| format!("{e}")))
        .unwrap_or_else(|e| {
            eprintln!("AFX_DEVICE: {e}");
            std::process::exit(2);
        });
    let batch_steps = env_usize("AFX_BATCH_STEPS", 1024);
    let repeats = env_usize("AFX_REPEATS", 5).max(1);
    let sides: Vec<usize> = std::env::var("AFX_BENCH_SIDES")
        .unwrap_or_else(|_| "64,128".into())
        .split(',')
        .filter_map(|s| s.trim().parse().ok())
        .collect();
    println!(
        "PPO batches of {batch_steps} steps in chunks of {CHUNK_STEPS}, built for {choice} ({}); medians of {repeats}",
        nets::device::backend_features()
    );
    println!("| px | builder | gathering (ms) | building (ms) | batch (ms) |");
    println!("|---|---|---|---|---|");
    for side in sides {
        let task = TaskSpec {
            image_size: side,
            ..TaskSpec::default()
        };
        let settings = PolicyConfig {
            batch_steps,
            ..PolicyConfig::default()
        };
        let messages: Vec<Vec<u8>> = (0..4)
            .map(|seed| {
                let mut rng = StdRng::seed_from_u64(seed);
                let chunk = synthetic::rollout(&task.layout(), CHUNK_STEPS, &mut rng);
                proto::encode(&chunk, MessageHeader::default())
            })
            .collect();
        let trainer = PolicyTrainer::new(&task, &settings, &device);
        let mut kept = trainer.batch_builder();
        // A batch each first: the kept builder's buffers grow to size.
        one_batch(&mut kept, &messages);
        one_batch(&mut trainer.batch_builder(), &messages);
        let (mut kept_times, mut fresh_times) = (Vec::new(), Vec::new());
        for _ in 0..repeats {
            kept_times.push(one_batch(&mut kept, &messages));
            fresh_times.push(one_batch(&mut trainer.batch_builder(), &messages));
        }
        for (name, times) in [("kept buffers", kept_times), ("fresh", fresh_times)] {
            let gathering = median(times.iter().map(|t| t.0).collect());
            let building = median(times.iter().map(|t| t.1).collect());
            let total = median(times.iter().map(|t| t.0 + t.1).collect());
            println!(
                "| {side} | {name} | {:.1} | {:.1} | {:.1} |",
                gathering * 1e3,
                building * 1e3,
                total * 1e3
            );
        }
    }
}
