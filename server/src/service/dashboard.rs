//! The web dashboard: static files compiled into the binary.
//!
//! The sources live in `server/dashboard/src/` as plain ES modules (no
//! bundler); `include_bytes!` embeds each one here, so `lightwire serve`
//! needs no files beside it and the browser loads nothing from elsewhere
//! (the zstd decoder is vendored in `src/vendor/`). `GET /` serves
//! `index.html`; the rest are under `/dashboard/`. Every response carries a
//! Content-Security-Policy that allows only this origin, so a page that
//! tried to load a script from a CDN would fail loudly (the end-to-end test
//! in `server/tests/dashboard.rs` fails on any console error).

use axum::extract::Path;
use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};

/// One embedded file.
struct Asset {
    /// Path under `/dashboard/`.
    path: &'static str,
    /// Its `Content-Type`.
    mime: &'static str,
    body: &'static [u8],
}

macro_rules! asset {
    ($path:literal, $mime:expr) => {
        Asset {
            path: $path,
            mime: $mime,
            body: include_bytes!(concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/dashboard/src/",
                $path
            )),
        }
    };
}

const JS: &str = "text/javascript; charset=utf-8";

/// Everything the page loads.
const ASSETS: &[Asset] = &[
    asset!("index.html", "text/html; charset=utf-8"),
    asset!("style.css", "text/css; charset=utf-8"),
    asset!("app.js", JS),
    asset!("connection.js", JS),
    asset!("protocol.js", JS),
    asset!("lightmap.js", JS),
    asset!("tone.js", JS),
    asset!("chart.js", JS),
    asset!("view3d.js", JS),
    asset!("vendor/fzstd.js", JS),
    asset!("vendor/fzstd.LICENSE", "text/plain; charset=utf-8"),
];

/// Scripts, styles, fetches and WebSockets from this origin only; images
/// also from `data:` (the empty favicon).
const CSP: &str = "default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data:; connect-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'";

fn serve(asset: &Asset) -> Response {
    (
        [
            (header::CONTENT_TYPE, HeaderValue::from_static(asset.mime)),
            // The files change with the binary; let browsers revalidate.
            (header::CACHE_CONTROL, HeaderValue::from_static("no-cache")),
            (
                header::CONTENT_SECURITY_POLICY,
                HeaderValue::from_static(CSP),
            ),
            (
                header::X_CONTENT_TYPE_OPTIONS,
                HeaderValue::from_static("nosniff"),
            ),
        ],
        asset.body,
    )
        .into_response()
}

fn find(path: &str) -> Option<&'static Asset> {
    ASSETS.iter().find(|a| a.path == path)
}

/// `GET /`: the dashboard page.
pub async fn index() -> Response {
    match find("index.html") {
        Some(asset) => serve(asset),
        None => (
            StatusCode::INTERNAL_SERVER_ERROR,
            "dashboard not embedded\n",
        )
            .into_response(),
    }
}

/// `GET /dashboard/{*path}`: one embedded file, or 404.
pub async fn file(Path(path): Path<String>) -> Response {
    match find(&path) {
        Some(asset) => serve(asset),
        None => (
            StatusCode::NOT_FOUND,
            format!("no dashboard file \"{path}\"\n"),
        )
            .into_response(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every module the page imports is embedded: a missing one would only
    /// show up in a browser as a failed import.
    #[test]
    fn every_relative_import_and_page_reference_is_embedded() {
        for asset in ASSETS.iter().filter(|a| a.path.ends_with(".js")) {
            let text = std::str::from_utf8(asset.body).expect("utf-8");
            let dir = asset.path.rsplit_once('/').map_or("", |(d, _)| d);
            for line in text
                .lines()
                .filter(|l| l.trim_start().starts_with("import "))
            {
                let Some(spec) = line.split(['\'', '"']).nth(1) else {
                    continue;
                };
                let spec = spec.trim_start_matches("./");
                let path = if dir.is_empty() {
                    spec.to_string()
                } else {
                    format!("{dir}/{spec}")
                };
                assert!(
                    find(&path).is_some(),
                    "{} imports {path}, not embedded",
                    asset.path
                );
            }
        }
        let page = std::str::from_utf8(find("index.html").expect("index").body).expect("utf-8");
        for reference in page.split("\"/dashboard/").skip(1) {
            let path = reference.split('"').next().unwrap_or_default();
            assert!(
                find(path).is_some(),
                "index.html references {path}, not embedded"
            );
        }
    }
}
