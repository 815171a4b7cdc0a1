//! `lightwire-client` as a user runs it, against a real `lightwire serve`
//! process on loopback.
//!
//! The server binary: Cargo hands a test the paths of its own package's
//! binaries only (`CARGO_BIN_EXE_lightwire-client` here), so the test asks
//! Cargo to make sure the workspace's binaries are built, with the same
//! profile and target directory, and runs `target/<profile>/lightwire`
//! (see [`lightwire_binary`]): a no-op under `cargo test --workspace`, a
//! build when this test runs alone, and never a stale binary.
//! ARCHITECTURE.md explains the choice.
//!
//! The server runs in development mode on cornell-low at a fifth of its
//! texel density with the CPU reference solver at 3 ticks per second: a
//! re-solve per tick while the box moves, no GPU start-up, a few CPU
//! seconds in all (the machine running CI has two cores).

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use serde_json::Value;

/// The `lightwire` server binary, fresh, next to ours.
///
/// Runs `cargo test --workspace --no-run` with our profile and target
/// directory: under `make test` (`cargo test --workspace`) that is a no-op
/// check, because the outer run already built every binary with exactly
/// these features; run alone, it builds what is missing or stale. A plain
/// `cargo build -p lightwire-server` would not do: dev-dependencies of other
/// members change the unified features of shared crates (wgpu's among
/// them), so it would compile a second copy of half the dependency graph.
fn lightwire_binary() -> &'static Path {
    static BINARY: OnceLock<PathBuf> = OnceLock::new();
    BINARY.get_or_init(|| {
        let ours = Path::new(env!("CARGO_BIN_EXE_lightwire-client"));
        let profile_dir = ours.parent().expect("target/<profile>/");
        let target_dir = profile_dir.parent().expect("target/");
        let profile: &[&str] = match profile_dir.file_name().and_then(|p| p.to_str()) {
            Some("debug") => &[],
            Some("release") => &["--release"],
            Some(other) => &["--profile", other],
            None => panic!("unexpected binary path {}", ours.display()),
        };
        let cargo = std::env::var("CARGO").unwrap_or_else(|_| env!("CARGO").to_string());
        let manifest = Path::new(env!("CARGO_MANIFEST_DIR")).join("../Cargo.toml");
        let status = Command::new(cargo)
            .args(["test", "--workspace", "--no-run", "--quiet"])
            .args(profile)
            .arg("--manifest-path")
            .arg(&manifest)
            .arg("--target-dir")
            .arg(target_dir)
            .status()
            .expect("cargo runs");
        assert!(status.success(), "building the workspace's binaries failed");
        let binary = profile_dir.join(format!("lightwire{}", std::env::consts::EXE_SUFFIX));
        assert!(binary.exists(), "{} was not built", binary.display());
        binary
    })
}

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// A `lightwire serve --dev` child process, killed on drop.
struct Server {
    child: Child,
    addr: String,
}

impl Server {
    fn start() -> Server {
        let mut child = Command::new(lightwire_binary())
            .args(["serve", "--dev", "--listen", "127.0.0.1:0"])
            .args(["--solver", "reference", "--density-scale", "0.2"])
            .args(["--tick-hz", "3", "--scene"])
            .arg(repo().join("scenes/cornell-low.json"))
            .env("RUST_LOG", "warn")
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("lightwire starts");
        let stdout = child.stdout.take().expect("piped stdout");
        let mut lines = BufReader::new(stdout).lines();
        let addr = loop {
            let line = lines
                .next()
                .expect("the server prints its address before exiting")
                .expect("stdout is UTF-8");
            if let Some(rest) = line.strip_prefix("lightwire listening on http://") {
                break rest
                    .split_whitespace()
                    .next()
                    .expect("an address")
                    .to_string();
            }
        };
        // Keep draining stdout so the server never blocks on a full pipe.
        std::thread::spawn(move || for _ in lines {});
        let server = Server { child, addr };
        let deadline = Instant::now() + Duration::from_secs(60);
        while server.get("/readyz").0 != 200 {
            assert!(Instant::now() < deadline, "the server never became ready");
            std::thread::sleep(Duration::from_millis(50));
        }
        server
    }

    fn url(&self) -> String {
        format!("http://{}", self.addr)
    }

    /// A minimal blocking HTTP/1.1 GET: status and body.
    fn get(&self, path: &str) -> (u16, Vec<u8>) {
        let mut stream = TcpStream::connect(&self.addr).expect("connect");
        write!(
            stream,
            "GET {path} HTTP/1.1\r\nHost: {}\r\nConnection: close\r\n\r\n",
            self.addr
        )
        .expect("send");
        let mut response = Vec::new();
        stream.read_to_end(&mut response).expect("read");
        let split = response
            .windows(4)
            .position(|w| w == b"\r\n\r\n")
            .expect("headers end");
        let status = String::from_utf8_lossy(&response[..split])
            .split_whitespace()
            .nth(1)
            .and_then(|c| c.parse().ok())
            .expect("status");
        (status, response[split + 4..].to_vec())
    }

    /// The published version, from `GET /api/scenes`.
    fn version(&self) -> u64 {
        let (status, body) = self.get("/api/scenes");
        assert_eq!(status, 200);
        let scenes: Value = serde_json::from_slice(&body).expect("json");
        scenes[0]["version"].as_u64().expect("version")
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn client(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_lightwire-client"))
        .args(args)
        .env_remove("LIGHTWIRE_TOKEN")
        .output()
        .expect("lightwire-client runs")
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
    let server = Server::start();
    let first_version = server.version();
    let report = report_path("two-hundred-viewers.json");
    let orbit = repo().join("scenes/scripts/orbit.json");
    let started = Instant::now();
    let out = client(&[
        "load",
        &server.url(),
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
    assert_eq!(server.version(), final_version, "the server's own version");
    std::thread::sleep(Duration::from_millis(700));
    assert_eq!(server.version(), final_version, "the server is quiet");
    // A fresh client's keyframe of the server's state has the same texels.
    let fresh = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("runtime")
        .block_on(async {
            let c = lightwire_client::Client::connect(&server.url(), None, Some("cornell-low"))
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
    let out = client(&[
        "drive",
        "http://127.0.0.1:9",
        "--scene",
        "x",
        "--script",
        bad.to_str().expect("utf-8"),
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("bad.json: keyframes[0].translation"),
        "{stderr}"
    );
    let out = client(&["watch", "http://127.0.0.1:9/api/scenes"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("http://127.0.0.1:9/api/scenes") && stderr.contains("unexpected path"),
        "{stderr}"
    );

    let server = Server::start();
    let url = server.url();
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
        line.starts_with(&format!("v{}", server.version())) && line.contains("unshot"),
        "{line}"
    );

    // drive: moves the box, measures its own poses' latency, exits 0.
    let rotate = repo().join("scenes/scripts/rotate.json");
    let before = server.version();
    let out = client(&[
        "drive",
        &url,
        "--scene",
        "cornell-low",
        "--script",
        rotate.to_str().expect("utf-8"),
        "--duration",
        "1s",
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(
        stderr.contains("done: ") && stderr.contains("reached the light"),
        "{stderr}"
    );
    assert!(server.version() > before, "driving produced new versions");

    // load: a missed limit is exit code 1 and says which.
    let report = report_path("missed-limit.json");
    let out = client(&[
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
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("FAILED: p99 latency"), "{stderr}");
    let r: Value =
        serde_json::from_str(&std::fs::read_to_string(&report).expect("report")).expect("json");
    assert_eq!(r["passed"], false);
    assert_eq!(r["errors"], 0, "{r:#}");
}
