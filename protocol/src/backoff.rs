//! Reconnect delays: exponential, capped, jittered.
//!
//! When a server restarts, every client notices at once. Without jitter
//! they would all reconnect in the same millisecond, again and again; with
//! a random factor in `[1 - jitter, 1 + jitter]` their attempts spread out.
//! The cap keeps a client from waiting minutes after a long outage, and
//! [`Backoff::reset`] (called once a session has delivered a lightmap)
//! makes the next outage start from the short delay again.

use std::time::Duration;

/// The reconnect policy; see the module docs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BackoffPolicy {
    /// Delay before the first reconnect attempt.
    pub initial: Duration,
    /// Largest delay before any attempt (before jitter).
    pub max: Duration,
    /// Each failed attempt multiplies the delay by this (>= 1).
    pub factor: f64,
    /// Relative jitter in [0, 1): the delay is scaled by a random factor
    /// in `[1 - jitter, 1 + jitter]`.
    pub jitter: f64,
    /// Give up after this many consecutive failed attempts (`None`: never).
    pub max_attempts: Option<u32>,
}

impl Default for BackoffPolicy {
    fn default() -> Self {
        BackoffPolicy {
            initial: Duration::from_millis(100),
            max: Duration::from_secs(5),
            factor: 2.0,
            jitter: 0.2,
            max_attempts: None,
        }
    }
}

/// The state of one client's reconnect sequence.
#[derive(Debug)]
pub struct Backoff {
    policy: BackoffPolicy,
    /// Consecutive attempts since the last reset.
    attempts: u32,
    rng: fastrand::Rng,
}

impl Backoff {
    /// A fresh sequence (the next delay is `policy.initial`, jittered).
    pub fn new(policy: BackoffPolicy) -> Self {
        Backoff {
            policy,
            attempts: 0,
            rng: fastrand::Rng::new(),
        }
    }

    /// Like [`Backoff::new`] with a fixed random seed (for tests).
    pub fn with_seed(policy: BackoffPolicy, seed: u64) -> Self {
        Backoff {
            policy,
            attempts: 0,
            rng: fastrand::Rng::with_seed(seed),
        }
    }

    /// The delay before the next attempt, or `None` once
    /// `max_attempts` consecutive attempts have been used up.
    pub fn next_delay(&mut self) -> Option<Duration> {
        if self
            .policy
            .max_attempts
            .is_some_and(|max| self.attempts >= max)
        {
            return None;
        }
        let base = self.policy.initial.as_secs_f64()
            * self
                .policy
                .factor
                .max(1.0)
                .powi(self.attempts.min(64) as i32);
        let capped = base.min(self.policy.max.as_secs_f64());
        let jitter = self.policy.jitter.clamp(0.0, 0.99);
        let scale = 1.0 + jitter * (2.0 * self.rng.f64() - 1.0);
        self.attempts = self.attempts.saturating_add(1);
        Some(Duration::from_secs_f64(capped * scale))
    }

    /// Consecutive attempts since the last reset.
    pub fn attempts(&self) -> u32 {
        self.attempts
    }

    /// Starts over: called after a session that got somewhere.
    pub fn reset(&mut self) {
        self.attempts = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn delays_grow_exponentially_stay_within_jittered_bounds_and_cap() {
        let policy = BackoffPolicy::default();
        for seed in 0..50 {
            let mut b = Backoff::with_seed(policy, seed);
            for attempt in 0..20 {
                let d = b.next_delay().expect("unlimited attempts").as_secs_f64();
                let nominal = (0.1 * 2f64.powi(attempt)).min(5.0);
                assert!(
                    d >= nominal * 0.8 - 1e-9 && d <= nominal * 1.2 + 1e-9,
                    "attempt {attempt}: {d} s outside {nominal} s +- 20%"
                );
            }
        }
    }

    #[test]
    fn jitter_spreads_simultaneous_clients() {
        let policy = BackoffPolicy::default();
        let delays: std::collections::BTreeSet<_> = (0..20)
            .map(|seed| Backoff::with_seed(policy, seed).next_delay().expect("some"))
            .collect();
        assert!(
            delays.len() > 10,
            "20 clients should not all pick the same delay: {delays:?}"
        );
    }

    #[test]
    fn reset_starts_over_and_max_attempts_gives_up() {
        let policy = BackoffPolicy {
            jitter: 0.0,
            max_attempts: Some(3),
            ..BackoffPolicy::default()
        };
        let mut b = Backoff::new(policy);
        let first: Vec<_> = (0..3).map(|_| b.next_delay()).collect();
        assert_eq!(
            first,
            [100, 200, 400].map(|ms| Some(Duration::from_millis(ms)))
        );
        assert_eq!(b.next_delay(), None, "gives up after 3 attempts");
        b.reset();
        assert_eq!(b.next_delay(), Some(Duration::from_millis(100)));
    }
}
