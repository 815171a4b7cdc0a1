//! `lightwire relay`: fans a solver's lightmap streams out to many viewers.
//!
//! A solver pod owns a GPU and a few scenes; it should spend its time
//! solving, not writing the same bytes to thousands of sockets. A relay is
//! a stateless process in front of it:
//!
//! ```text
//! solver ──ws──► upstream task (per scene) ──► Mirror ──► Publisher ──watch──► sessions ──► viewers
//!    ▲                 │                                                        │
//!    └── Transform ────┘◄──────────────── Inbox (one slot per object) ◄─────────┘ drivers
//! ```
//!
//! 1. [`upstream::Upstream`] connects to one scene of a solver as an
//!    ordinary protocol client (`Hello` with the relay's upstream token)
//!    and reads its keyframes and deltas.
//! 2. [`mirror::Mirror`] applies them to the relay's copy (validating every
//!    tile, so a bad upstream frame is refused, never forwarded) and maps
//!    upstream versions to **relay versions**, which only ever increase,
//!    across upstream reconnects and solver restarts (see the mirror's
//!    module doc for why and how).
//! 3. Each relay version is published through the same
//!    [`crate::service::publication::Publisher`] the solver uses, and served
//!    by the same [`crate::service::session`] code through a
//!    [`crate::service::feed::Feed`]: handshake, tokens and roles, limits,
//!    and "delta onto the exact base, merged delta a few versions behind,
//!    else keyframe" are the solver's rules, not a copy of them.
//! 4. Drivers' transforms are checked by the session (role, object, pose,
//!    seq, rate), wait in the feed's inbox and are forwarded upstream by the
//!    upstream task, paced and coalesced per object.
//!
//! When an upstream goes away the feed keeps its newest publication: the
//! relay keeps serving the last version (and stays ready), reconnects with
//! backoff, and resyncs its viewers with a delta of exactly the tiles that
//! differ when the upstream is back.

pub mod metrics;
pub mod mirror;
pub mod upstream;

use std::collections::{BTreeMap, HashMap};
use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{SystemTime, UNIX_EPOCH};

use anyhow::{Result, bail};
use axum::Router;
use axum::extract::{ConnectInfo, Path, Query, State, WebSocketUpgrade};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use lightwire_protocol::Stats;
use serde_json::json;
use tokio::net::TcpListener;
use tokio::sync::watch;

use crate::service::feed::Feed;
use crate::service::http::upgrade_websocket;
use crate::service::publication::Publisher;
use crate::service::{Config, Shared, auth, serve_http};
use metrics::RelayMetrics;
use upstream::{Upstream, UpstreamStatus, UpstreamUrl};

/// One relayed scene.
struct Relayed {
    url: UpstreamUrl,
    feed: Arc<Feed>,
    status: Arc<UpstreamStatus>,
}

/// What the relay's HTTP handlers share.
struct RelayState {
    shared: Arc<Shared>,
    scenes: BTreeMap<String, Relayed>,
}

/// Serves the relay on `listener` until `shutdown` flips: one upstream
/// task per configured upstream, sessions for every viewer.
pub async fn relay(
    config: Config,
    listener: TcpListener,
    shutdown: watch::Receiver<bool>,
) -> Result<()> {
    let mut metrics = crate::service::metrics::Metrics::new();
    let relay_metrics = Arc::new(RelayMetrics::default());
    relay_metrics.register(metrics.registry_mut());
    let metrics = Arc::new(metrics);
    let auth = auth::Auth::from_config(&config)?;
    let mut urls = Vec::new();
    for text in &config.upstreams {
        let url = UpstreamUrl::parse(text)?;
        if urls.iter().any(|u: &UpstreamUrl| u.scene == url.scene) {
            bail!(
                "two upstreams serve scene \"{}\"; a relay serves each scene id once",
                url.scene
            );
        }
        urls.push(url);
    }
    let token = config.upstream_token.clone();
    let shared = Arc::new(Shared {
        config,
        metrics: metrics.clone(),
        auth,
        shutdown: shutdown.clone(),
    });
    let mut scenes = BTreeMap::new();
    let mut tasks = Vec::new();
    for url in urls {
        let (publisher, publications) = Publisher::new();
        let (stats_tx, stats_rx) = watch::channel(Stats {
            version: 0,
            unshot_fraction: 1.0,
            tick_ms: 0.0,
            solve_ms: 0.0,
            redistribution_ms: 0.0,
            clients: 0,
            server_time_us: SystemTime::now()
                .duration_since(UNIX_EPOCH)
                .map_or(0, |d| d.as_micros() as u64),
        });
        let feed = Arc::new(Feed::new(url.scene.clone(), None, publications, stats_rx));
        let status = Arc::new(UpstreamStatus::default());
        tasks.push(tokio::spawn(
            Upstream {
                url: url.clone(),
                token: token.clone(),
                feed: feed.clone(),
                publisher,
                stats: stats_tx,
                status: status.clone(),
                metrics: metrics.clone(),
                relay_metrics: relay_metrics.clone(),
                shutdown: shutdown.clone(),
            }
            .run(),
        ));
        scenes.insert(url.scene.clone(), Relayed { url, feed, status });
    }
    let state = Arc::new(RelayState {
        shared: shared.clone(),
        scenes,
    });
    let app = Router::new()
        .route("/healthz", get(|| async { "ok\n" }))
        .route("/readyz", get(readyz))
        .route("/metrics", get(metrics_text))
        .route("/api/scenes", get(list_scenes))
        .route("/ws/scenes/{id}", get(websocket))
        .with_state(state);
    let mut stop = shutdown.clone();
    serve_http(
        listener,
        app,
        shared.config.socket_send_buffer,
        async move {
            let _ = stop.wait_for(|s| *s).await;
        },
    )
    .await?;
    for task in tasks {
        let _ = task.await;
    }
    Ok(())
}

/// 200 once every scene has a version to serve. A relay whose upstream is
/// down but that has served before stays ready: it serves the last
/// version, which is the point of the relay tier.
async fn readyz(State(state): State<Arc<RelayState>>) -> Response {
    let waiting: Vec<&String> = state
        .scenes
        .iter()
        .filter(|(_, s)| !s.feed.ready.load(Ordering::Acquire))
        .map(|(id, _)| id)
        .collect();
    if waiting.is_empty() {
        (StatusCode::OK, "ready\n").into_response()
    } else {
        (
            StatusCode::SERVICE_UNAVAILABLE,
            axum::Json(json!({ "ready": false, "waiting_for_upstream": waiting })),
        )
            .into_response()
    }
}

async fn metrics_text(State(state): State<Arc<RelayState>>) -> Response {
    (
        [(
            header::CONTENT_TYPE,
            "application/openmetrics-text; version=1.0.0; charset=utf-8",
        )],
        state.shared.metrics.render(),
    )
        .into_response()
}

/// Per scene: the relay version, the upstream version it equals, whether
/// the upstream is connected, clients, and why the upstream was last lost.
async fn list_scenes(State(state): State<Arc<RelayState>>) -> Response {
    let scenes: Vec<_> = state
        .scenes
        .iter()
        .map(|(id, s)| {
            let upstream_version = s.status.upstream_version.load(Ordering::Relaxed);
            json!({
                "id": id,
                "upstream": s.url.url,
                "connected": s.status.connected.load(Ordering::Relaxed),
                "connects": s.status.connects.load(Ordering::Relaxed),
                "last_error": *s.status.last_error.lock().unwrap_or_else(|p| p.into_inner()),
                "ready": s.feed.ready.load(Ordering::Acquire),
                "version": s.feed.latest().map(|p| p.version),
                "upstream_version": (upstream_version > 0).then_some(upstream_version),
                "clients": s.feed.clients.load(Ordering::Relaxed),
            })
        })
        .collect();
    axum::Json(scenes).into_response()
}

async fn websocket(
    State(state): State<Arc<RelayState>>,
    Path(id): Path<String>,
    Query(query): Query<HashMap<String, String>>,
    ConnectInfo(peer): ConnectInfo<SocketAddr>,
    headers: HeaderMap,
    upgrade: WebSocketUpgrade,
) -> Response {
    let Some(scene) = state.scenes.get(&id) else {
        return (
            StatusCode::NOT_FOUND,
            axum::Json(json!({
                "error": format!("this relay does not relay scene \"{id}\"; GET /api/scenes lists what it does")
            })),
        )
            .into_response();
    };
    tracing::debug!(%peer, scene = %id, "websocket upgrade");
    upgrade_websocket(
        state.shared.clone(),
        scene.feed.clone(),
        &headers,
        &query,
        upgrade,
    )
}
