//! One function per service shape, with every limit spelled out. Both sides
//! call these, so the settings always agree.

use iceoryx2::port::notifier::Notifier;
use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::{event, publish_subscribe};
use proto::MessageKind;

use crate::config::TransportConfig;
use crate::{service_name, Ipc, TransportError};

/// Opens or creates the publish-subscribe service that carries `kind`.
pub(crate) fn open_pubsub(
    node: &Node<Ipc>,
    config: &TransportConfig,
    kind: MessageKind,
) -> Result<publish_subscribe::PortFactory<Ipc, [u8], ()>, TransportError> {
    let suffix = proto::service::for_kind(kind);
    let name = service_name(&config.service_prefix, suffix)?;
    let spare = config.spare_ports as usize;
    let actors = config.max_actors as usize;
    let builder = node
        .service_builder(&name)
        .publish_subscribe::<[u8]>()
        .max_nodes(config.max_nodes());
    let builder = match kind {
        // Many actors publish, one learner (plus spares) subscribes; no history,
        // no overflow: a full learner buffer discards the newest message, and
        // the publisher counts it.
        MessageKind::Rollout | MessageKind::Frames | MessageKind::Stats | MessageKind::Join => {
            builder
                .max_publishers(actors + spare)
                .max_subscribers(config.upstream_subscribers())
                .subscriber_max_buffer_size(config.learner_buffer)
                .subscriber_max_borrowed_samples(1)
                .history_size(0)
                .enable_safe_overflow(false)
        }
        // One learner publishes to every actor; newest weights win; history 1
        // for late joiners.
        MessageKind::Weights => builder
            .max_publishers(1 + spare)
            .max_subscribers(actors + spare)
            .subscriber_max_buffer_size(1)
            // An actor holds its newest sample while it looks for a newer one.
            .subscriber_max_borrowed_samples(2)
            .history_size(1)
            .enable_safe_overflow(true),
    };
    builder
        .open_or_create()
        .map_err(|e| TransportError::new("open service", suffix, e))
}

/// Opens or creates an event service (many notifiers and listeners).
pub(crate) fn open_event(
    node: &Node<Ipc>,
    config: &TransportConfig,
    name: &ServiceName,
) -> Result<event::PortFactory<Ipc>, TransportError> {
    let ports = config.max_actors as usize + 1 + config.spare_ports as usize;
    node.service_builder(name)
        .event()
        .max_nodes(config.max_nodes())
        .max_notifiers(ports)
        .max_listeners(ports)
        .open_or_create()
        .map_err(|e| TransportError::new("open event service", name.as_str(), e))
}

/// The event an actor notifies after publishing.
pub(crate) fn wakeup_service(config: &TransportConfig) -> Result<ServiceName, TransportError> {
    service_name(&config.service_prefix, proto::service::LEARNER_WAKEUP)
}

/// A notifier on the wakeup event of `config`'s run: what an actor rings
/// after publishing (and a thread that stands in for one, [`crate::Wakeup`]).
pub(crate) fn wakeup_notifier(
    node: &Node<Ipc>,
    config: &TransportConfig,
) -> Result<Notifier<Ipc>, TransportError> {
    open_event(node, config, &wakeup_service(config)?)?
        .notifier_builder()
        .create()
        .map_err(|e| TransportError::new("create notifier", proto::service::LEARNER_WAKEUP, e))
}

/// The event the learner notifies after publishing weights.
pub(crate) fn weights_ready_service(
    config: &TransportConfig,
) -> Result<ServiceName, TransportError> {
    service_name(&config.service_prefix, proto::service::WEIGHTS_READY)
}
