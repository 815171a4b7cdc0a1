//! Viewers per relay: how many viewers one `lightwire relay` feeds while a
//! driver sends poses at 30 Hz, and at what delivery latency.
//!
//! ```sh
//! cargo build --release -p lightwire-server --bin lightwire --example relay_bench
//! ./target/release/examples/relay_bench --viewers 250,500,1000,2000 --duration 20
//! ```
//!
//! It starts an upstream and one relay (`lightwire relay`, the release
//! build next to this example). The upstream is either
//!
//! - `--upstream synthetic` (default): this program itself acts as a
//!   solver of cornell-low (its real atlas and `SceneInfo`, 3039 elements)
//!   that publishes one version per pose it receives, at most every tick
//!   of 1/60 s, with a bright band that moves with the pose (about a third
//!   of its 80 tiles change per version), encoded by the protocol crate's
//!   `Encoder` like a real solver. This is the load a GPU solver that
//!   keeps up with 30 Hz poses puts on a relay, which no solver on this
//!   machine's CPUs does (lavapipe needs 0.6-2.6 s per move, see
//!   BENCHMARKS.md);
//! - `--upstream reference`: a real `lightwire serve` with the CPU
//!   reference solver on cornell-low at `--density-scale` (default 0.5),
//!   which re-solves each move from scratch and so publishes a few
//!   versions per second.
//!
//! Then, for each viewer count N:
//!
//! - one **reference viewer** connects to the solver directly and notes
//!   when each version arrives;
//! - N **viewers** connect to the relay; each applies every frame to a
//!   validating `Lightmap` (as a real client would) and notes arrivals;
//! - one **driver** on the relay sends poses at `--rate` Hz for
//!   `--duration` seconds (forwarded upstream by the relay).
//!
//! Reported per N: **relay delivery latency** (a viewer's arrival of a
//! version minus the reference viewer's arrival of the same version: the
//! relay hop plus fan-out queueing), **transform-to-delivery latency**
//! (pose sent by the driver -> first frame at the viewer that reflects it:
//! what a player would see, solver included), versions per second,
//! versions the viewers skipped, and errors. Everything runs on this one
//! machine: the viewers' decoding competes with the relay for the CPUs,
//! so the numbers are a lower bound of what a relay on its own host does.

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use futures_util::{SinkExt, StreamExt};
use lightwire_protocol::lightmap::Lightmap;
use lightwire_protocol::{
    ClientMessage, PROTOCOL_VERSION, Pose, ServerMessage, decode_server, encode_client,
};
use lightwire_testkit::Lightwire;
use lightwire_testkit::peer::{Ws, hello};
use lightwire_testkit::pose::{box_turned, transform};
use tokio::sync::watch;
use tokio_tungstenite::tungstenite::Message;

const DRIVER: &str = "bench-driver-token";
const VIEWER: &str = "bench-viewer-token";

struct Args {
    viewers: Vec<usize>,
    duration: Duration,
    rate: f64,
    density: String,
    synthetic: bool,
    /// Viewers check every frame's versions and base but do not
    /// decompress tiles, so that more of them fit on this machine's CPUs
    /// next to the relay.
    light: bool,
}

fn parse_args() -> Args {
    let mut args = Args {
        viewers: vec![250, 500, 1000],
        duration: Duration::from_secs(20),
        rate: 30.0,
        density: "0.5".into(),
        synthetic: true,
        light: false,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        if flag == "--light-viewers" {
            args.light = true;
            continue;
        }
        let value = it.next().unwrap_or_else(|| {
            eprintln!("{flag} needs a value");
            std::process::exit(2)
        });
        let bad = |what: &str| -> ! {
            eprintln!("{flag} {value:?}: {what}");
            std::process::exit(2)
        };
        match flag.as_str() {
            "--viewers" => {
                args.viewers = value
                    .split(',')
                    .map(|v| v.trim().parse().unwrap_or_else(|_| bad("not a count")))
                    .collect()
            }
            "--duration" => {
                args.duration =
                    Duration::from_secs_f64(value.parse().unwrap_or_else(|_| bad("seconds")))
            }
            "--rate" => args.rate = value.parse().unwrap_or_else(|_| bad("poses per second")),
            "--density-scale" => args.density = value,
            "--upstream" => {
                args.synthetic = match value.as_str() {
                    "synthetic" => true,
                    "reference" => false,
                    _ => bad("synthetic or reference"),
                }
            }
            _ => bad(
                "unknown flag (--viewers, --duration, --rate, --upstream, --density-scale, --light-viewers)",
            ),
        }
    }
    args
}

/// What one viewer saw.
#[derive(Default)]
struct Seen {
    /// Version -> arrival.
    arrivals: Vec<(u64, Instant)>,
    /// Driver seq -> first arrival of a frame reflecting it (or a later one).
    reflected: Vec<(u64, Instant)>,
    errors: u64,
    skipped: u64,
}

/// Reads frames until `stop`, applying them (or, `light`, only checking
/// their versions), noting arrivals.
async fn view(mut ws: Ws, mut stop: watch::Receiver<bool>, light: bool) -> Seen {
    let mut seen = Seen::default();
    let mut map: Option<Lightmap> = None;
    let mut held: Option<u64> = None;
    let mut last_seq = 0u64;
    loop {
        let frame = tokio::select! {
            _ = async { stop.wait_for(|s| *s).await.map(|_| ()) } => break,
            f = ws.next() => f,
        };
        let bytes = match frame {
            Some(Ok(Message::Binary(b))) => b,
            Some(Ok(_)) => continue,
            _ => {
                seen.errors += 1;
                break;
            }
        };
        let now = Instant::now();
        let Ok(message) = decode_server(&bytes) else {
            seen.errors += 1;
            continue;
        };
        let (version, reflected) = match message {
            ServerMessage::Welcome { scene, .. } => {
                map = Lightmap::for_scene(&scene).ok();
                continue;
            }
            ServerMessage::Keyframe(k) => {
                let ok = light || map.as_mut().is_some_and(|m| m.apply_keyframe(&k).is_ok());
                if !ok {
                    seen.errors += 1;
                }
                held = Some(k.version);
                (k.version, k.reflected)
            }
            ServerMessage::Delta(d) => {
                if held != Some(d.base_version) || d.version <= d.base_version {
                    seen.errors += 1;
                    continue;
                }
                if !light && map.as_mut().is_none_or(|m| m.apply_delta(&d).is_err()) {
                    seen.errors += 1;
                    continue;
                }
                seen.skipped += d.version - d.base_version - 1;
                held = Some(d.version);
                (d.version, d.reflected)
            }
            _ => continue,
        };
        seen.arrivals.push((version, now));
        if let Some(seq) = reflected.iter().find(|r| r.object == 1).map(|r| r.seq) {
            if seq > last_seq {
                seen.reflected.push((seq, now));
                last_seq = seq;
            }
        }
    }
    seen
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

fn summary(mut ms: Vec<f64>) -> String {
    ms.sort_by(f64::total_cmp);
    format!(
        "{:.1} / {:.1} / {:.1} / {:.1}",
        percentile(&ms, 0.5),
        percentile(&ms, 0.95),
        percentile(&ms, 0.99),
        ms.last().copied().unwrap_or(f64::NAN)
    )
}

fn pose(t: f64) -> Pose {
    box_turned((t * 0.8) as f32)
}

/// CPU time (user + system) of process `pid` so far.
fn cpu_time(pid: u32) -> Duration {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    // Fields after the command name (which is in parentheses).
    let fields: Vec<&str> = stat
        .rsplit_once(')')
        .map_or(vec![], |(_, rest)| rest.split_whitespace().collect());
    let ticks = |i: usize| {
        fields
            .get(i)
            .and_then(|v| v.parse::<u64>().ok())
            .unwrap_or(0)
    };
    // utime and stime are fields 14 and 15 (1-based), 11 and 12 here;
    // USER_HZ is 100 on Linux.
    Duration::from_millis((ticks(11) + ticks(12)) * 10)
}

async fn round(
    relay: &str,
    relay_pid: u32,
    solver: &str,
    viewers: usize,
    args: &Args,
    seq0: u64,
) -> u64 {
    let (stop_tx, stop) = watch::channel(false);
    let reference = hello(solver, VIEWER).await.expect("reference viewer");
    let reference = tokio::spawn(view(reference, stop.clone(), args.light));
    let mut tasks = Vec::new();
    let mut failed = 0;
    for _ in 0..viewers {
        match hello(relay, VIEWER).await {
            Some(ws) => tasks.push(tokio::spawn(view(ws, stop.clone(), args.light))),
            None => failed += 1,
        }
    }
    tokio::time::sleep(Duration::from_secs(2)).await;
    let mut driver = hello(relay, DRIVER).await.expect("driver");
    let sent: Arc<Mutex<HashMap<u64, Instant>>> = Arc::default();
    let started = Instant::now();
    let relay_cpu = cpu_time(relay_pid);
    let period = Duration::from_secs_f64(1.0 / args.rate);
    let mut tick = tokio::time::interval(period);
    let mut seq = seq0;
    while started.elapsed() < args.duration {
        tick.tick().await;
        seq += 1;
        let t = transform(1, seq, pose(started.elapsed().as_secs_f64()));
        sent.lock().expect("lock").insert(seq, Instant::now());
        if driver
            .send(Message::Binary(encode_client(&t).into()))
            .await
            .is_err()
        {
            eprintln!("driver lost");
            break;
        }
        // Keep the driver's socket drained.
        while let Ok(Some(_)) = tokio::time::timeout(Duration::ZERO, driver.next()).await {}
    }
    let drive_time = started.elapsed();
    let relay_cpu = cpu_time(relay_pid).saturating_sub(relay_cpu);
    tokio::time::sleep(Duration::from_secs(2)).await;
    let _ = stop_tx.send(true);
    let reference = reference.await.expect("reference");
    let first: HashMap<u64, Instant> = reference.arrivals.iter().copied().collect();
    let sent = sent.lock().expect("lock").clone();
    let (mut hop, mut t2d) = (Vec::new(), Vec::new());
    let (mut errors, mut skipped, mut frames) = (0u64, 0u64, 0usize);
    for t in tasks {
        let seen = t.await.expect("viewer");
        errors += seen.errors;
        skipped += seen.skipped;
        frames += seen.arrivals.len();
        for (v, at) in &seen.arrivals {
            if let Some(r) = first.get(v) {
                hop.push(at.saturating_duration_since(*r).as_secs_f64() * 1e3);
            }
        }
        // Every seq up to the reflected one is delivered by that frame.
        let mut covered = seq0;
        for (s, at) in &seen.reflected {
            for k in covered + 1..=*s {
                if let Some(t) = sent.get(&k) {
                    t2d.push(at.saturating_duration_since(*t).as_secs_f64() * 1e3);
                }
            }
            covered = covered.max(*s);
        }
    }
    let versions = reference
        .arrivals
        .iter()
        .filter(|(_, at)| *at >= started)
        .count();
    println!(
        "| {viewers} | {failed} | {:.1} | {} | {} | {skipped} | {errors} | {} | {:.0} % |",
        versions as f64 / drive_time.as_secs_f64(),
        summary(hop),
        summary(t2d),
        frames,
        relay_cpu.as_secs_f64() / drive_time.as_secs_f64() * 100.0,
    );
    seq
}

/// One version of the synthetic solver, encoded.
struct Version {
    keyframe: bytes::Bytes,
    delta: bytes::Bytes,
    base: u64,
    version: u64,
}

/// The synthetic solver's shared state.
struct Synthetic {
    /// Newest (seq, pose) from a driver, not yet published.
    pending: Mutex<Option<(u64, Pose)>>,
    /// Newest version.
    versions: watch::Sender<Option<Arc<Version>>>,
    welcome: bytes::Bytes,
}

/// An image of cornell-low's atlas with a bright vertical band whose
/// position follows the pose's angle about y.
fn synthetic_image(width: u32, height: u32, pose: &Pose) -> Vec<[f32; 3]> {
    let angle = 2.0 * pose.rotation[1].atan2(pose.rotation[3]);
    let centre = (angle.rem_euclid(std::f32::consts::TAU) / std::f32::consts::TAU) * width as f32;
    let half = width as f32 / 10.0;
    (0..width * height)
        .map(|i| {
            let (x, y) = ((i % width) as f32, (i / width) as f32);
            let base = 0.5 + 0.4 * (x / width as f32) + 0.1 * (y / height as f32);
            let d = (x - centre).abs().min(width as f32 - (x - centre).abs());
            let glow = if d < half {
                4.0 * (1.0 - d / half)
            } else {
                0.0
            };
            [base + glow, base * 0.8 + glow, base * 0.6]
        })
        .collect()
}

/// Starts the synthetic solver; returns its address.
async fn synthetic_solver() -> String {
    use lightwire_scene::Scene;
    use lightwire_scene::atlas::Atlas;
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../scenes/cornell-low.json");
    let scene = Scene::load_with(&path, Default::default()).expect("scene");
    let atlas = Atlas::build(&scene).expect("atlas");
    let info = lightwire_server::service::wire::scene_info(&scene, &atlas);
    let (w, h) = (info.atlas_width, info.atlas_height);
    let mut encoder =
        lightwire_protocol::lightmap::Encoder::new(w, h, info.tile_size, info.format, 1.0 / 256.0);
    let welcome = bytes::Bytes::from(lightwire_protocol::encode_server(&ServerMessage::Welcome {
        protocol_version: PROTOCOL_VERSION,
        server: "relay-bench synthetic solver".into(),
        role: lightwire_protocol::Role::Driver,
        capabilities: 0,
        scene: info,
    }));
    let (versions, _) = watch::channel(None);
    let state = Arc::new(Synthetic {
        pending: Mutex::new(Some((0, pose(0.0)))),
        versions,
        welcome,
    });
    // Publisher: one version per new pose, at most every 1/60 s.
    let publisher = state.clone();
    tokio::spawn(async move {
        let mut tick = tokio::time::interval(Duration::from_secs_f64(1.0 / 60.0));
        loop {
            tick.tick().await;
            let Some((seq, p)) = publisher.pending.lock().expect("lock").take() else {
                continue;
            };
            let reflected = if seq > 0 {
                vec![lightwire_protocol::ObjectSeq { object: 1, seq }]
            } else {
                vec![]
            };
            let delta = encoder.publish(&synthetic_image(w, h, &p), reflected);
            let key =
                lightwire_protocol::encode_server(&ServerMessage::Keyframe(encoder.keyframe()));
            let (base, version) = (delta.base_version, delta.version);
            let delta = lightwire_protocol::encode_server(&ServerMessage::Delta(delta));
            publisher.versions.send_replace(Some(Arc::new(Version {
                keyframe: key.into(),
                delta: delta.into(),
                base,
                version,
            })));
        }
    });
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
        .await
        .expect("bind");
    let addr = listener.local_addr().expect("addr").to_string();
    tokio::spawn(async move {
        while let Ok((tcp, _)) = listener.accept().await {
            let _ = tcp.set_nodelay(true);
            let state = state.clone();
            tokio::spawn(async move {
                let Ok(ws) = tokio_tungstenite::accept_async(tcp).await else {
                    return;
                };
                serve_synthetic(ws, state).await;
            });
        }
    });
    addr
}

/// One connection to the synthetic solver: Welcome, then the newest
/// version as a delta onto what the peer holds, or a keyframe; poses from
/// drivers go to `pending`; Stats every 250 ms.
async fn serve_synthetic(
    ws: tokio_tungstenite::WebSocketStream<tokio::net::TcpStream>,
    state: Arc<Synthetic>,
) {
    let (mut sink, mut stream) = ws.split();
    // Hello first.
    if !matches!(stream.next().await, Some(Ok(Message::Binary(_)))) {
        return;
    }
    if sink
        .send(Message::Binary(state.welcome.clone()))
        .await
        .is_err()
    {
        return;
    }
    let mut versions = state.versions.subscribe();
    versions.mark_changed();
    let mut held: Option<u64> = None;
    let mut stats = tokio::time::interval(Duration::from_millis(250));
    loop {
        tokio::select! {
            frame = stream.next() => {
                let Some(Ok(frame)) = frame else { return };
                if let Message::Binary(bytes) = frame {
                    if let Ok(ClientMessage::Transform { seq, pose, .. }) =
                        lightwire_protocol::decode_client(&bytes)
                    {
                        *state.pending.lock().expect("lock") = Some((seq, pose));
                    }
                }
            }
            changed = versions.changed() => {
                if changed.is_err() { return; }
                let Some(v) = versions.borrow_and_update().clone() else { continue };
                let frame = if held == Some(v.base) { v.delta.clone() } else { v.keyframe.clone() };
                if sink.send(Message::Binary(frame)).await.is_err() { return; }
                held = Some(v.version);
            }
            _ = stats.tick() => {
                let s = lightwire_protocol::Stats {
                    version: held.unwrap_or(0),
                    unshot_fraction: 0.0,
                    tick_ms: 0.0,
                    solve_ms: 0.0,
                    redistribution_ms: 0.0,
                    clients: 1,
                    server_time_us: 0,
                };
                let frame = lightwire_protocol::encode_server(&ServerMessage::Stats(s));
                if sink.send(Message::Binary(frame.into())).await.is_err() { return; }
            }
        }
    }
}

fn main() {
    let args = parse_args();
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .expect("runtime");
    let scene = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../scenes/cornell-low.json");
    let tokens = format!("driver:{DRIVER},viewer:{VIEWER}");
    let scene = scene.display().to_string();
    // target/release/examples/relay_bench -> target/release/lightwire
    let lightwire = Lightwire::beside_current_exe();
    let (_solver, solver_addr) = if args.synthetic {
        (None, runtime.block_on(synthetic_solver()))
    } else {
        let solver = lightwire.spawn(
            &[
                "serve",
                "--listen",
                "127.0.0.1:0",
                "--solver",
                "reference",
                "--density-scale",
                &args.density,
                "--scene",
                &scene,
            ],
            &[("LIGHTWIRE_TOKENS", tokens.clone())],
        );
        let addr = solver.addr.clone();
        (Some(solver), addr)
    };
    let upstream = format!("ws://{solver_addr}/ws/scenes/cornell-low");
    let relay = lightwire.spawn(
        &["relay", "--listen", "127.0.0.1:0", "--upstream", &upstream],
        &[
            ("LIGHTWIRE_TOKENS", tokens),
            ("LIGHTWIRE_UPSTREAM_TOKEN", DRIVER.to_string()),
        ],
    );
    let relay_url = format!("ws://{}/ws/scenes/cornell-low", relay.addr);
    runtime.block_on(async {
        // Wait until the relay has a version.
        let deadline = Instant::now() + Duration::from_secs(60);
        loop {
            if let Some(ws) = hello(&relay_url, VIEWER).await {
                let (tx, rx) = watch::channel(false);
                let probe = tokio::spawn(view(ws, rx, false));
                tokio::time::sleep(Duration::from_millis(500)).await;
                let _ = tx.send(true);
                if !probe.await.expect("probe").arrivals.is_empty() {
                    break;
                }
            }
            assert!(Instant::now() < deadline, "the relay never served a version");
            tokio::time::sleep(Duration::from_millis(200)).await;
        }
        println!(
            "upstream: {}; viewers {}; {} Hz poses for {:?} per row; latencies in ms as p50 / p95 / p99 / max",
            if args.synthetic { "synthetic (one version per pose)".to_string() } else { format!("reference solver, density x{}", args.density) },
            if args.light { "check versions only (--light-viewers)" } else { "apply every frame" },
            args.rate,
            args.duration
        );
        println!(
            "| viewers | connect errors | versions/s | relay delivery (vs direct viewer of the solver) | transform-to-delivery | versions skipped | errors | frames | relay CPU (of one core) |"
        );
        println!("| --- | --- | --- | --- | --- | --- | --- | --- | --- |");
        let mut seq = 0;
        for &n in &args.viewers {
            seq = round(&relay_url, relay.child.id(), &upstream, n, &args, seq).await;
        }
    });
}
