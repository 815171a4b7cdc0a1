//! Helpers shared by the server's integration tests.

// Each test binary compiles this module and uses only some helpers.
#![allow(dead_code)]

use std::path::PathBuf;

use lightwire_server::atlas::Atlas;
use lightwire_server::scene::{LoadOptions, Scene};

/// Path of a file in the repository's `scenes/` directory.
pub fn scene_path(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../scenes")
        .join(name)
}

/// Loads a scene from `scenes/` at a density scale, with its atlas.
pub fn load(name: &str, density_scale: f32) -> (Scene, Atlas) {
    let scene = Scene::load_with(&scene_path(name), LoadOptions { density_scale })
        .unwrap_or_else(|e| panic!("{name} must load: {e}"));
    let atlas = Atlas::build(&scene).unwrap_or_else(|e| panic!("{name} must fit: {e}"));
    (scene, atlas)
}

/// Parses an inline scene, with its atlas.
pub fn parse(text: &str) -> (Scene, Atlas) {
    let scene =
        Scene::parse(text, "inline").unwrap_or_else(|e| panic!("inline scene must load: {e}"));
    let atlas = Atlas::build(&scene).unwrap_or_else(|e| panic!("inline scene must fit: {e}"));
    (scene, atlas)
}
