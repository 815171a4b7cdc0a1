//! Transforms accepted from drivers, waiting for whoever consumes them: the
//! tick thread of `lightwire serve`, or the upstream connection of
//! `lightwire relay`, which forwards them to its solver.

use std::sync::{Condvar, Mutex};
use std::time::Instant;

use lightwire_protocol::Pose;
use tokio::sync::Notify;

/// A pose waiting to be consumed: already checked
/// ([`super::wire::check_transform`]), in wire form so that a relay
/// forwards exactly the bits its driver sent.
#[derive(Debug, Clone, Copy)]
pub struct PendingPose {
    pub seq: u64,
    pub pose: Pose,
}

/// Poses from drivers, one slot per object: the newest seq wins, so the
/// inbox holds at most one pose per object however fast drivers send.
pub struct Inbox {
    slots: Mutex<Slots>,
    /// Wakes an async consumer (the relay) when a pose arrives.
    arrived: Notify,
    /// Wakes the tick thread waiting between ticks
    /// ([`Inbox::wait_until`]) when a pose arrives.
    offered: Condvar,
}

struct Slots {
    pending: Vec<Option<PendingPose>>,
    /// Highest seq accepted per object (also for already-drained slots), so
    /// a stale transform is recognised after its successor was consumed.
    accepted: Vec<u64>,
    /// Some slot was filled since the last drain.
    fresh: bool,
}

/// What the inbox did with an offered transform.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Offer {
    Accepted,
    /// `seq` is not newer than the last accepted one for this object.
    Stale {
        latest: u64,
    },
    /// The index is beyond the objects this inbox was sized for (a relay's
    /// scene can change under a session; the session checked an older
    /// description).
    UnknownObject,
}

impl Inbox {
    /// An inbox for `objects` objects.
    pub fn new(objects: usize) -> Self {
        Self {
            slots: Mutex::new(Slots {
                pending: vec![None; objects],
                accepted: vec![0; objects],
                fresh: false,
            }),
            arrived: Notify::new(),
            offered: Condvar::new(),
        }
    }

    /// Forgets everything and sizes the inbox for `objects` objects (a
    /// relay whose upstream now serves a different scene description).
    pub fn reset(&self, objects: usize) {
        let mut slots = self.slots.lock().unwrap_or_else(|p| p.into_inner());
        slots.pending = vec![None; objects];
        slots.accepted = vec![0; objects];
        slots.fresh = false;
    }

    /// Offers a validated pose for `object`.
    pub fn offer(&self, object: usize, seq: u64, pose: Pose) -> Offer {
        let mut slots = self.slots.lock().unwrap_or_else(|p| p.into_inner());
        let Some(&latest) = slots.accepted.get(object) else {
            return Offer::UnknownObject;
        };
        if seq <= latest {
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

    /// Resolves when a pose was offered since the last call (a permit is
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

    #[test]
    fn an_index_beyond_the_objects_is_refused_not_a_panic() {
        let inbox = Inbox::new(1);
        assert_eq!(inbox.offer(3, 1, pose()), Offer::UnknownObject);
        inbox.reset(4);
        assert_eq!(inbox.offer(3, 1, pose()), Offer::Accepted);
    }
}
