//! Transforms and light states accepted from drivers, waiting for whoever
//! consumes them: the tick thread of `lightwire serve`, or the upstream
//! connection of `lightwire relay`, which forwards them to its solver.

use std::sync::{Condvar, Mutex};
use std::time::Instant;

use lightwire_protocol::{LightState, Pose, seq_is_newer};
use tokio::sync::Notify;

/// A pose waiting to be consumed: already checked
/// ([`super::wire::check_transform`]), in wire form so that a relay
/// forwards exactly the bits its driver sent.
#[derive(Debug, Clone, Copy)]
pub struct PendingPose {
    pub seq: u64,
    pub pose: Pose,
}

/// A light state waiting to be consumed, already checked
/// ([`super::wire::check_light`]).
#[derive(Debug, Clone, Copy)]
pub struct PendingLight {
    pub seq: u64,
    pub state: LightState,
}

/// Poses and light states from drivers, one slot per object and per
/// light: the newest seq wins (serial-number order,
/// [`seq_is_newer`]), so the inbox holds at most one pose per object and
/// one state per light however fast drivers send.
pub struct Inbox {
    slots: Mutex<Slots>,
    /// Wakes an async consumer (the relay) when a pose or light state
    /// arrives.
    arrived: Notify,
    /// Wakes the tick thread waiting between ticks
    /// ([`Inbox::wait_until`]) when a pose arrives.
    offered: Condvar,
}

struct Slots {
    pending: Vec<Option<PendingPose>>,
    /// Newest seq accepted per object (also for already-drained slots), so
    /// a stale transform is recognised after its successor was consumed.
    accepted: Vec<u64>,
    /// The same per light.
    lights: Vec<Option<PendingLight>>,
    lights_accepted: Vec<u64>,
    /// Some slot was filled since the last drain.
    fresh: bool,
}

/// What the inbox did with an offered transform.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Offer {
    Accepted,
    /// `seq` is not newer than the last accepted one for this object (light).
    Stale {
        latest: u64,
    },
    /// The index is beyond the objects this inbox was sized for (a relay's
    /// scene can change under a session; the session checked an older
    /// description).
    UnknownObject,
}

impl Inbox {
    /// An inbox for `objects` objects and no lights.
    pub fn new(objects: usize) -> Self {
        Self::with_lights(objects, 0)
    }

    /// An inbox for `objects` objects and `lights` lights.
    pub fn with_lights(objects: usize, lights: usize) -> Self {
        Self {
            slots: Mutex::new(Slots {
                pending: vec![None; objects],
                accepted: vec![0; objects],
                lights: vec![None; lights],
                lights_accepted: vec![0; lights],
                fresh: false,
            }),
            arrived: Notify::new(),
            offered: Condvar::new(),
        }
    }

    /// Forgets everything and sizes the inbox for `objects` objects and
    /// `lights` lights (a relay whose upstream now serves a different
    /// scene description).
    pub fn reset(&self, objects: usize, lights: usize) {
        let mut slots = self.slots.lock().unwrap_or_else(|p| p.into_inner());
        slots.pending = vec![None; objects];
        slots.accepted = vec![0; objects];
        slots.lights = vec![None; lights];
        slots.lights_accepted = vec![0; lights];
        slots.fresh = false;
    }

    /// Offers a validated pose for `object`.
    pub fn offer(&self, object: usize, seq: u64, pose: Pose) -> Offer {
        let mut slots = self.slots.lock().unwrap_or_else(|p| p.into_inner());
        let Some(&latest) = slots.accepted.get(object) else {
            return Offer::UnknownObject;
        };
        if !seq_is_newer(seq, latest) {
            return Offer::Stale { latest };
        }
        slots.accepted[object] = seq;
        slots.pending[object] = Some(PendingPose { seq, pose });
        slots.fresh = true;
        drop(slots);
        self.offered.notify_all();
        self.arrived.notify_one();
        Offer::Accepted
    }

    /// Offers a validated state for light `light`.
    pub fn offer_light(&self, light: usize, seq: u64, state: LightState) -> Offer {
        let mut slots = self.slots.lock().unwrap_or_else(|p| p.into_inner());
        let Some(&latest) = slots.lights_accepted.get(light) else {
            return Offer::UnknownObject;
        };
        if !seq_is_newer(seq, latest) {
            return Offer::Stale { latest };
        }
        slots.lights_accepted[light] = seq;
        slots.lights[light] = Some(PendingLight { seq, state });
        slots.fresh = true;
        drop(slots);
        self.offered.notify_all();
        self.arrived.notify_one();
        Offer::Accepted
    }

    /// Takes every pending light state, by light index.
    pub fn drain_lights(&self) -> Vec<(usize, PendingLight)> {
        let mut slots = self.slots.lock().unwrap_or_else(|p| p.into_inner());
        slots
            .lights
            .iter_mut()
            .enumerate()
            .filter_map(|(i, s)| s.take().map(|p| (i, p)))
            .collect()
    }

    /// Takes every pending pose, by object index.
    pub fn drain(&self) -> Vec<(usize, PendingPose)> {
        let mut slots = self.slots.lock().unwrap_or_else(|p| p.into_inner());
        slots.fresh = false;
        slots
            .pending
            .iter_mut()
            .enumerate()
            .filter_map(|(i, s)| s.take().map(|p| (i, p)))
            .collect()
    }

    /// Blocks until a pose is waiting to be drained or `deadline` passes;
    /// returns whether one is waiting. For the tick thread, which sleeps
    /// between ticks here, so that a transform starts its work at once
    /// instead of at the next tick.
    pub fn wait_until(&self, deadline: Instant) -> bool {
        let mut slots = self.slots.lock().unwrap_or_else(|p| p.into_inner());
        while !slots.fresh {
            let now = Instant::now();
            if now >= deadline {
                return false;
            }
            slots = self
                .offered
                .wait_timeout(slots, deadline - now)
                .unwrap_or_else(|p| p.into_inner())
                .0;
        }
        true
    }

    /// Resolves when a pose or light state was offered since the last call (a permit is
    /// stored if none was waiting, so no arrival is missed).
    pub async fn arrived(&self) {
        self.arrived.notified().await;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose() -> Pose {
        Pose {
            translation: [0.0; 3],
            rotation: [0.0, 0.0, 0.0, 1.0],
            scale: 1.0,
        }
    }

    #[test]
    fn the_newest_seq_wins_and_stale_ones_are_named() {
        let inbox = Inbox::new(2);
        assert_eq!(inbox.offer(1, 5, pose()), Offer::Accepted);
        assert_eq!(inbox.offer(1, 7, pose()), Offer::Accepted);
        assert_eq!(inbox.offer(1, 6, pose()), Offer::Stale { latest: 7 });
        let drained = inbox.drain();
        assert_eq!(drained.len(), 1, "one slot per object");
        assert_eq!((drained[0].0, drained[0].1.seq), (1, 7));
        // Still stale after the slot was drained.
        assert_eq!(inbox.offer(1, 7, pose()), Offer::Stale { latest: 7 });
        assert!(inbox.drain().is_empty());
    }

    /// The tick thread's wait ends when a pose arrives, not at its
    /// deadline, and a pose already waiting ends it at once; once drained,
    /// the wait runs to the deadline.
    #[test]
    fn a_waiting_tick_thread_wakes_when_a_pose_arrives() {
        use std::sync::Arc;
        use std::time::Duration;
        let inbox = Arc::new(Inbox::new(1));
        let far = Instant::now() + Duration::from_secs(30);
        let offering = inbox.clone();
        let sender = std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(20));
            offering.offer(0, 1, pose())
        });
        assert!(inbox.wait_until(far), "woken by the offer");
        assert!(Instant::now() < far);
        assert_eq!(sender.join().ok(), Some(Offer::Accepted));
        assert!(inbox.wait_until(far), "still waiting to be drained");
        assert_eq!(inbox.drain().len(), 1);
        let soon = Instant::now() + Duration::from_millis(10);
        assert!(!inbox.wait_until(soon), "nothing new: runs to the deadline");
        assert!(Instant::now() >= soon);
    }

    /// Whatever seq a driver sends, the next one is newer: a transform or
    /// light state with seq 2^64 − 1 does not freeze its object or light.
    #[test]
    fn no_seq_freezes_an_object_or_a_light() {
        let inbox = Inbox::with_lights(1, 1);
        let state = LightState {
            on: true,
            color: [1.0; 3],
            intensity: 1.0,
            position: [0.0; 3],
            direction: [0.0, -1.0, 0.0],
        };
        // The largest seq is not newer than 0 (half the circle or more
        // ahead): no single message reaches it...
        assert_eq!(inbox.offer(0, u64::MAX, pose()), Offer::Stale { latest: 0 });
        // ...but steps of less than half the circle do, and then the
        // values after it (0, 1, ...) are newer still.
        for seq in [1 << 62, 1 << 63, u64::MAX] {
            assert_eq!(inbox.offer(0, seq, pose()), Offer::Accepted, "{seq}");
        }
        assert_eq!(
            inbox.offer(0, u64::MAX - 1, pose()),
            Offer::Stale { latest: u64::MAX }
        );
        assert_eq!(
            inbox.offer(0, 0, pose()),
            Offer::Accepted,
            "0 follows 2^64 - 1"
        );
        assert_eq!(inbox.offer(0, 1, pose()), Offer::Accepted);
        for seq in [1 << 62, 1 << 63, u64::MAX, 3] {
            assert_eq!(inbox.offer_light(0, seq, state), Offer::Accepted, "{seq}");
        }
        assert_eq!(inbox.offer_light(0, 2, state), Offer::Stale { latest: 3 });
        assert_eq!(inbox.drain_lights().len(), 1, "one slot per light");
        assert_eq!(inbox.offer_light(1, 1, state), Offer::UnknownObject);
    }

    #[test]
    fn an_index_beyond_the_objects_is_refused_not_a_panic() {
        let inbox = Inbox::new(1);
        assert_eq!(inbox.offer(3, 1, pose()), Offer::UnknownObject);
        let state = LightState {
            on: true,
            color: [1.0; 3],
            intensity: 1.0,
            position: [0.0; 3],
            direction: [0.0, -1.0, 0.0],
        };
        assert_eq!(inbox.offer_light(0, 1, state), Offer::UnknownObject);
        // A relay's inbox is sized by its upstream's description, lights
        // too (it forwards them).
        inbox.reset(4, 1);
        assert_eq!(inbox.offer(3, 1, pose()), Offer::Accepted);
        assert_eq!(inbox.offer_light(0, 1, state), Offer::Accepted);
        assert_eq!(inbox.offer_light(1, 1, state), Offer::UnknownObject);
    }
}
