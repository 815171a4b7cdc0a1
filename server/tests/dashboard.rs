//! The web dashboard, in a real browser: `lightwire serve --dev` as a real
//! process on cornell-low (GPU solver, on lavapipe without a GPU), and
//! `server/dashboard/e2e/dashboard.e2e.mjs` driving Debian's headless
//! Chromium through Playwright against it. The script checks the page's
//! contracts (no console errors, WebSocket, chart, atlas, 3D view, the
//! scene's lights as gizmos, dragging the box changes the light, and on
//! cornell-point switching and dragging the bulb does too) and saves
//! screenshots to `target/dashboard-artifacts/`. It runs four times: on a
//! development server, on a development server of a triangle-mesh scene (a
//! `.glb`), on one of a scene lit by a point light (`cornell-point`, whose
//! gizmo must be drawn), and on a relay (of a solver with tokens) opened as
//! `/?token=<driver>`, where the page must present the token to the REST
//! API as well as to the WebSocket, and its drags go through the relay.
//!
//! Needs `node`, `chromium` and `npm ci` in `server/dashboard`; `make test`
//! provides all three. Without them this test fails and says what to
//! install: a dashboard that cannot be tested is not a passing one.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use lightwire_testkit::process::Proc;
use lightwire_testkit::{DRIVER_TOKEN, dashboard, lightwire, scene_path};

/// The browser test's own time limit (it is usually done in 15-40 s).
const E2E_TIMEOUT: Duration = Duration::from_secs(300);

/// `lightwire serve --dev` on `scenes/<scene>` on a free port, with extra
/// `serve` flags.
fn dev_server_on(scene: &str, flags: &[&str]) -> Proc {
    lightwire!().serve_dev_on(scene_path(scene), flags)
}

fn dashboard_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("dashboard")
}

/// `target/`, from the path of the binary under test (`target/<profile>/lightwire`).
fn target_dir() -> PathBuf {
    lightwire!().target_dir()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_embedded_files_are_served_and_nothing_else() {
    // No need for the GPU here: the cheap reference solver on a coarse atlas.
    let server = lightwire!().dev_solver();
    dashboard::assert_served(&server.addr).await;
}

/// Runs `dashboard.e2e.mjs` against the page at `url` with `flags` and
/// checks that it passed and left its screenshots in `artifacts`.
fn run_e2e(url: &str, artifacts: &Path, flags: &[&str]) {
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
    let started = Instant::now();
    let mut node = Command::new("node")
        .current_dir(&dir)
        .arg("e2e/dashboard.e2e.mjs")
        .arg("--url")
        .arg(url)
        .arg("--artifacts")
        .arg(artifacts)
        .arg("--chromium")
        .arg(&chromium)
        .args(flags)
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

#[test]
fn the_dashboard_works_in_headless_chromium() {
    let server = dev_server_on("cornell-low.json", &[]);
    run_e2e(
        &format!("http://{}/", server.addr),
        &target_dir().join("dashboard-artifacts"),
        &[],
    );
}

/// A triangle-mesh scene opened from its `.glb` (its dynamic box a glTF
/// node): the 3D view draws the triangles, and dragging the box relights
/// the room, as on the quad scenes.
#[test]
fn the_dashboard_works_on_a_mesh_scene() {
    let server = dev_server_on("meshes/cornell-dynamic.glb", &["--density-scale", "0.35"]);
    run_e2e(
        &format!("http://{}/", server.addr),
        &target_dir().join("dashboard-artifacts/mesh"),
        &[],
    );
}

/// A scene lit by a point light (`cornell-point`): the page fetches the
/// scene's lights (`GET /api/scenes/{id}/lights`) and draws them as
/// gizmos, which its `lights` box hides; it switches the bulb off and on
/// in the Lights panel, and drags the bulb's gizmo towards the red wall,
/// which then brightens against the green one; besides everything above.
#[test]
fn the_dashboard_draws_the_scenes_lights() {
    let server = dev_server_on("cornell-point.json", &["--density-scale", "0.5"]);
    run_e2e(
        &format!("http://{}/", server.addr),
        &target_dir().join("dashboard-artifacts/lights"),
        &["--expect-lights"],
    );
}

/// The page on a relay, with tokens configured: the token in the page's
/// URL goes to the REST list and the WebSocket alike, and a driver's drag
/// goes through the relay to the solver and back.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_dashboard_works_on_a_relay_with_a_token() {
    let solver = lightwire!().solver("127.0.0.1:0");
    let relay = lightwire!().relay(&solver.addr);
    relay.ready().await;
    let url = format!("http://{}/?token={DRIVER_TOKEN}", relay.addr);
    let artifacts = target_dir().join("dashboard-artifacts/relay");
    tokio::task::spawn_blocking(move || run_e2e(&url, &artifacts, &[]))
        .await
        .expect("the browser test ran");
}
