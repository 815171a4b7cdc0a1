//! The three.js example (`server/dashboard/src/examples/threejs/`): a stock
//! engine draws the stream. Its files are served at `/examples/threejs/`
//! under their own Content-Security-Policy, and in a real browser
//! (`server/dashboard/e2e/threejs.e2e.mjs`, headless Chromium through
//! Playwright, WebGL2 on SwiftShader) `lightwire serve --dev` on
//! cornell-large (GPU solver, lavapipe without a GPU) is drawn lit by the
//! stream, not black and not the placeholder, moving the box changes the
//! picture, and nothing logs a console error. Screenshots land in
//! `target/threejs-artifacts/`. The garage level's run of the same script
//! is in `levels.rs` (`make test-levels`).
//!
//! Needs `node`, `chromium` and `npm ci` in `server/dashboard`; `make test`
//! provides all three. Without them this test fails and says what to
//! install.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use lightwire_testkit::{http, lightwire, scene_path};

/// The browser test's own time limit (it is usually done in 10-30 s).
const E2E_TIMEOUT: Duration = Duration::from_secs(300);

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_example_is_served_with_its_policy_and_nothing_else() {
    // No GPU needed: the files hold no data.
    let server = lightwire!().dev_solver();
    for path in ["/examples/threejs/", "/examples/threejs"] {
        let page = http::get(&server.addr, path, None).await;
        assert_eq!(page.status, 200, "{path}");
        assert!(
            page.header("content-type")
                .is_some_and(|t| t.starts_with("text/html")),
            "{path}: {:?}",
            page.headers
        );
        let csp = page.header("content-security-policy").unwrap_or_default();
        assert!(
            csp.starts_with("default-src 'self'; script-src 'self' 'sha256-")
                && !csp.contains("unsafe"),
            "{path}: {csp}"
        );
        let text = page.text();
        assert!(text.contains("<script type=\"importmap\">"), "{text}");
        assert!(text.contains("src=\"/examples/threejs/main.js\""), "{text}");
    }
    for (path, mime) in [
        ("/examples/threejs/main.js", "text/javascript"),
        ("/examples/threejs/style.css", "text/css"),
        (
            "/dashboard/vendor/three/build/three.module.js",
            "text/javascript",
        ),
        (
            "/dashboard/vendor/three/build/three.core.js",
            "text/javascript",
        ),
        (
            "/dashboard/vendor/three/examples/jsm/loaders/GLTFLoader.js",
            "text/javascript",
        ),
        (
            "/dashboard/vendor/three/examples/jsm/controls/OrbitControls.js",
            "text/javascript",
        ),
        ("/dashboard/vendor/three/LICENSE", "text/plain"),
    ] {
        let r = http::get(&server.addr, path, None).await;
        assert_eq!(r.status, 200, "{path}");
        assert!(
            r.header("content-type")
                .is_some_and(|t| t.starts_with(mime)),
            "{path}: {:?}",
            r.headers
        );
    }
    for missing in [
        "/examples/threejs/nope.js",
        "/examples/threejs/../../Cargo.toml",
        "/examples/other/",
    ] {
        let r = http::get(&server.addr, missing, None).await;
        assert_eq!(r.status, 404, "{missing}");
    }
}

/// Runs `threejs.e2e.mjs` on the page at `url` (moving the dynamic object
/// by `movement`: "DX,DY,DZ,YAW_DEGREES") and checks that it passed and
/// left its three screenshots, `<name>-*.png`, in `artifacts`.
fn run_e2e(url: &str, name: &str, movement: &str, artifacts: &Path) {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("dashboard");
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
    let started = Instant::now();
    let mut node = Command::new("node")
        .current_dir(&dir)
        .arg("e2e/threejs.e2e.mjs")
        .args(["--url", url, "--name", name, "--move", movement])
        .arg("--artifacts")
        .arg(artifacts)
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
    assert!(
        status.success(),
        "the three.js example's browser test failed ({status}); see its output above and the screenshots in {}",
        artifacts.display()
    );
    for shot in ["placeholder", "lit", "moved"] {
        let path = artifacts.join(format!("{name}-{shot}.png"));
        let size = std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0);
        assert!(
            size > 1_000,
            "screenshot {} is missing or empty",
            path.display()
        );
    }
}

#[test]
fn three_js_draws_the_stream_and_follows_a_move() {
    let server = lightwire!().serve_dev_on(scene_path("cornell-large.json"), &[]);
    server.wait_ready();
    // The box, 0.8 m towards the green wall and turned by 30°: inside the room.
    run_e2e(
        &server.url("/examples/threejs/?scene=cornell-large"),
        "cornell-large",
        "0.8,0,0,30",
        &lightwire!().target_dir().join("threejs-artifacts"),
    );
}
