//! `lightwire-client` as a user runs it, against a real `lightwire serve`
//! process on loopback.
//!
//! The server binary: Cargo hands a test the paths of its own package's
//! binaries only (`CARGO_BIN_EXE_lightwire-client` here), so the test asks
//! Cargo to make sure the workspace's binaries are built, with the same
//! profile and target directory, and runs `target/<profile>/lightwire`
//! (see `lightwire_testkit::Lightwire::built`): a no-op under `cargo test --workspace`, a
//! build when this test runs alone, and never a stale binary.
//! ARCHITECTURE.md explains the choice.
//!
//! The server runs in development mode on cornell-low at a fifth of its
//! texel density with the CPU reference solver at 3 ticks per second: a
//! re-solve per tick while the box moves, no GPU start-up, a few CPU
//! seconds in all (the machine running CI has two cores).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

use lightwire_testkit::process::Proc;
use lightwire_testkit::{Lightwire, repo, scene_path};
use serde_json::Value;

/// cornell-low at a fifth of its density on the reference solver, 3 ticks
/// per second.
fn start_server() -> Proc {
    let flags = [
        "--solver",
        "reference",
        "--density-scale",
        "0.2",
        "--tick-hz",
        "3",
    ];
    let server = Lightwire::built().serve_dev_on(scene_path("cornell-low.json"), &flags);
    server.wait_ready();
    server
}

/// The published version, from `GET /api/scenes`.
fn version(server: &Proc) -> u64 {
    let response = server.get("/api/scenes");
    assert_eq!(response.status, 200);
    let scenes: Value = serde_json::from_slice(&response.body).expect("json");
    scenes[0]["version"].as_u64().expect("version")
}

fn client(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_lightwire-client"))
        .args(args)
        .env_remove("LIGHTWIRE_TOKEN")
        .output()
        .expect("lightwire-client runs")
}

/// Runs `lightwire-client ARGS`, which must exit with `code`; returns
/// what it said on stderr.
fn client_exits(args: &[&str], code: i32) -> String {
    let out = client(args);
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(out.status.code(), Some(code), "{stderr}");
    stderr
}

fn report_path(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_BIN_EXE_lightwire-client"))
        .parent()
        .expect("target/<profile>/")
        .join("load-reports");
    std::fs::create_dir_all(&dir).expect("report directory");
    dir.join(name)
}

#[test]
fn two_hundred_viewers_and_two_drivers_for_twenty_seconds_end_on_the_servers_version() {
    let server = start_server();
    let first_version = version(&server);
    let report = report_path("two-hundred-viewers.json");
    let orbit = repo().join("scenes/scripts/orbit.json");
    let started = Instant::now();
    let out = client(&[
        "load",
        &server.url(""),
        "--scene",
        "cornell-low",
        "--script",
        orbit.to_str().expect("utf-8 path"),
        "--viewers",
        "200",
        "--drivers",
        "2",
        "--duration",
        "20s",
        "--max-errors",
        "0",
        "--report",
        report.to_str().expect("utf-8 path"),
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    eprintln!(
        "{stderr}(load took {:.1} s)",
        started.elapsed().as_secs_f64()
    );
    assert!(
        out.status.success(),
        "load failed: {:?}\n{stderr}",
        out.status
    );
    let r: Value =
        serde_json::from_str(&std::fs::read_to_string(&report).expect("report")).expect("json");

    // Zero errors of any kind, every connection opened.
    assert_eq!(r["connect_errors"], 0, "{r:#}");
    assert_eq!(r["errors"], 0, "errors: {}", r["error_messages"]);
    assert_eq!(r["viewers"], 200);
    // The drivers really drove and the light really followed.
    let final_version = r["final_version"].as_u64().expect("a final version");
    assert!(
        // Nominally 2 x 30 x 20 = 1200; a quarter leaves room for a
        // starved machine (missed ticks are skipped, not caught up).
        r["poses_sent"].as_u64().expect("poses") >= 2 * 30 * 20 / 4,
        "two drivers at 30 poses/s for 20 s: {}",
        r["poses_sent"]
    );
    assert!(
        final_version >= first_version + 10,
        "the moves produced new versions: {first_version} -> {final_version}"
    );
    assert!(
        r["latency"]["samples"].as_u64().expect("samples") >= 200 * 10,
        "every viewer measured deliveries: {}",
        r["latency"]
    );

    // Every viewer ended on the server's final version, bit for bit.
    assert_eq!(r["settled"], true, "{r:#}");
    assert_eq!(r["viewers_on_final_version"], 200);
    let viewers = r["viewer_final"].as_array().expect("viewer_final");
    assert_eq!(viewers.len(), 200);
    // The server agrees: that is its published version, and it stays so.
    assert_eq!(version(&server), final_version, "the server's own version");
    std::thread::sleep(Duration::from_millis(700));
    assert_eq!(version(&server), final_version, "the server is quiet");
    // A fresh client's keyframe of the server's state has the same texels.
    let fresh = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("runtime")
        .block_on(async {
            let c = lightwire_client::Client::connect(&server.url(""), None, Some("cornell-low"))
                .await
                .expect("connects");
            let frame = c
                .wait_for_version(final_version, Duration::from_secs(10))
                .await
                .expect("the keyframe");
            c.close().await;
            frame
        });
    assert_eq!(fresh.version(), final_version);
    let expected = format!("{:016x}", fresh.checksum());
    for (i, v) in viewers.iter().enumerate() {
        assert_eq!(v["version"], final_version, "viewer {i}");
        assert_eq!(
            v["checksum"].as_str(),
            Some(expected.as_str()),
            "viewer {i}'s lightmap differs from the server's version {final_version}"
        );
    }
}

#[test]
fn watch_drive_and_load_limits_as_a_user_sees_them() {
    // Bad input is refused before connecting, saying what and where.
    let dir = report_path("bad-script").with_extension("d");
    std::fs::create_dir_all(&dir).expect("dir");
    let bad = dir.join("bad.json");
    std::fs::write(&bad, "{ \"keyframes\": [ { \"t\": 0, \"scale\": 1 } ] }\n").expect("write");
    let stderr = client_exits(
        &[
            "drive",
            "http://127.0.0.1:9",
            "--scene",
            "x",
            "--script",
            bad.to_str().expect("utf-8"),
        ],
        2,
    );
    assert!(
        stderr.contains("bad.json: keyframes[0].translation"),
        "{stderr}"
    );
    let stderr = client_exits(&["watch", "http://127.0.0.1:9/api/scenes"], 2);
    assert!(
        stderr.contains("http://127.0.0.1:9/api/scenes") && stderr.contains("unexpected path"),
        "{stderr}"
    );

    let server = start_server();
    let url = server.url("");
    // watch: a line per interval with the version and the server's stats.
    let out = client(&[
        "watch",
        &url,
        "--scene",
        "cornell-low",
        "--every",
        "300ms",
        "--duration",
        "1s",
    ]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let line = stdout.lines().last().expect("a status line");
    assert!(
        line.starts_with(&format!("v{}", version(&server))) && line.contains("unshot"),
        "{line}"
    );

    // drive: moves the box, measures its own poses' latency, exits 0.
    let rotate = repo().join("scenes/scripts/rotate.json");
    let before = version(&server);
    let stderr = client_exits(
        &[
            "drive",
            &url,
            "--scene",
            "cornell-low",
            "--script",
            rotate.to_str().expect("utf-8"),
            "--duration",
            "1s",
        ],
        0,
    );
    assert!(
        stderr.contains("done: ") && stderr.contains("reached the light"),
        "{stderr}"
    );
    assert!(version(&server) > before, "driving produced new versions");

    // load: a missed limit is exit code 1 and says which.
    let report = report_path("missed-limit.json");
    let stderr = client_exits(
        &[
            "load",
            &url,
            "--scene",
            "cornell-low",
            "--script",
            rotate.to_str().expect("utf-8"),
            "--viewers",
            "2",
            "--drivers",
            "1",
            "--duration",
            "1s",
            "--quiet",
            "300ms",
            "--max-p99-ms",
            "0.001",
            "--report",
            report.to_str().expect("utf-8"),
        ],
        1,
    );
    assert!(stderr.contains("FAILED: p99 latency"), "{stderr}");
    let r: Value =
        serde_json::from_str(&std::fs::read_to_string(&report).expect("report")).expect("json");
    assert_eq!(r["passed"], false);
    assert_eq!(r["errors"], 0, "{r:#}");
}
