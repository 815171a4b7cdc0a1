//! The web dashboard as a `lightwire serve` or `lightwire relay` process
//! serves it: both have the same routes (`/` and `/dashboard/{*path}`),
//! files embedded in the binary and open without a token.

use crate::http;

/// The scripts under `/dashboard/`: the page's modules and the vendored
/// zstd decoder.
pub const SCRIPTS: [&str; 9] = [
    "app.js",
    "connection.js",
    "protocol.js",
    "lightmap.js",
    "tone.js",
    "view3d.js",
    "gizmos.js",
    "chart.js",
    "vendor/fzstd.js",
];

/// Checks that the process at `addr` serves the dashboard: `/` is its HTML
/// page, under a content security policy of its own origin, loading
/// `app.js` as a module; each of [`SCRIPTS`] is JavaScript; other paths
/// under `/dashboard/` are 404.
pub async fn assert_served(addr: &str) {
    let index = http::get(addr, "/", None).await;
    assert_eq!(index.status, 200, "/ on {addr}");
    assert_header_starts(&index, "content-type", "text/html");
    assert_header_starts(&index, "content-security-policy", "default-src 'self'");
    assert!(
        index
            .text()
            .contains("<script type=\"module\" src=\"/dashboard/app.js\">")
    );
    for file in SCRIPTS {
        let r = http::get(addr, &format!("/dashboard/{file}"), None).await;
        assert_eq!(r.status, 200, "/dashboard/{file} on {addr}");
        assert_header_starts(&r, "content-type", "text/javascript");
    }
    for missing in ["/dashboard/nope.js", "/dashboard/../Cargo.toml"] {
        let r = http::get(addr, missing, None).await;
        assert_eq!(r.status, 404, "{missing} on {addr}");
    }
}

/// Checks that `response` has a header `name` that starts with `prefix`.
fn assert_header_starts(response: &http::Response, name: &str, prefix: &str) {
    assert!(
        response.header(name).is_some_and(|v| v.starts_with(prefix)),
        "{name} is not {prefix}...: {:?}",
        response.headers
    );
}
