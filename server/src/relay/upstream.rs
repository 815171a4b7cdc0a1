//! The relay's connection to one solver scene: a protocol client that
//! feeds a [`Feed`] instead of a screen.
//!
//! One task per upstream runs [`run`]: connect, `Hello` with the relay's
//! upstream token, `Welcome`, then read frames for as long as the
//! connection lives, turning each into relay versions through the
//! [`Mirror`] and publishing them to the relay's sessions, with the
//! upstream's `Poses` and `Lights` (it asks for both). Transforms and light
//! states the relay's drivers sent wait in the feed's inbox (one slot per
//! object and per light, latest seq wins) and are forwarded, paced to
//! [`UPSTREAM_TRANSFORMS_PER_SECOND`] messages together. The relay follows
//! lights (announces `CAP_LIGHTS`, takes `SetLight`) while its upstream
//! does.
//!
//! When the connection ends (closed, an error, or silence longer than
//! [`SILENCE`]: a solver sends `Stats` every 250 ms) the feed keeps its
//! newest publication, so viewers keep the last version; the task
//! reconnects with exponential backoff and jitter, and resyncs on the next
//! keyframe ([`Mirror::on_keyframe`]).
//!
//! This is written against the protocol crate rather than the
//! `lightwire-client` library: the relay republishes the upstream's
//! compressed tiles as they are (no decode-encode round trip), so it needs
//! the raw `Keyframe`/`Delta` values, not a rendered lightmap.

use std::sync::Arc;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, anyhow, bail};
use futures_util::{SinkExt, StreamExt};
use lightwire_protocol::backoff::{Backoff, BackoffPolicy};
use lightwire_protocol::unix_micros;
use lightwire_protocol::{
    CAP_LIGHTS, ClientMessage, ErrorCode, HELLO_LIGHTS, HELLO_POSES, MAX_FRAME_BYTES,
    PROTOCOL_VERSION, SceneInfo, ServerMessage, Stats, decode_server, encode_client,
};
use tokio::net::TcpStream;
use tokio::sync::watch;
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::tungstenite::protocol::WebSocketConfig;
use tokio_tungstenite::{MaybeTlsStream, WebSocketStream};

use super::metrics::RelayMetrics;
use super::mirror::{Mirror, MirrorError, Publish};
use crate::service::auth::may_drive;
use crate::service::feed::Feed;
use crate::service::metrics::Metrics;
use crate::service::publication::Publisher;

/// Transforms and light states forwarded per second and upstream, at
/// most, together. Below the solver's default per-connection limit (120/s,
/// bursts of 240, counting both), so a relay never trips it however many
/// drivers it has: poses and states that arrive faster are coalesced per
/// object and per light (latest seq wins).
pub const UPSTREAM_TRANSFORMS_PER_SECOND: f64 = 100.0;
/// A connection that delivers nothing for this long is presumed dead.
pub const SILENCE: Duration = Duration::from_secs(5);
/// Time to connect and be welcomed.
const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(10);
/// Invalid frames one upstream connection may send before it is dropped
/// (and reconnected).
const MAX_BAD_FRAMES: u32 = 10;
/// Reconnect backoff: first delay and cap.
const BACKOFF_FIRST: Duration = Duration::from_millis(100);
const BACKOFF_MAX: Duration = Duration::from_secs(5);

/// Where an upstream scene lives.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct UpstreamUrl {
    /// `ws://host:port/ws/scenes/id`.
    pub url: String,
    /// The scene id (the last path segment); the relay serves it under the
    /// same path.
    pub scene: String,
}

impl UpstreamUrl {
    /// Parses `ws://HOST[:PORT]/ws/scenes/ID` (or `http://...`, the same).
    pub fn parse(text: &str) -> Result<Self> {
        let uri: axum::http::Uri = text
            .parse()
            .with_context(|| format!("upstream {text:?} is not a URL"))?;
        match uri.scheme_str() {
            Some("ws") | Some("http") => {}
            Some("wss") | Some("https") => bail!(
                "upstream {text:?}: TLS upstreams are not supported; relay from ws:// inside the cluster (terminate TLS in front of the relay instead)"
            ),
            _ => bail!("upstream {text:?} must start with ws:// (or http://)"),
        }
        let authority = uri
            .authority()
            .ok_or_else(|| anyhow!("upstream {text:?} has no host"))?;
        let scene = uri
            .path()
            .strip_prefix("/ws/scenes/")
            .filter(|id| !id.is_empty() && !id.contains('/'))
            .ok_or_else(|| {
                anyhow!("upstream {text:?} must name a scene: ws://{authority}/ws/scenes/SCENE_ID")
            })?
            .to_string();
        Ok(Self {
            url: format!("ws://{authority}/ws/scenes/{scene}"),
            scene,
        })
    }
}

/// What `/api/scenes` reports about an upstream.
#[derive(Default)]
pub struct UpstreamStatus {
    pub connected: AtomicBool,
    /// The upstream version the relay's state equals (0: none).
    pub upstream_version: AtomicU64,
    /// Successful handshakes so far.
    pub connects: AtomicU64,
    /// Why the last connection ended or failed.
    pub last_error: Mutex<Option<String>>,
}

/// Everything one upstream task owns.
pub struct Upstream {
    pub url: UpstreamUrl,
    pub token: Option<String>,
    pub feed: Arc<Feed>,
    pub publisher: Publisher,
    pub stats: watch::Sender<Stats>,
    pub status: Arc<UpstreamStatus>,
    pub metrics: Arc<Metrics>,
    pub relay_metrics: Arc<RelayMetrics>,
    pub shutdown: watch::Receiver<bool>,
}

type Ws = WebSocketStream<MaybeTlsStream<TcpStream>>;

/// How a connection ended.
enum Ended {
    Shutdown,
    /// Lost after it had delivered a keyframe: reconnect quickly.
    LostAfterSync(String),
}

/// The relay's reconnect policy (`lightwire_protocol::backoff`, the one
/// the client library follows): 100 ms doubling to 5 s, +-25 %, so that a
/// fleet of relays does not reconnect to a restarted solver in lockstep.
fn backoff_policy() -> BackoffPolicy {
    BackoffPolicy {
        initial: BACKOFF_FIRST,
        max: BACKOFF_MAX,
        factor: 2.0,
        jitter: 0.25,
        max_attempts: None,
    }
}

impl Upstream {
    /// Runs until shutdown: connect, relay, reconnect.
    pub async fn run(mut self) {
        let mut mirror: Option<Mirror> = None;
        let mut backoff = Backoff::new(backoff_policy());
        loop {
            let ended = self.connection(&mut mirror).await;
            if self.status.connected.swap(false, Ordering::Relaxed) {
                self.relay_metrics.upstreams_connected.dec();
            }
            if let Some(m) = mirror.as_mut() {
                m.unsync();
            }
            let why = match ended {
                Ok(Ended::Shutdown) => return,
                Ok(Ended::LostAfterSync(why)) => {
                    backoff.reset();
                    why
                }
                Err(e) => format!("{e:#}"),
            };
            self.relay_metrics.upstream_failures.inc();
            let delay = backoff.next_delay().unwrap_or(BACKOFF_MAX);
            let serving = if self.publisher.latest().is_some() {
                "serving the last version"
            } else {
                "nothing to serve yet"
            };
            tracing::warn!(upstream = %self.url.url, "upstream lost: {why}; {serving}, reconnecting in {delay:?}");
            *self
                .status
                .last_error
                .lock()
                .unwrap_or_else(|p| p.into_inner()) = Some(why);
            let mut shutdown = self.shutdown.clone();
            tokio::select! {
                _ = tokio::time::sleep(delay) => {}
                _ = async { shutdown.wait_for(|s| *s).await.map(|_| ()) } => return,
            }
        }
    }

    /// One connection, from connect to its end.
    async fn connection(&mut self, mirror: &mut Option<Mirror>) -> Result<Ended> {
        let (mut ws, role) = self.handshake(mirror).await?;
        let mirror = mirror
            .as_mut()
            .ok_or_else(|| anyhow!("no mirror for the upstream scene"))?;
        // Poses and light states are per connection: this upstream sends
        // its own before its first lightmap, or none (one without CAP_POSES
        // or CAP_LIGHTS); never publish the previous connection's with its
        // versions.
        mirror.poses = Arc::default();
        mirror.lights = Arc::default();
        self.status.connected.store(true, Ordering::Relaxed);
        self.relay_metrics.upstreams_connected.inc();
        self.status.connects.fetch_add(1, Ordering::Relaxed);
        self.relay_metrics.upstream_connects.inc();
        tracing::info!(upstream = %self.url.url, ?role, "upstream connected");

        let mut link = Link::default();
        let pace = Duration::from_secs_f64(1.0 / UPSTREAM_TRANSFORMS_PER_SECOND);
        let mut next_forward = Instant::now();
        let mut forward_due: Option<Instant> = None;
        let mut shutdown = self.shutdown.clone();
        let mut last_frame = tokio::time::Instant::now();
        let lost = |why: String, synced: bool| {
            if synced {
                Ok(Ended::LostAfterSync(why))
            } else {
                Err(anyhow!(why))
            }
        };
        loop {
            let due = forward_due;
            tokio::select! {
                biased;
                _ = async { shutdown.wait_for(|s| *s).await.map(|_| ()) } => {
                    let _ = tokio::time::timeout(Duration::from_secs(1), ws.close(None)).await;
                    return Ok(Ended::Shutdown);
                }
                // A deadline from the last frame, not a timeout per wait:
                // forwarding transforms must not keep a dead upstream alive.
                _ = tokio::time::sleep_until(last_frame + SILENCE) => {
                    return lost(format!("no frame for {SILENCE:?}"), link.synced);
                }
                next = ws.next() => {
                    last_frame = tokio::time::Instant::now();
                    if let Err(why) = self.on_frame(next, mirror, &mut link, &mut ws).await {
                        return lost(why, link.synced);
                    }
                }
                _ = self.feed.inbox.arrived(), if due.is_none() => {
                    forward_due = Some(next_forward.max(Instant::now()));
                }
                _ = sleep_until(due) , if due.is_some() => {
                    forward_due = None;
                    let sent = match self.forward(&mut ws).await {
                        Ok(sent) => sent,
                        Err(why) => return lost(why, link.synced),
                    };
                    // The pace counts messages: a batch of several (objects
                    // and lights) waits for all of them.
                    next_forward = Instant::now() + pace * sent.max(1);
                }
            }
        }
    }

    /// Connects, says Hello, takes the Welcome and checks it, and makes
    /// `mirror` mirror the upstream's scene (a new one if its description
    /// changed).
    async fn handshake(
        &mut self,
        mirror: &mut Option<Mirror>,
    ) -> Result<(Ws, lightwire_protocol::Role)> {
        let config = WebSocketConfig::default()
            .max_message_size(Some(MAX_FRAME_BYTES))
            .max_frame_size(Some(MAX_FRAME_BYTES));
        let (mut ws, _) = tokio::time::timeout(
            HANDSHAKE_TIMEOUT,
            tokio_tungstenite::connect_async_with_config(self.url.url.as_str(), Some(config), true),
        )
        .await
        .map_err(|_| anyhow!("connecting timed out after {HANDSHAKE_TIMEOUT:?}"))?
        // tungstenite's error already names its I/O cause: no chain.
        .map_err(|e| anyhow!("connecting: {e}"))?;
        let hello = ClientMessage::Hello {
            protocol_version: PROTOCOL_VERSION,
            client: concat!("lightwire-relay/", env!("CARGO_PKG_VERSION")).to_string(),
            token: self.token.clone(),
            // The dynamic objects' poses and the lights' states, for the
            // relay's viewers that ask.
            capabilities: HELLO_POSES | HELLO_LIGHTS,
        };
        ws.send(Message::Binary(encode_client(&hello).into()))
            .await
            .context("sending Hello")?;
        let (role, capabilities, scene) = tokio::time::timeout(HANDSHAKE_TIMEOUT, welcome(&mut ws))
            .await
            .map_err(|_| anyhow!("no Welcome within {HANDSHAKE_TIMEOUT:?}"))??;
        if scene.id != self.url.scene {
            bail!(
                "the upstream serves scene \"{}\" at {}, expected \"{}\"",
                scene.id,
                self.url.url,
                self.url.scene
            );
        }
        *self
            .feed
            .transforms_refused
            .lock()
            .unwrap_or_else(|p| p.into_inner()) = (!may_drive(role)).then(|| {
            format!(
                "this relay's upstream token grants the {role:?} role: it cannot forward transforms or light states"
            )
        });
        // The relay follows lights while its upstream does: it forwards
        // `SetLight`s and passes the upstream's `Lights` on.
        self.feed
            .follows_lights
            .store(capabilities & CAP_LIGHTS != 0, Ordering::Relaxed);
        // The lights' states in a `Welcome` are the upstream's now, which
        // drivers change without changing the scene: a reconnect to a
        // scene whose lights only changed state keeps the mirror.
        if !mirror
            .as_ref()
            .is_some_and(|m| m.info.same_description(&scene))
        {
            // A new description (or the first): start a new mirror; relay
            // versions continue after the newest published one. The feed
            // switches description with the first publication.
            let last = self.publisher.latest().map_or(0, |p| p.version);
            *mirror = Some(
                Mirror::new(Arc::new(scene), last)
                    .map_err(|e| anyhow!("the upstream's scene is unusable: {e}"))?,
            );
        }
        Ok((ws, role))
    }

    /// One frame from upstream (or the end of the stream). `Err` says why
    /// the connection is lost.
    async fn on_frame(
        &mut self,
        next: Option<Result<Message, tokio_tungstenite::tungstenite::Error>>,
        mirror: &mut Mirror,
        link: &mut Link,
        ws: &mut Ws,
    ) -> Result<(), String> {
        let bytes = match next {
            None => return Err("the upstream closed the connection".into()),
            Some(Err(e)) => return Err(format!("upstream connection failed: {e}")),
            Some(Ok(Message::Binary(bytes))) => bytes,
            Some(Ok(Message::Close(frame))) => {
                let why = frame.map_or_else(String::new, |f| format!(" ({} {})", f.code, f.reason));
                return Err(format!("the upstream closed the connection{why}"));
            }
            Some(Ok(Message::Text(_))) => return link.bad_frame(&self.relay_metrics, None),
            Some(Ok(_)) => return Ok(()), // ping/pong: tungstenite answers
        };
        self.relay_metrics.upstream_frames.inc();
        self.relay_metrics.upstream_bytes.inc_by(bytes.len() as u64);
        let message = match decode_server(&bytes) {
            Ok(m) => m,
            Err(e) => {
                tracing::warn!(upstream = %self.url.url, "undecodable upstream frame: {e}");
                return link.bad_frame(&self.relay_metrics, None);
            }
        };
        let Some(e) = self.on_message(message, mirror, link)? else {
            return Ok(());
        };
        // Never publish what does not apply: unsync and ask for a keyframe
        // (deltas until then are ignored).
        if !matches!(
            e,
            MirrorError::NotSynced
                | MirrorError::Apply(lightwire_protocol::lightmap::ApplyError::WrongBase { .. })
        ) {
            link.bad_frame(&self.relay_metrics, Some(&e))?;
        }
        tracing::warn!(upstream = %self.url.url, "upstream frame refused ({e}); asking for a resync");
        mirror.unsync();
        link.awaiting_keyframe = true;
        self.relay_metrics.upstream_resyncs.inc();
        let resync = ClientMessage::Resync {
            have_version: self.status_version(),
        };
        ws.send(Message::Binary(encode_client(&resync).into()))
            .await
            .map_err(|e| format!("sending Resync: {e}"))
    }

    /// One decoded message from upstream: what the mirror refused, if it
    /// refused it; `Err` says why the connection is lost.
    fn on_message(
        &mut self,
        message: ServerMessage,
        mirror: &mut Mirror,
        link: &mut Link,
    ) -> Result<Option<MirrorError>, String> {
        Ok(match message {
            ServerMessage::Keyframe(k) => match mirror.on_keyframe(&k) {
                Ok(publish) => {
                    link.awaiting_keyframe = false;
                    link.synced = true;
                    if let Some(p) = publish {
                        self.publish(mirror, p);
                    }
                    self.status
                        .upstream_version
                        .store(k.version, Ordering::Relaxed);
                    None
                }
                Err(e) => Some(e),
            },
            ServerMessage::Delta(_) if link.awaiting_keyframe => None,
            ServerMessage::Delta(d) => match mirror.on_delta(&d) {
                Ok(p) => {
                    self.publish(mirror, p);
                    self.status
                        .upstream_version
                        .store(d.version, Ordering::Relaxed);
                    None
                }
                Err(e) => Some(e),
            },
            ServerMessage::Stats(s) => {
                self.stats.send_replace(Stats {
                    version: mirror.version(),
                    clients: self.feed.clients.load(Ordering::Relaxed),
                    server_time_us: unix_micros(),
                    ..s
                });
                None
            }
            ServerMessage::Error { code, message } => {
                // Errors answer forwarded transforms (a stale seq from a
                // driver of another relay, a rate limit): nothing to
                // attribute them to.
                self.relay_metrics.upstream_errors.inc();
                tracing::debug!(upstream = %self.url.url, ?code, "upstream error: {message}");
                if matches!(
                    code,
                    ErrorCode::Unauthorized | ErrorCode::UnsupportedVersion
                ) {
                    return Err(format!("upstream refused the relay: {code:?}: {message}"));
                }
                None
            }
            ServerMessage::Pong { .. } => None,
            ServerMessage::Poses { poses, .. } => {
                if let Err(e) = mirror.on_poses(poses) {
                    tracing::warn!(upstream = %self.url.url, "upstream Poses refused: {e}");
                    link.bad_frame(&self.relay_metrics, Some(&e))?;
                }
                None
            }
            ServerMessage::Lights { lights, .. } => {
                if let Err(e) = mirror.on_lights(lights) {
                    tracing::warn!(upstream = %self.url.url, "upstream Lights refused: {e}");
                    link.bad_frame(&self.relay_metrics, Some(&e))?;
                }
                None
            }
            ServerMessage::Welcome { .. } => {
                return Err("a second Welcome from upstream".into());
            }
        })
    }

    /// Forwards the drivers' latest transforms and light states upstream;
    /// how many messages went.
    async fn forward(&mut self, ws: &mut Ws) -> Result<u32, String> {
        let mut sent = 0;
        for (object, pending) in self.feed.inbox.drain() {
            let transform = ClientMessage::Transform {
                object: object as u32,
                seq: pending.seq,
                pose: pending.pose,
                client_time_us: unix_micros(),
            };
            ws.send(Message::Binary(encode_client(&transform).into()))
                .await
                .map_err(|e| format!("forwarding a transform: {e}"))?;
            self.relay_metrics.transforms_forwarded.inc();
            sent += 1;
        }
        for (light, pending) in self.feed.inbox.drain_lights() {
            let set = ClientMessage::SetLight {
                light: light as u32,
                seq: pending.seq,
                state: pending.state,
                client_time_us: unix_micros(),
            };
            ws.send(Message::Binary(encode_client(&set).into()))
                .await
                .map_err(|e| format!("forwarding a light state: {e}"))?;
            self.relay_metrics.lights_forwarded.inc();
            sent += 1;
        }
        Ok(sent)
    }

    fn status_version(&self) -> Option<u64> {
        Some(self.status.upstream_version.load(Ordering::Relaxed)).filter(|v| *v > 0)
    }

    /// Hands a new relay version to the sessions.
    fn publish(&self, mirror: &Mirror, p: Publish) {
        let current = self.feed.info();
        if !current
            .as_ref()
            .is_some_and(|c| Arc::ptr_eq(c, &mirror.info))
        {
            // First version of a (new) description: welcome new clients
            // with it; sessions welcomed with the old one close on this
            // publication and their clients reconnect.
            self.feed
                .inbox
                .reset(mirror.info.objects.len(), mirror.info.lights.len());
            self.feed.info.send_replace(Some(mirror.info.clone()));
        }
        self.publisher.publish_lit(
            mirror.info.clone(),
            p.keyframe,
            p.delta,
            (mirror.poses.clone(), mirror.lights.clone()),
        );
        self.metrics.versions_published.inc();
        self.feed.ready.store(true, Ordering::Release);
    }
}

async fn sleep_until(at: Option<Instant>) {
    if let Some(at) = at {
        tokio::time::sleep_until(at.into()).await;
    }
}

/// The state of one upstream connection.
#[derive(Default)]
struct Link {
    /// A keyframe has been applied on this connection.
    synced: bool,
    /// Deltas are ignored until the keyframe a resync asked for.
    awaiting_keyframe: bool,
    /// Bad frames so far.
    bad: u32,
}

impl Link {
    /// Counts a bad frame; `Err` once there are too many (`last` names the
    /// last one's fault in the reason).
    fn bad_frame(
        &mut self,
        metrics: &RelayMetrics,
        last: Option<&dyn std::fmt::Display>,
    ) -> Result<(), String> {
        metrics.upstream_bad_frames.inc();
        self.bad += 1;
        if self.bad < MAX_BAD_FRAMES {
            return Ok(());
        }
        Err(match last {
            Some(e) => format!("{} bad frames from upstream (last: {e})", self.bad),
            None => format!("{} bad frames from upstream", self.bad),
        })
    }
}

/// Reads the upstream's answer to `Hello`: role, capabilities, scene.
async fn welcome(ws: &mut Ws) -> Result<(lightwire_protocol::Role, u32, SceneInfo)> {
    loop {
        match ws.next().await {
            Some(Ok(Message::Binary(bytes))) => {
                return match decode_server(&bytes).context("decoding the upstream's Welcome")? {
                    ServerMessage::Welcome {
                        protocol_version,
                        role,
                        capabilities,
                        scene,
                        ..
                    } if protocol_version == PROTOCOL_VERSION => Ok((role, capabilities, scene)),
                    ServerMessage::Welcome {
                        protocol_version, ..
                    } => bail!(
                        "the upstream speaks protocol {protocol_version}, the relay {PROTOCOL_VERSION}"
                    ),
                    ServerMessage::Error { code, message } => {
                        bail!("the upstream refused the relay: {code:?}: {message}")
                    }
                    other => bail!("expected Welcome from upstream, got {}", other.name()),
                };
            }
            Some(Ok(Message::Close(frame))) => bail!(
                "the upstream closed the connection before Welcome{}",
                frame.map_or_else(String::new, |f| format!(" ({} {})", f.code, f.reason))
            ),
            Some(Ok(_)) => continue,
            Some(Err(e)) => return Err(e).context("reading the upstream's Welcome"),
            None => bail!("the upstream closed the connection before Welcome"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn upstream_urls_name_their_scene_or_are_refused_with_the_reason() {
        let u = UpstreamUrl::parse("ws://solver-0.solver:8080/ws/scenes/cornell-low").expect("ok");
        assert_eq!(u.scene, "cornell-low");
        assert_eq!(u.url, "ws://solver-0.solver:8080/ws/scenes/cornell-low");
        let u = UpstreamUrl::parse("http://127.0.0.1:9/ws/scenes/x").expect("http is ws");
        assert_eq!(u.url, "ws://127.0.0.1:9/ws/scenes/x");
        for (bad, why) in [
            ("wss://a/ws/scenes/x", "TLS"),
            ("ftp://a/ws/scenes/x", "ws://"),
            ("ws://a/", "must name a scene"),
            ("ws://a/ws/scenes/", "must name a scene"),
            ("ws://a/ws/scenes/x/y", "must name a scene"),
            ("not a url", "not a URL"),
        ] {
            let err = UpstreamUrl::parse(bad).expect_err(bad).to_string();
            assert!(err.contains(why), "{bad}: {err}");
        }
    }

    #[test]
    fn backoff_doubles_to_its_cap_with_bounded_jitter() {
        let mut b = Backoff::new(backoff_policy());
        let mut step = BACKOFF_FIRST;
        for _ in 0..10 {
            let d = b.next_delay().expect("the relay never gives up");
            assert!(
                d >= step.mul_f64(0.75) && d <= step.mul_f64(1.25),
                "{d:?} vs {step:?}"
            );
            step = (step * 2).min(BACKOFF_MAX);
        }
        b.reset();
        assert!(b.next_delay().expect("never gives up") <= BACKOFF_FIRST.mul_f64(1.25));
    }
}
