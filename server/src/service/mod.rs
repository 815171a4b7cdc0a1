//! The streaming service: `lightwire serve`.
//!
//! Data flow, one way:
//!
//! 1. [`session`] tasks (one per WebSocket) decode client frames. A driver's
//!    `Transform` is checked ([`wire`]) and stored in its scene's
//!    [`inbox::Inbox`]: one slot per dynamic object, the latest `seq` wins,
//!    so the inbox can never grow.
//! 2. Each scene has a tick thread ([`runtime`]) that owns the solver. Every
//!    tick it drains the inbox, converts new poses ([`wire`]) and hands them
//!    to the solver ([`live::LiveSolver`]) with a tag, the seqs they carry,
//!    which the solver returns with the state that reflects them (solvers
//!    know nothing of seqs or the wire), runs solver work within the tick
//!    budget, and when the solver has a complete state it quantizes and
//!    encodes it once ([`lightwire_protocol::lightmap::Encoder`]) into a
//!    [`publication::Publication`] that echoes those seqs.
//! 3. Publications go out through a `tokio::sync::watch` channel, which
//!    holds only the newest one. Each session's writer sends the delta if
//!    the client holds exactly its base version, a merged delta if it is a
//!    few versions behind, otherwise a keyframe. A client that reads slowly
//!    therefore skips versions instead of queueing them: per-client memory
//!    is one publication reference plus the socket buffer, whatever the
//!    client does.
//!
//! 4. When a solver fails (lost GPU device, GPU error, panic), its step
//!    says so ([`live::SolverFailure`]) and the tick thread marks its feed
//!    failed (`/readyz` 503 with the scene and the reason), keeps the last
//!    publication for sessions, and rebuilds the solver with backoff at the
//!    current poses ([`runtime`]).
//!
//! Sessions see a scene only as a [`feed::Feed`] (description, inbox,
//! publications, stats), which is how `lightwire relay` (`crate::relay`)
//! serves its copy of a solver's scene with the same session code.
//!
//! [`http`] serves the REST endpoints, metrics and the WebSocket upgrade;
//! [`dashboard`] the web dashboard's files, embedded in the binary;
//! [`config`] merges the config file, flags and environment; [`auth`] maps
//! tokens to roles; [`wire`] is where protocol types become scene types and
//! back.

pub mod auth;
pub mod config;
pub mod dashboard;
pub mod feed;
pub mod http;
pub mod inbox;
pub mod lights;
pub mod live;
pub mod metrics;
pub mod publication;
pub mod runtime;
pub mod session;
pub mod wire;

use std::collections::BTreeMap;
use std::sync::Arc;

use anyhow::{Context, Result};
use tokio::net::TcpListener;
use tokio::sync::watch;

pub use config::Config;

/// What every session shares, on a solver (`serve`) or a relay.
pub struct Shared {
    pub config: Config,
    pub metrics: Arc<metrics::Metrics>,
    pub auth: auth::Auth,
    /// Flips to `true` when the server begins a graceful shutdown.
    pub shutdown: watch::Receiver<bool>,
}

/// Everything the HTTP handlers of `lightwire serve` share.
pub struct AppState {
    pub shared: Arc<Shared>,
    pub scenes: BTreeMap<String, Arc<runtime::SceneRuntime>>,
}

/// Loads every scene, starts its tick thread, and serves HTTP until
/// `shutdown` flips. Returns after the tick threads have finished their
/// current tick and every session has sent its close frame.
pub async fn serve(
    config: Config,
    listener: TcpListener,
    shutdown: watch::Receiver<bool>,
) -> Result<()> {
    let metrics = Arc::new(metrics::Metrics::new());
    let auth = auth::Auth::from_config(&config)?;
    let mut scenes = BTreeMap::new();
    for path in &config.scenes {
        let runtime =
            runtime::SceneRuntime::start(path, &config, metrics.clone(), shutdown.clone())
                .with_context(|| format!("starting scene {}", path.display()))?;
        let id = runtime.info.id.clone();
        if scenes.insert(id.clone(), runtime).is_some() {
            anyhow::bail!("two scene files are both named \"{id}\"; scene names must be unique");
        }
    }
    let state = Arc::new(AppState {
        shared: Arc::new(Shared {
            config,
            metrics,
            auth,
            shutdown: shutdown.clone(),
        }),
        scenes,
    });
    let app = http::router(state.clone());
    let mut stop = shutdown.clone();
    serve_http(
        listener,
        app,
        state.shared.config.socket_send_buffer,
        async move {
            let _ = stop.wait_for(|s| *s).await;
        },
    )
    .await?;
    for runtime in state.scenes.values() {
        runtime.join();
    }
    Ok(())
}

/// Serves `app` on `listener` until `stop` resolves; shared by `serve` and
/// `relay`. Every accepted socket gets `TCP_NODELAY` (frames are latency
/// bound) and, if `send_buffer > 0`, that `SO_SNDBUF`: a client that stops
/// reading then holds at most this much in the kernel, and the server
/// notices it is slow (and skips it forward) sooner.
pub async fn serve_http(
    listener: TcpListener,
    app: axum::Router,
    send_buffer: usize,
    stop: impl std::future::Future<Output = ()> + Send + 'static,
) -> Result<()> {
    let listener =
        axum::serve::ListenerExt::tap_io(listener, move |tcp: &mut tokio::net::TcpStream| {
            let _ = tcp.set_nodelay(true);
            if send_buffer > 0 {
                if let Err(e) = socket2::SockRef::from(&*tcp).set_send_buffer_size(send_buffer) {
                    tracing::warn!("cannot set SO_SNDBUF to {send_buffer}: {e}");
                }
            }
        });
    axum::serve(
        listener,
        app.into_make_service_with_connect_info::<std::net::SocketAddr>(),
    )
    .with_graceful_shutdown(stop)
    .await
    .context("HTTP server failed")
}
