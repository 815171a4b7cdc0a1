//! One scene as sessions see it.
//!
//! A [`Feed`] is everything a [`super::session`] needs: what the scene
//! looks like (for `Welcome`), the newest publication, statistics, and the
//! [`Inbox`] that accepted transforms go to. `lightwire serve` fills it from
//! a solver's tick thread ([`super::runtime`]); `lightwire relay` fills it
//! from an upstream connection to a solver (`crate::relay`). Sessions cannot
//! tell the two apart, which is what lets the relay reuse every rule of a
//! session (handshake, roles, limits, delta-or-keyframe) without a copy.

use std::sync::atomic::{AtomicBool, AtomicU32};
use std::sync::{Arc, Mutex};

use lightwire_protocol::{SceneInfo, Stats};
use tokio::sync::watch;

use super::inbox::Inbox;
use super::publication::Publication;

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
    /// A lightmap version exists (readiness).
    pub ready: AtomicBool,
    /// Why transforms are refused right now, if they are: a relay whose
    /// upstream token grants only the viewer role cannot forward them, and
    /// says so to its drivers instead of accepting poses that go nowhere.
    pub transforms_refused: Mutex<Option<String>>,
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
        Self {
            id,
            info: watch::Sender::new(info),
            publications,
            stats,
            inbox: Inbox::new(objects),
            clients: AtomicU32::new(0),
            ready: AtomicBool::new(false),
            transforms_refused: Mutex::new(None),
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

    /// Why transforms are refused now, if they are.
    pub fn transforms_refused(&self) -> Option<String> {
        self.transforms_refused
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }
}
