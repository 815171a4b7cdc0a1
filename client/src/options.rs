//! Connection settings: what [`Client::connect_with`](crate::Client::connect_with)
//! takes and the connection task reads for every (re)connect.

use std::sync::Arc;
use std::time::Duration;

use lightwire_protocol::backoff::BackoffPolicy;

use crate::latency::{LatencyBook, SeqSource};

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
    /// Ask the server for the lights' states (`Hello` sets `HELLO_LIGHTS`):
    /// every [`Frame`](crate::Frame) then carries the states its version
    /// was lit with ([`Frame::lights`](crate::Frame::lights)), and
    /// [`VersionEvent::lights_delivered`](crate::VersionEvent::lights_delivered)
    /// the `SetLight`s it newly shows. A client that sets lights wants
    /// this; one that only watches or moves objects need not (default
    /// false: the server sends it no `Lights`).
    pub lights: bool,
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
            lights: false,
        }
    }
}
