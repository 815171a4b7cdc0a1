//! `lightwire-client load`: many viewers, a few drivers, one report.
//!
//! 1. **Connect** `--drivers K` driver and `--viewers N` viewer clients
//!    (at most `--connect-concurrency` handshakes at a time). A failed
//!    connection is a *connect error*; the run goes on without it.
//! 2. **Drive** for `--duration D`: every driver samples the script at
//!    `--rate` poses/s on a shared clock. Driver `i` moves dynamic object
//!    `i mod M` (M dynamic objects in the scene); drivers of the same
//!    object share one seq source and are staggered by `1/(rate * K_obj)`
//!    so their poses interleave. Every client shares one [`LatencyBook`],
//!    so each viewer measures the transform-to-delivery latency of every
//!    driver's pose: send → the viewer has applied the version that echoes
//!    the seq. With `--interval I` the drive phase is cut into intervals
//!    of `I`: each gets its own latency percentiles (a histogram reset
//!    when the interval closes), errors, versions skipped, reconnects and
//!    stale seqs, in the report's `intervals` and as one line on stderr as
//!    it closes, so a long run shows drift as it happens.
//! 3. **Settle**: the drivers stop; the run waits until the server's
//!    version (from `Stats`) has not changed for `--quiet` and every
//!    viewer holds it (and, for a script with light keys, the `Lights`
//!    of the version it holds shows the last state the drivers sent each
//!    light: a solver busy with it publishes nothing meanwhile), or
//!    `--settle-timeout` passes. Each viewer's final
//!    version and lightmap checksum (FNV-1a of its texels) go into the
//!    report, so a test can compare them with the server's state.
//!    `--verify-url` does that comparison itself: a fresh client on that
//!    server (e.g. the solver behind the relay under test) takes a
//!    keyframe, and every viewer whose texels differ is an error.
//! 4. **Report** (`--report FILE`, JSON; a summary on stderr) and exit
//!    code: 0, or 1 when `--max-p99-ms` or `--max-errors` is missed.
//!
//! Errors (what `--max-errors` counts): connect errors, disconnects,
//! failed reconnects, server frames that do not decode or apply, server
//! `Error` frames (except `StaleSeq`), refused poses, and viewers not on
//! the final version after settling, and with `--verify-url` viewers not
//! bit-exact with its keyframe. `StaleSeq` refusals are reported
//! separately: when two drivers move one object, a pose overtaken by the
//! other driver's newer one is refused by design ("latest seq wins").
//! *Versions skipped*: per viewer, the versions between two it applied
//! that it never held (a slow viewer is skipped forward by a merged delta
//! or a keyframe). Poses the solver coalesced into one version are not
//! numbered and do not count; behind a relay, versions the relay itself
//! was skipped past by its upstream do (its version numbers follow the
//! solver's).
//! Rates (frames/s, bytes/s, poses/s) are measured over the drive phase
//! only; latency samples include the settle phase (the last poses'
//! deliveries).
//!
//! **Light keys.** A script with `lights` makes the drivers replay them
//! too: light track `j` (in the script's order) is sent by driver `j mod
//! K`, at the same `--rate`, each sample as a `SetLight` when it differs
//! from the last one that driver sent (a held or stepped state is sent
//! once, not 30 times a second); the fields the keys leave out are the
//! light's state in the first `Lights` a driver received. Every client
//! then asks for `Lights`, and each viewer measures the light latency:
//! `SetLight` sent → the viewer has applied the first version whose
//! `Lights` shows its seq (the same shared book, the same meaning as for
//! transforms). The report's `lights_sent` and `light_latency` hold them;
//! `--max-p99-ms` applies to the transform latency of a script with
//! keyframes and to the light latency of one with light keys.
//! A script without keyframes moves no object.
//!
//! Where the latency goes: per transform, the first viewer's latency is
//! the server's part (inbox, wait for the tick, solve, encode) plus one
//! hop; the spread between the first and the last viewer is the fan-out
//! (the server writing N sockets, the viewers decoding, all on the same
//! machine). The report gives both, and the server's own tick and solve
//! times from its `Stats`.

use std::collections::{BTreeMap, HashMap};
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use hdrhistogram::Histogram;
use lightwire_client::latency::{LatencyBook, SeqSource};
use lightwire_client::script::Script;
use lightwire_client::{
    Client, ClientError, Counters, Endpoint, ErrorCode, Event, Frame, LightState, Options,
};
use lightwire_protocol::seq_is_newer;
use serde::Serialize;
use tokio::sync::{Semaphore, watch};
use tokio::task::JoinSet;

use super::{ServerArgs, ms, parse_duration, parse_rate, pick_object};

/// Error messages kept verbatim in the report (the rest are counted).
const MAX_MESSAGES: usize = 20;
/// Transforms whose per-viewer deliveries are tracked for the first
/// delivery / fan-out spread split (later ones are not tracked).
const MAX_TRACKED_TRANSFORMS: usize = 200_000;

/// Arguments of `load`.
#[derive(clap::Args, Debug)]
pub struct LoadArgs {
    #[command(flatten)]
    pub server: ServerArgs,
    /// The transform script the drivers replay.
    #[arg(long)]
    pub script: PathBuf,
    /// Concurrent viewer connections.
    #[arg(long, default_value_t = 10)]
    pub viewers: usize,
    /// Concurrent driver connections.
    #[arg(long, default_value_t = 1)]
    pub drivers: usize,
    /// How long the drivers drive (e.g. 20s, 2m).
    #[arg(long, value_parser = parse_duration, default_value = "10s")]
    pub duration: Duration,
    /// Poses per second per driver.
    #[arg(long, value_parser = parse_rate, default_value = "30")]
    pub rate: f64,
    /// Where to write the JSON report.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Fail (exit 1) if the p99 transform-to-delivery latency exceeds this.
    #[arg(long)]
    pub max_p99_ms: Option<f64>,
    /// Fail (exit 1) if there are more errors than this.
    #[arg(long)]
    pub max_errors: Option<u64>,
    /// The object the drivers move (default: the script's `object`, else
    /// every dynamic object, drivers spread over them).
    #[arg(long)]
    pub object: Option<String>,
    /// Token for viewers (default: --token / LIGHTWIRE_TOKEN).
    #[arg(long)]
    pub viewer_token: Option<String>,
    /// Handshakes in flight at once while connecting.
    #[arg(long, default_value_t = 32)]
    pub connect_concurrency: usize,
    /// The server counts as settled when its version has not changed for this long.
    #[arg(long, value_parser = parse_duration, default_value = "1500ms")]
    pub quiet: Duration,
    /// Give up waiting for the viewers to settle after this long.
    #[arg(long, value_parser = parse_duration, default_value = "60s")]
    pub settle_timeout: Duration,
    /// Report latency percentiles, errors, versions skipped and reconnects
    /// per interval of the drive phase (e.g. 60s; at most
    /// 10,000 intervals), in the report's `intervals` and on stderr.
    #[arg(long, value_parser = parse_duration)]
    pub interval: Option<Duration>,
    /// After settling, compare every viewer's lightmap with a fresh
    /// keyframe from this server (e.g. the solver behind the relay the
    /// viewers use); a viewer that differs is an error. Same URL forms and
    /// `--scene` as the server argument; the viewer token.
    #[arg(long)]
    pub verify_url: Option<String>,
}

/// Latency percentiles in milliseconds.
#[derive(Debug, Serialize, PartialEq)]
pub struct LatencyReport {
    /// Samples: (viewer, transform) deliveries, or transforms for the
    /// per-transform figures.
    pub samples: u64,
    pub p50_ms: f64,
    pub p95_ms: f64,
    pub p99_ms: f64,
    pub max_ms: f64,
    pub mean_ms: f64,
}

/// The server's tick timings (means of its `Stats`, sampled every 250 ms
/// during the drive phase): where the server's share of the latency goes.
#[derive(Debug, Serialize)]
pub struct ServerReport {
    /// `Stats` frames sampled.
    pub samples: u64,
    /// Mean wall time of a tick, ms.
    pub tick_ms_mean: f64,
    /// Longest sampled tick, ms.
    pub tick_ms_max: f64,
    /// Mean solver time per tick, ms.
    pub solve_ms_mean: f64,
    /// Mean redistribution time per tick, ms.
    pub redistribution_ms_mean: f64,
}

/// One viewer's end state.
#[derive(Debug, Serialize)]
pub struct ViewerFinal {
    /// The version it held at the end (`null`: it never got a keyframe).
    pub version: Option<u64>,
    /// FNV-1a 64 of its texel bytes, hex.
    pub checksum: Option<String>,
}

/// One interval of the drive phase (`--interval`).
#[derive(Debug, Serialize, PartialEq)]
pub struct IntervalReport {
    /// 0 for the first interval.
    pub index: usize,
    /// Seconds since the drive phase began.
    pub start_s: f64,
    pub end_s: f64,
    /// Transform-to-delivery latency of the deliveries in this interval.
    pub latency: LatencyReport,
    /// Errors in this interval (what `--max-errors` counts, as they happen).
    pub errors: u64,
    /// Versions viewers did not receive one by one (skipped forward by a
    /// merged delta or a keyframe), summed over viewers.
    pub versions_skipped: u64,
    /// Versions viewers applied, summed over viewers.
    pub versions_applied: u64,
    /// Sessions re-opened after a disconnect, all clients.
    pub reconnects: u64,
    /// `StaleSeq` refusals (by design with drivers sharing an object).
    pub stale_seqs: u64,
    /// Poses the drivers handed to their clients (the outbox may still
    /// coalesce some before they are written).
    pub poses_sent: u64,
    /// Light states the drivers handed to their clients (likewise).
    pub lights_sent: u64,
}

/// The end-of-run comparison with a fresh keyframe (`--verify-url`).
#[derive(Debug, Serialize)]
pub struct VerifyReport {
    pub url: String,
    /// The fresh keyframe's version (a relay's versions equal its solver's
    /// only while it has followed one solver run).
    pub version: u64,
    /// FNV-1a 64 of its texels, hex.
    pub checksum: String,
    /// Viewers whose lightmap has exactly these texels.
    pub viewers_bit_exact: usize,
    pub viewers_differing: usize,
}

/// The JSON report.
#[derive(Debug, Serialize)]
pub struct Report {
    pub url: String,
    pub scene: String,
    pub script: String,
    pub viewers: usize,
    pub drivers: usize,
    pub duration_s: f64,
    pub rate_hz: f64,
    /// Connections that could not be opened at the start.
    pub connect_errors: u64,
    /// Everything `--max-errors` counts (see the module docs).
    pub errors: u64,
    pub error_breakdown: BTreeMap<&'static str, u64>,
    /// The first error messages, verbatim.
    pub error_messages: Vec<String>,
    /// Versions viewers skipped (see [`IntervalReport::versions_skipped`]),
    /// over the whole run.
    pub versions_skipped: u64,
    /// Poses refused because another driver's newer pose was first.
    pub stale_seqs: u64,
    pub resyncs: u64,
    pub reconnects: u64,
    /// All binary frames viewers received during the drive phase, per second.
    pub frames_per_s: f64,
    pub frames_per_s_per_viewer: f64,
    /// Lightmap versions applied by viewers, per second per viewer.
    pub versions_per_s_per_viewer: f64,
    pub bytes_per_s: f64,
    pub bytes_per_s_per_viewer: f64,
    pub poses_sent: u64,
    pub poses_per_s: f64,
    /// `SetLight`s the drivers wrote during the drive phase (a script's
    /// light keys; 0 without).
    pub lights_sent: u64,
    pub lights_per_s: f64,
    /// Transform (driver send) to delivery (viewer applied), every
    /// (viewer, transform) pair.
    pub latency: LatencyReport,
    /// `SetLight` (driver send) to the first version whose `Lights` shows
    /// its seq (viewer applied), every (viewer, light state) pair.
    pub light_latency: LatencyReport,
    /// Per transform, the latency of the first viewer to apply it: the
    /// server's part (inbox, tick, solve, encode) plus one hop.
    pub first_delivery: LatencyReport,
    /// Per transform that reached every viewer: last minus first viewer,
    /// the time the fan-out to all viewers took (server sends and the
    /// viewers' decoding, on the same cores).
    pub fanout_spread: LatencyReport,
    /// The server's own timings during the drive phase.
    pub server: ServerReport,
    /// The server's version after settling (from `Stats`).
    pub final_version: Option<u64>,
    pub settled: bool,
    pub settle_s: f64,
    pub viewers_on_final_version: usize,
    /// Distinct lightmap checksums among viewers on the final version.
    pub final_checksums: Vec<String>,
    pub viewer_final: Vec<ViewerFinal>,
    /// Per interval of the drive phase (`--interval`; empty without).
    pub intervals: Vec<IntervalReport>,
    /// The comparison with `--verify-url` (`null` without).
    pub verify: Option<VerifyReport>,
    /// Limits that were missed.
    pub failures: Vec<String>,
    pub passed: bool,
}

/// Runs `load`; `Ok(false)` when a limit was missed.
pub fn run(args: LoadArgs) -> Result<bool> {
    let script = Script::load(&args.script)?;
    if !script.has_poses() && args.object.is_some() {
        bail!(
            "--object: {} has no keyframes to move an object along",
            args.script.display()
        );
    }
    if args.viewers == 0 && args.drivers == 0 {
        bail!("--viewers and --drivers are both 0: nothing to do");
    }
    if let Some(step) = args.interval {
        if step < Duration::from_millis(100) {
            bail!("--interval {step:?} is too short (at least 100ms)");
        }
        let n = interval_count(args.duration, step);
        if n > MAX_INTERVALS {
            bail!(
                "--interval {step:?} cuts --duration {:?} into {n} intervals; at most {MAX_INTERVALS}",
                args.duration
            );
        }
    }
    let report = super::runtime()?.block_on(load(&args, script))?;
    let text = serde_json::to_string_pretty(&report).context("encoding the report")?;
    if let Some(path) = &args.report {
        std::fs::write(path, format!("{text}\n"))
            .with_context(|| format!("writing the report to {}", path.display()))?;
    }
    eprintln!(
        "load: {} viewers, {} drivers, {:.0} s: {} errors ({} connect), {:.0} frames/s, {:.1} KiB/s, latency p50 {:.1} ms p95 {:.1} ms p99 {:.1} ms max {:.1} ms ({} samples; first viewer p50 {:.1} ms, fan-out spread p50 {:.1} ms p99 {:.1} ms), {} resyncs, {} stale; final version {:?}, {} of {} viewers on it{}",
        report.viewers,
        report.drivers,
        report.duration_s,
        report.errors,
        report.connect_errors,
        report.frames_per_s,
        report.bytes_per_s / 1024.0,
        report.latency.p50_ms,
        report.latency.p95_ms,
        report.latency.p99_ms,
        report.latency.max_ms,
        report.latency.samples,
        report.first_delivery.p50_ms,
        report.fanout_spread.p50_ms,
        report.fanout_spread.p99_ms,
        report.resyncs,
        report.stale_seqs,
        report.final_version,
        report.viewers_on_final_version,
        report.viewers,
        if report.settled { "" } else { " (NOT settled)" }
    );
    if let Some(v) = &report.verify {
        eprintln!(
            "load: {} of {} viewers bit-exact with {} version {} (checksum {}); {} versions skipped",
            v.viewers_bit_exact,
            report.viewers,
            v.url,
            v.version,
            v.checksum,
            report.versions_skipped
        );
    }
    if report.lights_sent > 0 || report.light_latency.samples > 0 {
        eprintln!(
            "load: {} light states sent, light latency p50 {:.1} ms p95 {:.1} ms p99 {:.1} ms max {:.1} ms ({} samples)",
            report.lights_sent,
            report.light_latency.p50_ms,
            report.light_latency.p95_ms,
            report.light_latency.p99_ms,
            report.light_latency.max_ms,
            report.light_latency.samples,
        );
    }
    for m in &report.error_messages {
        eprintln!("  error: {m}");
    }
    for f in &report.failures {
        eprintln!("FAILED: {f}");
    }
    Ok(report.passed)
}

/// The whole run's latency histogram and the current interval's (reset
/// when the interval closes, so memory does not grow with the duration).
struct Latencies {
    all: Histogram<u64>,
    window: Histogram<u64>,
}

impl Latencies {
    fn new() -> Result<Self> {
        let all = Histogram::new_with_bounds(1, 60_000_000, 3).context("latency histogram")?;
        Ok(Self {
            window: all.clone(),
            all,
        })
    }

    fn record(&mut self, latency: Duration) {
        let us = latency.as_micros() as u64;
        self.all.saturating_record(us);
        self.window.saturating_record(us);
    }
}

/// Counts since the start of the run, updated as events arrive; an
/// interval is the difference of two snapshots.
#[derive(Default)]
struct Tally {
    errors: AtomicU64,
    versions_skipped: AtomicU64,
    versions_applied: AtomicU64,
    reconnects: AtomicU64,
    stale_seqs: AtomicU64,
    poses_sent: AtomicU64,
    lights_sent: AtomicU64,
}

impl Tally {
    fn snapshot(&self) -> TallySnapshot {
        let get = |a: &AtomicU64| a.load(Ordering::Relaxed);
        TallySnapshot {
            errors: get(&self.errors),
            versions_skipped: get(&self.versions_skipped),
            versions_applied: get(&self.versions_applied),
            reconnects: get(&self.reconnects),
            stale_seqs: get(&self.stale_seqs),
            poses_sent: get(&self.poses_sent),
            lights_sent: get(&self.lights_sent),
        }
    }
}

/// A copy of [`Tally`] at one instant.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct TallySnapshot {
    errors: u64,
    versions_skipped: u64,
    versions_applied: u64,
    reconnects: u64,
    stale_seqs: u64,
    poses_sent: u64,
    lights_sent: u64,
}

/// The interval being measured: when it began and the counts then.
struct Window {
    index: usize,
    start_s: f64,
    at_start: TallySnapshot,
}

impl Window {
    fn new(at_start: TallySnapshot) -> Self {
        Self {
            index: 0,
            start_s: 0.0,
            at_start,
        }
    }

    /// Ends the interval at `now_s` (seconds since the drive began):
    /// its percentiles from `latency` (which is then reset) and the counts
    /// since it began; the next interval starts here.
    fn close(
        &mut self,
        latency: &mut Histogram<u64>,
        now: TallySnapshot,
        now_s: f64,
    ) -> IntervalReport {
        let since = |f: fn(&TallySnapshot) -> u64| f(&now).saturating_sub(f(&self.at_start));
        let report = IntervalReport {
            index: self.index,
            start_s: (self.start_s * 1000.0).round() / 1000.0,
            end_s: (now_s * 1000.0).round() / 1000.0,
            latency: percentiles(latency),
            errors: since(|t| t.errors),
            versions_skipped: since(|t| t.versions_skipped),
            versions_applied: since(|t| t.versions_applied),
            reconnects: since(|t| t.reconnects),
            stale_seqs: since(|t| t.stale_seqs),
            poses_sent: since(|t| t.poses_sent),
            lights_sent: since(|t| t.lights_sent),
        };
        latency.reset();
        self.index += 1;
        self.start_s = now_s;
        self.at_start = now;
        report
    }
}

/// Versions between the one a viewer held and the one it now holds that
/// it never held (0 for its first version, or if versions went back, as
/// they can on a solver that restarted).
fn skipped(held: Option<u64>, new: u64) -> u64 {
    held.map_or(0, |h| new.saturating_sub(h).saturating_sub(1))
}

/// Intervals of `step` that cover `duration` (the last may be shorter).
fn interval_count(duration: Duration, step: Duration) -> u64 {
    if step.is_zero() {
        return u64::MAX;
    }
    (duration.as_secs_f64() / step.as_secs_f64() - 1e-9)
        .ceil()
        .max(1.0) as u64
}

/// At most this many intervals (`--interval`), so their reports stay small.
const MAX_INTERVALS: u64 = 10_000;

/// What every client task shares.
struct Shared {
    latency: Mutex<Latencies>,
    /// `SetLight` to the first version showing it, per (viewer, state).
    light_latency: Mutex<Histogram<u64>>,
    /// Running counts the intervals are cut from.
    tally: Tally,
    /// The server's tick timings as its `Stats` report them (one client
    /// records them; every client sees the same frames).
    server: Mutex<ServerSamples>,
    /// Per transform (object, seq): the earliest and latest viewer
    /// latency and how many viewers got it, for the first-delivery and
    /// fan-out split of the latency.
    deliveries: Mutex<HashMap<(u32, u64), Spread>>,
    /// Highest `Stats.version` seen by anyone.
    server_version: AtomicU64,
    /// Per light, the newest `SetLight` seq a driver handed its client.
    last_light_seqs: Mutex<BTreeMap<u32, u64>>,
    errors: Mutex<Errors>,
}

/// One transform's deliveries: earliest and latest viewer latency, and
/// how many viewers applied it.
type Spread = (Duration, Duration, u32);

/// Sums of `Stats` samples taken during the drive phase.
#[derive(Default)]
struct ServerSamples {
    samples: u64,
    tick_ms: f64,
    solve_ms: f64,
    redistribution_ms: f64,
    max_tick_ms: f64,
}

#[derive(Default)]
struct Errors {
    counts: BTreeMap<&'static str, u64>,
    messages: Vec<String>,
}

impl Shared {
    fn error(&self, kind: &'static str, message: String) {
        self.tally.errors.fetch_add(1, Ordering::Relaxed);
        let mut e = self.errors.lock().unwrap_or_else(|p| p.into_inner());
        *e.counts.entry(kind).or_default() += 1;
        if e.messages.len() < MAX_MESSAGES {
            e.messages.push(message);
        }
    }
}

/// The phases of a run, in order; client tasks snapshot their counters
/// when one begins.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
enum Phase {
    Connecting = 0,
    Driving = 1,
    Settling = 2,
    Stopped = 3,
}

/// What a driver task needs.
struct Driving {
    /// The object it moves (`None`: the script has no keyframes).
    object: Option<u32>,
    /// The light tracks it plays: (index in the script's tracks, light
    /// index in the scene, the light's state at the start).
    lights: Vec<(usize, u32, LightState)>,
    script: Arc<Script>,
    /// The script's time zero.
    clock: Instant,
    /// The first pose of this driver (staggered per object).
    first: tokio::time::Instant,
    period: Duration,
}

/// What a client task hands back.
struct Finished {
    client: Client,
    viewer: bool,
    /// Counters when each phase began (`Connecting` = at spawn).
    marks: [Counters; 4],
}

/// Reads a client's events until the run stops, recording latency and
/// errors; a driver also sends its poses during the drive phase.
async fn client_task(
    mut client: Client,
    shared: Arc<Shared>,
    mut phase: watch::Receiver<Phase>,
    driving: Option<Driving>,
    record_stats: bool,
) -> Finished {
    let viewer = driving.is_none();
    // The version this viewer last applied (for versions skipped).
    let mut held: Option<u64> = None;
    let mut marks: [Option<Counters>; 4] = [Some(client.counters()), None, None, None];
    let mut poses = driving.as_ref().map(|d| {
        let mut i = tokio::time::interval_at(d.first, d.period);
        i.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
        i
    });
    // The last state sent per light this driver plays.
    let mut sent_lights: BTreeMap<u32, LightState> = BTreeMap::new();
    loop {
        tokio::select! {
            changed = phase.changed() => {
                let now = *phase.borrow_and_update();
                marks[now as usize] = Some(client.counters());
                if changed.is_err() || now == Phase::Stopped {
                    break;
                }
            }
            _ = async {
                match poses.as_mut() {
                    Some(p) => { p.tick().await; }
                    None => std::future::pending::<()>().await,
                }
            } => {
                if let Some(d) = driving.as_ref().filter(|_| *phase.borrow() == Phase::Driving) {
                    let t = d.clock.elapsed().as_secs_f64();
                    if let Some(object) = d.object {
                        match client.send_pose(object, d.script.pose_at(t)) {
                            Ok(_) => { shared.tally.poses_sent.fetch_add(1, Ordering::Relaxed); }
                            Err(e) => shared.error("pose_refused_locally", e.to_string()),
                        }
                    }
                    for &(track, light, base) in &d.lights {
                        let state = d.script.light_at(track, t, &base);
                        if sent_lights.get(&light) == Some(&state) {
                            continue;
                        }
                        match client.send_light(light, state) {
                            Ok(seq) => {
                                sent_lights.insert(light, state);
                                let mut last = shared.last_light_seqs.lock().unwrap_or_else(|p| p.into_inner());
                                let newest = last.entry(light).or_insert(seq);
                                if seq_is_newer(seq, *newest) {
                                    *newest = seq;
                                }
                                drop(last);
                                shared.tally.lights_sent.fetch_add(1, Ordering::Relaxed);
                            }
                            Err(e) => shared.error("light_refused_locally", e.to_string()),
                        }
                    }
                }
            }
            event = client.next_event() => match event {
                Some(Event::Version(v)) if viewer => {
                    shared.tally.versions_applied.fetch_add(1, Ordering::Relaxed);
                    shared.tally.versions_skipped.fetch_add(skipped(held, v.version), Ordering::Relaxed);
                    held = Some(v.version);
                    let mut h = shared.latency.lock().unwrap_or_else(|p| p.into_inner());
                    for d in &v.delivered {
                        let Some(l) = d.latency else { continue };
                        h.record(l);
                    }
                    drop(h);
                    if !v.lights_delivered.is_empty() {
                        let mut h = shared.light_latency.lock().unwrap_or_else(|p| p.into_inner());
                        for l in v.lights_delivered.iter().filter_map(|d| d.latency) {
                            h.saturating_record(l.as_micros() as u64);
                        }
                    }
                    let mut per = shared.deliveries.lock().unwrap_or_else(|p| p.into_inner());
                    for d in &v.delivered {
                        let Some(l) = d.latency else { continue };
                        let key = (d.object, d.seq);
                        if let Some(e) = per.get_mut(&key) {
                            *e = (e.0.min(l), e.1.max(l), e.2 + 1);
                        } else if per.len() < MAX_TRACKED_TRANSFORMS {
                            per.insert(key, (l, l, 1));
                        }
                    }
                }
                Some(Event::Stats(s)) => {
                    shared.server_version.fetch_max(s.version, Ordering::Relaxed);
                    if record_stats && *phase.borrow() == Phase::Driving {
                        let mut acc = shared.server.lock().unwrap_or_else(|p| p.into_inner());
                        acc.samples += 1;
                        acc.tick_ms += f64::from(s.tick_ms);
                        acc.solve_ms += f64::from(s.solve_ms);
                        acc.redistribution_ms += f64::from(s.redistribution_ms);
                        acc.max_tick_ms = acc.max_tick_ms.max(f64::from(s.tick_ms));
                    }
                }
                // By design when drivers share an object; the run's total
                // comes from the counters.
                Some(Event::ServerError { code: ErrorCode::StaleSeq, .. }) => {
                    shared.tally.stale_seqs.fetch_add(1, Ordering::Relaxed);
                }
                // An error; the run's total comes from the counters.
                Some(Event::ServerError { code: ErrorCode::RateLimited, .. }) => {
                    shared.tally.errors.fetch_add(1, Ordering::Relaxed);
                }
                Some(Event::Connected { reconnect: true, .. }) => {
                    shared.tally.reconnects.fetch_add(1, Ordering::Relaxed);
                }
                Some(Event::ServerError { code, message }) => {
                    shared.error("server_error", format!("{}: server error {code}: {message}", client.endpoint()));
                }
                Some(Event::Error(e)) => shared.error(error_kind(&e), e.to_string()),
                Some(Event::Disconnected(e)) => shared.error("disconnect", e.to_string()),
                Some(Event::Lagged { dropped }) => {
                    shared.error("events_dropped", format!("{}: {dropped} events dropped (the load tester fell behind)", client.endpoint()));
                }
                Some(Event::Closed(Some(e))) => {
                    shared.error("closed", e.to_string());
                    // Wait for the end of the run so the marks stay in order.
                    let _ = phase.wait_for(|p| *p == Phase::Stopped).await;
                    break;
                }
                Some(Event::Closed(None)) | None => {
                    let _ = phase.wait_for(|p| *p == Phase::Stopped).await;
                    break;
                }
                Some(_) => {}
            },
        }
    }
    // A phase this task did not see begin (it ended early, or two phases
    // began between two polls) gets the previous phase's counters.
    let mut filled = [Counters::default(); 4];
    let mut last = Counters::default();
    for (slot, mark) in filled.iter_mut().zip(marks) {
        last = mark.unwrap_or(last);
        *slot = last;
    }
    Finished {
        client,
        viewer,
        marks: filled,
    }
}

fn error_kind(e: &ClientError) -> &'static str {
    match e {
        ClientError::Decode { .. } | ClientError::Protocol { .. } => "bad_frame",
        ClientError::Apply { .. } => "apply_failed",
        ClientError::Connect { .. } | ClientError::Handshake { .. } => "reconnect_failed",
        _ => "other",
    }
}

/// Opens `count` connections, `concurrency` handshakes at a time, in order.
async fn connect_all(
    endpoint: &Endpoint,
    options: &Options,
    count: usize,
    concurrency: &Arc<Semaphore>,
) -> Vec<Result<Client, ClientError>> {
    let mut set = JoinSet::new();
    for i in 0..count {
        let endpoint = endpoint.clone();
        let options = options.clone();
        let permits = concurrency.clone();
        set.spawn(async move {
            let _permit = permits.acquire_owned().await;
            (i, Client::connect_with(endpoint, options).await)
        });
    }
    let mut results: Vec<Option<Result<Client, ClientError>>> = (0..count).map(|_| None).collect();
    while let Some(joined) = set.join_next().await {
        if let Ok((i, r)) = joined {
            results[i] = Some(r);
        }
    }
    results
        .into_iter()
        .map(|r| r.unwrap_or(Err(ClientError::Closed)))
        .collect()
}

fn percentiles(h: &Histogram<u64>) -> LatencyReport {
    LatencyReport {
        samples: h.len(),
        p50_ms: ms(h.value_at_quantile(0.5)),
        p95_ms: ms(h.value_at_quantile(0.95)),
        p99_ms: ms(h.value_at_quantile(0.99)),
        max_ms: ms(h.max()),
        mean_ms: (h.mean() / 10.0).round() / 100.0,
    }
}

/// Sum of `f` over the counters at phase `to` minus at phase `from`.
fn delta(done: &[&Finished], from: Phase, to: Phase, f: impl Fn(&Counters) -> u64) -> u64 {
    done.iter()
        .map(|d| f(&d.marks[to as usize]).saturating_sub(f(&d.marks[from as usize])))
        .sum()
}

/// Compares every viewer's final lightmap with a fresh keyframe from
/// `url`; each viewer that differs (or holds nothing) is an error.
async fn verify(
    url: &str,
    args: &LoadArgs,
    options: &Options,
    viewers: &[ViewerFinal],
    shared: &Shared,
) -> Result<VerifyReport> {
    let endpoint = Endpoint::parse(url, args.server.scene.as_deref())
        .with_context(|| format!("--verify-url {url}"))?;
    let options = Options {
        client_name: "lightwire-client load verify".into(),
        ..options.clone()
    };
    let client = Client::connect_with(endpoint.clone(), options)
        .await
        .context("--verify-url")?;
    let frame = client
        .wait_for_version(0, Duration::from_secs(30))
        .await
        .context("--verify-url");
    client.close().await;
    let frame = frame?;
    let checksum = format!("{:016x}", frame.checksum());
    let exact = viewers
        .iter()
        .filter(|v| v.checksum.as_deref() == Some(checksum.as_str()))
        .count();
    let differing = viewers.len() - exact;
    if differing > 0 {
        shared.error(
            "not_bit_exact",
            format!(
                "{differing} of {} viewers do not hold the texels of {endpoint}'s version {} (checksum {checksum})",
                viewers.len(),
                frame.version()
            ),
        );
    }
    Ok(VerifyReport {
        url: endpoint.ws_url(),
        version: frame.version(),
        checksum,
        viewers_bit_exact: exact,
        viewers_differing: differing,
    })
}

async fn load(args: &LoadArgs, script: Script) -> Result<Report> {
    let endpoint = args.server.endpoint()?;
    let driver_token = args.server.token();
    let viewer_token = args.viewer_token.clone().or_else(|| driver_token.clone());
    // One book: every viewer looks up every driver's send times. One seq
    // source: seqs increase across all drivers, hence per object too.
    let base = Options {
        event_capacity: 1024,
        latency: Arc::new(LatencyBook::new(
            ((args.rate * args.drivers as f64 * 120.0) as usize).clamp(4096, 1 << 20),
        )),
        seqs: Arc::new(SeqSource::new()),
        // Drivers learn the lights' states to play keys onto, viewers
        // measure when each state shows.
        lights: !script.lights().is_empty(),
        ..Options::default()
    };
    let shared = Arc::new(Shared {
        latency: Mutex::new(Latencies::new()?),
        light_latency: Mutex::new(
            Histogram::new_with_bounds(1, 60_000_000, 3).context("light latency histogram")?,
        ),
        tally: Tally::default(),
        server: Mutex::new(ServerSamples::default()),
        deliveries: Mutex::new(HashMap::new()),
        server_version: AtomicU64::new(0),
        last_light_seqs: Mutex::new(BTreeMap::new()),
        errors: Mutex::new(Errors::default()),
    });
    let permits = Arc::new(Semaphore::new(args.connect_concurrency.max(1)));

    // 1. Connect.
    let mut connect_errors = 0u64;
    let driver_options = Options {
        token: driver_token,
        client_name: "lightwire-client load driver".into(),
        ..base.clone()
    };
    let mut drivers = Vec::new();
    for r in connect_all(&endpoint, &driver_options, args.drivers, &permits).await {
        match r {
            Ok(c) if c.role() == lightwire_client::Role::Viewer => bail!(
                "{endpoint}: the token grants the viewer role; drivers need a driver or admin token"
            ),
            Ok(c) => drivers.push(c),
            // A bad token or a missing scene will not get better.
            Err(e) if e.is_permanent() => bail!("driver: {e}"),
            Err(e) => {
                connect_errors += 1;
                shared.error("connect", format!("driver: {e}"));
            }
        }
    }
    let viewer_options = Options {
        token: viewer_token,
        client_name: "lightwire-client load viewer".into(),
        ..base.clone()
    };
    let mut viewers = Vec::new();
    for r in connect_all(&endpoint, &viewer_options, args.viewers, &permits).await {
        match r {
            Ok(c) => viewers.push(c),
            Err(e) => {
                connect_errors += 1;
                shared.error("connect", format!("viewer: {e}"));
            }
        }
    }
    let Some(scene) = drivers.first().or(viewers.first()).map(|c| c.scene()) else {
        bail!("{endpoint}: no connection could be opened");
    };

    // Which object each driver moves; drivers of one object are staggered
    // evenly over one pose period.
    let objects: Vec<u32> = match args.object.as_deref().or(script.object.as_deref()) {
        _ if !script.has_poses() => Vec::new(),
        Some(name) => vec![pick_object(&scene, Some(name), None)?],
        None => scene
            .objects
            .iter()
            .enumerate()
            .filter(|(_, o)| o.dynamic)
            .map(|(i, _)| i as u32)
            .collect(),
    };
    if !drivers.is_empty() && script.has_poses() && objects.is_empty() {
        bail!("scene \"{}\" has no dynamic object to drive", scene.id);
    }
    // The lights the script plays, with their states at the start (the
    // first `Lights` a driver got; the Welcome's from a server that sent
    // none).
    let mut lights: Vec<(usize, u32, LightState)> = Vec::new();
    if !script.lights().is_empty() {
        let indices = script.light_indices(&scene)?;
        if let Some(first) = drivers.first() {
            if !first.follows_lights() {
                bail!(
                    "{}: {}",
                    args.script.display(),
                    ClientError::NoLights {
                        url: endpoint.ws_url()
                    }
                );
            }
            let frame = first
                .wait_for_version(0, Duration::from_secs(60))
                .await
                .context("a driver waiting for its first lightmap")?;
            for (track, light) in indices.into_iter().enumerate() {
                let base = frame
                    .lights
                    .get(&light)
                    .map_or(scene.lights[light as usize].state, |l| l.state);
                lights.push((track, light, base));
            }
        }
    }
    let period = Duration::from_secs_f64(1.0 / args.rate);
    let script = Arc::new(script);
    let (phase_tx, phase_rx) = watch::channel(Phase::Connecting);
    let start = tokio::time::Instant::now() + Duration::from_millis(200);
    let clock = Instant::now() + Duration::from_millis(200);
    let viewer_frames: Vec<watch::Receiver<Option<Arc<Frame>>>> =
        viewers.iter().map(|v| v.subscribe()).collect();
    let mut tasks = JoinSet::new();
    let n_drivers = drivers.len();
    for (i, client) in drivers.into_iter().enumerate() {
        let n_objects = objects.len().max(1);
        let object = objects.get(i % n_objects).copied();
        let sharing = (0..n_drivers)
            .filter(|j| j % n_objects == i % n_objects)
            .count();
        let rank = i / n_objects;
        let driving = Driving {
            object,
            lights: lights
                .iter()
                .copied()
                .filter(|(track, _, _)| track % n_drivers == i)
                .collect(),
            script: script.clone(),
            clock,
            first: start + period.mul_f64(rank as f64 / sharing as f64),
            period,
        };
        tasks.spawn(client_task(
            client,
            shared.clone(),
            phase_rx.clone(),
            Some(driving),
            i == 0,
        ));
    }
    let n_viewers = viewers.len();
    for (i, v) in viewers.into_iter().enumerate() {
        let record = n_drivers == 0 && i == 0;
        tasks.spawn(client_task(
            v,
            shared.clone(),
            phase_rx.clone(),
            None,
            record,
        ));
    }

    // 2. Drive, cut into intervals if asked.
    tokio::time::sleep_until(start).await;
    let _ = phase_tx.send(Phase::Driving);
    let mut intervals = Vec::new();
    if let Some(step) = args.interval {
        {
            // Deliveries before the drive began belong to no interval.
            let mut l = shared.latency.lock().unwrap_or_else(|p| p.into_inner());
            l.window.reset();
        }
        let mut window = Window::new(shared.tally.snapshot());
        let mut end = Duration::ZERO;
        while end < args.duration {
            end = (end + step).min(args.duration);
            tokio::time::sleep_until(start + end).await;
            let report = {
                let mut l = shared.latency.lock().unwrap_or_else(|p| p.into_inner());
                window.close(&mut l.window, shared.tally.snapshot(), end.as_secs_f64())
            };
            eprintln!(
                "load: interval {} ({:.0}-{:.0} s): latency p50 {:.1} ms p95 {:.1} ms p99 {:.1} ms max {:.1} ms ({} samples), {} versions applied, {} skipped, {} errors, {} reconnects, {} stale, {} poses, {} light states",
                report.index,
                report.start_s,
                report.end_s,
                report.latency.p50_ms,
                report.latency.p95_ms,
                report.latency.p99_ms,
                report.latency.max_ms,
                report.latency.samples,
                report.versions_applied,
                report.versions_skipped,
                report.errors,
                report.reconnects,
                report.stale_seqs,
                report.poses_sent,
                report.lights_sent,
            );
            intervals.push(report);
        }
    } else {
        tokio::time::sleep_until(start + args.duration).await;
    }
    let _ = phase_tx.send(Phase::Settling);
    let drive_secs = args.duration.as_secs_f64();

    // 3. Settle: the server's version stops changing and every viewer has it.
    let settle_started = Instant::now();
    let mut last_version = shared.server_version.load(Ordering::Relaxed);
    let mut last_change = Instant::now();
    let settled = loop {
        tokio::time::sleep(Duration::from_millis(100)).await;
        let v = shared.server_version.load(Ordering::Relaxed);
        if v != last_version {
            last_version = v;
            last_change = Instant::now();
        }
        let lights_sent = shared
            .last_light_seqs
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone();
        let shows_lights = |f: &Frame| {
            lights_sent.iter().all(|(light, &seq)| {
                f.lights
                    .get(light)
                    .is_some_and(|l| l.seq == seq || seq_is_newer(l.seq, seq))
            })
        };
        let all_there = viewer_frames.iter().all(|f| {
            f.borrow()
                .as_ref()
                .is_some_and(|f| f.version() == v && shows_lights(f))
        });
        if last_change.elapsed() >= args.quiet && all_there {
            break true;
        }
        if settle_started.elapsed() >= args.settle_timeout {
            break false;
        }
    };
    let settle_secs = settle_started.elapsed().as_secs_f64();
    let final_version = (last_version > 0).then_some(last_version);

    // 4. Collect.
    let _ = phase_tx.send(Phase::Stopped);
    let mut finished = Vec::new();
    while let Some(joined) = tasks.join_next().await {
        match joined {
            Ok(f) => finished.push(f),
            Err(e) => shared.error("task", format!("a client task failed: {e}")),
        }
    }
    let viewers_done: Vec<&Finished> = finished.iter().filter(|f| f.viewer).collect();
    let drivers_done: Vec<&Finished> = finished.iter().filter(|f| !f.viewer).collect();
    let all_done: Vec<&Finished> = finished.iter().collect();
    let mut viewer_final = Vec::with_capacity(viewer_frames.len());
    let mut on_final = 0;
    let mut checksums = std::collections::BTreeSet::new();
    for f in &viewer_frames {
        let frame = f.borrow().clone();
        let version = frame.as_ref().map(|f| f.version());
        let checksum = frame.as_ref().map(|f| format!("{:016x}", f.checksum()));
        if version.is_some() && version == final_version {
            on_final += 1;
            checksums.extend(checksum.clone());
        }
        viewer_final.push(ViewerFinal { version, checksum });
    }
    let verify = match &args.verify_url {
        Some(url) => match verify(url, args, &viewer_options, &viewer_final, &shared).await {
            Ok(v) => Some(v),
            Err(e) => {
                shared.error("verify_failed", format!("{e:#}"));
                None
            }
        },
        None => None,
    };
    if on_final < n_viewers {
        shared.error(
            "not_on_final_version",
            format!(
                "{} of {n_viewers} viewers do not hold the server's final version {final_version:?} after settling",
                n_viewers - on_final
            ),
        );
    }
    let (c, d, s) = (Phase::Connecting, Phase::Driving, Phase::Settling);
    let frames = delta(&viewers_done, d, s, |c| c.frames);
    let bytes = delta(&viewers_done, d, s, |c| c.bytes);
    let versions = delta(&viewers_done, d, s, |c| c.keyframes + c.deltas);
    let poses = delta(&drivers_done, d, s, |c| c.poses_sent);
    let lights_sent = delta(&drivers_done, d, s, |c| c.lights_sent);
    let total = |f: fn(&Counters) -> u64| delta(&all_done, c, Phase::Stopped, f);
    let (stale_seqs, resyncs, reconnects, rate_limited) = (
        total(|c| c.stale_seqs),
        total(|c| c.resyncs),
        total(|c| c.reconnects),
        total(|c| c.rate_limited),
    );
    let closing: Vec<_> = finished.into_iter().map(|f| f.client.close()).collect();
    let _ = tokio::time::timeout(
        Duration::from_secs(10),
        futures_util::future::join_all(closing),
    )
    .await;

    let errors = shared.errors.lock().unwrap_or_else(|p| p.into_inner());
    let mut breakdown = errors.counts.clone();
    if rate_limited > 0 {
        breakdown.insert("rate_limited", rate_limited);
    }
    let total_errors: u64 = breakdown.values().sum();
    let latency = percentiles(&shared.latency.lock().unwrap_or_else(|p| p.into_inner()).all);
    let light_latency = percentiles(
        &shared
            .light_latency
            .lock()
            .unwrap_or_else(|p| p.into_inner()),
    );
    let (first_delivery, fanout_spread) = {
        let per = shared.deliveries.lock().unwrap_or_else(|p| p.into_inner());
        let mut first = Histogram::<u64>::new_with_bounds(1, 60_000_000, 3).context("histogram")?;
        let mut spread = first.clone();
        for &(lo, hi, count) in per.values() {
            first.saturating_record(lo.as_micros() as u64);
            if count as usize == n_viewers {
                spread.saturating_record((hi - lo).as_micros() as u64);
            }
        }
        (percentiles(&first), percentiles(&spread))
    };
    let server = {
        let acc = shared.server.lock().unwrap_or_else(|p| p.into_inner());
        let mean = |sum: f64| {
            if acc.samples == 0 {
                0.0
            } else {
                (sum / acc.samples as f64 * 100.0).round() / 100.0
            }
        };
        ServerReport {
            samples: acc.samples,
            tick_ms_mean: mean(acc.tick_ms),
            tick_ms_max: acc.max_tick_ms,
            solve_ms_mean: mean(acc.solve_ms),
            redistribution_ms_mean: mean(acc.redistribution_ms),
        }
    };
    let mut failures = Vec::new();
    if let Some(limit) = args.max_p99_ms {
        if script.has_poses() {
            if latency.samples == 0 {
                failures.push(format!(
                    "--max-p99-ms {limit}: no latency was measured (no driver pose reached a viewer)"
                ));
            } else if latency.p99_ms > limit {
                failures.push(format!(
                    "p99 latency {:.1} ms exceeds --max-p99-ms {limit}",
                    latency.p99_ms
                ));
            }
        }
        if !script.lights().is_empty() {
            if light_latency.samples == 0 {
                failures.push(format!(
                    "--max-p99-ms {limit}: no light latency was measured (no driver's light state reached a viewer)"
                ));
            } else if light_latency.p99_ms > limit {
                failures.push(format!(
                    "p99 light latency {:.1} ms exceeds --max-p99-ms {limit}",
                    light_latency.p99_ms
                ));
            }
        }
    }
    if let Some(limit) = args.max_errors {
        if total_errors > limit {
            failures.push(format!("{total_errors} errors exceed --max-errors {limit}"));
        }
    }
    let per_viewer = |x: f64| {
        if n_viewers == 0 {
            0.0
        } else {
            x / n_viewers as f64
        }
    };
    Ok(Report {
        url: endpoint.ws_url(),
        scene: scene.id.clone(),
        script: args.script.display().to_string(),
        viewers: args.viewers,
        drivers: args.drivers,
        duration_s: drive_secs,
        rate_hz: args.rate,
        connect_errors,
        errors: total_errors,
        error_breakdown: breakdown,
        error_messages: errors.messages.clone(),
        versions_skipped: shared.tally.snapshot().versions_skipped,
        stale_seqs,
        resyncs,
        reconnects,
        frames_per_s: frames as f64 / drive_secs,
        frames_per_s_per_viewer: per_viewer(frames as f64 / drive_secs),
        versions_per_s_per_viewer: per_viewer(versions as f64 / drive_secs),
        bytes_per_s: bytes as f64 / drive_secs,
        bytes_per_s_per_viewer: per_viewer(bytes as f64 / drive_secs),
        poses_sent: poses,
        poses_per_s: poses as f64 / drive_secs,
        lights_sent,
        lights_per_s: lights_sent as f64 / drive_secs,
        latency,
        light_latency,
        first_delivery,
        fanout_spread,
        server,
        final_version,
        settled,
        settle_s: settle_secs,
        viewers_on_final_version: on_final,
        final_checksums: checksums.into_iter().collect(),
        viewer_final,
        intervals,
        verify,
        passed: failures.is_empty(),
        failures,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn histogram() -> Histogram<u64> {
        Histogram::new_with_bounds(1, 60_000_000, 3).expect("histogram")
    }

    #[test]
    fn an_interval_has_its_own_percentiles_and_counts_and_the_next_starts_empty() {
        let tally = Tally::default();
        let mut latencies = Latencies::new().expect("histograms");
        let mut window = Window::new(tally.snapshot());
        // First interval: 1..=100 ms, 3 errors, 5 skipped.
        for ms in 1..=100u64 {
            latencies.record(Duration::from_millis(ms));
        }
        tally.errors.fetch_add(3, Ordering::Relaxed);
        tally.versions_skipped.fetch_add(5, Ordering::Relaxed);
        tally.versions_applied.fetch_add(40, Ordering::Relaxed);
        tally.poses_sent.fetch_add(60, Ordering::Relaxed);
        let first = window.close(&mut latencies.window, tally.snapshot(), 60.0);
        assert_eq!((first.index, first.start_s, first.end_s), (0, 0.0, 60.0));
        assert_eq!(first.latency.samples, 100);
        assert!((first.latency.p50_ms - 50.0).abs() < 0.1, "{first:?}");
        assert!((first.latency.p99_ms - 99.0).abs() < 0.1, "{first:?}");
        assert!((first.latency.max_ms - 100.0).abs() < 0.1, "{first:?}");
        assert_eq!(
            (
                first.errors,
                first.versions_skipped,
                first.versions_applied,
                first.poses_sent
            ),
            (3, 5, 40, 60)
        );
        assert_eq!((first.reconnects, first.stale_seqs), (0, 0));

        // Second interval: only what happened since, 500 ms each.
        for _ in 0..10 {
            latencies.record(Duration::from_millis(500));
        }
        tally.reconnects.fetch_add(1, Ordering::Relaxed);
        tally.stale_seqs.fetch_add(2, Ordering::Relaxed);
        let second = window.close(&mut latencies.window, tally.snapshot(), 90.5);
        assert_eq!(
            (second.index, second.start_s, second.end_s),
            (1, 60.0, 90.5)
        );
        assert_eq!(second.latency.samples, 10);
        assert!((second.latency.p50_ms - 500.0).abs() < 1.0, "{second:?}");
        assert_eq!(
            (second.errors, second.versions_skipped, second.poses_sent),
            (0, 0, 0)
        );
        assert_eq!((second.reconnects, second.stale_seqs), (1, 2));

        // An empty interval reports zero samples, not stale figures.
        let third = window.close(&mut latencies.window, tally.snapshot(), 120.0);
        assert_eq!(third.latency, percentiles(&histogram()));
        assert_eq!(third.latency.samples, 0);
        // The run's histogram kept everything.
        assert_eq!(latencies.all.len(), 110);
    }

    #[test]
    fn versions_skipped_are_the_gaps_a_viewer_never_held() {
        assert_eq!(skipped(None, 17), 0, "the first version skips nothing");
        assert_eq!(skipped(Some(4), 5), 0);
        assert_eq!(
            skipped(Some(4), 8),
            3,
            "a merged delta 4 -> 8 skips 5, 6, 7"
        );
        assert_eq!(
            skipped(Some(9), 3),
            0,
            "a restarted solver counts from 1 again"
        );
        assert_eq!(skipped(Some(9), 9), 0);
        assert_eq!(skipped(Some(0), u64::MAX), u64::MAX - 1);
    }

    #[test]
    fn intervals_cover_the_duration_and_are_bounded() {
        let s = Duration::from_secs;
        assert_eq!(interval_count(s(600), s(60)), 10);
        assert_eq!(interval_count(s(601), s(60)), 11, "a shorter last interval");
        assert_eq!(interval_count(s(30), s(60)), 1);
        assert_eq!(interval_count(Duration::from_secs_f64(0.3), s(60)), 1);
        assert_eq!(interval_count(s(10), Duration::ZERO), u64::MAX);
    }
}
