//! The HTTP edge: the live page at `/`, `/metrics`, `/api/status`,
//! `/api/history`, `/api/config`, `/healthz`. Handlers only render the
//! shared status or read the run's history file.

use std::sync::Arc;

use axum::extract::{Query, State};
use axum::http::{header, StatusCode};
use axum::response::{Html, IntoResponse};
use axum::routing::get;
use axum::{Json, Router};

use crate::shared::Shared;
use crate::status::StatusSnapshot;

/// The router over the shared learner state.
pub fn router(shared: Arc<Shared>) -> Router {
    Router::new()
        .route("/", get(|| async { Html(LIVE_PAGE) }))
        .route("/metrics", get(metrics))
        .route("/api/status", get(status))
        .route("/api/history", get(history))
        .route("/api/config", get(config))
        .route("/healthz", get(|| async { "ok\n" }))
        .with_state(shared)
}

/// The live page: the training curves, updated from `/api/history` every
/// 5 s, the actors, the run's config. One file compiled into the binary,
/// nothing fetched from elsewhere, so it works offline.
const LIVE_PAGE: &str = include_str!("live_page.html");

/// The run's config as the learner runs it (TOML).
async fn config(State(shared): State<Arc<Shared>>) -> impl IntoResponse {
    (
        [(header::CONTENT_TYPE, "text/plain; charset=utf-8")],
        shared.config.to_toml(),
    )
}

/// OpenMetrics for a scraper whose `Accept` asks for it (Prometheus does),
/// the classic text format for everything else (`promtool`, `curl`).
async fn metrics(
    State(shared): State<Arc<Shared>>,
    headers: axum::http::HeaderMap,
) -> impl IntoResponse {
    let (snapshot, timings) = {
        let status = shared.status();
        (
            status.snapshot(shared.config.actor_timeout_s),
            status.timings.clone(),
        )
    };
    let text = crate::prometheus::render(&snapshot, &timings);
    let openmetrics = headers
        .get_all(header::ACCEPT)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .any(|v| v.contains("application/openmetrics-text"));
    if openmetrics {
        (
            [(
                header::CONTENT_TYPE,
                "application/openmetrics-text; version=1.0.0; charset=utf-8",
            )],
            text,
        )
    } else {
        (
            [(
                header::CONTENT_TYPE,
                "text/plain; version=0.0.4; charset=utf-8",
            )],
            crate::prometheus::to_classic(&text),
        )
    }
}

/// `/api/status`: the learner's status, and the actor hosts that a gateway
/// on this host serves (`remote_hosts`, from its counts file), each with the
/// messages its actors lost on the way (`gaps`, from their sequence numbers).
async fn status(State(shared): State<Arc<Shared>>) -> impl IntoResponse {
    let snapshot = shared.status().snapshot(shared.config.actor_timeout_s);
    let remote_hosts = remote_hosts(&shared.run_dir, &snapshot);
    Json(StatusView {
        snapshot,
        remote_hosts,
    })
}

/// The status with the remote hosts beside it.
#[derive(serde::Serialize)]
struct StatusView {
    #[serde(flatten)]
    snapshot: StatusSnapshot,
    #[serde(skip_serializing_if = "Option::is_none")]
    remote_hosts: Option<serde_json::Map<String, serde_json::Value>>,
}

/// The gateway's per-host counts, if it runs, with each host's gaps: the
/// losses the learner counted for the actors the host speaks for.
fn remote_hosts(
    run_dir: &std::path::Path,
    snapshot: &StatusSnapshot,
) -> Option<serde_json::Map<String, serde_json::Value>> {
    let text = std::fs::read_to_string(run_dir.join(transport::REMOTE_HOSTS_FILE)).ok()?;
    let mut hosts: serde_json::Map<String, serde_json::Value> = serde_json::from_str(&text).ok()?;
    for host in hosts.values_mut() {
        let gaps: u64 = host["actors"]
            .as_array()
            .into_iter()
            .flatten()
            .filter_map(serde_json::Value::as_u64)
            .filter_map(|id| snapshot.actors.iter().find(|a| u64::from(a.id) == id))
            .map(|a| a.dropped)
            .sum();
        if let Some(host) = host.as_object_mut() {
            host.insert("gaps".into(), gaps.into());
        }
    }
    Some(hosts)
}

/// `/api/history?kind=episode&last=500`.
#[derive(Debug, serde::Deserialize)]
struct HistoryQuery {
    /// `episode`, `ppo` or `unet`; all kinds when absent.
    kind: Option<String>,
    /// The newest this many records (default 1000).
    last: Option<usize>,
}

/// The run's history records as JSON: `{"total": n, "records": [...]}`,
/// the newest `last` of them (of one `kind` if asked).
async fn history(
    State(shared): State<Arc<Shared>>,
    Query(query): Query<HistoryQuery>,
) -> impl IntoResponse {
    let run_dir = shared.run_dir.clone();
    let read = tokio::task::spawn_blocking(move || {
        crate::history::read_records(&run_dir, query.kind.as_deref()).map(|mut records| {
            let total = records.len();
            let keep = query.last.unwrap_or(1000);
            records.drain(..total.saturating_sub(keep));
            serde_json::json!({"total": total, "records": records})
        })
    })
    .await;
    match read {
        Ok(Ok(body)) => Ok(Json(body)),
        Ok(Err(e)) => Err((StatusCode::INTERNAL_SERVER_ERROR, format!("{e:#}\n"))),
        Err(e) => Err((StatusCode::INTERNAL_SERVER_ERROR, format!("{e}\n"))),
    }
}
