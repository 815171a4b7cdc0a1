//! Lights over the wire (issue 60, protocol version 4): a driver switches,
//! dims and recolours a light with `SetLight`, viewers that ask get the
//! states each version was lit with (`Lights`), and hostile light messages
//! get their documented errors without disturbing anyone.

use std::time::{Duration, Instant};

use futures_util::{SinkExt, StreamExt};
use lightwire_protocol::{
    CAP_LIGHTS, ClientMessage, ErrorCode, LightState, LightType, ServerMessage, decode_server,
    encode_client,
};
use tokio_tungstenite::tungstenite::Message;

use lightwire_testkit::peer::Peer;
use lightwire_testkit::process::Proc;
use lightwire_testkit::{DRIVER_TOKEN, VIEWER_TOKEN, http, lightwire};

/// cornell-point (a box lit by one point light, the bulb) at half its
/// density, served by `solver` with the three tokens.
fn serve(solver: &str) -> Proc {
    lightwire!().solver_of("cornell-point.json", ("127.0.0.1:0", solver), &[])
}

/// The scene's version as `/api/scenes` reports it.
async fn version(server: &Proc) -> u64 {
    let list = http::get(&server.addr, "/api/scenes", Some(VIEWER_TOKEN)).await;
    assert_eq!(list.status, 200);
    list.json()[0]["version"].as_u64().expect("version")
}

/// Reads on `peers` until the server has published nothing new for 3 s
/// and every peer holds that version, which reflects light seq `seq` of
/// light 0 in the `Lights` of the first peer (which asked for them).
async fn settle(server: &Proc, peers: &mut [&mut Peer], seq: u64) -> u64 {
    let deadline = Instant::now() + Duration::from_secs(180);
    loop {
        let v = version(server).await;
        for p in peers.iter_mut() {
            p.pump_until_version(v, Duration::from_secs(60)).await;
        }
        let shown = peers[0]
            .lights
            .last()
            .map(|(_, lights)| lights[0].seq)
            .unwrap_or(0);
        if shown == seq {
            tokio::time::sleep(Duration::from_secs(3)).await;
            if version(server).await == v {
                for p in peers.iter_mut() {
                    p.pump_until_version(v, Duration::from_secs(60)).await;
                }
                return v;
            }
        }
        assert!(
            Instant::now() < deadline,
            "the server never settled on light seq {seq}"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

fn rgb(peer: &Peer) -> Vec<[f32; 3]> {
    peer.map.as_ref().expect("welcomed").to_rgb()
}

/// A driver switches the bulb off, then on again as it was: a viewer
/// that asked sees the `Lights` of each version before its lightmap, the
/// room goes dark (what the bulb gave is taken back to under 1% of the
/// brightest texel) and comes back to what it showed at first (99% of the
/// lit texels within 2%, none beyond 5%); a viewer that did not ask gets
/// no `Lights` and the same texels.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_switched_light_goes_dark_and_comes_back_for_every_viewer() {
    let server = serve("progressive");
    server.ready().await;
    let url = server
        .url("/ws/scenes/cornell-point")
        .replacen("http", "ws", 1);
    let mut viewer = Peer::connect_asking_lights(&url, VIEWER_TOKEN).await;
    let mut old = Peer::connect(&url, VIEWER_TOKEN).await;
    assert_ne!(
        viewer.capabilities & CAP_LIGHTS,
        0,
        "a solver follows lights"
    );
    let scene = viewer.scene.clone().expect("welcomed");
    assert_eq!(scene.lights.len(), 1, "{:?}", scene.lights);
    let bulb = scene.lights[0].clone();
    assert_eq!((bulb.name.as_str(), bulb.kind), ("bulb", LightType::Point));
    assert!(bulb.state.on && bulb.state.intensity == 8.0, "{bulb:?}");

    let first = settle(&server, &mut [&mut viewer, &mut old], 0).await;
    let (v, lights) = viewer.lights.first().cloned().expect("Lights first");
    assert!(v <= first, "the first Lights is of a version shown");
    assert_eq!((lights[0].seq, lights[0].state), (0, bulb.state));
    let on = rgb(&viewer);
    let brightest = on
        .iter()
        .map(|c| c[0].max(c[1]).max(c[2]))
        .fold(0.0, f32::max);
    assert!(brightest > 0.1, "the bulb lights the room: {brightest}");

    let mut driver = Peer::connect(&url, DRIVER_TOKEN).await;
    let off = LightState {
        on: false,
        ..bulb.state
    };
    driver.set_light(0, 1, off).await;
    settle(&server, &mut [&mut viewer, &mut old], 1).await;
    let dark = rgb(&viewer);
    let left = dark
        .iter()
        .map(|c| c[0].max(c[1]).max(c[2]))
        .fold(0.0, f32::max);
    assert!(
        left < 0.01 * brightest,
        "switched off, the brightest texel still holds {left} of {brightest}"
    );
    let (_, shown) = viewer.lights.last().cloned().expect("Lights");
    assert_eq!((shown[0].seq, shown[0].state), (1, off));

    driver.set_light(0, 2, bulb.state).await;
    settle(&server, &mut [&mut viewer, &mut old], 2).await;
    let back = rgb(&viewer);
    let lit: Vec<usize> = (0..on.len())
        .filter(|&i| on[i].iter().sum::<f32>() > 0.01 * brightest)
        .collect();
    let off_by = |i: usize| {
        let (a, b) = (back[i].iter().sum::<f32>(), on[i].iter().sum::<f32>());
        ((a - b) / b).abs()
    };
    let over_2 = lit.iter().filter(|&&i| off_by(i) > 0.02).count();
    let worst = lit.iter().map(|&i| off_by(i)).fold(0.0, f32::max);
    eprintln!(
        "{} lit texels: {over_2} more than 2% off the first state, worst {:.2}%",
        lit.len(),
        worst * 100.0
    );
    assert!(
        over_2 as f32 <= 0.01 * lit.len() as f32,
        "{over_2} of {} texels more than 2% off",
        lit.len()
    );
    assert!(worst <= 0.05, "a texel {:.1}% off", worst * 100.0);
    assert!(driver.errors.is_empty(), "{:?}", driver.errors);
    assert!(old.lights.is_empty(), "Lights only to those who ask");
    assert_eq!(old.texels(), viewer.texels(), "the same light either way");
}

/// The errors of PROTOCOL.md §1.7 for light messages, in its order:
/// a viewer's `Forbidden`, an unknown light's `UnknownLight`, a bad
/// state's `InvalidLight`, stale seqs' `StaleSeq`, a flood's
/// `RateLimited`, a version 3 client's `ProtocolViolation`. No seq
/// freezes the light: after 2^64 − 1 come 0 and 1. A watching viewer
/// sees no error and keeps receiving versions.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn hostile_light_messages_get_their_errors_and_disturb_no_one() {
    let server = serve("reference");
    server.ready().await;
    let url = server
        .url("/ws/scenes/cornell-point")
        .replacen("http", "ws", 1);
    let mut watcher = Peer::connect_asking_lights(&url, VIEWER_TOKEN).await;
    watcher
        .read_until(Duration::from_secs(30), "a keyframe", |p| p.keyframes > 0)
        .await;
    let state = watcher.scene.clone().expect("welcomed").lights[0].state;

    let mut viewer = Peer::connect(&url, VIEWER_TOKEN).await;
    viewer.set_light(0, 1, state).await;
    let mut driver = Peer::connect(&url, DRIVER_TOKEN).await;
    let bad = |f: fn(&mut LightState)| {
        let mut s = state;
        f(&mut s);
        s
    };
    let cases: [(u32, u64, LightState, ErrorCode); 6] = [
        (1, 1, state, ErrorCode::UnknownLight),
        (u32::MAX, 1, state, ErrorCode::UnknownLight),
        (
            0,
            1,
            bad(|s| s.intensity = f32::NAN),
            ErrorCode::InvalidLight,
        ),
        (
            0,
            1,
            bad(|s| s.color = [2.0, 1.0, 1.0]),
            ErrorCode::InvalidLight,
        ),
        (
            0,
            1,
            bad(|s| s.direction = [0.0; 3]),
            ErrorCode::InvalidLight,
        ),
        (0, 1, bad(|s| s.position[1] = 1e9), ErrorCode::InvalidLight),
    ];
    for (light, seq, s, _) in &cases {
        driver.set_light(*light, *seq, *s).await;
    }
    // No seq freezes the light. The largest is not newer than 0 (half the
    // circle or more ahead, serial-number order), so no single message
    // reaches it; steps of less than half the circle do, and after it
    // come 0 and 1.
    let dim = LightState {
        intensity: 4.0,
        ..state
    };
    let seqs: [(u64, LightState, bool); 8] = [
        (u64::MAX, dim, false),
        (1 << 62, dim, true),
        (1 << 63, state, true),
        (u64::MAX, dim, true),
        (u64::MAX - 1, state, false),
        (0, dim, true),
        (1, state, true),
        (1, dim, false),
    ];
    for (seq, s, _) in seqs {
        driver.set_light(0, seq, s).await;
    }
    let stale = seqs.iter().filter(|s| !s.2).count();
    refused_as_forbidden(&mut viewer).await;
    driver
        .read_until(Duration::from_secs(10), "the errors", |p| {
            p.errors.len() >= cases.len() + stale
        })
        .await;
    driver.pump(Duration::from_secs(1)).await;
    let codes: Vec<ErrorCode> = driver.errors.iter().map(|e| e.0).collect();
    let mut want: Vec<ErrorCode> = cases.iter().map(|c| c.3).collect();
    want.extend(vec![ErrorCode::StaleSeq; stale]);
    assert_eq!(codes, want, "{:?}", driver.errors);
    let messages: Vec<&str> = driver.errors[cases.len()..]
        .iter()
        .map(|e| e.1.as_str())
        .collect();
    assert!(
        messages[0].ends_with("not newer than 0")
            && messages[1].ends_with("not newer than 18446744073709551615")
            && messages[2].ends_with("not newer than 1"),
        "each stale seq's error names the latest: {messages:?}"
    );

    // The light ends as seq 1 set it (the scene's own state), and the
    // watcher is told so.
    watcher
        .read_until(Duration::from_secs(60), "Lights of seq 1", |p| {
            p.lights.last().is_some_and(|(_, l)| l[0].seq == 1)
        })
        .await;
    assert_eq!(watcher.lights.last().map(|(_, l)| l[0].state), Some(state));

    // A flood: one bucket for transforms and lights, 120 a second.
    let before = driver.errors.len();
    for seq in 2..400 {
        driver.set_light(0, seq, state).await;
    }
    driver
        .read_until(Duration::from_secs(20), "RateLimited", |p| {
            p.errors[before..]
                .iter()
                .any(|e| e.0 == ErrorCode::RateLimited)
        })
        .await;

    // A version 3 client is welcomed in version 3 and may not set lights.
    let (mut ws, _) = tokio_tungstenite::connect_async(&url)
        .await
        .expect("connects");
    let hello = ClientMessage::Hello {
        protocol_version: 3,
        client: "v3".into(),
        token: Some(DRIVER_TOKEN.into()),
        capabilities: lightwire_protocol::HELLO_LIGHTS,
    };
    ws.send(Message::Binary(encode_client(&hello).into()))
        .await
        .expect("send");
    let set = ClientMessage::SetLight {
        light: 0,
        seq: 1_000,
        state,
        client_time_us: 0,
    };
    ws.send(Message::Binary(encode_client(&set).into()))
        .await
        .expect("send");
    let deadline = Instant::now() + Duration::from_secs(20);
    let mut first = true;
    let code = loop {
        assert!(
            Instant::now() < deadline,
            "no error for a version 3 SetLight"
        );
        let Some(Ok(Message::Binary(bytes))) = ws.next().await else {
            panic!("the version 3 connection ended");
        };
        if std::mem::take(&mut first) {
            assert_eq!(bytes[1], 3, "a version 3 Welcome");
            continue;
        }
        match decode_server(&bytes) {
            Ok(ServerMessage::Error { code, .. }) => break code,
            Ok(ServerMessage::Lights { .. }) => panic!("Lights sent to a version 3 client"),
            _ => {}
        }
    };
    assert_eq!(code, ErrorCode::ProtocolViolation);

    watcher.pump(Duration::from_secs(1)).await;
    assert!(watcher.errors.is_empty(), "{:?}", watcher.errors);
}

/// The brightest channel of any texel.
fn brightest(rgb: &[[f32; 3]]) -> f32 {
    rgb.iter()
        .map(|c| c[0].max(c[1]).max(c[2]))
        .fold(0.0, f32::max)
}

/// The JSON chunk of a GLB file (`scene.glb`).
fn glb_json(glb: &[u8]) -> serde_json::Value {
    let word = |at: usize| {
        let bytes: [u8; 4] = glb
            .get(at..at + 4)
            .and_then(|b| b.try_into().ok())
            .expect("a GLB header");
        u32::from_le_bytes(bytes) as usize
    };
    assert_eq!(&glb[..4], b"glTF", "a GLB file");
    let length = word(12);
    serde_json::from_slice(&glb[20..20 + length]).expect("the GLB's JSON chunk")
}

/// What a newcomer is told is the lights as they are now (issue 60): after
/// a driver switched the bulb off, a viewer that connects later, without
/// asking for `Lights`, is welcomed with the bulb off, and the first
/// lightmap it gets is dark; one that asks is told seq 1 too. `GET
/// /api/scenes/{id}` (what `Welcome` carries), `GET .../lights` (off,
/// seq 1, its colour and intensity as when on, the scene file's state
/// under `file`) and `scene.glb` (the bulb's `KHR_lights_punctual`
/// intensity 0) say the same; switched on again, the next newcomer is
/// welcomed with it on; moved and dimmed, the route lists it so and still
/// gives the scene file's state under `file`.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_newcomer_is_told_the_lights_as_they_are_now() {
    let server = serve("reference");
    server.ready().await;
    let url = server
        .url("/ws/scenes/cornell-point")
        .replacen("http", "ws", 1);
    let mut watcher = Peer::connect_asking_lights(&url, VIEWER_TOKEN).await;
    let bulb = watcher.scene.clone().expect("welcomed").lights[0].clone();
    assert!(bulb.state.on, "the scene file's bulb is on: {bulb:?}");
    settle(&server, &mut [&mut watcher], 0).await;
    let lit = brightest(&rgb(&watcher));
    assert!(lit > 0.1, "the bulb lights the room: {lit}");

    let mut driver = Peer::connect(&url, DRIVER_TOKEN).await;
    let off = LightState {
        on: false,
        ..bulb.state
    };
    driver.set_light(0, 1, off).await;
    settle(&server, &mut [&mut watcher], 1).await;
    assert!(driver.errors.is_empty(), "{:?}", driver.errors);

    // A newcomer that does not ask for Lights: told off, and its first
    // lightmap is dark.
    let mut late = Peer::connect(&url, VIEWER_TOKEN).await;
    let told = late.scene.clone().expect("welcomed").lights[0].state;
    assert_eq!(told, off, "the Welcome tells the bulb as it is now");
    late.read_until(Duration::from_secs(30), "a keyframe", |p| p.keyframes > 0)
        .await;
    assert_eq!(late.applied.first().map(|a| a.1), Some(true));
    let first = brightest(&rgb(&late));
    assert!(
        first < 0.01 * lit,
        "the first lightmap of a newcomer told \"off\" holds {first} of {lit}"
    );
    // One that asks is told the seq as well, before that lightmap.
    let mut asking = Peer::connect_asking_lights(&url, VIEWER_TOKEN).await;
    assert_eq!(asking.scene.clone().expect("welcomed").lights[0].state, off);
    asking
        .read_until(Duration::from_secs(30), "a keyframe", |p| p.keyframes > 0)
        .await;
    let (_, shown) = asking.lights.first().cloned().expect("Lights first");
    assert_eq!((shown[0].seq, shown[0].state), (1, off));

    // REST says the same.
    let info = http::get(
        &server.addr,
        "/api/scenes/cornell-point",
        Some(VIEWER_TOKEN),
    )
    .await;
    assert_eq!(info.status, 200, "{}", info.text());
    assert_eq!(
        info.json()["lights"][0]["state"]["on"],
        false,
        "{}",
        info.text()
    );
    let listed = http::get(
        &server.addr,
        "/api/scenes/cornell-point/lights",
        Some(VIEWER_TOKEN),
    )
    .await;
    assert_eq!(listed.status, 200, "{}", listed.text());
    let entry = &listed.json()["lights"][0];
    assert_eq!(
        (
            &entry["name"],
            &entry["on"],
            &entry["seq"],
            &entry["intensity"]
        ),
        (&"bulb".into(), &false.into(), &1.into(), &8.0.into()),
        "{entry}"
    );
    // The scene file's state stays under `file`: what pages anchor on.
    let file = serde_json::json!({
        "on": true,
        "color": [1.0, 1.0, 1.0],
        "intensity": 8.0,
        "position": [2.78, 4.488, 2.796]
    });
    assert_eq!(entry["file"], file, "{entry}");
    let glb = http::get(
        &server.addr,
        "/api/scenes/cornell-point/scene.glb",
        Some(VIEWER_TOKEN),
    )
    .await;
    assert_eq!(glb.status, 200, "{}", glb.text());
    let doc = glb_json(&glb.body);
    let punctual = &doc["extensions"]["KHR_lights_punctual"]["lights"];
    assert_eq!(punctual[0]["name"], "bulb", "{punctual}");
    assert_eq!(punctual[0]["intensity"].as_f64(), Some(0.0), "{punctual}");

    // On again: the next newcomer is told so.
    driver.set_light(0, 2, bulb.state).await;
    settle(&server, &mut [&mut watcher], 2).await;
    let again = Peer::connect(&url, VIEWER_TOKEN).await;
    assert_eq!(
        again.scene.clone().expect("welcomed").lights[0].state,
        bulb.state
    );
    let listed = http::get(
        &server.addr,
        "/api/scenes/cornell-point/lights",
        Some(VIEWER_TOKEN),
    )
    .await;
    assert_eq!(listed.json()["lights"][0]["on"], true, "{}", listed.text());

    // Moved and dimmed: the route lists it where it is now, and the scene
    // file's state under `file` still.
    let [x, y, z] = bulb.state.position;
    let moved = LightState {
        intensity: 2.0,
        position: [x - 0.5, y - 0.5, z + 0.25],
        ..bulb.state
    };
    driver.set_light(0, 3, moved).await;
    settle(&server, &mut [&mut watcher], 3).await;
    assert!(driver.errors.is_empty(), "{:?}", driver.errors);
    let listed = http::get(
        &server.addr,
        "/api/scenes/cornell-point/lights",
        Some(VIEWER_TOKEN),
    )
    .await;
    let entry = &listed.json()["lights"][0];
    assert_eq!(
        (&entry["seq"], &entry["intensity"], &entry["on"]),
        (&3.into(), &2.0.into(), &true.into()),
        "{entry}"
    );
    let at: Vec<f32> = (0..3)
        .map(|i| entry["position"][i].as_f64().expect("a number") as f32)
        .collect();
    assert_eq!(at, moved.position, "{entry}");
    assert_eq!(entry["file"], file, "{entry}");
}

/// A relay forwards lights (issue 60): it announces `CAP_LIGHTS` as its
/// upstream does; a driver on the relay switches the bulb off, and a
/// viewer on the solver and one on the relay are both told (`Lights`,
/// seq 1) and both see the room go dark; a newcomer on the relay is
/// welcomed with the bulb off; a viewer on the relay may still not set
/// lights.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_driver_on_a_relay_switches_a_light_for_viewers_on_both() {
    let server = serve("reference");
    server.ready().await;
    let relay = lightwire!().relay_of(&server.addr, "cornell-point", &[]);
    relay.ready().await;
    let ws = |p: &Proc| p.url("/ws/scenes/cornell-point").replacen("http", "ws", 1);
    let mut direct = Peer::connect_asking_lights(&ws(&server), VIEWER_TOKEN).await;
    let mut relayed = Peer::connect_asking_lights(&ws(&relay), VIEWER_TOKEN).await;
    assert_ne!(
        relayed.capabilities & CAP_LIGHTS,
        0,
        "a relay of a solver follows lights"
    );
    let bulb = relayed.scene.clone().expect("welcomed").lights[0].clone();
    assert!(bulb.state.on, "{bulb:?}");
    for peer in [&mut direct, &mut relayed] {
        peer.read_until(Duration::from_secs(60), "a lit room", |p| {
            p.keyframes > 0 && brightest(&rgb(p)) > 0.1
        })
        .await;
    }
    let lit = brightest(&rgb(&relayed));
    let (_, shown) = relayed
        .lights
        .first()
        .cloned()
        .expect("Lights via the relay");
    assert_eq!((shown[0].seq, shown[0].state), (0, bulb.state));

    let mut driver = Peer::connect(&ws(&relay), DRIVER_TOKEN).await;
    let off = LightState {
        on: false,
        ..bulb.state
    };
    driver.set_light(0, 1, off).await;
    for (peer, name) in [
        (&mut direct, "on the solver"),
        (&mut relayed, "on the relay"),
    ] {
        peer.read_until(Duration::from_secs(60), "the bulb off", |p| {
            p.lights.last().is_some_and(|(_, l)| l[0].seq == 1)
                && p.map
                    .as_ref()
                    .is_some_and(|m| m.version >= p.lights.last().map_or(0, |l| l.0))
                && brightest(&rgb(p)) < 0.01 * lit
        })
        .await;
        let (_, shown) = peer.lights.last().cloned().expect("Lights");
        assert_eq!((shown[0].seq, shown[0].state), (1, off), "{name}");
    }
    assert!(driver.errors.is_empty(), "{:?}", driver.errors);

    let late = Peer::connect(&ws(&relay), VIEWER_TOKEN).await;
    assert_eq!(
        late.scene.clone().expect("welcomed").lights[0].state,
        off,
        "a newcomer on the relay is told the bulb is off"
    );
    let mut viewer = Peer::connect(&ws(&relay), VIEWER_TOKEN).await;
    viewer.set_light(0, 2, bulb.state).await;
    refused_as_forbidden(&mut viewer).await;
    assert!(relayed.errors.is_empty() && direct.errors.is_empty());
}

/// Waits for `peer`'s first error and asserts it is `Forbidden`.
async fn refused_as_forbidden(peer: &mut Peer) {
    peer.read_until(Duration::from_secs(10), "Forbidden", |p| {
        !p.errors.is_empty()
    })
    .await;
    assert_eq!(peer.errors[0].0, ErrorCode::Forbidden, "{:?}", peer.errors);
}
