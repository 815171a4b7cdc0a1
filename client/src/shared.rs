//! The state a [`Client`](crate::Client) handle and its connection task
//! share:
//!
//! - the **front** lightmap, a `watch` of `Arc<Frame>` (newest only), which
//!   renderers read without locking;
//! - the scene (a `watch`, replaced only when a reconnect's `Welcome`
//!   differs: another scene, or the same one with its lights in other
//!   states), the role and the server's capabilities;
//! - the **outbox** of poses to send: one slot per object, newest wins;
//!   and of light states: one slot per light of the scene, newest wins;
//! - per light, the newest seq seen in a `Lights` or handed out, which
//!   the next `SetLight`'s seq must be newer than;
//! - counters and the latest `Stats`;
//! - the [`LatencyBook`] of send times.
//!
//! Everything else the task reports goes through a bounded event channel
//! ([`crate::Event`]); it is not kept here.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use lightwire_protocol::{LightState, LightStatus, Pose, Role, SceneInfo, Stats, seq_is_newer};
use tokio::sync::{Notify, watch};

use crate::buffer::Frame;
use crate::endpoint::Endpoint;
use crate::latency::{LatencyBook, SeqSource};

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
    /// `SetLight`s written to the socket.
    pub lights_sent: u64,
    /// Light states replaced in the outbox by a newer one before being
    /// sent.
    pub lights_coalesced: u64,
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
    pub lights_sent: AtomicU64,
    pub lights_coalesced: AtomicU64,
    pub events_dropped: AtomicU64,
}

impl AtomicCounters {
    pub(crate) fn snapshot(&self) -> Counters {
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
            lights_sent: get(&self.lights_sent),
            lights_coalesced: get(&self.lights_coalesced),
            events_dropped: get(&self.events_dropped),
        }
    }
}

/// What the handle and the task share; see the module docs.
pub(crate) struct Shared {
    pub endpoint: Endpoint,
    pub scene: watch::Sender<Arc<SceneInfo>>,
    role: Mutex<Role>,
    /// The latest `Welcome`'s capabilities.
    capabilities: AtomicU32,
    pub frames: watch::Sender<Option<Arc<Frame>>>,
    pub stats: watch::Sender<Option<Stats>>,
    pub counters: AtomicCounters,
    /// Events dropped that a `Lagged` event has already reported.
    pub lag_reported: AtomicU64,
    /// Newest pose per object, waiting for the socket: (seq, pose).
    outbox: Mutex<BTreeMap<u32, (u64, Pose)>>,
    /// Newest state per light, waiting for the socket: (seq, state).
    light_outbox: Mutex<BTreeMap<u32, (u64, LightState)>>,
    /// Per light, the newest seq (serial-number order) seen in a `Lights`
    /// or handed out by `queue_light`.
    light_seqs: Mutex<BTreeMap<u32, u64>>,
    pub outbox_ready: Notify,
    pub latency: Arc<LatencyBook>,
    seqs: Arc<SeqSource>,
}

impl Shared {
    /// The state of a client whose first session was welcomed with `scene`
    /// and `role`: no frame, no stats, an empty outbox.
    pub(crate) fn new(
        endpoint: Endpoint,
        scene: Arc<SceneInfo>,
        role: Role,
        capabilities: u32,
        latency: Arc<LatencyBook>,
        seqs: Arc<SeqSource>,
    ) -> Shared {
        Shared {
            endpoint,
            scene: watch::Sender::new(scene),
            role: Mutex::new(role),
            capabilities: AtomicU32::new(capabilities),
            frames: watch::Sender::new(None),
            stats: watch::Sender::new(None),
            counters: AtomicCounters::default(),
            lag_reported: AtomicU64::new(0),
            outbox: Mutex::new(BTreeMap::new()),
            light_outbox: Mutex::new(BTreeMap::new()),
            light_seqs: Mutex::new(BTreeMap::new()),
            outbox_ready: Notify::new(),
            latency,
            seqs,
        }
    }

    pub(crate) fn set_role(&self, role: Role) {
        *self.role.lock().unwrap_or_else(|p| p.into_inner()) = role;
    }

    pub(crate) fn role(&self) -> Role {
        *self.role.lock().unwrap_or_else(|p| p.into_inner())
    }

    pub(crate) fn set_capabilities(&self, capabilities: u32) {
        self.capabilities.store(capabilities, Ordering::Relaxed);
    }

    pub(crate) fn capabilities(&self) -> u32 {
        self.capabilities.load(Ordering::Relaxed)
    }

    /// Puts `pose` in `object`'s outbox slot under a new seq, replacing
    /// (and counting in `poses_coalesced`) a pose not yet sent, wakes the
    /// task, and returns the seq.
    pub(crate) fn queue_pose(&self, object: u32, pose: Pose) -> u64 {
        let seq = self.seqs.next();
        let replaced = self
            .outbox
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .insert(object, (seq, pose));
        if replaced.is_some() {
            self.counters
                .poses_coalesced
                .fetch_add(1, Ordering::Relaxed);
        }
        self.outbox_ready.notify_one();
        seq
    }

    pub(crate) fn take_outbox(&self) -> BTreeMap<u32, (u64, Pose)> {
        std::mem::take(&mut *self.outbox.lock().unwrap_or_else(|p| p.into_inner()))
    }

    /// Puts `state` in `light`'s outbox slot under a new seq, replacing
    /// (and counting in `lights_coalesced`) a state not yet sent, wakes
    /// the task, and returns the seq.
    ///
    /// The seq is the clock's ([`SeqSource`]), unless that is not newer,
    /// in serial-number order, than the newest seq this client saw for
    /// the light in a `Lights` or handed out before: then that one plus
    /// one. So another driver's seq (a counter, or one far ahead) never
    /// makes this client's states stale.
    pub(crate) fn queue_light(&self, light: u32, state: LightState) -> u64 {
        let clock = self.seqs.next();
        let seq = {
            let mut seqs = self.light_seqs.lock().unwrap_or_else(|p| p.into_inner());
            let latest = seqs.get(&light).copied().unwrap_or(0);
            let seq = if seq_is_newer(clock, latest) {
                clock
            } else {
                latest.wrapping_add(1)
            };
            seqs.insert(light, seq);
            seq
        };
        let replaced = self
            .light_outbox
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .insert(light, (seq, state));
        if replaced.is_some() {
            self.counters
                .lights_coalesced
                .fetch_add(1, Ordering::Relaxed);
        }
        self.outbox_ready.notify_one();
        seq
    }

    pub(crate) fn take_light_outbox(&self) -> BTreeMap<u32, (u64, LightState)> {
        std::mem::take(&mut *self.light_outbox.lock().unwrap_or_else(|p| p.into_inner()))
    }

    /// Takes in the seqs of a `Lights` message: each light's newest seq
    /// becomes the floor for the next `SetLight` of it.
    pub(crate) fn saw_lights(&self, lights: &[LightStatus]) {
        let mut seqs = self.light_seqs.lock().unwrap_or_else(|p| p.into_inner());
        for l in lights {
            let latest = seqs.entry(l.light).or_insert(0);
            if seq_is_newer(l.seq, *latest) {
                *latest = l.seq;
            }
        }
    }
}
