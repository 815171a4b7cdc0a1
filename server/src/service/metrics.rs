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

/// Registers fields of `metrics` in `registry`, each under its field's
/// name with its help text, in the order given (the relay's metrics too).
macro_rules! register_fields {
    ($registry:expr, $metrics:expr, $($field:ident: $help:literal,)*) => {
        $($registry.register(stringify!($field), $help, $metrics.$field.clone());)*
    };
}
pub(crate) use register_fields;

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
    /// 1 while a scene's solver has nothing left to do at its poses.
    pub solver_idle: Family<SceneLabels, Gauge>,
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
            solver_idle: Family::default(),
            registry: Registry::default(),
        };
        register_fields! {
            registry, m,
            ticks: "Tick loop iterations, all scenes",
            versions_published: "Lightmap versions published",
            tick_ms: "Wall time of a tick, milliseconds",
            solve_ms: "Solver time per tick, milliseconds",
            redistribution_ms: "Solver time per tick spent following moved objects, milliseconds",
            clients: "Connected WebSocket clients",
            bytes_sent: "WebSocket payload bytes sent",
            frames_sent: "WebSocket frames sent",
            frames_skipped: "Lightmap versions slow clients skipped (they got a newer keyframe instead)",
            keyframes_sent: "Keyframes sent (joins and resyncs)",
            catch_up_deltas_sent: "Merged deltas sent to clients a few versions behind (instead of a keyframe)",
            bad_frames: "Invalid client frames, by kind",
            connections_closed_for_abuse: "Connections closed after too many invalid frames",
            solver_failures: "Solver failures (lost GPU device, GPU error, panic), per scene",
            solver_rebuilds: "Attempts to rebuild a failed solver, per scene",
            scene_ready: "1 while a scene serves versions, 0 while it solves its first or its solver has failed",
            solver_idle: "1 while a scene's solver has nothing left to do at its poses (refined and corrected: the light is as accurate as it will get until something moves), 0 while it works or has failed",
        }
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
