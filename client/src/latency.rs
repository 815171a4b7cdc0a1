//! Transform-to-light latency: when was the pose that a lightmap version
//! reflects sent?
//!
//! Every published keyframe and delta lists in `reflected` the newest
//! transform `seq` per object it includes (PROTOCOL.md §1.7). A client that
//! remembers when it sent `(object, seq)` can therefore tell, when a frame
//! echoing that seq is applied, how long the light took to follow the move.
//! [`LatencyBook`] is that memory: a bounded map from `(object, seq)` to
//! the send instant. It is shared (`Arc`) so that the many connections of
//! a load test measure delivery of any driver's pose to every viewer.
//!
//! Light states work alike: `Lights` lists the `SetLight` seq each
//! light's state came from, and the version it precedes is the first lit
//! with it; the book keeps their send times apart from the transforms'
//! ([`LatencyBook::record_light_sent`], [`LatencyBook::light_latency`]).
//!
//! The book is bounded: beyond its capacity the oldest entries are
//! forgotten (their deliveries then report no latency), so a long-running
//! driver uses constant memory however many frames it sends.
//!
//! [`SeqSource`] hands out the `seq`s: Unix time in microseconds, bumped to
//! stay strictly increasing. Seqs that are timestamps keep growing across
//! reconnects and client restarts (the server refuses a seq that is not
//! newer than the last accepted one, `StaleSeq`), and the dashboard uses
//! the same convention, so a passive watcher on a synchronised clock can
//! estimate latency from a seq alone ([`seq_clock_age`]).

use std::collections::{HashMap, VecDeque};
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// The default capacity of a [`LatencyBook`]: at 30 poses/s and two
/// drivers, about a minute of history.
pub const DEFAULT_LATENCY_BOOK_CAPACITY: usize = 4096;

/// Send instants of recent transforms, bounded; see the module docs.
#[derive(Debug)]
pub struct LatencyBook {
    capacity: usize,
    inner: Mutex<BookInner>,
}

#[derive(Debug, Default)]
struct BookInner {
    sent: HashMap<Sent, Instant>,
    /// Insertion order, for evicting the oldest entry first.
    order: VecDeque<Sent>,
}

/// What was sent: a transform of an object or a state of a light, with
/// its seq (objects and lights are numbered apart).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum Sent {
    Transform(u32, u64),
    Light(u32, u64),
}

impl LatencyBook {
    /// An empty book that remembers at most `capacity` (>= 1) transforms.
    pub fn new(capacity: usize) -> Self {
        LatencyBook {
            capacity: capacity.max(1),
            inner: Mutex::new(BookInner::default()),
        }
    }

    /// Remembers that transform `seq` of `object` was sent at `at`,
    /// forgetting the oldest entry if the book is full. Recording the same
    /// key again keeps the first instant.
    pub fn record_sent(&self, object: u32, seq: u64, at: Instant) {
        self.record(Sent::Transform(object, seq), at);
    }

    /// When transform `seq` of `object` was sent, if still remembered.
    pub fn sent_at(&self, object: u32, seq: u64) -> Option<Instant> {
        self.lookup(Sent::Transform(object, seq))
    }

    /// `delivered - sent` for a remembered transform.
    pub fn latency(&self, object: u32, seq: u64, delivered: Instant) -> Option<Duration> {
        self.sent_at(object, seq)
            .map(|sent| delivered.saturating_duration_since(sent))
    }

    /// Remembers that `SetLight` `seq` of light `light` was sent at `at`
    /// (as [`LatencyBook::record_sent`], in the same bounded book).
    pub fn record_light_sent(&self, light: u32, seq: u64, at: Instant) {
        self.record(Sent::Light(light, seq), at);
    }

    /// When `SetLight` `seq` of `light` was sent, if still remembered.
    pub fn light_sent_at(&self, light: u32, seq: u64) -> Option<Instant> {
        self.lookup(Sent::Light(light, seq))
    }

    /// `delivered - sent` for a remembered light state.
    pub fn light_latency(&self, light: u32, seq: u64, delivered: Instant) -> Option<Duration> {
        self.light_sent_at(light, seq)
            .map(|sent| delivered.saturating_duration_since(sent))
    }

    fn record(&self, key: Sent, at: Instant) {
        let mut inner = self.inner.lock().unwrap_or_else(|p| p.into_inner());
        if inner.sent.contains_key(&key) {
            return;
        }
        while inner.order.len() >= self.capacity {
            if let Some(old) = inner.order.pop_front() {
                inner.sent.remove(&old);
            }
        }
        inner.sent.insert(key, at);
        inner.order.push_back(key);
    }

    fn lookup(&self, key: Sent) -> Option<Instant> {
        let inner = self.inner.lock().unwrap_or_else(|p| p.into_inner());
        inner.sent.get(&key).copied()
    }

    /// Entries currently remembered (at most the capacity).
    pub fn len(&self) -> usize {
        self.inner
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .order
            .len()
    }

    /// Whether nothing is remembered.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The most entries this book keeps.
    pub fn capacity(&self) -> usize {
        self.capacity
    }
}

impl Default for LatencyBook {
    fn default() -> Self {
        LatencyBook::new(DEFAULT_LATENCY_BOOK_CAPACITY)
    }
}

/// Strictly increasing transform seqs that are Unix time in microseconds
/// (see the module docs). Share one between drivers of the same object so
/// that their seqs never collide.
#[derive(Debug, Default)]
pub struct SeqSource {
    last: AtomicU64,
}

impl SeqSource {
    /// A source starting from the current time.
    pub fn new() -> Self {
        SeqSource::default()
    }

    /// The next seq: `max(now_us, previous + 1)`.
    pub fn next(&self) -> u64 {
        let now = unix_micros();
        let mut prev = self.last.load(Ordering::Relaxed);
        loop {
            let next = now.max(prev.saturating_add(1));
            match self
                .last
                .compare_exchange_weak(prev, next, Ordering::Relaxed, Ordering::Relaxed)
            {
                Ok(_) => return next,
                Err(actual) => prev = actual,
            }
        }
    }
}

pub use lightwire_protocol::unix_micros;

/// How old a seq is if it follows the "seq = Unix µs at send" convention:
/// `Some(now - seq)` when that is between 0 and 10 minutes, else `None`
/// (the seq is a plain counter, or the clocks disagree). An estimate for
/// passive watchers; drivers use the exact [`LatencyBook`].
pub fn seq_clock_age(seq: u64, now_us: u64) -> Option<Duration> {
    let age = now_us.checked_sub(seq)?;
    (age <= 600_000_000).then(|| Duration::from_micros(age))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_book_measures_send_to_delivery_and_stays_bounded() {
        let book = LatencyBook::new(3);
        let t0 = Instant::now();
        for seq in 1..=5u64 {
            book.record_sent(1, seq, t0 + Duration::from_millis(seq * 10));
        }
        assert_eq!(book.len(), 3, "capacity bounds the book");
        assert_eq!(book.sent_at(1, 1), None, "the oldest entries are forgotten");
        assert_eq!(book.sent_at(1, 2), None);
        assert_eq!(
            book.latency(1, 4, t0 + Duration::from_millis(65)),
            Some(Duration::from_millis(25))
        );
        assert_eq!(book.latency(2, 4, t0), None, "objects are keyed separately");
        assert_eq!(book.light_sent_at(1, 4), None, "lights apart from objects");
        book.record_light_sent(1, 4, t0);
        assert_eq!(
            book.light_latency(1, 4, t0 + Duration::from_millis(7)),
            Some(Duration::from_millis(7))
        );
        assert_eq!(
            book.sent_at(1, 3),
            None,
            "the light's entry evicted the oldest"
        );
        assert_eq!(book.sent_at(1, 4), Some(t0 + Duration::from_millis(40)));
        // A delivery "before" the send (clock quirks) is zero, not a panic.
        assert_eq!(book.latency(1, 5, t0), Some(Duration::ZERO));
        // Re-recording keeps the first send time.
        book.record_sent(1, 5, t0 + Duration::from_secs(9));
        assert_eq!(book.sent_at(1, 5), Some(t0 + Duration::from_millis(50)));
    }

    #[test]
    fn seqs_strictly_increase_across_threads_and_look_like_the_clock() {
        let source = std::sync::Arc::new(SeqSource::new());
        let start = unix_micros();
        let threads: Vec<_> = (0..4)
            .map(|_| {
                let s = source.clone();
                std::thread::spawn(move || (0..1000).map(|_| s.next()).collect::<Vec<_>>())
            })
            .collect();
        let mut all: Vec<u64> = Vec::new();
        for t in threads {
            let seqs = t.join().expect("thread");
            assert!(
                seqs.windows(2).all(|w| w[0] < w[1]),
                "per thread increasing"
            );
            all.extend(seqs);
        }
        let n = all.len();
        all.sort_unstable();
        all.dedup();
        assert_eq!(all.len(), n, "no seq handed out twice");
        assert!(all[0] >= start, "seqs are Unix microseconds");
        assert!(seq_clock_age(all[0], unix_micros()).is_some());
        assert_eq!(
            seq_clock_age(7, unix_micros()),
            None,
            "a counter is not a time"
        );
        assert_eq!(
            seq_clock_age(unix_micros() + 5_000_000, unix_micros()),
            None
        );
    }
}
