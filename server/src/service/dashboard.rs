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
//!
//! The three.js example (`src/examples/threejs/`: a stock engine drawing the
//! stream) is served the same way at `/examples/threejs/`; it imports the
//! dashboard's protocol modules and three.js, vendored in
//! `src/vendor/three/` (byte for byte the pinned npm package's files, see
//! `test/vendor.test.mjs`), from `/dashboard/`.

use axum::extract::Path;
use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};

/// One embedded file.
struct Asset {
    /// Path under `/dashboard/` (or `/examples/threejs/`).
    path: &'static str,
    /// Its `Content-Type`.
    mime: &'static str,
    body: &'static [u8],
}

macro_rules! asset {
    ($path:literal, $mime:expr) => {
        asset!("", $path, $mime)
    };
    ($dir:literal, $path:literal, $mime:expr) => {
        Asset {
            path: $path,
            mime: $mime,
            body: include_bytes!(concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/dashboard/src/",
                $dir,
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
    asset!("gizmos.js", JS),
    asset!("vendor/fzstd.js", JS),
    asset!("vendor/fzstd.LICENSE", "text/plain; charset=utf-8"),
    // three.js, for the example below: the ES modules it loads.
    asset!("vendor/three/build/three.module.js", JS),
    asset!("vendor/three/build/three.core.js", JS),
    asset!("vendor/three/examples/jsm/loaders/GLTFLoader.js", JS),
    asset!("vendor/three/examples/jsm/utils/BufferGeometryUtils.js", JS),
    asset!("vendor/three/examples/jsm/utils/SkeletonUtils.js", JS),
    asset!("vendor/three/examples/jsm/controls/OrbitControls.js", JS),
    asset!("vendor/three/LICENSE", "text/plain; charset=utf-8"),
];

/// The three.js example, under `/examples/threejs/`.
const EXAMPLE: &[Asset] = &[
    asset!(
        "examples/threejs/",
        "index.html",
        "text/html; charset=utf-8"
    ),
    asset!("examples/threejs/", "main.js", JS),
    asset!("examples/threejs/", "style.css", "text/css; charset=utf-8"),
];

/// Scripts, styles, fetches and WebSockets from this origin only; images
/// also from `data:` (the empty favicon).
const CSP: &str = "default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data:; connect-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'";

/// The example's policy: [`CSP`], plus its inline import map (which maps
/// `three` to the vendored build; Chromium loads no import map from a file),
/// allowed by its SHA-256 (`test/examples.test.mjs` checks it against
/// `index.html`), and `blob:` images and fetches, through which GLTFLoader
/// decodes the images embedded in a `.glb`.
const EXAMPLE_CSP: &str = "default-src 'self'; script-src 'self' 'sha256-tDmiaXn5Gq2mm60HOUUEJ/F+NLwHNn8pZzBauSVNDY4='; style-src 'self'; img-src 'self' data: blob:; connect-src 'self' blob:; base-uri 'none'; form-action 'none'; frame-ancestors 'none'";

fn serve(asset: &Asset) -> Response {
    serve_with(asset, CSP)
}

fn serve_with(asset: &Asset, csp: &'static str) -> Response {
    (
        [
            (header::CONTENT_TYPE, HeaderValue::from_static(asset.mime)),
            // The files change with the binary; let browsers revalidate.
            (header::CACHE_CONTROL, HeaderValue::from_static("no-cache")),
            (
                header::CONTENT_SECURITY_POLICY,
                HeaderValue::from_static(csp),
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

/// `GET /examples/threejs/` (and without the slash): the three.js
/// example's page.
pub async fn example_index() -> Response {
    example(Path("index.html".to_string())).await
}

/// `GET /examples/threejs/{*path}`: one of the example's files, or 404.
pub async fn example(Path(path): Path<String>) -> Response {
    match EXAMPLE.iter().find(|a| a.path == path) {
        Some(asset) => serve_with(asset, EXAMPLE_CSP),
        None => (
            StatusCode::NOT_FOUND,
            format!("no example file \"{path}\"\n"),
        )
            .into_response(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The asset a module specifier or page reference names: an absolute
    /// `/dashboard/...` or `/examples/threejs/...` path, one relative to
    /// the importing file (`dir` in `table`), or a bare one (`three`)
    /// through the example page's import map.
    fn resolve(spec: &str, dir: &str, table: &'static [Asset]) -> Option<&'static Asset> {
        let lookup = |t: &'static [Asset], p: &str| t.iter().find(|a| a.path == p);
        if let Some(rest) = spec.strip_prefix("/dashboard/") {
            return lookup(ASSETS, rest);
        }
        if let Some(rest) = spec.strip_prefix("/examples/threejs/") {
            return lookup(EXAMPLE, rest);
        }
        if spec.starts_with('.') {
            let mut parts: Vec<&str> = dir.split('/').filter(|p| !p.is_empty()).collect();
            for part in spec.split('/') {
                match part {
                    "." => {}
                    ".." => {
                        parts.pop()?;
                    }
                    _ => parts.push(part),
                }
            }
            return lookup(table, &parts.join("/"));
        }
        let (target, rest) = import_map().into_iter().find_map(|(key, target)| {
            if key == spec {
                Some((target, String::new()))
            } else if key.ends_with('/') {
                spec.strip_prefix(&key)
                    .map(|rest| (target, rest.to_string()))
            } else {
                None
            }
        })?;
        resolve(&format!("{target}{rest}"), "", table)
    }

    /// The example page's import map, `(specifier, address)`.
    fn import_map() -> Vec<(String, String)> {
        let page = std::str::from_utf8(EXAMPLE[0].body).expect("utf-8");
        let json = page
            .split("<script type=\"importmap\">")
            .nth(1)
            .and_then(|rest| rest.split("</script>").next())
            .expect("index.html has an import map");
        let map: serde_json::Value = serde_json::from_str(json).expect("the import map is JSON");
        map["imports"]
            .as_object()
            .expect("an `imports` object")
            .iter()
            .map(|(k, v)| (k.clone(), v.as_str().expect("a string").to_string()))
            .collect()
    }

    /// Every module a page imports is embedded: a missing one would only
    /// show up in a browser as a failed import.
    #[test]
    fn every_import_and_page_reference_is_embedded() {
        for table in [ASSETS, EXAMPLE] {
            for asset in table.iter().filter(|a| a.path.ends_with(".js")) {
                let text = std::str::from_utf8(asset.body).expect("utf-8");
                let dir = asset.path.rsplit_once('/').map_or("", |(d, _)| d);
                // `import ... 'x'`, and the last line of a multi-line import
                // or a re-export: `} from 'x'`, `export { ... } from 'x'`.
                for line in text.lines().map(str::trim_start).filter(|l| {
                    l.starts_with("import ")
                        || (l.starts_with("} from ") || l.starts_with("export "))
                            && l.contains(" from ")
                }) {
                    let Some(spec) = line.split(['\'', '"']).nth(1) else {
                        continue;
                    };
                    assert!(
                        resolve(spec, dir, table).is_some(),
                        "{} imports {spec}, not embedded",
                        asset.path
                    );
                }
            }
        }
        for (page, prefix) in [
            (find("index.html"), "\"/dashboard/"),
            (EXAMPLE.first(), "\"/"),
        ] {
            let page = std::str::from_utf8(page.expect("page").body).expect("utf-8");
            for reference in page.split(prefix).skip(1) {
                let path = reference.split('"').next().unwrap_or_default();
                let path = format!("{}{path}", &prefix[1..]);
                if path.ends_with('/') {
                    continue; // an import map's prefix, checked below
                }
                assert!(
                    resolve(&path, "", ASSETS).is_some(),
                    "a page references {path}, not embedded"
                );
            }
        }
        // The import map itself points at embedded modules.
        for (key, target) in import_map() {
            if !key.ends_with('/') {
                assert!(
                    resolve(&target, "", ASSETS).is_some(),
                    "{key} maps to {target}, not embedded"
                );
            }
        }
    }
}
