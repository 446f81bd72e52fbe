//! A way for a thread that is not an actor to cut a learner's
//! [`LearnerPorts::wait`](crate::LearnerPorts::wait) short.
//!
//! Why: that wait is an iceoryx2 listener whose timeout is a socket receive
//! timeout, which the kernel counts in scheduler ticks: asked for 2 ms, it
//! returns after about 8 on a kernel with 250 ticks a second. A loop that
//! also looks at something iceoryx2 does not signal (a gateway on an actor
//! host, which waits for its actors' messages and for weights arriving over
//! Zenoh) would see the latter up to 8 ms late unless what delivers them
//! rings the same event (docs/decisions/0009-zenoh-gateway.md).

use iceoryx2::port::notifier::Notifier;
use iceoryx2::prelude::*;

use crate::config::TransportConfig;
use crate::services::wakeup_notifier;
use crate::{open_node, Ipc, TransportError};

/// A notifier on the wakeup event of the run described by a config, on a
/// node of its own (so it can live on any thread).
pub struct Wakeup {
    notifier: Notifier<Ipc>,
    _node: Node<Ipc>,
}

impl Wakeup {
    /// Opens a node named `name` with a notifier on `config`'s wakeup event
    /// (it takes one of the event's spare notifier slots).
    pub fn open(config: &TransportConfig, name: &str) -> Result<Self, TransportError> {
        let node = open_node(name)?;
        let notifier = wakeup_notifier(&node, config)?;
        Ok(Self {
            notifier,
            _node: node,
        })
    }

    /// Wakes whoever waits on the event now.
    pub fn notify(&self) -> Result<(), TransportError> {
        self.notifier
            .notify()
            .map(|_| ())
            .map_err(|e| TransportError::new("notify", proto::service::LEARNER_WAKEUP, e))
    }
}
