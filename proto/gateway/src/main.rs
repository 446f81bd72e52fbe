//! `gateway`: one per host, carrying a run's messages between the learner's
//! host and actor hosts over Zenoh (see the library's docs).

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use anyhow::Context;
use clap::{Parser, Subcommand};
use gateway::actor_host::{self, ActorHost};
use gateway::learner_host::{self, LearnerHost};

/// Carries a run's messages between hosts: start `learner-host` beside the
/// learner and `actor-host` on every other host, before or after its actors.
///
/// Endpoints are `tls/HOST:PORT` (certificates in a Zenoh config file given
/// with --zenoh-config, as deploy/make-certs.sh writes them) or `tcp/HOST:PORT`
/// (plain, unauthenticated, unencrypted: only on a network you trust). The
/// run's join key is the credential of every host: an actor host needs a
/// copy of the learner's RUN_DIR/join.key.
#[derive(Parser)]
#[command(name = "gateway", version)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// On the learner's host: listen for actor hosts, send them the run's
    /// config and weights, put their actors' messages into the learner's
    /// shared memory. Counts per remote host go to RUN_DIR/remote-hosts.json
    /// (shown by the learner's /api/status).
    LearnerHost {
        /// The learner's run directory (its config.toml and join.key).
        #[arg(long)]
        run_dir: PathBuf,
        /// Where to listen, an address of this host, e.g. tls/10.0.0.5:7447
        /// (there is no default: nothing listens on every interface unless
        /// told to with 0.0.0.0).
        #[arg(long, value_name = "ENDPOINT")]
        listen: String,
        /// The run's name in Zenoh keys; the actor hosts must give the same.
        /// Default: the run directory's name.
        #[arg(long)]
        run: Option<String>,
        /// A Zenoh config file (JSON5): TLS certificates, mutual TLS, access
        /// control. The gateway sets mode, endpoint and link settings itself.
        #[arg(long, value_name = "FILE")]
        zenoh_config: Option<PathBuf>,
    },
    /// On an actor host: fetch the run's config from the learner's host into
    /// RUN_DIR/config.toml, send this host's actors' messages to the learner
    /// and its weights to them. Start actors with --config RUN_DIR/config.toml.
    ActorHost {
        /// The learner host's gateway, e.g. tls/learner.lab:7447.
        #[arg(long, value_name = "ENDPOINT")]
        learner_at: String,
        /// This host's run directory (created): the run's config.toml is
        /// written here; the run's join.key must be copied here.
        #[arg(long)]
        run_dir: PathBuf,
        /// The run's name, as the learner host's gateway has it.
        #[arg(long)]
        run: String,
        /// This host's name, unique among the run's hosts (letters, digits,
        /// '.', '_', '-'). Default: the system's host name.
        #[arg(long)]
        host: Option<String>,
        /// Service-name prefix of this host's shared memory (default: the
        /// run's); two "hosts" on one machine need different ones.
        #[arg(long, value_name = "PREFIX")]
        service_prefix: Option<String>,
        /// The run's join key, if not RUN_DIR/join.key.
        #[arg(long, value_name = "FILE")]
        join_key: Option<PathBuf>,
        /// A Zenoh config file (JSON5): TLS certificates for the link.
        #[arg(long, value_name = "FILE")]
        zenoh_config: Option<PathBuf>,
    },
    /// Measures the gateway pair against local iceoryx2 and one loopback TCP
    /// stream, side by side: throughput and lock-step latency of valid
    /// rollout messages, and the time new weights take to reach a remote
    /// actor. Prints a Markdown table.
    Bench {
        /// Message sizes in MiB.
        #[arg(long, value_delimiter = ',', default_value = "0.1,1,4,16")]
        sizes_mib: Vec<f64>,
        /// Messages per size and path (as many again for latency).
        #[arg(long, default_value_t = 50)]
        count: usize,
        /// Also through iceoryx2's own bridge, as a baseline: the path of
        /// its `iox2-link-tunnel-zenoh` binary (`cargo install
        /// iceoryx2-integrations-zenoh-link-tunnel-cli`).
        #[arg(long, value_name = "BINARY")]
        upstream_tunnel: Option<PathBuf>,
    },
}

fn main() -> anyhow::Result<()> {
    transport::init_logging("info,zenoh=warn");
    let cli = Cli::parse();
    let stop = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, stop.clone()).context("installing signal handlers")?;
    }
    match cli.command {
        Command::Bench {
            sizes_mib,
            count,
            upstream_tunnel,
        } => {
            anyhow::ensure!(
                count > 0 && sizes_mib.iter().all(|&s| s > 0.0 && s <= 64.0),
                "--count must be positive and --sizes-mib in (0, 64]"
            );
            let sizes: Vec<usize> = sizes_mib
                .iter()
                .map(|s| (s * f64::from(1u32 << 20)) as usize)
                .collect();
            let scratch =
                std::env::temp_dir().join(format!("afx-gateway-bench-{}", std::process::id()));
            if let Some(binary) = &upstream_tunnel {
                anyhow::ensure!(
                    binary.is_file(),
                    "--upstream-tunnel {}: no such file (install it with `cargo install iceoryx2-integrations-zenoh-link-tunnel-cli`)",
                    binary.display()
                );
            }
            let result = gateway::bench::run(&sizes, count, &scratch, upstream_tunnel.as_deref());
            let _ = std::fs::remove_dir_all(&scratch);
            print!("{}", gateway::bench::table(&result?));
            Ok(())
        }
        Command::LearnerHost {
            run_dir,
            listen,
            run,
            zenoh_config,
        } => {
            let run = match run {
                Some(run) => run,
                None => run_dir
                    .canonicalize()
                    .ok()
                    .and_then(|dir| dir.file_name().map(|n| n.to_string_lossy().into_owned()))
                    .with_context(|| {
                        format!("naming the run after {}: give --run", run_dir.display())
                    })?,
            };
            learner_host::run(
                &LearnerHost {
                    run_dir,
                    run,
                    listen,
                    zenoh_config,
                },
                &stop,
            )
        }
        Command::ActorHost {
            learner_at,
            run_dir,
            run,
            host,
            service_prefix,
            join_key,
            zenoh_config,
        } => {
            let host = match host {
                Some(host) => host,
                None => std::fs::read_to_string("/proc/sys/kernel/hostname")
                    .map(|name| name.trim().to_string())
                    .context("reading this host's name: give --host")?,
            };
            actor_host::run(
                &ActorHost {
                    run_dir,
                    run,
                    host,
                    learner_at,
                    service_prefix,
                    join_key,
                    zenoh_config,
                },
                &stop,
            )
        }
    }
}
