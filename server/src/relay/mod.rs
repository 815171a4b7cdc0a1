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
//! 4. Drivers' transforms and light states are checked by the session
//!    (role, object or light, pose or state, seq, rate), wait in the feed's
//!    inbox and are forwarded upstream by the upstream task, paced and
//!    coalesced per object and per light; the upstream's `Poses` and
//!    `Lights` go to the viewers that ask, and the relay announces
//!    `CAP_LIGHTS` while its upstream does.
//!
//! When an upstream goes away the feed keeps its newest publication: the
//! relay keeps serving the last version (and stays ready), reconnects with
//! backoff, and resyncs its viewers with a delta of exactly the tiles that
//! differ when the upstream is back.
//!
//! A viewer needs nothing from the solver that the relay does not serve:
//! the relay's routes are the solver's ([`crate::service::http::routes`],
//! on the relay's feeds) — the dashboard (`/`, `/dashboard/{*path}`),
//! `/healthz`, `/metrics`, `/api/scenes` (with the upstream's status per
//! scene), `/api/scenes/{id}`, the snapshots
//! `/api/scenes/{id}/lightmap.exr|png` and the lit `scene.glb` of the
//! version the relay holds (its number in `x-lightwire-version`, the
//! relay's own version; dynamic objects at the description's poses) and
//! `/ws/scenes/{id}` — with the same token and Origin rules, checked with
//! the relay's own tokens; only `/readyz` is the relay's own (ready once
//! every scene has a version, and still ready while an upstream is away).

pub mod metrics;
pub mod mirror;
pub mod upstream;

use std::collections::BTreeMap;
use std::sync::Arc;
use std::sync::atomic::Ordering;

use anyhow::{Result, bail};
use axum::Router;
use axum::extract::State;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use lightwire_protocol::Stats;
use serde_json::{Value, json};
use tokio::net::TcpListener;
use tokio::sync::watch;

use crate::service::feed::Feed;
use crate::service::http::{self, Scenes};
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
        let (stats_tx, stats_rx) = watch::channel(Stats::initial());
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
        .route("/readyz", get(readyz))
        .with_state(state.clone())
        .merge(http::routes(state));
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

impl Scenes for RelayState {
    fn shared(&self) -> &Arc<Shared> {
        &self.shared
    }

    fn feed(&self, id: &str) -> Option<&Arc<Feed>> {
        self.scenes.get(id).map(|s| &s.feed)
    }

    /// Per scene, besides what any server says: the relay version, the
    /// upstream version it equals, whether the upstream is connected, and
    /// why the upstream was last lost.
    fn list(&self) -> Vec<Value> {
        self.scenes
            .values()
            .map(|s| {
                let upstream_version = s.status.upstream_version.load(Ordering::Relaxed);
                let mut entry = http::feed_summary(&s.feed);
                entry.insert("upstream".into(), json!(s.url.url));
                entry.insert(
                    "connected".into(),
                    json!(s.status.connected.load(Ordering::Relaxed)),
                );
                entry.insert(
                    "connects".into(),
                    json!(s.status.connects.load(Ordering::Relaxed)),
                );
                entry.insert(
                    "last_error".into(),
                    json!(
                        *s.status
                            .last_error
                            .lock()
                            .unwrap_or_else(|p| p.into_inner())
                    ),
                );
                entry.insert("version".into(), json!(s.feed.latest().map(|p| p.version)));
                entry.insert(
                    "upstream_version".into(),
                    json!((upstream_version > 0).then_some(upstream_version)),
                );
                Value::Object(entry)
            })
            .collect()
    }

    fn unknown(&self, id: &str) -> String {
        format!("this relay does not relay scene \"{id}\"; GET /api/scenes lists what it does")
    }
}
