//! The relay's own metrics, exported next to the session metrics of
//! [`crate::service::metrics::Metrics`] on the same `/metrics`.

use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::registry::Registry;

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
}

impl RelayMetrics {
    /// Registers every metric in `registry` (prefix `lightwire_relay_`).
    pub fn register(&self, registry: &mut Registry) {
        let r = registry.sub_registry_with_prefix("relay");
        r.register(
            "upstreams_connected",
            "Upstream scenes connected now",
            self.upstreams_connected.clone(),
        );
        r.register(
            "upstream_connects",
            "Successful upstream handshakes",
            self.upstream_connects.clone(),
        );
        r.register(
            "upstream_failures",
            "Upstream connections lost or failed (each is retried with backoff)",
            self.upstream_failures.clone(),
        );
        r.register(
            "upstream_frames",
            "Frames received from upstreams",
            self.upstream_frames.clone(),
        );
        r.register(
            "upstream_bytes",
            "Payload bytes received from upstreams",
            self.upstream_bytes.clone(),
        );
        r.register(
            "upstream_bad_frames",
            "Upstream frames refused (undecodable, or not applicable to the relay's state)",
            self.upstream_bad_frames.clone(),
        );
        r.register(
            "upstream_resyncs",
            "Resyncs the relay asked of its upstreams",
            self.upstream_resyncs.clone(),
        );
        r.register(
            "upstream_errors",
            "Error frames received from upstreams (answers to forwarded transforms)",
            self.upstream_errors.clone(),
        );
        r.register(
            "transforms_forwarded",
            "Driver transforms forwarded upstream (after coalescing)",
            self.transforms_forwarded.clone(),
        );
    }
}
