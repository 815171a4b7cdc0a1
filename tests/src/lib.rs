//! The test kit: what every process-level test of Lightwire shares.
//!
//! - [`Lightwire`]: where the `lightwire` binary is, and starting it as
//!   `serve` or `relay` ([`process::Proc`]: the child's address from its
//!   banner, readiness by `/readyz`, its stdout and stderr captured for its
//!   whole life, killed on drop);
//! - [`http`]: a minimal HTTP/1.1 GET, async and blocking;
//! - [`peer`]: a raw protocol peer that applies keyframes and deltas as the
//!   protocol demands and records what it saw;
//! - [`fake`]: a scripted fake server, for tests where the test plays the
//!   solver (a relay's upstream, the client library's server);
//! - [`pose`]: poses of the Cornell scenes' box and transform messages;
//! - [`dashboard`]: the web dashboard's files as a server or relay serves
//!   them;
//! - [`validator`]: the Khronos glTF validator.
//!
//! The kit depends on `lightwire-protocol` only of ours, never on the
//! scene, solver or server crates, so that the client's tests do not link
//! the solver. Tests that need their types keep such helpers to themselves
//! (`solve/tests/common`).

pub mod dashboard;
pub mod fake;
pub mod http;
pub mod peer;
pub mod pose;
pub mod process;
pub mod validator;

mod binary;

pub use binary::Lightwire;

use std::path::PathBuf;

/// The driver token of the processes [`Lightwire::solver`] and
/// [`Lightwire::relay`] start.
pub const DRIVER_TOKEN: &str = "driver-token-0123";
/// Their viewer token.
pub const VIEWER_TOKEN: &str = "viewer-token-0123";
/// Their admin token.
pub const ADMIN_TOKEN: &str = "admin-token-0123";
/// The scene [`Lightwire::solver`] serves (and a relay relays).
pub const SCENE: &str = "cornell-low";

/// `LIGHTWIRE_TOKENS` for the three tokens above.
pub fn tokens() -> String {
    format!("driver:{DRIVER_TOKEN},viewer:{VIEWER_TOKEN},admin:{ADMIN_TOKEN}")
}

/// The repository root.
pub fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// `/api/scenes/{SCENE}/{file}`: a file of [`SCENE`] in the REST API
/// (`lightmap.exr`, `lightmap.png`, `scene.glb`, ...).
pub fn scene_file(file: &str) -> String {
    format!("/api/scenes/{SCENE}/{file}")
}

/// The REST routes that need a viewer token where tokens are configured:
/// the scene list, [`SCENE`]'s description, its snapshots and lit
/// `scene.glb`, and its lights (a solver's route: a relay answers 404
/// once the token and origin pass).
pub fn viewer_routes() -> [String; 6] {
    [
        "/api/scenes".to_string(),
        format!("/api/scenes/{SCENE}"),
        scene_file("lightmap.exr"),
        scene_file("lightmap.png"),
        scene_file("scene.glb"),
        scene_file("lights"),
    ]
}

/// Path of a file in the repository's `scenes/` directory.
pub fn scene_path(name: &str) -> PathBuf {
    repo().join("scenes").join(name)
}
