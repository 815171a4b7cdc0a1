//! The connection task: one per [`crate::Client`], owning the socket and
//! the back buffer.
//!
//! A session is one WebSocket: `Hello` → `Welcome` ([`open`]), then a loop
//! ([`Session::run`]) that
//!
//! - applies `Keyframe`s unconditionally and `Delta`s only onto their
//!   exact base ([`DoubleBuffer`]); a delta that does not fit makes it
//!   send `Resync` and ignore deltas until the next keyframe;
//! - publishes each completed version to the shared front (`watch`, newest
//!   only) and as an [`Event::Version`] with the transform-to-light
//!   latency of the seqs it newly reflects;
//! - sends the poses waiting in the outbox (one slot per object: newest
//!   wins, exactly like the server's inbox, so a slow socket coalesces
//!   poses instead of queueing them), and the light states likewise (one
//!   slot per light, as `SetLight`);
//! - takes a `Lights` (asked for with `HELLO_LIGHTS` when
//!   [`Options::lights`] is set) as the states of the version after it,
//!   and its seqs as the floor for this client's next `SetLight`s;
//! - ends on close, error, or silence longer than the idle timeout (the
//!   server sends `Stats` every 250 ms, so silence means a dead peer).
//!
//! When a session ends for a reason that retrying can fix, [`run`] waits
//! a [`Backoff`](lightwire_protocol::backoff::Backoff) delay and opens a new one; the front keeps showing the
//! last complete version meanwhile, and the new session's first keyframe
//! brings it up to date. A new session whose `Welcome` describes the same
//! scene ([`SceneInfo::same_description`]: the lights' states may differ,
//! a driver changed them meanwhile) keeps the buffers and takes the
//! `Welcome`'s states; only another scene gets new ones.

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use futures_util::{SinkExt, StreamExt};
use lightwire_protocol::lightmap::ApplyError;
use lightwire_protocol::{
    ClientMessage, ErrorCode, MAX_FRAME_BYTES, PROTOCOL_VERSION, Role, SceneInfo, ServerMessage,
    decode_server, encode_client,
};
use tokio::net::TcpStream;
use tokio::sync::{mpsc, watch};
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::tungstenite::protocol::WebSocketConfig;
use tokio_tungstenite::{MaybeTlsStream, WebSocketStream};

use crate::buffer::{Applied, DoubleBuffer};
use crate::error::ClientError;
use crate::events::{Delivered, Event, LightDelivered, VersionEvent};
use crate::latency::unix_micros;
use crate::options::Options;
use crate::shared::Shared;
use lightwire_protocol::backoff::Backoff;

/// The socket type.
pub(crate) type Ws = WebSocketStream<MaybeTlsStream<TcpStream>>;

/// After this many keyframes in a row that do not apply, the session is
/// dropped and re-opened instead of asking for yet another keyframe.
const MAX_BAD_KEYFRAMES: u32 = 3;

/// A successful handshake.
pub(crate) struct Opened {
    pub ws: Ws,
    pub role: Role,
    pub capabilities: u32,
    pub server: String,
    pub scene: SceneInfo,
}

/// Opens the WebSocket, says `Hello` and waits for `Welcome`.
pub(crate) async fn open(url: &str, options: &Options) -> Result<Opened, ClientError> {
    let connect_err = |reason: String, permanent: bool| ClientError::Connect {
        url: url.to_string(),
        reason,
        permanent,
    };
    // Frames larger than the protocol's limit are refused by the socket
    // layer before they are buffered whole.
    let config = WebSocketConfig::default()
        .max_message_size(Some(MAX_FRAME_BYTES))
        .max_frame_size(Some(MAX_FRAME_BYTES));
    let connecting = tokio_tungstenite::connect_async_with_config(url, Some(config), true);
    let (mut ws, _) = match tokio::time::timeout(options.connect_timeout, connecting).await {
        Err(_) => {
            return Err(connect_err(
                format!(
                    "timed out after {:.1} s",
                    options.connect_timeout.as_secs_f64()
                ),
                false,
            ));
        }
        Ok(Err(tokio_tungstenite::tungstenite::Error::Http(response))) => {
            let status = response.status();
            let body = response
                .body()
                .as_deref()
                .map(|b| {
                    String::from_utf8_lossy(&b[..b.len().min(300)])
                        .trim()
                        .to_string()
                })
                .unwrap_or_default();
            return Err(connect_err(
                format!("HTTP {status} on the upgrade: {body}"),
                status.is_client_error(),
            ));
        }
        Ok(Err(e)) => return Err(connect_err(e.to_string(), false)),
        Ok(Ok(pair)) => pair,
    };
    let hello = ClientMessage::Hello {
        protocol_version: PROTOCOL_VERSION,
        client: options.client_name.clone(),
        token: options.token.clone(),
        // The dynamic objects' poses with the versions lit for them, so a
        // viewer draws them where their light is (`Frame::poses`); the
        // lights' states if asked (`Frame::lights`).
        capabilities: lightwire_protocol::HELLO_POSES
            | if options.lights {
                lightwire_protocol::HELLO_LIGHTS
            } else {
                0
            },
    };
    let handshake = |reason: String| ClientError::Handshake {
        url: url.to_string(),
        reason,
    };
    tokio::time::timeout(
        options.connect_timeout,
        ws.send(Message::Binary(encode_client(&hello).into())),
    )
    .await
    .map_err(|_| handshake("sending Hello timed out".into()))?
    .map_err(|e| handshake(format!("sending Hello: {e}")))?;
    loop {
        let next = tokio::time::timeout(options.connect_timeout, ws.next())
            .await
            .map_err(|_| {
                handshake(format!(
                    "no Welcome within {:.1} s",
                    options.connect_timeout.as_secs_f64()
                ))
            })?;
        let bytes = match next {
            Some(Ok(Message::Binary(bytes))) => bytes,
            Some(Ok(Message::Close(frame))) => {
                return Err(handshake(format!(
                    "the server closed the socket before Welcome{}",
                    describe_close(frame.as_ref())
                )));
            }
            Some(Ok(Message::Text(_))) => {
                return Err(handshake("a text frame arrived instead of Welcome".into()));
            }
            Some(Ok(_)) => continue, // ping/pong
            Some(Err(e)) => return Err(handshake(e.to_string())),
            None => return Err(handshake("the socket closed before Welcome".into())),
        };
        return match decode_server(&bytes) {
            Ok(ServerMessage::Welcome {
                protocol_version,
                server,
                role,
                capabilities,
                scene,
            }) => {
                if protocol_version != PROTOCOL_VERSION {
                    return Err(handshake(format!(
                        "the server speaks protocol {protocol_version}, this client {PROTOCOL_VERSION}"
                    )));
                }
                Ok(Opened {
                    ws,
                    role,
                    capabilities,
                    server,
                    scene,
                })
            }
            Ok(ServerMessage::Error { code, message }) => Err(ClientError::Refused {
                url: url.to_string(),
                code,
                message,
            }),
            Ok(other) => Err(handshake(format!(
                "expected Welcome first, got {}",
                other.name()
            ))),
            Err(e) => Err(handshake(format!(
                "the first frame ({} bytes) does not decode: {e}",
                bytes.len()
            ))),
        };
    }
}

fn describe_close(frame: Option<&tokio_tungstenite::tungstenite::protocol::CloseFrame>) -> String {
    match frame {
        Some(f) => format!(
            " (close code {}: {:?})",
            u16::from(f.code),
            f.reason.as_str()
        ),
        None => String::new(),
    }
}

/// The state that outlives sessions.
pub(crate) struct Task {
    pub shared: Arc<Shared>,
    pub options: Options,
    pub buffer: DoubleBuffer,
    pub events: mpsc::Sender<Event>,
    pub shutdown: watch::Receiver<bool>,
    pub backoff: Backoff,
}

/// How a session ended.
enum End {
    /// The client was closed.
    Shutdown,
    /// Retrying may help.
    Lost(ClientError),
    /// Retrying cannot help.
    Fatal(ClientError),
}

/// Runs sessions until the client is closed or a permanent error.
pub(crate) async fn run(mut task: Task, first: Opened) {
    let url = task.shared.endpoint.ws_url();
    let mut ws = first.ws;
    loop {
        let end = Session {
            task: &mut task,
            url: &url,
            awaiting_keyframe: false,
            bad_keyframes: 0,
            frame_index: 1,
        }
        .run(&mut ws)
        .await;
        let lost = match end {
            End::Shutdown => {
                let _ = tokio::time::timeout(Duration::from_secs(2), ws.close(None)).await;
                task.emit(Event::Closed(None));
                return;
            }
            End::Fatal(e) => {
                let _ = tokio::time::timeout(Duration::from_secs(2), ws.close(None)).await;
                task.emit(Event::Closed(Some(e)));
                return;
            }
            End::Lost(e) => e,
        };
        task.emit(Event::Disconnected(lost.clone()));
        // Reconnect with backoff until a session opens.
        let mut last = lost.to_string();
        ws = loop {
            let attempt = task.backoff.attempts() + 1;
            let Some(delay) = task.backoff.next_delay() else {
                task.emit(Event::Closed(Some(ClientError::GaveUp {
                    url: url.clone(),
                    attempts: task.backoff.attempts(),
                    last,
                })));
                return;
            };
            task.emit(Event::Reconnecting { attempt, delay });
            let mut shutdown = task.shutdown.clone();
            tokio::select! {
                _ = async { shutdown.wait_for(|stop| *stop).await.map(|_| ()) } => {
                    task.emit(Event::Closed(None));
                    return;
                }
                _ = tokio::time::sleep(delay) => {}
            }
            match open(&url, &task.options).await {
                Ok(opened) => {
                    task.shared
                        .counters
                        .reconnects
                        .fetch_add(1, Ordering::Relaxed);
                    if let Err(e) = task.welcome(&opened) {
                        task.emit(Event::Closed(Some(e)));
                        return;
                    }
                    break opened.ws;
                }
                Err(e) if e.is_permanent() => {
                    task.emit(Event::Closed(Some(e)));
                    return;
                }
                Err(e) => {
                    last = e.to_string();
                    task.shared
                        .counters
                        .connect_errors
                        .fetch_add(1, Ordering::Relaxed);
                    task.emit(Event::Error(e));
                }
            }
        };
    }
}

impl Task {
    /// Sends an event if there is room; otherwise counts it as dropped and
    /// tells the receiver with a [`Event::Lagged`] once there is room again.
    pub(crate) fn emit(&self, event: Event) {
        let dropped = self.shared.counters.events_dropped.load(Ordering::Relaxed);
        let pending = self.shared.lag_reported.load(Ordering::Relaxed);
        if dropped > pending {
            match self.events.try_send(Event::Lagged {
                dropped: dropped - pending,
            }) {
                Ok(()) => {
                    self.shared.lag_reported.store(dropped, Ordering::Relaxed);
                }
                Err(_) => {
                    self.shared
                        .counters
                        .events_dropped
                        .fetch_add(1, Ordering::Relaxed);
                    return;
                }
            }
        }
        if self.events.try_send(event).is_err() {
            self.shared
                .counters
                .events_dropped
                .fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Takes in a (re)connection's Welcome: role, and the scene if it
    /// changed. A Welcome whose lights only changed state (a driver
    /// switched, dimmed or moved one meanwhile; PROTOCOL.md §3) describes
    /// the same scene: the buffers and the lightmap are kept, and the
    /// Welcome's states are the lights' states from its first keyframe
    /// on. Any other change is a new scene: new buffers for its layout.
    fn welcome(&mut self, opened: &Opened) -> Result<(), ClientError> {
        self.shared.set_role(opened.role);
        self.shared.set_capabilities(opened.capabilities);
        if **self.buffer.scene() != opened.scene {
            let scene = Arc::new(opened.scene.clone());
            if !self.buffer.relit(scene.clone()) {
                self.buffer =
                    DoubleBuffer::new(scene.clone()).map_err(|e| ClientError::Protocol {
                        url: self.shared.endpoint.ws_url(),
                        reason: format!("the Welcome's atlas is unusable: {e}"),
                    })?;
            }
            self.shared.scene.send_replace(scene);
        }
        // Poses and light states are per connection: the new server sends
        // its own before its first lightmap (or none, if it does not offer
        // them).
        self.buffer.clear_poses();
        self.buffer.clear_lights();
        self.emit(Event::Connected {
            role: opened.role,
            server: opened.server.clone(),
            scene: self.buffer.scene().clone(),
            reconnect: true,
        });
        Ok(())
    }
}

/// One WebSocket session.
struct Session<'a> {
    task: &'a mut Task,
    url: &'a str,
    /// A `Resync` was sent: deltas are ignored until a keyframe.
    awaiting_keyframe: bool,
    /// Keyframes in a row that did not apply.
    bad_keyframes: u32,
    /// Frames received in this session (the Welcome was #1).
    frame_index: u64,
}

impl Session<'_> {
    async fn run(mut self, ws: &mut Ws) -> End {
        let idle = self.task.options.idle_timeout;
        // Poses and light states queued while disconnected go out first.
        if let Err(e) = self.send_outbox(ws).await {
            return End::Lost(e);
        }
        let shared = self.task.shared.clone();
        loop {
            let mut shutdown = self.task.shutdown.clone();
            tokio::select! {
                biased;
                _ = async { shutdown.wait_for(|stop| *stop).await.map(|_| ()) } => return End::Shutdown,
                _ = shared.outbox_ready.notified() => {
                    if let Err(e) = self.send_outbox(ws).await {
                        return End::Lost(e);
                    }
                }
                next = tokio::time::timeout(idle, ws.next()) => {
                    let message = match next {
                        Err(_) => return End::Lost(self.lost(format!(
                            "no frame for {:.1} s (the server sends Stats every 250 ms)",
                            idle.as_secs_f64()
                        ))),
                        Ok(None) => return End::Lost(self.lost("the socket closed without a close frame".into())),
                        Ok(Some(Err(e))) => return End::Lost(self.lost(e.to_string())),
                        Ok(Some(Ok(m))) => m,
                    };
                    match message {
                        Message::Binary(bytes) => {
                            if let Some(end) = self.on_frame(ws, &bytes).await {
                                return end;
                            }
                        }
                        Message::Close(frame) => {
                            return End::Lost(self.lost(format!(
                                "the server closed the session{}",
                                describe_close(frame.as_ref())
                            )));
                        }
                        Message::Text(_) => {
                            self.frame_index += 1;
                            let e = ClientError::Protocol {
                                url: self.url.to_string(),
                                reason: format!("frame #{} is a text frame; the protocol is binary", self.frame_index),
                            };
                            self.task.shared.counters.decode_errors.fetch_add(1, Ordering::Relaxed);
                            self.task.emit(Event::Error(e));
                        }
                        _ => {} // ping/pong: answered by tungstenite
                    }
                }
            }
        }
    }

    fn lost(&self, reason: String) -> ClientError {
        ClientError::Lost {
            url: self.url.to_string(),
            reason,
        }
    }

    async fn send(&self, ws: &mut Ws, message: &ClientMessage) -> Result<(), ClientError> {
        let frame = Message::Binary(encode_client(message).into());
        match tokio::time::timeout(self.task.options.idle_timeout, ws.send(frame)).await {
            Ok(Ok(())) => Ok(()),
            Ok(Err(e)) => Err(self.lost(format!("sending: {e}"))),
            Err(_) => Err(self.lost("a send did not complete in time".into())),
        }
    }

    /// Sends every pose and light state waiting in the outbox.
    async fn send_outbox(&mut self, ws: &mut Ws) -> Result<(), ClientError> {
        self.send_poses(ws).await?;
        self.send_lights(ws).await
    }

    /// Sends every light state waiting in the outbox (newest per light).
    async fn send_lights(&mut self, ws: &mut Ws) -> Result<(), ClientError> {
        let pending = self.task.shared.take_light_outbox();
        for (light, (seq, state)) in pending {
            self.task
                .shared
                .latency
                .record_light_sent(light, seq, Instant::now());
            let message = ClientMessage::SetLight {
                light,
                seq,
                state,
                client_time_us: unix_micros(),
            };
            self.send(ws, &message).await?;
            self.task
                .shared
                .counters
                .lights_sent
                .fetch_add(1, Ordering::Relaxed);
        }
        Ok(())
    }

    /// Sends every pose waiting in the outbox (newest per object).
    async fn send_poses(&mut self, ws: &mut Ws) -> Result<(), ClientError> {
        let pending = self.task.shared.take_outbox();
        for (object, (seq, pose)) in pending {
            self.task
                .shared
                .latency
                .record_sent(object, seq, Instant::now());
            let message = ClientMessage::Transform {
                object,
                seq,
                pose,
                client_time_us: unix_micros(),
            };
            self.send(ws, &message).await?;
            self.task
                .shared
                .counters
                .poses_sent
                .fetch_add(1, Ordering::Relaxed);
        }
        Ok(())
    }

    async fn resync(&mut self, ws: &mut Ws, have: Option<u64>) -> Result<(), ClientError> {
        self.awaiting_keyframe = true;
        self.task
            .shared
            .counters
            .resyncs
            .fetch_add(1, Ordering::Relaxed);
        self.send(ws, &ClientMessage::Resync { have_version: have })
            .await
    }

    /// Handles one binary frame; `Some` ends the session.
    async fn on_frame(&mut self, ws: &mut Ws, bytes: &[u8]) -> Option<End> {
        self.frame_index += 1;
        let counters = &self.task.shared.counters;
        counters.frames.fetch_add(1, Ordering::Relaxed);
        counters
            .bytes
            .fetch_add(bytes.len() as u64, Ordering::Relaxed);
        let message = match decode_server(bytes) {
            Ok(m) => m,
            Err(source) => {
                counters.decode_errors.fetch_add(1, Ordering::Relaxed);
                self.task.emit(Event::Error(ClientError::Decode {
                    url: self.url.to_string(),
                    index: self.frame_index,
                    len: bytes.len(),
                    source,
                }));
                return None;
            }
        };
        match message {
            ServerMessage::Keyframe(k) => {
                let what = format!("keyframe {}", k.version);
                match self.task.buffer.apply_keyframe(&k) {
                    Ok(applied) => {
                        self.awaiting_keyframe = false;
                        self.bad_keyframes = 0;
                        // This session delivered a lightmap: an outage
                        // after this starts from the short delay again.
                        self.task.backoff.reset();
                        counters.keyframes.fetch_add(1, Ordering::Relaxed);
                        self.publish(applied, None, k.tiles.len(), bytes.len());
                    }
                    Err(source) => {
                        self.bad_keyframes += 1;
                        self.apply_failed(what, source);
                        if self.bad_keyframes >= MAX_BAD_KEYFRAMES {
                            return Some(End::Lost(self.lost(format!(
                                "{MAX_BAD_KEYFRAMES} keyframes in a row did not apply"
                            ))));
                        }
                        let have = self.task.buffer.version();
                        if let Err(e) = self.resync(ws, have).await {
                            return Some(End::Lost(e));
                        }
                    }
                }
            }
            ServerMessage::Delta(d) => {
                if self.awaiting_keyframe {
                    counters.deltas_ignored.fetch_add(1, Ordering::Relaxed);
                    return None;
                }
                match self.task.buffer.apply_delta(&d) {
                    Ok(applied) => {
                        counters.deltas.fetch_add(1, Ordering::Relaxed);
                        let tiles = applied.tiles;
                        self.publish(applied, Some(d.base_version), tiles, bytes.len());
                    }
                    Err(ApplyError::WrongBase { base, .. }) => {
                        let have = self.task.buffer.version();
                        self.task.emit(Event::Resync {
                            have,
                            delta_base: base,
                        });
                        if let Err(e) = self.resync(ws, have).await {
                            return Some(End::Lost(e));
                        }
                    }
                    Err(source) => {
                        let what = format!("delta {} -> {}", d.base_version, d.version);
                        self.apply_failed(what, source);
                        let have = self.task.buffer.version();
                        if let Err(e) = self.resync(ws, have).await {
                            return Some(End::Lost(e));
                        }
                    }
                }
            }
            ServerMessage::Stats(stats) => {
                self.task.shared.stats.send_replace(Some(stats));
                self.task.emit(Event::Stats(stats));
            }
            ServerMessage::Error { code, message } => {
                let counter = match code {
                    ErrorCode::StaleSeq => &counters.stale_seqs,
                    ErrorCode::RateLimited => &counters.rate_limited,
                    _ => &counters.server_errors,
                };
                counter.fetch_add(1, Ordering::Relaxed);
                let fatal = matches!(
                    code,
                    ErrorCode::Unauthorized | ErrorCode::UnsupportedVersion
                );
                self.task.emit(Event::ServerError {
                    code,
                    message: message.clone(),
                });
                if fatal {
                    return Some(End::Fatal(ClientError::Refused {
                        url: self.url.to_string(),
                        code,
                        message,
                    }));
                }
            }
            ServerMessage::Pong { .. } => {}
            ServerMessage::Poses { poses, .. } => self.task.buffer.set_poses(&poses),
            ServerMessage::Lights { lights, .. } => {
                // Only if asked for (`HELLO_LIGHTS`); a server that sends
                // them anyway is not followed.
                if self.task.options.lights {
                    self.task.shared.saw_lights(&lights);
                    self.task.buffer.set_lights(&lights);
                }
            }
            ServerMessage::Welcome { .. } => {
                return Some(End::Lost(ClientError::Protocol {
                    url: self.url.to_string(),
                    reason: format!(
                        "frame #{} is a second Welcome in one session",
                        self.frame_index
                    ),
                }));
            }
        }
        None
    }

    fn apply_failed(&mut self, what: String, source: ApplyError) {
        self.task
            .shared
            .counters
            .apply_errors
            .fetch_add(1, Ordering::Relaxed);
        self.task.emit(Event::Error(ClientError::Apply {
            url: self.url.to_string(),
            what,
            source,
        }));
    }

    /// Makes a completed version the front and reports it.
    fn publish(&mut self, applied: Applied, base: Option<u64>, tiles: usize, bytes: usize) {
        let shared = &self.task.shared;
        let delivered_at = applied.frame.applied_at;
        let delivered = applied
            .newly_reflected
            .iter()
            .map(|r| Delivered {
                object: r.object,
                seq: r.seq,
                latency: shared.latency.latency(r.object, r.seq, delivered_at),
            })
            .collect();
        let lights_delivered = applied
            .newly_lit
            .iter()
            .map(|l| LightDelivered {
                light: l.light,
                seq: l.seq,
                latency: shared.latency.light_latency(l.light, l.seq, delivered_at),
            })
            .collect();
        let version = applied.frame.version();
        if let Some(old) = shared.frames.send_replace(Some(applied.frame)) {
            self.task.buffer.recycle(old);
        }
        self.task.emit(Event::Version(VersionEvent {
            version,
            base,
            tiles,
            bytes,
            delivered,
            lights_delivered,
        }));
    }
}
