//! On the learner's host: which remote host speaks for which actor id, and
//! the local ports through which each remote actor's messages enter the
//! learner's shared memory.
//!
//! A remote actor joins as it would locally (its [`proto::Join`] proves it
//! holds the run's key); the gateway checks the proof, takes the id for the
//! host the join came from, and joins the learner itself for that id from
//! ports of its own. From then on only that host's messages for that id go
//! through: a host speaks only for the actors that joined through it. An id
//! whose host has been silent for [`RemoteActors::release_after`] may be
//! taken by another host (its actors moved).

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::time::{Duration, Instant};

use proto::{JoinKey, Limits, Message, MessageKind};
use transport::{ActorPorts, Delivery, TransportConfig, TransportError};

/// Where a remote actor's messages are published on this host.
pub trait Forward {
    /// Publishes a validated message as it is.
    fn forward(&mut self, kind: MessageKind, bytes: &[u8]) -> Result<Delivery, TransportError>;
}

impl Forward for ActorPorts {
    fn forward(&mut self, kind: MessageKind, bytes: &[u8]) -> Result<Delivery, TransportError> {
        ActorPorts::forward(self, kind, bytes)
    }
}

/// What happened to one message from a remote host.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Outcome {
    /// Published into the learner's services.
    Forwarded,
    /// Not delivered: the learner's buffer was full or no learner listens
    /// (the learner counts it as a sequence gap).
    Dropped,
    /// A join: the id now speaks through this gateway for the host.
    Joined(u32),
    /// Refused and counted under this reason.
    Refused(&'static str),
}

/// Counts for one remote host, for logs and the status file.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct HostCounters {
    /// Messages received from the host (valid or not).
    pub messages: u64,
    /// Their bytes.
    pub bytes: u64,
    /// Messages published into the learner's services.
    pub forwarded: u64,
    /// Messages the learner's services did not take (buffer full).
    pub dropped: u64,
    /// Messages refused, by reason.
    pub refused: BTreeMap<&'static str, u64>,
    /// Actor ids the host speaks for now.
    pub actors: BTreeSet<u32>,
    /// Seconds since the host's last message, when the counts were taken.
    pub silent_s: Option<f64>,
    #[serde(skip)]
    last_seen: Option<Instant>,
}

struct RemoteActor<F> {
    host: String,
    ports: F,
}

/// The learner host's record of remote actors.
pub struct RemoteActors<F> {
    key: JoinKey,
    transport: TransportConfig,
    open: Box<dyn FnMut(u32) -> Result<F, TransportError>>,
    actors: HashMap<u32, RemoteActor<F>>,
    hosts: BTreeMap<String, HostCounters>,
    release_after: Duration,
}

impl<F: Forward> RemoteActors<F> {
    /// No remote actor yet. Joins must prove `key`; `open` makes the local
    /// ports for an id (which join the learner themselves).
    pub fn new(
        key: JoinKey,
        transport: TransportConfig,
        open: impl FnMut(u32) -> Result<F, TransportError> + 'static,
    ) -> Self {
        Self {
            key,
            transport,
            open: Box::new(open),
            actors: HashMap::new(),
            hosts: BTreeMap::new(),
            release_after: Duration::from_secs(30),
        }
    }

    /// How long a host must be silent before another host may take its ids.
    pub fn release_after(mut self, after: Duration) -> Self {
        self.release_after = after;
        self
    }

    /// Handles `bytes` that `host` published under the key of `kind`.
    pub fn handle(&mut self, host: &str, kind: MessageKind, bytes: &[u8]) -> Outcome {
        let now = Instant::now();
        let counters = self.hosts.entry(host.to_string()).or_default();
        counters.messages += 1;
        counters.bytes += bytes.len() as u64;
        counters.last_seen = Some(now);
        let outcome = self.route(host, kind, bytes, now);
        let counters = self.hosts.entry(host.to_string()).or_default();
        match outcome {
            Outcome::Forwarded => counters.forwarded += 1,
            Outcome::Dropped => counters.dropped += 1,
            Outcome::Joined(id) => {
                counters.actors.insert(id);
            }
            Outcome::Refused(reason) => *counters.refused.entry(reason).or_default() += 1,
        }
        outcome
    }

    fn route(&mut self, host: &str, kind: MessageKind, bytes: &[u8], now: Instant) -> Outcome {
        let limits = Limits {
            max_actors: self.transport.max_actors,
            max_payload_len: self.transport.max_bytes(kind) as u64,
        };
        // The header routes it; the learner checks the rest (checksum,
        // layout) on arrival, so it is not read here once more.
        let (header, wire_kind) = match proto::decode_header(bytes, &limits) {
            Ok(checked) => checked,
            Err(error) => return Outcome::Refused(error.reason()),
        };
        // Joins travel on the stats service, as inside a host.
        let carried = match wire_kind {
            MessageKind::Join => MessageKind::Stats,
            other => other,
        };
        if carried != kind {
            return Outcome::Refused("kind_under_another_key");
        }
        let id = header.actor_id;
        if wire_kind == MessageKind::Join {
            let join = match proto::decode(bytes, &limits) {
                Ok((_, Message::Join(join))) => join,
                Ok(_) => return Outcome::Refused("kind_under_another_key"),
                Err(error) => return Outcome::Refused(error.reason()),
            };
            if !join.verify(&self.key, id) {
                return Outcome::Refused("bad_join_proof");
            }
            return self.join(host, id, now);
        }
        match self.actors.get_mut(&id) {
            Some(actor) if actor.host == host => match actor.ports.forward(kind, bytes) {
                Ok(Delivery::Delivered(_)) => Outcome::Forwarded,
                Ok(Delivery::Dropped) => Outcome::Dropped,
                Err(error) => {
                    tracing::warn!(
                        actor = id,
                        host,
                        "forwarding to the learner failed: {error}"
                    );
                    Outcome::Dropped
                }
            },
            Some(_) => Outcome::Refused("id_of_another_host"),
            None => Outcome::Refused("not_joined"),
        }
    }

    fn join(&mut self, host: &str, id: u32, now: Instant) -> Outcome {
        if let Some(actor) = self.actors.get(&id) {
            if actor.host == host {
                return Outcome::Joined(id);
            }
            let owner_silent = self.hosts.get(&actor.host).is_none_or(|c| {
                c.last_seen
                    .is_none_or(|seen| now.duration_since(seen) >= self.release_after)
            });
            if !owner_silent {
                return Outcome::Refused("id_of_another_host");
            }
            let old = actor.host.clone();
            tracing::info!(
                actor = id,
                from = old,
                to = host,
                "actor id moves to another host (its host was silent)"
            );
            if let Some(counters) = self.hosts.get_mut(&old) {
                counters.actors.remove(&id);
            }
            self.actors.remove(&id);
        }
        match (self.open)(id) {
            Ok(ports) => {
                tracing::info!(actor = id, host, "remote actor joined");
                self.actors.insert(
                    id,
                    RemoteActor {
                        host: host.to_string(),
                        ports,
                    },
                );
                Outcome::Joined(id)
            }
            Err(error) => {
                tracing::warn!(
                    actor = id,
                    host,
                    "cannot open the learner's ports for a remote actor: {error}"
                );
                Outcome::Refused("no_local_ports")
            }
        }
    }

    /// Counts per host, as of now.
    pub fn hosts(&self) -> BTreeMap<String, HostCounters> {
        let now = Instant::now();
        self.hosts
            .iter()
            .map(|(host, counters)| {
                let mut counters = counters.clone();
                counters.silent_s = counters
                    .last_seen
                    .map(|seen| now.duration_since(seen).as_secs_f64());
                (host.clone(), counters)
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use std::cell::RefCell;
    use std::rc::Rc;

    use proto::{EpisodeStats, Join, MessageHeader, StatField};

    use super::*;

    /// What the ports of each id were asked to publish: (id, kind, bytes).
    type Log = Rc<RefCell<Vec<(u32, MessageKind, usize)>>>;

    /// Ports that record what they were asked to publish.
    struct Recorded {
        id: u32,
        log: Log,
    }

    impl Forward for Recorded {
        fn forward(&mut self, kind: MessageKind, bytes: &[u8]) -> Result<Delivery, TransportError> {
            self.log.borrow_mut().push((self.id, kind, bytes.len()));
            Ok(Delivery::Delivered(1))
        }
    }

    fn key(byte: u8) -> JoinKey {
        JoinKey::from_bytes([byte; proto::JOIN_KEY_LEN])
    }

    fn join(key: &JoinKey, id: u32) -> Vec<u8> {
        let header = MessageHeader {
            actor_id: id,
            sequence: 1,
            ..MessageHeader::default()
        };
        proto::encode(&Join::new(key, id, [1, 2, 3]), header)
    }

    fn stats(id: u32, sequence: u64) -> Vec<u8> {
        let header = MessageHeader {
            actor_id: id,
            sequence,
            ..MessageHeader::default()
        };
        proto::encode(
            &EpisodeStats::new(sequence, 10, 0).with(StatField::EpisodeReturn, 1.0),
            header,
        )
    }

    fn remote(release_after: Duration) -> (RemoteActors<Recorded>, Log) {
        let log = Rc::new(RefCell::new(Vec::new()));
        let opened = log.clone();
        let actors = RemoteActors::new(key(7), TransportConfig::default(), move |id| {
            Ok(Recorded {
                id,
                log: opened.clone(),
            })
        })
        .release_after(release_after);
        (actors, log)
    }

    #[test]
    fn a_host_speaks_only_for_the_ids_that_joined_through_it() {
        let (mut actors, log) = remote(Duration::from_secs(30));
        let s = MessageKind::Stats;
        assert_eq!(
            actors.handle("a", s, &stats(0, 1)),
            Outcome::Refused("not_joined")
        );
        assert_eq!(actors.handle("a", s, &join(&key(7), 0)), Outcome::Joined(0));
        assert_eq!(actors.handle("a", s, &stats(0, 2)), Outcome::Forwarded);
        // Another host claims the id, with and without the key.
        assert_eq!(
            actors.handle("b", s, &join(&key(7), 0)),
            Outcome::Refused("id_of_another_host")
        );
        assert_eq!(
            actors.handle("b", s, &join(&key(8), 1)),
            Outcome::Refused("bad_join_proof")
        );
        assert_eq!(
            actors.handle("b", s, &stats(0, 3)),
            Outcome::Refused("id_of_another_host")
        );
        // A message under another kind's key, and garbage.
        assert_eq!(
            actors.handle("a", MessageKind::Rollout, &stats(0, 4)),
            Outcome::Refused("kind_under_another_key")
        );
        assert_eq!(
            actors.handle("a", s, b"not a message"),
            Outcome::Refused("truncated")
        );
        // Only host a's message for actor 0 after its join was published.
        assert_eq!(*log.borrow(), vec![(0, s, stats(0, 2).len())]);
        let hosts = actors.hosts();
        assert_eq!(hosts["a"].forwarded, 1);
        assert_eq!(hosts["a"].actors, BTreeSet::from([0]));
        assert_eq!(hosts["b"].refused["id_of_another_host"], 2);
        assert_eq!(hosts["b"].refused["bad_join_proof"], 1);
        assert_eq!(hosts["a"].messages, 5);
    }

    #[test]
    fn an_id_moves_to_another_host_only_once_its_host_is_silent() {
        let (mut actors, log) = remote(Duration::from_millis(50));
        let s = MessageKind::Stats;
        assert_eq!(actors.handle("a", s, &join(&key(7), 3)), Outcome::Joined(3));
        assert_eq!(
            actors.handle("b", s, &join(&key(7), 3)),
            Outcome::Refused("id_of_another_host")
        );
        std::thread::sleep(Duration::from_millis(80));
        assert_eq!(actors.handle("b", s, &join(&key(7), 3)), Outcome::Joined(3));
        assert_eq!(actors.handle("b", s, &stats(3, 1)), Outcome::Forwarded);
        assert_eq!(
            actors.handle("a", s, &stats(3, 9)),
            Outcome::Refused("id_of_another_host")
        );
        assert_eq!(log.borrow().len(), 1);
        let hosts = actors.hosts();
        assert!(hosts["a"].actors.is_empty());
        assert_eq!(hosts["b"].actors, BTreeSet::from([3]));
    }
}
