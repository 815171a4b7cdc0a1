//! Where a dynamic session's time goes (issue 19): named stages, timed per
//! frame, for `lightwire bench dynamic --profile`.
//!
//! A [`Profiler`] is a cheap handle that the [`crate::gpu::DynamicSolver`]
//! and its [`crate::gpu::ProgressiveSolver`] share. Disabled (the default,
//! and always in the service) it holds nothing and every call returns at
//! once. Enabled, it keeps, per frame, the time of each [`Stage`] within
//! each [`Unit`] of work, by one of two clocks:
//!
//! - [`Clock::Gpu`]: GPU passes are bracketed by timestamp queries written
//!   between them in the command encoder (wgpu's `TIMESTAMP_QUERY` and
//!   `TIMESTAMP_QUERY_INSIDE_ENCODERS`, requested by [`crate::gpu::Device`]
//!   when the adapter has them). The commands and their order are exactly
//!   those of an unprofiled run; the queries are resolved and read back
//!   when the frame ends, outside its time. GPU stages run on the queue
//!   while the CPU prepares the next batch, so GPU and CPU stages may
//!   overlap: each clock's stages sum to at most the frame, both together
//!   may exceed it.
//! - [`Clock::Cpu`]: at every stage boundary inside an encoder the work so
//!   far is submitted and waited for, and the wall time since the previous
//!   boundary is the stage's. This serialises CPU and GPU (a profiled frame
//!   is slower than an unprofiled one) but the stages are disjoint
//!   intervals of one thread: they sum to at most the frame.
//!
//! Stages that run on the CPU (shooter setup, the regather's ray casting,
//! readbacks, encoding) are timed on the CPU with either clock; before a
//! timed readback [`Profiler::sync`] waits for the queued GPU work, so that
//! the readback's time is its own and not the GPU's.
//!
//! Neither clock changes what is computed: the same passes run on the same
//! buffers in the same order (thesis §4.5.3's batches stay as they are).

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use super::buffers::read_back;
use super::device::{Device, GpuError};

/// Timestamp queries per query set (wgpu's `QUERY_SET_MAX_QUERIES`).
const QUERIES_PER_SET: u32 = 4096;

/// Which clock a profiler times GPU stages with (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Clock {
    /// GPU timestamp queries between passes.
    Gpu,
    /// Submit and wait at each stage boundary, CPU wall time.
    Cpu,
}

impl Clock {
    /// The name in reports.
    pub fn name(self) -> &'static str {
        match self {
            Self::Gpu => "gpu timestamps",
            Self::Cpu => "cpu (submit and wait per stage)",
        }
    }

    /// The best clock the device offers: GPU timestamps inside encoders
    /// when it was created with them, else CPU timing.
    pub fn best_for(gpu: &Device) -> Clock {
        let needed =
            wgpu::Features::TIMESTAMP_QUERY | wgpu::Features::TIMESTAMP_QUERY_INSIDE_ENCODERS;
        if gpu.device.features().contains(needed) {
            Clock::Gpu
        } else {
            Clock::Cpu
        }
    }
}

/// The unit of work of a [`crate::gpu::DynamicSolver`] a stage belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Unit {
    /// Following new poses: a redistribution, or for the full method a new
    /// solver.
    Move,
    /// Progressive refinement rounds (after a full or incremental move; for
    /// cross, of the static set around the passive moving objects, and its
    /// first solve without them).
    Refinement,
    /// Cross: the moving objects inserted after the static set's first
    /// solve.
    Insertion,
    /// What the service does with a completed state: read it back and
    /// encode the lightmap delta.
    Publication,
}

impl Unit {
    /// Every unit, in report order.
    pub const ALL: [Unit; 4] = [
        Self::Move,
        Self::Refinement,
        Self::Insertion,
        Self::Publication,
    ];

    /// The stable name in reports and JSON.
    pub fn name(self) -> &'static str {
        match self {
            Self::Move => "move",
            Self::Refinement => "refinement",
            Self::Insertion => "insertion",
            Self::Publication => "publication",
        }
    }
}

/// A timed part of a unit of work.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Stage {
    /// CPU: a full recompute's new solver (validity, upload, placement,
    /// first selection).
    SolverSetup,
    /// CPU: the start of a move (validity near the moved objects,
    /// placement at the new poses, reset of M, planning the batches).
    MoveSetup,
    /// CPU: a redistribution batch's shooters or tiles and their upload.
    JobSetup,
    /// GPU: incremental batches' shooter energies.
    ShooterEnergy,
    /// GPU: hemicube item buffers (cross: front and back, at the new
    /// position, and at the old one unless the last move's are copied
    /// back).
    ItemBuffers,
    /// GPU: cross's front hemicubes of element ids, from which M gathers
    /// R_g(C, M) (drawn again after the move only for a move of several
    /// jobs).
    FrontHemicubes,
    /// GPU: cross's back hemicubes of C's elements with their distance, at
    /// the new position and at the old one unless the last move's are
    /// copied back.
    BackHemicubes,
    /// CPU: M's direct light per texel (cross; on the CPU while the GPU
    /// draws the first job's hemicubes, so the GPU clock does not see it).
    DirectLight,
    /// GPU: the moving tiles gather from their front hemicubes.
    TileGather,
    /// GPU: `shade_back`, which shades the back hemicubes with C's shot
    /// radiosity, and `reconstruct_dyn` for cross: every element of C samples the
    /// back hemicubes (the cross projection R_x(C, C), eq. 3.3.1) with
    /// reprojection by depth (Alg. 4.5 REPROJECT), and receives the tiles'
    /// shots. Projection and reprojection are one loop of one kernel and
    /// cannot be timed apart.
    CrossProjection,
    /// GPU: `reconstruct_dyn` for incremental batches.
    Reconstruct,
    /// GPU: the moving texels read their tiles' light bilinearly.
    Smoothing,
    /// CPU: the regather's readback of radiosity and unshot radiosity.
    RegatherReadback,
    /// CPU: the regather's ray casting and upload.
    Regather,
    /// GPU: per-patch unshot power and the choice of the next shooter.
    Selection,
    /// CPU: reading the selection back.
    SelectionReadback,
    /// CPU wall time of progressive refinement batches (shooters, the GPU
    /// batch, the selection and its readback; `shoot.rs` is not
    /// instrumented).
    Batches,
    /// CPU clock only: waiting for GPU work queued outside any stage.
    Wait,
    /// CPU: the completed state's radiosity read back.
    Readback,
    /// CPU: invalid texels filled, the atlas image, and
    /// `Encoder::publish`'s delta, as the service does per version.
    Encode,
}

impl Stage {
    /// Every stage, in report order.
    pub const ALL: [Stage; 20] = [
        Self::SolverSetup,
        Self::MoveSetup,
        Self::JobSetup,
        Self::ShooterEnergy,
        Self::ItemBuffers,
        Self::FrontHemicubes,
        Self::BackHemicubes,
        Self::DirectLight,
        Self::TileGather,
        Self::CrossProjection,
        Self::Reconstruct,
        Self::Smoothing,
        Self::RegatherReadback,
        Self::Regather,
        Self::Selection,
        Self::SelectionReadback,
        Self::Batches,
        Self::Wait,
        Self::Readback,
        Self::Encode,
    ];

    /// The stable name in reports and JSON.
    pub fn name(self) -> &'static str {
        match self {
            Self::SolverSetup => "solver setup",
            Self::MoveSetup => "move setup",
            Self::JobSetup => "job setup",
            Self::ShooterEnergy => "shooter energy",
            Self::ItemBuffers => "item buffers",
            Self::FrontHemicubes => "front hemicubes",
            Self::BackHemicubes => "back hemicubes",
            Self::DirectLight => "direct light",
            Self::TileGather => "tile gather",
            Self::CrossProjection => "cross projection + reprojection",
            Self::Reconstruct => "reconstruct",
            Self::Smoothing => "smoothing",
            Self::RegatherReadback => "regather readback",
            Self::Regather => "regather",
            Self::Selection => "selection",
            Self::SelectionReadback => "selection readback",
            Self::Batches => "batches",
            Self::Wait => "wait",
            Self::Readback => "readback",
            Self::Encode => "encode",
        }
    }

    /// Whether the stage is GPU passes (timed by the profiler's clock);
    /// the others are CPU work, timed on the CPU.
    pub fn is_gpu(self) -> bool {
        matches!(
            self,
            Self::ShooterEnergy
                | Self::ItemBuffers
                | Self::FrontHemicubes
                | Self::BackHemicubes
                | Self::TileGather
                | Self::CrossProjection
                | Self::Reconstruct
                | Self::Smoothing
                | Self::Selection
        )
    }
}

/// One frame's times.
#[derive(Debug, Clone, Default)]
pub struct FrameProfile {
    /// Wall time from [`Profiler::begin_frame`] to [`Profiler::end_frame`].
    pub wall: Duration,
    /// Time per unit and stage; stages that did not run are absent.
    pub stages: BTreeMap<(Unit, Stage), Duration>,
    /// How many times each of them was timed (batches, readbacks, ...).
    pub counts: BTreeMap<(Unit, Stage), u32>,
}

impl FrameProfile {
    /// Sum over the stages that `keep` accepts.
    pub fn sum(&self, keep: impl Fn(Stage) -> bool) -> Duration {
        self.stages
            .iter()
            .filter(|((_, s), _)| keep(*s))
            .map(|(_, d)| *d)
            .sum()
    }
}

/// A shared handle on a profiler, or nothing (see the module doc).
#[derive(Clone, Default)]
pub struct Profiler(Option<Arc<Mutex<State>>>);

impl std::fmt::Debug for Profiler {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_tuple("Profiler").field(&self.clock()).finish()
    }
}

struct State {
    clock: Clock,
    unit: Unit,
    frame_started: Instant,
    stages: BTreeMap<(Unit, Stage), Duration>,
    counts: BTreeMap<(Unit, Stage), u32>,
    /// The device, to submit and wait (CPU clock) and to write timestamps.
    gpu: Option<(wgpu::Device, wgpu::Queue)>,
    /// CPU clock: when the open GPU span began.
    span_started: Option<Instant>,
    /// GPU clock: the timestamps of the frame.
    timestamps: Timestamps,
}

#[derive(Default)]
struct Timestamps {
    sets: Vec<wgpu::QuerySet>,
    /// Queries written so far this frame.
    used: u32,
    /// The query that opens the current span.
    open: Option<u32>,
    /// Closed spans: unit, stage, first and last query.
    spans: Vec<(Unit, Stage, u32, u32)>,
}

impl Profiler {
    /// A profiler that records nothing.
    pub fn disabled() -> Self {
        Self(None)
    }

    /// An enabled profiler on `gpu`, timing GPU stages with `clock`, or
    /// with CPU timing when the device has no timestamp queries.
    pub fn new(gpu: &Device, clock: Clock) -> Self {
        let clock = match clock {
            Clock::Gpu => Clock::best_for(gpu),
            Clock::Cpu => Clock::Cpu,
        };
        Self::with(Some((gpu.device.clone(), gpu.queue.clone())), clock)
    }

    fn with(gpu: Option<(wgpu::Device, wgpu::Queue)>, clock: Clock) -> Self {
        Self(Some(Arc::new(Mutex::new(State {
            clock,
            unit: Unit::Move,
            frame_started: Instant::now(),
            stages: BTreeMap::new(),
            counts: BTreeMap::new(),
            gpu,
            span_started: None,
            timestamps: Timestamps::default(),
        }))))
    }

    fn state(&self) -> Option<MutexGuard<'_, State>> {
        self.0
            .as_ref()
            .map(|s| s.lock().unwrap_or_else(|p| p.into_inner()))
    }

    /// Whether anything is recorded.
    pub fn is_enabled(&self) -> bool {
        self.0.is_some()
    }

    /// The clock, when enabled.
    pub fn clock(&self) -> Option<Clock> {
        self.state().map(|s| s.clock)
    }

    /// The unit the following stages belong to.
    pub fn set_unit(&self, unit: Unit) {
        if let Some(mut s) = self.state() {
            s.unit = unit;
        }
    }

    /// Starts timing a CPU stage: pass the result to [`Profiler::stop`].
    /// `None` (nothing is read) when disabled.
    pub fn start(&self) -> Option<Instant> {
        self.0.as_ref().map(|_| Instant::now())
    }

    /// Adds the time since `started` to `stage` of the current unit.
    pub fn stop(&self, started: Option<Instant>, stage: Stage) {
        if let (Some(started), Some(mut s)) = (started, self.state()) {
            let unit = s.unit;
            s.add(unit, stage, started.elapsed());
        }
    }

    /// Opens a GPU span at the current end of `encoder`: call after
    /// creating an encoder whose passes are marked. With the CPU clock it
    /// first waits for queued work (counted as [`Stage::Wait`]).
    pub fn open(&self, encoder: &mut wgpu::CommandEncoder) {
        let Some(mut s) = self.state() else { return };
        match s.clock {
            Clock::Cpu => {
                let waited = Instant::now();
                s.wait_idle();
                let unit = s.unit;
                s.add(unit, Stage::Wait, waited.elapsed());
                s.span_started = Some(Instant::now());
            }
            Clock::Gpu => {
                let query = s.write_timestamp(encoder);
                s.timestamps.open = query;
            }
        }
    }

    /// The passes encoded into `encoder` since [`Profiler::open`] or the
    /// previous mark are `stage`; opens the next span. With the CPU clock
    /// the encoder is submitted, waited for and replaced by a new one.
    pub fn mark(&self, encoder: &mut wgpu::CommandEncoder, stage: Stage) {
        let Some(mut s) = self.state() else { return };
        let unit = s.unit;
        match s.clock {
            Clock::Cpu => {
                if let Some((device, queue)) = &s.gpu {
                    let done = std::mem::replace(
                        encoder,
                        device.create_command_encoder(&Default::default()),
                    );
                    queue.submit([done.finish()]);
                }
                s.wait_idle();
                let now = Instant::now();
                if let Some(started) = s.span_started.replace(now) {
                    s.add(unit, stage, now - started);
                }
            }
            Clock::Gpu => {
                let end = s.write_timestamp(encoder);
                if let (Some(first), Some(last)) = (s.timestamps.open, end) {
                    s.timestamps.spans.push((unit, stage, first, last));
                }
                s.timestamps.open = end;
            }
        }
    }

    /// Waits for every submitted command, so that a CPU stage timed next
    /// (a readback) does not include queued GPU work. With the CPU clock
    /// the wait is counted as [`Stage::Wait`]; with the GPU clock it is
    /// not counted (the GPU stages hold that time).
    pub fn sync(&self) {
        let Some(mut s) = self.state() else { return };
        let waited = Instant::now();
        s.wait_idle();
        if s.clock == Clock::Cpu {
            let unit = s.unit;
            s.add(unit, Stage::Wait, waited.elapsed());
        }
    }

    /// Starts a frame: forgets the previous one's times.
    pub fn begin_frame(&self) {
        if let Some(mut s) = self.state() {
            s.stages.clear();
            s.counts.clear();
            s.timestamps.used = 0;
            s.timestamps.open = None;
            s.timestamps.spans.clear();
            s.span_started = None;
            s.unit = Unit::Move;
            s.frame_started = Instant::now();
        }
    }

    /// Ends the frame: its wall time, then (outside it) the GPU stages'
    /// timestamps resolved and read back. `None` when disabled.
    pub fn end_frame(&self) -> Result<Option<FrameProfile>, GpuError> {
        let Some(mut s) = self.state() else {
            return Ok(None);
        };
        let wall = s.frame_started.elapsed();
        if s.clock == Clock::Gpu && !s.timestamps.spans.is_empty() {
            let ticks = s.read_timestamps()?;
            let period = s
                .gpu
                .as_ref()
                .map_or(1.0, |(_, q)| q.get_timestamp_period());
            let spans = std::mem::take(&mut s.timestamps.spans);
            for (unit, stage, first, last) in spans {
                let (a, b) = (ticks[first as usize], ticks[last as usize]);
                let ns = b.saturating_sub(a) as f64 * f64::from(period);
                s.add(unit, stage, Duration::from_nanos(ns as u64));
            }
        }
        Ok(Some(FrameProfile {
            wall,
            stages: std::mem::take(&mut s.stages),
            counts: std::mem::take(&mut s.counts),
        }))
    }
}

impl State {
    fn add(&mut self, unit: Unit, stage: Stage, time: Duration) {
        *self.stages.entry((unit, stage)).or_default() += time;
        *self.counts.entry((unit, stage)).or_default() += 1;
    }

    fn wait_idle(&self) {
        if let Some((device, _)) = &self.gpu {
            // A failed wait shows up in the solver's own next readback.
            let _ = device.poll(wgpu::PollType::wait_indefinitely());
        }
    }

    /// Writes the next timestamp into `encoder`; its query index.
    fn write_timestamp(&mut self, encoder: &mut wgpu::CommandEncoder) -> Option<u32> {
        let (device, _) = self.gpu.as_ref()?;
        let index = self.timestamps.used;
        let set = (index / QUERIES_PER_SET) as usize;
        if set == self.timestamps.sets.len() {
            self.timestamps
                .sets
                .push(device.create_query_set(&wgpu::QuerySetDescriptor {
                    label: Some("profile timestamps"),
                    ty: wgpu::QueryType::Timestamp,
                    count: QUERIES_PER_SET,
                }));
        }
        encoder.write_timestamp(&self.timestamps.sets[set], index % QUERIES_PER_SET);
        self.timestamps.used += 1;
        Some(index)
    }

    /// The frame's timestamps, in ticks.
    fn read_timestamps(&self) -> Result<Vec<u64>, GpuError> {
        let Some((device, queue)) = &self.gpu else {
            return Ok(Vec::new());
        };
        let used = self.timestamps.used;
        let size = u64::from(used.max(1)) * 8;
        let resolved = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("profile timestamps resolved"),
            size,
            usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let label = ("profile timestamps readback", size);
        let bytes = read_back(device, queue, label, &resolved, |encoder| {
            for (i, set) in self.timestamps.sets.iter().enumerate() {
                let first = i as u32 * QUERIES_PER_SET;
                if first >= used {
                    break;
                }
                let count = (used - first).min(QUERIES_PER_SET);
                encoder.resolve_query_set(set, 0..count, &resolved, u64::from(first) * 8);
            }
        })?;
        Ok(bytemuck::pod_collect_to_vec(&bytes))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A disabled profiler is a no-op: no clock, no frame, nothing timed.
    #[test]
    fn disabled_profiler_records_nothing() {
        let p = Profiler::disabled();
        assert!(!p.is_enabled());
        assert_eq!(p.clock(), None);
        p.begin_frame();
        p.set_unit(Unit::Refinement);
        let t = p.start();
        assert!(t.is_none(), "a disabled profiler reads no clock");
        p.stop(t, Stage::Batches);
        p.sync();
        assert!(p.end_frame().expect("nothing to read back").is_none());
    }

    /// Stages land under the unit current when they stop, a stage timed
    /// twice adds up, disjoint CPU stages sum to at most the frame, and a
    /// new frame starts empty.
    #[test]
    fn stages_add_up_per_unit_within_the_frame() {
        let p = Profiler::with(None, Clock::Cpu);
        p.begin_frame();
        for _ in 0..2 {
            let t = p.start();
            std::hint::black_box((0..10_000u64).sum::<u64>());
            p.stop(t, Stage::JobSetup);
        }
        p.set_unit(Unit::Publication);
        let t = p.start();
        p.stop(t, Stage::Encode);
        let frame = p.end_frame().expect("no GPU").expect("enabled");
        let keys: Vec<_> = frame.stages.keys().copied().collect();
        assert_eq!(
            keys,
            [
                (Unit::Move, Stage::JobSetup),
                (Unit::Publication, Stage::Encode)
            ]
        );
        assert_eq!(frame.counts[&(Unit::Move, Stage::JobSetup)], 2);
        assert!(frame.sum(|_| true) <= frame.wall);
        p.begin_frame();
        let next = p.end_frame().expect("no GPU").expect("enabled");
        assert!(next.stages.is_empty());
    }

    /// Reports and JSON key on these names: they stay as they are, and no
    /// two stages or units share one.
    #[test]
    fn names_are_stable_and_distinct() {
        let stages: Vec<&str> = Stage::ALL.iter().map(|s| s.name()).collect();
        assert_eq!(
            stages,
            [
                "solver setup",
                "move setup",
                "job setup",
                "shooter energy",
                "item buffers",
                "front hemicubes",
                "back hemicubes",
                "direct light",
                "tile gather",
                "cross projection + reprojection",
                "reconstruct",
                "smoothing",
                "regather readback",
                "regather",
                "selection",
                "selection readback",
                "batches",
                "wait",
                "readback",
                "encode",
            ]
        );
        let units: Vec<&str> = Unit::ALL.iter().map(|u| u.name()).collect();
        assert_eq!(units, ["move", "refinement", "insertion", "publication"]);
        let mut distinct = stages.clone();
        distinct.sort_unstable();
        distinct.dedup();
        assert_eq!(distinct.len(), stages.len());
    }
}
