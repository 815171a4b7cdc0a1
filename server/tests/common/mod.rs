//! Helpers shared by the server's solver-level tests: scenes with their
//! atlas, the furnace check, accuracy where a viewer can see. What tests of
//! `lightwire` processes share is in the test kit (`lightwire-testkit`,
//! `tests/`).

// Each test binary compiles this module and uses only some helpers.
#![allow(dead_code)]

use glam::Vec3;
use lightwire_server::atlas::Atlas;
use lightwire_server::scene::{LoadOptions, Scene};

pub use lightwire_testkit::scene_path;

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

/// Furnace check: every element of `b` within `tolerance` (relative, per
/// channel) of `expected`; returns the largest relative error.
pub fn assert_uniform(atlas: &Atlas, b: &[Vec3], expected: Vec3, tolerance: f32) -> f32 {
    let mut worst = 0.0f32;
    for (i, v) in b.iter().enumerate() {
        let error = ((*v - expected) / expected).abs().max_element();
        worst = worst.max(error);
        assert!(
            error < tolerance,
            "element {i} at texel {:?} (st {:?}): {v} vs {expected}",
            atlas.elements[i].texel,
            atlas.elements[i].st
        );
    }
    worst
}

/// [`lightwire_server::metrics::accuracy`] over the elements a viewer can
/// see: the non-emitting elements that are not inside or under geometry at
/// `poses` ([`lightwire_server::validity`]).
pub fn visible_accuracy(
    scene: &Scene,
    atlas: &Atlas,
    poses: &[lightwire_server::scene::Pose],
    values: &[Vec3],
    reference: &[Vec3],
) -> lightwire_server::metrics::Accuracy {
    let validity = lightwire_server::validity::Validity::compute(scene, atlas, poses);
    lightwire_server::metrics::accuracy_where(atlas, values, reference, validity.keep())
        .unwrap_or_else(|| panic!("lengths must match and the reference must be lit"))
}
