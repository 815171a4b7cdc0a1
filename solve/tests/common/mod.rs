//! Helpers shared by the server's solver-level tests: scenes with their
//! atlas, the furnace check, accuracy where a viewer can see. What tests of
//! `lightwire` processes share is in the test kit (`lightwire-testkit`,
//! `tests/`).

// Each test binary compiles this module and uses only some helpers.
#![allow(dead_code)]

use glam::{Vec2, Vec3};
use lightwire_scene::atlas::Atlas;
use lightwire_scene::{LoadOptions, Scene};

pub use lightwire_testkit::scene_path;

/// A lightmap with a different value in every texel and nowhere black, so
/// that a texel read from the wrong place shows.
pub fn gradient(atlas: &Atlas) -> Vec<[f32; 3]> {
    (0..atlas.width * atlas.height)
        .map(|i| {
            let (x, y) = (i % atlas.width, i / atlas.width);
            [x as f32 * 0.01, y as f32 * 0.02, 0.5]
        })
        .collect()
}

/// The atlas image read as a client's bilinear filter reads it at
/// normalized lightmap coordinates `uv` (texel `(x, y)`'s centre at
/// `((x + 0.5) / width, (y + 0.5) / height)`, clamped at the borders).
pub fn filtered(image: &[[f32; 3]], atlas: &Atlas, uv: Vec2) -> Vec3 {
    let (w, h) = (atlas.width as i64, atlas.height as i64);
    let f = uv * Vec2::new(w as f32, h as f32) - Vec2::splat(0.5);
    let (x, y) = (f.x.floor(), f.y.floor());
    let (fx, fy) = (f.x - x, f.y - y);
    let texel = |dx: i64, dy: i64| {
        let xx = (x as i64 + dx).clamp(0, w - 1);
        let yy = (y as i64 + dy).clamp(0, h - 1);
        Vec3::from(image[(yy * w + xx) as usize])
    };
    (texel(0, 0) * (1.0 - fx) + texel(1, 0) * fx) * (1.0 - fy)
        + (texel(0, 1) * (1.0 - fx) + texel(1, 1) * fx) * fy
}

/// Loads a scene from `scenes/` at a density scale, with its atlas.
pub fn load(name: &str, density_scale: f32) -> (Scene, Atlas) {
    let scene = Scene::load_with(&scene_path(name), LoadOptions::scaled(density_scale))
        .unwrap_or_else(|e| panic!("{name} must load: {e}"));
    let atlas = Atlas::build(&scene).unwrap_or_else(|e| panic!("{name} must fit: {e}"));
    (scene, atlas)
}

/// [`load`] with every triangle of a mesh its own patch, also where two
/// form a parallelogram that would otherwise share a chart: for tests of
/// the triangle paths.
pub fn load_triangles(name: &str, density_scale: f32) -> (Scene, Atlas) {
    let options = LoadOptions::unpaired(density_scale);
    let scene = Scene::load_with(&scene_path(name), options)
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

/// [`lightwire_solve::accuracy::accuracy`] over the elements a viewer can
/// see: the non-emitting elements that are not inside or under geometry at
/// `poses` ([`lightwire_solve::validity`]).
pub fn visible_accuracy(
    scene: &Scene,
    atlas: &Atlas,
    poses: &[lightwire_scene::Pose],
    values: &[Vec3],
    reference: &[Vec3],
) -> lightwire_solve::accuracy::Accuracy {
    let validity = lightwire_solve::validity::Validity::compute(scene, atlas, poses);
    lightwire_solve::accuracy::accuracy_where(atlas, values, reference, validity.keep())
        .unwrap_or_else(|| panic!("lengths must match and the reference must be lit"))
}

/// The lightmap of `scene.triangulated()` (atlas `tri_atlas`, `tri_values`
/// per element with invalid texels filled) read as a client reads it at the
/// sample point of every element of the quad scene's atlas `atlas`: a quad
/// `p` became triangles `2p` (its points with `t <= s`, same parameters) and
/// `2p + 1` (its `(s, t)` there is `(1 - s, 1 - t)`); see
/// `Scene::triangulated`.
/// `scene` must hold quads only.
pub fn resample_triangulated(
    scene: &Scene,
    atlas: &Atlas,
    tri_atlas: &Atlas,
    tri_values: &[Vec3],
) -> Vec<Vec3> {
    assert!(
        scene.patches.iter().all(|p| !p.shape.is_triangle()),
        "resample_triangulated takes a scene of quads"
    );
    assert_eq!(tri_atlas.charts.len(), 2 * scene.patches.len());
    atlas
        .elements
        .iter()
        .map(|e| {
            let [s, t] = e.st;
            if t <= s {
                tri_atlas.sample(tri_values, 2 * e.patch, [s, t])
            } else {
                tri_atlas.sample(tri_values, 2 * e.patch + 1, [1.0 - s, 1.0 - t])
            }
        })
        .collect()
}

/// One GPU device shared by all tests of a test binary (lavapipe where
/// there is no GPU).
pub fn gpu() -> &'static lightwire_solve::gpu::Device {
    static DEVICE: std::sync::OnceLock<lightwire_solve::gpu::Device> = std::sync::OnceLock::new();
    DEVICE.get_or_init(|| {
        let device = lightwire_solve::gpu::Device::new(None).unwrap_or_else(|e| panic!("{e}"));
        eprintln!("adapter: {}", device.describe());
        device
    })
}
