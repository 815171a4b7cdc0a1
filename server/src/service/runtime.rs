//! One scene's tick loop, on its own thread.
//!
//! The thread owns the solver (it may block: a GPU queue wait, a CPU
//! re-solve) and the lightmap [`Encoder`]. Per tick (thesis §4.5.3: work is
//! cut into slices that fit a budget, readers only see complete states):
//!
//! 1. drain the scene's [`super::inbox::Inbox`]: the newest pose per
//!    object;
//! 2. if any pose changed, hand all poses to the solver and remember which
//!    seqs they carry;
//! 3. run solver work for the tick budget;
//! 4. if the solver completed a state, scatter it into the atlas, encode it
//!    once and publish it through a [`Publisher`] (the newest publication
//!    replaces the previous one in a `watch` channel, echoing the seqs
//!    that state reflects);
//! 5. update stats and metrics, sleep to the next tick (ticks missed while
//!    the solver ran long are skipped, not caught up).

use std::path::Path;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use anyhow::{Context, Result};
use glam::{Quat, Vec3};
use lightwire_protocol::lightmap::Encoder;
use lightwire_protocol::{
    DEFAULT_TILE_SIZE, MAX_FRAME_BYTES, MaterialInfo, ObjectInfo, ObjectSeq, PixelFormat,
    Pose as WirePose, SceneInfo, Stats, SurfaceInfo,
};
use tokio::sync::watch;

use super::config::{Config, SolverChoice};
use super::feed::Feed;
use super::live::{GpuLive, LiveSolver, ReferenceLive};
use super::metrics::Metrics;
use super::publication::{Publication, Publisher};
use crate::atlas::Atlas;
use crate::reference::MAX_ELEMENTS;
use crate::scene::{LoadOptions, Pose, Scene};

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

/// Converts a wire pose (already validated) to a scene pose.
pub fn from_wire(p: &WirePose) -> Pose {
    Pose {
        translation: Vec3::from_array(p.translation),
        rotation: Quat::from_array(p.rotation).normalize(),
        scale: p.scale,
    }
}

/// Converts a scene pose to a wire pose.
pub fn to_wire(p: &Pose) -> WirePose {
    WirePose {
        translation: p.translation.to_array(),
        rotation: p.rotation.to_array(),
        scale: p.scale,
    }
}

/// Describes a scene for clients.
pub fn scene_info(scene: &Scene, atlas: &Atlas) -> SceneInfo {
    SceneInfo {
        id: scene.name.clone(),
        atlas_width: atlas.width,
        atlas_height: atlas.height,
        tile_size: DEFAULT_TILE_SIZE,
        format: PixelFormat::Rgb9e5,
        objects: scene
            .objects
            .iter()
            .map(|o| ObjectInfo {
                name: o.name.clone(),
                dynamic: o.dynamic,
                pose: to_wire(&o.initial_pose),
            })
            .collect(),
        materials: scene
            .materials
            .iter()
            .map(|m| MaterialInfo {
                name: m.name.clone(),
                albedo: m.albedo.to_array(),
                emission: m.emission.to_array(),
            })
            .collect(),
        surfaces: scene
            .patches
            .iter()
            .zip(&atlas.charts)
            .map(|(p, c)| SurfaceInfo {
                name: p.name.clone(),
                object: p.object,
                material: p.material,
                corners: p.shape.corners().map(|c| c.to_array()),
                rect: [c.x, c.y, c.w, c.h],
            })
            .collect(),
    }
}

fn now_us() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_micros() as u64)
        .unwrap_or(0)
}

impl SceneRuntime {
    /// Loads a scene and starts its tick thread.
    pub fn start(
        path: &Path,
        config: &Config,
        metrics: Arc<Metrics>,
        shutdown: watch::Receiver<bool>,
    ) -> Result<Arc<Self>> {
        let scene = Scene::load_with(
            path,
            LoadOptions {
                density_scale: config.density_scale,
            },
        )?;
        let atlas =
            Atlas::build(&scene).map_err(|issue| anyhow::anyhow!("{}: {issue}", path.display()))?;
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
        let solver: Box<dyn LiveSolver> = match config.solver {
            SolverChoice::Reference => {
                if atlas.elements.len() > MAX_ELEMENTS {
                    anyhow::bail!(
                        "{} has {} elements; the reference solver serves at most {MAX_ELEMENTS} (use --density-scale or --solver progressive)",
                        path.display(),
                        atlas.elements.len()
                    );
                }
                Box::new(ReferenceLive::new(scene.clone(), atlas.clone()))
            }
            SolverChoice::Progressive => {
                let device = crate::gpu::Device::new(config.adapter.as_deref())?;
                tracing::info!(scene = %scene.name, adapter = %device.describe(), "GPU solver");
                let method = config
                    .scene_redistribution
                    .get(&scene.name)
                    .copied()
                    .unwrap_or(config.redistribution);
                tracing::info!(scene = %scene.name, %method, "redistribution");
                Box::new(GpuLive::new(device, scene.clone(), atlas.clone(), method)?)
            }
        };
        let (publisher, pub_rx) = Publisher::new();
        let (stats_tx, stats_rx) = watch::channel(Stats {
            version: 0,
            unshot_fraction: 1.0,
            tick_ms: 0.0,
            solve_ms: 0.0,
            redistribution_ms: 0.0,
            clients: 0,
            server_time_us: now_us(),
        });
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
        let tick = TickLoop {
            runtime: runtime.clone(),
            solver,
            encoder: Encoder::new(
                runtime.atlas.width,
                runtime.atlas.height,
                DEFAULT_TILE_SIZE,
                PixelFormat::Rgb9e5,
                config.epsilon,
            ),
            poses: runtime.scene.initial_poses(),
            seqs: vec![0; runtime.scene.objects.len()],
            publisher,
            stats: stats_tx,
            metrics,
            shutdown,
            period: config.tick(),
            budget: config.budget(),
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

struct TickLoop {
    runtime: Arc<SceneRuntime>,
    solver: Box<dyn LiveSolver>,
    encoder: Encoder,
    poses: Vec<Pose>,
    /// Latest seq per object handed to the solver.
    seqs: Vec<u64>,
    publisher: Publisher,
    stats: watch::Sender<Stats>,
    metrics: Arc<Metrics>,
    shutdown: watch::Receiver<bool>,
    period: Duration,
    budget: Duration,
}

impl TickLoop {
    fn run(mut self) {
        let id = self.runtime.info.id.clone();
        tracing::info!(scene = %id, solver = self.solver.name(), elements = self.runtime.atlas.elements.len(), "tick loop started");
        let mut next = Instant::now();
        let mut published_seqs: Vec<u64> = vec![0; self.seqs.len()];
        while !*self.shutdown.borrow() {
            let started = Instant::now();
            let drained = self.runtime.feed.inbox.drain();
            if !drained.is_empty() {
                for (object, pending) in drained {
                    self.poses[object] = from_wire(&pending.pose);
                    self.seqs[object] = pending.seq;
                }
                self.solver.set_poses(&self.poses, &self.seqs);
            }
            let report = self.solver.step(self.budget);
            // Echo the seqs newly reflected since the previous version. A
            // transform that changed nothing (the pose the object already
            // had) is reflected at once without new light; it still gets a
            // version, with no tiles, so that every accepted seq is echoed
            // (PROTOCOL.md §3, `reflected`).
            let solved = self.solver.reflected();
            let reflected: Vec<ObjectSeq> = solved
                .iter()
                .zip(&published_seqs)
                .enumerate()
                .filter(|(_, (now, before))| now > before)
                .map(|(object, (seq, _))| ObjectSeq {
                    object: object as u32,
                    seq: *seq,
                })
                .collect();
            if report.completed || !reflected.is_empty() {
                published_seqs = solved.to_vec();
                let image = self.runtime.atlas.to_image(self.solver.radiosity());
                let delta = self.encoder.publish(&image, reflected);
                let keyframe = self.encoder.keyframe();
                self.metrics.versions_published.inc();
                self.publisher
                    .publish(self.runtime.info.clone(), keyframe, Some(delta));
                self.runtime.feed.ready.store(true, Ordering::Release);
            }
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
                server_time_us: now_us(),
            });
            next += self.period;
            let now = Instant::now();
            if next > now {
                std::thread::sleep(next - now);
            } else {
                // Ran long (a blocking re-solve): skip the missed ticks.
                next = now;
            }
        }
        tracing::info!(scene = %id, "tick loop stopped");
    }
}
