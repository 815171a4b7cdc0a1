//! HTTP routes: health, readiness, metrics, the REST API, lightmap
//! snapshots, the WebSocket upgrade and the dashboard (its embedded files
//! are in [`super::dashboard`]).

use std::collections::HashMap;
use std::io::Cursor;
use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::Ordering;

use axum::Router;
use axum::extract::{ConnectInfo, Path, Query, State, WebSocketUpgrade};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use lightwire_protocol::lightmap::Lightmap;
use serde_json::json;

use super::dashboard;
use super::feed::Feed;
use super::runtime::SceneRuntime;
use super::session;
use super::{AppState, Shared};

/// Builds the router.
pub fn router(state: Arc<AppState>) -> Router {
    Router::new()
        .route("/", get(dashboard::index))
        .route("/dashboard/{*path}", get(dashboard::file))
        .route("/healthz", get(|| async { "ok\n" }))
        .route("/readyz", get(readyz))
        .route("/metrics", get(metrics))
        .route("/api/scenes", get(list_scenes))
        .route("/api/scenes/{id}", get(scene_info))
        .route("/api/scenes/{id}/{file}", get(lightmap_file))
        .route("/ws/scenes/{id}", get(websocket))
        .with_state(state)
}

fn not_found(what: String) -> Response {
    (StatusCode::NOT_FOUND, axum::Json(json!({ "error": what }))).into_response()
}

fn scene<'a>(state: &'a AppState, id: &str) -> Result<&'a Arc<SceneRuntime>, Box<Response>> {
    state.scenes.get(id).ok_or_else(|| {
        Box::new(not_found(format!(
            "no scene \"{id}\"; GET /api/scenes lists them"
        )))
    })
}

async fn readyz(State(state): State<Arc<AppState>>) -> Response {
    // 200 when every scene serves versions; otherwise 503 with the scenes
    // still solving their first version and those whose solver failed
    // (with why and since when; they still serve their last version).
    use super::feed::Health;
    let mut solving = Vec::new();
    let mut failed = Vec::new();
    for (id, s) in &state.scenes {
        match s.feed.health() {
            Health::Ready => {}
            Health::Solving => solving.push(id),
            Health::Failed(f) => failed.push(json!({
                "scene": id,
                "reason": f.reason,
                "since_unix_ms": f.since_unix_ms,
                "rebuild_attempts": f.rebuild_attempts,
            })),
        }
    }
    if solving.is_empty() && failed.is_empty() {
        (StatusCode::OK, "ready\n").into_response()
    } else {
        (
            StatusCode::SERVICE_UNAVAILABLE,
            axum::Json(json!({ "ready": false, "solving": solving, "failed": failed })),
        )
            .into_response()
    }
}

async fn metrics(State(state): State<Arc<AppState>>) -> Response {
    (
        [(
            header::CONTENT_TYPE,
            "application/openmetrics-text; version=1.0.0; charset=utf-8",
        )],
        state.shared.metrics.render(),
    )
        .into_response()
}

async fn list_scenes(State(state): State<Arc<AppState>>) -> Response {
    let scenes: Vec<_> = state
        .scenes
        .values()
        .map(|s| {
            let stats = *s.feed.stats.borrow();
            json!({
                "id": s.info.id,
                "description": s.scene.description,
                "elements": s.atlas.elements.len(),
                "atlas": { "width": s.info.atlas_width, "height": s.info.atlas_height },
                "objects": s.info.objects.iter().filter(|o| o.dynamic).map(|o| &o.name).collect::<Vec<_>>(),
                "ready": s.feed.ready.load(Ordering::Acquire),
                "version": stats.version,
                "unshot_fraction": stats.unshot_fraction,
                "clients": s.feed.clients.load(Ordering::Relaxed),
            })
        })
        .collect();
    axum::Json(scenes).into_response()
}

async fn scene_info(State(state): State<Arc<AppState>>, Path(id): Path<String>) -> Response {
    match scene(&state, &id) {
        Ok(s) => axum::Json(&*s.info).into_response(),
        Err(r) => *r,
    }
}

/// Decodes the current publication to linear RGB, exactly what a client
/// holds.
fn current_rgb(s: &SceneRuntime) -> Option<(u32, u32, u64, Vec<[f32; 3]>)> {
    let p = s.latest()?;
    let mut map = Lightmap::new(
        s.info.atlas_width,
        s.info.atlas_height,
        s.info.tile_size,
        s.info.format,
    );
    map.apply_keyframe(&p.keyframe).ok()?;
    Some((map.width, map.height, p.version, map.to_rgb()))
}

async fn lightmap_file(
    State(state): State<Arc<AppState>>,
    Path((id, file)): Path<(String, String)>,
) -> Response {
    let s = match scene(&state, &id) {
        Ok(s) => s.clone(),
        Err(r) => return *r,
    };
    let format = match file.as_str() {
        "lightmap.exr" => image::ImageFormat::OpenExr,
        "lightmap.png" => image::ImageFormat::Png,
        _ => {
            return not_found(format!(
                "no file \"{file}\"; try lightmap.exr or lightmap.png"
            ));
        }
    };
    let encoded = tokio::task::spawn_blocking(move || -> Result<(u64, Vec<u8>), String> {
        let (w, h, version, rgb) = current_rgb(&s).ok_or("no lightmap published yet")?;
        let mut out = Cursor::new(Vec::new());
        let image = match format {
            image::ImageFormat::OpenExr => {
                let flat: Vec<f32> = rgb.iter().flatten().copied().collect();
                image::DynamicImage::ImageRgb32F(
                    image::ImageBuffer::from_raw(w, h, flat).ok_or("bad image size")?,
                )
            }
            _ => image::DynamicImage::ImageRgb8(
                image::ImageBuffer::from_raw(w, h, crate::bake::tone_map(&rgb))
                    .ok_or("bad image size")?,
            ),
        };
        image
            .write_to(&mut out, format)
            .map_err(|e| e.to_string())?;
        Ok((version, out.into_inner()))
    })
    .await;
    match encoded {
        Ok(Ok((version, bytes))) => {
            let mime = if file.ends_with(".exr") {
                "image/x-exr"
            } else {
                "image/png"
            };
            (
                [
                    (header::CONTENT_TYPE, mime.to_string()),
                    (
                        header::HeaderName::from_static("x-lightwire-version"),
                        version.to_string(),
                    ),
                    (header::CACHE_CONTROL, "no-store".to_string()),
                ],
                bytes,
            )
                .into_response()
        }
        Ok(Err(why)) => (
            StatusCode::SERVICE_UNAVAILABLE,
            axum::Json(json!({ "error": why })),
        )
            .into_response(),
        Err(_) => (StatusCode::INTERNAL_SERVER_ERROR, "encoding failed").into_response(),
    }
}

/// Whether a browser `Origin` may open a WebSocket here.
fn origin_allowed(state: &Shared, headers: &HeaderMap) -> bool {
    let Some(origin) = headers.get(header::ORIGIN) else {
        return true; // not a browser
    };
    let Ok(origin) = origin.to_str() else {
        return false;
    };
    let port = state.config.listen.port();
    let own = [
        format!("http://{}", state.config.listen),
        format!("http://localhost:{port}"),
        format!("http://127.0.0.1:{port}"),
    ];
    if let Some(host) = headers.get(header::HOST).and_then(|h| h.to_str().ok()) {
        if origin == format!("http://{host}") || origin == format!("https://{host}") {
            return true;
        }
    }
    own.iter().any(|o| o == origin) || state.config.allowed_origins.iter().any(|o| o == origin)
}

async fn websocket(
    State(state): State<Arc<AppState>>,
    Path(id): Path<String>,
    Query(query): Query<HashMap<String, String>>,
    ConnectInfo(peer): ConnectInfo<SocketAddr>,
    headers: HeaderMap,
    upgrade: WebSocketUpgrade,
) -> Response {
    let s = match scene(&state, &id) {
        Ok(s) => s.clone(),
        Err(r) => return *r,
    };
    tracing::debug!(%peer, scene = %id, "websocket upgrade");
    upgrade_websocket(
        state.shared.clone(),
        s.feed.clone(),
        &headers,
        &query,
        upgrade,
    )
}

/// Upgrades a request for `feed`'s WebSocket into a [`session`], after the
/// checks every server (solver or relay) makes: the browser origin, and
/// that the scene's description is known (a relay that has not reached its
/// upstream yet answers 503, so clients retry). The token may come on the
/// upgrade (`Authorization: Bearer`, `?token=`); `Hello.token` wins.
pub fn upgrade_websocket(
    shared: Arc<Shared>,
    feed: Arc<Feed>,
    headers: &HeaderMap,
    query: &HashMap<String, String>,
    upgrade: WebSocketUpgrade,
) -> Response {
    if !origin_allowed(&shared, headers) {
        shared.metrics.bad_frame("origin");
        return (StatusCode::FORBIDDEN, "origin not allowed\n").into_response();
    }
    if feed.info().is_none() {
        return (
            StatusCode::SERVICE_UNAVAILABLE,
            axum::Json(json!({
                "error": format!("scene \"{}\" is not available yet; retry", feed.id)
            })),
        )
            .into_response();
    }
    let token = headers
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.strip_prefix("Bearer "))
        .map(str::to_string)
        .or_else(|| query.get("token").cloned());
    let max = shared.config.max_message_bytes;
    upgrade
        .max_message_size(max)
        .max_frame_size(max)
        .on_upgrade(move |socket| session::run(socket, shared, feed, token))
}
