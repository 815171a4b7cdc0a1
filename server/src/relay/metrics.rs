//! The relay's own metrics, exported next to the session metrics of
//! [`crate::service::metrics::Metrics`] on the same `/metrics`.

use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::registry::Registry;

use crate::service::metrics::register_fields;

/// Upstream health and traffic, summed over the relay's upstreams.
#[derive(Default)]
pub struct RelayMetrics {
    /// Upstreams connected now (the relay serves its last version for the
    /// others).
    pub upstreams_connected: Gauge,
    pub upstream_connects: Counter,
    pub upstream_failures: Counter,
    pub upstream_frames: Counter,
    pub upstream_bytes: Counter,
    pub upstream_bad_frames: Counter,
    pub upstream_resyncs: Counter,
    pub upstream_errors: Counter,
    pub transforms_forwarded: Counter,
    pub lights_forwarded: Counter,
}

impl RelayMetrics {
    /// Registers every metric in `registry` (prefix `lightwire_relay_`).
    pub fn register(&self, registry: &mut Registry) {
        let r = registry.sub_registry_with_prefix("relay");
        register_fields! {
            r, self,
            upstreams_connected: "Upstream scenes connected now",
            upstream_connects: "Successful upstream handshakes",
            upstream_failures: "Upstream connections lost or failed (each is retried with backoff)",
            upstream_frames: "Frames received from upstreams",
            upstream_bytes: "Payload bytes received from upstreams",
            upstream_bad_frames: "Upstream frames refused (undecodable, or not applicable to the relay's state)",
            upstream_resyncs: "Resyncs the relay asked of its upstreams",
            upstream_errors: "Error frames received from upstreams (answers to forwarded transforms)",
            transforms_forwarded: "Driver transforms forwarded upstream (after coalescing)",
            lights_forwarded: "Driver light states (SetLight) forwarded upstream (after coalescing)",
        }
    }
}
