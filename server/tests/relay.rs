//! `lightwire relay` as real processes over real sockets: a solver, two
//! relays and 500 viewers on loopback.
//!
//! The contract under test (issue "Deploy and scale out"):
//!
//! - killing one relay, its viewers reconnect to the other within
//!   [`FAILOVER_BOUND`] and end bit-exact with the solver's version;
//! - restarting the solver, the relays keep serving the last version
//!   (readiness stays 200, a late joiner gets it as a keyframe, no viewer
//!   is disconnected) and resync within [`RESYNC_BOUND`] of the new
//!   solver's first version, bit-exact, with relay versions that only
//!   increase although the new solver counts from 1 again;
//! - no viewer ever receives a delta whose base is not the version it
//!   holds (every viewer applies every frame to a validating `Lightmap`
//!   and counts refusals);
//! - drivers' transforms go through a relay to the solver, and the relay
//!   checks roles (a viewer's transform is refused at the relay).
//!
//! The viewers are lightweight tokio tasks speaking the protocol directly.
//! The bounds are generous on purpose (CI shares 2 cores with builds); the
//! measured times are printed.

use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use futures_util::{SinkExt, StreamExt};
use lightwire_protocol::lightmap::{ApplyError, Lightmap};
use lightwire_protocol::{
    ClientMessage, ErrorCode, Pose, ServerMessage, decode_server, encode_client,
};
use tokio_tungstenite::tungstenite::Message;

use lightwire_testkit::fake::FakeServer;
use lightwire_testkit::peer::{Peer, hello};
use lightwire_testkit::pose::{assert_same_pose, box_turned, transform};
use lightwire_testkit::process::Proc;
use lightwire_testkit::{
    DRIVER_TOKEN, SCENE, VIEWER_TOKEN, dashboard, http, lightwire, scene_file, viewer_routes,
};

const VIEWERS: usize = 500;
/// Killing a relay: every one of its viewers is connected to the other
/// relay and holds its current version within this.
const FAILOVER_BOUND: Duration = Duration::from_secs(20);
/// Restarting the solver: every viewer holds the new solver's state within
/// this after the new solver published its first version.
const RESYNC_BOUND: Duration = Duration::from_secs(20);

/// The relay's view of its scene (from `/api/scenes`).
async fn relay_status(addr: &str) -> serde_json::Value {
    let list = http::get(addr, "/api/scenes", Some(VIEWER_TOKEN)).await;
    assert_eq!(list.status, 200);
    list.json()[0].clone()
}

/// A viewer that has just joined `url`, holding the keyframe it was sent.
async fn joined(url: &str) -> Peer {
    let mut viewer = Peer::connect(url, VIEWER_TOKEN).await;
    viewer
        .read_until(Duration::from_secs(10), "the first keyframe", |v| {
            v.keyframes > 0
        })
        .await;
    viewer
}

/// The state a protocol client holds right after joining `url`: its
/// version, its texels and the seq of object 1 it reflects.
async fn joined_state(url: &str) -> (u64, Vec<u8>, Option<u64>) {
    let viewer = joined(url).await;
    let seq = viewer.reflected.get(&1).copied();
    (viewer.version(), viewer.texels().to_vec(), seq)
}

/// How long the solver's state must stay put to count as settled: longer
/// than `lightwire serve`'s `settle_ms` (500 ms by default; after that much
/// idle time it publishes its unchanged lightmap once more, as a new
/// version, to send the texels still waiting within the encoder's error
/// budget) plus a tick or two on a loaded machine. A shorter wait could
/// return the version before that flush, which the viewers then leave.
const QUIET: Duration = Duration::from_millis(1500);

/// Waits until the solver's state reflects `seq` of the box and stays put
/// for [`QUIET`]; returns it.
async fn settled(solver: &Proc, seq: Option<u64>) -> (u64, Vec<u8>) {
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let (version, texels, reflected) = joined_state(&solver.ws_url()).await;
        if reflected == seq {
            tokio::time::sleep(QUIET).await;
            let (again, _, _) = joined_state(&solver.ws_url()).await;
            if again == version {
                return (version, texels);
            }
        }
        assert!(
            Instant::now() < deadline,
            "the solver never settled on seq {seq:?}"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

/// What a viewer task reports, live.
#[derive(Default)]
struct ViewerState {
    /// Index of the relay it is connected to, or `usize::MAX`.
    relay: AtomicUsize,
    /// Connections opened (1 = never reconnected).
    connections: AtomicU32,
    /// The version it holds (0: none).
    version: AtomicU64,
    /// Its texels at that version.
    texels: Mutex<Vec<u8>>,
    /// Deltas that did not apply onto the held version. Must stay 0.
    wrong_base: AtomicU32,
    /// Frames on one connection whose version did not increase. Must stay 0.
    not_increasing: AtomicU32,
    /// Tile or frame errors other than a wrong base. Must stay 0.
    other_errors: AtomicU32,
}

/// A viewer: connects to `relays[first]`, and on any loss to the next
/// relay in turn, applying every frame to a validating `Lightmap`.
async fn viewer(
    relays: Arc<Vec<String>>,
    first: usize,
    state: Arc<ViewerState>,
    stop: Arc<AtomicBool>,
) {
    let mut index = first;
    let mut delay = Duration::from_millis(20);
    state.relay.store(usize::MAX, Ordering::Relaxed);
    while !stop.load(Ordering::Relaxed) {
        let Some(mut ws) = hello(&relays[index], VIEWER_TOKEN).await else {
            index = (index + 1) % relays.len();
            tokio::time::sleep(delay).await;
            delay = (delay * 2).min(Duration::from_millis(500));
            continue;
        };
        state.connections.fetch_add(1, Ordering::Relaxed);
        state.relay.store(index, Ordering::Relaxed);
        let mut map: Option<Lightmap> = None;
        let mut last_on_connection = 0u64;
        while !stop.load(Ordering::Relaxed) {
            let frame = match tokio::time::timeout(Duration::from_secs(2), ws.next()).await {
                Ok(Some(Ok(Message::Binary(bytes)))) => bytes,
                Ok(Some(Ok(Message::Close(_)))) | Ok(None) | Ok(Some(Err(_))) => break,
                Ok(Some(Ok(_))) | Err(_) => continue,
            };
            let Ok(message) = decode_server(&frame) else {
                state.other_errors.fetch_add(1, Ordering::Relaxed);
                continue;
            };
            let version = match message {
                ServerMessage::Welcome { scene, .. } => {
                    map = Lightmap::for_scene(&scene).ok();
                    continue;
                }
                ServerMessage::Keyframe(k) => {
                    let Some(map) = map.as_mut() else { continue };
                    if map.apply_keyframe(&k).is_err() {
                        state.other_errors.fetch_add(1, Ordering::Relaxed);
                        continue;
                    }
                    k.version
                }
                ServerMessage::Delta(d) => {
                    let Some(map) = map.as_mut() else { continue };
                    match map.apply_delta(&d) {
                        Ok(()) => d.version,
                        Err(ApplyError::WrongBase { .. }) => {
                            state.wrong_base.fetch_add(1, Ordering::Relaxed);
                            let resync = ClientMessage::Resync {
                                have_version: Some(map.version),
                            };
                            let _ = ws
                                .send(Message::Binary(encode_client(&resync).into()))
                                .await;
                            continue;
                        }
                        Err(_) => {
                            state.other_errors.fetch_add(1, Ordering::Relaxed);
                            continue;
                        }
                    }
                }
                _ => continue,
            };
            if version <= last_on_connection {
                state.not_increasing.fetch_add(1, Ordering::Relaxed);
            }
            last_on_connection = version;
            if let Some(map) = map.as_ref() {
                *state.texels.lock().expect("lock") = map.texels.clone();
            }
            state.version.store(version, Ordering::Relaxed);
        }
        state.relay.store(usize::MAX, Ordering::Relaxed);
        index = (index + 1) % relays.len();
        delay = Duration::from_millis(20);
    }
}

/// Waits until every viewer satisfies `ok`, at most `bound` after
/// `started`; returns the time since `started`.
async fn all_viewers(
    viewers: &[Arc<ViewerState>],
    started: Instant,
    bound: Duration,
    what: &str,
    ok: impl Fn(&ViewerState) -> bool,
) -> Duration {
    loop {
        let pending = viewers.iter().filter(|v| !ok(v)).count();
        if pending == 0 {
            return started.elapsed();
        }
        assert!(
            started.elapsed() < bound,
            "{what}: {pending} of {} viewers still not there after {bound:?}; they hold {}",
            viewers.len(),
            census(viewers)
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

/// Waits, at most 30 s, until every viewer holds `version` with `texels`.
async fn all_viewers_hold(viewers: &[Arc<ViewerState>], version: u64, texels: &[u8], what: &str) {
    let bound = Duration::from_secs(30);
    all_viewers(viewers, Instant::now(), bound, what, |v| {
        holds(v, version, texels)
    })
    .await;
}

/// What the viewers hold, for a failure message: how many are on which
/// relay at which version, after how many connections.
fn census(viewers: &[Arc<ViewerState>]) -> String {
    let mut counts = std::collections::BTreeMap::new();
    for v in viewers {
        let relay = match v.relay.load(Ordering::Relaxed) {
            usize::MAX => "none".to_string(),
            r => r.to_string(),
        };
        let key = (
            relay,
            v.version.load(Ordering::Relaxed),
            v.connections.load(Ordering::Relaxed),
        );
        *counts.entry(key).or_insert(0usize) += 1;
    }
    counts
        .iter()
        .map(|((relay, version, connections), n)| {
            format!("{n} on relay {relay} at version {version} after {connections} connection(s)")
        })
        .collect::<Vec<_>>()
        .join(", ")
}

fn holds(v: &ViewerState, version: u64, texels: &[u8]) -> bool {
    v.version.load(Ordering::Relaxed) == version && *v.texels.lock().expect("lock") == texels
}

fn pose_at(step: u32) -> Pose {
    box_turned(step as f32 * 0.3)
}

/// A driver on `url` sends seq `step` and reads the answers for a moment;
/// returns the error codes it got.
async fn drive(url: &str, token: &str, step: u32) -> Vec<ErrorCode> {
    let mut ws = hello(url, token).await.expect("connects");
    let transform = transform(1, u64::from(step), pose_at(step));
    ws.send(Message::Binary(encode_client(&transform).into()))
        .await
        .expect("send");
    let mut errors = Vec::new();
    let until = Instant::now() + Duration::from_millis(600);
    while let Ok(Some(Ok(frame))) = tokio::time::timeout_at(until.into(), ws.next()).await {
        if let Message::Binary(bytes) = frame {
            if let Ok(ServerMessage::Error { code, .. }) = decode_server(&bytes) {
                errors.push(code);
            }
        }
    }
    errors
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn five_hundred_viewers_survive_a_relay_kill_and_a_solver_restart_bit_exactly() {
    let test_started = Instant::now();
    let mut solver = lightwire!().solver("127.0.0.1:0");
    let solver_addr = solver.addr.clone();
    solver.ready().await;
    let relay_a = lightwire!().relay(&solver_addr);
    let relay_b = lightwire!().relay(&solver_addr);
    relay_a.ready().await;
    relay_b.ready().await;
    let relays = Arc::new(vec![relay_a.ws_url(), relay_b.ws_url()]);

    // 500 viewers, alternating between the relays.
    let stop = Arc::new(AtomicBool::new(false));
    let spawned = Instant::now();
    let viewers: Vec<Arc<ViewerState>> = (0..VIEWERS)
        .map(|_| Arc::new(ViewerState::default()))
        .collect();
    let tasks: Vec<_> = viewers
        .iter()
        .enumerate()
        .map(|(i, v)| tokio::spawn(viewer(relays.clone(), i % 2, v.clone(), stop.clone())))
        .collect();
    let (v0, texels0) = settled(&solver, None).await;
    let joined = all_viewers(&viewers, spawned, Duration::from_secs(60), "joining", |v| {
        holds(v, v0, &texels0)
    })
    .await;
    eprintln!(
        "{VIEWERS} viewers joined through 2 relays and hold the solver's version {v0} within {joined:?}"
    );

    // Roles are checked at the relay; a driver's moves reach the solver.
    assert_eq!(
        drive(&relays[1], VIEWER_TOKEN, 1).await,
        vec![ErrorCode::Forbidden],
        "a viewer may not move objects through a relay"
    );
    for step in 1..=3 {
        assert_eq!(drive(&relays[1], DRIVER_TOKEN, step).await, vec![]);
    }
    let (v1, texels1) = settled(&solver, Some(3)).await;
    assert!(v1 > v0 && texels1 != texels0, "the move changed the light");
    all_viewers_hold(&viewers, v1, &texels1, "after the move").await;

    // Kill relay A: its viewers move to relay B.
    let on_a = viewers
        .iter()
        .filter(|v| v.relay.load(Ordering::Relaxed) == 0)
        .count();
    assert_eq!(on_a, VIEWERS / 2);
    let killed = Instant::now();
    drop(relay_a);
    let failover = all_viewers(&viewers, killed, FAILOVER_BOUND, "failover", |v| {
        v.relay.load(Ordering::Relaxed) == 1 && holds(v, v1, &texels1)
    })
    .await;
    eprintln!(
        "relay A killed: its {on_a} viewers reconnected to relay B and hold version {v1} within {failover:?}"
    );
    // And they follow the next move, bit-exact with the solver.
    assert_eq!(drive(&relays[1], DRIVER_TOKEN, 4).await, vec![]);
    let (v2, texels2) = settled(&solver, Some(4)).await;
    all_viewers_hold(&viewers, v2, &texels2, "after failover").await;
    let connections_before: Vec<u32> = viewers
        .iter()
        .map(|v| v.connections.load(Ordering::Relaxed))
        .collect();

    // Restart the solver. While it is gone, the relay serves the last
    // version: it stays ready and a late joiner gets that version.
    drop(solver);
    let down = Instant::now();
    let deadline = Instant::now() + Duration::from_secs(15);
    while relay_status(&relay_b.addr).await["connected"] != false {
        assert!(Instant::now() < deadline, "the relay never noticed");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    assert_eq!(
        http::get(&relay_b.addr, "/readyz", Some(VIEWER_TOKEN))
            .await
            .status,
        200,
        "a relay without its upstream still serves the last version"
    );
    let (late_version, late_texels, _) = joined_state(&relays[1]).await;
    assert_eq!(late_version, v2, "a late joiner gets the last version");
    assert!(late_texels == texels2, "... bit-exact");
    tokio::time::sleep(Duration::from_millis(500)).await;
    solver = lightwire!().solver(&solver_addr);
    solver.ready().await;
    let restarted = Instant::now();
    // The new run starts from the scene's initial pose and version 1; its
    // first version is its state until something moves.
    let (v3, texels3, _) = joined_state(&solver.ws_url()).await;
    assert!(
        texels3 != texels2,
        "the restarted solver lights the box elsewhere"
    );
    assert!(
        v3 < v2,
        "the new run counts again from 1 (got {v3} after {v2})"
    );
    let resync = all_viewers(&viewers, restarted, RESYNC_BOUND, "resync", |v| {
        v.version.load(Ordering::Relaxed) > v2 && *v.texels.lock().expect("lock") == texels3
    })
    .await;
    assert_eq!(
        settled(&solver, None).await,
        (v3, texels3),
        "no newer version"
    );
    eprintln!(
        "solver restarted ({:?} down): every viewer resynced to the new run's state within {resync:?} of the solver being ready",
        restarted - down
    );
    let status = relay_status(&relay_b.addr).await;
    assert_eq!(status["connected"], true);
    assert_eq!(status["upstream_version"].as_u64(), Some(v3));
    let relay_version = status["version"].as_u64().expect("version");
    assert!(relay_version > v2, "relay versions never go back");
    assert!(
        viewers
            .iter()
            .all(|v| v.version.load(Ordering::Relaxed) == relay_version),
        "every viewer holds the relay's version {relay_version}"
    );
    let reconnected = viewers
        .iter()
        .zip(&connections_before)
        .filter(|(v, before)| v.connections.load(Ordering::Relaxed) != **before)
        .count();
    assert_eq!(
        reconnected, 0,
        "viewers stay connected to the relay while the solver restarts"
    );

    stop.store(true, Ordering::Relaxed);
    for t in tasks {
        let _ = t.await;
    }
    let sum = |f: fn(&ViewerState) -> u32| viewers.iter().map(|v| f(v)).sum::<u32>();
    assert_eq!(
        sum(|v| v.wrong_base.load(Ordering::Relaxed)),
        0,
        "no viewer was ever sent a delta onto a version it did not hold"
    );
    assert_eq!(sum(|v| v.not_increasing.load(Ordering::Relaxed)), 0);
    assert_eq!(sum(|v| v.other_errors.load(Ordering::Relaxed)), 0);
    eprintln!("wall time {:?}", test_started.elapsed());
}

/// A scripted upstream for the relay: the test plays the solver.
mod fake {
    use super::*;
    use lightwire_protocol::lightmap::Encoder;
    use lightwire_protocol::{ObjectInfo, PixelFormat, Role, SceneInfo};
    use lightwire_testkit::fake::{Conn, welcome};
    pub use lightwire_testkit::fake::{delta, keyframe, raw, recv};

    pub fn scene() -> SceneInfo {
        let pose = Pose {
            translation: [0.0; 3],
            rotation: [0.0, 0.0, 0.0, 1.0],
            scale: 1.0,
        };
        SceneInfo {
            id: SCENE.into(),
            atlas_width: 16,
            atlas_height: 8,
            tile_size: 8,
            format: PixelFormat::Rgb9e5,
            objects: vec![
                ObjectInfo {
                    name: "room".into(),
                    dynamic: false,
                    pose,
                },
                ObjectInfo {
                    name: "box".into(),
                    dynamic: true,
                    pose,
                },
            ],
            materials: vec![],
            surfaces: vec![],
            lights: Vec::new(),
        }
    }

    pub fn encoder() -> Encoder {
        Encoder::new(16, 8, 8, PixelFormat::Rgb9e5, 0.0)
    }

    /// An image whose two tiles have brightness `a` and `b`.
    pub fn image(a: f32, b: f32) -> Vec<[f32; 3]> {
        (0..16 * 8)
            .map(|i| [if i % 16 < 8 { a } else { b }, 0.5, 0.25])
            .collect()
    }

    /// Accepts the relay's next connection, checks its Hello and answers
    /// with a Welcome granting `role`.
    pub async fn accept(listener: &FakeServer, role: Role) -> Conn {
        let (mut peer, token) = listener.accept().await;
        assert_eq!(token.as_deref(), Some(DRIVER_TOKEN), "upstream token");
        lightwire_testkit::fake::send(&mut peer, &welcome(role, scene())).await;
        peer
    }
}

/// A viewer of the relay that keeps reading on a task and reports what it
/// holds.
fn watch_relay(url: String) -> (Arc<ViewerState>, Arc<AtomicBool>) {
    let state = Arc::new(ViewerState::default());
    let stop = Arc::new(AtomicBool::new(false));
    tokio::spawn(viewer(Arc::new(vec![url]), 0, state.clone(), stop.clone()));
    (state, stop)
}

async fn until(what: &str, ok: impl Fn() -> bool) {
    let deadline = Instant::now() + Duration::from_secs(20);
    while !ok() {
        assert!(Instant::now() < deadline, "timed out: {what}");
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_upstream_frames_are_refused_resynced_and_never_reach_viewers() {
    use lightwire_protocol::Role;
    let listener = FakeServer::bind().await;
    let upstream = listener.addr();
    let relay = lightwire!().relay(&upstream);
    let mut solver = fake::encoder();

    // Connection 1: a driver role, keyframe v1.
    let mut peer = fake::accept(&listener, Role::Driver).await;
    let _ = solver.publish(&fake::image(1.0, 1.0), vec![]);
    fake::keyframe(&mut peer, solver.keyframe()).await;
    let (viewer, stop) = watch_relay(relay.ws_url());
    let state_v1 = solver.state().texels.clone();
    until("the viewer holds v1", || holds(&viewer, 1, &state_v1)).await;

    // Garbage, a text frame, and a delta whose payload is not zstd: refused,
    // and the relay asks for a resync.
    fake::raw(&mut peer, Message::Binary(vec![0xff, 0x00, 0x13].into())).await;
    fake::raw(&mut peer, Message::Text("hello?".into())).await;
    let mut corrupt = solver.publish(&fake::image(2.0, 1.0), vec![]);
    corrupt.residual = vec![0xde, 0xad, 0xbe, 0xef];
    fake::delta(&mut peer, corrupt).await;
    assert!(matches!(
        fake::recv(&mut peer).await,
        ClientMessage::Resync { .. }
    ));
    // Nothing reached the viewer.
    tokio::time::sleep(Duration::from_millis(300)).await;
    assert!(holds(&viewer, 1, &state_v1), "the viewer keeps v1");

    // The keyframe that answers the resync (upstream v2) reaches viewers
    // as relay version 2.
    fake::keyframe(&mut peer, solver.keyframe()).await;
    let state_v2 = solver.state().texels.clone();
    until("the viewer holds v2", || holds(&viewer, 2, &state_v2)).await;

    // A delta onto a version the relay does not hold: resync again; the
    // keyframe that follows is unchanged, so nothing is published; the
    // next delta continues the relay's numbering.
    let mut wrong = solver.publish(&fake::image(3.0, 1.0), vec![]);
    wrong.base_version += 5;
    wrong.version += 5;
    fake::delta(&mut peer, wrong).await;
    assert!(matches!(
        fake::recv(&mut peer).await,
        ClientMessage::Resync { .. }
    ));
    // Upstream v3 is the state after `wrong`'s real tiles; the relay's
    // viewers hold v2's state, so this keyframe is a change: relay v3.
    fake::keyframe(&mut peer, solver.keyframe()).await;
    let state_v3 = solver.state().texels.clone();
    until("the viewer holds v3", || holds(&viewer, 3, &state_v3)).await;
    // The same keyframe again (a reconnect-like resync): no new version.
    fake::keyframe(&mut peer, solver.keyframe()).await;
    let d = solver.publish(&fake::image(4.0, 1.0), vec![]);
    fake::delta(&mut peer, d).await;
    let state_v4 = solver.state().texels.clone();
    until("the viewer holds v4", || holds(&viewer, 4, &state_v4)).await;

    // Transforms from the relay's drivers are forwarded (the relay's
    // upstream role is Driver).
    assert_eq!(drive(&relay.ws_url(), DRIVER_TOKEN, 7).await, vec![]);
    loop {
        match fake::recv(&mut peer).await {
            ClientMessage::Transform { object, seq, .. } => {
                assert_eq!((object, seq), (1, 7));
                break;
            }
            ClientMessage::Resync { .. } | ClientMessage::Ping { .. } => {}
            other => panic!("unexpected {other:?}"),
        }
    }

    // Too many bad frames: the relay drops the connection and reconnects;
    // the viewer is not disturbed.
    for _ in 0..12 {
        fake::raw(&mut peer, Message::Binary(vec![0xee; 5].into())).await;
    }
    let mut peer = fake::accept(&listener, Role::Driver).await;
    fake::keyframe(&mut peer, solver.keyframe()).await;
    tokio::time::sleep(Duration::from_millis(300)).await;
    assert!(holds(&viewer, 4, &state_v4), "same state: still v4");

    // An upstream that goes silent without closing is dropped after
    // SILENCE (5 s), even while drivers keep the relay sending to it.
    let silent = Instant::now();
    let relay_url = relay.ws_url();
    let driving = tokio::spawn(async move {
        let mut ws = hello(&relay_url, DRIVER_TOKEN).await.expect("driver");
        for seq in 100..200u64 {
            let t = transform(1, seq, pose_at(seq as u32));
            if ws
                .send(Message::Binary(encode_client(&t).into()))
                .await
                .is_err()
            {
                break;
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    });
    let mut peer = fake::accept(&listener, Role::Viewer).await;
    let waited = silent.elapsed();
    driving.abort();
    assert!(
        waited >= Duration::from_secs(2) && waited < Duration::from_secs(15),
        "a silent upstream is dropped after about 5 s, not {waited:?}"
    );
    eprintln!("silent upstream replaced after {waited:?}");
    fake::keyframe(&mut peer, solver.keyframe()).await;
    tokio::time::sleep(Duration::from_millis(300)).await;
    assert!(holds(&viewer, 4, &state_v4), "same state: still v4");
    assert_eq!(viewer.connections.load(Ordering::Relaxed), 1);
    // With a viewer role upstream, the relay refuses transforms itself.
    assert_eq!(
        drive(&relay.ws_url(), DRIVER_TOKEN, 8).await,
        vec![ErrorCode::Forbidden]
    );

    stop.store(true, Ordering::Relaxed);
    assert_eq!(viewer.wrong_base.load(Ordering::Relaxed), 0);
    assert_eq!(viewer.other_errors.load(Ordering::Relaxed), 0);
    assert_eq!(viewer.not_increasing.load(Ordering::Relaxed), 0);
    let status = relay_status(&relay.addr).await;
    assert_eq!(status["connects"], 3, "{status}");
    assert_eq!(status["upstream_version"].as_u64(), Some(4));
}

/// A solver and a relay of it, both ready (the relay holds a version).
async fn ready_solver_and_relay() -> (Proc, Proc) {
    let solver = lightwire!().solver("127.0.0.1:0");
    solver.ready().await;
    let relay = lightwire!().relay(&solver.addr);
    relay.ready().await;
    (solver, relay)
}

/// A viewer on a relay needs nothing from the solver: the relay serves the
/// scene info, snapshots and `scene.glb` of the version it holds and the dashboard, with
/// the solver's token and Origin rules (PROTOCOL.md §7, Relays and REST);
/// the scene's lights, which the description does not carry, are the
/// solver's to list (a clear 404).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_relay_serves_scene_info_snapshots_and_the_dashboard() {
    let (solver, relay) = ready_solver_and_relay().await;
    // Nothing moves, so once settled the state stays put.
    let _ = settled(&solver, None).await;
    let viewer = joined(&relay.ws_url()).await;
    let (version, rgb) = (viewer.version(), viewer.map.expect("welcomed").to_rgb());
    let addr = relay.addr.as_str();

    // Scene info: the solver's description, byte for byte.
    let info_path = format!("/api/scenes/{SCENE}");
    let from_relay = http::get(addr, &info_path, Some(VIEWER_TOKEN)).await;
    assert_eq!(from_relay.status, 200, "{}", from_relay.text());
    let from_solver = http::get(&solver.addr, &info_path, Some(VIEWER_TOKEN)).await;
    assert_eq!(from_relay.json(), from_solver.json());

    // Snapshots of the version the relay's viewer holds.
    let exr = http::get(addr, &scene_file("lightmap.exr"), Some(VIEWER_TOKEN)).await;
    assert_eq!(exr.status, 200, "{}", exr.text());
    assert_eq!(exr.header("content-type"), Some("image/x-exr"));
    assert_eq!(
        exr.version(),
        Some(version),
        "the snapshot is the version a WebSocket client of the relay holds"
    );
    let image = exr.exr();
    let pixels: Vec<[f32; 3]> = image.pixels().map(|p| p.0).collect();
    assert!(
        pixels == rgb,
        "the EXR is bit-exact with the viewer's lightmap"
    );
    let png = http::get(
        addr,
        &scene_file(&format!("lightmap.png?token={VIEWER_TOKEN}")),
        None,
    )
    .await;
    assert_eq!(png.status, 200, "{}", png.text());
    assert_eq!(png.header("content-type"), Some("image/png"));
    assert_eq!(png.version(), Some(version));
    let decoded =
        image::load_from_memory_with_format(&png.body, image::ImageFormat::Png).expect("valid PNG");
    assert_eq!(
        (decoded.width(), decoded.height()),
        (image.width(), image.height())
    );

    // The lit scene: exactly the export of the description and the
    // version the relay holds.
    let glb = http::get(addr, &scene_file("scene.glb"), Some(VIEWER_TOKEN)).await;
    assert_eq!(glb.status, 200, "{}", glb.text());
    assert_eq!(glb.header("content-type"), Some("model/gltf-binary"));
    assert_eq!(glb.version(), Some(version));
    let info: lightwire_protocol::SceneInfo =
        serde_json::from_value(from_relay.json()).expect("a SceneInfo");
    let expected =
        lightwire_server::bake::scene_glb(&info, &rgb, Some(version)).expect("scene.glb");
    assert!(
        glb.body == expected,
        "the relay's scene.glb is the export of the version it holds"
    );

    // The list says which scenes, for the dashboard's picker.
    let list = http::get(addr, "/api/scenes", Some(VIEWER_TOKEN))
        .await
        .json();
    assert_eq!(list[0]["id"], SCENE);
    assert_eq!(list[0]["version"].as_u64(), Some(version));
    assert_eq!(list[0]["connected"], true);

    // The same rules as the solver's, with the relay's own tokens.
    for route in viewer_routes() {
        let none = http::get(addr, &route, None).await;
        assert_eq!(none.status, 401, "{route} on the relay without a token");
        assert!(none.json()["error"].is_string());
        let foreign =
            http::get_from(addr, &route, Some(VIEWER_TOKEN), "https://evil.example").await;
        assert_eq!(foreign.status, 403, "{route} from a foreign origin");
    }
    let unknown = http::get(addr, "/api/scenes/nope", Some(VIEWER_TOKEN)).await;
    assert_eq!(unknown.status, 404);
    let lights = http::get(addr, &scene_file("lights"), Some(VIEWER_TOKEN)).await;
    assert_eq!(lights.status, 404, "{}", lights.text());
    let error = lights.json()["error"]
        .as_str()
        .unwrap_or_default()
        .to_string();
    assert!(error.contains("relay"), "{error:?}");

    // The dashboard.
    dashboard::assert_served(addr).await;
    // Metrics are open by default on the relay too.
    assert_eq!(http::get(addr, "/metrics", None).await.status, 200);
}

/// PROTOCOL.md §3, `Poses`, through a relay: it asks its upstream for the
/// poses and passes them on with its own versions to the viewers that ask,
/// never to those that do not (the kit's `Peer` panics on one it did not
/// ask for).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_relay_passes_the_poses_on_to_viewers_that_ask() {
    let (_solver, relay) = ready_solver_and_relay().await;
    let url = relay.ws_url();
    let mut viewer = Peer::connect_asking_poses(&url, VIEWER_TOKEN).await;
    let mut old = Peer::connect(&url, VIEWER_TOKEN).await;
    let mut driver = Peer::connect(&url, DRIVER_TOKEN).await;
    driver.transform(1, 7, pose_at(2)).await;
    viewer
        .read_until(
            Duration::from_secs(120),
            "seq 7 at the relay's viewer",
            |v| v.reflected.get(&1) == Some(&7),
        )
        .await;
    let (version, poses) = viewer
        .poses
        .last()
        .cloned()
        .expect("Poses through the relay");
    assert_eq!(version, viewer.version(), "the relay's own version");
    assert_eq!((poses[0].object, poses[0].seq), (1, 7), "{poses:?}");
    assert_same_pose(&poses[0].pose, &pose_at(2));
    old.read_until_version(viewer.version(), Duration::from_secs(60))
        .await;
    assert_eq!(old.texels(), viewer.texels());
    assert!(driver.errors.is_empty(), "{:?}", driver.errors);
}
