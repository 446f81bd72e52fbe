//! How `gateway bench` measures one path: streaming throughput with a few
//! messages in flight, then lock-step latency, counting arrivals on a
//! condition variable the sender sleeps on.

use std::sync::{Condvar, Mutex};
use std::time::{Duration, Instant};

use anyhow::bail;

/// Messages a sender may have in flight.
pub(crate) const WINDOW: usize = 4;

/// How long one case may take before the benchmark gives up.
const CASE_TIMEOUT: Duration = Duration::from_secs(120);

/// One measured case.
#[derive(Debug, Clone)]
pub struct Figures {
    /// Transport.
    pub path: &'static str,
    /// Message bytes.
    pub bytes: usize,
    /// Streaming throughput, MiB/s.
    pub mib_per_s: f64,
    /// Lock-step latency, median and 99th percentile, ms.
    pub p50_ms: f64,
    /// See `p50_ms`.
    pub p99_ms: f64,
}

/// Messages received so far, which a sender can sleep on (a spinning
/// sender would take a core from the paths it measures).
#[derive(Default)]
pub(crate) struct Received {
    count: Mutex<usize>,
    changed: Condvar,
}

impl Received {
    pub(crate) fn add(&self) {
        *self.count.lock().unwrap_or_else(|p| p.into_inner()) += 1;
        self.changed.notify_all();
    }

    fn now(&self) -> usize {
        *self.count.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Waits until at least `n` arrived or `until` passes; returns the count.
    fn wait_for(&self, n: usize, until: Instant) -> usize {
        let mut count = self.count.lock().unwrap_or_else(|p| p.into_inner());
        while *count < n {
            let left = until.saturating_duration_since(Instant::now());
            if left.is_zero() {
                break;
            }
            count = self
                .changed
                .wait_timeout(count, left)
                .unwrap_or_else(|p| p.into_inner())
                .0;
        }
        *count
    }
}

pub(crate) fn percentile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

/// Streams `count` messages through `send` with at most `window` in
/// flight, then `count` more one at a time; `received` counts what arrived.
pub(crate) fn measure(
    path: &'static str,
    bytes: usize,
    count: usize,
    window: usize,
    received: &Received,
    send: &mut dyn FnMut() -> anyhow::Result<()>,
) -> anyhow::Result<Figures> {
    let deadline = Instant::now() + CASE_TIMEOUT;
    let wait_until = |n: usize| -> anyhow::Result<()> {
        let got = received.wait_for(n, deadline);
        if got < n {
            bail!("{path}: only {got} of {n} messages arrived");
        }
        Ok(())
    };
    // One message first, sent again until it arrives: a new actor's first
    // messages may overtake its join and be refused on the way.
    let mut base = received.now();
    while received.now() == base {
        if Instant::now() > deadline {
            bail!("{path}: no message arrived");
        }
        send()?;
        received.wait_for(base + 1, Instant::now() + Duration::from_millis(200));
    }
    std::thread::sleep(Duration::from_millis(300));
    base = received.now();
    let start = Instant::now();
    for sent in 0..count {
        wait_until((base + sent).saturating_sub(window - 1))?;
        send()?;
    }
    wait_until(base + count)?;
    let seconds = start.elapsed().as_secs_f64().max(1e-9);
    let mut latencies = Vec::with_capacity(count);
    for i in 0..count {
        let t = Instant::now();
        send()?;
        wait_until(base + count + i + 1)?;
        latencies.push(t.elapsed().as_secs_f64() * 1e3);
    }
    latencies.sort_by(f64::total_cmp);
    Ok(Figures {
        path,
        bytes,
        mib_per_s: (bytes * count) as f64 / seconds / f64::from(1u32 << 20),
        p50_ms: percentile(&latencies, 0.5),
        p99_ms: percentile(&latencies, 0.99),
    })
}
