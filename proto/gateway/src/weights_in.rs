//! The learner's weights as they arrive at an actor host, handed to the
//! gateway's loop the moment they do.
//!
//! The actor host's loop sleeps on its shared-memory wakeup event, which
//! its actors ring; weights come over Zenoh, which does not ring it, and
//! the event's timeout is counted in kernel ticks (about 8 ms asked for 2,
//! see [`transport::Wakeup`]). So a thread of its own waits for them and
//! rings the event: new weights reach local actors without that delay.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender, TrySendError};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

use anyhow::Context;
use transport::{TransportConfig, Wakeup};
use zenoh::handlers::{FifoChannel, FifoChannelHandler};
use zenoh::pubsub::Subscriber;
use zenoh::sample::Sample;
use zenoh::Wait;

use crate::keys::RunKeys;
use crate::zenoh_error;

/// Weights messages held between the thread and the loop, which takes them
/// all each pass.
const HELD: usize = 4;

/// How often the thread looks whether it should stop.
const STOP_POLL: Duration = Duration::from_millis(200);

/// The receiving thread and what it hands over; dropping it stops the thread.
pub struct WeightsIn {
    arrived: Receiver<Sample>,
    quit: Arc<AtomicBool>,
    thread: Option<JoinHandle<anyhow::Result<()>>>,
}

impl WeightsIn {
    /// Subscribes to the run's weights on `session` and starts the thread
    /// that rings the wakeup event of `transport`'s services when they come.
    pub fn start(
        session: &zenoh::Session,
        keys: &RunKeys,
        transport: &TransportConfig,
    ) -> anyhow::Result<Self> {
        let subscriber = session
            .declare_subscriber(keys.weights())
            .with(FifoChannel::new(HELD))
            .wait()
            .map_err(zenoh_error)
            .context("subscribing to the learner's weights")?;
        let (handed, arrived) = sync_channel(HELD);
        let quit = Arc::new(AtomicBool::new(false));
        let thread = {
            let (transport, quit) = (transport.clone(), quit.clone());
            std::thread::Builder::new()
                .name("gateway-weights-in".into())
                .spawn(move || receive(subscriber, &transport, &handed, &quit))
                .context("starting the weights thread")?
        };
        Ok(Self {
            arrived,
            quit,
            thread: Some(thread),
        })
    }

    /// The next weights message that arrived, if any; an error if the thread
    /// stopped on one.
    pub fn try_next(&mut self) -> anyhow::Result<Option<Sample>> {
        if let Ok(sample) = self.arrived.try_recv() {
            return Ok(Some(sample));
        }
        if self.thread.as_ref().is_some_and(JoinHandle::is_finished) {
            if let Some(thread) = self.thread.take() {
                thread
                    .join()
                    .map_err(|_| anyhow::anyhow!("the weights thread panicked"))??;
            }
            anyhow::bail!("the weights thread stopped");
        }
        Ok(None)
    }
}

impl Drop for WeightsIn {
    fn drop(&mut self) {
        self.quit.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

/// Hands every weights message from `subscriber` to the loop and rings its
/// wakeup event, until `quit`.
fn receive(
    subscriber: Subscriber<FifoChannelHandler<Sample>>,
    transport: &TransportConfig,
    handed: &SyncSender<Sample>,
    quit: &AtomicBool,
) -> anyhow::Result<()> {
    let wakeup = Wakeup::open(transport, "gateway-weights-in")?;
    while !quit.load(Ordering::Relaxed) {
        let Some(sample) = subscriber
            .recv_timeout(STOP_POLL)
            .map_err(zenoh_error)
            .context("receiving weights from the learner's host")?
        else {
            continue;
        };
        if !hand_over(sample, handed, quit) {
            return Ok(());
        }
        wakeup.notify()?;
    }
    Ok(())
}

/// Puts `sample` in the loop's queue, waiting while it is full (the loop
/// empties it every pass); false if the loop is gone or `quit` was set.
fn hand_over(mut sample: Sample, handed: &SyncSender<Sample>, quit: &AtomicBool) -> bool {
    loop {
        match handed.try_send(sample) {
            Ok(()) => return true,
            Err(TrySendError::Full(back)) if !quit.load(Ordering::Relaxed) => {
                sample = back;
                std::thread::sleep(Duration::from_millis(1));
            }
            Err(_) => return false,
        }
    }
}
