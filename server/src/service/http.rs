//! HTTP routes: health, readiness, metrics, the REST API, lightmap
//! snapshots and the lit scene as glTF (`scene.glb`), the WebSocket
//! upgrade, the dashboard and the three.js example (their embedded files
//! are in [`super::dashboard`]).
//!
//! Every route but `/readyz` is served by [`routes`] on anything that
//! implements [`Scenes`]: a solver's scenes ([`AppState`]) or a relay's
//! (`crate::relay`). Both are [`Feed`]s, so scene info, the snapshots and
//! the WebSocket answer the same way on both, from the version that
//! server holds. What needs the loaded scene ([`Scenes::geometry`]) is the
//! solver's alone: the `uv-lightmaps`, the `lights` (and so the lights and
//! sky in a solver's `scene.glb`; a relay's has none).
//!
//! Access (PROTOCOL.md §7, REST): the scene list, scene info and snapshots
//! need at least a viewer token, exactly as the WebSocket does, and refuse
//! a foreign browser `Origin` like the upgrade; [`request_token`] reads
//! the token for both. `/metrics` is open or needs an admin token
//! (`metrics` in [`super::config`]). `/healthz`, `/readyz` and the
//! dashboard's and the three.js example's files (no data in them) are open.

use std::collections::HashMap;
use std::io::Cursor;
use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::Ordering;

use axum::Router;
use axum::extract::{ConnectInfo, Path, Query, Request, State, WebSocketUpgrade};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use lightwire_protocol::Role;
use lightwire_protocol::lightmap::Lightmap;
use serde_json::{Value, json};

use super::config::MetricsAccess;
use super::dashboard;
use super::feed::Feed;
use super::session;
use super::{AppState, Shared};

/// The scenes a server serves, as the shared handlers see them.
pub trait Scenes: Send + Sync + 'static {
    /// What every session and handler shares.
    fn shared(&self) -> &Arc<Shared>;
    /// The feed of scene `id`, if this server serves it.
    fn feed(&self, id: &str) -> Option<&Arc<Feed>>;
    /// The entries of `GET /api/scenes`, in id order.
    fn list(&self) -> Vec<Value>;
    /// The 404 message for a scene id this server does not serve.
    fn unknown(&self, id: &str) -> String {
        format!("no scene \"{id}\"; GET /api/scenes lists them")
    }
    /// The scene and atlas of `id`, for what needs its geometry or its
    /// lights (the lightmaps in an asset's own UVs, `lights`, the lights in
    /// `scene.glb`); `None` on a relay, which holds only the description
    /// clients get.
    fn geometry(&self, _id: &str) -> Option<Arc<super::runtime::SceneRuntime>> {
        None
    }
}

impl Scenes for AppState {
    fn shared(&self) -> &Arc<Shared> {
        &self.shared
    }

    fn feed(&self, id: &str) -> Option<&Arc<Feed>> {
        self.scenes.get(id).map(|s| &s.feed)
    }

    fn geometry(&self, id: &str) -> Option<Arc<super::runtime::SceneRuntime>> {
        self.scenes.get(id).cloned()
    }

    fn list(&self) -> Vec<Value> {
        self.scenes
            .values()
            .map(|s| {
                let stats = *s.feed.stats.borrow();
                let mut entry = feed_summary(&s.feed);
                entry.insert("description".into(), json!(s.scene.description));
                entry.insert("elements".into(), json!(s.atlas.elements.len()));
                // How many lights `GET /api/scenes/{id}/lights` lists.
                entry.insert("lights".into(), json!(s.scene.lights.len()));
                entry.insert("version".into(), json!(stats.version));
                entry.insert("unshot_fraction".into(), json!(stats.unshot_fraction));
                Value::Object(entry)
            })
            .collect()
    }
}

/// What `GET /api/scenes` says of any feed: id, readiness, clients, and
/// (once known) the atlas size and the dynamic objects' names.
pub fn feed_summary(feed: &Feed) -> serde_json::Map<String, Value> {
    let mut entry = serde_json::Map::new();
    entry.insert("id".into(), json!(feed.id));
    if let Some(info) = feed.info() {
        entry.insert(
            "atlas".into(),
            json!({ "width": info.atlas_width, "height": info.atlas_height }),
        );
        let dynamic: Vec<&String> = info
            .objects
            .iter()
            .filter(|o| o.dynamic)
            .map(|o| &o.name)
            .collect();
        entry.insert("objects".into(), json!(dynamic));
    }
    entry.insert("ready".into(), json!(feed.ready.load(Ordering::Acquire)));
    entry.insert(
        "clients".into(),
        json!(feed.clients.load(Ordering::Relaxed)),
    );
    entry
}

/// `lightwire serve`'s router: [`routes`] and the solver's `/readyz`.
pub fn router(state: Arc<AppState>) -> Router {
    Router::new()
        .route("/readyz", get(readyz))
        .with_state(state.clone())
        .merge(routes(state))
}

/// Every route a solver and a relay share: the dashboard, `/healthz`,
/// `/metrics`, the REST API, the snapshots and the WebSocket.
pub fn routes<S: Scenes>(scenes: Arc<S>) -> Router {
    let shared = scenes.shared().clone();
    let api = Router::new()
        .route("/api/scenes", get(list_scenes::<S>))
        .route("/api/scenes/{id}", get(scene_info::<S>))
        .route("/api/scenes/{id}/{file}", get(lightmap_file::<S>))
        .route(
            "/api/scenes/{id}/uv-lightmaps/{file}",
            get(uv_lightmap_file::<S>),
        )
        .route_layer(middleware::from_fn_with_state(
            (shared.clone(), Role::Viewer),
            require,
        ));
    let mut metrics_route = Router::new().route("/metrics", get(metrics));
    if shared.config.metrics == MetricsAccess::Token {
        metrics_route = metrics_route.route_layer(middleware::from_fn_with_state(
            (shared.clone(), Role::Admin),
            require,
        ));
    }
    Router::new()
        .route("/", get(dashboard::index))
        .route("/dashboard/{*path}", get(dashboard::file))
        .route("/examples/threejs", get(dashboard::example_index))
        .route("/examples/threejs/", get(dashboard::example_index))
        .route("/examples/threejs/{*path}", get(dashboard::example))
        .route("/healthz", get(|| async { "ok\n" }))
        .route("/ws/scenes/{id}", get(websocket::<S>))
        .merge(api)
        .with_state(scenes)
        .merge(metrics_route.with_state(shared))
}

fn json_error(status: StatusCode, message: String) -> Response {
    (status, axum::Json(json!({ "error": message }))).into_response()
}

fn not_found(what: String) -> Response {
    json_error(StatusCode::NOT_FOUND, what)
}

/// The token a request presents: `Authorization: Bearer <token>`, else
/// `?token=<token>`. The WebSocket upgrade and the REST routes read it
/// the same way (a `Hello.token` then overrides it on the WebSocket).
pub fn request_token(headers: &HeaderMap, query: &HashMap<String, String>) -> Option<String> {
    headers
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| {
            let (scheme, token) = v.split_once(' ')?;
            scheme.eq_ignore_ascii_case("bearer").then(|| token.trim())
        })
        .filter(|t| !t.is_empty())
        .map(str::to_string)
        .or_else(|| query.get("token").cloned())
}

/// Whether `role` includes `needed` (admin ⊃ driver ⊃ viewer).
fn includes(role: Role, needed: Role) -> bool {
    let rank = |r: Role| match r {
        Role::Viewer => 0,
        Role::Driver => 1,
        Role::Admin => 2,
    };
    rank(role) >= rank(needed)
}

/// Checks a REST request: the browser origin (403), then that its token
/// grants at least `needed` (401, or 403 for a known token with too small
/// a role). In development mode without tokens every request is an admin.
fn authorize(shared: &Shared, request: &Request, needed: Role) -> Result<(), Box<Response>> {
    let headers = request.headers();
    if !origin_allowed(shared, headers) {
        let origin = headers
            .get(header::ORIGIN)
            .map(|o| String::from_utf8_lossy(o.as_bytes()).into_owned())
            .unwrap_or_default();
        return Err(Box::new(json_error(
            StatusCode::FORBIDDEN,
            format!(
                "origin {origin:?} is not allowed; the server's own origin and `allowed_origins` are"
            ),
        )));
    }
    let query = Query::<HashMap<String, String>>::try_from_uri(request.uri())
        .map(|q| q.0)
        .unwrap_or_default();
    let token = request_token(headers, &query);
    let needs = match needed {
        Role::Viewer => "a viewer, driver or admin token",
        Role::Driver => "a driver or admin token",
        Role::Admin => "an admin token",
    };
    match shared.auth.role(token.as_deref()) {
        Some(role) if includes(role, needed) => Ok(()),
        Some(role) => Err(Box::new(json_error(
            StatusCode::FORBIDDEN,
            format!("this endpoint needs {needs}; yours grants the {role:?} role"),
        ))),
        None => {
            let what = if token.is_some() {
                "unknown token"
            } else {
                "missing token"
            };
            let mut response = json_error(
                StatusCode::UNAUTHORIZED,
                format!(
                    "{what}: this endpoint needs {needs}, as `Authorization: Bearer <token>` or `?token=<token>`"
                ),
            );
            response.headers_mut().insert(
                header::WWW_AUTHENTICATE,
                HeaderValue::from_static("Bearer realm=\"lightwire\""),
            );
            Err(Box::new(response))
        }
    }
}

/// Middleware that lets a request on only with the state's role
/// ([`authorize`]).
async fn require(
    State((shared, role)): State<(Arc<Shared>, Role)>,
    request: Request,
    next: Next,
) -> Response {
    match authorize(&shared, &request, role) {
        Ok(()) => next.run(request).await,
        Err(refused) => *refused,
    }
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

async fn metrics(State(shared): State<Arc<Shared>>) -> Response {
    (
        [(
            header::CONTENT_TYPE,
            "application/openmetrics-text; version=1.0.0; charset=utf-8",
        )],
        shared.metrics.render(),
    )
        .into_response()
}

async fn list_scenes<S: Scenes>(State(scenes): State<Arc<S>>) -> Response {
    axum::Json(scenes.list()).into_response()
}

/// The feed of `id`, or the 404 to answer.
fn feed_of<S: Scenes>(scenes: &S, id: &str) -> Result<Arc<Feed>, Box<Response>> {
    scenes
        .feed(id)
        .cloned()
        .ok_or_else(|| Box::new(not_found(scenes.unknown(id))))
}

/// 503 for a scene whose description is not known yet (a relay that has
/// not reached its upstream): clients retry.
fn not_available(id: &str) -> Response {
    json_error(
        StatusCode::SERVICE_UNAVAILABLE,
        format!("scene \"{id}\" is not available yet; retry"),
    )
}

async fn scene_info<S: Scenes>(State(scenes): State<Arc<S>>, Path(id): Path<String>) -> Response {
    let feed = match feed_of(&*scenes, &id) {
        Ok(feed) => feed,
        Err(r) => return *r,
    };
    // What a `Welcome` would carry now: the lights in the states the
    // newest version was lit with.
    match feed.info() {
        Some(info) => match feed.latest().filter(|p| Arc::ptr_eq(&p.scene, &info)) {
            Some(p) => axum::Json(super::wire::lit_info(&info, &p.lights)).into_response(),
            None => axum::Json(&*info).into_response(),
        },
        None => not_available(&id),
    }
}

/// One version of a scene's lightmap, decoded.
struct Snapshot {
    /// The description the lightmap was decoded for.
    info: Arc<lightwire_protocol::SceneInfo>,
    /// The dynamic objects' poses the version was lit for (empty when
    /// unknown: a relay whose upstream sends none).
    poses: Arc<[lightwire_protocol::ObjectPose]>,
    /// The lights' states the version was lit with (empty when unknown:
    /// a relay whose upstream sends none).
    lights: Arc<[lightwire_protocol::LightStatus]>,
    width: u32,
    height: u32,
    version: u64,
    rgb: Vec<[f32; 3]>,
}

/// Decodes the feed's newest publication to linear RGB, exactly what a
/// client of this server holds.
fn current_rgb(feed: &Feed) -> Result<Snapshot, String> {
    let info = feed.info().ok_or("the scene is not available yet")?;
    let p = feed.latest().ok_or("no lightmap published yet")?;
    let mut map = Lightmap::new(
        info.atlas_width,
        info.atlas_height,
        info.tile_size,
        info.format,
    );
    // Only a relay whose upstream just changed the scene's description
    // can hold a publication of the old one; its next one will fit.
    map.apply_keyframe(&p.keyframe).map_err(|e| {
        format!("the newest lightmap does not fit the scene's description yet ({e}); retry")
    })?;
    Ok(Snapshot {
        info,
        poses: p.poses.clone(),
        lights: p.lights.clone(),
        width: map.width,
        height: map.height,
        version: p.version,
        rgb: map.to_rgb(),
    })
}

async fn lightmap_file<S: Scenes>(
    State(scenes): State<Arc<S>>,
    Path((id, file)): Path<(String, String)>,
) -> Response {
    let feed = match feed_of(&*scenes, &id) {
        Ok(feed) => feed,
        Err(r) => return *r,
    };
    if file == crate::bake::UV_LIGHTMAPS {
        return uv_lightmap_list(&*scenes, &id);
    }
    if file == LIGHTS {
        return light_list(&*scenes, &id);
    }
    // The file and its media type.
    let (format, mime) = match file.as_str() {
        "lightmap.exr" => (Some(image::ImageFormat::OpenExr), "image/x-exr"),
        "lightmap.png" => (Some(image::ImageFormat::Png), "image/png"),
        // The scene with this version's lightmap on it
        // (`bake::scene_glb_lit`).
        crate::bake::SCENE_GLB => (None, "model/gltf-binary"),
        _ => {
            return not_found(format!(
                "no file \"{file}\"; try lightmap.exr, lightmap.png, scene.glb, uv-lightmaps or lights"
            ));
        }
    };
    // The scene's lights and sky go into `scene.glb` as `bake` writes
    // them; a relay holds none (only the description clients get).
    let runtime = format.is_none().then(|| scenes.geometry(&id)).flatten();
    let encoded = tokio::task::spawn_blocking(move || -> Result<(u64, Vec<u8>), String> {
        let Snapshot {
            info,
            poses,
            lights,
            width: w,
            height: h,
            version,
            rgb,
        } = current_rgb(&feed)?;
        let Some(format) = format else {
            // The dynamic objects where this version's light has them,
            // not at the scene file's poses.
            let mut posed = (*info).clone();
            for p in poses.iter() {
                if let Some(o) = posed.objects.get_mut(p.object as usize) {
                    o.pose = p.pose;
                }
            }
            // The lights as this version was lit with them (the states
            // `SetLight`s gave them), not as the scene file has them.
            // A light riding with a dynamic object where this version's
            // pose of the object puts it.
            let (now, sky) = match &runtime {
                Some(r) => {
                    let mut at = r.scene.initial_poses();
                    for p in poses.iter() {
                        if let Some(pose) = at.get_mut(p.object as usize) {
                            *pose = super::wire::from_wire(&p.pose);
                        }
                    }
                    let states = super::wire::lights_now(&r.scene.lights, &lights);
                    (r.scene.lights_at(&states, &at), r.scene.sky.as_ref())
                }
                None => (Vec::new(), None),
            };
            let glb = crate::bake::scene_glb_lit(&posed, &rgb, Some(version), (&now, sky))
                .map_err(|e| format!("{e:#}"))?;
            return Ok((version, glb));
        };
        let white = crate::bake::white_point(&rgb);
        Ok((version, encode_image(&rgb, w, h, format, white)?))
    })
    .await;
    versioned(encoded, mime)
}

/// Linear RGB as OpenEXR (f32), or as a PNG tone-mapped with white point
/// `white` (the one tone curve).
fn encode_image(
    rgb: &[[f32; 3]],
    w: u32,
    h: u32,
    format: image::ImageFormat,
    white: f32,
) -> Result<Vec<u8>, String> {
    let image = match format {
        image::ImageFormat::OpenExr => {
            let flat: Vec<f32> = rgb.iter().flatten().copied().collect();
            image::DynamicImage::ImageRgb32F(
                image::ImageBuffer::from_raw(w, h, flat).ok_or("bad image size")?,
            )
        }
        _ => image::DynamicImage::ImageRgb8(
            image::ImageBuffer::from_raw(
                w,
                h,
                lightwire_protocol::tone::tone_map_image(rgb, white),
            )
            .ok_or("bad image size")?,
        ),
    };
    let mut out = Cursor::new(Vec::new());
    image
        .write_to(&mut out, format)
        .map_err(|e| e.to_string())?;
    Ok(out.into_inner())
}

/// A snapshot's answer: the bytes with their media type and version, 503
/// with the reason when there is none yet.
fn versioned(
    encoded: Result<Result<(u64, Vec<u8>), String>, tokio::task::JoinError>,
    mime: &str,
) -> Response {
    match encoded {
        Ok(Ok((version, bytes))) => (
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
            .into_response(),
        Ok(Err(why)) => json_error(StatusCode::SERVICE_UNAVAILABLE, why),
        Err(_) => (StatusCode::INTERNAL_SERVER_ERROR, "encoding failed").into_response(),
    }
}

/// The scene's geometry for the lightmaps in an asset's own UVs, or the
/// 404 a relay (or a scene without such meshes) answers.
type Geometry = (Arc<Feed>, Arc<super::runtime::SceneRuntime>);

fn uv_geometry<S: Scenes>(scenes: &S, id: &str) -> Result<Geometry, Box<Response>> {
    let feed = feed_of(scenes, id)?;
    let Some(runtime) = scenes.geometry(id) else {
        return Err(Box::new(not_found(format!(
            "this server holds no geometry of \"{id}\" (a relay): ask the solver for its uv-lightmaps"
        ))));
    };
    Ok((feed, runtime))
}

/// `GET /api/scenes/{id}/uv-lightmaps`: the glTF meshes with their own
/// lightmap UVs and where their lightmaps are (relative to the scene's
/// URL), as `lightwire bake` lists them in `atlas.json`.
fn uv_lightmap_list<S: Scenes>(scenes: &S, id: &str) -> Response {
    let runtime = match uv_geometry(scenes, id) {
        Ok((_, r)) => r,
        Err(r) => return *r,
    };
    let scene = &runtime.scene;
    let list: Vec<Value> = scene
        .uv_meshes
        .iter()
        .enumerate()
        .filter(|(_, mesh)| !mesh.generated)
        .map(|(k, mesh)| {
            let stem = crate::bake::uv_lightmap_stem(k, &mesh.name);
            let size = lightwire_scene::uvmap::default_size(scene, mesh);
            json!({
                "mesh": mesh.name,
                "object": scene.objects[mesh.object as usize].name,
                "exr": format!("{}/{stem}.exr", crate::bake::UV_LIGHTMAPS),
                "png": format!("{}/{stem}.png", crate::bake::UV_LIGHTMAPS),
                "width": size,
                "height": size,
            })
        })
        .collect();
    axum::Json(json!({ "uv_lightmaps": list })).into_response()
}

/// `GET /api/scenes/{id}/uv-lightmaps/NN-node_mesh.exr|png`: mesh `NN`'s
/// lightmap in its own UVs (`uvmap::resample`) from the newest version,
/// as `lightwire bake` writes it; `x-lightwire-version` as the snapshots.
async fn uv_lightmap_file<S: Scenes>(
    State(scenes): State<Arc<S>>,
    Path((id, file)): Path<(String, String)>,
) -> Response {
    let (feed, runtime) = match uv_geometry(&*scenes, &id) {
        Ok(g) => g,
        Err(r) => return *r,
    };
    let (stem, extension) = file.rsplit_once('.').unwrap_or((file.as_str(), ""));
    let index =
        stem.split_once('-')
            .and_then(|(k, _)| k.parse::<usize>().ok())
            .filter(|&k| {
                runtime.scene.uv_meshes.get(k).is_some_and(|m| {
                    !m.generated && crate::bake::uv_lightmap_stem(k, &m.name) == stem
                })
            });
    let (Some(k), Some((format, mime))) = (
        index,
        match extension {
            "exr" => Some((image::ImageFormat::OpenExr, "image/x-exr")),
            "png" => Some((image::ImageFormat::Png, "image/png")),
            _ => None,
        },
    ) else {
        return not_found(format!(
            "no uv-lightmap \"{file}\"; GET /api/scenes/{id}/uv-lightmaps lists them"
        ));
    };
    let encoded = tokio::task::spawn_blocking(move || -> Result<(u64, Vec<u8>), String> {
        let snapshot = current_rgb(&feed)?;
        let scene = &runtime.scene;
        let mesh = &scene.uv_meshes[k];
        let locator = lightwire_scene::uvmap::Locator::new(&scene.patches);
        let size = lightwire_scene::uvmap::default_size(scene, mesh);
        let map =
            lightwire_scene::uvmap::resample(&locator, &runtime.atlas, &snapshot.rgb, mesh, size);
        // A PNG at the atlas's exposure, as `lightmap.png` and bake.
        let white = crate::bake::white_point(&snapshot.rgb);
        let bytes = encode_image(&map.pixels, map.width, map.height, format, white)?;
        Ok((snapshot.version, bytes))
    })
    .await;
    versioned(encoded, mime)
}

/// The last segment of `GET /api/scenes/{id}/lights`.
pub const LIGHTS: &str = "lights";

/// `GET /api/scenes/{id}/lights`: the scene's point, spot and directional
/// lights, in the states the newest version was lit with, and its sky, as
/// a scene file gives them (`super::lights`); 404 on a relay, which holds
/// only the description clients get.
fn light_list<S: Scenes>(scenes: &S, id: &str) -> Response {
    if let Err(r) = feed_of(scenes, id) {
        return *r;
    }
    match scenes.geometry(id) {
        Some(runtime) => {
            let lit = runtime
                .latest()
                .map(|p| p.lights.clone())
                .unwrap_or_default();
            axum::Json(super::lights::lights_as_lit(&runtime.scene, &lit)).into_response()
        }
        None => not_found(format!(
            "this server holds no lights of \"{id}\" (a relay): ask the solver for them"
        )),
    }
}

/// Whether a browser `Origin` may use this server (the WebSocket upgrade
/// and the REST routes).
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

async fn websocket<S: Scenes>(
    State(scenes): State<Arc<S>>,
    Path(id): Path<String>,
    Query(query): Query<HashMap<String, String>>,
    ConnectInfo(peer): ConnectInfo<SocketAddr>,
    headers: HeaderMap,
    upgrade: WebSocketUpgrade,
) -> Response {
    let feed = match feed_of(&*scenes, &id) {
        Ok(feed) => feed,
        Err(r) => return *r,
    };
    tracing::debug!(%peer, scene = %id, "websocket upgrade");
    upgrade_websocket(scenes.shared().clone(), feed, &headers, &query, upgrade)
}

/// Upgrades a request for `feed`'s WebSocket into a [`session`], after the
/// checks every server (solver or relay) makes: the browser origin, and
/// that the scene's description is known (a relay that has not reached its
/// upstream yet answers 503, so clients retry). The token may come on the
/// upgrade ([`request_token`]); `Hello.token` wins.
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
        return not_available(&feed.id);
    }
    let token = request_token(headers, query);
    let max = shared.config.max_message_bytes;
    upgrade
        .max_message_size(max)
        .max_frame_size(max)
        .on_upgrade(move |socket| session::run(socket, shared, feed, token))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn headers(authorization: Option<&str>) -> HeaderMap {
        let mut h = HeaderMap::new();
        if let Some(a) = authorization {
            h.insert(
                header::AUTHORIZATION,
                HeaderValue::from_str(a).expect("valid header"),
            );
        }
        h
    }

    #[test]
    fn the_bearer_header_wins_over_the_query_and_other_schemes_fall_back() {
        let query: HashMap<String, String> =
            [("token".to_string(), "from-query".to_string())].into();
        let none = HashMap::new();
        assert_eq!(
            request_token(&headers(Some("Bearer from-header")), &query).as_deref(),
            Some("from-header")
        );
        assert_eq!(
            request_token(&headers(Some("bearer  spaced ")), &none).as_deref(),
            Some("spaced"),
            "the scheme is case-insensitive"
        );
        assert_eq!(
            request_token(&headers(Some("Basic dXNlcjpwdw==")), &query).as_deref(),
            Some("from-query")
        );
        assert_eq!(
            request_token(&headers(Some("Bearer ")), &query).as_deref(),
            Some("from-query")
        );
        assert_eq!(request_token(&headers(None), &none), None);
    }

    #[test]
    fn roles_include_the_smaller_ones() {
        assert!(includes(Role::Admin, Role::Viewer));
        assert!(includes(Role::Driver, Role::Viewer));
        assert!(includes(Role::Viewer, Role::Viewer));
        assert!(!includes(Role::Viewer, Role::Admin));
        assert!(!includes(Role::Driver, Role::Admin));
    }
}
