//! glTF out (`bake::scene_glb`): the lit scene as `scene.glb`.
//!
//! - `lightwire bake` writes a `scene.glb` the Khronos glTF validator
//!   accepts with zero errors, whose embedded lightmap is `lightmap.png`
//!   pixel for pixel, shown by unlit materials on `TEXCOORD_1`, and which
//!   names `lightmap.exr`; the same file without its extension declared is
//!   refused, so the validator is really checking it;
//! - importing it again (`scene::gltf::import`) gives the same triangles in
//!   world space, the same materials and the same dynamic objects, and it
//!   opens as a scene of its own;
//! - every corner's `TEXCOORD_1` is the centre of its chart's corner texel,
//!   as the clients draw it (PROTOCOL.md §3);
//! - the bytes are deterministic, and the same from a `Scene` and from the
//!   wire's `SceneInfo` (what `lightwire serve` and a relay build it from);
//! - a description that does not fit (as a relay's upstream could send) is
//!   an error, not a panic.
//!
//! The REST route `GET /api/scenes/{id}/scene.glb` is tested with the other
//! snapshots in `rest_auth.rs`; here, that it keeps the scene's lights as
//! `bake` does, and `GET /api/scenes/{id}/lights`.

// The solver-level tests' helpers (`gradient`, `filtered`), not copied.
#[path = "../../solve/tests/common/mod.rs"]
mod common;

use std::path::{Path, PathBuf};

use glam::{Quat, Vec2, Vec3};
use lightwire_scene::atlas::Atlas;
use lightwire_scene::gltf::write::pack_glb;
use lightwire_scene::gltf::{ImportOptions, ImportedScene, import_slice};
use lightwire_scene::load::parse_scene;
use lightwire_scene::{LightKind, LoadOptions, Scene};
use lightwire_server::bake::{self, describe, scene_glb};
use lightwire_testkit::validator::khronos_validate;

use common::gradient;

/// A small room: a floor, a light, a wall of two mesh triangles, and a
/// dynamic crate turned 45° about y.
const ROOM: &str = r#"{
  "name": "export-room",
  "description": "glTF export test: quads, mesh triangles and a turned dynamic box",
  "lightmap": { "texel_density": 4, "max_atlas_size": 256 },
  "materials": [
    { "name": "light", "albedo": [0, 0, 0], "emission": [20, 18, 15] },
    { "name": "white", "albedo": [0.7, 0.7, 0.7] },
    { "name": "red", "albedo": [0.6, 0.1, 0.1] }
  ],
  "objects": [
    { "name": "crate", "pose": { "translation": [1.2, 0.25, 0.9], "rotation": [0, 0.38268343, 0, 0.92387953] } }
  ],
  "surfaces": [
    { "name": "floor", "material": "white", "quad": { "origin": [0, 0, 0], "u": [0, 0, 2], "v": [2, 0, 0] } },
    { "name": "light", "material": "light", "quad": { "origin": [0.75, 1.5, 0.75], "u": [0.5, 0, 0], "v": [0, 0, 0.5] } },
    { "name": "wall", "material": "red",
      "mesh": { "positions": [[0, 0, 0], [0, 1, 0], [0, 1, 2], [0, 0, 2]], "indices": [0, 1, 2, 0, 2, 3] } },
    { "name": "crate", "material": "white", "object": "crate", "box": { "center": [0, 0, 0], "size": [0.5, 0.5, 0.5] } }
  ]
}"#;

fn room() -> (Scene, Atlas) {
    // Unpaired: the wall's two triangles form a parallelogram, which would
    // otherwise be one quad patch; here they show how triangles export.
    let options = LoadOptions::unpaired(1.0);
    parse_scene(ROOM, "export-room.json", options).expect("the room loads")
}

fn exported(scene: &Scene, atlas: &Atlas) -> Vec<u8> {
    scene_glb(
        &describe(scene, atlas, &scene.initial_poses()),
        &gradient(atlas),
        None,
    )
    .expect("scene.glb")
}

fn reimport(glb: &[u8]) -> ImportedScene {
    import_slice(glb, None, "scene.glb", &ImportOptions::default())
        .unwrap_or_else(|e| panic!("the exported scene.glb re-imports: {e}"))
}

/// One triangle as drawn: its object, material, world-space corners in
/// winding order, and (for the expected ones) the lightmap coordinates.
#[derive(Debug, Clone)]
struct Tri {
    object: String,
    material: String,
    world: [Vec3; 3],
    uv1: [Vec2; 3],
}

/// The triangles a client draws for `scene` at its initial poses, with the
/// chart corner texel centres computed here from the atlas (PROTOCOL.md §3:
/// corner 0 at texel (x, y), 1 at (x + w - 1, y), 2 at (x + w - 1,
/// y + h - 1), 3 at (x, y + h - 1)), independently of the exporter.
fn expected_triangles(scene: &Scene, atlas: &Atlas) -> Vec<Tri> {
    let poses = scene.initial_poses();
    let mut out = Vec::new();
    for (p, c) in scene.patches.iter().zip(&atlas.charts) {
        let corners = p
            .shape
            .transformed(&poses[p.object as usize])
            .quad_corners();
        let centre = |tx: u32, ty: u32| {
            Vec2::new(
                ((f64::from(tx) + 0.5) / f64::from(atlas.width)) as f32,
                ((f64::from(ty) + 0.5) / f64::from(atlas.height)) as f32,
            )
        };
        let uv = [
            centre(c.x, c.y),
            centre(c.x + c.w - 1, c.y),
            centre(c.x + c.w - 1, c.y + c.h - 1),
            centre(c.x, c.y + c.h - 1),
        ];
        let mut tris = vec![[0, 1, 2]];
        if !p.shape.is_triangle() {
            tris.push([0, 2, 3]);
        }
        for t in tris {
            out.push(Tri {
                object: scene.objects[p.object as usize].name.clone(),
                material: scene.materials[p.material as usize].name.clone(),
                world: t.map(|k| corners[k]),
                uv1: t.map(|k| uv[k]),
            });
        }
    }
    out
}

/// The triangles of an imported file in world space.
fn imported_triangles(imported: &ImportedScene) -> Vec<Tri> {
    let mut out = Vec::new();
    for inst in &imported.instances {
        let object = &imported.objects[inst.object as usize];
        let uv1 = inst
            .lightmap_uvs
            .as_ref()
            .expect("every primitive has TEXCOORD_1");
        for t in &inst.indices {
            out.push(Tri {
                object: object.name.clone(),
                material: imported.materials[inst.material as usize].name.clone(),
                world: t.map(|i| object.pose.transform_point(inst.positions[i as usize])),
                uv1: t.map(|i| uv1[i as usize]),
            });
        }
    }
    out
}

/// Pairs every expected triangle with the imported one at the same world
/// corners in the same order (within `tolerance` m), each used once.
fn pair_up(expected: &[Tri], got: &[Tri], tolerance: f32) -> Vec<(Tri, Tri)> {
    assert_eq!(got.len(), expected.len(), "triangle count");
    let mut used = vec![false; got.len()];
    expected
        .iter()
        .map(|e| {
            let k = (0..got.len())
                .find(|&k| {
                    !used[k]
                        && e.world
                            .iter()
                            .zip(&got[k].world)
                            .all(|(a, b)| (*a - *b).abs().max_element() <= tolerance)
                })
                .unwrap_or_else(|| panic!("no exported triangle at {:?}", e.world));
            used[k] = true;
            (e.clone(), got[k].clone())
        })
        .collect()
}

#[test]
fn reimporting_gives_the_same_triangles_materials_and_dynamic_objects() {
    let (scene, atlas) = room();
    let glb = exported(&scene, &atlas);
    let imported = reimport(&glb);

    // Triangles: the same in world space (1e-6 m), with their object and
    // material.
    let pairs = pair_up(
        &expected_triangles(&scene, &atlas),
        &imported_triangles(&imported),
        1e-6,
    );
    for (want, got) in &pairs {
        assert_eq!(got.object, want.object, "{:?}", want.world);
        assert_eq!(got.material, want.material, "{:?}", want.world);
    }
    // The wall's mesh triangles stay triangles and the quads two each.
    let triangles = scene
        .patches
        .iter()
        .filter(|p| p.shape.is_triangle())
        .count();
    assert_eq!(triangles, 2);
    assert_eq!(
        pairs.len(),
        2 * (scene.patches.len() - triangles) + triangles
    );

    // Materials: the physical ones, exactly (not the white base colour the
    // viewer shows the lightmap with).
    assert_eq!(imported.materials.len(), scene.materials.len());
    for (got, want) in imported.materials.iter().zip(&scene.materials) {
        assert_eq!(got.name, want.name);
        assert_eq!(got.albedo, want.albedo, "{}", want.name);
        assert_eq!(got.emission, want.emission, "{}", want.name);
        assert!(
            got.base_color_texture.is_none(),
            "{}: the lightmap is not an albedo texture",
            want.name
        );
    }

    // Objects: the static world and the crate, dynamic, at its pose.
    let names: Vec<&str> = imported.objects.iter().map(|o| o.name.as_str()).collect();
    assert_eq!(names, ["static", "crate"]);
    let want = scene.objects[1].initial_pose;
    let got = imported.objects[1].pose;
    assert!((got.translation - want.translation).abs().max_element() < 1e-6);
    assert!(got.rotation.angle_between(want.rotation) < 1e-5);
    assert!(
        want.rotation.angle_between(Quat::IDENTITY) > 0.5,
        "a turned crate"
    );

    // And it opens as a scene on its own (`lightwire bake --scene
    // scene.glb`): every patch, the same materials and dynamic objects.
    let dir = temp_dir("reimport");
    let path = dir.join("scene.glb");
    std::fs::write(&path, &glb).expect("write");
    // (Unpaired, a patch per exported triangle.)
    let again =
        Scene::load_with(&path, LoadOptions::unpaired(1.0)).expect("scene.glb opens as a scene");
    assert_eq!(again.patches.len(), pairs.len());
    assert_eq!(again.materials, scene.materials);
    let dynamic: Vec<(&str, bool)> = again
        .objects
        .iter()
        .map(|o| (o.name.as_str(), o.dynamic))
        .collect();
    assert_eq!(dynamic, [("static", false), ("crate", true)]);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn texcoord_1_is_each_corners_chart_texel_centre() {
    let (scene, atlas) = room();
    let imported = reimport(&exported(&scene, &atlas));
    let pairs = pair_up(
        &expected_triangles(&scene, &atlas),
        &imported_triangles(&imported),
        1e-6,
    );
    for (want, got) in pairs {
        assert_eq!(
            got.uv1, want.uv1,
            "TEXCOORD_1 of the triangle at {:?}",
            want.world
        );
    }
}

#[test]
fn the_bytes_are_deterministic_and_the_same_from_the_scene_and_from_the_wire() {
    let (scene, atlas) = room();
    let a = exported(&scene, &atlas);
    assert_eq!(
        a,
        exported(&scene, &atlas),
        "the same input, the same bytes"
    );
    // What the server and a relay build it from: the Welcome's description.
    let wire = lightwire_server::service::wire::scene_info(&scene, &atlas);
    assert_eq!(describe(&scene, &atlas, &scene.initial_poses()), wire);
    let served = scene_glb(&wire, &gradient(&atlas), None).expect("scene.glb");
    assert_eq!(a, served);
}

#[test]
fn a_description_that_does_not_fit_is_an_error() {
    let (scene, atlas) = room();
    let info = describe(&scene, &atlas, &scene.initial_poses());
    let rgb = gradient(&atlas);
    let error = |info: &lightwire_protocol::SceneInfo, rgb: &[[f32; 3]]| {
        format!(
            "{:#}",
            scene_glb(info, rgb, None).expect_err("refused, not written")
        )
    };
    assert!(error(&info, &rgb[1..]).contains("texels"));
    let mut bad = info.clone();
    bad.surfaces[0].rect[0] = atlas.width;
    assert!(
        error(&bad, &rgb).contains("not inside"),
        "{}",
        error(&bad, &rgb)
    );
    let mut bad = info.clone();
    bad.surfaces[1].object = 7;
    assert!(error(&bad, &rgb).contains("missing object"));
    let mut bad = info.clone();
    bad.surfaces[2].corners[1][0] = f32::NAN;
    assert!(error(&bad, &rgb).contains("finite"));
    let mut bad = info.clone();
    bad.surfaces[0].uvs = vec![[0.5, 0.5]; 3];
    assert!(error(&bad, &rgb).contains("3 lightmap coordinates"));
    let mut bad = info.clone();
    bad.surfaces[0].uvs = vec![[0.5, 1.5]; 4];
    assert!(error(&bad, &rgb).contains("each in [0, 1]"));
    let mut bad = info;
    bad.objects[1].pose.scale = 0.0;
    assert!(error(&bad, &rgb).contains("pose"));
}

// ---- a real bake and the Khronos validator ---------------------------------

fn temp_dir(test: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("lightwire-export-{}-{test}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("create temp dir");
    dir
}

/// Writes the scene file `name` holding `json` into `dir` and bakes it
/// with `lightwire bake FLAGS --scene FILE --solver reference --out
/// DIR/out`, which must succeed; returns the output directory and what the
/// bake said on stderr.
fn bake(dir: &Path, name: &str, json: &str, flags: &[&str]) -> (PathBuf, String) {
    let scene_file = dir.join(name);
    std::fs::write(&scene_file, json).expect("write scene");
    let out_dir = dir.join("out");
    let out = lightwire_testkit::lightwire!()
        .command()
        .arg("bake")
        .args(flags)
        .arg("--scene")
        .arg(&scene_file)
        .args(["--solver", "reference", "--out"])
        .arg(&out_dir)
        .output()
        .expect("lightwire runs");
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{stderr}");
    (out_dir, stderr)
}

#[test]
fn bake_writes_a_scene_glb_the_khronos_validator_accepts() {
    let dir = temp_dir("bake");
    let (out_dir, stderr) = bake(&dir, "export-room.json", ROOM, &[]);
    assert!(
        stderr.contains("scene.glb"),
        "the bake says it wrote it: {stderr}"
    );
    let path = out_dir.join(bake::SCENE_GLB);
    let glb = std::fs::read(&path).expect("bake wrote scene.glb");

    let (ok, text) = khronos_validate(&[&path]);
    assert!(ok && text.contains(" errors 0 "), "{text}");
    eprintln!("{text}");

    // Every material shows the lightmap unlit on TEXCOORD_1, and the
    // lightmap is lightmap.png pixel for pixel.
    let gltf = gltf::Gltf::from_slice(&glb).expect("parses");
    let blob = gltf.blob.as_deref().expect("a binary chunk");
    let mut lightmaps = Vec::new();
    for m in gltf.materials() {
        assert!(m.unlit(), "{:?} is unlit", m.name());
        let info = m
            .pbr_metallic_roughness()
            .base_color_texture()
            .expect("the lightmap as base colour");
        assert_eq!(info.tex_coord(), 1, "{:?}", m.name());
        assert_eq!(m.pbr_metallic_roughness().base_color_factor(), [1.0; 4]);
        lightmaps.push(info.texture().source().index());
    }
    lightmaps.dedup();
    assert_eq!(lightmaps.len(), 1, "one lightmap for every material");
    let image = gltf.images().nth(lightmaps[0]).expect("the image");
    let gltf::image::Source::View { view, mime_type } = image.source() else {
        panic!("the lightmap is embedded");
    };
    assert_eq!(mime_type, "image/png");
    let embedded = image::load_from_memory(&blob[view.offset()..view.offset() + view.length()])
        .expect("the embedded PNG decodes")
        .to_rgb8();
    let png = image::open(out_dir.join("lightmap.png"))
        .expect("lightmap.png")
        .to_rgb8();
    assert_eq!(embedded.dimensions(), png.dimensions());
    assert!(
        embedded.as_raw() == png.as_raw(),
        "the embedded lightmap is lightmap.png"
    );

    // The linear lightmap is named in the asset's extras.
    let extras = serde_json::to_value(&gltf.as_json().asset.extras).expect("JSON");
    assert_eq!(extras["lightwire"]["lightmap"], "lightmap.exr");
    assert_eq!(extras["lightwire"]["scene"], "export-room");
    assert!(out_dir.join("lightmap.exr").is_file());

    // The validator checks what matters here: the same file with the unlit
    // extension used but not declared is refused.
    let parsed = gltf::binary::Glb::from_slice(&glb).expect("a GLB");
    let mut json: serde_json::Value = serde_json::from_slice(&parsed.json).expect("JSON chunk");
    json["extensionsUsed"] = serde_json::json!([]);
    let broken = pack_glb(
        serde_json::to_string(&json).expect("JSON").as_bytes(),
        parsed.bin.as_deref().unwrap_or_default(),
    )
    .expect("pack");
    let broken_path = dir.join("broken.glb");
    std::fs::write(&broken_path, broken).expect("write");
    let (ok, text) = khronos_validate(&[&broken_path]);
    assert!(
        !ok,
        "the validator accepted an undeclared extension: {text}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// Issue 18, items 2 and 6: a mesh lit on its own lightmap UVs is exported
/// with them. `bake --charts lightmap-uvs` on a floor and a wall whose
/// `lightmap_uvs` share one lightmap (affine over the floor, which is lit
/// as one parallelogram on it; a trapezoid on the wall, whose triangles
/// stay apart): the Khronos validator accepts the
/// `scene.glb`, `atlas.json` names the mesh's block, and every exported
/// `TEXCOORD_1` is the asset's UV placed in that block.
#[test]
fn a_mesh_baked_on_its_own_lightmap_uvs_exports_them() {
    const UVS: &str = r#"{
      "name": "uv-room",
      "lightmap": { "texel_density": 6 },
      "materials": [
        { "name": "white", "albedo": [0.7, 0.7, 0.7] },
        { "name": "light", "albedo": [0.5, 0.5, 0.5], "emission": [10, 10, 10] }
      ],
      "surfaces": [
        { "name": "room", "material": "white", "mesh": {
            "positions": [[0, 0, 0], [2, 0, 0], [2, 0, -2], [0, 0, -2],
                          [0, 0, -2], [2, 0, -2], [2, 1.5, -2], [0, 1.5, -2]],
            "indices": [0, 1, 2, 0, 2, 3, 4, 5, 6, 4, 6, 7],
            "lightmap_uvs": [[0.05, 0.95], [0.55, 0.95], [0.55, 0.45], [0.05, 0.45],
                             [0.05, 0.4], [0.95, 0.4], [0.85, 0.05], [0.15, 0.05]] } },
        { "name": "lamp", "material": "light",
          "quad": { "origin": [0.5, 1.4, -0.5], "u": [1, 0, 0], "v": [0, 0, -1] } }
      ]
    }"#;
    let dir = temp_dir("uvs");
    let (out_dir, _) = bake(&dir, "uv-room.json", UVS, &["--charts", "lightmap-uvs"]);
    let path = out_dir.join(bake::SCENE_GLB);
    let (ok, text) = khronos_validate(&[&path]);
    assert!(ok && text.contains(" errors 0 "), "{text}");

    let atlas: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out_dir.join("atlas.json")).expect("atlas.json"),
    )
    .expect("JSON");
    let blocks = atlas["lightmap_blocks"]
        .as_array()
        .expect("lightmap_blocks");
    assert_eq!(blocks.len(), 1, "{blocks:?}");
    assert_eq!(blocks[0]["mesh"], "room");
    let rect: Vec<f32> = blocks[0]["uv_rect"]
        .as_array()
        .expect("uv_rect")
        .iter()
        .map(|v| v.as_f64().expect("number") as f32)
        .collect();
    // Each TEXCOORD_1 of the room's triangles, taken back into the block,
    // is one of the asset's UVs.
    let asset: Vec<[f32; 2]> = vec![
        [0.05, 0.95],
        [0.55, 0.95],
        [0.55, 0.45],
        [0.05, 0.45],
        [0.05, 0.4],
        [0.95, 0.4],
        [0.85, 0.05],
        [0.15, 0.05],
    ];
    let glb = std::fs::read(&path).expect("scene.glb");
    let imported = import_slice(&glb, None, "scene.glb", &ImportOptions::default())
        .unwrap_or_else(|e| panic!("{e}"));
    let mut checked = 0;
    for inst in &imported.instances {
        let Some(uvs) = &inst.lightmap_uvs else {
            continue;
        };
        for (uv, p) in uvs.iter().zip(&inst.positions) {
            // The lamp (at y = 1.4, a quad on Lightwire's own chart) lies
            // outside the block.
            if (p.y - 1.4).abs() < 1e-4 {
                continue;
            }
            let local = [
                (uv.x - rect[0]) / (rect[2] - rect[0]),
                (uv.y - rect[1]) / (rect[3] - rect[1]),
            ];
            assert!(
                asset
                    .iter()
                    .any(|a| (a[0] - local[0]).abs() < 1e-4 && (a[1] - local[1]).abs() < 1e-4),
                "TEXCOORD_1 {uv:?} at {p:?} is {local:?} in the block, not one of the asset's UVs"
            );
            checked += 1;
        }
    }
    // The floor's UVs are affine over it: one parallelogram, four corners;
    // the wall's (a trapezoid) are not: two triangles.
    assert_eq!(
        checked,
        4 + 2 * 3,
        "the floor's parallelogram, the wall's triangles"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// Issue 59: the exported `scene.glb` keeps the scene's lights as
/// `KHR_lights_punctual` (683 lm/W, a directional light's angular radius
/// in its `extras`) and its sky in the asset's `extras`, so that importing
/// it again gives the same lights: every kind, position, direction,
/// intensity per channel, range and cone within 1e-5 (relative), the sky
/// the same; the Khronos validator accepts the file.
#[test]
fn the_exported_scene_keeps_its_lights_and_sky() {
    let lit = ROOM.replacen(
        r#""surfaces": ["#,
        r#""lights": [
    { "name": "bulb", "type": "point", "position": [0.4, 0.9, 1.1], "color": [1, 0.8, 0.6], "intensity": 5, "range": 6 },
    { "name": "spot", "type": "spot", "position": [1, 0.95, 1], "direction": [0.2, -1, 0.1], "intensity": 12,
      "inner_cone_deg": 20, "outer_cone_deg": 35 },
    { "name": "sun", "type": "directional", "direction": [0.3, -0.8, -0.5], "color": [1, 0.95, 0.85], "intensity": 700,
      "angular_diameter_deg": 0.53 }
  ],
  "sky": { "zenith": [2, 3, 5], "horizon": [4, 4, 4.5], "ground_albedo": [0.2, 0.3, 0.1] },
  "surfaces": ["#,
        1,
    );
    assert!(lit.contains("\"bulb\""), "the lights went in");
    let (scene, atlas) =
        parse_scene(&lit, "lit-room.json", LoadOptions::unpaired(1.0)).expect("the lit room loads");
    assert_eq!(scene.lights.len(), 3);
    let glb = bake::scene_glb_lit(
        &describe(&scene, &atlas, &scene.initial_poses()),
        &gradient(&atlas),
        None,
        (&scene.lights, scene.sky.as_ref()),
    )
    .expect("scene.glb");
    let imported = reimport(&glb);
    assert_eq!(
        imported.lights.len(),
        scene.lights.len(),
        "{:?}",
        imported.lights
    );
    let close = |a: Vec3, b: Vec3| (a - b).length() <= 1e-5 * b.length().max(1.0);
    for (want, got) in scene.lights.iter().zip(&imported.lights) {
        assert_eq!(got.name, want.name);
        assert!(
            close(got.intensity, want.intensity),
            "{}: {} vs {}",
            want.name,
            got.intensity,
            want.intensity
        );
        assert!(
            close(got.position, want.position),
            "{}: {} vs {}",
            want.name,
            got.position,
            want.position
        );
        assert_eq!(got.range, want.range, "{}", want.name);
        match (got.kind, want.kind) {
            (LightKind::Point, LightKind::Point) => {}
            (
                LightKind::Spot {
                    direction: d,
                    inner: i,
                    outer: o,
                },
                LightKind::Spot {
                    direction,
                    inner,
                    outer,
                },
            ) => {
                assert!(close(d, direction), "spot direction {d} vs {direction}");
                assert!(
                    (i - inner).abs() < 1e-6 && (o - outer).abs() < 1e-6,
                    "cones {i} {o} vs {inner} {outer}"
                );
            }
            (
                LightKind::Directional {
                    direction: d,
                    angular_radius: r,
                },
                LightKind::Directional {
                    direction,
                    angular_radius,
                },
            ) => {
                assert!(close(d, direction), "sun direction {d} vs {direction}");
                assert!(
                    (r - angular_radius).abs() < 1e-7,
                    "angular radius {r} vs {angular_radius}"
                );
            }
            (got, want) => panic!("{}: {got:?} where {want:?} was exported", want_name(want)),
        }
    }
    let sky = imported.sky.expect("the sky comes back");
    let want = scene.sky.expect("the room has a sky");
    assert!(
        close(sky.zenith, want.zenith)
            && close(sky.horizon, want.horizon)
            && close(sky.ground_albedo, want.ground_albedo),
        "{sky:?} vs {want:?}"
    );
    assert!(want.ground.max_element() > 0.0, "a lit ground: {want:?}");

    let dir = temp_dir("lights");
    let path = dir.join(bake::SCENE_GLB);
    std::fs::write(&path, &glb).expect("written");
    let (ok, text) = khronos_validate(&[&path]);
    assert!(ok && text.contains(" errors 0 "), "{text}");
}

fn want_name(kind: LightKind) -> &'static str {
    match kind {
        LightKind::Point => "point",
        LightKind::Spot { .. } => "spot",
        LightKind::Directional { .. } => "directional",
    }
}

/// `lightwire serve`'s `GET /api/scenes/{id}/scene.glb` keeps the scene's
/// lights as `bake` does: cornell-point's bulb (a point light, 8 W/sr per
/// channel) comes back from a re-import at its position with its
/// intensity (through 683 lm/W both ways), and the Khronos validator
/// accepts the file. `GET /api/scenes` counts the lights, `GET
/// /api/scenes/{id}/lights` lists them as the scene file gives them (no
/// `SetLight` yet: on, seq 0, and the same state under `file`), and
/// an unknown scene's lights are a 404 that says so.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_served_scene_glb_keeps_the_scenes_lights() {
    use lightwire_testkit::{http, lightwire, scene_path};
    let server = lightwire!().serve_dev_on(
        scene_path("cornell-point.json"),
        &["--solver", "reference", "--density-scale", "0.3"],
    );
    server.ready().await;
    let addr = server.addr.as_str();

    let glb = http::get(addr, "/api/scenes/cornell-point/scene.glb", None).await;
    assert_eq!(glb.status, 200, "{}", glb.text());
    assert_eq!(glb.header("content-type"), Some("model/gltf-binary"));
    let imported = reimport(&glb.body);
    assert_eq!(imported.lights.len(), 1, "{:?}", imported.lights);
    let bulb = &imported.lights[0];
    assert_eq!(bulb.name, "bulb");
    assert_eq!(bulb.kind, LightKind::Point);
    let at = Vec3::new(2.78, 4.488, 2.796);
    assert!((bulb.position - at).length() < 1e-5, "{}", bulb.position);
    assert!(
        (bulb.intensity - Vec3::splat(8.0)).length() < 1e-4,
        "{} W/sr",
        bulb.intensity
    );
    assert_eq!(bulb.range, None);
    assert!(imported.sky.is_none(), "cornell-point has no sky");
    let dir = temp_dir("served-lights");
    let path = dir.join(bake::SCENE_GLB);
    std::fs::write(&path, &glb.body).expect("written");
    let (ok, text) = khronos_validate(&[&path]);
    assert!(ok && text.contains(" errors 0 "), "{text}");

    let list = http::get(addr, "/api/scenes", None).await.json();
    assert_eq!(list[0]["lights"], 1, "{list}");
    let lights = http::get(addr, "/api/scenes/cornell-point/lights", None).await;
    assert_eq!(lights.status, 200, "{}", lights.text());
    assert_eq!(
        lights.json(),
        serde_json::json!({
            "lights": [{
                "name": "bulb",
                "type": "point",
                "position": [2.78, 4.488, 2.796],
                "color": [1.0, 1.0, 1.0],
                "intensity": 8.0,
                "on": true,
                "seq": 0,
                "file": {
                    "on": true,
                    "color": [1.0, 1.0, 1.0],
                    "intensity": 8.0,
                    "position": [2.78, 4.488, 2.796]
                }
            }],
            "sky": null
        })
    );
    let unknown = http::get(addr, "/api/scenes/nope/lights", None).await;
    assert_eq!(unknown.status, 404);
    let error = unknown.json()["error"]
        .as_str()
        .unwrap_or_default()
        .to_string();
    assert!(error.contains("no scene \"nope\""), "{error:?}");
}

/// Issues 59 and 60: a light riding with a dynamic object is exported
/// under that object's node, where the object's pose puts it: with the
/// crate moved and turned, the reimported lamp rides with the crate's
/// object, at the placed position and direction (1e-5), and goes where the
/// crate goes from there.
#[test]
fn a_light_riding_with_an_object_is_exported_under_its_node() {
    let lit = ROOM.replacen(
        r#""surfaces": ["#,
        r#""lights": [
    { "name": "lamp", "type": "spot", "object": "crate", "position": [1, 0.9, 1], "direction": [0, -1, 0.2],
      "intensity": 3 }
  ],
  "surfaces": ["#,
        1,
    );
    let (scene, atlas) =
        parse_scene(&lit, "lamp-room.json", LoadOptions::unpaired(1.0)).expect("the room loads");
    let crate_ = scene.object_by_name("crate").expect("a crate");
    assert_eq!(scene.lights[0].object, crate_);
    let mut poses = scene.initial_poses();
    poses[crate_ as usize].translation += Vec3::new(0.4, 0.0, -0.3);
    poses[crate_ as usize].rotation = glam::Quat::from_rotation_y(0.7);
    let placed = scene.lights_at(&scene.lights, &poses);
    let glb = bake::scene_glb_lit(
        &describe(&scene, &atlas, &poses),
        &gradient(&atlas),
        None,
        (&placed, None),
    )
    .expect("scene.glb");
    let imported = reimport(&glb);
    let lamp = &imported.lights[0];
    assert_eq!(
        imported.objects[lamp.object as usize].name, "crate",
        "the lamp rides with the crate: {lamp:?}"
    );
    let close = |a: Vec3, b: Vec3| (a - b).length() <= 1e-5;
    assert!(
        close(lamp.position, placed[0].position),
        "{} vs {}",
        lamp.position,
        placed[0].position
    );
    let (
        LightKind::Spot { direction: got, .. },
        LightKind::Spot {
            direction: want, ..
        },
    ) = (lamp.kind, placed[0].kind)
    else {
        panic!("a spot: {lamp:?}");
    };
    assert!(close(got, want), "{got} vs {want}");
}
