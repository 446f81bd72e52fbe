//! The learner's ports: three subscribers, the weights publisher, two events.

use std::time::Duration;

use iceoryx2::port::listener::{Listener, ListenerWaitError};
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;
use iceoryx2::sample::Sample;
use iceoryx2::service::port_factory::publish_subscribe;
use proto::{JoinKey, MessageHeader, MessageKind, WeightsBlob, LEARNER_ID};

use crate::config::TransportConfig;
use crate::services::{open_event, open_pubsub, wakeup_service, weights_ready_service};
use crate::{open_node, Delivery, Ipc, TransportError};

/// A message still in shared memory; dropping it returns the buffer.
pub struct ReceivedMessage(Sample<Ipc, [u8], ()>);

impl ReceivedMessage {
    pub(crate) fn new(sample: Sample<Ipc, [u8], ()>) -> Self {
        Self(sample)
    }
}

impl ReceivedMessage {
    /// The message bytes (header and payload), unvalidated.
    pub fn bytes(&self) -> &[u8] {
        self.0.payload()
    }

    /// The iceoryx2 id of the publisher the message came through: known to
    /// the receiving side, not taken from the message, so a sender cannot
    /// choose it.
    pub fn origin(&self) -> u128 {
        self.0.origin().value()
    }
}

/// A publish-subscribe service of byte messages.
type ByteService = publish_subscribe::PortFactory<Ipc, [u8], ()>;

/// Everything the learner process reads from and writes to.
pub struct LearnerPorts {
    node: Node<Ipc>,
    /// The actor→learner services, kept to count their publishers.
    upstream: [(MessageKind, ByteService); 3],
    rollouts: Subscriber<Ipc, [u8], ()>,
    frames: Subscriber<Ipc, [u8], ()>,
    stats: Subscriber<Ipc, [u8], ()>,
    weights: Publisher<Ipc, [u8], ()>,
    wakeup: Listener<Ipc>,
    weights_ready: Notifier<Ipc>,
    weights_sequence: u64,
    max_weights_bytes: usize,
    /// The run's key, which signs every weights message.
    run_key: JoinKey,
}

impl LearnerPorts {
    /// Cleans up after crashed processes, then opens (or creates) every service
    /// of the run described by `config`. Weights go out signed with
    /// `run_key` (the run's join key), which actors check.
    pub fn open(config: &TransportConfig, run_key: JoinKey) -> Result<Self, TransportError> {
        crate::remove_dead_nodes()?;
        let node = open_node("learner")?;
        let upstream = [
            MessageKind::Rollout,
            MessageKind::Frames,
            MessageKind::Stats,
        ]
        .map(|kind| open_pubsub(&node, config, kind).map(|service| (kind, service)));
        let [rollouts, frames, stats] = upstream;
        let upstream = [rollouts?, frames?, stats?];
        let subscriber = |i: usize| -> Result<Subscriber<Ipc, [u8], ()>, TransportError> {
            let (kind, service) = &upstream[i];
            service
                .subscriber_builder()
                .buffer_size(config.learner_buffer)
                .create()
                .map_err(|e| {
                    TransportError::new("create subscriber", proto::service::for_kind(*kind), e)
                })
        };
        let rollouts = subscriber(0)?;
        let frames = subscriber(1)?;
        let stats = subscriber(2)?;
        let weights_service = open_pubsub(&node, config, MessageKind::Weights)?;
        let pool = config.max_actors as usize + 4;
        let weights = weights_service
            .publisher_builder()
            .initial_max_slice_len(config.max_weights_bytes)
            .allocation_strategy(AllocationStrategy::Static)
            .max_loaned_samples(1)
            .override_sample_preallocation(move |worst| worst.min(pool))
            .create()
            .map_err(|e| TransportError::new("create publisher", proto::service::WEIGHTS, e))?;
        let wakeup = open_event(&node, config, &wakeup_service(config)?)?
            .listener_builder()
            .create()
            .map_err(|e| {
                TransportError::new("create listener", proto::service::LEARNER_WAKEUP, e)
            })?;
        let weights_ready = open_event(&node, config, &weights_ready_service(config)?)?
            .notifier_builder()
            .create()
            .map_err(|e| {
                TransportError::new("create notifier", proto::service::WEIGHTS_READY, e)
            })?;
        Ok(Self {
            node,
            upstream,
            rollouts,
            frames,
            stats,
            weights,
            wakeup,
            weights_ready,
            weights_sequence: 0,
            max_weights_bytes: config.max_weights_bytes,
            run_key,
        })
    }

    /// Blocks until an actor signals new data or `timeout` passes (or a
    /// signal arrives, which the caller's handler records). Returns true if
    /// woken by an actor.
    pub fn wait(&self, timeout: Duration) -> Result<bool, TransportError> {
        let mut woken = false;
        match self.wakeup.timed_wait(|_| woken = true, timeout) {
            Ok(_) | Err(ListenerWaitError::InterruptSignal) => Ok(woken),
            Err(e) => Err(TransportError::new(
                "wait on",
                proto::service::LEARNER_WAKEUP,
                e,
            )),
        }
    }

    /// Takes the oldest pending message of `kind` (not `Weights`), if any.
    pub fn receive(&self, kind: MessageKind) -> Result<Option<ReceivedMessage>, TransportError> {
        let subscriber = match kind {
            MessageKind::Rollout => &self.rollouts,
            MessageKind::Frames => &self.frames,
            MessageKind::Stats | MessageKind::Join => &self.stats,
            MessageKind::Weights => return Ok(None),
        };
        subscriber
            .receive()
            .map(|s| s.map(ReceivedMessage))
            .map_err(|e| TransportError::new("receive from", proto::service::for_kind(kind), e))
    }

    /// Publishes a safetensors weights blob with its versions, signed with
    /// the run's key, and wakes actors that wait for weights.
    pub fn publish_weights(
        &mut self,
        policy_version: u64,
        unet_version: u64,
        safetensors: &[u8],
    ) -> Result<Delivery, TransportError> {
        let header = MessageHeader {
            actor_id: LEARNER_ID,
            policy_version,
            unet_version,
            sequence: self.weights_sequence + 1,
            ..MessageHeader::default()
        };
        let blob = WeightsBlob::signed(&self.run_key, &header, safetensors);
        let len = proto::encoded_len(&blob);
        if len > self.max_weights_bytes {
            return Err(TransportError::new(
                "publish",
                proto::service::WEIGHTS,
                format!("weights message of {len} bytes exceeds max_weights_bytes {}; raise it in the transport config", self.max_weights_bytes),
            ));
        }
        let Some(mut sample) = crate::loan_zeroed(&self.weights, len) else {
            return Ok(Delivery::Dropped);
        };
        self.weights_sequence = header.sequence;
        proto::encode_into(&blob, header, sample.payload_mut());
        self.send_weights(sample)
    }

    /// Sends a weights sample and wakes actors that wait for weights.
    fn send_weights(
        &self,
        sample: iceoryx2::sample_mut::SampleMut<Ipc, [u8], ()>,
    ) -> Result<Delivery, TransportError> {
        let delivered = sample
            .send()
            .map_err(|e| TransportError::new("send on", proto::service::WEIGHTS, e))?;
        // Waking is best effort: actors also poll the weights subscriber.
        let _ = self.weights_ready.notify();
        Ok(Delivery::Delivered(delivered))
    }

    /// Publishes a weights message another learner signed, as it is (the
    /// gateway on an actor's host hands the learner's weights to its local
    /// actors so), and wakes actors that wait for weights. Actors check the
    /// signature themselves.
    pub fn forward_weights(&mut self, bytes: &[u8]) -> Result<Delivery, TransportError> {
        if bytes.is_empty() || bytes.len() > self.max_weights_bytes {
            return Ok(Delivery::Dropped);
        }
        let Some(sample) = crate::loan_copy(&self.weights, bytes) else {
            return Ok(Delivery::Dropped);
        };
        self.send_weights(sample)
    }

    /// How many publishers each actor→learner service has now (actors and
    /// anything else holding a slot): the slots left are
    /// `max_actors + spare_ports` minus these.
    pub fn publishers(&self) -> Vec<(&'static str, usize)> {
        self.upstream
            .iter()
            .map(|(kind, service)| {
                (
                    proto::service::for_kind(*kind),
                    service.dynamic_config().number_of_publishers(),
                )
            })
            .collect()
    }

    /// Periodic upkeep: hands the newest weights to subscribers that joined
    /// since the last publish, and removes resources of crashed actors.
    pub fn maintain(&self) {
        let _ = self.weights.update_connections();
        let _ = self.node.try_cleanup_dead_nodes();
    }
}
