//! One scene's tick loop, on its own thread.
//!
//! The thread owns the solver (it may block: a GPU queue wait, a CPU
//! re-solve) and the lightmap [`Encoder`]. Per tick (thesis §4.5.3: work is
//! cut into slices that fit a budget, readers only see complete states):
//!
//! 1. drain the scene's [`super::inbox::Inbox`]: the newest pose per
//!    object;
//! 2. if any pose changed, hand all poses to the solver, tagged with the
//!    seq per object they carry and the poses themselves ([`Tag`]: the
//!    solver keeps the tag without
//!    looking inside and hands it back with the state that reflects those
//!    poses);
//! 3. run solver work for the tick budget;
//! 4. if the solver completed a state, scatter it into the atlas, encode it
//!    once and publish it through a [`Publisher`] (the newest publication
//!    replaces the previous one in a `watch` channel, echoing the seqs
//!    that state reflects, with the dynamic objects' poses it was lit
//!    for, which the sessions send to clients that ask, PROTOCOL.md §3
//!    `Poses`);
//! 5. update stats and metrics, sleep to the next tick (ticks missed while
//!    the solver ran long are skipped, not caught up); a transform that
//!    arrives meanwhile starts the next tick at once (at most four ticks
//!    per period).
//!
//! When the solver fails (its `step` returns a [`SolverFailure`], or
//! panics: each step runs under `catch_unwind`), the tick loop owns the
//! policy: it drops the solver, marks the feed failed with the reason (so
//! `/readyz` answers 503 naming the scene), counts
//! `lightwire_solver_failures_total{scene}`, sets `lightwire_scene_ready`
//! to 0 and logs one error line for the whole episode. Sessions keep the
//! last publication (viewers keep their version; new ones get it as a
//! keyframe). Transforms keep being drained into the current poses, and
//! the solver is rebuilt from those poses (a fresh GPU device) after 0.5
//! s, doubling up to 30 s between attempts. The encoder is not rebuilt, so
//! version numbers keep increasing and the rebuilt solver's first version
//! is a delta onto the last one; it makes the scene ready again.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::Path;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use lightwire_protocol::lightmap::Encoder;
use lightwire_protocol::unix_micros;
use lightwire_protocol::{
    DEFAULT_TILE_SIZE, LightStatus, MAX_FRAME_BYTES, ObjectPose, PixelFormat, SceneInfo, Stats,
};
use tokio::sync::watch;

use super::config::{Config, SolverChoice};
use super::feed::{Failure, Feed};
use super::live::{GpuLive, LiveSolver, ReferenceLive, SolverFailure, StepReport};
use super::metrics::Metrics;
use super::publication::{Publication, Publisher};
use super::wire::{from_wire, light_from_wire, newly_reflected, scene_info, to_wire};
use lightwire_scene::atlas::Atlas;
use lightwire_scene::{Light, LoadOptions, Pose, Scene};
use lightwire_solve::load::load_scene;
use lightwire_solve::reference::MAX_ELEMENTS;

/// A running scene: its description and the [`Feed`] its sessions serve.
pub struct SceneRuntime {
    /// What clients need to draw the scene (the same `Arc` as the feed's,
    /// and as every publication's `scene`).
    pub info: Arc<SceneInfo>,
    pub scene: Scene,
    pub atlas: Atlas,
    /// Inbox, publications, stats, client count and readiness.
    pub feed: Arc<Feed>,
    thread: Mutex<Option<JoinHandle<()>>>,
}

/// The tag the tick loop gives each set of poses and lights it hands its
/// solver: the seq per object of the transforms they carry (0: none yet),
/// and per light of the `SetLight` that set it. The solver hands it back
/// with the state that reflects them, whose version then echoes the seqs
/// (PROTOCOL.md §3, `reflected`) and sends the poses (`Poses`) and the
/// lights' states (`Lights`).
#[derive(Clone, Debug, PartialEq)]
pub struct Tag {
    /// Per object, the seq of the transform that set its pose (0: none).
    pub seqs: Arc<[u64]>,
    /// Per object, its pose.
    pub poses: Arc<[Pose]>,
    /// Per light, the seq of the `SetLight` that set its state (0: none)
    /// and that state.
    pub lights: Arc<[LightStatus]>,
}

impl Tag {
    /// `poses` with the seqs `seqs`, and the lights `lights`.
    fn new(seqs: &[u64], poses: &[Pose], lights: &[LightStatus]) -> Self {
        Tag {
            seqs: seqs.into(),
            poses: poses.into(),
            lights: lights.into(),
        }
    }

    /// `poses` carrying no transform, and `lights`.
    fn untransformed(poses: &[Pose], lights: &[LightStatus]) -> Self {
        Tag::new(&vec![0; poses.len()], poses, lights)
    }
}

/// The lights' states of a scene as it was loaded: no `SetLight` yet.
fn initial_lights(info: &SceneInfo) -> Vec<LightStatus> {
    info.lights
        .iter()
        .enumerate()
        .map(|(k, l)| LightStatus {
            light: k as u32,
            seq: 0,
            state: l.state,
        })
        .collect()
}

/// The poses of `info`'s dynamic objects that `tag` holds, as the wire's
/// `Poses` lists them.
fn dynamic_poses(info: &SceneInfo, tag: &Tag) -> Arc<[ObjectPose]> {
    info.objects
        .iter()
        .enumerate()
        .filter(|(_, o)| o.dynamic)
        .filter_map(|(k, _)| {
            Some(ObjectPose {
                object: k as u32,
                seq: *tag.seqs.get(k)?,
                pose: to_wire(tag.poses.get(k)?),
            })
        })
        .collect()
}

/// A scene's solver as the tick loop owns it.
type Solver = Box<dyn LiveSolver<Tag>>;

/// Builds a scene's solver starting from given poses and lights with their
/// tag: once at start, and again after each failure.
type Build = Box<dyn FnMut(&[Pose], &[Light], Tag) -> Result<Solver> + Send>;

/// The wait before the first rebuild of a failed solver.
pub const REBUILD_FIRST: Duration = Duration::from_millis(500);
/// The longest wait between rebuilds.
pub const REBUILD_MAX: Duration = Duration::from_secs(30);

/// The wait before the next rebuild after `attempts` of them: 0.5 s,
/// doubling, at most 30 s.
pub fn rebuild_delay(attempts: u32) -> Duration {
    REBUILD_FIRST
        .saturating_mul(1u32 << attempts.min(16))
        .min(REBUILD_MAX)
}

impl SceneRuntime {
    /// Loads a scene and starts its tick thread.
    pub fn start(
        path: &Path,
        config: &Config,
        metrics: Arc<Metrics>,
        shutdown: watch::Receiver<bool>,
    ) -> Result<Arc<Self>> {
        let (scene, atlas) = load_scene(
            path,
            LoadOptions {
                density_scale: config.density_scale,
                charts: config.charts,
            },
        )?;
        for w in &scene.warnings {
            tracing::warn!("{}: {w}", path.display());
        }
        // A keyframe must fit in one frame: bound it by its uncompressed
        // size plus per-tile overhead (zstd never grows data much).
        let texels = u64::from(atlas.width) * u64::from(atlas.height);
        let tiles = texels.div_ceil(u64::from(DEFAULT_TILE_SIZE) * u64::from(DEFAULT_TILE_SIZE));
        let worst = texels * PixelFormat::Rgb9e5.bytes_per_texel() as u64 + tiles * 64 + 4096;
        if worst > MAX_FRAME_BYTES as u64 {
            anyhow::bail!(
                "{}: a {}x{} atlas could need {worst} bytes per keyframe, over the protocol's {MAX_FRAME_BYTES}-byte frame limit; lower the texel density",
                path.display(),
                atlas.width,
                atlas.height
            );
        }
        let info = Arc::new(scene_info(&scene, &atlas));
        let mut build: Build = match config.solver {
            SolverChoice::Reference => {
                if atlas.elements.len() > MAX_ELEMENTS {
                    anyhow::bail!(
                        "{} has {} elements; the reference solver serves at most {MAX_ELEMENTS} (use --density-scale or --solver progressive)",
                        path.display(),
                        atlas.elements.len()
                    );
                }
                let (scene, atlas) = (scene.clone(), atlas.clone());
                Box::new(move |poses: &[Pose], lights: &[Light], tag: Tag| {
                    let mut scene = scene.clone();
                    scene.lights = lights.to_vec();
                    let solver = ReferenceLive::new(scene, atlas.clone(), poses, tag);
                    Ok(Box::new(solver) as Solver)
                })
            }
            SolverChoice::Progressive => {
                let method = config
                    .scene_redistribution
                    .get(&scene.name)
                    .copied()
                    .unwrap_or(config.redistribution);
                tracing::info!(scene = %scene.name, %method, "redistribution");
                let adapter = config.adapter.clone();
                let (scene, atlas) = (scene.clone(), atlas.clone());
                Box::new(move |poses: &[Pose], lights: &[Light], tag: Tag| {
                    let device = lightwire_solve::gpu::Device::new(adapter.as_deref())?;
                    tracing::info!(scene = %scene.name, adapter = %device.describe(), "GPU solver");
                    let mut scene = scene.clone();
                    scene.lights = lights.to_vec();
                    let solver = GpuLive::new(device, &scene, &atlas, poses, tag, method)?;
                    Ok(Box::new(solver) as Solver)
                })
            }
        };
        let initial = scene.initial_poses();
        let lit = initial_lights(&info);
        let solver = build(&initial, &scene.lights, Tag::untransformed(&initial, &lit))?;
        let (publisher, pub_rx) = Publisher::new();
        let (stats_tx, stats_rx) = watch::channel(Stats::initial());
        let feed = Arc::new(Feed::new(
            info.id.clone(),
            Some(info.clone()),
            pub_rx,
            stats_rx,
        ));
        let runtime = Arc::new(SceneRuntime {
            info,
            scene,
            atlas,
            feed,
            thread: Mutex::new(None),
        });
        runtime.feed.follows_lights.store(true, Ordering::Relaxed);
        let labels = Metrics::scene(&runtime.info.id);
        let failures = metrics.solver_failures.get_or_create(&labels).clone();
        let rebuilds = metrics.solver_rebuilds.get_or_create(&labels).clone();
        let ready = metrics.scene_ready.get_or_create(&labels).clone();
        ready.set(0);
        let idle = metrics.solver_idle.get_or_create(&labels).clone();
        idle.set(0);
        let tick = TickLoop {
            runtime: runtime.clone(),
            name: solver.name(),
            solver: Some(solver),
            has_state: false,
            image: Vec::new(),
            build,
            episode: None,
            fail_at_seq: config.test_fail_solver.map(|h| h.at_seq),
            rebuild_at_seq: config.test_fail_solver.and_then(|h| h.rebuild_at_seq),
            rebuild_fails: config.test_fail_solver.map_or(0, |h| h.rebuild_fails),
            failures,
            rebuilds,
            ready,
            idle,
            encoder: Encoder::new(
                runtime.atlas.width,
                runtime.atlas.height,
                DEFAULT_TILE_SIZE,
                PixelFormat::Rgb9e5,
                config.epsilon,
            ),
            poses: runtime.scene.initial_poses(),
            seqs: vec![0; runtime.scene.objects.len()],
            lights: runtime.scene.lights.clone(),
            light_states: lit,
            publisher,
            stats: stats_tx,
            metrics,
            shutdown,
            period: config.tick(),
            budget: config.budget(),
            settle: config.settle(),
        };
        let handle = std::thread::Builder::new()
            .name(format!("tick-{}", runtime.info.id))
            .spawn(move || tick.run())
            .context("spawning the tick thread")?;
        *runtime.thread.lock().unwrap_or_else(|p| p.into_inner()) = Some(handle);
        Ok(runtime)
    }

    /// Waits for the tick thread to finish (after shutdown).
    pub fn join(&self) {
        let handle = self.thread.lock().unwrap_or_else(|p| p.into_inner()).take();
        if let Some(h) = handle {
            if h.join().is_err() {
                tracing::error!(scene = %self.info.id, "tick thread panicked");
            }
        }
    }

    /// The newest publication, if any.
    pub fn latest(&self) -> Option<Arc<Publication>> {
        self.feed.latest()
    }
}

/// A failure of the solver, from when it is noticed until a rebuilt solver
/// publishes.
struct Episode {
    failure: Failure,
    /// When to try the next rebuild.
    retry_at: Instant,
}

struct TickLoop {
    runtime: Arc<SceneRuntime>,
    /// `None` between a failure and a successful rebuild.
    solver: Option<Solver>,
    /// The solver has completed a state (its `radiosity` is one).
    has_state: bool,
    /// The image of the solver's latest complete state, as a client
    /// receives it ([`crate::publish`]); published again, unchanged, by
    /// the versions that only echo seqs or flush the encoder.
    image: Vec<[f32; 3]>,
    name: &'static str,
    build: Build,
    episode: Option<Episode>,
    /// Test hook: the seq whose arrival makes the solver fail (once).
    fail_at_seq: Option<u64>,
    /// Test hook: no rebuild until a transform with this seq came.
    rebuild_at_seq: Option<u64>,
    /// Test hook: rebuild attempts still to fail.
    rebuild_fails: u32,
    failures: prometheus_client::metrics::counter::Counter,
    rebuilds: prometheus_client::metrics::counter::Counter,
    ready: prometheus_client::metrics::gauge::Gauge,
    /// `lightwire_solver_idle{scene}`.
    idle: prometheus_client::metrics::gauge::Gauge,
    encoder: Encoder,
    poses: Vec<Pose>,
    /// Latest seq per object, handed to the solver as the poses' tag.
    seqs: Vec<u64>,
    /// The lights as the latest `SetLight`s set them, and their states
    /// and seqs as the wire has them (in the tag).
    lights: Vec<Light>,
    light_states: Vec<LightStatus>,
    publisher: Publisher,
    stats: watch::Sender<Stats>,
    metrics: Arc<Metrics>,
    shutdown: watch::Receiver<bool>,
    period: Duration,
    budget: Duration,
    /// Idle time before the encoder's waiting texels are sent.
    settle: Duration,
}

fn unix_ms() -> u64 {
    unix_micros() / 1000
}

/// The text of a panic's payload.
fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "(no message)".into())
}

/// A tick without a solver: no work, the last state's unshot fraction.
fn down(last: &StepReport) -> StepReport {
    StepReport {
        completed: false,
        unshot_fraction: last.unshot_fraction,
        redistribution: Duration::ZERO,
        solve: Duration::ZERO,
    }
}

/// One step, with a panic turned into a failure like any other.
fn guarded_step<T>(solver: &mut dyn LiveSolver<T>, budget: Duration) -> Result<StepReport, String> {
    match catch_unwind(AssertUnwindSafe(|| solver.step(budget))) {
        Ok(Ok(report)) => Ok(report),
        Ok(Err(SolverFailure(reason))) => Err(reason),
        Err(payload) => {
            let message = panic_message(payload.as_ref());
            // A lost device explains the panic better than its message.
            Err(match solver.failure() {
                Some(cause) => format!("{cause} (the step panicked: {message})"),
                None => format!("the solver panicked: {message}"),
            })
        }
    }
}

impl TickLoop {
    /// Drops the failed solver, marks the scene failed and schedules a
    /// rebuild. Logs at error level once per episode.
    fn fail(&mut self, reason: String) {
        if let Some(old) = self.solver.take() {
            // Freeing resources of a lost device must not end the thread.
            if catch_unwind(AssertUnwindSafe(move || drop(old))).is_err() {
                tracing::warn!(scene = %self.runtime.info.id, "dropping the failed solver panicked");
            }
        }
        self.failures.inc();
        self.ready.set(0);
        self.idle.set(0);
        let id = &self.runtime.info.id;
        let version = self.encoder.state().version;
        match &mut self.episode {
            None => {
                let delay = rebuild_delay(0);
                tracing::error!(
                    scene = %id,
                    version,
                    "solver failed: {reason}; scene not ready, still serving version {version}, rebuilding in {delay:?}"
                );
                self.episode = Some(Episode {
                    failure: Failure {
                        reason,
                        since_unix_ms: unix_ms(),
                        rebuild_attempts: 0,
                    },
                    retry_at: Instant::now() + delay,
                });
            }
            Some(episode) => {
                // A rebuilt solver failed before publishing: the same
                // episode, so no second error line.
                let delay = rebuild_delay(episode.failure.rebuild_attempts);
                tracing::warn!(scene = %id, "rebuilt solver failed: {reason}; next rebuild in {delay:?}");
                episode.failure.reason = reason;
                episode.retry_at = Instant::now() + delay;
            }
        }
        self.show_failure();
    }

    fn show_failure(&self) {
        if let Some(episode) = &self.episode {
            self.runtime.feed.set_failure(Some(episode.failure.clone()));
        }
    }

    /// Rebuilds the solver at the current poses once the backoff allows.
    fn rebuild_when_due(&mut self) {
        let Some(episode) = &mut self.episode else {
            return;
        };
        if self.solver.is_some() || Instant::now() < episode.retry_at {
            return;
        }
        if let Some(at) = self.rebuild_at_seq {
            if self.seqs.iter().all(|&s| s < at) {
                return;
            }
            self.rebuild_at_seq = None;
        }
        episode.failure.rebuild_attempts += 1;
        let attempt = episode.failure.rebuild_attempts;
        self.rebuilds.inc();
        let id = self.runtime.info.id.clone();
        let poses = self.poses.clone();
        let build = &mut self.build;
        // The new solver's state reflects no transform until it takes up
        // the tagged poses handed to it below; it starts with the lights
        // as they are now, and reflects their seqs from its first state.
        let (lights, lit) = (&self.lights, &self.light_states);
        let built = match catch_unwind(AssertUnwindSafe(|| {
            build(&poses, lights, Tag::untransformed(&poses, lit))
        })) {
            Ok(Ok(_)) if self.rebuild_fails > 0 => {
                self.rebuild_fails -= 1;
                Err("test-injected rebuild failure (LIGHTWIRE_TEST_FAIL_SOLVER)".into())
            }
            Ok(Ok(solver)) => Ok(solver),
            Ok(Err(e)) => Err(format!("{e:#}")),
            Err(payload) => Err(format!("panicked: {}", panic_message(payload.as_ref()))),
        };
        match built {
            Ok(mut solver) => {
                solver.set_poses(&self.poses, self.tag());
                tracing::info!(scene = %id, attempt, "solver rebuilt; ready again at its first version");
                self.solver = Some(solver);
                self.has_state = false;
            }
            Err(e) => {
                let delay = rebuild_delay(attempt);
                tracing::warn!(scene = %id, attempt, "rebuilding the solver failed: {e}; next try in {delay:?}");
                episode.failure.reason = format!("rebuilding the solver failed: {e}");
                episode.retry_at = Instant::now() + delay;
            }
        }
        self.show_failure();
    }

    fn run(mut self) {
        let id = self.runtime.info.id.clone();
        tracing::info!(scene = %id, solver = self.name, elements = self.runtime.atlas.elements.len(), "tick loop started");
        let mut next = Instant::now();
        let mut published = Tag::untransformed(&self.poses, &self.light_states);
        // Since when the solver has had nothing to do (and no transform came).
        let mut idle_since: Option<Instant> = None;
        let mut last = StepReport {
            completed: false,
            unshot_fraction: 1.0,
            redistribution: Duration::ZERO,
            solve: Duration::ZERO,
        };
        while !*self.shutdown.borrow() {
            let started = Instant::now();
            let drained = self.runtime.feed.inbox.drain();
            let mut inject = false;
            let moved = !drained.is_empty();
            for (object, pending) in drained {
                self.poses[object] = from_wire(&pending.pose);
                self.seqs[object] = pending.seq;
                inject |= self.fail_at_seq.is_some_and(|at| pending.seq >= at);
            }
            let switched = self.runtime.feed.inbox.drain_lights();
            let relit = !switched.is_empty();
            for (k, pending) in switched {
                let (Some(base), Some(light), Some(status)) = (
                    self.runtime.scene.lights.get(k),
                    self.lights.get_mut(k),
                    self.light_states.get_mut(k),
                ) else {
                    continue;
                };
                *light = light_from_wire(base, &pending.state);
                status.seq = pending.seq;
                status.state = pending.state;
            }
            // While failed, poses only accumulate: the rebuilt solver
            // starts from them.
            self.rebuild_when_due();
            let tag = self.tag();
            let Some(solver) = self.solver.as_mut() else {
                self.finish_tick(started, down(&last));
                next = self.sleep_until_next(next);
                continue;
            };
            if moved {
                solver.set_poses(&self.poses, tag.clone());
            }
            if relit {
                solver.set_lights(&self.lights, tag);
            }
            if inject {
                self.fail_at_seq = None;
                tracing::warn!(scene = %id, "test hook LIGHTWIRE_TEST_FAIL_SOLVER: failing the solver");
                solver.inject_failure();
            }
            let report = match guarded_step(solver.as_mut(), self.budget) {
                Ok(report) => report,
                Err(reason) => {
                    self.fail(reason);
                    self.finish_tick(started, down(&last));
                    next = self.sleep_until_next(next);
                    continue;
                }
            };
            last = report;
            // Echo the seqs newly reflected since the previous version. A
            // transform that changed nothing (the pose the object already
            // had) is reflected at once without new light; it still gets a
            // version, with no tiles, so that every accepted seq is echoed
            // (PROTOCOL.md §3, `reflected`).
            let solved = solver.reflected().clone();
            let reflected = newly_reflected(&solved.seqs, &published.seqs);
            // So is a light state, in the version's `Lights`.
            let lights_echoed = solved.lights != published.lights;
            // A new (or rebuilt) solver's `radiosity` means nothing before
            // its first complete state: no echo-only version until then.
            // Once the solver has been idle for `settle` (no transform in
            // between) with texels still waiting within the encoder's error
            // budget, its unchanged lightmap is published once more, which
            // sends them (the encoder sends everything that differs when
            // the lightmap holds still): viewers then hold the solver's
            // lightmap exactly. Waiting first keeps a driver that pauses
            // between moves from paying for a flush after every move.
            if moved || relit || !solver.is_idle() {
                idle_since = None;
            } else if idle_since.is_none() {
                idle_since = Some(Instant::now());
            }
            self.idle.set(i64::from(idle_since.is_some()));
            let settle = self.has_state
                && idle_since.is_some_and(|t| t.elapsed() >= self.settle)
                && self.encoder.pending_texels() > 0;
            let echo = !reflected.is_empty() || lights_echoed;
            if report.completed || settle || (self.has_state && echo) {
                self.has_state = true;
                let poses = dynamic_poses(&self.runtime.info, &solved);
                let lights = solved.lights.clone();
                published = solved;
                if report.completed {
                    let mut radiosity = solver.radiosity().to_vec();
                    self.image = crate::publish::lightmap(
                        &self.runtime.atlas,
                        solver.validity(),
                        &mut radiosity,
                    );
                }
                let delta = self.encoder.publish(&self.image, reflected);
                let keyframe = self.encoder.keyframe();
                self.metrics.versions_published.inc();
                self.publisher.publish_lit(
                    self.runtime.info.clone(),
                    keyframe,
                    Some(delta),
                    (poses, lights),
                );
                if let Some(episode) = self.episode.take() {
                    self.runtime.feed.set_failure(None);
                    tracing::info!(
                        scene = %id,
                        version = self.encoder.state().version,
                        attempts = episode.failure.rebuild_attempts,
                        "solver recovered; scene ready"
                    );
                }
                self.runtime.feed.ready.store(true, Ordering::Release);
                self.ready.set(1);
            }
            self.finish_tick(started, last);
            next = self.sleep_until_next(next);
        }
        tracing::info!(scene = %id, "tick loop stopped");
    }

    /// The tag of the current poses and lights.
    fn tag(&self) -> Tag {
        Tag::new(&self.seqs, &self.poses, &self.light_states)
    }

    /// Stats and metrics of a tick whose solver work was `report`.
    fn finish_tick(&self, started: Instant, report: StepReport) {
        let tick_time = started.elapsed();
        self.metrics.ticks.inc();
        self.metrics
            .observe_tick(tick_time, report.solve, report.redistribution);
        let _ = self.stats.send(Stats {
            version: self.encoder.state().version,
            unshot_fraction: report.unshot_fraction as f32,
            tick_ms: tick_time.as_secs_f32() * 1000.0,
            solve_ms: report.solve.as_secs_f32() * 1000.0,
            redistribution_ms: report.redistribution.as_secs_f32() * 1000.0,
            clients: self.runtime.feed.clients.load(Ordering::Relaxed),
            server_time_us: unix_micros(),
        });
    }

    /// Waits for the tick after the one scheduled at `next` and returns
    /// when it starts: a period after `next`, or as soon as a transform
    /// arrives, so that a move does not wait for the tick grid (up to a
    /// period, 17 ms at 60 Hz) before its work starts; but never sooner
    /// than a quarter period after `next`, so that drivers sending faster
    /// than the ticks cannot run them back to back.
    fn sleep_until_next(&self, next: Instant) -> Instant {
        let due = next + self.period;
        let now = Instant::now();
        if due <= now {
            // Ran long (a blocking re-solve): skip the missed ticks.
            return now;
        }
        let earliest = next + self.period / 4;
        if earliest > now {
            std::thread::sleep(earliest - now);
        }
        if self.runtime.feed.inbox.wait_until(due) {
            Instant::now()
        } else {
            due
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A solver whose step panics, or fails, as told.
    struct Broken {
        panic: bool,
        lost: Option<String>,
    }

    impl LiveSolver<()> for Broken {
        fn name(&self) -> &'static str {
            "broken"
        }
        fn set_poses(&mut self, _: &[Pose], _: ()) {}
        fn set_lights(&mut self, _: &[Light], _: ()) {}
        fn step(&mut self, _: Duration) -> Result<StepReport, SolverFailure> {
            if self.panic {
                panic!("boom");
            }
            Err(SolverFailure("it broke".into()))
        }
        fn radiosity(&self) -> &[glam::Vec3] {
            &[]
        }
        fn validity(&self) -> &lightwire_solve::validity::Validity {
            unreachable!("a broken solver completes no state")
        }
        fn reflected(&self) -> &() {
            &()
        }
        fn is_idle(&self) -> bool {
            false
        }
        fn failure(&self) -> Option<String> {
            self.lost.clone()
        }
        fn inject_failure(&mut self) {}
    }

    #[test]
    fn a_panicking_step_is_a_failure_with_its_best_reason() {
        let budget = Duration::from_millis(1);
        let mut failing = Broken {
            panic: false,
            lost: None,
        };
        assert_eq!(
            guarded_step(&mut failing, budget).err().as_deref(),
            Some("it broke")
        );
        let mut panicking = Broken {
            panic: true,
            lost: None,
        };
        assert_eq!(
            guarded_step(&mut panicking, budget).err().as_deref(),
            Some("the solver panicked: boom")
        );
        let mut lost = Broken {
            panic: true,
            lost: Some("GPU device lost (Destroyed)".into()),
        };
        assert_eq!(
            guarded_step(&mut lost, budget).err().as_deref(),
            Some("GPU device lost (Destroyed) (the step panicked: boom)")
        );
    }

    #[test]
    fn rebuilds_back_off_from_half_a_second_to_thirty() {
        let delays: Vec<Duration> = (0..10).map(rebuild_delay).collect();
        assert_eq!(delays[0], Duration::from_millis(500));
        assert_eq!(delays[1], Duration::from_secs(1));
        assert_eq!(delays[5], Duration::from_secs(16));
        assert_eq!(delays[6], Duration::from_secs(30));
        assert_eq!(rebuild_delay(u32::MAX), Duration::from_secs(30));
        assert!(delays.windows(2).all(|w| w[0] <= w[1]));
    }
}
