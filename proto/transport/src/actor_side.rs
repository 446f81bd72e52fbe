//! An actor's ports: three publishers, the weights subscriber, two events.

use std::time::{Duration, Instant};

use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::{Publisher, PublisherCreateError};
use iceoryx2::prelude::*;
use proto::{Join, JoinKey, MessageHeader, MessageKind, Payload, ProtoError, WeightsView};

use crate::config::TransportConfig;
use crate::learner_side::ReceivedMessage;
use crate::services::{open_pubsub, wakeup_notifier};
use crate::weights_side::WeightsSubscriber;
use crate::{open_node, Delivery, Ipc, TransportError};

/// How often an actor repeats a join that reached the learner: a learner
/// that restarted after the actor learns who it is within this time.
const JOIN_REFRESH: Duration = Duration::from_secs(2);
/// How soon an actor retries a join that reached no learner (none was
/// connected, or its queue was full).
const JOIN_RETRY: Duration = Duration::from_millis(50);

struct Upstream {
    kind: MessageKind,
    publisher: Publisher<Ipc, [u8], ()>,
    max_bytes: usize,
    sequence: u64,
}

/// Everything one actor process reads from and writes to.
pub struct ActorPorts {
    actor_id: u32,
    upstream: [Upstream; 3],
    join_key: JoinKey,
    /// When the next join is due (see [`JOIN_REFRESH`], [`JOIN_RETRY`]).
    join_due: Instant,
    joins_sent: u64,
    weights: WeightsSubscriber,
    wakeup: Notifier<Ipc>,
    _node: Node<Ipc>,
}

impl ActorPorts {
    /// Opens the actor's side of the run described by `config` and joins
    /// the run as `actor_id` with the run's `join_key` (see [`proto::Join`]);
    /// the join is repeated while publishing, so a learner that starts later
    /// still learns who this actor is.
    pub fn open(
        config: &TransportConfig,
        actor_id: u32,
        join_key: JoinKey,
    ) -> Result<Self, TransportError> {
        if actor_id >= config.max_actors {
            return Err(TransportError::new(
                "open actor ports",
                &format!("actor {actor_id}"),
                format!("actor id must be below max_actors = {}", config.max_actors),
            ));
        }
        // A crashed process's slots are freed first (the learner also does
        // so periodically), so that this actor's own earlier life, killed,
        // does not hold the slots it needs.
        crate::remove_dead_nodes()?;
        let node = open_node(&format!("actor-{actor_id}"))?;
        // Enough samples for a full learner buffer plus one in flight: when the
        // pool is exhausted the next message is dropped, so memory stays fixed.
        let pool = config.learner_buffer + 2;
        let upstream = |kind: MessageKind| -> Result<Upstream, TransportError> {
            let max_bytes = config.max_bytes(kind);
            let publisher = open_pubsub(&node, config, kind)?
                .publisher_builder()
                .initial_max_slice_len(max_bytes)
                .allocation_strategy(AllocationStrategy::Static)
                .backpressure_strategy(BackpressureStrategy::DiscardData)
                .max_loaned_samples(1)
                .override_sample_preallocation(move |worst| worst.min(pool))
                .create()
                .map_err(|e| {
                    let service = proto::service::for_kind(kind);
                    match e {
                        PublisherCreateError::ExceedsMaxSupportedPublishers => {
                            let mut error = TransportError::explained(
                                "create publisher",
                                service,
                                format!(
                                    "all {} publisher slots of the service are taken ([transport] \
                                 max_actors {} + spare_ports {}): other processes hold them. \
                                 `learner clean` frees the slots of crashed processes; raise \
                                 max_actors or spare_ports in the run's config for more",
                                    config.max_actors as usize + config.spare_ports as usize,
                                    config.max_actors,
                                    config.spare_ports
                                ),
                            );
                            error.slots_taken = true;
                            error
                        }
                        other => TransportError::new("create publisher", service, other),
                    }
                })?;
            Ok(Upstream {
                kind,
                publisher,
                max_bytes,
                sequence: 0,
            })
        };
        let upstream = [
            upstream(MessageKind::Rollout)?,
            upstream(MessageKind::Frames)?,
            upstream(MessageKind::Stats)?,
        ];
        let weights = WeightsSubscriber::open(&node, config)?;
        let wakeup = wakeup_notifier(&node, config)?;
        let mut ports = Self {
            actor_id,
            upstream,
            join_key,
            join_due: Instant::now(),
            joins_sent: 0,
            weights,
            wakeup,
            _node: node,
        };
        ports.join()?;
        Ok(ports)
    }

    /// The iceoryx2 ids of this actor's rollouts, frames and stats
    /// publishers: the learner accepts this actor's messages only from them.
    pub fn publisher_ids(&self) -> [u128; 3] {
        self.upstream.each_ref().map(|u| u.publisher.id().value())
    }

    /// Sends this actor's join (see [`proto::Join`]) on the stats service.
    fn join(&mut self) -> Result<(), TransportError> {
        let join = Join::new(&self.join_key, self.actor_id, self.publisher_ids());
        self.joins_sent += 1;
        let header = MessageHeader {
            actor_id: self.actor_id,
            sequence: self.joins_sent,
            ..MessageHeader::default()
        };
        self.join_due = Instant::now() + JOIN_RETRY;
        let up = self.upstream_mut(MessageKind::Join)?;
        let Some(mut sample) = crate::loan_zeroed(&up.publisher, proto::encoded_len(&join)) else {
            return Ok(());
        };
        proto::encode_into(&join, header, sample.payload_mut());
        if let Delivery::Delivered(_) = self.send(MessageKind::Join, sample)? {
            self.join_due = Instant::now() + JOIN_REFRESH;
        }
        Ok(())
    }

    /// Encodes `payload` straight into shared memory and sends it to the
    /// learner. Sequence numbers are per kind and count every attempt, so the
    /// learner sees dropped messages as gaps.
    pub fn publish<P: Payload>(
        &mut self,
        payload: &P,
        policy_version: u64,
        unet_version: u64,
    ) -> Result<Delivery, TransportError> {
        if Instant::now() >= self.join_due {
            self.join()?;
        }
        let actor_id = self.actor_id;
        let up = self.upstream_mut(P::KIND)?;
        let len = proto::encoded_len(payload);
        if len > up.max_bytes {
            return Err(TransportError::new(
                "publish",
                proto::service::for_kind(P::KIND),
                format!("message of {len} bytes exceeds the configured maximum of {} bytes; raise max_{}_bytes in the transport config", up.max_bytes, P::KIND.as_str()),
            ));
        }
        up.sequence += 1;
        let header = MessageHeader {
            actor_id,
            policy_version,
            unet_version,
            sequence: up.sequence,
            ..MessageHeader::default()
        };
        let Some(mut sample) = crate::loan_zeroed(&up.publisher, len) else {
            return Ok(Delivery::Dropped);
        };
        proto::encode_into(payload, header, sample.payload_mut());
        self.send(P::KIND, sample)
    }

    /// Sends another process's message on as it is (header included: its
    /// actor id and sequence number), joining first when a join is due: what
    /// a gateway does with the messages of an actor on another host, which
    /// joined through it as this port's actor id. The caller checks that
    /// the header names this id; the learner refuses messages that do not.
    pub fn forward(&mut self, kind: MessageKind, bytes: &[u8]) -> Result<Delivery, TransportError> {
        if Instant::now() >= self.join_due {
            self.join()?;
        }
        self.publish_raw(kind, bytes)
    }

    /// Sends bytes as they are, unvalidated: for tools and tests that exercise
    /// the learner's validation.
    pub fn publish_raw(
        &mut self,
        kind: MessageKind,
        bytes: &[u8],
    ) -> Result<Delivery, TransportError> {
        let up = self.upstream_mut(kind)?;
        if bytes.len() > up.max_bytes || bytes.is_empty() {
            return Ok(Delivery::Dropped);
        }
        let Some(sample) = crate::loan_copy(&up.publisher, bytes) else {
            return Ok(Delivery::Dropped);
        };
        self.send(kind, sample)
    }

    /// The publisher of the service that carries `kind`.
    fn upstream_mut(&mut self, kind: MessageKind) -> Result<&mut Upstream, TransportError> {
        let service = proto::service::for_kind(kind);
        self.upstream
            .iter_mut()
            .find(|u| proto::service::for_kind(u.kind) == service)
            .ok_or_else(|| {
                TransportError::new(
                    "publish",
                    proto::service::for_kind(kind),
                    "actors do not publish this kind",
                )
            })
    }

    fn send(
        &self,
        kind: MessageKind,
        sample: iceoryx2::sample_mut::SampleMut<Ipc, [u8], ()>,
    ) -> Result<Delivery, TransportError> {
        let delivered = sample
            .send()
            .map_err(|e| TransportError::new("send on", proto::service::for_kind(kind), e))?;
        if delivered == 0 {
            return Ok(Delivery::Dropped);
        }
        let _ = self.wakeup.notify();
        Ok(Delivery::Delivered(delivered))
    }

    /// The newest weights message that arrived since the last call, if any
    /// (older ones are skipped).
    pub fn take_latest_weights(&self) -> Result<Option<ReceivedMessage>, TransportError> {
        self.weights.take_latest()
    }

    /// Validates a weights message that [`Self::take_latest_weights`] or
    /// [`Self::wait_for_weights`] returned: its structure and size, and
    /// that the run's learner signed it with the run's key. Anything may
    /// publish on the weights service; only weights that pass this may be
    /// loaded.
    pub fn check_weights<'m>(
        &self,
        message: &'m ReceivedMessage,
    ) -> Result<(MessageHeader, WeightsView<'m>), ProtoError> {
        self.weights.check(message.bytes(), &self.join_key)
    }

    /// Waits up to `timeout` for weights; `None` if none came.
    pub fn wait_for_weights(
        &self,
        timeout: Duration,
    ) -> Result<Option<ReceivedMessage>, TransportError> {
        self.weights.wait(timeout)
    }
}
