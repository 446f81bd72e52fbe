//! The gateway on the learner's host: listens for actor hosts, answers
//! their requests for the run's config and newest weights, publishes every
//! new weights message to them at a higher priority than their data, and
//! puts their actors' messages into the learner's shared memory through
//! ports of its own ([`RemoteActors`]).

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::Context;
use transport::{ActorPorts, WeightsTap};
use zenoh::handlers::FifoChannel;
use zenoh::qos::{CongestionControl, Priority};
use zenoh::Wait;

use crate::keys::RunKeys;
use crate::link::{self, Role};
use crate::remote::RemoteActors;
use crate::{run_transport_config, write_whole, zenoh_error};

/// Messages from actor hosts waiting to be put into shared memory: when
/// they are this many, Zenoh stops reading the links, and the actor hosts'
/// sends block (back-pressure, not growth).
const UPSTREAM_QUEUE: usize = 64;

/// How often the remote hosts' counts are written for the learner's status.
const HOSTS_EVERY: Duration = Duration::from_secs(2);

/// What the learner host's gateway needs.
#[derive(Debug, Clone)]
pub struct LearnerHost {
    /// The learner's run directory (its config.toml and join.key).
    pub run_dir: PathBuf,
    /// The run's name in key expressions.
    pub run: String,
    /// Where to listen, e.g. `tls/0.0.0.0:7447`.
    pub listen: String,
    /// A Zenoh config file (TLS certificates, access control).
    pub zenoh_config: Option<PathBuf>,
}

/// Runs until `stop` is set.
pub fn run(options: &LearnerHost, stop: &Arc<AtomicBool>) -> anyhow::Result<()> {
    let keys = RunKeys::new(&options.run)?;
    let config_path = options.run_dir.join("config.toml");
    let config_text = std::fs::read_to_string(&config_path).with_context(|| {
        format!(
            "reading the run's config {}: start the learner first (it writes config.toml and join.key)",
            config_path.display()
        )
    })?;
    let transport = run_transport_config(&config_text, &config_path)?;
    let key = transport::read_join_key(&options.run_dir.join(transport::JOIN_KEY_FILE))?;
    let session = link::open(link::config(
        Role::Listen,
        &options.listen,
        options.zenoh_config.as_deref(),
    )?)?;
    let config_bytes = config_text.into_bytes();
    let config_key = keys.config();
    let _config = session
        .declare_queryable(keys.config())
        .callback(move |query| {
            let _ = query.reply(&config_key, config_bytes.clone()).wait();
        })
        .wait()
        .map_err(zenoh_error)
        .context("declaring the config queryable")?;
    let newest: Arc<Mutex<Option<Vec<u8>>>> = Arc::default();
    let answer = newest.clone();
    let weights_key = keys.weights();
    let _weights_queryable = session
        .declare_queryable(keys.weights())
        .callback(move |query| {
            let weights = answer.lock().unwrap_or_else(|p| p.into_inner()).clone();
            if let Some(weights) = weights {
                let _ = query.reply(&weights_key, weights).wait();
            }
        })
        .wait()
        .map_err(zenoh_error)
        .context("declaring the weights queryable")?;
    let weights_out = session
        .declare_publisher(keys.weights())
        .congestion_control(CongestionControl::Block)
        .priority(Priority::DataHigh)
        .wait()
        .map_err(zenoh_error)
        .context("declaring the weights publisher")?;
    // Weights on a thread of their own, woken by the learner's publish: they
    // never wait behind the actors' data.
    let weights = {
        let (transport, key, stop) = (transport.clone(), key.clone(), stop.clone());
        std::thread::Builder::new()
            .name("gateway-weights".into())
            .spawn(move || send_weights(&transport, &key, &weights_out, &newest, &stop))
            .context("starting the weights thread")?
    };
    let upstream = session
        .declare_subscriber(keys.all_upstream())
        .with(FifoChannel::new(UPSTREAM_QUEUE))
        .wait()
        .map_err(zenoh_error)
        .context("subscribing to the actor hosts")?;
    let ports_config = transport.clone();
    let ports_key = key.clone();
    let mut remote = RemoteActors::new(key.clone(), transport.clone(), move |id| {
        ActorPorts::open(&ports_config, id, ports_key.clone())
    });
    tracing::info!(
        listen = options.listen,
        run = options.run,
        "learner host's gateway ready"
    );
    let mut status_due = Instant::now() + HOSTS_EVERY;
    while !stop.load(Ordering::Relaxed) && !weights.is_finished() {
        let first = upstream
            .recv_timeout(Duration::from_millis(20))
            .map_err(zenoh_error)
            .context("receiving from the actor hosts")?;
        let more = std::iter::from_fn(|| upstream.try_recv().ok().flatten());
        for sample in first.into_iter().chain(more.take(UPSTREAM_QUEUE)) {
            let key_expr = sample.key_expr().as_str();
            let Some((host, kind)) = keys.parse_upstream(key_expr) else {
                continue;
            };
            remote.handle(host, kind, &sample.payload().to_bytes());
        }
        if Instant::now() >= status_due {
            status_due = Instant::now() + HOSTS_EVERY;
            write_hosts(&options.run_dir, &remote)?;
        }
    }
    // Counts of a gateway that stopped would read as current.
    let _ = std::fs::remove_file(options.run_dir.join(transport::REMOTE_HOSTS_FILE));
    weights
        .join()
        .map_err(|_| anyhow::anyhow!("the weights thread panicked"))?
}

/// Sends every weights message the run's learner signed to the actor hosts
/// and keeps the newest for hosts that ask, until `stop`.
fn send_weights(
    transport: &transport::TransportConfig,
    key: &proto::JoinKey,
    out: &zenoh::pubsub::Publisher<'static>,
    newest: &Mutex<Option<Vec<u8>>>,
    stop: &AtomicBool,
) -> anyhow::Result<()> {
    let tap = WeightsTap::open(transport, "gateway-weights")?;
    while !stop.load(Ordering::Relaxed) {
        let Some(message) = tap.wait(Duration::from_millis(200))? else {
            continue;
        };
        match tap.check(message.bytes(), key) {
            Ok(_) => {
                let bytes = message.bytes().to_vec();
                out.put(bytes.clone())
                    .wait()
                    .map_err(zenoh_error)
                    .context("publishing weights to the actor hosts")?;
                *newest.lock().unwrap_or_else(|p| p.into_inner()) = Some(bytes);
            }
            Err(error) => {
                tracing::warn!("not forwarding weights the run's learner did not sign: {error}")
            }
        }
    }
    Ok(())
}

/// Writes the remote hosts' counts to [`transport::REMOTE_HOSTS_FILE`] (whole, by rename).
fn write_hosts(run_dir: &Path, remote: &RemoteActors<ActorPorts>) -> anyhow::Result<()> {
    let hosts = remote.hosts();
    for (host, counts) in &hosts {
        tracing::debug!(host, ?counts, "remote host");
    }
    write_whole(
        &run_dir.join(transport::REMOTE_HOSTS_FILE),
        &serde_json::to_vec_pretty(&hosts)?,
    )
}
