//! The gateway on an actor host: fetches the run's config from the
//! learner's host, then stands in for the learner on this host: it reads
//! the local actors' messages (screened and validated as the learner does),
//! sends them to the learner's host, and republishes the learner's weights
//! into the local weights service, whose history hands them to actors that
//! start later.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::Context;
use proto::{JoinKey, Limits, Message, MessageHeader, MessageKind};
use transport::membership::{Membership, Sender};
use transport::{LearnerPorts, TransportConfig};
use zenoh::handlers::FifoChannelHandler;
use zenoh::pubsub::Publisher;
use zenoh::qos::{CongestionControl, Priority};
use zenoh::query::Reply;
use zenoh::Wait;

use crate::keys::{check_name, RunKeys, UPSTREAM};
use crate::link::{self, Role};
use crate::weights_in::WeightsIn;
use crate::{run_transport_config, write_whole, zenoh_error, STATUS_EVERY};

/// Messages of one kind taken from shared memory per pass, so one busy
/// kind cannot starve the others or the weights.
const PER_PASS: usize = 16;

/// How often actors that started since the last weights get them from the
/// local service's history (as the learner does it).
const MAINTENANCE_EVERY: Duration = Duration::from_millis(250);

/// How often a request for the newest weights is repeated until some arrive.
const WEIGHTS_RETRY: Duration = Duration::from_secs(2);

/// What an actor host's gateway needs.
#[derive(Debug, Clone)]
pub struct ActorHost {
    /// This host's run directory: the run's config.toml is written here,
    /// the run's join.key must be here (or at `join_key`).
    pub run_dir: PathBuf,
    /// The run's name in key expressions (as the learner host's gateway).
    pub run: String,
    /// This host's name, unique among the run's hosts.
    pub host: String,
    /// The learner host's gateway, e.g. `tls/learner.lab:7447`.
    pub learner_at: String,
    /// Service-name prefix of this host's shared memory, if not the run's.
    pub service_prefix: Option<String>,
    /// The run's join key, if not `run_dir/join.key`.
    pub join_key: Option<PathBuf>,
    /// A Zenoh config file (TLS certificates).
    pub zenoh_config: Option<PathBuf>,
}

/// The run's config as this host uses it: the learner's, with this host's
/// service prefix when one is given.
pub fn localise_config(text: &str, service_prefix: Option<&str>) -> anyhow::Result<String> {
    let mut table: toml::Table =
        toml::from_str(text).context("the learner's config.toml is not TOML")?;
    if let Some(prefix) = service_prefix {
        let transport = table
            .entry("transport")
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        let transport = transport
            .as_table_mut()
            .context("[transport] in the learner's config is not a table")?;
        transport.insert(
            "service_prefix".into(),
            toml::Value::String(prefix.to_string()),
        );
    }
    Ok(toml::to_string(&table)?)
}

/// What this gateway has done, for its periodic log line.
#[derive(Debug, Default)]
struct Counts {
    sent: u64,
    sent_bytes: u64,
    refused: BTreeMap<&'static str, u64>,
    weights: u64,
}

/// Runs until `stop` is set.
pub fn run(options: &ActorHost, stop: &AtomicBool) -> anyhow::Result<()> {
    let keys = RunKeys::new(&options.run)?;
    check_name("host name", &options.host)?;
    let key_path = options
        .join_key
        .clone()
        .unwrap_or_else(|| options.run_dir.join(transport::JOIN_KEY_FILE));
    let key = transport::read_join_key(&key_path).with_context(|| {
        format!(
            "the run's join key: copy the learner's RUN_DIR/{} to {} (it is the run's secret: copy it as you would an SSH key)",
            transport::JOIN_KEY_FILE,
            key_path.display()
        )
    })?;
    let Some(session) = connect(options, stop)? else {
        return Ok(());
    };
    let Some(config_text) = fetch_config(&session, &keys, stop)? else {
        return Ok(());
    };
    std::fs::create_dir_all(&options.run_dir)
        .with_context(|| format!("creating {}", options.run_dir.display()))?;
    let config_path = options.run_dir.join("config.toml");
    let local = localise_config(&config_text, options.service_prefix.as_deref())?;
    write_whole(&config_path, local.as_bytes())?;
    let transport = run_transport_config(&local, &config_path)?;
    tracing::info!(
        config = %config_path.display(),
        prefix = transport.service_prefix,
        "the run's config arrived; start this host's actors with --config {}",
        config_path.display()
    );
    let mut ports = LearnerPorts::open(&transport, key.clone())?;
    let publishers = upstream_publishers(&session, &keys, &options.host)?;
    let mut weights_in = WeightsIn::start(&session, &keys, &transport)?;
    let mut forwarding = Forwarding {
        transport: &transport,
        key: &key,
        members: Membership::new(key.clone()),
        counts: Counts::default(),
        last_weights: None,
    };
    let mut asked: Option<(Instant, FifoChannelHandler<Reply>)> = None;
    let mut status_due = Instant::now() + STATUS_EVERY;
    let mut last_maintenance = Instant::now();
    while !stop.load(Ordering::Relaxed) {
        // Weights first, live or asked for, so actors never wait behind data.
        while let Some(sample) = weights_in.try_next()? {
            forwarding.weights(&mut ports, &sample.payload().to_bytes())?;
        }
        if forwarding.last_weights.is_none()
            && asked
                .as_ref()
                .is_none_or(|(at, _)| at.elapsed() >= WEIGHTS_RETRY)
        {
            let replies = session
                .get(keys.weights())
                .timeout(WEIGHTS_RETRY)
                .wait()
                .map_err(zenoh_error)
                .context("asking for the newest weights")?;
            asked = Some((Instant::now(), replies));
        }
        if let Some((_, replies)) = &asked {
            while let Ok(Some(reply)) = replies.try_recv() {
                if let Ok(sample) = reply.result() {
                    forwarding.weights(&mut ports, &sample.payload().to_bytes())?;
                }
            }
        }
        // Woken by local actors' messages and by weights arriving from the
        // learner's host ([`WeightsIn`]).
        ports.wait(Duration::from_millis(2))?;
        if last_maintenance.elapsed() >= MAINTENANCE_EVERY {
            // Hands the newest weights (the service's history) to actors
            // that started since they were published.
            ports.maintain();
            last_maintenance = Instant::now();
        }
        for (kind, publisher) in UPSTREAM.iter().zip(&publishers) {
            forwarding.upstream(&ports, *kind, publisher)?;
        }
        if Instant::now() >= status_due {
            status_due = Instant::now() + STATUS_EVERY;
            let c = &forwarding.counts;
            tracing::info!(
                sent = c.sent,
                sent_mb = c.sent_bytes as f64 / 1e6,
                weights = c.weights,
                refused = ?c.refused,
                "actor host's gateway"
            );
        }
    }
    Ok(())
}

/// One publisher per upstream kind, under this host's keys.
fn upstream_publishers(
    session: &zenoh::Session,
    keys: &RunKeys,
    host: &str,
) -> anyhow::Result<Vec<Publisher<'static>>> {
    UPSTREAM
        .into_iter()
        .map(|kind| {
            // Reliable (Zenoh's default) and blocking: a full link stops
            // this gateway, then the local actors' messages are dropped
            // at the source and counted as gaps by the learner, and
            // memory stays bounded. Episode stats never wait behind
            // frames.
            let priority = match kind {
                MessageKind::Frames => Priority::DataLow,
                _ => Priority::Data,
            };
            session
                .declare_publisher(keys.upstream(host, kind))
                .congestion_control(CongestionControl::Block)
                .priority(priority)
                .wait()
                .map_err(zenoh_error)
                .with_context(|| format!("declaring the {} publisher", kind.as_str()))
        })
        .collect()
}

/// The state of forwarding between this host's shared memory and Zenoh.
struct Forwarding<'a> {
    transport: &'a TransportConfig,
    key: &'a JoinKey,
    members: Membership,
    counts: Counts,
    /// The header of the last weights republished (the same message can
    /// arrive live and as an answer).
    last_weights: Option<MessageHeader>,
}

impl Forwarding<'_> {
    fn refuse(&mut self, reason: &'static str) {
        *self.counts.refused.entry(reason).or_default() += 1;
    }

    /// Republishes the learner's weights locally, if the run's learner
    /// signed them.
    fn weights(&mut self, ports: &mut LearnerPorts, bytes: &[u8]) -> anyhow::Result<()> {
        let limits = Limits {
            max_actors: self.transport.max_actors,
            max_payload_len: self.transport.max_weights_bytes as u64,
        };
        let header = match proto::decode_weights(bytes, &limits, self.key) {
            Ok((header, _)) => header,
            Err(error) => {
                self.refuse(error.reason());
                return Ok(());
            }
        };
        if self.last_weights == Some(header) {
            return Ok(());
        }
        ports.forward_weights(bytes)?;
        self.last_weights = Some(header);
        self.counts.weights += 1;
        Ok(())
    }

    /// Sends this host's actors' messages of `kind` on, screened and
    /// validated as the learner would (what arrives from a publisher that
    /// did not join is not even read).
    fn upstream(
        &mut self,
        ports: &LearnerPorts,
        kind: MessageKind,
        publisher: &Publisher<'static>,
    ) -> anyhow::Result<()> {
        let max_bytes = self.transport.max_bytes(kind);
        let limits = Limits {
            max_actors: self.transport.max_actors,
            max_payload_len: max_bytes as u64,
        };
        for _ in 0..PER_PASS {
            let Some(message) = ports.receive(kind)? else {
                break;
            };
            let origin = message.origin();
            let len = message.bytes().len();
            if len > max_bytes {
                self.refuse("payload_too_large");
                continue;
            }
            let sender = match self.members.screen(kind, origin, len) {
                Ok(sender) => sender,
                Err(reason) => {
                    self.refuse(reason);
                    continue;
                }
            };
            let bytes = message.bytes();
            // The header routes it; the learner checks the rest (checksum,
            // layout) on arrival, so it is not read here once more.
            let (header, carried) = match proto::decode_header(bytes, &limits) {
                Ok(checked) => checked,
                Err(error) => {
                    self.refuse(error.reason());
                    continue;
                }
            };
            let admitted = match carried {
                MessageKind::Join => match proto::decode(bytes, &limits) {
                    Ok((_, Message::Join(join))) => self
                        .members
                        .join(header.actor_id, &join, origin)
                        .map(|_| ()),
                    Ok(_) => Err("kind_under_another_key"),
                    Err(error) => Err(error.reason()),
                },
                _ if sender == Sender::Stranger => Err("unknown_publisher"),
                _ => self.members.admit(header.actor_id, kind, origin),
            };
            if let Err(reason) = admitted {
                self.refuse(reason);
                continue;
            }
            publisher
                .put(bytes.to_vec())
                .wait()
                .map_err(zenoh_error)
                .context("sending to the learner's host")?;
            self.counts.sent += 1;
            self.counts.sent_bytes += len as u64;
        }
        Ok(())
    }
}

/// Opens the session, trying again until the learner host's gateway
/// answers or `stop` is set (then `None`).
fn connect(options: &ActorHost, stop: &AtomicBool) -> anyhow::Result<Option<zenoh::Session>> {
    let mut said = false;
    while !stop.load(Ordering::Relaxed) {
        let config = link::config(
            Role::Connect,
            &options.learner_at,
            options.zenoh_config.as_deref(),
        )?;
        match link::open(config) {
            Ok(session) => return Ok(Some(session)),
            Err(error) if !said => {
                tracing::info!(
                    "waiting for the learner host's gateway at {} ({error:#})",
                    options.learner_at
                );
                said = true;
            }
            Err(_) => {}
        }
        std::thread::sleep(Duration::from_millis(500));
    }
    Ok(None)
}

/// Asks the learner host's gateway for the run's config until it answers
/// or `stop` is set (then `None`).
fn fetch_config(
    session: &zenoh::Session,
    keys: &RunKeys,
    stop: &AtomicBool,
) -> anyhow::Result<Option<String>> {
    while !stop.load(Ordering::Relaxed) {
        let replies = session
            .get(keys.config())
            .timeout(Duration::from_secs(2))
            .wait()
            .map_err(zenoh_error)
            .context("asking for the run's config")?;
        while let Ok(reply) = replies.recv() {
            if let Ok(sample) = reply.result() {
                let text = String::from_utf8(sample.payload().to_bytes().into_owned())
                    .context("the run's config is not UTF-8")?;
                return Ok(Some(text));
            }
        }
        std::thread::sleep(Duration::from_millis(500));
    }
    Ok(None)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_local_config_keeps_the_learners_values_but_this_hosts_prefix() {
        let learner = "[transport]\nservice_prefix = \"afx_run\"\nmax_actors = 32\n\n[task]\nimage_size = 64\n";
        let local = localise_config(learner, Some("afx_box2")).unwrap();
        let table: toml::Table = toml::from_str(&local).unwrap();
        assert_eq!(
            table["transport"]["service_prefix"].as_str(),
            Some("afx_box2")
        );
        assert_eq!(table["transport"]["max_actors"].as_integer(), Some(32));
        assert_eq!(table["task"]["image_size"].as_integer(), Some(64));
        let same = localise_config(learner, None).unwrap();
        assert_eq!(
            toml::from_str::<toml::Table>(&same).unwrap(),
            toml::from_str::<toml::Table>(learner).unwrap()
        );
        let no_table = localise_config("[task]\nimage_size = 64\n", Some("p")).unwrap();
        assert!(no_table.contains("service_prefix = \"p\""), "{no_table}");
        assert!(localise_config("not toml [", None).is_err());
    }
}
