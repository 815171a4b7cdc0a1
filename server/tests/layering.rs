//! The architecture invariants of ARCHITECTURE.md ("Architecture
//! invariants"), checked on the manifests and the sources: what a crate
//! may link and what a module may import. A change that breaks one fails
//! here with the rule it breaks, instead of surfacing later as a thin
//! client that links wgpu or a relay that builds a solver.

use std::path::{Path, PathBuf};

/// The workspace root (this crate lives in `server/`).
fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("server/ has a parent")
        .to_path_buf()
}

/// The dependency names of a manifest's `[dependencies]` table.
fn dependencies(manifest: &str) -> Vec<String> {
    let path = root().join(manifest);
    let text = std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("reading {}: {e}", path.display()));
    let value: toml::Table = text
        .parse()
        .unwrap_or_else(|e| panic!("parsing {}: {e}", path.display()));
    value
        .get("dependencies")
        .and_then(|d| d.as_table())
        .map(|t| t.keys().cloned().collect())
        .unwrap_or_default()
}

/// Every `.rs` file under `dir` (relative to the root), with its text.
fn sources(dir: &str) -> Vec<(PathBuf, String)> {
    let mut out = Vec::new();
    let mut stack = vec![root().join(dir)];
    while let Some(d) = stack.pop() {
        let entries =
            std::fs::read_dir(&d).unwrap_or_else(|e| panic!("reading {}: {e}", d.display()));
        for entry in entries {
            let path = entry.expect("directory entry").path();
            if path.is_dir() {
                stack.push(path);
            } else if path.extension().is_some_and(|x| x == "rs") {
                let text = std::fs::read_to_string(&path)
                    .unwrap_or_else(|e| panic!("reading {}: {e}", path.display()));
                out.push((path, text));
            }
        }
    }
    assert!(!out.is_empty(), "no sources under {dir}");
    out
}

/// Lines of code (not comments) in `files` that mention any of `paths`.
fn mentions(files: &[(PathBuf, String)], paths: &[&str]) -> Vec<String> {
    let mut found = Vec::new();
    for (file, text) in files {
        for (n, line) in text.lines().enumerate() {
            let code = line.trim_start();
            if code.starts_with("//") {
                continue;
            }
            for p in paths {
                if code.contains(p) {
                    found.push(format!("{}:{}: {}", file.display(), n + 1, code));
                }
            }
        }
    }
    found
}

#[test]
fn the_protocol_crate_knows_no_tokio_wgpu_or_other_lightwire_crate() {
    let deps = dependencies("protocol/Cargo.toml");
    for banned in [
        "tokio",
        "wgpu",
        "axum",
        "tokio-tungstenite",
        "lightwire-server",
    ] {
        assert!(
            !deps.iter().any(|d| d == banned),
            "protocol/Cargo.toml depends on {banned}: every client shares the protocol crate"
        );
    }
    let hits = mentions(&sources("protocol/src"), &["tokio::", "wgpu::"]);
    assert!(
        hits.is_empty(),
        "protocol/src uses tokio or wgpu:\n{}",
        hits.join("\n")
    );
}

#[test]
fn a_thin_client_never_links_the_solver() {
    let deps = dependencies("client/Cargo.toml");
    assert!(
        !deps.iter().any(|d| d == "lightwire-server"),
        "client/Cargo.toml depends on lightwire-server: a game would link the solver"
    );
}

#[test]
fn a_relay_never_builds_a_solver() {
    let hits = mentions(
        &sources("server/src/relay"),
        &[
            "crate::gpu",
            "crate::reference",
            "crate::pathtrace",
            "service::runtime",
            "service::live",
        ],
    );
    assert!(
        hits.is_empty(),
        "server/src/relay reaches for the solver:\n{}",
        hits.join("\n")
    );
}

#[test]
fn the_solvers_know_no_service_and_the_gpu_path_not_the_reference() {
    let gpu = sources("server/src/gpu");
    let hits = mentions(
        &gpu,
        &[
            "crate::reference",
            "crate::pathtrace",
            "crate::service",
            "crate::relay",
        ],
    );
    assert!(
        hits.is_empty(),
        "server/src/gpu imports the reference, the path tracer or the service:\n{}",
        hits.join("\n")
    );
    for dir in ["server/src/reference", "server/src/pathtrace"] {
        let hits = mentions(
            &sources(dir),
            &["crate::gpu", "crate::service", "crate::relay"],
        );
        assert!(
            hits.is_empty(),
            "{dir} imports the GPU solvers or the service:\n{}",
            hits.join("\n")
        );
    }
}

#[test]
fn the_gpu_building_blocks_know_no_solver() {
    for file in ["binding.rs", "buffers.rs", "placement.rs", "hemicube.rs"] {
        let path = format!("server/src/gpu/{file}");
        let text = std::fs::read_to_string(root().join(&path))
            .unwrap_or_else(|e| panic!("reading {path}: {e}"));
        let hits = mentions(
            &[(PathBuf::from(&path), text)],
            &["progressive", "gather::", "dynamic::", "GatherSolver"],
        );
        assert!(
            hits.is_empty(),
            "{path} is a building block but reaches for a solver:\n{}",
            hits.join("\n")
        );
    }
}
