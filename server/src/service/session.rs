//! One WebSocket connection.
//!
//! Order on the wire: the client sends `Hello` (within the hello timeout);
//! the server answers `Welcome`, then a `Keyframe` as soon as a version
//! exists, then a `Delta` per version for as long as the client keeps up.
//! The `Welcome` tells the lights' states of the newest publication, and
//! that publication's lightmap is the first the client gets, so what a
//! newcomer is told is what its first lightmap shows (PROTOCOL.md §3).
//!
//! Two halves run concurrently:
//!
//! - the **reader** decodes client frames, checks them (role, object and
//!   pose through [`super::wire::check_transform`], rate, seq) and hands
//!   accepted poses to the scene's inbox;
//!   anything invalid earns an `Error` frame with a code, and after
//!   `max_bad_frames` of those the connection is closed (1008), the
//!   reader then draining what the client still sends until it answers
//!   the Close (at most `LINGER` after the writer is done); a frame
//!   over `max_message_bytes` earns `Error TooLarge` and close 1009;
//! - the **writer** owns the socket's sink. It waits for the newest
//!   publication and sends the delta if the client holds exactly its base,
//!   a merged delta if it holds one of the few versions before that, else
//!   a keyframe ([`Publication::frame_for`]), preceded by the version's
//!   `Poses` when the client's `Hello` asked for them and they differ from
//!   those it last got. While a send is blocked on a
//!   slow client, newer publications simply replace older ones in the
//!   watch channel, so nothing queues. Control frames from the reader
//!   (errors, pongs) go through a small bounded channel; when it is full
//!   the reader waits, so a client flooding bad frames is slowed to the
//!   pace it reads its replies, and every refusal's `Error` arrives, in
//!   order, before any close.
//!
//! A session serves a [`Feed`]: the same code serves a solver's scene
//! (`lightwire serve`) and a relay's copy of one (`lightwire relay`).

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use axum::extract::ws::{CloseFrame, Message, WebSocket};
use bytes::Bytes;
use futures_util::stream::SplitSink;
use futures_util::{SinkExt, StreamExt};
use lightwire_protocol::{
    ClientMessage, ErrorCode, HELLO_LIGHTS, HELLO_POSES, LightState, LightStatus,
    MIN_PROTOCOL_VERSION, ObjectPose, PROTOCOL_VERSION, Role, SceneInfo, ServerMessage,
    decode_client, encode_server, encode_welcome_for,
};
use tokio::sync::{mpsc, watch};

use super::Shared;
use super::auth::may_drive;
use super::feed::Feed;
use super::inbox::Offer;
use super::publication::Publication;
use super::wire::{Refusal, check_light, check_transform, lit_info, unknown_object};

/// Close code for policy violations (RFC 6455 §7.4.1).
const CLOSE_POLICY: u16 = 1008;
/// Close code when the server goes away.
const CLOSE_GOING_AWAY: u16 = 1001;
/// Close code for a protocol error.
const CLOSE_PROTOCOL: u16 = 1002;
/// Close code "message too big" (RFC 6455 §7.4.1): a client frame over
/// `max_message_bytes`, after an `Error TooLarge`.
const CLOSE_TOO_BIG: u16 = 1009;
/// Close code "service restart": the scene's description changed (a
/// relay's upstream came back with another one); reconnect for a new
/// `Welcome`.
const CLOSE_RESTART: u16 = 1012;
/// Close code "try again later": no scene description yet (a relay that
/// has not reached its upstream).
const CLOSE_TRY_AGAIN: u16 = 1013;
/// Control frames (errors, pongs) waiting for the writer.
const CONTROL_QUEUE: usize = 32;
/// How long sending a Close may wait for room in the socket. The Close
/// queues behind whatever the client has not read yet (a keyframe, the
/// Errors of a flood); a client that reads slowly on a loaded machine
/// still gets it, one that never reads holds only its own connection.
const CLOSE_TIMEOUT: Duration = Duration::from_secs(10);
/// After closing a client for abuse, how long the server keeps reading
/// (and discarding) what it still sends, until it answers the Close: a
/// socket closed over unread data is reset by the kernel, and a reset may
/// discard the Errors and the Close the client has not read yet.
const LINGER: Duration = Duration::from_secs(2);
/// How often the writer sends `Stats`.
const STATS_PERIOD: Duration = Duration::from_millis(250);
/// A send that takes longer than this means the client stopped reading
/// for good; the connection is dropped.
const WRITE_TIMEOUT: Duration = Duration::from_secs(30);

/// Identifies the server in `Welcome`.
pub const SERVER_NAME: &str = concat!("lightwire/", env!("CARGO_PKG_VERSION"));

type Sink = SplitSink<WebSocket, Message>;

/// What the reader asks of the writer.
enum Control {
    Frame(Bytes),
    Resync,
    /// A frame over the size limit arrived: refuse it and close.
    TooLarge,
}

fn error_frame(code: ErrorCode, message: impl Into<String>) -> Bytes {
    Bytes::from(encode_server(&ServerMessage::Error {
        code,
        message: message.into(),
    }))
}

/// Whether a read error is the WebSocket layer refusing a frame longer than
/// `max_message_bytes`. The layer refuses it from the frame header, before
/// reading the payload, so an oversized frame never costs its size in
/// memory; the write half still works and can say why.
fn is_too_large(error: &axum::Error) -> bool {
    // axum wraps tungstenite's `Error::Capacity(MessageTooLong { .. })` in
    // an opaque error; its text is the only stable handle on it (a test
    // over a real socket checks that the reply is TooLarge).
    error.to_string().contains("Message too long")
}

/// Refuses an oversized frame: `Error TooLarge` (2), then close 1009.
async fn refuse_too_large(sink: &mut Sink, state: &Shared) {
    state.metrics.bad_frame("too_large");
    let frame = error_frame(
        ErrorCode::TooLarge,
        format!(
            "a client frame may be at most {} bytes",
            state.config.max_message_bytes
        ),
    );
    let _ = tokio::time::timeout(Duration::from_secs(2), sink.send(Message::Binary(frame))).await;
    close(sink, CLOSE_TOO_BIG, "frame too large").await;
}

async fn close(sink: &mut Sink, code: u16, reason: &str) {
    let frame = CloseFrame {
        code,
        reason: reason.into(),
    };
    let _ = tokio::time::timeout(CLOSE_TIMEOUT, sink.send(Message::Close(Some(frame)))).await;
}

/// What a client's `Hello` asked for.
struct Hello {
    token: Option<String>,
    client: String,
    wants_poses: bool,
    /// `HELLO_LIGHTS` from a client of version 4 or later (an older one
    /// could not decode `Lights`).
    wants_lights: bool,
    version: u16,
}

/// Refuses a client before it joins: counts a bad frame of `kind`, says
/// why in an `Error` frame and closes with `code` and `reason`.
async fn refuse(
    sink: &mut Sink,
    state: &Shared,
    kind: &str,
    error: (ErrorCode, String),
    (code, reason): (u16, &str),
) {
    state.metrics.bad_frame(kind);
    let _ = sink
        .send(Message::Binary(error_frame(error.0, error.1)))
        .await;
    close(sink, code, reason).await;
}

/// The handshake's first half: the first frame must be a `Hello` with a
/// version we speak. `None` when the client is refused or gone.
async fn hello(
    sink: &mut Sink,
    stream: &mut futures_util::stream::SplitStream<WebSocket>,
    state: &Shared,
) -> Option<Hello> {
    let hello_timeout = Duration::from_secs_f64(state.config.hello_timeout_secs);
    let first = tokio::time::timeout(hello_timeout, stream.next()).await;
    match first {
        Ok(Some(Ok(Message::Binary(bytes)))) => match decode_client(&bytes) {
            Ok(ClientMessage::Hello {
                protocol_version,
                client,
                token,
                capabilities,
            }) => {
                if !(MIN_PROTOCOL_VERSION..=PROTOCOL_VERSION).contains(&protocol_version) {
                    let why = lightwire_protocol::version_mismatch(protocol_version);
                    let error = (ErrorCode::UnsupportedVersion, why);
                    let closing = (CLOSE_PROTOCOL, "unsupported protocol version");
                    refuse(sink, state, "unsupported_version", error, closing).await;
                    return None;
                }
                Some(Hello {
                    token,
                    client,
                    wants_poses: capabilities & HELLO_POSES != 0,
                    wants_lights: capabilities & HELLO_LIGHTS != 0 && protocol_version >= 4,
                    version: protocol_version,
                })
            }
            Ok(_) => {
                let error = (
                    ErrorCode::ProtocolViolation,
                    "the first frame must be Hello".into(),
                );
                refuse(
                    sink,
                    state,
                    "no_hello",
                    error,
                    (CLOSE_PROTOCOL, "expected Hello"),
                )
                .await;
                None
            }
            Err(e) => {
                let error = (ErrorCode::BadFrame, e.to_string());
                refuse(
                    sink,
                    state,
                    "malformed",
                    error,
                    (CLOSE_PROTOCOL, "malformed Hello"),
                )
                .await;
                None
            }
        },
        Ok(Some(Ok(Message::Close(_)))) | Ok(None) => None, // left without a word
        Ok(Some(Ok(_))) => {
            // A text frame (pings and pongs are answered by the layer and
            // never reach here as the first frame).
            let error = (
                ErrorCode::BadFrame,
                "frames must be binary; the first must be Hello".into(),
            );
            let closing = (CLOSE_PROTOCOL, "expected a binary Hello");
            refuse(sink, state, "text", error, closing).await;
            None
        }
        Ok(Some(Err(e))) if is_too_large(&e) => {
            refuse_too_large(sink, state).await;
            None
        }
        Ok(Some(Err(_))) => None, // the connection failed
        Err(_) => {
            state.metrics.bad_frame("hello_timeout");
            close(sink, CLOSE_POLICY, "no Hello in time").await;
            None
        }
    }
}

/// Whom a session welcomed: its role, the scene description it was
/// welcomed to, the publication whose lightmap it gets first (the newest
/// when it was welcomed, if any), and the lights' states its `Welcome`
/// told (for a version 4 client; a version 2 or 3 one was told none).
struct Welcomed {
    role: Role,
    info: Arc<SceneInfo>,
    first: Option<Arc<Publication>>,
    told: Option<Vec<LightState>>,
}

/// The handshake's second half: the token's role, and the `Welcome` in
/// the client's protocol version. `None` when the client is refused or
/// gone.
async fn welcome(
    sink: &mut Sink,
    state: &Shared,
    feed: &Feed,
    hello: Hello,
    header_token: Option<String>,
) -> Option<Welcomed> {
    let token = hello.token.or(header_token);
    let Some(role) = state.auth.role(token.as_deref()) else {
        let error = (ErrorCode::Unauthorized, "missing or unknown token".into());
        refuse(
            sink,
            state,
            "unauthorized",
            error,
            (CLOSE_POLICY, "unauthorized"),
        )
        .await;
        return None;
    };
    // The HTTP handler answers 503 before upgrading when there is no
    // description yet; this covers the race with a relay's scene change.
    let Some(info) = feed.info() else {
        close(sink, CLOSE_TRY_AGAIN, "scene not available yet").await;
        return None;
    };
    // The lights as the lightmap this client gets first was lit with
    // (PROTOCOL.md §3): the newest publication's `Lights`, which the
    // writer then sends first. Without one yet, the description's.
    let first = feed.latest().filter(|p| Arc::ptr_eq(&p.scene, &info));
    let scene = match &first {
        Some(p) => lit_info(&info, &p.lights),
        None => (*info).clone(),
    };
    let told =
        (hello.version >= 4).then(|| scene.lights.iter().map(|l| l.state).collect::<Vec<_>>());
    let welcome = ServerMessage::Welcome {
        protocol_version: PROTOCOL_VERSION,
        server: if state.auth.dev_mode() {
            format!("{SERVER_NAME} (DEVELOPMENT MODE: no authentication)")
        } else {
            SERVER_NAME.to_string()
        },
        role,
        // `http.rs` serves `scene.glb` on every router, solver and relay;
        // the writer sends `Poses` to a client that asked (a relay's as
        // its upstream gives them).
        // A solver's scene follows `SetLight` and sends `Lights`; so does
        // a relay whose upstream does (it forwards them).
        capabilities: lightwire_protocol::CAP_SCENE_GLB
            | lightwire_protocol::CAP_POSES
            | if feed.follows_lights.load(Ordering::Relaxed) {
                lightwire_protocol::CAP_LIGHTS
            } else {
                0
            },
        scene,
    };
    // In the client's version: a version 2 client gets version 2's
    // `Welcome`, unless a surface needs what only version 3 describes.
    let Some(welcome) = encode_welcome_for(hello.version, &welcome) else {
        let why = lightwire_protocol::version_mismatch(hello.version);
        let error = (ErrorCode::UnsupportedVersion, why);
        let closing = (CLOSE_PROTOCOL, "unsupported protocol version");
        refuse(sink, state, "unsupported_version", error, closing).await;
        return None;
    };
    let sent = sink.send(Message::Binary(Bytes::from(welcome))).await;
    sent.is_ok().then_some(Welcomed {
        role,
        info,
        first,
        told,
    })
}

/// Runs one connection to completion. `header_token` is a token presented
/// on the HTTP upgrade (header or query); `Hello.token` takes precedence.
pub async fn run(
    socket: WebSocket,
    state: Arc<Shared>,
    feed: Arc<Feed>,
    header_token: Option<String>,
) {
    let (mut sink, mut stream) = socket.split();
    let metrics = state.metrics.clone();
    let Some(hello) = hello(&mut sink, &mut stream, &state).await else {
        return;
    };
    let client_name = hello.client.clone();
    let wants = (hello.wants_poses, hello.wants_lights);
    let version = hello.version;
    let Some(welcomed) = welcome(&mut sink, &state, &feed, hello, header_token).await else {
        return;
    };
    let (role, info) = (welcomed.role, welcomed.info.clone());
    tracing::debug!(scene = %feed.id, client = %client_name, ?role, "client joined");
    feed.clients.fetch_add(1, Ordering::Relaxed);
    metrics.clients.inc();

    let (control_tx, control_rx) = mpsc::channel(CONTROL_QUEUE);
    let (close_tx, close_rx) = watch::channel(None::<(u16, String)>);
    let closing = close_tx.subscribe();
    let mut reader = tokio::spawn(read_loop(
        stream,
        state.clone(),
        feed.clone(),
        info.clone(),
        (role, version),
        control_tx,
        close_tx,
    ));
    write_loop(
        sink,
        state.clone(),
        feed.clone(),
        welcomed,
        wants,
        control_rx,
        close_rx,
    )
    .await;
    // A reader that closed the connection for abuse is draining until the
    // client answers the Close (`LINGER`); let it, so that the socket is
    // not dropped over unread frames.
    let policy = matches!(*closing.borrow(), Some((code, _)) if code == CLOSE_POLICY);
    if policy {
        let _ = tokio::time::timeout(LINGER, &mut reader).await;
    }
    reader.abort();

    feed.clients.fetch_sub(1, Ordering::Relaxed);
    metrics.clients.dec();
    tracing::debug!(scene = %feed.id, client = %client_name, "client left");
}

/// Token bucket for transforms and light states (one per connection,
/// shared by both).
struct RateLimit {
    capacity: f64,
    tokens: f64,
    per_second: f64,
    last: Instant,
}

impl RateLimit {
    fn new(per_second: f64) -> Self {
        Self {
            capacity: 2.0 * per_second,
            tokens: 2.0 * per_second,
            per_second,
            last: Instant::now(),
        }
    }

    fn allow(&mut self) -> bool {
        let now = Instant::now();
        self.tokens =
            (self.tokens + (now - self.last).as_secs_f64() * self.per_second).min(self.capacity);
        self.last = now;
        if self.tokens >= 1.0 {
            self.tokens -= 1.0;
            true
        } else {
            false
        }
    }
}

async fn read_loop(
    mut stream: futures_util::stream::SplitStream<WebSocket>,
    state: Arc<Shared>,
    feed: Arc<Feed>,
    info: Arc<SceneInfo>,
    client: (Role, u16),
    control: mpsc::Sender<Control>,
    close: watch::Sender<Option<(u16, String)>>,
) {
    let metrics = state.metrics.clone();
    let mut bad = 0u32;
    let mut rate = RateLimit::new(state.config.transforms_per_second);
    while let Some(message) = stream.next().await {
        let reply = match message {
            Ok(Message::Binary(bytes)) => {
                handle(&bytes, &state, &feed, &info, client, &mut rate, &control).await
            }
            Ok(Message::Text(_)) => Err((
                ErrorCode::BadFrame,
                "text",
                "frames must be binary".to_string(),
            )),
            Err(e) if is_too_large(&e) => {
                // The writer sends TooLarge and closes 1009; nothing after
                // an oversized frame can be read reliably.
                let _ = control.send(Control::TooLarge).await;
                return;
            }
            Ok(Message::Close(_)) | Err(_) => break,
            Ok(_) => Ok(()), // ping/pong handled by the WebSocket layer
        };
        if let Err((code, kind, message)) = reply {
            metrics.bad_frame(kind);
            // Every refusal gets its Error, in order (PROTOCOL.md §1.7):
            // waiting for room in the writer's queue slows this reader, and
            // so the misbehaving client, down to the pace its socket takes
            // the replies; nothing is dropped and nothing queues without
            // bound. Only a vanished writer (connection gone) fails here.
            if control
                .send(Control::Frame(error_frame(code, message)))
                .await
                .is_err()
            {
                break;
            }
            // Rate limiting and stale seqs are a client's timing, not
            // abuse; everything else counts toward closing.
            if !matches!(code, ErrorCode::RateLimited | ErrorCode::StaleSeq) {
                bad += 1;
                if bad >= state.config.max_bad_frames {
                    metrics.connections_closed_for_abuse.inc();
                    let _ = close.send(Some((CLOSE_POLICY, format!("{bad} invalid frames"))));
                    let drain = async {
                        while let Some(Ok(message)) = stream.next().await {
                            if matches!(message, Message::Close(_)) {
                                break;
                            }
                        }
                    };
                    let _ = tokio::time::timeout(LINGER + CLOSE_TIMEOUT, drain).await;
                    return;
                }
            }
        }
    }
    // The stream ended: tell the writer to stop too.
    if close.borrow().is_none() {
        let _ = close.send(Some((1000, String::new())));
    }
}

async fn handle(
    bytes: &[u8],
    state: &Shared,
    feed: &Feed,
    info: &SceneInfo,
    (role, version): (Role, u16),
    rate: &mut RateLimit,
    control: &mpsc::Sender<Control>,
) -> Result<(), Refusal> {
    let message =
        decode_client(bytes).map_err(|e| (ErrorCode::BadFrame, "malformed", e.to_string()))?;
    match message {
        ClientMessage::Transform {
            object, seq, pose, ..
        } => {
            if !may_drive(role) {
                return Err((
                    ErrorCode::Forbidden,
                    "forbidden",
                    format!("a {role:?} may not move objects"),
                ));
            }
            if let Some(why) = feed.transforms_refused() {
                return Err((ErrorCode::Forbidden, "forbidden", why));
            }
            let index = check_transform(info, object, &pose)?;
            if !rate.allow() {
                return Err((
                    ErrorCode::RateLimited,
                    "rate_limited",
                    format!(
                        "more than {} transforms per second",
                        state.config.transforms_per_second
                    ),
                ));
            }
            match feed.inbox.offer(index, seq, pose) {
                Offer::Accepted => Ok(()),
                Offer::UnknownObject => Err(unknown_object(info, object)),
                Offer::Stale { latest } => Err((
                    ErrorCode::StaleSeq,
                    "stale_seq",
                    format!("seq {seq} for object {object} is not newer than {latest}"),
                )),
            }
        }
        ClientMessage::SetLight {
            light,
            seq,
            state: setting,
            ..
        } => {
            if !may_drive(role) {
                return Err((
                    ErrorCode::Forbidden,
                    "forbidden",
                    format!("a {role:?} may not set lights"),
                ));
            }
            if version < 4 {
                return Err((
                    ErrorCode::ProtocolViolation,
                    "protocol_violation",
                    format!(
                        "SetLight needs protocol version 4; this connection announced {version}"
                    ),
                ));
            }
            if !feed.follows_lights.load(Ordering::Relaxed) {
                return Err((
                    ErrorCode::Forbidden,
                    "forbidden",
                    "this server does not follow lights (a relay whose upstream does not offer CAP_LIGHTS); connect to the solver's server".into(),
                ));
            }
            // A relay whose upstream token grants only the viewer role
            // cannot forward light states either.
            if let Some(why) = feed.transforms_refused() {
                return Err((ErrorCode::Forbidden, "forbidden", why));
            }
            let index = check_light(info, light, &setting)?;
            if !rate.allow() {
                return Err((
                    ErrorCode::RateLimited,
                    "rate_limited",
                    format!(
                        "more than {} transforms and light states per second",
                        state.config.transforms_per_second
                    ),
                ));
            }
            match feed.inbox.offer_light(index, seq, setting) {
                Offer::Accepted => Ok(()),
                Offer::UnknownObject => Err((
                    ErrorCode::UnknownLight,
                    "unknown_light",
                    format!("light {light} is not a light of scene \"{}\"", info.id),
                )),
                Offer::Stale { latest } => Err((
                    ErrorCode::StaleSeq,
                    "stale_seq",
                    format!("seq {seq} for light {light} is not newer than {latest}"),
                )),
            }
        }
        ClientMessage::Resync { .. } => {
            let _ = control.send(Control::Resync).await;
            Ok(())
        }
        ClientMessage::Ping { nonce } => {
            let pong = Bytes::from(encode_server(&ServerMessage::Pong { nonce }));
            let _ = control.send(Control::Frame(pong)).await;
            Ok(())
        }
        ClientMessage::Hello { .. } => Err((
            ErrorCode::ProtocolViolation,
            "duplicate_hello",
            "Hello was already received".into(),
        )),
    }
}

/// Sends one frame, counting it; `false` if the connection is gone.
async fn send(sink: &mut Sink, state: &Shared, frame: Bytes) -> bool {
    let len = frame.len() as u64;
    match tokio::time::timeout(WRITE_TIMEOUT, sink.send(Message::Binary(frame))).await {
        Ok(Ok(())) => {
            state.metrics.frames_sent.inc();
            state.metrics.bytes_sent.inc_by(len);
            true
        }
        _ => false,
    }
}

/// What the writer sends a client holding `held` for publication `p`:
/// `None` if it is up to date, else a delta, merged delta or keyframe.
fn frame_for(state: &Shared, held: Option<u64>, p: &Publication) -> Option<Bytes> {
    if held == Some(p.version) {
        return None;
    }
    if let Some(frame) = held.and_then(|h| p.frame_for(h)) {
        if held != p.base_version {
            state.metrics.catch_up_deltas_sent.inc();
        }
        return Some(frame);
    }
    if let Some(v) = held {
        state
            .metrics
            .frames_skipped
            .inc_by(p.version.saturating_sub(v + 1));
    }
    state.metrics.keyframes_sent.inc();
    Some(p.keyframe_frame())
}

/// What a connection's writer has sent so far.
struct Sent {
    /// The version the client holds, as far as we sent it. Versions only
    /// ever increase on one connection (a relay renumbers across upstream
    /// restarts to keep it so), so "holds v" identifies one exact state.
    held: Option<u64>,
    /// The poses last sent to a client that asked for them
    /// (`HELLO_POSES`): a `Poses` frame goes before a version's lightmap
    /// only when they differ.
    poses: Option<Arc<[ObjectPose]>>,
    /// The same for the lights' states (`HELLO_LIGHTS`, `Lights`).
    lights: Option<Arc<[LightStatus]>>,
}

/// Sends the client what brings it to publication `p` (nothing if it
/// holds it), preceded by `p`'s `Poses` and `Lights` when it asked for
/// them and they changed; `false` if the connection is gone.
async fn send_publication(
    sink: &mut Sink,
    state: &Shared,
    p: &Publication,
    (wants_poses, wants_lights): (bool, bool),
    sent: &mut Sent,
) -> bool {
    let Some(frame) = frame_for(state, sent.held, p) else {
        return true;
    };
    if wants_poses && !p.poses.is_empty() && sent.poses.as_deref() != Some(&*p.poses) {
        if !send(sink, state, p.poses_frame()).await {
            return false;
        }
        sent.poses = Some(p.poses.clone());
    }
    if wants_lights && !p.lights.is_empty() && sent.lights.as_deref() != Some(&*p.lights) {
        if !send(sink, state, p.lights_frame()).await {
            return false;
        }
        sent.lights = Some(p.lights.clone());
    }
    if !send(sink, state, frame).await {
        return false;
    }
    sent.held = Some(p.version);
    true
}

/// Whether publication `p` was lit with lights in other states than
/// `told` (a `Welcome`'s).
fn lit_otherwise(p: &Publication, told: &[LightState]) -> bool {
    p.lights
        .iter()
        .any(|s| told.get(s.light as usize).is_some_and(|t| *t != s.state))
}

async fn write_loop(
    mut sink: Sink,
    state: Arc<Shared>,
    feed: Arc<Feed>,
    welcomed: Welcomed,
    wants: (bool, bool),
    mut control: mpsc::Receiver<Control>,
    mut close_rx: watch::Receiver<Option<(u16, String)>>,
) {
    let Welcomed {
        info, first, told, ..
    } = welcomed;
    let mut publications = feed.publications.clone();
    let mut stats = feed.stats.clone();
    let mut shutdown = state.shutdown.clone();
    let mut sent = Sent {
        held: None,
        poses: None,
        lights: None,
    };
    // The `Welcome` told the lights' states of `first`: its lightmap goes
    // first, whatever was published since (the next one follows at once).
    // Welcomed before any version, a version 4 client that did not ask
    // for `Lights` was told the description's states; if the first
    // version was lit otherwise (a `SetLight` before it), it could not
    // learn so, and is asked to reconnect for a `Welcome` that tells.
    let mut unchecked = match &first {
        Some(p) => {
            if !send_publication(&mut sink, &state, p, wants, &mut sent).await {
                return;
            }
            None
        }
        None if !wants.1 => told,
        None => None,
    };
    // Then whatever is published now or later.
    publications.mark_changed();
    let mut stats_timer = tokio::time::interval(STATS_PERIOD);
    stats_timer.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    loop {
        tokio::select! {
            biased;
            _ = async { shutdown.wait_for(|s| *s).await.map(|_| ()) } => {
                close(&mut sink, CLOSE_GOING_AWAY, "server shutting down").await;
                return;
            }
            changed = close_rx.changed() => {
                let request = close_rx.borrow().clone();
                if changed.is_err() || request.is_some() {
                    // The reader has stopped: deliver the replies it queued
                    // (the Error for the frame that ended it among them)
                    // before the close.
                    while let Ok(c) = control.try_recv() {
                        match c {
                            Control::Frame(frame) => {
                                if !send(&mut sink, &state, frame).await { return; }
                            }
                            Control::TooLarge => {
                                refuse_too_large(&mut sink, &state).await;
                                return;
                            }
                            Control::Resync => {}
                        }
                    }
                    if let Some((code, reason)) = request {
                        if code != 1000 {
                            close(&mut sink, code, &reason).await;
                        }
                    }
                    return;
                }
            }
            Some(c) = control.recv() => {
                let ok = match c {
                    Control::Frame(frame) => send(&mut sink, &state, frame).await,
                    Control::Resync => {
                        sent.held = None;
                        publications.mark_changed();
                        true
                    }
                    Control::TooLarge => {
                        refuse_too_large(&mut sink, &state).await;
                        return;
                    }
                };
                if !ok { return; }
            }
            changed = publications.changed() => {
                if changed.is_err() { return; }
                let latest = publications.borrow_and_update().clone();
                let Some(p) = latest else { continue };
                if !Arc::ptr_eq(&p.scene, &info) {
                    // Never send tiles of one scene description to a client
                    // welcomed with another.
                    close(&mut sink, CLOSE_RESTART, "the scene changed; reconnect").await;
                    return;
                }
                if unchecked.take().is_some_and(|told| lit_otherwise(&p, &told)) {
                    close(&mut sink, CLOSE_RESTART, "the lights changed before the first lightmap; reconnect").await;
                    return;
                }
                if !send_publication(&mut sink, &state, &p, wants, &mut sent).await { return; }
            }
            _ = stats_timer.tick() => {
                let s = *stats.borrow_and_update();
                if !send(&mut sink, &state, Bytes::from(encode_server(&ServerMessage::Stats(s)))).await { return; }
            }
        }
    }
}
