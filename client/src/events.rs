//! What the connection task tells the application: the [`Event`]s that
//! [`Client::next_event`](crate::Client::next_event) returns, and the
//! transforms and light states a new version delivered.

use std::sync::Arc;
use std::time::Duration;

use lightwire_protocol::{ErrorCode, Role, SceneInfo, Stats};

use crate::error::ClientError;

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
        /// The scene (a new `Arc` if the `Welcome` differs; compare with
        /// [`SceneInfo::same_description`] to tell another scene from the
        /// same one whose lights changed state meanwhile, which keeps the
        /// lightmap).
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
    /// the send time is known to this client's
    /// [`LatencyBook`](crate::latency::LatencyBook).
    pub delivered: Vec<Delivered>,
    /// Light states this version is the first to show (from the `Lights`
    /// before it; only for a client that asked,
    /// [`Options::lights`](crate::Options::lights)), with the latency of
    /// the `SetLight`s whose send time the book knows.
    pub lights_delivered: Vec<LightDelivered>,
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

/// One light state that reached the light.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LightDelivered {
    /// Light index.
    pub light: u32,
    /// The `SetLight`'s seq (0: the scene file's state).
    pub seq: u64,
    /// Send to applied (the first version lit with it), if the send time
    /// is known.
    pub latency: Option<Duration>,
}
