//! A GPU solver failure over real sockets: `lightwire serve --solver
//! progressive` as a real process, its device destroyed by the test hook
//! `LIGHTWIRE_TEST_FAIL_SOLVER` (the same path as a lost device: the
//! device-lost callback, then the tick loop's failure handling).
//!
//! What must hold: `/readyz` answers 503 naming the scene and the reason,
//! the failure is counted in `/metrics`, logged once (not once per tick),
//! viewers stay connected on the last version (and a new viewer gets it as
//! a keyframe), and the solver is rebuilt: `/readyz` is 200 again, versions
//! continue as deltas onto the exact base, and a transform sent during the
//! failure is reflected.

use std::time::{Duration, Instant};

use lightwire_protocol::{Pose, Role};

use lightwire_testkit::peer::Peer;
use lightwire_testkit::pose::box_turned;
use lightwire_testkit::process::Proc;
use lightwire_testkit::{DRIVER_TOKEN, VIEWER_TOKEN, http, lightwire};

/// The transform seq at which the hook destroys the device.
const FAIL_AT: u64 = 1000;
/// The transform seq that lets the rebuild happen (sent during the
/// failure, so it must be reflected after it).
const REBUILD_AT: u64 = 2000;
/// The dynamic box of cornell-low.
const BOX: u32 = 1;

/// The solver under test: `lightwire serve --solver progressive` with the
/// failure hook, its stderr collected.
struct Server {
    proc: Proc,
}

impl Server {
    fn start() -> Server {
        let env = [
            (
                "LIGHTWIRE_TEST_FAIL_SOLVER",
                // The first rebuild attempt fails too, so that the rebuild
                // backs off once before it succeeds.
                format!("at_seq:{FAIL_AT},rebuild_at_seq:{REBUILD_AT},rebuild_fails:1"),
            ),
            ("RUST_LOG", "info".to_string()),
            ("NO_COLOR", "1".to_string()),
        ];
        Server {
            proc: lightwire!().solver_with("127.0.0.1:0", "progressive", &env),
        }
    }

    fn ws_url(&self) -> String {
        self.proc.ws_url()
    }

    /// Lines of stderr so far that contain every one of `words`.
    fn log_lines(&self, words: &[&str]) -> Vec<String> {
        self.proc.stderr_lines(words)
    }

    async fn get(&self, path: &str) -> http::Response {
        http::get(&self.proc.addr, path, Some(VIEWER_TOKEN)).await
    }

    async fn readyz(&self) -> (u16, Option<serde_json::Value>) {
        let r = self.get("/readyz").await;
        (r.status, serde_json::from_slice(&r.body).ok())
    }

    /// Checks that `/metrics` gives the scene each `(name, value)` of
    /// `expected`.
    async fn assert_metrics(&self, expected: &[(&str, f64)]) {
        let r = self.get("/metrics").await;
        assert_eq!(r.status, 200);
        let metrics = r.text();
        for &(name, value) in expected {
            assert_eq!(metric(&metrics, name), Some(value), "{name}: {metrics}");
        }
    }

    /// The scene's current version, from `/api/scenes`.
    async fn version(&self) -> u64 {
        let r = self.get("/api/scenes").await;
        assert_eq!(r.status, 200, "{}", r.text());
        r.json()[0]["version"].as_u64().expect("version")
    }
}

fn pose_at(step: u32) -> Pose {
    box_turned(step as f32 * 0.3)
}

/// Keeps `clients` read while waiting, up to `limit`, for `done` to say
/// yes about the server.
async fn wait_for<F, Fut>(what: &str, limit: Duration, clients: &mut [&mut Peer], mut done: F)
where
    F: FnMut() -> Fut,
    Fut: std::future::Future<Output = bool>,
{
    let deadline = Instant::now() + limit;
    while !done().await {
        assert!(Instant::now() < deadline, "timed out waiting for {what}");
        for c in clients.iter_mut() {
            c.pump(Duration::from_millis(20)).await;
        }
    }
}

fn metric(text: &str, name: &str) -> Option<f64> {
    let prefix = format!("{name}{{scene=\"cornell-low\"}} ");
    text.lines()
        .find_map(|l| l.strip_prefix(&prefix))
        .and_then(|v| v.trim().parse().ok())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_lost_device_is_reported_served_through_and_rebuilt() {
    let server = Server::start();
    let generous = Duration::from_secs(120);
    wait_for("the first version", generous, &mut [], || async {
        server.readyz().await.0 == 200
    })
    .await;
    server
        .assert_metrics(&[
            ("lightwire_scene_ready", 1.0),
            ("lightwire_solver_failures_total", 0.0),
        ])
        .await;

    let mut viewer = Peer::connect(&server.ws_url(), VIEWER_TOKEN).await;
    assert_eq!(viewer.role, Some(Role::Viewer));
    let mut driver = Peer::connect(&server.ws_url(), DRIVER_TOKEN).await;
    assert_eq!(driver.role, Some(Role::Driver));
    // A viewer of a ready scene gets a version.
    viewer.pump_until_version(1, generous).await;
    // Left alone, the solver refines and corrects, then has nothing to do.
    wait_for(
        "the solver to be idle",
        generous,
        &mut [&mut viewer],
        || async {
            let r = server.get("/metrics").await;
            metric(&r.text(), "lightwire_solver_idle") == Some(1.0)
        },
    )
    .await;

    // The transform that makes the hook destroy the device.
    driver.transform(BOX, FAIL_AT, pose_at(1)).await;
    let deadline = Instant::now() + generous;
    let failed = loop {
        let (status, body) = server.readyz().await;
        if let Some(body) = body.filter(|_| status == 503) {
            if body["failed"].as_array().is_some_and(|f| !f.is_empty()) {
                break body;
            }
        }
        assert!(
            Instant::now() < deadline,
            "/readyz never reported the failure (last: {status})"
        );
        viewer.pump(Duration::from_millis(20)).await;
        driver.pump(Duration::from_millis(20)).await;
    };
    assert_eq!(failed["ready"], false, "{failed}");
    let failures = failed["failed"].as_array().expect("failed is a list");
    assert_eq!(failures.len(), 1, "{failed}");
    assert_eq!(failures[0]["scene"], "cornell-low", "{failed}");
    let reason = failures[0]["reason"].as_str().expect("a reason");
    assert!(
        reason.contains("device lost"),
        "the reason names the lost device: {failed}"
    );
    assert!(failures[0]["since_unix_ms"].as_u64().is_some(), "{failed}");
    assert_eq!(failed["solving"], serde_json::json!([]), "{failed}");

    server
        .assert_metrics(&[
            ("lightwire_solver_failures_total", 1.0),
            ("lightwire_scene_ready", 0.0),
            ("lightwire_solver_idle", 0.0),
        ])
        .await;

    // The failed scene keeps serving its last version: the viewer reaches
    // it and nothing newer comes, for many ticks (the hook holds the
    // rebuild until seq REBUILD_AT).
    let last = server.version().await;
    viewer.pump_until_version(last, generous).await;
    viewer.pump(Duration::from_secs(2)).await;
    driver.pump(Duration::from_millis(100)).await;
    assert_eq!(viewer.version(), last, "no version while failed");
    assert_eq!(server.version().await, last);
    assert_eq!(
        server.readyz().await.0,
        503,
        "still failed while the rebuild is held"
    );
    // A viewer joining now gets the last version as a keyframe, the same
    // bits.
    let mut late = Peer::connect(&server.ws_url(), VIEWER_TOKEN).await;
    late.pump_until_version(1, generous).await;
    assert_eq!(
        late.applied,
        vec![(last, true)],
        "a keyframe of the last version"
    );
    assert_eq!(late.texels(), viewer.texels(), "the same lightmap");

    // A transform accepted during the failure; it also releases the hook's
    // hold on the rebuild.
    driver.transform(BOX, REBUILD_AT, pose_at(2)).await;
    wait_for(
        "/readyz to be 200 again",
        generous,
        &mut [&mut viewer, &mut driver, &mut late],
        || async { server.readyz().await.0 == 200 },
    )
    .await;
    let deadline = Instant::now() + generous;
    while viewer.reflected.get(&BOX) != Some(&REBUILD_AT) {
        assert!(
            Instant::now() < deadline,
            "the transform sent during the failure was never reflected (viewer at {}, reflected {:?})",
            viewer.version(),
            viewer.reflected
        );
        viewer.pump(Duration::from_millis(50)).await;
        driver.pump(Duration::from_millis(10)).await;
        late.pump(Duration::from_millis(10)).await;
    }
    // Versions kept increasing across the rebuild, the first one after it
    // a delta onto the exact last version (every delta was checked
    // against its base when applied).
    assert!(viewer.version() > last);
    assert!(
        viewer.applied.windows(2).all(|w| w[0].0 < w[1].0),
        "versions only increase: {:?}",
        viewer.applied
    );
    let after = viewer
        .applied
        .iter()
        .position(|&(v, _)| v == last)
        .expect("the viewer held the last version");
    assert_eq!(
        viewer.applied.get(after + 1).map(|&(_, keyframe)| keyframe),
        Some(false),
        "the rebuilt solver's first version is a delta onto the last one: {:?}",
        viewer.applied
    );
    assert!(
        viewer.errors.is_empty() && driver.errors.is_empty(),
        "{:?} {:?}",
        viewer.errors,
        driver.errors
    );

    server
        .assert_metrics(&[
            ("lightwire_scene_ready", 1.0),
            ("lightwire_solver_failures_total", 1.0),
            // The first rebuild failed (the hook), the second, after
            // its backoff, succeeded.
            ("lightwire_solver_rebuilds_total", 2.0),
        ])
        .await;
    assert_eq!(
        server
            .log_lines(&["WARN", "rebuilding the solver failed", "next try in 1s"])
            .len(),
        1
    );

    // One error line for the whole episode, though it lasted many ticks
    // (the service's own lines: wgpu's adapter probing logs errors of its
    // own about GL drivers on every device creation).
    let errors = server.log_lines(&["ERROR lightwire"]);
    assert_eq!(errors.len(), 1, "one error line: {errors:#?}");
    assert!(
        errors[0].contains("solver failed") && errors[0].contains("cornell-low"),
        "{errors:?}"
    );
    assert_eq!(
        server.log_lines(&["solver recovered", "attempts=2"]).len(),
        1
    );
    assert!(server.log_lines(&["panicked"]).is_empty(), "no panic");
}

/// The device side on its own: the error scopes catch a validation error,
/// an error outside them is recorded instead of panicking, and a destroyed
/// device reports itself lost.
#[test]
fn device_errors_are_captured_recorded_and_lost_is_seen() {
    let gpu = lightwire_solve::gpu::Device::new(None).expect("a GPU adapter (lavapipe)");
    gpu.record_uncaptured_errors();
    // MAP_READ may only be combined with COPY_DST: a validation error.
    let bad = wgpu::BufferDescriptor {
        label: Some("invalid on purpose"),
        size: 16,
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::STORAGE,
        mapped_at_creation: false,
    };
    let (_, caught) = gpu.capture(|| gpu.device.create_buffer(&bad));
    let caught = caught.expect("the scope catches the validation error");
    assert!(caught.contains("invalid on purpose"), "{caught}");
    assert_eq!(
        gpu.failure(),
        None,
        "a caught error is not a device failure"
    );

    let _ = gpu.device.create_buffer(&bad);
    let uncaptured = gpu.failure().expect("recorded, not panicked on");
    assert!(uncaptured.contains("invalid on purpose"), "{uncaptured}");

    let fresh = lightwire_solve::gpu::Device::new(None).expect("a second device");
    assert_eq!(fresh.failure(), None);
    fresh.device.destroy();
    let _ = fresh.device.poll(wgpu::PollType::Poll);
    let lost = fresh.failure().expect("the device-lost callback ran");
    assert!(lost.contains("device lost"), "{lost}");
}
