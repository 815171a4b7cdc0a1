//! What stitching the seams between lightmap islands costs a publication
//! (`scene/src/atlas/stitch.rs`): a floor of `N` x `N` cells, each its own
//! island of the floor's lightmap (scattered, transposed), so that every
//! cell edge is a seam. Prints the atlas build and `Atlas::to_image` without
//! the seams' adjustment, with it on the first call, and with it on later
//! calls whose light changes by 1% each (as a publication's does).
//!
//! `cargo run --release -p lightwire-scene --example seam_cost -- 20`

use lightwire_scene::atlas::Atlas;
use lightwire_scene::{LoadOptions, Scene};
fn main() {
    let n: usize = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(20);
    let mut pos = Vec::new();
    let mut uvs = Vec::new();
    let mut idx = Vec::new();
    let cell = 1.0 / n as f32;
    for j in 0..n {
        for i in 0..n {
            let b = pos.len();
            let (x0, z0) = (i as f32, -(j as f32));
            pos.extend([
                [x0, 0.0, z0],
                [x0 + 1.0, 0.0, z0],
                [x0 + 1.0, 0.0, z0 - 1.0],
                [x0, 0.0, z0 - 1.0],
            ]);
            // Each cell its own island, scattered (transposed) in the lightmap.
            let (u0, v0) = (j as f32 * cell + 0.1 * cell, i as f32 * cell + 0.1 * cell);
            let s = 0.8 * cell;
            uvs.extend([[u0, v0], [u0 + s, v0], [u0 + s, v0 + s], [u0, v0 + s]]);
            idx.extend([b, b + 1, b + 2, b, b + 2, b + 3]);
        }
    }
    let text = format!(
        r#"{{ "name": "islands", "lightmap": {{ "texel_density": 12, "max_atlas_size": 8192 }},
        "materials": [ {{ "name": "m", "albedo": [0.5, 0.5, 0.5], "emission": [1, 1, 1] }} ],
        "surfaces": [ {{ "name": "floor", "material": "m", "mesh": {{ "positions": {:?}, "indices": {:?}, "lightmap_uvs": {:?} }} }} ] }}"#,
        pos, idx, uvs
    );
    let scene = Scene::parse_with(&text, "inline", LoadOptions::default()).expect("a valid scene");
    let t = std::time::Instant::now();
    let atlas = Atlas::build(&scene).expect("it fits");
    let build = t.elapsed();
    let values: Vec<glam::Vec3> = atlas
        .elements
        .iter()
        .map(|e| glam::Vec3::splat(e.position.x * 0.1 + (e.position.z * 3.0).sin()))
        .collect();
    let mut plain = atlas.clone();
    plain.island_seams = Default::default();
    let t = std::time::Instant::now();
    for _ in 0..5 {
        std::hint::black_box(plain.to_image(&values));
    }
    let base = t.elapsed() / 5;
    let t = std::time::Instant::now();
    std::hint::black_box(atlas.to_image(&values));
    let first = t.elapsed();
    let t = std::time::Instant::now();
    for k in 1..=5 {
        let changed: Vec<glam::Vec3> = values
            .iter()
            .map(|v| *v * (1.0 + 0.01 * k as f32))
            .collect();
        std::hint::black_box(atlas.to_image(&changed));
    }
    let later = t.elapsed() / 5;
    println!(
        "{n}x{n} islands: {} patches, {} elements, atlas {}x{}, {} seam equations over {} texels; build {:?}; to_image {:?} without seams, with them {:?} first, {:?} later",
        scene.patches.len(),
        atlas.elements.len(),
        atlas.width,
        atlas.height,
        atlas.island_seams.len(),
        atlas.island_seams.texels().len(),
        build,
        base,
        first,
        later
    );
}
