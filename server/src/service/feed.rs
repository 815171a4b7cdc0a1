//! One scene as sessions see it.
//!
//! A [`Feed`] is everything a [`super::session`] needs: what the scene
//! looks like (for `Welcome`), the newest publication, statistics, and the
//! [`Inbox`] that accepted transforms go to. `lightwire serve` fills it from
//! a solver's tick thread ([`super::runtime`]); `lightwire relay` fills it
//! from an upstream connection to a solver (`crate::relay`). Sessions cannot
//! tell the two apart, which is what lets the relay reuse every rule of a
//! session (handshake, roles, limits, delta-or-keyframe) without a copy.
//!
//! Readiness ([`Feed::health`]): a scene is *solving* until its first
//! version, then *ready*; a solver's tick loop marks it *failed* (with the
//! reason and since when) while its solver is broken and being rebuilt,
//! and ready again at the rebuilt solver's first version. Sessions keep
//! serving the last publication throughout.

use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::{Arc, Mutex};

use lightwire_protocol::{SceneInfo, Stats};
use tokio::sync::watch;

use super::inbox::Inbox;
use super::publication::Publication;

/// Why a scene's solver is not serving new versions.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Failure {
    /// What failed, in one line (a lost device, a GPU error, a panic).
    pub reason: String,
    /// When the failure was noticed, milliseconds since the Unix epoch.
    pub since_unix_ms: u64,
    /// Rebuilds of the solver tried since.
    pub rebuild_attempts: u32,
}

/// A scene's readiness, as `/readyz` reports it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Health {
    /// Serving versions.
    Ready,
    /// No version yet.
    Solving,
    /// The solver failed; the last version (if any) is still served.
    Failed(Failure),
}

/// One scene's stream, shared by its sessions.
pub struct Feed {
    /// The scene id, the `{id}` of `/ws/scenes/{id}`.
    pub id: String,
    /// What clients need to draw the scene. `None` until known: a relay
    /// learns it from its upstream's `Welcome`. A relay replaces it when
    /// its upstream comes back serving a different description; sessions
    /// that welcomed clients with the old one then close (1012), so that
    /// their clients reconnect and are welcomed with the new one.
    pub info: watch::Sender<Option<Arc<SceneInfo>>>,
    /// The newest complete lightmap version (`None` until the first).
    pub publications: watch::Receiver<Option<Arc<Publication>>>,
    /// Statistics of the newest tick (or, on a relay, the newest upstream
    /// `Stats`, with the relay's own version and client count).
    pub stats: watch::Receiver<Stats>,
    /// Transforms from drivers, one slot per object.
    pub inbox: Inbox,
    /// Connected WebSocket clients.
    pub clients: AtomicU32,
    /// A lightmap version exists and its source is healthy (readiness).
    /// A tick loop clears it while its solver has failed.
    pub ready: AtomicBool,
    /// Set while the solver has failed (see [`Feed::health`]).
    pub failure: Mutex<Option<Failure>>,
    /// Why transforms are refused right now, if they are: a relay whose
    /// upstream token grants only the viewer role cannot forward them, and
    /// says so to its drivers instead of accepting poses that go nowhere.
    pub transforms_refused: Mutex<Option<String>>,
    /// Whether drivers' `SetLight`s are followed and the lights' states
    /// published (`Lights`, `CAP_LIGHTS`): always on a solver's scene; on
    /// a relay while its upstream announces `CAP_LIGHTS` (it forwards them
    /// and passes the upstream's `Lights` on). Without it `SetLight` is
    /// refused with `Forbidden`.
    pub follows_lights: AtomicBool,
}

impl Feed {
    /// A feed for scene `id`; `info` may be unknown yet.
    pub fn new(
        id: String,
        info: Option<Arc<SceneInfo>>,
        publications: watch::Receiver<Option<Arc<Publication>>>,
        stats: watch::Receiver<Stats>,
    ) -> Self {
        let objects = info.as_ref().map_or(0, |i| i.objects.len());
        let lights = info.as_ref().map_or(0, |i| i.lights.len());
        Self {
            id,
            info: watch::Sender::new(info),
            publications,
            stats,
            inbox: Inbox::with_lights(objects, lights),
            clients: AtomicU32::new(0),
            ready: AtomicBool::new(false),
            failure: Mutex::new(None),
            transforms_refused: Mutex::new(None),
            follows_lights: AtomicBool::new(false),
        }
    }

    /// The current scene description.
    pub fn info(&self) -> Option<Arc<SceneInfo>> {
        self.info.borrow().clone()
    }

    /// The newest publication, if any.
    pub fn latest(&self) -> Option<Arc<Publication>> {
        self.publications.borrow().clone()
    }

    /// Ready, solving, or failed with why.
    pub fn health(&self) -> Health {
        let failure = self
            .failure
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone();
        match failure {
            Some(f) => Health::Failed(f),
            None if self.ready.load(Ordering::Acquire) => Health::Ready,
            None => Health::Solving,
        }
    }

    /// Marks the scene failed (not ready) with `failure`, or healthy
    /// again with `None` (ready only once `ready` is set).
    pub fn set_failure(&self, failure: Option<Failure>) {
        let mut slot = self.failure.lock().unwrap_or_else(|p| p.into_inner());
        if failure.is_some() {
            self.ready.store(false, Ordering::Release);
        }
        *slot = failure;
    }

    /// Why transforms are refused now, if they are.
    pub fn transforms_refused(&self) -> Option<String> {
        self.transforms_refused
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }
}
