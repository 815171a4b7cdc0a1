//! Triangle meshes as scenes: a `.glb` opened on its own, glTF imports in a
//! scene file beside quads, and what the loader says when they clash.
//! (The solvers on triangles are tested in `triangles_cpu.rs` and
//! `triangles_gpu.rs`; bad `mesh` surfaces are fixtures of `scenes/fixtures/bad`.)

use lightwire_scene::atlas::Atlas;
use lightwire_scene::load::load_scene;
use lightwire_scene::{LoadOptions, Scene};

use lightwire_testkit::scene_path;

#[test]
fn a_glb_opens_as_a_scene_of_triangles() {
    let path = scene_path("meshes/cornell-large.glb");
    let (scene, atlas) = load_scene(&path, LoadOptions::default())
        .unwrap_or_else(|e| panic!("cornell-large.glb must load: {e}"));
    assert_eq!(scene.name, "cornell-large");
    // Five walls, the light and the box's six faces, two triangles each,
    // and each face's two a parallelogram: one quad patch per face
    // (`scene/pairs.rs`), a triangle each without pairing.
    assert_eq!(scene.patches.len(), 12);
    assert!(
        scene
            .patches
            .iter()
            .all(|p| !p.shape.is_triangle() && p.mesh)
    );
    let unpaired = LoadOptions::unpaired(1.0);
    let triangles = Scene::load_with(&path, unpaired).expect("loads");
    assert_eq!(triangles.patches.len(), 24);
    assert!(triangles.patches.iter().all(|p| p.shape.is_triangle()));
    let area = |s: &Scene| s.patches.iter().map(|p| p.shape.area()).sum::<f32>();
    assert!((area(&scene) - area(&triangles)).abs() < 1e-4 * area(&scene));
    assert_eq!(scene.objects.len(), 1, "nothing in cornell-large.glb moves");
    let light = scene
        .materials
        .iter()
        .find(|m| m.name == "light")
        .expect("the glTF's light material");
    assert_eq!(light.emission.to_array(), [16.0; 3]);
    // The documented default density: about 16,384 texels on the surface.
    let area: f32 = scene.patches.iter().map(|p| p.shape.area()).sum();
    let expected = (16384.0 / area).sqrt();
    assert!(
        (scene.texel_density - expected).abs() < 1e-3 * expected,
        "{} texels/m for {area} m²",
        scene.texel_density
    );
    let covered: f32 = atlas.elements.iter().map(|e| e.area).sum();
    assert!((covered - area).abs() < 1e-3 * area, "{covered} vs {area}");

    // --density-scale applies as to scene files.
    let half = Scene::load_with(&path, LoadOptions::scaled(0.5)).expect("loads");
    assert!((half.texel_density - 0.5 * scene.texel_density).abs() < 1e-4);
}

#[test]
fn a_scene_file_imports_a_dynamic_glb_beside_its_own_quads() {
    let text = r#"{
        "name": "imported",
        "lightmap": { "texel_density": 2 },
        "materials": [ { "name": "white", "albedo": [0.73, 0.73, 0.73] } ],
        "objects": [ { "name": "cart", "pose": { "translation": [1, 0, 1] } } ],
        "surfaces": [
            { "name": "cart", "material": "white", "object": "cart",
              "box": { "center": [0, 0.2, 0], "size": [0.4, 0.4, 0.4] } }
        ],
        "imports": [ { "file": "meshes/cornell-dynamic.glb", "texel_density": 1.5 } ]
    }"#;
    // Imports resolve against the scene file's directory: scenes/.
    let origin = scene_path("imported.json").display().to_string();
    let scene = Scene::parse(text, &origin).unwrap_or_else(|e| panic!("{e}"));
    // The scene's white is the glTF's white (same values): shared, not doubled.
    assert_eq!(
        scene.materials.iter().filter(|m| m.name == "white").count(),
        1
    );
    let names: Vec<&str> = scene.objects.iter().map(|o| o.name.as_str()).collect();
    assert_eq!(names, ["static", "cart", "box"]);
    let box_object = 2;
    let pose = scene.objects[box_object].initial_pose;
    assert!((pose.translation - glam::Vec3::new(2.78, 0.85, 2.796)).length() < 1e-4);
    let box_patches: Vec<_> = scene
        .patches
        .iter()
        .filter(|p| p.object == box_object as u32)
        .collect();
    assert_eq!(
        box_patches.len(),
        6,
        "six faces, two triangles each, paired"
    );
    assert!(
        box_patches
            .iter()
            .all(|p| p.name.starts_with("box/box/0/") && p.texel_density == 1.5)
    );
    // The quads of the file keep the scene's density and stay quads.
    let cart: Vec<_> = scene.patches.iter().filter(|p| p.object == 1).collect();
    assert_eq!(cart.len(), 6);
    assert!(
        cart.iter()
            .all(|p| !p.shape.is_triangle() && !p.mesh && p.texel_density == 2.0)
    );
    Atlas::build(&scene).expect("fits");
}

#[test]
fn imports_that_clash_with_the_scene_file_name_the_import_and_the_name() {
    let text = r#"{
        "name": "clash",
        "lightmap": { "texel_density": 2 },
        "materials": [ { "name": "white", "albedo": [0.5, 0.5, 0.5] } ],
        "objects": [ { "name": "box" } ],
        "surfaces": [
            { "name": "crate", "material": "white", "object": "box",
              "box": { "center": [0, 0.2, 0], "size": [0.4, 0.4, 0.4] } }
        ],
        "imports": [ { "file": "meshes/cornell-dynamic.glb" } ]
    }"#;
    let origin = scene_path("clash.json").display().to_string();
    let err = Scene::parse(text, &origin)
        .expect_err("a material and an object of the same name differ")
        .to_string();
    for needle in [
        "import #0 \"meshes/cornell-dynamic.glb\"",
        "material \"white\" is also defined elsewhere",
        "dynamic node \"box\" has the name of an object that already exists",
    ] {
        assert!(err.contains(needle), "{needle:?} missing from:\n{err}");
    }

    // A path that is not there is named with the import.
    let missing = text.replace("meshes/cornell-dynamic.glb", "meshes/nope.glb");
    let err = Scene::parse(&missing, &origin)
        .expect_err("missing file")
        .to_string();
    assert!(
        err.contains("import #0 \"meshes/nope.glb\"") && err.contains("cannot read scene file"),
        "{err}"
    );
}

#[test]
fn a_glb_without_an_emitter_is_refused() {
    // The furnace sphere emits; a copy of the atrium restricted to its floor
    // does not: import only the floor node through a scene file.
    let text = r#"{
        "name": "dark",
        "lightmap": { "texel_density": 1 },
        "materials": [],
        "imports": [ { "file": "meshes/atrium.glb", "nodes": ["floor"] } ]
    }"#;
    let origin = scene_path("dark.json").display().to_string();
    let err = Scene::parse(text, &origin)
        .expect_err("no emitter")
        .to_string();
    assert!(err.contains("has no light"), "{err}");
}

#[test]
fn an_import_gives_its_materials_the_albedo_and_light_the_scene_file_says() {
    // The atrium's floor alone has no emitter; the scene file makes its
    // material glow and every other material grey ("*").
    let text = r#"{
        "name": "lit-floor",
        "lightmap": { "texel_density": 1 },
        "materials": [],
        "imports": [ { "file": "meshes/atrium.glb", "nodes": ["floor", "wall-north"],
                       "materials": { "floor": { "emission": [2, 3, 4] },
                                      "*": { "albedo": [0.25, 0.5, 0.75] } } } ]
    }"#;
    let origin = scene_path("lit-floor.json").display().to_string();
    let scene = Scene::parse(text, &origin).unwrap_or_else(|e| panic!("{e}"));
    let material = |name: &str| {
        scene
            .materials
            .iter()
            .find(|m| m.name == name)
            .unwrap_or_else(|| panic!("{name}"))
    };
    assert_eq!(material("floor").emission, glam::Vec3::new(2.0, 3.0, 4.0));
    assert_eq!(material("stone").albedo, glam::Vec3::new(0.25, 0.5, 0.75));
    assert_eq!(material("stone").emission, glam::Vec3::ZERO);
    // The floor keeps its own albedo: "*" is for materials not named.
    assert_ne!(material("floor").albedo, glam::Vec3::new(0.25, 0.5, 0.75));

    // A name the file does not have, and an albedo of 1, are errors that
    // say where.
    let bad = text
        .replace("\"floor\": { \"emission\"", "\"flor\": { \"emission\"")
        .replace("[0.25, 0.5, 0.75]", "[1, 0.5, 0.75]");
    let err = Scene::parse(&bad, &origin)
        .expect_err("unknown material, albedo 1")
        .to_string();
    for needle in [
        "import #0 \"meshes/atrium.glb\"",
        "materials.\"flor\": the file has no material of that name (it has floor, stone",
        "materials.\"*\"",
        "must lie in [0, 1)",
    ] {
        assert!(err.contains(needle), "{needle:?} missing from:\n{err}");
    }
}

#[test]
fn a_mesh_triangle_with_its_corners_on_a_line_is_dropped_with_a_warning() {
    let text = r#"{
        "name": "sliver",
        "lightmap": { "texel_density": 4 },
        "materials": [ { "name": "white", "albedo": [0.7, 0.7, 0.7] },
                       { "name": "light", "albedo": [0.5, 0.5, 0.5], "emission": [10, 10, 10] } ],
        "surfaces": [
            { "name": "light", "material": "light",
              "quad": { "origin": [0.75, 2, 0.75], "u": [0.5, 0, 0], "v": [0, 0, 0.5] } },
            { "name": "floor", "material": "white",
              "mesh": { "positions": [[0, 0, 0], [2, 0, 0], [2, 0, -2], [1, 0, 0]],
                        "indices": [0, 1, 2, 0, 3, 1] } }
        ]
    }"#;
    let origin = scene_path("sliver.json").display().to_string();
    let scene = Scene::parse(text, &origin).unwrap_or_else(|e| panic!("{e}"));
    let floor: Vec<&str> = scene
        .patches
        .iter()
        .filter(|p| p.name.starts_with("floor"))
        .map(|p| p.name.as_str())
        .collect();
    assert_eq!(
        floor,
        ["floor/0"],
        "the sound triangle, under its own number"
    );
    assert_eq!(scene.warnings.len(), 1, "{:?}", scene.warnings);
    let w = scene.warnings[0].to_string();
    assert!(
        w.contains("surface #1 \"floor\"")
            && w.contains("dropped 1 of 2")
            && w.contains("#1 (indices [0, 3, 1])"),
        "{w}"
    );
}
