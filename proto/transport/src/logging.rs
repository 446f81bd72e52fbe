//! Logging of every process that talks over the transport (learner, actors,
//! gateway): one setup, so that all of them log alike and none can die of
//! its own log.
//!
//! Logs go to stderr, which `deploy/local.sh` points at files in the run
//! directory. When that disk fills up, a write of a log line fails; the
//! formatter's default is then to report the failure with `eprintln!`, which
//! panics when stderr cannot be written, and so kills whichever thread
//! logged (a learner's receive loop died that way, 2026-11-29, and the run
//! stalled). Here a log line that cannot be written is lost, never the
//! thread: the run's own files (history, checkpoints) say what failed.

use std::io::IsTerminal;

use tracing_subscriber::fmt::MakeWriter;
use tracing_subscriber::EnvFilter;

/// A subscriber that writes events to `writer` as text, filtered by
/// `RUST_LOG` or else `default_filter` (e.g. `"info"`), and never reports
/// a failed write (see the module's doc).
fn subscriber<W>(default_filter: &str, writer: W, ansi: bool) -> impl tracing::Subscriber
where
    W: for<'w> MakeWriter<'w> + Send + Sync + 'static,
{
    tracing_subscriber::fmt()
        .with_env_filter(
            EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new(default_filter)),
        )
        .with_writer(writer)
        .with_ansi(ansi)
        .log_internal_errors(false)
        .finish()
}

/// Installs that subscriber on stderr for the whole process (colour codes
/// only on a terminal, so that log files stay plain text) and quietens
/// iceoryx2's own logger to warnings unless `IOX2_LOG_LEVEL` says otherwise.
/// Call it once, first thing in `main`.
pub fn init_logging(default_filter: &str) {
    let ansi = std::io::stderr().is_terminal();
    // A second call (only a test would make one) keeps the first subscriber.
    let _ =
        tracing::subscriber::set_global_default(subscriber(default_filter, std::io::stderr, ansi));
    iceoryx2::prelude::set_log_level_from_env_or(iceoryx2::prelude::LogLevel::Warn);
}
