//! One U-Net for the environments' threads on a GPU: each environment's
//! thread hands its camera frame (as the network's input) to a batching
//! thread and waits for its logits; the batching thread runs every frame
//! waiting in one forward pass. The environments' threads make the inputs
//! and the probabilities, so the batching thread does nothing but the pass.
//!
//! Why: a GPU's batch of frames costs little more than one frame, and
//! nobody waits at a barrier for a batch to fill: the batches size
//! themselves. While one batch runs, the frames of the environments that
//! finish their first halves meanwhile queue up for the next, so the
//! busier the U-Net, the larger its batches.
//!
//! `AFX_UNET_BATCHERS=2` (up to 4) starts that many batching threads on one
//! queue, each taking every frame waiting when it is free: one batch's
//! copies and launches then overlap another's wait for the GPU. One by
//! default; whether two pay is for the next GPU run to measure
//! (docs/notebook/2026-11-27-actor-unet-on-libtorch.md).

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{channel, Receiver, Sender};
use std::sync::{Arc, Mutex, PoisonError, RwLock};
use std::thread::Scope;
use std::time::{Duration, Instant};

use anyhow::{anyhow, Context};

use super::named_thread::spawn_named;
use crate::env::affordance_model::{network_input, AffordanceModel, CameraFrame, Logits};
use crate::env::time_tally::TimeTally;

/// A frame's logits (or why there are none).
type Reply = Result<Logits, String>;

/// A camera frame as the network's input, and where its logits go.
struct Request {
    input: Vec<f32>,
    height: usize,
    width: usize,
    reply: Sender<Reply>,
}

/// An environment thread's way to the batching thread.
pub(crate) struct UnetClient {
    requests: Sender<Request>,
    reply: Sender<Reply>,
    replies: Receiver<Reply>,
}

impl UnetClient {
    /// A client of the batching thread that `requests` reach.
    fn new(requests: Sender<Request>) -> Self {
        let (reply, replies) = channel();
        Self {
            requests,
            reply,
            replies,
        }
    }

    /// Per affordance, the probability plane of `frame`, from the next batch.
    pub(crate) fn predict(&self, frame: &CameraFrame<'_>) -> anyhow::Result<Vec<Vec<f32>>> {
        let request = Request {
            input: network_input(frame),
            height: frame.height,
            width: frame.width,
            reply: self.reply.clone(),
        };
        let ended = || anyhow!("the U-Net's batching thread ended");
        self.requests.send(request).map_err(|_| ended())?;
        let logits = self
            .replies
            .recv()
            .map_err(|_| ended())?
            .map_err(|e| anyhow!(e))
            .context("the U-Net's batch")?;
        Ok(logits.probabilities())
    }
}

/// How many batching threads an actor starts: `AFX_UNET_BATCHERS` (1 to
/// 4), else 1.
pub(crate) fn batching_threads() -> usize {
    match std::env::var("AFX_UNET_BATCHERS") {
        Err(_) => 1,
        Ok(v) => match v.trim().parse() {
            Ok(n @ 1..=4) => n,
            _ => {
                tracing::warn!("AFX_UNET_BATCHERS takes 1 to 4, not {v:?}; using 1");
                1
            }
        },
    }
}

/// Starts `threads` batching threads in `scope` on one queue, running
/// `model` (which the caller may replace between batches); returns a maker
/// of clients. The threads end once the maker and every client are dropped.
pub(crate) fn start<'scope, 'env>(
    scope: &'scope Scope<'scope, 'env>,
    model: &'env RwLock<Option<AffordanceModel>>,
    threads: usize,
) -> Clients {
    let (requests, queue) = channel();
    let queue = Arc::new(Mutex::new(queue));
    for _ in 0..threads.max(1) {
        let queue = Arc::clone(&queue);
        spawn_named(scope, "unet-batch".to_owned(), move || serve(model, &queue));
    }
    Clients { requests }
}

/// Makes [`UnetClient`]s of one batching thread.
pub(crate) struct Clients {
    requests: Sender<Request>,
}

impl Clients {
    /// A client for one environment's thread.
    pub(crate) fn client(&self) -> UnetClient {
        UnetClient::new(self.requests.clone())
    }
}

/// Runs every waiting frame in one batch, until no client is left; with
/// other batching threads on the same queue, each takes what is waiting
/// when it is free.
fn serve(model: &RwLock<Option<AffordanceModel>>, queue: &Mutex<Receiver<Request>>) {
    loop {
        let batch = {
            let queue = queue.lock().unwrap_or_else(PoisonError::into_inner);
            let Ok(first) = queue.recv() else {
                return;
            };
            let mut batch = vec![first];
            batch.extend(queue.try_iter());
            batch
        };
        let started = Instant::now();
        // A panic in the network (a backend's) is every frame's error, not
        // a thread gone while environments wait for it.
        let logits = catch_unwind(AssertUnwindSafe(|| infer(model, &batch))).unwrap_or_else(|_| {
            let error = "the U-Net panicked".to_string();
            batch.iter().map(|_| Err(error.clone())).collect()
        });
        record(batch.len(), started.elapsed());
        for (request, logits) in batch.into_iter().zip(logits) {
            // A client gone meanwhile (its environment failed) wants nothing.
            let _ = request.reply.send(logits);
        }
    }
}

/// The logits of each frame of `batch`, in one forward pass (an actor's
/// environments share one task, so its frames share one size).
fn infer(model: &RwLock<Option<AffordanceModel>>, batch: &[Request]) -> Vec<Reply> {
    let every = |error: &str| batch.iter().map(|_| Err(error.to_string())).collect();
    let model = model.read().unwrap_or_else(PoisonError::into_inner);
    let Some(model) = model.as_ref() else {
        return every("this environment's camera frames need the U-Net");
    };
    let (height, width) = (batch[0].height, batch[0].width);
    if batch.iter().any(|r| (r.height, r.width) != (height, width)) {
        return every("the frames of one batch differ in size");
    }
    let inputs: Vec<&[f32]> = batch.iter().map(|r| r.input.as_slice()).collect();
    let logits = model.logits(&inputs, height, width);
    if logits.len() != batch.len() {
        return every("the U-Net gave logits for a different number of frames");
    }
    logits.into_iter().map(Ok).collect()
}

/// What the batching threads of this process did, in all: read by
/// benchmarks as the difference of two readings (how large the batches
/// grew, how busy the U-Net was).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct BatchTimes {
    /// Batches run.
    pub batches: u64,
    /// Frames in them.
    pub frames: u64,
    /// Time spent running them.
    pub busy: Duration,
}

impl BatchTimes {
    /// What happened from `earlier` to this reading.
    pub fn since(&self, earlier: &BatchTimes) -> BatchTimes {
        BatchTimes {
            batches: self.batches - earlier.batches,
            frames: self.frames - earlier.frames,
            busy: self.busy - earlier.busy,
        }
    }

    /// One phrase: the batches' mean size and how busy the U-Net was over
    /// `over` (the time the batches were run in); `None` when no batch
    /// ran (the U-Net on each environment's thread).
    pub fn describe(&self, over: Duration) -> Option<String> {
        (self.batches > 0).then(|| {
            format!(
                "U-Net batches of {:.1} frames, busy {:.0} % of the time ({:.1} ms each)",
                self.frames as f64 / self.batches as f64,
                100.0 * self.busy.as_secs_f64() / over.as_secs_f64().max(1e-9),
                self.busy.as_secs_f64() * 1e3 / self.batches as f64
            )
        })
    }
}

static BATCHES: AtomicU64 = AtomicU64::new(0);
static FRAMES: AtomicU64 = AtomicU64::new(0);
static BUSY: TimeTally = TimeTally::new();

/// This process's [`BatchTimes`] so far.
pub fn batch_times() -> BatchTimes {
    BatchTimes {
        batches: BATCHES.load(Ordering::Relaxed),
        frames: FRAMES.load(Ordering::Relaxed),
        busy: BUSY.total(),
    }
}

fn record(frames: usize, busy: Duration) {
    BATCHES.fetch_add(1, Ordering::Relaxed);
    FRAMES.fetch_add(frames as u64, Ordering::Relaxed);
    BUSY.add(busy);
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame_bytes(side: usize, shade: u8) -> (Vec<u8>, Vec<f32>) {
        let rgb = (0..side * side * 3)
            .map(|i| (i as u8).wrapping_mul(shade))
            .collect();
        let depth = (0..side * side)
            .map(|i| 0.5 + (i % 7) as f32 * 0.1 + f32::from(shade) * 0.01)
            .collect();
        (rgb, depth)
    }

    #[test]
    fn batch_times_describe_the_mean_batch_and_the_busy_share() {
        let earlier = BatchTimes {
            batches: 10,
            frames: 20,
            busy: Duration::from_millis(100),
        };
        let now = BatchTimes {
            batches: 40,
            frames: 140,
            busy: Duration::from_millis(250),
        };
        let between = now.since(&earlier);
        assert_eq!(
            between.describe(Duration::from_millis(600)).as_deref(),
            Some("U-Net batches of 4.0 frames, busy 25 % of the time (5.0 ms each)")
        );
        assert_eq!(
            earlier.since(&earlier).describe(Duration::from_secs(1)),
            None
        );
    }

    #[test]
    fn every_thread_gets_the_planes_of_its_own_frame_as_the_model_alone_gives_them() {
        for batching_threads in [1, 2] {
            planes_of_each_frame_as_alone(batching_threads);
        }
    }

    /// Six environments' threads hand their frames to `batching_threads`
    /// batching threads; each gets its own frame's planes.
    fn planes_of_each_frame_as_alone(batching_threads: usize) {
        let device = nets::device::open_device(nets::device::DeviceChoice::Cpu).unwrap();
        let model = RwLock::new(Some(AffordanceModel::new(2, &device)));
        let frames: Vec<(Vec<u8>, Vec<f32>)> = (1..=6).map(|k| frame_bytes(16, k)).collect();
        fn camera((rgb, depth): &(Vec<u8>, Vec<f32>)) -> CameraFrame<'_> {
            CameraFrame {
                rgb,
                depth_m: depth,
                height: 16,
                width: 16,
            }
        }
        let before = batch_times();
        let got: Vec<Vec<Vec<f32>>> = std::thread::scope(|scope| {
            let clients = start(scope, &model, batching_threads);
            let handles: Vec<_> = frames
                .iter()
                .map(|f| {
                    let client = clients.client();
                    scope.spawn(move || client.predict(&camera(f)).unwrap())
                })
                .collect();
            drop(clients);
            handles.into_iter().map(|h| h.join().unwrap()).collect()
        });
        let model = model.read().unwrap();
        for (k, (planes, f)) in got.iter().zip(&frames).enumerate() {
            let alone = model.as_ref().unwrap().predict(&camera(f));
            assert_eq!(planes.len(), 2, "frame {k}: a plane per affordance");
            for (p, a) in planes.iter().zip(&alone) {
                let worst = p
                    .iter()
                    .zip(a)
                    .map(|(x, y)| (x - y).abs())
                    .fold(0.0, f32::max);
                assert!(worst < 1e-5, "frame {k}: {worst}");
            }
        }
        let batched = batch_times().since(&before);
        assert!(batched.frames >= 6 && batched.batches >= 1, "{batched:?}");
    }

    #[test]
    fn without_a_model_a_frame_is_an_error_not_a_hang() {
        let model = RwLock::new(None);
        let (rgb, depth) = frame_bytes(8, 1);
        let error = std::thread::scope(|scope| {
            let client = start(scope, &model, 1).client();
            client
                .predict(&CameraFrame {
                    rgb: &rgb,
                    depth_m: &depth,
                    height: 8,
                    width: 8,
                })
                .unwrap_err()
        });
        assert!(format!("{error:#}").contains("need the U-Net"), "{error:#}");
    }
}
