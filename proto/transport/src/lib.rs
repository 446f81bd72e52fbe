//! iceoryx2 shared-memory transport between actors and the learner.
//!
//! One function opens each side ([`LearnerPorts::open`], [`ActorPorts::open`])
//! with every limit spelled out from a [`TransportConfig`]. Messages are byte
//! slices in the layouts of the `proto` crate; this crate moves bytes and never
//! interprets them beyond what it needs to count. It knows nothing of RL,
//! simulators or HTTP.
//!
//! Delivery semantics:
//! - actor → learner services never block the actor: when the learner's buffer
//!   is full (or no learner is connected) the message is discarded and counted
//!   ([`Delivery::Dropped`]); each publisher's memory is a fixed pre-allocated pool.
//! - learner → actors `weights` keeps a history of 1, so an actor that starts
//!   late (or restarts) receives the newest weights as soon as it connects.

mod actor_side;
mod cleanup;
mod config;
mod error;
mod join_key;
mod learner_side;
mod logging;
pub mod membership;
mod services;
mod wakeup;
mod weights_side;

pub use actor_side::ActorPorts;
pub use cleanup::remove_dead_nodes;
pub use config::TransportConfig;
pub use error::{TransportError, SLOTS_TAKEN_EXIT};
pub use join_key::{load_or_create_join_key, read_join_key, JoinKeyFileError, JOIN_KEY_FILE};
pub use learner_side::{LearnerPorts, ReceivedMessage};
pub use logging::init_logging;
pub use wakeup::Wakeup;
pub use weights_side::{WeightsSubscriber, WeightsTap};

/// The file in a learner's run directory where the gateway on the learner's
/// host keeps its counts per actor host (JSON, an object keyed by host
/// name); the learner's `/api/status` shows it as `remote_hosts`.
pub const REMOTE_HOSTS_FILE: &str = "remote-hosts.json";

/// What happened to a message handed to a publisher.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Delivery {
    /// Delivered to this many subscribers.
    Delivered(usize),
    /// Not delivered: no subscriber connected, its buffer was full, or the
    /// publisher's pool had no free sample. Counted by the caller.
    Dropped,
}

/// The iceoryx2 service flavour used between processes.
pub(crate) type Ipc = iceoryx2::prelude::ipc::Service;

/// Opens a node with our settings: no iceoryx2 signal handlers (binaries
/// handle SIGINT/SIGTERM themselves) and a built-in config, so no config file
/// is searched for.
pub(crate) fn open_node(name: &str) -> Result<iceoryx2::prelude::Node<Ipc>, TransportError> {
    use iceoryx2::prelude::*;
    let node_name = NodeName::new(name).map_err(|e| TransportError::new("node name", name, e))?;
    NodeBuilder::new()
        .name(&node_name)
        .config(&Config::default())
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<Ipc>()
        .map_err(|e| TransportError::new("create node", name, e))
}

/// Builds a service name, checking it is a valid iceoryx2 name.
pub(crate) fn service_name(
    prefix: &str,
    suffix: &str,
) -> Result<iceoryx2::prelude::ServiceName, TransportError> {
    let full = proto::service::name(prefix, suffix);
    full.as_str()
        .try_into()
        .map_err(|e| TransportError::new("service name", &full, e))
}

/// Loans a `len`-byte sample and zero-fills it with one `memset`.
///
/// `loan_slice` would initialise element by element in generic code compiled
/// at this crate's optimisation level, which made 16 MiB loans cost more than
/// the transfer itself.
pub(crate) fn loan_zeroed(
    publisher: &iceoryx2::port::publisher::Publisher<Ipc, [u8], ()>,
    len: usize,
) -> Option<iceoryx2::sample_mut::SampleMut<Ipc, [u8], ()>> {
    let mut sample = publisher.loan_slice_uninit(len).ok()?;
    let buf = sample.payload_mut();
    // SAFETY: `buf` is a valid, exclusively borrowed region of `buf.len()` bytes;
    // writing zeros initialises every element, which is what `assume_init` requires.
    unsafe {
        std::ptr::write_bytes(buf.as_mut_ptr(), 0, buf.len());
        Some(sample.assume_init())
    }
}

/// Loans a sample of `bytes.len()` bytes filled with `bytes` in one pass
/// (no zero-fill first): what forwarding a whole message costs.
pub(crate) fn loan_copy(
    publisher: &iceoryx2::port::publisher::Publisher<Ipc, [u8], ()>,
    bytes: &[u8],
) -> Option<iceoryx2::sample_mut::SampleMut<Ipc, [u8], ()>> {
    let mut sample = publisher.loan_slice_uninit(bytes.len()).ok()?;
    let buf = sample.payload_mut();
    // SAFETY: `buf` is an exclusively borrowed region of `bytes.len()`
    // elements that cannot overlap `bytes` (a fresh loan); copying all of
    // them initialises every element, which is what `assume_init` requires.
    unsafe {
        std::ptr::copy_nonoverlapping(bytes.as_ptr(), buf.as_mut_ptr().cast::<u8>(), bytes.len());
        Some(sample.assume_init())
    }
}
