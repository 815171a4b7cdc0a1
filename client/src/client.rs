//! [`Client`]: the handle a game, a renderer or a load tester holds.
//!
//! `Client::connect` opens the WebSocket, completes the handshake and then
//! hands the socket to a background task (see [`crate::connection`]). The
//! handle and the task share:
//!
//! - the **front** lightmap, a `watch` of `Arc<Frame>` (newest only), which
//!   renderers read without locking;
//! - the scene (a `watch`, replaced only if a reconnect finds a different
//!   scene) and the role;
//! - the **outbox** of poses to send: one slot per object, newest wins;
//! - counters and the latest `Stats`;
//! - the [`LatencyBook`] of send times.
//!
//! Everything else the task reports goes through a bounded event channel;
//! when the application does not read it, events are dropped and counted
//! ([`Event::Lagged`]), never queued without bound.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use lightwire_protocol::{ErrorCode, Pose, Role, SceneInfo, Stats};
use tokio::sync::{Notify, mpsc, watch};

use crate::buffer::{DoubleBuffer, Frame};
use crate::connection::{self, Task};
use crate::endpoint::Endpoint;
use crate::error::ClientError;
use crate::latency::{LatencyBook, SeqSource};
use lightwire_protocol::backoff::{Backoff, BackoffPolicy};

/// Connection settings. `Options::default()` suits a game client.
#[derive(Clone, Debug)]
pub struct Options {
    /// Access token (`None` only for a `--dev` server).
    pub token: Option<String>,
    /// Sent in `Hello`, for the server's logs.
    pub client_name: String,
    /// Reconnect delays.
    pub backoff: BackoffPolicy,
    /// Limit for TCP connect, upgrade and Welcome together (each step).
    pub connect_timeout: Duration,
    /// A session that receives nothing for this long is considered dead
    /// (the server sends `Stats` every 250 ms).
    pub idle_timeout: Duration,
    /// Capacity of the event channel; events beyond it are dropped and
    /// counted.
    pub event_capacity: usize,
    /// Where send times are kept; share one between clients to measure
    /// delivery of one client's poses to others (the load tester does).
    pub latency: Arc<LatencyBook>,
    /// Where seqs come from; share one between drivers of the same object.
    pub seqs: Arc<SeqSource>,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            token: None,
            client_name: concat!("lightwire-client/", env!("CARGO_PKG_VERSION")).to_string(),
            backoff: BackoffPolicy::default(),
            connect_timeout: Duration::from_secs(10),
            idle_timeout: Duration::from_secs(10),
            event_capacity: 256,
            latency: Arc::new(LatencyBook::default()),
            seqs: Arc::new(SeqSource::new()),
        }
    }
}

/// Something the connection task wants the application to know.
#[derive(Clone, Debug)]
pub enum Event {
    /// A session opened (after a reconnect: `reconnect` is true; the first
    /// session is reported by `connect` returning).
    Connected {
        /// The role granted.
        role: Role,
        /// The server's name.
        server: String,
        /// The scene (a new `Arc` if it changed).
        scene: Arc<SceneInfo>,
        /// Always true: the first connection is `connect` itself.
        reconnect: bool,
    },
    /// A new complete lightmap version is in front.
    Version(VersionEvent),
    /// The server's statistics (every 250 ms).
    Stats(Stats),
    /// A delta did not fit the version held; a `Resync` was sent.
    Resync {
        /// The version held (`None` before the first keyframe).
        have: Option<u64>,
        /// The delta's base.
        delta_base: u64,
    },
    /// The server refused something this client sent.
    ServerError {
        /// The protocol code (e.g. `StaleSeq` when another driver's pose
        /// of the same object arrived first).
        code: ErrorCode,
        /// The server's reason.
        message: String,
    },
    /// A frame could not be used (it was ignored or a resync asked for),
    /// or a reconnect attempt failed; the client carries on.
    Error(ClientError),
    /// The session ended; a reconnect follows (see `Reconnecting`).
    Disconnected(ClientError),
    /// Waiting `delay` before reconnect attempt `attempt`.
    Reconnecting {
        /// 1 for the first attempt after a disconnect.
        attempt: u32,
        /// The backoff delay.
        delay: Duration,
    },
    /// This many events were dropped because the channel was full.
    Lagged {
        /// Dropped since the previous `Lagged`.
        dropped: u64,
    },
    /// The task ended: closed by the application (`None`) or for good
    /// (permanent refusal, or reconnecting gave up). No events follow.
    Closed(Option<ClientError>),
}

/// A version that became the front.
#[derive(Clone, Debug, PartialEq)]
pub struct VersionEvent {
    /// The new version.
    pub version: u64,
    /// The delta's base, or `None` for a keyframe.
    pub base: Option<u64>,
    /// Tiles the frame carried.
    pub tiles: usize,
    /// Size of the frame on the wire.
    pub bytes: usize,
    /// Transforms this version newly reflects, with their latency when
    /// the send time is known to this client's [`LatencyBook`].
    pub delivered: Vec<Delivered>,
}

/// One transform that reached the light.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Delivered {
    /// Object index.
    pub object: u32,
    /// The transform's seq.
    pub seq: u64,
    /// Send to applied, if the send time is known.
    pub latency: Option<Duration>,
}

/// Cumulative counts since `connect` (across reconnects).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct Counters {
    /// Binary frames received.
    pub frames: u64,
    /// Bytes of binary frames received.
    pub bytes: u64,
    /// Keyframes applied.
    pub keyframes: u64,
    /// Deltas applied.
    pub deltas: u64,
    /// Deltas ignored while waiting for a resync keyframe.
    pub deltas_ignored: u64,
    /// `Resync`s sent.
    pub resyncs: u64,
    /// Sessions re-opened after a disconnect.
    pub reconnects: u64,
    /// Failed reconnect attempts.
    pub connect_errors: u64,
    /// Server frames that did not decode (or were text).
    pub decode_errors: u64,
    /// Keyframes/deltas that decoded but did not apply.
    pub apply_errors: u64,
    /// `Error` frames other than `StaleSeq` and `RateLimited`.
    pub server_errors: u64,
    /// `StaleSeq` refusals: another pose of the object was newer.
    pub stale_seqs: u64,
    /// `RateLimited` refusals.
    pub rate_limited: u64,
    /// Transforms written to the socket.
    pub poses_sent: u64,
    /// Poses replaced in the outbox by a newer one before being sent.
    pub poses_coalesced: u64,
    /// Events dropped because the event channel was full.
    pub events_dropped: u64,
}

/// The atomics behind [`Counters`].
#[derive(Debug, Default)]
pub(crate) struct AtomicCounters {
    pub frames: AtomicU64,
    pub bytes: AtomicU64,
    pub keyframes: AtomicU64,
    pub deltas: AtomicU64,
    pub deltas_ignored: AtomicU64,
    pub resyncs: AtomicU64,
    pub reconnects: AtomicU64,
    pub connect_errors: AtomicU64,
    pub decode_errors: AtomicU64,
    pub apply_errors: AtomicU64,
    pub server_errors: AtomicU64,
    pub stale_seqs: AtomicU64,
    pub rate_limited: AtomicU64,
    pub poses_sent: AtomicU64,
    pub poses_coalesced: AtomicU64,
    pub events_dropped: AtomicU64,
}

impl AtomicCounters {
    fn snapshot(&self) -> Counters {
        let get = |a: &AtomicU64| a.load(Ordering::Relaxed);
        Counters {
            frames: get(&self.frames),
            bytes: get(&self.bytes),
            keyframes: get(&self.keyframes),
            deltas: get(&self.deltas),
            deltas_ignored: get(&self.deltas_ignored),
            resyncs: get(&self.resyncs),
            reconnects: get(&self.reconnects),
            connect_errors: get(&self.connect_errors),
            decode_errors: get(&self.decode_errors),
            apply_errors: get(&self.apply_errors),
            server_errors: get(&self.server_errors),
            stale_seqs: get(&self.stale_seqs),
            rate_limited: get(&self.rate_limited),
            poses_sent: get(&self.poses_sent),
            poses_coalesced: get(&self.poses_coalesced),
            events_dropped: get(&self.events_dropped),
        }
    }
}

/// What the handle and the task share; see the module docs.
pub(crate) struct Shared {
    pub endpoint: Endpoint,
    pub scene: watch::Sender<Arc<SceneInfo>>,
    role: Mutex<Role>,
    pub frames: watch::Sender<Option<Arc<Frame>>>,
    pub stats: watch::Sender<Option<Stats>>,
    pub counters: AtomicCounters,
    /// Events dropped that a `Lagged` event has already reported.
    pub lag_reported: AtomicU64,
    /// Newest pose per object, waiting for the socket: (seq, pose).
    outbox: Mutex<BTreeMap<u32, (u64, Pose)>>,
    pub outbox_ready: Notify,
    pub latency: Arc<LatencyBook>,
    seqs: Arc<SeqSource>,
}

impl Shared {
    pub(crate) fn set_role(&self, role: Role) {
        *self.role.lock().unwrap_or_else(|p| p.into_inner()) = role;
    }

    fn role(&self) -> Role {
        *self.role.lock().unwrap_or_else(|p| p.into_inner())
    }

    pub(crate) fn take_outbox(&self) -> BTreeMap<u32, (u64, Pose)> {
        std::mem::take(&mut *self.outbox.lock().unwrap_or_else(|p| p.into_inner()))
    }
}

/// A connection to one scene of a `lightwire serve`; see the crate docs.
///
/// Dropping the handle stops the background task (the socket is closed
/// with a close frame); [`Client::close`] does the same and waits for it.
pub struct Client {
    shared: Arc<Shared>,
    events: mpsc::Receiver<Event>,
    shutdown: watch::Sender<bool>,
    task: Option<tokio::task::JoinHandle<()>>,
}

impl Client {
    /// Connects to scene `scene` of the server at `url` (see
    /// [`Endpoint::parse`] for the accepted forms) with `token`, and
    /// returns once the server's `Welcome` arrived. The first attempt's
    /// failure is returned; later disconnects reconnect by themselves.
    /// Must be called within a tokio runtime.
    pub async fn connect(
        url: &str,
        token: Option<&str>,
        scene: Option<&str>,
    ) -> Result<Client, ClientError> {
        let endpoint = Endpoint::parse(url, scene)?;
        let options = Options {
            token: token.map(str::to_string),
            ..Options::default()
        };
        Client::connect_with(endpoint, options).await
    }

    /// [`Client::connect`] with every setting.
    pub async fn connect_with(endpoint: Endpoint, options: Options) -> Result<Client, ClientError> {
        let url = endpoint.ws_url();
        let opened = connection::open(&url, &options).await?;
        let scene = Arc::new(opened.scene.clone());
        let buffer = DoubleBuffer::new(scene.clone()).map_err(|e| ClientError::Protocol {
            url: url.clone(),
            reason: format!("the Welcome's atlas is unusable: {e}"),
        })?;
        let shared = Arc::new(Shared {
            endpoint,
            scene: watch::Sender::new(scene),
            role: Mutex::new(opened.role),
            frames: watch::Sender::new(None),
            stats: watch::Sender::new(None),
            counters: AtomicCounters::default(),
            lag_reported: AtomicU64::new(0),
            outbox: Mutex::new(BTreeMap::new()),
            outbox_ready: Notify::new(),
            latency: options.latency.clone(),
            seqs: options.seqs.clone(),
        });
        let (events_tx, events) = mpsc::channel(options.event_capacity.max(1));
        let (shutdown, shutdown_rx) = watch::channel(false);
        let task = Task {
            shared: shared.clone(),
            backoff: Backoff::new(options.backoff),
            options,
            buffer,
            events: events_tx,
            shutdown: shutdown_rx,
        };
        let handle = tokio::spawn(connection::run(task, opened));
        Ok(Client {
            shared,
            events,
            shutdown,
            task: Some(handle),
        })
    }

    /// Where this client connects.
    pub fn endpoint(&self) -> &Endpoint {
        &self.shared.endpoint
    }

    /// The scene as the latest `Welcome` described it: atlas layout,
    /// objects, materials and the quads with their atlas rectangles.
    pub fn scene(&self) -> Arc<SceneInfo> {
        self.shared.scene.borrow().clone()
    }

    /// The role the server granted.
    pub fn role(&self) -> Role {
        self.shared.role()
    }

    /// The front buffer: the newest complete lightmap version, with the
    /// scene it belongs to (`None` until the first keyframe).
    pub fn frame(&self) -> Option<Arc<Frame>> {
        self.shared.frames.borrow().clone()
    }

    /// The front's version.
    pub fn version(&self) -> Option<u64> {
        self.shared.frames.borrow().as_ref().map(|f| f.version())
    }

    /// A receiver that wakes whenever a new version is in front (newest
    /// only: a slow reader skips versions, it never queues them).
    pub fn subscribe(&self) -> watch::Receiver<Option<Arc<Frame>>> {
        self.shared.frames.subscribe()
    }

    /// Waits until the front is at `version` or newer.
    pub async fn wait_for_version(
        &self,
        version: u64,
        timeout: Duration,
    ) -> Result<Arc<Frame>, ClientError> {
        let mut frames = self.subscribe();
        let wait = frames.wait_for(|f| f.as_ref().is_some_and(|f| f.version() >= version));
        match tokio::time::timeout(timeout, wait).await {
            Ok(Ok(frame)) => Ok(frame.clone().ok_or(ClientError::Closed)?),
            Ok(Err(_)) => Err(ClientError::Closed),
            Err(_) => Err(ClientError::Timeout {
                what: format!(
                    "{}: waiting for lightmap version {version} (holding {:?})",
                    self.shared.endpoint,
                    self.version()
                ),
                seconds: timeout.as_secs_f64(),
            }),
        }
    }

    /// The server's latest `Stats`.
    pub fn stats(&self) -> Option<Stats> {
        *self.shared.stats.borrow()
    }

    /// Counts since `connect`.
    pub fn counters(&self) -> Counters {
        self.shared.counters.snapshot()
    }

    /// The send-time book this client measures latency with.
    pub fn latency_book(&self) -> &Arc<LatencyBook> {
        &self.shared.latency
    }

    /// The index of the object called `name`.
    pub fn object_index(&self, name: &str) -> Option<u32> {
        let scene = self.scene();
        scene
            .objects
            .iter()
            .position(|o| o.name == name)
            .map(|i| i as u32)
    }

    /// Queues `pose` for dynamic object `object` and returns its seq. The
    /// newest pose per object wins: one not yet written to the socket is
    /// replaced (and counted in [`Counters::poses_coalesced`]). Checked
    /// here like the server would: the role, the object, the pose.
    pub fn send_pose(&self, object: u32, pose: Pose) -> Result<u64, ClientError> {
        let role = self.role();
        if role == Role::Viewer {
            return Err(ClientError::Forbidden { role });
        }
        let scene = self.scene();
        match scene.objects.get(object as usize) {
            None => {
                return Err(ClientError::UnknownObject {
                    object: object.to_string(),
                    reason: format!("scene \"{}\" has {} objects", scene.id, scene.objects.len()),
                });
            }
            Some(o) if !o.dynamic => {
                return Err(ClientError::UnknownObject {
                    object: format!("{object} (\"{}\")", o.name),
                    reason: format!("not a dynamic object of scene \"{}\"", scene.id),
                });
            }
            Some(_) => {}
        }
        pose.validate()
            .map_err(|reason| ClientError::InvalidPose { object, reason })?;
        if self.task.as_ref().is_none_or(|t| t.is_finished()) {
            return Err(ClientError::Closed);
        }
        let seq = self.shared.seqs.next();
        let replaced = self
            .shared
            .outbox
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .insert(object, (seq, pose));
        if replaced.is_some() {
            self.shared
                .counters
                .poses_coalesced
                .fetch_add(1, Ordering::Relaxed);
        }
        self.shared.outbox_ready.notify_one();
        Ok(seq)
    }

    /// [`Client::send_pose`] by object name.
    pub fn send_pose_named(&self, name: &str, pose: Pose) -> Result<u64, ClientError> {
        let object = self
            .object_index(name)
            .ok_or_else(|| ClientError::UnknownObject {
                object: format!("{name:?}"),
                reason: format!("scene \"{}\" has no object by that name", self.scene().id),
            })?;
        self.send_pose(object, pose)
    }

    /// The next event; `None` once the task has ended and every event was
    /// read.
    pub async fn next_event(&mut self) -> Option<Event> {
        self.events.recv().await
    }

    /// An event if one is waiting.
    pub fn try_next_event(&mut self) -> Option<Event> {
        self.events.try_recv().ok()
    }

    /// Whether the background task still runs (it ends on close or a
    /// permanent error).
    pub fn is_running(&self) -> bool {
        self.task.as_ref().is_some_and(|t| !t.is_finished())
    }

    /// Closes the socket (with a close frame) and waits for the task.
    pub async fn close(mut self) {
        let _ = self.shutdown.send(true);
        if let Some(task) = self.task.take() {
            let _ = task.await;
        }
    }
}

impl Drop for Client {
    fn drop(&mut self) {
        // The task sees this and closes the socket itself.
        let _ = self.shutdown.send(true);
    }
}
