//! Base colour textures (issue 18): a textured glTF surface's lightmap
//! texels each get the texture averaged over their footprint as albedo, and
//! the light they reflect agrees with the path tracer, which looks the
//! texture up at every bounce instead (the second oracle).

use std::path::PathBuf;

use glam::{Vec2, Vec3};
use lightwire_scene::atlas::Atlas;
use lightwire_scene::gltf::write::{
    GlbImage, GlbMaterial, GlbMesh, GlbNode, GlbPrimitive, GlbScene,
};
use lightwire_scene::load::load_scene;
use lightwire_scene::texture::srgb_to_linear;
use lightwire_scene::{LoadOptions, Scene};
use lightwire_solve::accuracy;
use lightwire_solve::pathtrace::{self, PathTracer, Silent};
use lightwire_solve::reference::{self, ReferenceSolver, SolveOptions};

/// The checker's squares, in metres (the texture is 2 × 2 pixels and the
/// floor's `TEXCOORD_0` is its position in metres, repeating).
const SQUARE: f32 = 0.5;
/// The floor's `baseColorFactor`.
const FACTOR: f32 = 0.9;
/// The checker's two pixels, sRGB-encoded.
const BRIGHT: u8 = 255;
const DARK: u8 = 40;

/// A 2 × 2 checker PNG: bright at pixels (0, 0) and (1, 1).
fn checker_png() -> Vec<u8> {
    let mut pixels = Vec::new();
    for y in 0..2 {
        for x in 0..2 {
            let v = if (x + y) % 2 == 0 { BRIGHT } else { DARK };
            pixels.extend_from_slice(&[v, v, v]);
        }
    }
    let mut png = Vec::new();
    let encoder = image::codecs::png::PngEncoder::new(&mut png);
    image::ImageEncoder::write_image(encoder, &pixels, 2, 2, image::ExtendedColorType::Rgb8)
        .expect("PNG of 12 bytes");
    png
}

/// The floor's albedo at world `(x, z)`, computed from the world position
/// alone (not through the importer's texture coordinates).
fn floor_albedo(x: f32, z: f32) -> f32 {
    let i = (x / SQUARE).floor() as i64 + (z / SQUARE).floor() as i64;
    let code = if i.rem_euclid(2) == 0 { BRIGHT } else { DARK };
    FACTOR * srgb_to_linear(f32::from(code) / 255.0)
}

/// A 2 × 2 × 2 m room as a glTF (the coloured room of `path_tracer.rs`
/// without its box): a checker floor, white, red and green walls, a 0.6 m
/// square light in the ceiling. Every quad is two triangles.
fn room() -> GlbScene {
    let material =
        |name: &str, albedo: [f32; 3], emission: [f32; 3], texture: Option<usize>| GlbMaterial {
            name: name.to_string(),
            base_color: Vec3::from(albedo),
            emission: Vec3::from(emission),
            base_color_texture: texture,
        };
    let materials = vec![
        material("checker", [FACTOR; 3], [0.0; 3], Some(0)),
        material("white", [0.7; 3], [0.0; 3], None),
        material("red", [0.65, 0.1, 0.08], [0.0; 3], None),
        material("green", [0.12, 0.5, 0.1], [0.0; 3], None),
        material("light", [0.5; 3], [20.0; 3], None),
    ];
    // (node, material, origin, u, v): the quad faces u × v.
    let v3 = Vec3::new;
    let quads = [
        (
            "floor",
            0,
            v3(0.0, 0.0, 0.0),
            v3(0.0, 0.0, 2.0),
            v3(2.0, 0.0, 0.0),
        ),
        (
            "back",
            1,
            v3(0.0, 0.0, 0.0),
            v3(2.0, 0.0, 0.0),
            v3(0.0, 2.0, 0.0),
        ),
        (
            "front",
            1,
            v3(0.0, 0.0, 2.0),
            v3(0.0, 2.0, 0.0),
            v3(2.0, 0.0, 0.0),
        ),
        (
            "left",
            2,
            v3(0.0, 0.0, 0.0),
            v3(0.0, 2.0, 0.0),
            v3(0.0, 0.0, 2.0),
        ),
        (
            "right",
            3,
            v3(2.0, 0.0, 0.0),
            v3(0.0, 0.0, 2.0),
            v3(0.0, 2.0, 0.0),
        ),
        (
            "ceiling-back",
            1,
            v3(0.0, 2.0, 0.0),
            v3(2.0, 0.0, 0.0),
            v3(0.0, 0.0, 0.7),
        ),
        (
            "ceiling-front",
            1,
            v3(0.0, 2.0, 1.3),
            v3(2.0, 0.0, 0.0),
            v3(0.0, 0.0, 0.7),
        ),
        (
            "ceiling-left",
            1,
            v3(0.0, 2.0, 0.7),
            v3(0.7, 0.0, 0.0),
            v3(0.0, 0.0, 0.6),
        ),
        (
            "ceiling-right",
            1,
            v3(1.3, 2.0, 0.7),
            v3(0.7, 0.0, 0.0),
            v3(0.0, 0.0, 0.6),
        ),
        (
            "light",
            4,
            v3(0.7, 2.0, 0.7),
            v3(0.6, 0.0, 0.0),
            v3(0.0, 0.0, 0.6),
        ),
    ];
    let mut meshes = Vec::new();
    let mut nodes = Vec::new();
    for (name, material, o, u, v) in quads {
        let positions = vec![o, o + u, o + u + v, o + v];
        let normal = u.cross(v).normalize();
        let textured = material == 0;
        meshes.push(GlbMesh {
            name: name.to_string(),
            primitives: vec![GlbPrimitive {
                uv0: textured.then(|| positions.iter().map(|p| Vec2::new(p.x, p.z)).collect()),
                normals: Some(vec![normal; 4]),
                positions,
                uv1: None,
                indices: vec![[0, 1, 2], [0, 2, 3]],
                material: Some(material),
            }],
        });
        nodes.push(GlbNode::new(name, Some(meshes.len() - 1)));
    }
    GlbScene {
        materials,
        images: vec![GlbImage {
            name: "checker".to_string(),
            png: checker_png(),
        }],
        meshes,
        roots: (0..nodes.len()).collect(),
        nodes,
    }
}

/// Writes the room to a file of its own and loads it with `density` texels
/// per metre.
fn load_room(tag: &str, density: f32) -> (Scene, Atlas) {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR"));
    let path = dir.join(format!("textured-room-{tag}.glb"));
    std::fs::write(&path, room().to_glb().expect("the room writes")).expect("temp file");
    let default = Scene::load_with(&path, LoadOptions::default()).expect("the room loads");
    let density_scale = density / default.texel_density;
    load_scene(&path, LoadOptions::scaled(density_scale)).expect("the room loads")
}

fn is_floor(scene: &Scene, patch: u32) -> bool {
    scene.patches[patch as usize].name.starts_with("floor/")
}

#[test]
fn a_textured_floors_texels_hold_the_texture_averaged_over_their_footprint() {
    let (scene, atlas) = load_room("texels", 12.0);
    let floor: Vec<usize> = (0..atlas.elements.len())
        .filter(|&i| {
            is_floor(&scene, atlas.elements[i].patch) && atlas.elements[i].covers_surface()
        })
        .collect();
    assert!(floor.len() > 400, "{} floor texels", floor.len());
    assert!(
        floor
            .iter()
            .all(|&i| scene.patches[atlas.elements[i].patch as usize]
                .albedo_map
                .is_some()),
        "every floor triangle carries its texture"
    );
    let (bright, dark) = (floor_albedo(0.1, 0.1), floor_albedo(0.6, 0.1));
    let contrast = bright - dark;
    // Each texel against a 48 × 48 average of the checker over its region,
    // computed in world space.
    let mut errors = Vec::new();
    let mut weighted = (0.0f64, 0.0f64);
    for &i in &floor {
        let e = &atlas.elements[i];
        let shape = &scene.patches[e.patch as usize].shape;
        let (origin, u, v) = shape.frame();
        let [s0, t0, s1, t1] = e.region;
        let (mut sum, mut n) = (0.0f32, 0u32);
        for j in 0..48 {
            for k in 0..48 {
                let s = s0 + (s1 - s0) * (k as f32 + 0.5) / 48.0;
                let t = t0 + (t1 - t0) * (j as f32 + 0.5) / 48.0;
                if shape.is_triangle() && t > s {
                    continue;
                }
                let p = origin + u * s + v * t;
                sum += floor_albedo(p.x, p.z);
                n += 1;
            }
        }
        let expected = sum / n.max(1) as f32;
        let got = e.albedo;
        assert!(
            got.x == got.y && got.y == got.z,
            "grey texture, grey albedo: {got}"
        );
        errors.push((got.x - expected).abs() / contrast);
        weighted.0 += f64::from(e.area * got.x);
        weighted.1 += f64::from(e.area);
    }
    let mean = errors.iter().sum::<f32>() / errors.len() as f32;
    let worst = errors.iter().cloned().fold(0.0, f32::max);
    eprintln!(
        "{} floor texels: |albedo - footprint average| / contrast mean {:.4}, worst {:.4}",
        floor.len(),
        mean,
        worst
    );
    // Sampled 8 × 8 at least: a square's edge across a texel costs at most
    // 1/16 of the contrast (two edges, a corner: 1/8).
    assert!(
        worst <= 0.125,
        "worst texel {worst} of the contrast off its footprint's average"
    );
    assert!(mean <= 0.02, "mean {mean} of the contrast off");
    // Over the floor, the albedo averages to the checker's mean.
    let mean_albedo = (weighted.0 / weighted.1) as f32;
    let expected = 0.5 * (bright + dark);
    assert!(
        (mean_albedo - expected).abs() <= 0.01 * expected,
        "floor's mean albedo {mean_albedo} vs the checker's {expected}"
    );
    // Texels inside one square hold its albedo exactly (nearest filter).
    assert!(
        floor
            .iter()
            .any(|&i| (atlas.elements[i].albedo.x - bright).abs() < 1e-5)
    );
    assert!(
        floor
            .iter()
            .any(|&i| (atlas.elements[i].albedo.x - dark).abs() < 1e-5)
    );
}

/// The reference solver (element albedos, the texture averaged per texel)
/// against the path tracer (the texture looked up at every bounce): as for
/// the untextured coloured room, within 1% NRMSE plus the path tracer's
/// noise.
#[test]
fn path_tracer_agrees_with_the_reference_solver_over_a_textured_floor() {
    let (scene, atlas) = load_room("oracle", 6.0);
    let poses = scene.initial_poses();
    let solver =
        ReferenceSolver::new(&scene, &atlas, &poses, &reference::Silent).expect("small scene");
    let solution = solver.solve(SolveOptions::default(), &reference::Silent);
    let spp = 4096;
    let tracer = PathTracer::new(&scene, &poses);
    let estimates = tracer.estimate_elements(&atlas, spp, &Silent);
    let values: Vec<Vec3> = estimates.iter().map(|e| e.mean).collect();
    let noise = pathtrace::noise_summary(&atlas, &estimates);
    let accuracy = accuracy::accuracy(&atlas, &values, &solution.radiosity).expect("lit room");
    // The walls see the floor: what they receive from it depends on the
    // texture through both solvers' bounces.
    let walls = |b: &[Vec3]| -> f64 {
        let (mut sum, mut area) = (0.0, 0.0);
        for (e, b) in atlas.elements.iter().zip(b) {
            let name = &scene.patches[e.patch as usize].name;
            if ["back/", "front/", "left/", "right/"]
                .iter()
                .any(|w| name.starts_with(w))
            {
                sum += f64::from(e.area * b.x);
                area += f64::from(e.area);
            }
        }
        sum / area
    };
    let report = format!(
        "{} elements, path tracer at {spp} spp (noise NRMSE {:.2}%) vs reference: {accuracy}; walls' mean red radiosity {:.4} (path tracer) vs {:.4} (reference)",
        atlas.elements.len(),
        noise.noise_nrmse * 100.0,
        walls(&values),
        walls(&solution.radiosity),
    );
    eprintln!("textured room: {report}");
    assert!(noise.noise_nrmse < 0.015, "too noisy to judge: {report}");
    let bound = 0.01 + noise.noise_nrmse;
    assert!(
        accuracy.nrmse <= bound,
        "{report}; bound {:.2}%",
        bound * 100.0
    );
    // The texture is in the light: the floor's texels are as different
    // as its squares.
    let floor: Vec<f32> = (0..atlas.elements.len())
        .filter(|&i| {
            is_floor(&scene, atlas.elements[i].patch) && atlas.elements[i].covers_surface()
        })
        .map(|i| solution.radiosity[i].x)
        .collect();
    let (lo, hi) = floor.iter().fold((f32::INFINITY, 0.0f32), |(lo, hi), v| {
        (lo.min(*v), hi.max(*v))
    });
    assert!(
        lo < 0.2 * hi,
        "floor from {lo} to {hi}: the checker does not show"
    );
}
