//! The web dashboard, in a real browser: `lightwire serve --dev` as a real
//! process on cornell-low (GPU solver, on lavapipe without a GPU), and
//! `server/dashboard/e2e/dashboard.e2e.mjs` driving Debian's headless
//! Chromium through Playwright against it. The script checks the page's
//! contracts (no console errors, WebSocket, chart, atlas, 3D view, dragging
//! the box changes the light) and saves screenshots to
//! `target/dashboard-artifacts/`.
//!
//! Needs `node`, `chromium` and `npm ci` in `server/dashboard`; `make test`
//! provides all three. Without them this test fails and says what to
//! install: a dashboard that cannot be tested is not a passing one.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// The browser test's own time limit (it is usually done in 15-40 s).
const E2E_TIMEOUT: Duration = Duration::from_secs(300);

/// A `lightwire serve` child process, killed on drop.
struct Server {
    child: Child,
    addr: String,
}

impl Server {
    /// Serves cornell-low in development mode on a free port, with extra
    /// `serve` flags.
    fn start(flags: &[&str]) -> Server {
        let scene = dashboard_dir().join("../../scenes/cornell-low.json");
        let mut child = Command::new(env!("CARGO_BIN_EXE_lightwire"))
            .args(["serve", "--dev", "--listen", "127.0.0.1:0"])
            .args(flags)
            .arg("--scene")
            .arg(&scene)
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
        Server { child, addr }
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn dashboard_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("dashboard")
}

/// `target/`, from the path of the binary under test (`target/<profile>/lightwire`).
fn target_dir() -> PathBuf {
    Path::new(env!("CARGO_BIN_EXE_lightwire"))
        .parent()
        .and_then(Path::parent)
        .expect("the binary lives in target/<profile>/")
        .to_path_buf()
}

/// A minimal HTTP/1.1 GET: status line and headers, lowercased, and the body.
fn get(addr: &str, path: &str) -> (String, String) {
    let mut stream = TcpStream::connect(addr).expect("connect");
    stream
        .set_read_timeout(Some(Duration::from_secs(10)))
        .expect("timeout");
    write!(
        stream,
        "GET {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n"
    )
    .expect("send");
    let mut response = String::new();
    stream.read_to_string(&mut response).expect("read");
    let (head, body) = response.split_once("\r\n\r\n").expect("headers end");
    (head.to_ascii_lowercase(), body.to_string())
}

#[test]
fn the_embedded_files_are_served_and_nothing_else() {
    // No need for the GPU here: the cheap reference solver on a coarse atlas.
    let server = Server::start(&["--solver", "reference", "--density-scale", "0.5"]);
    let (head, body) = get(&server.addr, "/");
    assert!(head.starts_with("http/1.1 200"), "{head}");
    assert!(head.contains("content-type: text/html"), "{head}");
    assert!(
        head.contains("content-security-policy: default-src 'self'"),
        "{head}"
    );
    assert!(body.contains("<script type=\"module\" src=\"/dashboard/app.js\">"));
    for file in [
        "app.js",
        "protocol.js",
        "lightmap.js",
        "view3d.js",
        "chart.js",
        "vendor/fzstd.js",
    ] {
        let (head, _) = get(&server.addr, &format!("/dashboard/{file}"));
        assert!(head.starts_with("http/1.1 200"), "{file}: {head}");
        assert!(
            head.contains("content-type: text/javascript"),
            "{file}: {head}"
        );
    }
    for missing in ["/dashboard/nope.js", "/dashboard/../Cargo.toml"] {
        let (head, _) = get(&server.addr, missing);
        assert!(head.starts_with("http/1.1 404"), "{missing}: {head}");
    }
}

#[test]
fn the_dashboard_works_in_headless_chromium() {
    let dir = dashboard_dir();
    let chromium = std::env::var("CHROMIUM").unwrap_or_else(|_| "/usr/bin/chromium".into());
    assert!(
        Path::new(&chromium).exists(),
        "no Chromium at {chromium}: install the Debian package `chromium` (make test does)"
    );
    assert!(
        dir.join("node_modules/playwright-core").is_dir(),
        "{} has no node_modules/playwright-core: run `npm ci` there (make test does)",
        dir.display()
    );
    let artifacts = target_dir().join("dashboard-artifacts");
    let server = Server::start(&[]);
    let started = Instant::now();
    let mut node = Command::new("node")
        .current_dir(&dir)
        .arg("e2e/dashboard.e2e.mjs")
        .arg("--url")
        .arg(format!("http://{}/", server.addr))
        .arg("--artifacts")
        .arg(&artifacts)
        .arg("--chromium")
        .arg(&chromium)
        .stdout(Stdio::inherit())
        .stderr(Stdio::inherit())
        .spawn()
        .unwrap_or_else(|e| panic!("cannot run node (install nodejs; make test does): {e}"));
    let status = loop {
        if let Some(status) = node.try_wait().expect("wait for node") {
            break status;
        }
        if started.elapsed() > E2E_TIMEOUT {
            let _ = node.kill();
            let _ = node.wait();
            panic!("the browser test did not finish within {E2E_TIMEOUT:?}");
        }
        std::thread::sleep(Duration::from_millis(200));
    };
    drop(server);
    assert!(
        status.success(),
        "the dashboard's browser test failed ({status}); see its output above and the screenshots in {}",
        artifacts.display()
    );
    for shot in ["dashboard-before.png", "dashboard-after.png"] {
        let path = artifacts.join(shot);
        let size = std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0);
        assert!(
            size > 10_000,
            "screenshot {} is missing or empty",
            path.display()
        );
    }
}
