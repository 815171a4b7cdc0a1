//! `lightwire-client drive --light` and `load` with a script's light keys,
//! as a user runs them, against a real `lightwire serve` of cornell-point
//! (a Cornell box lit by one point light, the bulb) at half its density
//! on the CPU reference solver, with tokens. The server binary is found
//! as in `load.rs` (`lightwire_testkit::Lightwire::built`).
//!
//! What the server shows is checked with the client library itself: a
//! viewer that asks for lights (`Options::lights`) reads the bulb's state
//! and seq from the `Lights` of the version it holds.

use std::process::{Command, Output};
use std::time::Duration;

use lightwire_client::{Client, Endpoint, LightState, LightStatus, Options};
use lightwire_testkit::process::Proc;
use lightwire_testkit::{DRIVER_TOKEN, Lightwire, VIEWER_TOKEN, repo};
use serde_json::Value;

const SCENE: &str = "cornell-point";

/// cornell-point at half its density on the reference solver, with the
/// kit's three tokens, ready.
fn serve() -> Proc {
    let server =
        Lightwire::built().solver_of("cornell-point.json", ("127.0.0.1:0", "reference"), &[]);
    server.wait_ready();
    server
}

/// `lightwire-client ARGS`, its exit code and what it printed.
fn client(args: &[&str]) -> (Option<i32>, String, String) {
    let Output {
        status,
        stdout,
        stderr,
    } = Command::new(env!("CARGO_BIN_EXE_lightwire-client"))
        .args(args)
        .env_remove("LIGHTWIRE_TOKEN")
        .output()
        .expect("lightwire-client runs");
    let (stdout, stderr) = (
        String::from_utf8_lossy(&stdout).into_owned(),
        String::from_utf8_lossy(&stderr).into_owned(),
    );
    eprintln!("lightwire-client {}:\n{stdout}{stderr}", args.join(" "));
    (status.code(), stdout, stderr)
}

/// `drive URL --scene cornell-point --token TOKEN --light ARGS...`.
fn drive_light(server: &Proc, token: &str, light: &[&str]) -> (Option<i32>, String, String) {
    let url = server.url("");
    let mut args = vec![
        "drive",
        url.as_str(),
        "--scene",
        SCENE,
        "--token",
        token,
        "--timeout",
        "25s",
        "--light",
    ];
    args.extend_from_slice(light);
    client(&args)
}

/// The number after `word` in `text`.
fn number_after(text: &str, word: &str) -> u64 {
    let rest = &text[text
        .find(word)
        .unwrap_or_else(|| panic!("no {word:?} in {text:?}"))
        + word.len()..];
    let digits: String = rest
        .trim_start()
        .chars()
        .take_while(char::is_ascii_digit)
        .collect();
    digits
        .parse()
        .unwrap_or_else(|_| panic!("no number after {word:?} in {text:?}"))
}

/// What a fresh viewer that asks for lights learns of the bulb: the
/// version it holds and the bulb's status in it.
fn observe(server: &Proc) -> (u64, LightStatus) {
    let runtime = tokio::runtime::Runtime::new().expect("a runtime");
    runtime.block_on(async {
        let endpoint = Endpoint::parse(&server.url(""), Some(SCENE)).expect("endpoint");
        let options = Options {
            token: Some(VIEWER_TOKEN.into()),
            lights: true,
            ..Options::default()
        };
        let client = Client::connect_with(endpoint, options)
            .await
            .expect("a viewer connects");
        let frame = client
            .wait_for_version(0, Duration::from_secs(20))
            .await
            .expect("a first lightmap");
        client.close().await;
        (
            frame.version(),
            *frame.lights.get(&0).expect("the bulb's state"),
        )
    })
}

#[test]
fn drive_light_sets_the_bulb_and_waits_for_the_version_that_shows_it() {
    let server = serve();
    let (_, before) = observe(&server);
    assert_eq!(before.seq, 0, "the scene file's state");
    assert!(
        before.state.on && before.state.intensity == 8.0,
        "{before:?}"
    );

    // Dim and colour it: the rest of its state is kept.
    let (code, stdout, stderr) = drive_light(
        &server,
        DRIVER_TOKEN,
        &["bulb", "--intensity", "4", "--color", "1,0.5,0.25"],
    );
    assert_eq!(code, Some(0), "{stderr}");
    assert!(
        stdout.contains(
            "light \"bulb\" of scene \"cornell-point\": on, intensity 4 W/sr, color [1, 0.5, 0.25]"
        ),
        "{stdout}"
    );
    let seq = number_after(&stdout, "(seq");
    let version = number_after(&stdout, "shown from version");
    let dimmed = LightState {
        intensity: 4.0,
        color: [1.0, 0.5, 0.25],
        ..before.state
    };
    let (now, shown) = observe(&server);
    assert!(now >= version, "{now} < {version}");
    assert_eq!((shown.seq, shown.state), (seq, dimmed));

    // Off: the colour and intensity it was given stay.
    let (code, stdout, stderr) = drive_light(&server, DRIVER_TOKEN, &["bulb", "--off"]);
    assert_eq!(code, Some(0), "{stderr}");
    let off_seq = number_after(&stdout, "(seq");
    assert!(
        lightwire_protocol::seq_is_newer(off_seq, seq),
        "{off_seq} after {seq}"
    );
    let (_, shown) = observe(&server);
    assert_eq!(
        (shown.seq, shown.state),
        (
            off_seq,
            LightState {
                on: false,
                ..dimmed
            }
        )
    );

    // A viewer's token is refused, saying a driver token is needed.
    let (code, _, stderr) = drive_light(&server, VIEWER_TOKEN, &["bulb", "--on"]);
    assert_eq!(code, Some(2), "{stderr}");
    assert!(
        stderr.contains("viewer role") && stderr.contains("driver or admin token"),
        "{stderr}"
    );
    // A light the scene does not have: its lights are listed.
    let (code, _, stderr) = drive_light(&server, DRIVER_TOKEN, &["lamp", "--on"]);
    assert_eq!(code, Some(2), "{stderr}");
    assert!(
        stderr.contains("scene \"cornell-point\" has no light \"lamp\"; its lights: \"bulb\""),
        "{stderr}"
    );
    // An invalid value: which flag, and `LightState::validate`'s reason.
    let (code, _, stderr) = drive_light(&server, DRIVER_TOKEN, &["bulb", "--color", "1,2,0"]);
    assert_eq!(code, Some(2), "{stderr}");
    assert!(
        stderr.contains("--color 1,2,0: color is out of range (each channel in [0, 1])"),
        "{stderr}"
    );
    let (code, _, stderr) = drive_light(&server, DRIVER_TOKEN, &["bulb", "--intensity", "-1"]);
    assert_eq!(code, Some(2), "{stderr}");
    assert!(
        stderr.contains("--intensity -1: intensity is out of range"),
        "{stderr}"
    );
    // None of them changed the light.
    let (_, shown) = observe(&server);
    assert_eq!(shown.seq, off_seq);
}

#[test]
fn load_replays_a_scripts_light_keys_and_reports_their_latency() {
    let server = serve();
    let report = std::env::temp_dir().join(format!("lightwire-switch-{}.json", std::process::id()));
    let switch = repo().join("scenes/scripts/switch.json");
    let url = server.url("");
    let (code, _, stderr) = client(&[
        "load",
        &url,
        "--scene",
        SCENE,
        "--token",
        DRIVER_TOKEN,
        "--viewer-token",
        VIEWER_TOKEN,
        "--script",
        switch.to_str().expect("utf-8 path"),
        "--viewers",
        "3",
        "--drivers",
        "1",
        "--duration",
        "5s",
        "--max-errors",
        "0",
        "--report",
        report.to_str().expect("utf-8 path"),
    ]);
    assert_eq!(code, Some(0), "{stderr}");
    let r: Value =
        serde_json::from_str(&std::fs::read_to_string(&report).expect("report")).expect("json");
    let _ = std::fs::remove_file(&report);
    assert_eq!(r["errors"], 0, "{r:#}");
    assert_eq!(r["poses_sent"], 0, "a light script moves nothing");
    // On at 0 s, off at 2 s, on at 4 s: three states, each sent once.
    let sent = r["lights_sent"].as_u64().expect("lights_sent");
    assert!((2..=4).contains(&sent), "{sent} light states sent: {r:#}");
    // Every viewer saw states reach the light (a state the solver had not
    // taken up when the next came is overtaken by it, PROTOCOL.md §1.7,
    // so not necessarily every one).
    let samples = r["light_latency"]["samples"].as_u64().expect("samples");
    assert!(samples >= 3, "{samples} light deliveries: {r:#}");
    assert!(r["light_latency"]["p50_ms"].as_f64().expect("p50") > 0.0);
    assert_eq!(r["viewers_on_final_version"], 3, "{r:#}");
    // The bulb ends on as the script has it at 4 s, under the last seq.
    let (_, shown) = observe(&server);
    assert!(shown.state.on && shown.seq > 0, "{shown:?}");
}
