//! The Zenoh session each gateway opens: which end listens, which connects,
//! and the transport settings large messages and a pausing learner need.

use std::path::Path;

use anyhow::Context;

/// How long a blocked sender waits for the link before Zenoh closes it
/// (Zenoh's default is 5 s): a learner that pauses for a checkpoint or a
/// slow update must not tear the link down.
const BLOCK_BEFORE_CLOSE_US: u64 = 60_000_000;

/// Receive buffer per link: a 16 MiB message arrives without waiting for
/// the buffer to drain piece by piece (Zenoh's default is 64 KiB).
const RX_BUFFER_BYTES: u64 = 16 << 20;

/// Batches of 64 KiB each data priority's transmission queue holds (Zenoh's
/// default is 2, its maximum 16): a multi-MiB message is cut into 64 KiB
/// fragments, and with 2 the sending thread and the link's own hand over
/// every 128 KiB, which on a small machine costs more than the copying.
const DATA_QUEUE_BATCHES: u64 = 16;

/// Which end of the link this gateway is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// The learner's host: listens on an endpoint, routes between hosts.
    Listen,
    /// An actor host: connects to the learner's host as a client.
    Connect,
}

/// Checks an endpoint given on the command line: `tcp/ADDR:PORT` or
/// `tls/ADDR:PORT` with an explicit address (never a wildcard by default).
pub fn check_endpoint(endpoint: &str) -> anyhow::Result<()> {
    let (scheme, address) = endpoint.split_once('/').with_context(|| {
        format!("endpoint {endpoint:?} must look like tcp/HOST:PORT or tls/HOST:PORT")
    })?;
    anyhow::ensure!(
        matches!(scheme, "tcp" | "tls"),
        "endpoint {endpoint:?}: the gateway speaks tcp/ (plain, only on a network you trust) or tls/"
    );
    let (host, port) = address
        .rsplit_once(':')
        .with_context(|| format!("endpoint {endpoint:?} needs a port: {scheme}/HOST:PORT"))?;
    anyhow::ensure!(
        !host.is_empty() && port.parse::<u16>().is_ok_and(|p| p > 0),
        "endpoint {endpoint:?} needs a host and a port from 1 to 65535"
    );
    Ok(())
}

/// The session's configuration: the user's Zenoh config file if given
/// (TLS certificates, access control), then this gateway's role, its
/// endpoint, no multicast scouting, and the transport settings above.
pub fn config(role: Role, endpoint: &str, file: Option<&Path>) -> anyhow::Result<zenoh::Config> {
    check_endpoint(endpoint)?;
    let mut config = match file {
        Some(path) => zenoh::Config::from_file(path)
            .map_err(|e| anyhow::anyhow!("{e}"))
            .with_context(|| format!("reading the Zenoh config {}", path.display()))?,
        None => zenoh::Config::default(),
    };
    let endpoints = serde_json::to_string(&[endpoint])?;
    let settings = [
        (
            "mode",
            match role {
                Role::Listen => "\"router\"",
                Role::Connect => "\"client\"",
            },
        ),
        (
            match role {
                Role::Listen => "listen/endpoints",
                Role::Connect => "connect/endpoints",
            },
            endpoints.as_str(),
        ),
        ("scouting/multicast/enabled", "false"),
        (
            "transport/link/tx/queue/congestion_control/block/wait_before_close",
            &BLOCK_BEFORE_CLOSE_US.to_string(),
        ),
        (
            "transport/link/rx/buffer_size",
            &RX_BUFFER_BYTES.to_string(),
        ),
        (
            "transport/link/tx/queue/size/data_high",
            &DATA_QUEUE_BATCHES.to_string(),
        ),
        (
            "transport/link/tx/queue/size/data",
            &DATA_QUEUE_BATCHES.to_string(),
        ),
        (
            "transport/link/tx/queue/size/data_low",
            &DATA_QUEUE_BATCHES.to_string(),
        ),
    ];
    for (key, value) in settings {
        config
            .insert_json5(key, value)
            .map_err(|e| anyhow::anyhow!("{e}"))
            .with_context(|| format!("setting {key} = {value} in the Zenoh config"))?;
    }
    if role == Role::Connect {
        // Opening gives up after this long; the actor host's gateway tries
        // again until it is stopped, so it may start before the learner's.
        config
            .insert_json5("connect/timeout_ms", "2000")
            .map_err(|e| anyhow::anyhow!("{e}"))
            .context("setting connect/timeout_ms in the Zenoh config")?;
    }
    Ok(config)
}

/// Opens the session.
pub fn open(config: zenoh::Config) -> anyhow::Result<zenoh::Session> {
    use zenoh::Wait;
    zenoh::open(config)
        .wait()
        .map_err(|e| anyhow::anyhow!("{e}"))
        .context("opening the Zenoh session")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn endpoints_need_a_scheme_a_host_and_a_port() {
        for good in [
            "tcp/127.0.0.1:7447",
            "tls/learner.lab:7447",
            "tcp/[::1]:9000",
        ] {
            check_endpoint(good).unwrap();
        }
        for bad in [
            "127.0.0.1:7447",
            "udp/127.0.0.1:7447",
            "tcp/127.0.0.1",
            "tcp/:7447",
            "tcp/127.0.0.1:0",
            "tcp/127.0.0.1:70000",
        ] {
            assert!(check_endpoint(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn the_roles_listen_or_connect_on_the_endpoint_given() {
        let listen = config(Role::Listen, "tcp/127.0.0.1:7447", None).unwrap();
        let text = listen.to_string();
        assert!(text.contains("127.0.0.1:7447"), "{text}");
        assert_eq!(listen.get_json("mode").unwrap(), "\"router\"");
        let connect = config(Role::Connect, "tcp/127.0.0.1:7447", None).unwrap();
        assert_eq!(connect.get_json("mode").unwrap(), "\"client\"");
        assert_eq!(
            connect
                .get_json("transport/link/tx/queue/congestion_control/block/wait_before_close")
                .unwrap(),
            BLOCK_BEFORE_CLOSE_US.to_string()
        );
    }
}
