//! Prometheus metrics for `GET /metrics`.

use std::time::Duration;

use prometheus_client::encoding::EncodeLabelSet;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::metrics::histogram::{Histogram, exponential_buckets};
use prometheus_client::registry::Registry;

/// Label for bad frames: what was wrong.
#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub struct BadFrameLabels {
    pub kind: String,
}

/// Label for per-scene metrics.
#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub struct SceneLabels {
    pub scene: String,
}

/// Every metric the service exports.
pub struct Metrics {
    registry: Registry,
    pub ticks: Counter,
    pub versions_published: Counter,
    pub tick_ms: Histogram,
    pub solve_ms: Histogram,
    pub redistribution_ms: Histogram,
    pub clients: Gauge,
    pub bytes_sent: Counter,
    pub frames_sent: Counter,
    /// Versions a slow client never received (it got a newer keyframe).
    pub frames_skipped: Counter,
    pub keyframes_sent: Counter,
    /// Merged deltas sent to clients a few versions behind.
    pub catch_up_deltas_sent: Counter,
    pub bad_frames: Family<BadFrameLabels, Counter>,
    pub connections_closed_for_abuse: Counter,
    /// Solver failures (lost device, GPU error, panic), per scene.
    pub solver_failures: Family<SceneLabels, Counter>,
    /// Attempts to rebuild a failed solver, per scene.
    pub solver_rebuilds: Family<SceneLabels, Counter>,
    /// 1 while a scene serves versions, 0 while solving or failed.
    pub scene_ready: Family<SceneLabels, Gauge>,
}

impl Default for Metrics {
    fn default() -> Self {
        Self::new()
    }
}

impl Metrics {
    pub fn new() -> Self {
        let mut registry = Registry::with_prefix("lightwire");
        let ms_buckets = || Histogram::new(exponential_buckets(0.25, 2.0, 16));
        let m = Self {
            ticks: Counter::default(),
            versions_published: Counter::default(),
            tick_ms: ms_buckets(),
            solve_ms: ms_buckets(),
            redistribution_ms: ms_buckets(),
            clients: Gauge::default(),
            bytes_sent: Counter::default(),
            frames_sent: Counter::default(),
            frames_skipped: Counter::default(),
            keyframes_sent: Counter::default(),
            catch_up_deltas_sent: Counter::default(),
            bad_frames: Family::default(),
            connections_closed_for_abuse: Counter::default(),
            solver_failures: Family::default(),
            solver_rebuilds: Family::default(),
            scene_ready: Family::default(),
            registry: Registry::default(),
        };
        registry.register("ticks", "Tick loop iterations, all scenes", m.ticks.clone());
        registry.register(
            "versions_published",
            "Lightmap versions published",
            m.versions_published.clone(),
        );
        registry.register(
            "tick_ms",
            "Wall time of a tick, milliseconds",
            m.tick_ms.clone(),
        );
        registry.register(
            "solve_ms",
            "Solver time per tick, milliseconds",
            m.solve_ms.clone(),
        );
        registry.register(
            "redistribution_ms",
            "Solver time per tick spent following moved objects, milliseconds",
            m.redistribution_ms.clone(),
        );
        registry.register("clients", "Connected WebSocket clients", m.clients.clone());
        registry.register(
            "bytes_sent",
            "WebSocket payload bytes sent",
            m.bytes_sent.clone(),
        );
        registry.register(
            "frames_sent",
            "WebSocket frames sent",
            m.frames_sent.clone(),
        );
        registry.register(
            "frames_skipped",
            "Lightmap versions slow clients skipped (they got a newer keyframe instead)",
            m.frames_skipped.clone(),
        );
        registry.register(
            "keyframes_sent",
            "Keyframes sent (joins and resyncs)",
            m.keyframes_sent.clone(),
        );
        registry.register(
            "catch_up_deltas_sent",
            "Merged deltas sent to clients a few versions behind (instead of a keyframe)",
            m.catch_up_deltas_sent.clone(),
        );
        registry.register(
            "bad_frames",
            "Invalid client frames, by kind",
            m.bad_frames.clone(),
        );
        registry.register(
            "connections_closed_for_abuse",
            "Connections closed after too many invalid frames",
            m.connections_closed_for_abuse.clone(),
        );
        registry.register(
            "solver_failures",
            "Solver failures (lost GPU device, GPU error, panic), per scene",
            m.solver_failures.clone(),
        );
        registry.register(
            "solver_rebuilds",
            "Attempts to rebuild a failed solver, per scene",
            m.solver_rebuilds.clone(),
        );
        registry.register(
            "scene_ready",
            "1 while a scene serves versions, 0 while it solves its first or its solver has failed",
            m.scene_ready.clone(),
        );
        Self { registry, ..m }
    }

    /// The registry, to add metrics of another part (the relay's) before
    /// the metrics are shared.
    pub fn registry_mut(&mut self) -> &mut Registry {
        &mut self.registry
    }

    /// Records the timings of one tick.
    pub fn observe_tick(&self, tick: Duration, solve: Duration, redistribution: Duration) {
        self.tick_ms.observe(tick.as_secs_f64() * 1000.0);
        self.solve_ms.observe(solve.as_secs_f64() * 1000.0);
        if !redistribution.is_zero() {
            self.redistribution_ms
                .observe(redistribution.as_secs_f64() * 1000.0);
        }
    }

    /// Counts one invalid frame of `kind`.
    pub fn bad_frame(&self, kind: &str) {
        self.bad_frames
            .get_or_create(&BadFrameLabels {
                kind: kind.to_string(),
            })
            .inc();
    }

    /// Per-scene labels.
    pub fn scene(scene: &str) -> SceneLabels {
        SceneLabels {
            scene: scene.to_string(),
        }
    }

    /// The Prometheus text exposition.
    pub fn render(&self) -> String {
        let mut out = String::new();
        if prometheus_client::encoding::text::encode(&mut out, &self.registry).is_err() {
            out.clear();
        }
        out
    }
}
