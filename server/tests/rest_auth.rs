//! The REST routes follow the WebSocket's roles (PROTOCOL.md §7, REST), on
//! a real `lightwire serve` over real sockets:
//!
//! - with tokens configured, the scene list, scene info, both
//!   snapshots, the lit `scene.glb` and the lights answer 401 (a JSON `error` naming what is missing, and
//!   `WWW-Authenticate: Bearer`) without a token or with an unknown one,
//!   and 200 with a viewer token as `Authorization: Bearer` or `?token=`;
//! - a foreign browser `Origin` gets 403 even with a good token; the
//!   server's own origin is fine;
//! - `/healthz` and `/readyz` stay open; `/metrics` is open by default and
//!   needs an admin token with `metrics = "token"`;
//! - in development mode (no tokens) the REST routes are open;
//! - the `Welcome` announces `scene.glb` (`CAP_SCENE_GLB`), and the path
//!   the protocol crate builds from the scene id answers with the glb.

use lightwire_testkit::http::{self, Response};
use lightwire_testkit::{
    ADMIN_TOKEN, DRIVER_TOKEN, SCENE, VIEWER_TOKEN, lightwire, scene_file, viewer_routes,
};

fn assert_unauthorized(r: &Response, route: &str, what: &str) {
    assert_eq!(r.status, 401, "{route}: {}", r.text());
    assert_eq!(
        r.header("www-authenticate"),
        Some("Bearer realm=\"lightwire\""),
        "{route}"
    );
    let error = r.json()["error"].as_str().unwrap_or_default().to_string();
    assert!(
        error.contains(what) && error.contains("Authorization: Bearer"),
        "{route}: the 401 says what is missing and how to send it: {error:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn scene_routes_need_a_viewer_token_and_an_allowed_origin() {
    let server = lightwire!().solver("127.0.0.1:0");
    let addr = server.addr.as_str();
    server.ready().await;

    for route in viewer_routes() {
        let none = http::get(addr, &route, None).await;
        assert_unauthorized(&none, &route, "missing token");
        let unknown = http::get(addr, &route, Some("not-a-token-at-all")).await;
        assert_unauthorized(&unknown, &route, "unknown token");
        let wrong_query = http::get(addr, &format!("{route}?token=nope-nope-nope"), None).await;
        assert_unauthorized(&wrong_query, &route, "unknown token");

        for token in [VIEWER_TOKEN, DRIVER_TOKEN, ADMIN_TOKEN] {
            let header = http::get(addr, &route, Some(token)).await;
            assert_eq!(header.status, 200, "{route} with a Bearer token");
            let query = http::get(addr, &format!("{route}?token={token}"), None).await;
            assert_eq!(query.status, 200, "{route}?token=");
            assert_eq!(
                header.header("content-type"),
                query.header("content-type"),
                "{route}: the same answer either way"
            );
        }

        // The WebSocket's Origin rule: a foreign origin is refused even
        // with a good token, the server's own is not.
        let foreign =
            http::get_from(addr, &route, Some(VIEWER_TOKEN), "https://evil.example").await;
        assert_eq!(foreign.status, 403, "{route}");
        let error = foreign.json()["error"]
            .as_str()
            .unwrap_or_default()
            .to_string();
        assert!(error.contains("evil.example"), "{route}: {error:?}");
        let own = format!("http://{addr}");
        let same = http::get_from(addr, &route, Some(VIEWER_TOKEN), &own).await;
        assert_eq!(same.status, 200, "{route} from the server's own origin");
    }

    // What the 200s carry.
    let list = http::get(addr, "/api/scenes", Some(VIEWER_TOKEN))
        .await
        .json();
    assert_eq!(list[0]["id"], SCENE);
    let info = http::get(addr, &format!("/api/scenes/{SCENE}"), Some(VIEWER_TOKEN))
        .await
        .json();
    assert_eq!(info["id"], SCENE);
    let exr = http::get(addr, &scene_file("lightmap.exr"), Some(VIEWER_TOKEN)).await;
    assert_eq!(exr.header("content-type"), Some("image/x-exr"));
    assert!(exr.version().is_some());
    // The lit scene: a glb that imports, one triangle per triangle surface
    // and two per quad of the scene info, the version in its extras.
    let glb = http::get(addr, &scene_file("scene.glb"), Some(VIEWER_TOKEN)).await;
    assert_eq!(glb.header("content-type"), Some("model/gltf-binary"));
    let version = glb.version().expect("x-lightwire-version");
    let imported =
        lightwire_scene::gltf::import_slice(&glb.body, None, "scene.glb", &Default::default())
            .expect("the served scene.glb imports");
    let surfaces = info["surfaces"].as_array().expect("surfaces");
    let triangles: usize = surfaces
        .iter()
        .map(|s| {
            if s["corners"][2] == s["corners"][3] {
                1
            } else {
                2
            }
        })
        .sum();
    assert_eq!(imported.triangle_count(), triangles);
    let dynamic = info["objects"]
        .as_array()
        .expect("objects")
        .iter()
        .filter(|o| o["dynamic"] == true)
        .count();
    assert_eq!(imported.objects.len(), 1 + dynamic);
    let document = gltf::Gltf::from_slice(&glb.body).expect("parses");
    let extras = serde_json::to_value(&document.as_json().asset.extras).expect("JSON");
    assert_eq!(extras["lightwire"]["version"], version);
    assert_eq!(extras["lightwire"]["lightmap"], "lightmap.exr");

    // Open: health, readiness, the dashboard's files, and by default the
    // metrics.
    for open in ["/healthz", "/readyz", "/", "/dashboard/app.js", "/metrics"] {
        let r = http::get(addr, open, None).await;
        assert_eq!(r.status, 200, "{open} without a token");
    }
    assert!(
        http::get(addr, "/metrics", None)
            .await
            .text()
            .contains("# EOF"),
        "metrics are served"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn metrics_token_mode_needs_an_admin_token() {
    let server = lightwire!().solver_with(
        "127.0.0.1:0",
        "reference",
        &[("LIGHTWIRE_METRICS", "token".into())],
    );
    let addr = server.addr.as_str();
    let none = http::get(addr, "/metrics", None).await;
    assert_unauthorized(&none, "/metrics", "missing token");
    for token in [VIEWER_TOKEN, DRIVER_TOKEN] {
        let r = http::get(addr, "/metrics", Some(token)).await;
        assert_eq!(r.status, 403, "a non-admin token: {}", r.text());
        assert!(r.text().contains("admin token"), "{}", r.text());
    }
    let admin = http::get(addr, "/metrics", Some(ADMIN_TOKEN)).await;
    assert_eq!(admin.status, 200);
    assert!(admin.text().contains("# EOF"));
    let query = http::get(addr, &format!("/metrics?token={ADMIN_TOKEN}"), None).await;
    assert_eq!(query.status, 200);
    // Health and readiness stay open.
    assert_eq!(http::get(addr, "/healthz", None).await.status, 200);
    server.ready().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn development_mode_leaves_the_rest_routes_open() {
    let server = lightwire!().dev_solver();
    server.ready().await;
    for route in viewer_routes() {
        let r = http::get(&server.addr, &route, None).await;
        assert_eq!(r.status, 200, "{route} in development mode: {}", r.text());
    }
    assert_eq!(http::get(&server.addr, "/metrics", None).await.status, 200);
}

/// The `Welcome` of a real server sets `CAP_SCENE_GLB`, and
/// `scene_glb_path` of the scene id it carries, on the WebSocket's host
/// and with the connection's token, is the scene as glTF binary.
#[tokio::test]
async fn the_welcome_says_where_the_scene_glb_is() {
    use lightwire_protocol::{CAP_SCENE_GLB, scene_glb_path};
    use lightwire_testkit::peer::Peer;

    let server = lightwire!().solver("127.0.0.1:0");
    server.ready().await;
    // The kit's peer asserts that the first message is a Welcome.
    let viewer = Peer::connect(&server.ws_url(), VIEWER_TOKEN).await;
    let (capabilities, scene) = (viewer.capabilities, viewer.scene.expect("welcomed"));
    assert_ne!(
        capabilities & CAP_SCENE_GLB,
        0,
        "capabilities {capabilities:#x}"
    );
    let path = scene_glb_path(&scene.id);
    assert_eq!(path, scene_file("scene.glb"));
    let glb = http::get(&server.addr, &path, Some(VIEWER_TOKEN)).await;
    assert_eq!(glb.status, 200, "{path}");
    assert_eq!(glb.header("content-type"), Some("model/gltf-binary"));
    assert_eq!(
        &glb.body[..4],
        b"glTF",
        "a glTF binary begins with its magic"
    );
}
