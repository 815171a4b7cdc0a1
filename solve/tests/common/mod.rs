//! Helpers shared by the server's solver-level tests: scenes with their
//! atlas, the furnace check, accuracy where a viewer can see. What tests of
//! `lightwire` processes share is in the test kit (`lightwire-testkit`,
//! `tests/`).

// Each test binary compiles this module and uses only some helpers.
#![allow(dead_code)]

use std::f64::consts::PI;

use glam::{DVec3, Vec2, Vec3};
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

/// [`parse`] at a density scale, as [`load`] loads a file.
pub fn parse_scaled(text: &str, density_scale: f32) -> (Scene, Atlas) {
    let scene = Scene::parse_with(text, "inline", LoadOptions::scaled(density_scale))
        .unwrap_or_else(|e| panic!("inline scene must load: {e}"));
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

/// A closed 2 m room of quads (red and green side walls, a ceiling light
/// flush with the ceiling, a floating box that shadows the floor).
pub const ROOM: &str = r#"{
    "name": "coloured-room", "lightmap": { "texel_density": 6 },
    "materials": [
        { "name": "white", "albedo": [0.7, 0.7, 0.7] },
        { "name": "red", "albedo": [0.65, 0.1, 0.08] },
        { "name": "green", "albedo": [0.12, 0.5, 0.1] },
        { "name": "light", "albedo": [0.5, 0.5, 0.5], "emission": [20, 20, 20] }
    ],
    "surfaces": [
        { "name": "floor", "material": "white", "quad": { "origin": [0, 0, 0], "u": [0, 0, 2], "v": [2, 0, 0] } },
        { "name": "back", "material": "white", "quad": { "origin": [0, 0, 0], "u": [2, 0, 0], "v": [0, 2, 0] } },
        { "name": "front", "material": "white", "quad": { "origin": [0, 0, 2], "u": [0, 2, 0], "v": [2, 0, 0] } },
        { "name": "left", "material": "red", "quad": { "origin": [0, 0, 0], "u": [0, 2, 0], "v": [0, 0, 2] } },
        { "name": "right", "material": "green", "quad": { "origin": [2, 0, 0], "u": [0, 0, 2], "v": [0, 2, 0] } },
        { "name": "ceiling-back", "material": "white", "quad": { "origin": [0, 2, 0], "u": [2, 0, 0], "v": [0, 0, 0.7] } },
        { "name": "ceiling-front", "material": "white", "quad": { "origin": [0, 2, 1.3], "u": [2, 0, 0], "v": [0, 0, 0.7] } },
        { "name": "ceiling-left", "material": "white", "quad": { "origin": [0, 2, 0.7], "u": [0.7, 0, 0], "v": [0, 0, 0.6] } },
        { "name": "ceiling-right", "material": "white", "quad": { "origin": [1.3, 2, 0.7], "u": [0.7, 0, 0], "v": [0, 0, 0.6] } },
        { "name": "light", "material": "light", "texel_density": 20, "quad": { "origin": [0.7, 2, 0.7], "u": [0.6, 0, 0], "v": [0, 0, 0.6] } },
        { "name": "occluder", "material": "white", "box": { "center": [0.9, 0.7, 1.1], "size": [0.6, 0.4, 0.6] } }
    ]
}"#;

/// The square lamp's geometry in [`lamp_scene`]: 1 x 1 at height 1.5,
/// facing down.
pub const SQUARE_LAMP: &str =
    r#""quad": { "origin": [-0.5, 1.5, -0.5], "u": [1, 0, 0], "v": [0, 0, 1] }"#;

/// A scene named `name`: a lamp (E = 3) of geometry `lamp` (a surface's
/// shape, e.g. [`SQUARE_LAMP`]) over a black 8 x 8 floor at height 0;
/// with `plate`, a black 4 x 8 plate at height 0.75 covering x < 0
/// (facing down, so that it shadows the floor from the lamp's part over
/// x < 0).
pub fn lamp_scene(name: &str, lamp: &str, plate: bool) -> String {
    let plate = if plate {
        r#", { "name": "plate", "material": "black", "quad": { "origin": [-4, 0.75, -4], "u": [4, 0, 0], "v": [0, 0, 8] } }"#
    } else {
        ""
    };
    format!(
        r#"{{
        "name": "{name}", "lightmap": {{ "texel_density": 2 }},
        "materials": [
            {{ "name": "lamp", "albedo": [0, 0, 0], "emission": [3, 3, 3] }},
            {{ "name": "black", "albedo": [0, 0, 0] }}
        ],
        "surfaces": [
            {{ "name": "lamp", "material": "lamp", {lamp} }},
            {{ "name": "floor", "material": "black", "quad": {{ "origin": [-4, 0, -4], "u": [0, 0, 8], "v": [8, 0, 0] }} }}{plate}
        ]
    }}"#
    )
}

/// Asserts that the emitters' irradiance (red channel) at the floor
/// points `(x, 1e-6, z)`, facing up, is within 1e-5 (relative) of
/// `expected` there.
pub fn assert_floor_irradiance(
    scene: &Scene,
    atlas: &Atlas,
    points: impl IntoIterator<Item = (f64, f64)>,
    expected: impl Fn(DVec3) -> f64,
) {
    use lightwire_solve::direct::{Emitters, GRID};
    let caster = lightwire_solve::raycast::Raycaster::new(scene, &scene.initial_poses());
    let emitters = Emitters::of(scene);
    for (dx, dz) in points {
        let x = DVec3::new(dx, 1e-6, dz);
        let h = emitters.irradiance(&caster, atlas, x, DVec3::Y, GRID, |j| {
            atlas.elements[j].emission
        });
        let expected = expected(x);
        let got = f64::from(h.x);
        assert!(
            (got - expected).abs() <= 1e-5 * expected,
            "({dx}, {dz}): {got} vs {expected}"
        );
    }
}

/// The form factor between the two plates of `plates.json` implied by the
/// radiosity `b`: the receiver's area-weighted mean over ρ E (E = 1).
pub fn implied_form_factor(scene: &Scene, atlas: &Atlas, b: &[Vec3]) -> f64 {
    let receiver = atlas.elements_of(1);
    let area: f64 = receiver
        .clone()
        .map(|i| f64::from(atlas.elements[i].area))
        .sum();
    let mean: f64 = receiver
        .map(|i| f64::from(atlas.elements[i].area) * f64::from(b[i].x))
        .sum::<f64>()
        / area;
    let rho = f64::from(scene.materials[1].albedo.x);
    mean / (rho * 1.0)
}

/// Lambert's formula for the form factor from a differential area at `x`
/// with unit normal `n` to a convex polygon entirely above its horizon:
/// `F = (1/2π) Σ_i γ_i n · (r_i × r_{i+1}) / |r_i × r_{i+1}|`, `r_i = v_i − x`,
/// `γ_i` the angle between `r_i` and `r_{i+1}`. Written out here so that
/// the tests do not check the solvers against their own form factor.
pub fn lambert(x: DVec3, n: DVec3, polygon: &[DVec3]) -> f64 {
    let mut sum = 0.0;
    for i in 0..polygon.len() {
        let (a, b) = (polygon[i] - x, polygon[(i + 1) % polygon.len()] - x);
        let c = a.cross(b);
        let gamma = a.normalize().dot(b.normalize()).clamp(-1.0, 1.0).acos();
        sum += gamma * n.dot(c / c.length());
    }
    (sum / (2.0 * PI)).abs()
}
