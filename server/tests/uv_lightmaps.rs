//! The light in an asset's own lightmap UVs (`uvmap::resample_all`, the
//! `uv-lightmaps/` of `lightwire bake`).
//!
//! The contract: a pixel of a mesh's lightmap whose centre lies on one of
//! the mesh's `TEXCOORD_1` triangles holds the light an engine shows at the
//! surface point that centre stands for when it draws Lightwire's own
//! `scene.glb` (the atlas on Lightwire's charts); a pixel within the
//! padding of a triangle holds the light of the nearest triangle's nearest
//! point; pixels beyond it stay black.
//!
//! The expected values take the other road, independently of `uvmap`: the
//! exported `scene.glb` is imported again, the point is found on one of its
//! triangles, and the atlas is read bilinearly at that triangle's
//! interpolated `TEXCOORD_1`. The atlas holds a different value in every
//! texel, so a pixel mapped to the wrong patch, chart, orientation or row
//! shows. Checked on the triangulated Cornell box (one chart per face in
//! the asset, one patch per face or per triangle here), the dynamic Cornell
//! box (its box in object space) and the atrium (columns whose unrolled
//! side is one chart over many patches).

// The solver-level tests' helpers (`gradient`, `filtered`), not copied.
#[path = "../../solve/tests/common/mod.rs"]
mod common;

use glam::{Vec2, Vec3};
use lightwire_scene::atlas::Atlas;
use lightwire_scene::gltf::{ImportOptions, import_slice};
use lightwire_scene::uvmap::{self, PADDING};
use lightwire_scene::{Charts, LoadOptions, Scene};
use lightwire_server::bake::{describe, scene_glb};
use lightwire_testkit::scene_path;

use common::{filtered, gradient};

/// Barycentric coordinates of `p` in the 2D triangle `q`.
fn barycentric(q: &[Vec2; 3], p: Vec2) -> Vec3 {
    let m = glam::Mat2::from_cols(q[1] - q[0], q[2] - q[0]);
    let b = m.inverse() * (p - q[0]);
    Vec3::new(1.0 - b.x - b.y, b.x, b.y)
}

/// The distance from `p` to the 2D triangle `q` and the barycentric
/// coordinates of its nearest point.
fn nearest_point(q: &[Vec2; 3], p: Vec2) -> (f32, Vec3) {
    let b = barycentric(q, p);
    if b.min_element() >= 0.0 {
        return (0.0, b);
    }
    let mut best = (f32::INFINITY, Vec3::ZERO);
    for (i, j) in [(0, 1), (1, 2), (2, 0)] {
        let e = q[j] - q[i];
        let s = ((p - q[i]).dot(e) / e.length_squared()).clamp(0.0, 1.0);
        let d = (q[i] + e * s).distance(p);
        if d < best.0 {
            let mut b = Vec3::ZERO;
            b[i] = 1.0 - s;
            b[j] = s;
            best = (d, b);
        }
    }
    best
}

/// A triangle of the re-imported `scene.glb`: object-space corners and
/// their `TEXCOORD_1`.
struct Drawn {
    object: String,
    corners: [Vec3; 3],
    uv1: [Vec2; 3],
}

/// The light at object-space point `p` of `object` as a client draws
/// `scene.glb`: on the drawn triangle that holds `p`, if one does.
fn drawn_light(
    drawn: &[Drawn],
    object: &str,
    p: Vec3,
    normal: Vec3,
    image: &[[f32; 3]],
    atlas: &Atlas,
) -> Option<Vec3> {
    for d in drawn.iter().filter(|d| d.object == object) {
        let [a, b, c] = d.corners;
        let n = (b - a).cross(c - a);
        if n.normalize().dot(normal) < 0.999 || (p - a).dot(n.normalize()).abs() > 1e-4 {
            continue;
        }
        // Barycentric coordinates in the triangle's plane.
        let (e1, e2, q) = (b - a, c - a, p - a);
        let (d11, d12, d22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
        let (q1, q2) = (q.dot(e1), q.dot(e2));
        let det = d11 * d22 - d12 * d12;
        let s = (d22 * q1 - d12 * q2) / det;
        let t = (d11 * q2 - d12 * q1) / det;
        if s < -1e-4 || t < -1e-4 || s + t > 1.0 + 1e-4 {
            continue;
        }
        let uv = d.uv1[0] * (1.0 - s - t) + d.uv1[1] * s + d.uv1[2] * t;
        return Some(filtered(image, atlas, uv));
    }
    None
}

fn check(name: &str, charts: Charts) {
    let options = LoadOptions {
        charts,
        ..LoadOptions::scaled(1.0)
    };
    let scene = Scene::load_with(&scene_path(name), options)
        .unwrap_or_else(|e| panic!("{name} must load: {e}"));
    let atlas = Atlas::build(&scene).unwrap_or_else(|e| panic!("{name} must fit: {e}"));
    assert!(
        !scene.uv_meshes.is_empty(),
        "{name} has meshes with TEXCOORD_1"
    );
    let image = gradient(&atlas);
    let glb = scene_glb(
        &describe(&scene, &atlas, &scene.initial_poses()),
        &image,
        None,
    )
    .expect("scene.glb");
    let exported = import_slice(&glb, None, "scene.glb", &ImportOptions::default())
        .expect("the exported scene.glb imports");
    let drawn: Vec<Drawn> = exported
        .instances
        .iter()
        .flat_map(|inst| {
            let object = exported.objects[inst.object as usize].name.clone();
            let uv1 = inst.lightmap_uvs.clone().expect("exported with TEXCOORD_1");
            inst.indices
                .iter()
                .map(|t| Drawn {
                    object: object.clone(),
                    corners: t.map(|i| inst.positions[i as usize]),
                    uv1: t.map(|i| uv1[i as usize]),
                })
                .collect::<Vec<_>>()
        })
        .collect();
    let maps = uvmap::resample_all(&scene, &atlas, &image, None);
    assert_eq!(maps.len(), scene.uv_meshes.len());
    for (mesh, map) in scene.uv_meshes.iter().zip(&maps) {
        let at = format!("{name} ({charts:?}) {}", mesh.name);
        assert_eq!(map.unplaced, 0, "{at}: every triangle lies on a patch");
        let object = &scene.objects[mesh.object as usize].name;
        let size = Vec2::new(map.width as f32, map.height as f32);
        let uv_tris: Vec<[Vec2; 3]> = mesh.uvs.iter().map(|t| t.map(|c| c * size)).collect();
        // At most about 1,500 pixels per mesh (debug builds are slow).
        let stride = ((map.width as usize * map.height as usize) / 1500).max(1);
        let (mut on, mut near, mut far) = (0, 0, 0);
        for i in (0..map.pixels.len()).step_by(stride) {
            let (x, y) = (i as u32 % map.width, i as u32 / map.width);
            let c = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
            let got = Vec3::from(map.pixels[i]);
            let inside = uv_tris.iter().zip(&mesh.triangles).find_map(|(q, tri)| {
                let b = barycentric(q, c);
                (b.min_element() > 1e-3).then_some((b, tri))
            });
            if let Some((b, tri)) = inside {
                let p = tri[0] * b.x + tri[1] * b.y + tri[2] * b.z;
                let normal = (tri[1] - tri[0]).cross(tri[2] - tri[0]).normalize();
                let expected = drawn_light(&drawn, object, p, normal, &image, &atlas)
                    .unwrap_or_else(|| {
                        panic!("{at}: pixel ({x}, {y}) stands for {p}, on no drawn triangle")
                    });
                assert!(
                    (got - expected).abs().max_element() <= 2e-3 * expected.max_element().max(1.0),
                    "{at}: pixel ({x}, {y}) at {p}: {got} vs {expected} drawn"
                );
                on += 1;
                continue;
            }
            // Outside every triangle: within the padding, the light of the
            // nearest triangle's nearest point (any of those equally near);
            // black beyond it.
            let nearest: Vec<(f32, Vec3)> = uv_tris
                .iter()
                .zip(&mesh.triangles)
                .map(|(q, tri)| {
                    let (d, b) = nearest_point(q, c);
                    (d, tri[0] * b.x + tri[1] * b.y + tri[2] * b.z)
                })
                .collect();
            let distance = nearest.iter().map(|n| n.0).fold(f32::INFINITY, f32::min);
            if distance <= PADDING - 0.01 {
                let matches = nearest.iter().zip(&mesh.triangles).any(|((d, p), tri)| {
                    if *d > distance + 1e-3 {
                        return false;
                    }
                    let normal = (tri[1] - tri[0]).cross(tri[2] - tri[0]).normalize();
                    drawn_light(&drawn, object, *p, normal, &image, &atlas).is_some_and(
                        |expected| {
                            (got - expected).abs().max_element()
                                <= 2e-3 * expected.max_element().max(1.0)
                        },
                    )
                });
                assert!(
                    matches,
                    "{at}: padding pixel ({x}, {y}), {distance} px from a triangle: {got} is no nearest point's light"
                );
                near += 1;
            } else if distance > PADDING + 0.01 {
                assert_eq!(
                    got,
                    Vec3::ZERO,
                    "{at}: pixel ({x}, {y}) is {distance} px from every triangle"
                );
                far += 1;
            }
        }
        assert!(on >= 100, "{at}: only {on} pixels checked on triangles");
        eprintln!(
            "{at}: {}x{} px, {on} on triangles, {near} padding, {far} empty checked",
            map.width, map.height
        );
    }
}

#[test]
fn the_triangulated_cornell_box_reads_its_light_in_its_own_uvs() {
    check("meshes/cornell-large.glb", Charts::Parallelograms);
    check("meshes/cornell-large.glb", Charts::Triangles);
    // Lit on those UVs (`atlas/uv.rs`): the exported scene.glb carries them.
    check("meshes/cornell-large.glb", Charts::LightmapUvs);
}

#[test]
fn a_dynamic_mesh_reads_its_light_in_its_own_uvs() {
    check("meshes/cornell-dynamic.glb", Charts::Parallelograms);
    check("meshes/cornell-dynamic.glb", Charts::LightmapUvs);
}

#[test]
fn the_atrium_reads_its_light_in_its_own_uvs() {
    check("meshes/atrium.glb", Charts::Parallelograms);
    check("meshes/atrium.glb", Charts::LightmapUvs);
}

/// `lightwire serve` serves the same lightmaps for its newest version:
/// `GET /api/scenes/{id}/uv-lightmaps` lists them as `bake` does, and each
/// file is `uvmap::resample` of the lightmap snapshot of the same version,
/// bit for bit; names that are not listed are 404.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_server_serves_the_lightmaps_in_the_assets_own_uvs() {
    use lightwire_testkit::{http, lightwire};
    let path = scene_path("meshes/cornell-large.glb");
    let server =
        lightwire!().serve_dev_on(&path, &["--solver", "reference", "--density-scale", "0.3"]);
    server.ready().await;
    let file = async |name: &str| {
        http::get(
            &server.addr,
            &format!("/api/scenes/cornell-large/{name}"),
            None,
        )
        .await
    };
    let list = file("uv-lightmaps").await;
    assert_eq!(list.status, 200, "{}", list.text());
    let list = list.json();
    let entries = list["uv_lightmaps"].as_array().expect("a list");
    assert_eq!(entries.len(), 7, "{list}");
    let box_entry = entries
        .iter()
        .find(|e| e["mesh"] == "box/box")
        .expect("the box's mesh");
    let exr_path = box_entry["exr"].as_str().expect("exr");
    // A version that holds still: the reference solver publishes once.
    let (version, atlas_rgb, served) = loop {
        let snapshot = file("lightmap.exr").await;
        let uv = file(exr_path).await;
        assert_eq!(uv.status, 200, "{}", uv.text());
        assert_eq!(uv.header("content-type"), Some("image/x-exr"));
        let v = snapshot.version();
        if v.is_some() && v == uv.version() {
            break (v, snapshot.exr_rgb(), uv.exr_rgb());
        }
    };
    assert!(version.is_some());
    let options = LoadOptions::scaled(0.3);
    let scene = Scene::load_with(&path, options).expect("loads");
    let atlas = Atlas::build(&scene).expect("fits");
    let k = scene
        .uv_meshes
        .iter()
        .position(|m| m.name == "box/box")
        .expect("the box");
    let locator = uvmap::Locator::new(&scene.patches);
    let size = uvmap::default_size(&scene, &scene.uv_meshes[k]);
    let expected = uvmap::resample(&locator, &atlas, &atlas_rgb, &scene.uv_meshes[k], size);
    assert_eq!(
        (
            Some(u64::from(expected.width)),
            Some(u64::from(expected.height))
        ),
        (box_entry["width"].as_u64(), box_entry["height"].as_u64())
    );
    assert!(
        served == expected.pixels,
        "the served EXR is the resampled snapshot"
    );
    assert!(served.iter().any(|p| p[0] > 0.0), "lit");
    for bad in [
        "uv-lightmaps/06-box_box.jpg",
        "uv-lightmaps/07-box_box.exr",
        "uv-lightmaps/06-nope.exr",
        "uv-lightmaps/x.exr",
    ] {
        let r = file(bad).await;
        assert_eq!(r.status, 404, "{bad}: {}", r.text());
    }
}

/// `scene` solved by the reference solver to 1e-4 unshot and published
/// (`Validity::fill`, `Atlas::to_image`), and the same image without the
/// adjustment of the seams between lightmap islands.
fn reference_images(scene: &Scene, atlas: &Atlas) -> (Vec<[f32; 3]>, Vec<[f32; 3]>) {
    use lightwire_scene::atlas::IslandSeams;
    use lightwire_solve::solver::{self, SolverKind, SolverSettings};
    let poses = scene.initial_poses();
    let mut solver = solver::build(
        SolverKind::Reference,
        scene,
        atlas,
        &poses,
        &SolverSettings::default(),
        &solver::Silent,
    )
    .unwrap_or_else(|e| panic!("{e}"));
    solver.solve(1e-4).unwrap_or_else(|e| panic!("{e}"));
    let mut values = solver.radiosity().unwrap_or_else(|e| panic!("{e}"));
    lightwire_solve::validity::Validity::compute(scene, atlas, &poses).fill(atlas, &mut values);
    let mut plain = atlas.clone();
    plain.island_seams = IslandSeams::default();
    (atlas.to_image(&values), plain.to_image(&values))
}

/// Where `uv`, a coordinate in the own lightmap of mesh `k`, lies in the
/// atlas (normalized): in the mesh's block.
fn in_block(atlas: &Atlas, k: usize, uv: Vec2) -> Vec2 {
    let block = atlas.blocks[k].unwrap_or_else(|| panic!("mesh {k} has a block"));
    (Vec2::new(block.x as f32, block.y as f32) + uv * block.w as f32)
        / Vec2::new(atlas.width as f32, atlas.height as f32)
}

/// 2% of the 95th percentile of `image`'s brightest channel: how bright
/// a reading must be to be judged against itself in [`relative_step`].
fn dark_floor(image: &[[f32; 3]]) -> f32 {
    let mut lum: Vec<f32> = image.iter().map(|p| p[0].max(p[1]).max(p[2])).collect();
    lum.sort_by(f32::total_cmp);
    0.02 * lum[lum.len() * 95 / 100]
}

/// How far apart two readings of the light are: their largest channel
/// difference over the brighter one, or over `floor` where both are
/// darker.
fn relative_step(a: Vec3, b: Vec3, floor: f32) -> f32 {
    (a - b).abs().max_element() / a.max_element().max(b.max_element()).max(floor)
}

/// A floor of two islands of its own lightmap: the left half of the floor
/// in the lower left of its `[0, 1]²`, the right half in the upper right,
/// turned a quarter (its `x` along `v`), so that the seam between them (the
/// line `x = 1`) is read from two unrelated rows of texels. A small lamp
/// just off the seam lights the floor steeply across it.
const TWO_ISLANDS: &str = r#"{
    "name": "two-islands",
    "lightmap": { "texel_density": 10 },
    "materials": [
        { "name": "white", "albedo": [0.7, 0.7, 0.7] },
        { "name": "lamp", "albedo": [0.5, 0.5, 0.5], "emission": [10, 10, 10] }
    ],
    "surfaces": [
        { "name": "floor", "material": "white", "mesh": {
            "positions": [[0, 0, 0], [1, 0, 0], [1, 0, -1], [0, 0, -1],
                          [1, 0, 0], [2, 0, 0], [2, 0, -1], [1, 0, -1]],
            "indices": [0, 1, 2, 0, 2, 3, 4, 5, 6, 4, 6, 7],
            "lightmap_uvs": [[0.05, 0.05], [0.45, 0.05], [0.45, 0.45], [0.05, 0.45],
                             [0.55, 0.55], [0.55, 0.95], [0.95, 0.95], [0.95, 0.55]] } },
        { "name": "lamp", "material": "lamp", "quad": {
            "origin": [1.1, 0.3, -0.2], "u": [0, 0, -0.5], "v": [0.3, 0, 0] } }
    ]
}"#;

/// Issue 18, item 3: texels on either side of a seam between two islands
/// of a mesh's own lightmap agree. The floor of [`TWO_ISLANDS`], solved by
/// the reference solver on its own UVs, is read as an engine reads it on
/// its own mesh (bilinearly, at each side's `TEXCOORD_1` placed in the
/// mesh's block of the atlas) at 64 points along the seam. Published
/// (`Atlas::to_image`), the two sides agree within 1% of the brighter (or
/// of 2% of the image's 95th percentile, where both are darker); without
/// the seam's least-squares adjustment (`atlas/stitch.rs`) they differ by
/// more than 5% somewhere, so the test fails without it. Only the texels the
/// seam's equations read change.
#[test]
fn both_sides_of_a_seam_between_lightmap_islands_read_alike() {
    let options = LoadOptions {
        charts: Charts::LightmapUvs,
        ..LoadOptions::scaled(1.0)
    };
    let scene = Scene::parse_with(TWO_ISLANDS, "inline", options).unwrap_or_else(|e| panic!("{e}"));
    let atlas = Atlas::build(&scene).unwrap_or_else(|e| panic!("{e}"));
    let on_uvs = scene
        .patches
        .iter()
        .filter(|p| p.lightmap.is_some())
        .count();
    assert_eq!(on_uvs, 2, "each island one parallelogram");
    assert!(
        atlas.island_seams.len() >= 20,
        "{} seam points",
        atlas.island_seams.len()
    );
    let (stitched, raw) = reference_images(&scene, &atlas);
    let in_atlas = |uv: Vec2| in_block(&atlas, 0, uv);
    let floor = dark_floor(&stitched);
    let worst = |image: &[[f32; 3]]| {
        (0..64)
            .map(|k| {
                let along = (k as f32 + 0.5) / 64.0;
                // The point (1, 0, -along) on either island.
                let left = filtered(image, &atlas, in_atlas(Vec2::new(0.45, 0.05 + 0.4 * along)));
                let right = filtered(image, &atlas, in_atlas(Vec2::new(0.55 + 0.4 * along, 0.55)));
                (relative_step(left, right, floor), along, left, right)
            })
            .fold((0.0f32, 0.0, Vec3::ZERO, Vec3::ZERO), |a, b| {
                if b.0 > a.0 { b } else { a }
            })
    };
    let (before, ..) = worst(&raw);
    let (after, along, left, right) = worst(&stitched);
    eprintln!(
        "seam between two islands: worst {:.2}% unstitched, {:.2}% published (at {along}: {left} vs {right}), {} equations over {} texels",
        before * 100.0,
        after * 100.0,
        atlas.island_seams.len(),
        atlas.island_seams.texels().len()
    );
    assert!(before > 0.05, "unstitched the sides differ: {before}");
    assert!(
        after <= 0.01,
        "published they agree: {after} at {along}: {left} vs {right}"
    );
    let touched: std::collections::HashSet<u32> =
        atlas.island_seams.texels().iter().copied().collect();
    for (t, (a, b)) in stitched.iter().zip(&raw).enumerate() {
        if a != b {
            assert!(
                touched.contains(&(t as u32)),
                "texel {t} changed but no seam reads it"
            );
        }
    }
}

/// Generated lightmap UVs (`scene/unwrap.rs`, issue 18 item 2): a static
/// mesh without `TEXCOORD_1` is lit on UVs Lightwire makes by default, and
/// they pass the checks an asset's `TEXCOORD_1` gets (inside [0, 1], no
/// overlap, no zero area); `--charts parallelograms` keeps Lightwire's own
/// charts; `--charts generated` lights every static mesh on generated UVs
/// while the asset's own stay for `uv-lightmaps/`, marked apart.
#[test]
fn meshes_without_lightmap_uvs_are_lit_on_generated_ones() {
    use lightwire_scene::gltf::find_uv_overlaps;
    let load = |name: &str, charts: Charts, scale: f32| {
        let options = LoadOptions {
            charts,
            ..LoadOptions::scaled(scale)
        };
        Scene::load_with(&scene_path(name), options).unwrap_or_else(|e| panic!("{name}: {e}"))
    };

    let sphere = load("meshes/furnace-sphere.glb", Charts::LightmapUvs, 0.1);
    assert_eq!(sphere.uv_meshes.len(), 1);
    let mesh = &sphere.uv_meshes[0];
    assert!(mesh.generated);
    assert_eq!(mesh.uvs.len(), 960);
    assert!(
        sphere
            .patches
            .iter()
            .all(|p| p.lightmap.is_some_and(|l| l.mesh == 0))
    );
    for uv in mesh.uvs.iter().flatten() {
        assert!(
            (0.0..=1.0).contains(&uv.x) && (0.0..=1.0).contains(&uv.y),
            "{uv}"
        );
    }
    for t in &mesh.uvs {
        let twice = (t[1] - t[0]).perp_dot(t[2] - t[0]).abs();
        assert!(twice > 1e-9, "{t:?}");
    }
    let overlaps = find_uv_overlaps(&mesh.uvs, 4).expect("checkable");
    assert!(overlaps.is_empty(), "{overlaps:?}");
    let atlas = Atlas::build(&sphere).unwrap_or_else(|e| panic!("{e}"));
    assert!(
        atlas.blocks[0].is_some(),
        "the generated lightmap is a block"
    );

    let own = load("meshes/furnace-sphere.glb", Charts::Parallelograms, 0.1);
    assert!(own.patches.iter().all(|p| p.lightmap.is_none()));

    // The atrium brings TEXCOORD_1 on every mesh: by default it is lit on
    // those, with `generated` on new ones.
    let atrium = load("meshes/atrium.glb", Charts::LightmapUvs, 0.3);
    assert!(atrium.uv_meshes.iter().all(|m| !m.generated));
    let generated = load("meshes/atrium.glb", Charts::Generated, 0.3);
    let lit: Vec<usize> = generated
        .patches
        .iter()
        .filter(|p| p.object == 0)
        .map(|p| p.lightmap.expect("every static patch on a lightmap").mesh as usize)
        .collect();
    assert!(lit.iter().all(|&m| generated.uv_meshes[m].generated));
    let own_meshes = generated.uv_meshes.iter().filter(|m| !m.generated).count();
    assert_eq!(
        own_meshes,
        atrium.uv_meshes.len(),
        "the asset's own UVs are kept"
    );
    for m in generated.uv_meshes.iter().filter(|m| m.generated) {
        let overlaps = find_uv_overlaps(&m.uvs, 4).expect("checkable");
        assert!(overlaps.is_empty(), "{}: {overlaps:?}", m.name);
    }
    Atlas::build(&generated).unwrap_or_else(|e| panic!("{e}"));
}

/// A grey material of `albedo` emitting `emission` (W/m² per channel).
fn grey(name: &str, albedo: f32, emission: f32) -> lightwire_scene::gltf::write::GlbMaterial {
    lightwire_scene::gltf::write::GlbMaterial {
        name: name.into(),
        base_color: Vec3::splat(albedo),
        emission: Vec3::splat(emission),
        base_color_texture: None,
    }
}

/// A `.glb` of two root nodes: `name` with a mesh of `primitives` (node and
/// mesh named alike) and `lamp` with one of the primitive `lamp`.
fn beside_a_lamp(
    name: &str,
    primitives: Vec<lightwire_scene::gltf::write::GlbPrimitive>,
    lamp: lightwire_scene::gltf::write::GlbPrimitive,
    materials: Vec<lightwire_scene::gltf::write::GlbMaterial>,
) -> Vec<u8> {
    use lightwire_scene::gltf::write::{GlbMesh, GlbNode, GlbScene};
    GlbScene {
        materials,
        images: Vec::new(),
        meshes: vec![
            GlbMesh {
                name: name.into(),
                primitives,
            },
            GlbMesh {
                name: "lamp".into(),
                primitives: vec![lamp],
            },
        ],
        nodes: vec![GlbNode::new(name, Some(0)), GlbNode::new("lamp", Some(1))],
        roots: vec![0, 1],
    }
    .to_glb()
    .unwrap_or_else(|e| panic!("write {name}: {e}"))
}

/// `glb` loaded (through a file named `file` in a temporary directory)
/// with lightmap UVs at `density_scale`, and the index of its uv mesh
/// `mesh`, which Lightwire generated.
fn load_generated(glb: &[u8], file: &str, density_scale: f32, mesh: &str) -> (Scene, usize) {
    let dir = std::env::temp_dir().join(format!("lightwire-{file}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap_or_else(|e| panic!("{e}"));
    let path = dir.join(file);
    std::fs::write(&path, glb).unwrap_or_else(|e| panic!("{e}"));
    let options = LoadOptions {
        charts: Charts::LightmapUvs,
        ..LoadOptions::scaled(density_scale)
    };
    let scene = Scene::load_with(&path, options).unwrap_or_else(|e| panic!("{e}"));
    let _ = std::fs::remove_dir_all(&dir);
    let k = scene
        .uv_meshes
        .iter()
        .position(|m| m.name == mesh)
        .unwrap_or_else(|| panic!("{mesh}'s generated UVs"));
    assert!(scene.uv_meshes[k].generated);
    (scene, k)
}

/// An octagonal prism (radius 0.5 m, 1 m tall, closed by two caps) beside
/// a small lamp facing it from +x, as a `.glb` without `TEXCOORD_1`. With
/// `smooth` the side's ring vertices are shared by neighbouring facets with
/// radial normals (an engine shades it as a cylinder); without, each facet
/// has its own vertices and face normal (hard edges).
fn prism_glb(smooth: bool) -> Vec<u8> {
    use lightwire_scene::gltf::write::GlbPrimitive;
    let sides = 8usize;
    let at = |i: usize, y: f32| {
        let phi = std::f32::consts::TAU * (i % sides) as f32 / sides as f32;
        Vec3::new(0.5 * phi.cos(), y, -0.5 * phi.sin())
    };
    // Positions with normals, without texture coordinates, in material 0.
    let empty = || GlbPrimitive {
        positions: Vec::new(),
        normals: Some(Vec::new()),
        uv0: None,
        uv1: None,
        indices: Vec::new(),
        material: Some(0),
    };
    let mut side = empty();
    let push = |p: &mut GlbPrimitive, x: Vec3, n: Vec3| {
        p.positions.push(x);
        if let Some(ns) = &mut p.normals {
            ns.push(n);
        }
        p.positions.len() as u32 - 1
    };
    for i in 0..sides {
        // Counter-clockwise seen from outside: φ grows towards −z.
        let (a, b) = (at(i, 0.0), at(i + 1, 0.0));
        let (c, d) = (at(i + 1, 1.0), at(i, 1.0));
        let face = (b - a).cross(d - a).normalize();
        let radial = |x: Vec3| Vec3::new(x.x, 0.0, x.z).normalize();
        let n = |x: Vec3| if smooth { radial(x) } else { face };
        let k = [a, b, c, d].map(|x| push(&mut side, x, n(x)));
        side.indices.push([k[0], k[1], k[2]]);
        side.indices.push([k[0], k[2], k[3]]);
    }
    if smooth {
        // Weld the ring: each position once (the importer keeps indices;
        // shared vertices with equal normals are what "smooth" means).
        let mut unique: Vec<(Vec3, Vec3)> = Vec::new();
        let mut remap = Vec::new();
        for (x, n) in side.positions.iter().zip(side.normals.iter().flatten()) {
            let k = unique
                .iter()
                .position(|(y, _)| (*y - *x).length() < 1e-6)
                .unwrap_or_else(|| {
                    unique.push((*x, *n));
                    unique.len() - 1
                });
            remap.push(k as u32);
        }
        side.indices = side
            .indices
            .iter()
            .map(|t| t.map(|i| remap[i as usize]))
            .collect();
        side.positions = unique.iter().map(|u| u.0).collect();
        side.normals = Some(unique.iter().map(|u| u.1).collect());
    }
    let mut caps = empty();
    for (y, up) in [(1.0f32, true), (0.0, false)] {
        let n = if up { Vec3::Y } else { Vec3::NEG_Y };
        let ring: Vec<u32> = (0..sides).map(|i| push(&mut caps, at(i, y), n)).collect();
        for i in 1..sides - 1 {
            let t = [ring[0], ring[i], ring[i + 1]];
            caps.indices.push(if up { t } else { [t[0], t[2], t[1]] });
        }
    }
    // The lamp: a 0.4 m square at x = 1.2 facing −x, centred at y = 0.5,
    // z = 0.25 (off the prism's axis, so facets on either side of a crease
    // see it differently).
    let mut lamp = GlbPrimitive {
        positions: Vec::new(),
        normals: None,
        uv0: None,
        uv1: None,
        indices: vec![[0, 1, 2], [0, 2, 3]],
        material: Some(1),
    };
    for (y, z) in [(0.3, 0.05), (0.3, 0.45), (0.7, 0.45), (0.7, 0.05)] {
        lamp.positions.push(Vec3::new(1.2, y, z));
    }
    beside_a_lamp(
        "prism",
        vec![side, caps],
        lamp,
        vec![grey("grey", 0.6, 0.0), grey("lamp", 0.5, 20.0)],
    )
}

/// Issue 18, item 3, on generated charts: a faceted surface the asset
/// shades smoothly shows no seams. Each of the octagonal prism's facets
/// (45° apart, over the unwrap's 30°) is a chart of its own, so every
/// vertical crease is a seam between two islands. Solved by the reference
/// solver and read as an engine reads the mesh (bilinearly at either
/// facet's generated UVs of the same point, 16 points up each crease):
/// with smooth normals the published sides agree within 2% (of the
/// brighter, or of 2% of the 95th percentile), where unstitched they differ
/// by more than 5% somewhere (the lamp lights neighbouring facets
/// differently); with hard normals the mesh has no smooth edges and its
/// creases keep their step.
#[test]
fn creases_an_asset_shades_smoothly_are_stitched_on_generated_charts() {
    let mut worst_of = Vec::new();
    for smooth in [true, false] {
        let file = format!("prism-{smooth}.glb");
        let (scene, k) = load_generated(&prism_glb(smooth), &file, 0.3, "prism/prism");
        let mesh = &scene.uv_meshes[k];
        // Coplanar neighbours always: the 8 facets' diagonals and the 5
        // inner edges of each cap's fan; smooth, the 8 creases too.
        let expect = if smooth { 26 } else { 18 };
        assert_eq!(mesh.smooth_edges.len(), expect, "smooth: {smooth}");
        let atlas = Atlas::build(&scene).unwrap_or_else(|e| panic!("{e}"));
        let (stitched, raw) = reference_images(&scene, &atlas);
        let in_atlas = |uv: Vec2| in_block(&atlas, k, uv);
        let floor = dark_floor(&stitched);
        // The UVs of point `x` on every side triangle whose edge holds it,
        // one per facet (by face normal).
        let sides_at = |x: Vec3| {
            let mut out: Vec<(Vec3, Vec2)> = Vec::new();
            for (tri, uv) in mesh.triangles.iter().zip(&mesh.uvs) {
                let n = (tri[1] - tri[0]).cross(tri[2] - tri[0]).normalize();
                if n.y.abs() > 0.5 || out.iter().any(|(m, _)| m.dot(n) > 0.999) {
                    continue;
                }
                for e in 0..3 {
                    let (a, b) = (tri[e], tri[(e + 1) % 3]);
                    let d = b - a;
                    let f = (x - a).dot(d) / d.length_squared();
                    if (0.0..=1.0).contains(&f) && (a + d * f - x).length() < 1e-5 {
                        out.push((n, uv[e].lerp(uv[(e + 1) % 3], f)));
                        break;
                    }
                }
            }
            out
        };
        let worst = |image: &[[f32; 3]]| {
            let mut worst = 0.0f32;
            for i in 0..8 {
                let phi = std::f32::consts::TAU * i as f32 / 8.0;
                for h in 0..16 {
                    let x = Vec3::new(0.5 * phi.cos(), (h as f32 + 0.5) / 16.0, -0.5 * phi.sin());
                    let sides = sides_at(x);
                    assert_eq!(sides.len(), 2, "two facets meet at {x}");
                    let a = filtered(image, &atlas, in_atlas(sides[0].1));
                    let b = filtered(image, &atlas, in_atlas(sides[1].1));
                    worst = worst.max(relative_step(a, b, floor));
                }
            }
            worst
        };
        let (before, after) = (worst(&raw), worst(&stitched));
        eprintln!(
            "prism, smooth normals {smooth}: worst crease step {:.2}% unstitched, {:.2}% published, {} seam equations",
            before * 100.0,
            after * 100.0,
            atlas.island_seams.len()
        );
        assert!(before > 0.05, "unstitched the facets differ: {before}");
        worst_of.push(after);
    }
    assert!(
        worst_of[0] <= 0.02,
        "smooth: published creases agree: {}",
        worst_of[0]
    );
    assert!(
        worst_of[1] > 0.05,
        "hard: the creases keep their step: {}",
        worst_of[1]
    );
}

/// A 1 m plate in the `y = 0` plane facing up, its left half (`x < 0`)
/// white (albedo 0.8) and its right half dark (0.1), two primitives of one
/// mesh sharing the edge `x = 0`, under a 0.4 m lamp centred over that
/// edge, as a `.glb` without `TEXCOORD_1`.
fn two_tone_plate_glb() -> Vec<u8> {
    use lightwire_scene::gltf::write::GlbPrimitive;
    // Counter-clockwise seen from +y: x then -z.
    let half = |x0: f32, x1: f32, material: usize| GlbPrimitive {
        positions: vec![
            Vec3::new(x0, 0.0, 0.5),
            Vec3::new(x1, 0.0, 0.5),
            Vec3::new(x1, 0.0, -0.5),
            Vec3::new(x0, 0.0, -0.5),
        ],
        normals: None,
        uv0: None,
        uv1: None,
        indices: vec![[0, 1, 2], [0, 2, 3]],
        material: Some(material),
    };
    // The lamp faces down: counter-clockwise seen from below.
    let lamp = GlbPrimitive {
        positions: vec![
            Vec3::new(-0.2, 0.6, -0.2),
            Vec3::new(0.2, 0.6, -0.2),
            Vec3::new(0.2, 0.6, 0.2),
            Vec3::new(-0.2, 0.6, 0.2),
        ],
        normals: None,
        uv0: None,
        uv1: None,
        indices: vec![[0, 1, 2], [0, 2, 3]],
        material: Some(2),
    };
    beside_a_lamp(
        "plate",
        vec![half(-0.5, 0.0, 0), half(0.0, 0.5, 1)],
        lamp,
        vec![
            grey("white", 0.8, 0.0),
            grey("dark", 0.1, 0.0),
            grey("lamp", 0.0, 20.0),
        ],
    )
}

/// A texel holds radiosity, albedo in it, so it stands for one material:
/// generated charts never join triangles of two materials and seams are
/// not stitched across them (`unwrap::unwrap_graded`,
/// `Scene::reflects_alike`). The two-tone plate, solved by the reference
/// solver and read as an engine reads it (bilinearly at each side's
/// generated UVs), 2 cm and 2 mm either side of the edge where the albedo
/// steps from 0.8 to 0.1 under a lamp centred over it: the irradiance
/// behind the two readings (each over its albedo) agrees within 10% at 16
/// points along the edge at each distance. One chart over both halves (or
/// the halves stitched together) shows the dark side several times too
/// bright.
#[test]
fn a_texel_holds_one_materials_light_on_generated_charts() {
    let (scene, k) = load_generated(&two_tone_plate_glb(), "plate.glb", 1.0, "plate/plate");
    let mesh = &scene.uv_meshes[k];
    assert_eq!(mesh.charts, 2, "one chart per material");
    let atlas = Atlas::build(&scene).unwrap_or_else(|e| panic!("{e}"));
    let (published, _) = reference_images(&scene, &atlas);
    // The UVs of the point `x` of the plate (y = 0), from the triangle
    // that holds it.
    let uv_at = |x: Vec3| -> Vec2 {
        for (tri, uv) in mesh.triangles.iter().zip(&mesh.uvs) {
            let flat = tri.map(|p| Vec2::new(p.x, p.z));
            let w = barycentric(&flat, Vec2::new(x.x, x.z));
            if w.min_element() >= -1e-5 {
                return uv[0] * w.x + uv[1] * w.y + uv[2] * w.z;
            }
        }
        panic!("no triangle holds {x}")
    };
    let mut worst = 0.0f32;
    for d in [0.02, 0.002] {
        for i in 0..16 {
            let z = -0.4 + 0.8 * (i as f32 + 0.5) / 16.0;
            let read = |x: f32| {
                let uv = in_block(&atlas, k, uv_at(Vec3::new(x, 0.0, z)));
                filtered(&published, &atlas, uv)
            };
            let (e_white, e_dark) = (read(-d).x / 0.8, read(d).x / 0.1);
            assert!(e_white > 0.0, "the white side is lit at z = {z}");
            worst = worst.max((e_dark / e_white - 1.0).abs());
        }
    }
    eprintln!(
        "two-tone plate: irradiance either side of the albedo step differs by at most {:.1}%",
        worst * 100.0
    );
    assert!(worst <= 0.10, "the dark side reads its own light: {worst}");
}
