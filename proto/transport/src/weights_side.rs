//! A weights subscriber with its wake-up listener: what an actor reads the
//! learner's weights through, and what a gateway forwards them from.

use std::time::{Duration, Instant};

use iceoryx2::port::listener::{Listener, ListenerWaitError};
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use proto::{JoinKey, Limits, MessageHeader, MessageKind, ProtoError, WeightsView};

use crate::config::TransportConfig;
use crate::learner_side::ReceivedMessage;
use crate::services::{open_event, open_pubsub, weights_ready_service};
use crate::{Ipc, TransportError};

/// The receiving end of the weights service.
pub struct WeightsSubscriber {
    /// What a weights message may be (its size, its sender).
    limits: Limits,
    subscriber: Subscriber<Ipc, [u8], ()>,
    ready: Listener<Ipc>,
}

impl WeightsSubscriber {
    /// Subscribes `node` to the weights of the run described by `config`;
    /// the service's history hands over the newest weights at once.
    pub(crate) fn open(node: &Node<Ipc>, config: &TransportConfig) -> Result<Self, TransportError> {
        let subscriber = open_pubsub(node, config, MessageKind::Weights)?
            .subscriber_builder()
            .buffer_size(1)
            .create()
            .map_err(|e| TransportError::new("create subscriber", proto::service::WEIGHTS, e))?;
        let ready = open_event(node, config, &weights_ready_service(config)?)?
            .listener_builder()
            .create()
            .map_err(|e| {
                TransportError::new("create listener", proto::service::WEIGHTS_READY, e)
            })?;
        Ok(Self {
            limits: Limits {
                max_actors: config.max_actors,
                max_payload_len: config.max_weights_bytes as u64,
            },
            subscriber,
            ready,
        })
    }

    /// The newest weights message that arrived since the last call, if any
    /// (older ones are skipped).
    pub fn take_latest(&self) -> Result<Option<ReceivedMessage>, TransportError> {
        let mut latest = None;
        loop {
            match self.subscriber.receive() {
                Ok(Some(sample)) => latest = Some(ReceivedMessage::new(sample)),
                Ok(None) => return Ok(latest),
                Err(e) => {
                    return Err(TransportError::new(
                        "receive from",
                        proto::service::WEIGHTS,
                        e,
                    ))
                }
            }
        }
    }

    /// Validates a weights message's structure and size, and that the run's
    /// learner signed it with `run_key`. Anything may publish on the weights
    /// service; only weights that pass this may be loaded or forwarded.
    pub fn check<'m>(
        &self,
        message: &'m [u8],
        run_key: &JoinKey,
    ) -> Result<(MessageHeader, WeightsView<'m>), ProtoError> {
        proto::decode_weights(message, &self.limits, run_key)
    }

    /// Waits up to `timeout` for weights; `None` if none came.
    pub fn wait(&self, timeout: Duration) -> Result<Option<ReceivedMessage>, TransportError> {
        let deadline = Instant::now() + timeout;
        loop {
            if let Some(weights) = self.take_latest()? {
                return Ok(Some(weights));
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Ok(None);
            }
            // Wake on the learner's notification, or re-poll at least every 50 ms
            // (history delivery to a late joiner sends no event). A signal
            // only cuts a wait short: the caller's handler records it.
            match self
                .ready
                .timed_wait(|_| {}, left.min(Duration::from_millis(50)))
            {
                Ok(_) | Err(ListenerWaitError::InterruptSignal) => {}
                Err(e) => {
                    return Err(TransportError::new(
                        "wait on",
                        proto::service::WEIGHTS_READY,
                        e,
                    ))
                }
            }
        }
    }
}

/// A weights subscriber on a node of its own: what a gateway on the
/// learner's host reads the weights it sends to other hosts from.
pub struct WeightsTap {
    weights: WeightsSubscriber,
    _node: Node<Ipc>,
}

impl WeightsTap {
    /// Opens a node named `name` subscribed to the weights of `config`'s run.
    pub fn open(config: &TransportConfig, name: &str) -> Result<Self, TransportError> {
        let node = crate::open_node(name)?;
        let weights = WeightsSubscriber::open(&node, config)?;
        Ok(Self {
            weights,
            _node: node,
        })
    }
}

impl std::ops::Deref for WeightsTap {
    type Target = WeightsSubscriber;

    fn deref(&self) -> &WeightsSubscriber {
        &self.weights
    }
}
