//! The client library against a scripted fake server (in-process, real
//! sockets): each test plays the server's side of PROTOCOL.md frame by
//! frame and checks what the client does — resync on a delta that does
//! not fit, nothing applied from a corrupt frame, reconnect with backoff,
//! permanent refusals, the pose outbox and transform-to-light latency,
//! and lights: `HELLO_LIGHTS` when asked, `Lights` onto frames, `SetLight`
//! seqs newer than any seen, refusals that name the scene's lights.

use std::sync::Arc;
use std::time::{Duration, Instant};

use futures_util::SinkExt;
use lightwire_client::{Client, ClientError, ErrorCode, Event, Frame, Options, Pose, Role};
use lightwire_protocol::lightmap::Encoder;
use lightwire_protocol::{
    CAP_LIGHTS, CAP_POSES, ClientMessage, HELLO_LIGHTS, HELLO_POSES, LightInfo, LightState,
    LightStatus, LightType, MaterialInfo, ObjectInfo, ObjectSeq, PROTOCOL_VERSION, PixelFormat,
    SceneInfo, ServerMessage, SurfaceInfo,
};
use lightwire_testkit::fake::{Conn, FakeServer, delta, keyframe, recv, send, welcome};
use tokio_tungstenite::tungstenite::Message;

const WAIT: Duration = Duration::from_secs(10);

fn scene() -> SceneInfo {
    SceneInfo {
        id: "fake".into(),
        atlas_width: 10,
        atlas_height: 9,
        tile_size: 4,
        format: PixelFormat::Rgb9e5,
        objects: vec![
            ObjectInfo {
                name: "room".into(),
                dynamic: false,
                pose: Pose::IDENTITY,
            },
            ObjectInfo {
                name: "box".into(),
                dynamic: true,
                pose: Pose::IDENTITY,
            },
        ],
        materials: vec![MaterialInfo {
            name: "white".into(),
            albedo: [0.5; 3],
            emission: [0.0; 3],
        }],
        surfaces: vec![SurfaceInfo {
            name: "floor".into(),
            object: 0,
            material: 0,
            corners: [
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [1.0, 0.0, 1.0],
                [0.0, 0.0, 1.0],
            ],
            rect: [0, 0, 10, 9],
            uvs: Vec::new(),
        }],
        lights: Vec::new(),
    }
}

fn image(value: f32) -> Vec<[f32; 3]> {
    (0..90)
        .map(|i| [value + i as f32 * 0.01, value, 0.5])
        .collect()
}

fn encoder() -> Encoder {
    Encoder::new(10, 9, 4, PixelFormat::Rgb9e5, 0.0)
}

/// A client of `fake` presenting `token`, welcomed as `role` on
/// [`scene`], and the fake server's side of its connection.
async fn connected(fake: &FakeServer, token: Option<&str>, role: Role) -> (Client, Conn) {
    let url = fake.ws_url("fake");
    let (client, ws) = tokio::join!(
        Client::connect(&url, token, None),
        fake.welcome(role, scene())
    );
    (client.expect("connects"), ws)
}

/// [`connected`], then holding version 1 ([`image`] of 1.0, a keyframe
/// of the returned encoder).
async fn at_version_1(
    fake: &FakeServer,
    token: Option<&str>,
    role: Role,
) -> (Client, Conn, Encoder) {
    let (client, mut ws) = connected(fake, token, role).await;
    let mut enc = encoder();
    enc.publish(&image(1.0), vec![]);
    keyframe(&mut ws, enc.keyframe()).await;
    front_is(&client, 1, &enc).await;
    (client, ws, enc)
}

/// Waits for the client's front to reach `version`, and checks that it is
/// that version with the texels `enc` published, bit for bit.
async fn front_is(client: &Client, version: u64, enc: &Encoder) -> Arc<Frame> {
    let front = client
        .wait_for_version(version, WAIT)
        .await
        .unwrap_or_else(|e| panic!("version {version}: {e}"));
    assert_eq!(front.version(), version);
    assert_eq!(
        front.lightmap.texels,
        enc.state().texels,
        "version {version} is bit-exact"
    );
    front
}

/// Waits for the first event matching `pick`.
async fn until<T>(client: &mut Client, mut pick: impl FnMut(&Event) -> Option<T>) -> T {
    let deadline = Instant::now() + WAIT;
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        let event = tokio::time::timeout(left, client.next_event())
            .await
            .expect("the event in time")
            .expect("the client still runs");
        if let Some(t) = pick(&event) {
            return t;
        }
    }
}

#[tokio::test]
async fn deltas_apply_only_onto_their_base_and_bad_frames_change_nothing() {
    let fake = FakeServer::bind().await;
    let (mut client, mut ws) = connected(&fake, None, Role::Viewer).await;
    assert_eq!(client.scene().id, "fake");
    assert_eq!(client.role(), Role::Viewer);

    let mut enc = encoder();
    enc.publish(&image(1.0), vec![]);
    let k1 = enc.keyframe();
    keyframe(&mut ws, k1.clone()).await;
    let v1 = front_is(&client, 1, &enc).await;

    // Garbage: reported with the frame's place, ignored; still version 1.
    ws.send(Message::Binary(vec![0x02, 0xff, 0xff].into()))
        .await
        .expect("send");
    let decode = until(&mut client, |e| match e {
        Event::Error(ClientError::Decode { index, len, .. }) => Some((*index, *len)),
        _ => None,
    })
    .await;
    assert_eq!(
        decode,
        (3, 3),
        "frame #3 (after Welcome, keyframe), 3 bytes"
    );

    // A delta with a corrupt payload: nothing applied, a resync requested.
    let d2 = enc.publish(&image(2.0), vec![]);
    let mut corrupt = d2.clone();
    corrupt.residual = vec![0x28, 0xb5, 0x2f, 0xfd, 0, 0];
    delta(&mut ws, corrupt).await;
    let message = until(&mut client, |e| match e {
        Event::Error(e @ ClientError::Apply { .. }) => Some(e.to_string()),
        _ => None,
    })
    .await;
    assert!(message.contains("delta 1 -> 2"), "{message}");
    assert_eq!(
        recv(&mut ws).await,
        ClientMessage::Resync {
            have_version: Some(1)
        }
    );
    let front = client.frame().expect("front");
    assert_eq!(front.version(), 1);
    assert_eq!(front.lightmap.texels, v1.lightmap.texels, "front untouched");

    // While waiting for the keyframe, even a fitting delta is ignored.
    delta(&mut ws, d2).await;
    // The keyframe of version 3 brings it up to date.
    enc.publish(&image(3.0), vec![]);
    keyframe(&mut ws, enc.keyframe()).await;
    front_is(&client, 3, &enc).await;
    assert_eq!(client.counters().deltas_ignored, 1);

    // A delta whose base is not the held version: Resync, not applied.
    enc.publish(&image(4.0), vec![]); // version 4: never sent
    let d5 = enc.publish(&image(5.0), vec![]);
    delta(&mut ws, d5).await;
    let (have, base) = until(&mut client, |e| match e {
        Event::Resync { have, delta_base } => Some((*have, *delta_base)),
        _ => None,
    })
    .await;
    assert_eq!((have, base), (Some(3), 4));
    assert_eq!(
        recv(&mut ws).await,
        ClientMessage::Resync {
            have_version: Some(3)
        }
    );
    assert_eq!(client.version(), Some(3));
    keyframe(&mut ws, enc.keyframe()).await;
    // Bit-exact after the resync.
    front_is(&client, 5, &enc).await;
    let c = client.counters();
    assert_eq!((c.resyncs, c.decode_errors, c.apply_errors), (2, 1, 1));
    client.close().await;
}

#[tokio::test]
async fn a_dropped_connection_reconnects_and_sends_the_newest_queued_pose() {
    let fake = FakeServer::bind().await;
    let (mut client, ws, mut enc) = at_version_1(&fake, Some("d"), Role::Driver).await;

    // The server goes away.
    drop(ws);
    until(&mut client, |e| {
        matches!(e, Event::Disconnected(_)).then_some(())
    })
    .await;
    // Poses sent while disconnected wait in the outbox; the newest wins.
    let pose = |x: f32| Pose {
        translation: [x, 0.0, 0.0],
        ..Pose::IDENTITY
    };
    let seqs: Vec<u64> = (0..3)
        .map(|i| client.send_pose(1, pose(i as f32)).expect("queued"))
        .collect();
    assert!(seqs.windows(2).all(|w| w[0] < w[1]), "seqs increase");
    let (attempt, delay) = until(&mut client, |e| match e {
        Event::Reconnecting { attempt, delay } => Some((*attempt, *delay)),
        _ => None,
    })
    .await;
    assert_eq!(attempt, 1);
    assert!(
        delay <= Duration::from_millis(120),
        "first delay ~100 ms: {delay:?}"
    );

    // The client comes back, says Hello with its token again, and sends
    // only the newest pose.
    let (mut ws, token) = fake.accept().await;
    assert_eq!(token.as_deref(), Some("d"));
    send(&mut ws, &welcome(Role::Driver, scene())).await;
    match recv(&mut ws).await {
        ClientMessage::Transform {
            object, seq, pose, ..
        } => {
            assert_eq!((object, seq), (1, seqs[2]));
            assert_eq!(pose.translation, [2.0, 0.0, 0.0]);
        }
        other => panic!("expected the queued Transform, got {other:?}"),
    }
    // The new session starts from a keyframe; the front catches up.
    enc.publish(&image(2.0), vec![]);
    enc.publish(&image(3.0), vec![]);
    keyframe(&mut ws, enc.keyframe()).await;
    front_is(&client, 3, &enc).await;
    let c = client.counters();
    assert_eq!((c.reconnects, c.poses_sent, c.poses_coalesced), (1, 1, 2));
    client.close().await;
}

#[tokio::test]
async fn latency_runs_from_sending_a_pose_to_the_version_that_echoes_it() {
    let fake = FakeServer::bind().await;
    let (mut client, mut ws, mut enc) = at_version_1(&fake, None, Role::Driver).await;

    // What the server would refuse is refused locally, saying why.
    assert!(matches!(
        client.send_pose(0, Pose::IDENTITY),
        Err(ClientError::UnknownObject { .. })
    ));
    assert!(matches!(
        client.send_pose(7, Pose::IDENTITY),
        Err(ClientError::UnknownObject { .. })
    ));
    let bad = Pose {
        scale: 0.0,
        ..Pose::IDENTITY
    };
    assert!(matches!(
        client.send_pose(1, bad),
        Err(ClientError::InvalidPose { object: 1, .. })
    ));

    let sent = Instant::now();
    let seq = client
        .send_pose_named("box", Pose::IDENTITY)
        .expect("a driver may");
    let got = match recv(&mut ws).await {
        ClientMessage::Transform { object, seq, .. } => (object, seq),
        other => panic!("expected a Transform, got {other:?}"),
    };
    assert_eq!(got, (1, seq));
    tokio::time::sleep(Duration::from_millis(50)).await;
    let d2 = enc.publish(&image(2.0), vec![ObjectSeq { object: 1, seq }]);
    delta(&mut ws, d2).await;
    let delivered = until(&mut client, |e| match e {
        Event::Version(v) if v.version == 2 => Some(v.delivered.clone()),
        _ => None,
    })
    .await;
    assert_eq!(delivered.len(), 1);
    assert_eq!((delivered[0].object, delivered[0].seq), (1, seq));
    let latency = delivered[0].latency.expect("the send time is known");
    assert!(
        latency >= Duration::from_millis(50) && latency <= sent.elapsed(),
        "latency {latency:?} spans the server's 50 ms hold"
    );
    assert_eq!(client.frame().expect("front").reflected.get(&1), Some(&seq));

    // A StaleSeq refusal is counted apart from other server errors.
    send(
        &mut ws,
        &ServerMessage::Error {
            code: ErrorCode::StaleSeq,
            message: "seq 1 is not newer than 2".into(),
        },
    )
    .await;
    until(&mut client, |e| {
        matches!(
            e,
            Event::ServerError {
                code: ErrorCode::StaleSeq,
                ..
            }
        )
        .then_some(())
    })
    .await;
    let c = client.counters();
    assert_eq!((c.stale_seqs, c.server_errors), (1, 0));
    client.close().await;
}

#[tokio::test]
async fn a_refused_token_is_permanent_and_a_viewer_may_not_drive() {
    let fake = FakeServer::bind().await;
    let url = fake.ws_url("fake");
    let refuse = async {
        let (mut ws, token) = fake.accept().await;
        assert_eq!(token.as_deref(), Some("wrong"));
        send(
            &mut ws,
            &ServerMessage::Error {
                code: ErrorCode::Unauthorized,
                message: "missing or unknown token".into(),
            },
        )
        .await;
    };
    let (result, ()) = tokio::join!(Client::connect(&url, Some("wrong"), None), refuse);
    let err = result.err().expect("refused");
    assert!(err.is_permanent(), "{err}");
    let text = err.to_string();
    assert!(
        text.contains(&url) && text.contains("missing or unknown token"),
        "{text}"
    );

    // No server at all: a connect error naming the address, not permanent.
    let closed = {
        let l = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
        l.local_addr().expect("addr")
    };
    let options = Options {
        connect_timeout: Duration::from_secs(2),
        ..Options::default()
    };
    let endpoint = lightwire_client::Endpoint::parse(&format!("http://{closed}"), Some("x"))
        .expect("endpoint");
    let err = Client::connect_with(endpoint, options)
        .await
        .err()
        .expect("refused");
    assert!(
        !err.is_permanent() && err.to_string().contains(&closed.to_string()),
        "{err}"
    );

    // A viewer's pose is refused before it reaches the socket.
    let (client, _ws) = connected(&fake, None, Role::Viewer).await;
    assert!(matches!(
        client.send_pose(1, Pose::IDENTITY),
        Err(ClientError::Forbidden { role: Role::Viewer })
    ));
    client.close().await;
}

/// [`scene`] with a bulb and a sun.
fn lit_scene() -> SceneInfo {
    let light = |name: &str, kind, state| LightInfo {
        name: name.into(),
        kind,
        range: None,
        cone: [0.0; 2],
        angular_radius: 0.0,
        state,
    };
    SceneInfo {
        lights: vec![
            light("bulb", LightType::Point, bulb()),
            light("sun", LightType::Directional, sun()),
        ],
        ..scene()
    }
}

fn bulb() -> LightState {
    LightState {
        on: true,
        color: [1.0; 3],
        intensity: 8.0,
        position: [0.5, 0.9, 0.5],
        direction: [0.0, -1.0, 0.0],
    }
}

fn sun() -> LightState {
    LightState {
        on: true,
        color: [1.0, 0.95, 0.85],
        intensity: 800.0,
        position: [0.0; 3],
        direction: [0.0, -0.6, -0.8],
    }
}

/// A client of `fake` that asks for lights (or not), welcomed as a
/// driver by a server offering `capabilities`; the Hello's capability
/// bits.
async fn lit_client(fake: &FakeServer, lights: bool, capabilities: u32) -> (Client, Conn, u32) {
    let endpoint = lightwire_client::Endpoint::parse(&fake.ws_url("fake"), None).expect("endpoint");
    let options = Options {
        lights,
        ..Options::default()
    };
    let accept = async {
        let (mut ws, _, hello) = fake.accept_hello().await;
        let welcome = ServerMessage::Welcome {
            protocol_version: PROTOCOL_VERSION,
            server: "fake".into(),
            role: Role::Driver,
            capabilities,
            scene: lit_scene(),
        };
        send(&mut ws, &welcome).await;
        (ws, hello)
    };
    let (client, (ws, hello)) = tokio::join!(Client::connect_with(endpoint, options), accept);
    (client.expect("connects"), ws, hello)
}

#[tokio::test]
async fn a_client_that_asks_follows_lights_and_sets_them_with_seqs_newer_than_any_seen() {
    let fake = FakeServer::bind().await;
    // Without `Options::lights` the Hello asks for poses only, as before.
    let (client, _ws, hello) = lit_client(&fake, false, CAP_POSES | CAP_LIGHTS).await;
    assert_eq!(hello, HELLO_POSES);
    client.close().await;

    let (mut client, mut ws, hello) = lit_client(&fake, true, CAP_POSES | CAP_LIGHTS).await;
    assert_eq!(hello, HELLO_POSES | HELLO_LIGHTS);
    assert!(client.follows_lights());
    assert_eq!(client.light_index("sun"), Some(1));
    // The first Lights: another driver set the bulb with a seq far ahead
    // of the clock (a quarter of the way round the circle).
    let far = 1u64 << 62;
    let dim = LightState {
        intensity: 2.0,
        ..bulb()
    };
    let status = |light, seq, state| LightStatus { light, seq, state };
    send(
        &mut ws,
        &ServerMessage::Lights {
            version: 1,
            lights: vec![status(0, far, dim), status(1, 0, sun())],
        },
    )
    .await;
    let mut enc = encoder();
    enc.publish(&image(1.0), vec![]);
    keyframe(&mut ws, enc.keyframe()).await;
    let front = front_is(&client, 1, &enc).await;
    assert_eq!(front.lights[&0], status(0, far, dim));
    assert_eq!(client.lights()[&1], status(1, 0, sun()));

    // What the server would refuse is refused here, naming the lights.
    let err = client
        .send_light_named("lamp", bulb())
        .expect_err("no lamp");
    assert!(matches!(err, ClientError::UnknownLight { .. }), "{err}");
    let text = err.to_string();
    assert!(
        text.contains("\"lamp\"") && text.contains("its lights: \"bulb\", \"sun\""),
        "{text}"
    );
    let err = client
        .send_light(2, bulb())
        .expect_err("no light 2")
        .to_string();
    assert!(
        err.contains("has 2 lights") && err.contains("\"bulb\", \"sun\""),
        "{err}"
    );
    let red = LightState {
        color: [2.0, 0.0, 0.0],
        ..bulb()
    };
    let err = client.send_light(0, red).expect_err("out of range");
    assert!(
        matches!(err, ClientError::InvalidLight { reason, .. } if reason.starts_with("color is out of range")),
        "{err}"
    );

    // The bulb's seq follows the one seen (the clock is not newer than
    // it, in serial-number order); the sun's is the clock.
    let sent = Instant::now();
    let off = LightState {
        on: false,
        ..bulb()
    };
    let seq = client.send_light_named("bulb", off).expect("a driver may");
    assert_eq!(seq, far + 1);
    match recv(&mut ws).await {
        ClientMessage::SetLight {
            light,
            seq: s,
            state,
            ..
        } => assert_eq!((light, s, state), (0, seq, off)),
        other => panic!("expected a SetLight, got {other:?}"),
    }
    let sun_seq = client.send_light(1, sun()).expect("a driver may");
    assert!(
        sun_seq > 1_600_000_000_000_000,
        "Unix microseconds: {sun_seq}"
    );
    match recv(&mut ws).await {
        ClientMessage::SetLight { light, seq: s, .. } => assert_eq!((light, s), (1, sun_seq)),
        other => panic!("expected a SetLight, got {other:?}"),
    }
    // Its own next seq is newer than its last.
    let again = client.send_light(0, off).expect("again");
    assert_eq!(again, far + 2);
    let _ = recv(&mut ws).await;

    // A version lit with the bulb's first state: delivered, with latency.
    tokio::time::sleep(Duration::from_millis(30)).await;
    send(
        &mut ws,
        &ServerMessage::Lights {
            version: 2,
            lights: vec![status(0, seq, off), status(1, 0, sun())],
        },
    )
    .await;
    delta(&mut ws, enc.publish(&image(2.0), vec![])).await;
    let delivered = until(&mut client, |e| match e {
        Event::Version(v) if v.version == 2 => Some(v.lights_delivered.clone()),
        _ => None,
    })
    .await;
    assert_eq!(delivered.len(), 1, "{delivered:?}");
    assert_eq!((delivered[0].light, delivered[0].seq), (0, seq));
    let latency = delivered[0].latency.expect("the send time is known");
    assert!(
        latency >= Duration::from_millis(30) && latency <= sent.elapsed(),
        "{latency:?}"
    );
    let shown = client
        .wait_for_light(0, seq, WAIT)
        .await
        .expect("version 2 shows it");
    assert_eq!((shown.version(), shown.lights[&0].state), (2, off));
    // The later seq is not shown yet: waiting for it times out.
    let err = client
        .wait_for_light(0, again, Duration::from_millis(200))
        .await
        .expect_err("not shown");
    assert!(matches!(err, ClientError::Timeout { .. }), "{err}");
    let c = client.counters();
    assert_eq!((c.lights_sent, c.server_errors), (3, 0));
    client.close().await;
}

#[tokio::test]
async fn lights_are_refused_by_a_server_without_cap_lights_and_to_a_viewer() {
    let fake = FakeServer::bind().await;
    let (client, _ws, _) = lit_client(&fake, true, CAP_POSES).await;
    assert!(!client.follows_lights());
    let err = client.send_light(0, bulb()).expect_err("no CAP_LIGHTS");
    assert!(matches!(err, ClientError::NoLights { .. }), "{err}");
    assert!(err.to_string().contains("CAP_LIGHTS"), "{err}");
    client.close().await;

    let (client, _ws) = connected(&fake, None, Role::Viewer).await;
    let err = client.send_light(0, bulb()).expect_err("a viewer");
    assert!(
        matches!(err, ClientError::Forbidden { role: Role::Viewer }),
        "{err}"
    );
    client.close().await;
}

/// The `Welcome` of the fake server, offering poses and lights, on `scene`.
fn lit_welcome(scene: SceneInfo) -> ServerMessage {
    ServerMessage::Welcome {
        protocol_version: PROTOCOL_VERSION,
        server: "fake".into(),
        role: Role::Driver,
        capabilities: CAP_POSES | CAP_LIGHTS,
        scene,
    }
}

/// The client's next `Connected` (a reconnect's Welcome taken), failing if
/// it stops instead.
async fn reconnected(client: &mut Client) -> Arc<SceneInfo> {
    until(client, |e| match e {
        Event::Connected { scene, .. } => Some(scene.clone()),
        Event::Closed(why) => panic!("the client stopped: {why:?}"),
        _ => None,
    })
    .await
}

/// A reconnect whose `Welcome` differs from the last one only in the
/// lights' states (a driver switched the bulb off meanwhile; PROTOCOL.md
/// §3) is the same scene: the client keeps its lightmap, carries on from
/// it and takes the new states. A description that differs otherwise (the
/// bulb became a spot) is a new scene: new buffers, whose first keyframe
/// is a catch-up that delivers nothing.
#[tokio::test]
async fn a_reconnect_after_a_light_changed_keeps_the_lightmap_and_takes_the_new_states() {
    let fake = FakeServer::bind().await;
    let (mut client, mut ws, _) = lit_client(&fake, true, CAP_POSES | CAP_LIGHTS).await;
    let status = |light, seq, state| LightStatus { light, seq, state };
    let lights = |version, bulb: LightStatus| ServerMessage::Lights {
        version,
        lights: vec![bulb, status(1, 0, sun())],
    };
    send(&mut ws, &lights(1, status(0, 0, bulb()))).await;
    let mut enc = encoder();
    enc.publish(&image(1.0), vec![]);
    keyframe(&mut ws, enc.keyframe()).await;
    front_is(&client, 1, &enc).await;
    let described = client.scene();
    assert!(described.lights[0].state.on);

    // The driver switches the bulb off; the server takes it and goes away
    // before any version shows it.
    let off = LightState {
        on: false,
        ..bulb()
    };
    let seq = client.send_light_named("bulb", off).expect("a driver may");
    match recv(&mut ws).await {
        ClientMessage::SetLight { light, seq: s, .. } => assert_eq!((light, s), (0, seq)),
        other => panic!("expected the SetLight, got {other:?}"),
    }
    drop(ws);
    until(&mut client, |e| {
        matches!(e, Event::Disconnected(_)).then_some(())
    })
    .await;

    // It comes back: the Welcome tells the bulb off, the rest as before.
    let (mut ws, _, _) = fake.accept_hello().await;
    let mut switched_off = lit_scene();
    switched_off.lights[0].state = off;
    send(&mut ws, &lit_welcome(switched_off.clone())).await;
    let scene = reconnected(&mut client).await;
    assert_eq!(*scene, switched_off);
    assert!(scene.same_description(&described));
    assert!(!client.scene().lights[0].state.on, "the bulb is off now");
    // Its first lightmap, lit with the bulb off, is delivered as the
    // driver's switch reaching the light: the client went on from the
    // version it held.
    send(&mut ws, &lights(2, status(0, seq, off))).await;
    enc.publish(&image(0.5), vec![]);
    keyframe(&mut ws, enc.keyframe()).await;
    let delivered = until(&mut client, |e| match e {
        Event::Version(v) if v.version == 2 => Some(v.lights_delivered.clone()),
        _ => None,
    })
    .await;
    let delivered: Vec<(u32, u64)> = delivered.iter().map(|d| (d.light, d.seq)).collect();
    assert_eq!(delivered, vec![(0, seq)], "a continuation, not a new scene");
    let front = front_is(&client, 2, &enc).await;
    assert_eq!(front.lights[&0], status(0, seq, off));
    assert!(!front.scene.lights[0].state.on);
    assert_eq!(client.lights()[&0].state, off);
    delta(&mut ws, enc.publish(&image(0.6), vec![])).await;
    front_is(&client, 3, &enc).await;
    let c = client.counters();
    assert_eq!(
        (c.reconnects, c.resyncs, c.apply_errors, c.server_errors),
        (1, 0, 0, 0)
    );

    // Another description: the bulb is a spot now. New buffers; their
    // first keyframe delivers nothing, though the bulb's seq moved on.
    drop(ws);
    let (mut ws, _, _) = fake.accept_hello().await;
    let mut spot = switched_off;
    spot.lights[0].kind = LightType::Spot;
    send(&mut ws, &lit_welcome(spot.clone())).await;
    let scene = reconnected(&mut client).await;
    assert!(!scene.same_description(&described));
    send(&mut ws, &lights(4, status(0, seq + 1, bulb()))).await;
    enc.publish(&image(0.7), vec![]);
    keyframe(&mut ws, enc.keyframe()).await;
    let delivered = until(&mut client, |e| match e {
        Event::Version(v) if v.version == 4 => Some(v.lights_delivered.clone()),
        _ => None,
    })
    .await;
    assert!(delivered.is_empty(), "{delivered:?}");
    assert_eq!(client.scene().lights[0].kind, LightType::Spot);
    client.close().await;
}
