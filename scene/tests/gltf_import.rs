//! glTF import (`scene::gltf`): the committed mesh scenes, node transforms,
//! the writer's round trip, and one error per kind of bad input, each naming
//! the file, node, mesh and primitive.

use std::path::{Path, PathBuf};

use glam::{Quat, Vec2, Vec3};
use lightwire_scene::gltf::content;
use lightwire_scene::gltf::write::{
    GlbImage, GlbMaterial, GlbMesh, GlbNode, GlbPrimitive, GlbScene, pack_glb,
};
use lightwire_scene::gltf::{ImageSource, ImportOptions, ImportedScene, import, import_slice};
use lightwire_scene::{Scene, SceneError};
use lightwire_testkit::validator::khronos_validate;

fn scenes_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../scenes")
}

fn meshes_dir() -> PathBuf {
    scenes_dir().join("meshes")
}

/// A fresh directory under the system temp dir for one test.
fn temp_dir(test: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("lightwire-gltf-{}-{test}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("create temp dir");
    dir
}

fn import_file(name: &str) -> ImportedScene {
    let path = meshes_dir().join(name);
    import(&path, &ImportOptions::default()).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn close(a: Vec3, b: Vec3) -> bool {
    (a - b).abs().max_element() < 1e-5
}

/// Twice the area of a triangle and its (unnormalised) normal.
fn tri_normal(p: &[Vec3], t: [u32; 3]) -> Vec3 {
    let [a, b, c] = t.map(|i| p[i as usize]);
    (b - a).cross(c - a)
}

fn area(p: &[Vec3], indices: &[[u32; 3]]) -> f32 {
    indices
        .iter()
        .map(|&t| 0.5 * tri_normal(p, t).length())
        .sum()
}

#[test]
fn committed_meshes_are_byte_identical_to_a_regeneration() {
    let generated = content::generate_all().expect("generate");
    assert_eq!(generated.len(), 4);
    for (name, bytes) in generated {
        let path = meshes_dir().join(name);
        let committed = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        assert!(
            committed == bytes,
            "{} differs from what the generator makes now ({} vs {} bytes): run `cargo run -p lightwire-scene --example make_meshes` and commit",
            path.display(),
            committed.len(),
            bytes.len()
        );
        assert!(bytes.len() < 1 << 20, "{name} is {} bytes", bytes.len());
    }
}

#[test]
fn every_committed_mesh_imports_with_its_triangle_count() {
    for (name, _) in content::FILES {
        let scene = import_file(name);
        let expected = content::expected_triangles(name).expect("known file");
        assert_eq!(scene.triangle_count(), expected, "{name}");
    }
    // The atrium is "a few thousand triangles".
    let atrium = content::expected_triangles("atrium.glb").expect("atrium");
    assert!((2000..10_000).contains(&atrium), "{atrium}");
}

/// The triangulated Cornell box has the quad scene's materials and surfaces:
/// every quad of `scenes/cornell-large.json` has a mesh of the same name,
/// material and area, and the same emitted power.
#[test]
fn cornell_mesh_matches_the_quad_scene() {
    let quads = Scene::load(&scenes_dir().join("cornell-large.json")).expect("cornell-large.json");
    let mesh = import_file("cornell-large.glb");
    assert_eq!(mesh.objects.len(), 1, "the box is static in this file");
    for m in &quads.materials {
        let got = mesh
            .material(&m.name)
            .unwrap_or_else(|| panic!("material {}", m.name));
        assert!(
            close(got.albedo, m.albedo),
            "{}: {} vs {}",
            m.name,
            got.albedo,
            m.albedo
        );
        assert!(
            close(got.emission, m.emission),
            "{}: {} vs {}",
            m.name,
            got.emission,
            m.emission
        );
    }
    let pose = quads.objects[quads.object_by_name("box").expect("box") as usize].initial_pose;
    let mut power = Vec3::ZERO;
    for patch in &quads.patches {
        // Box faces are `box/+x` etc.; the mesh has one `box` node.
        let node = patch.name.split('/').next().unwrap_or(&patch.name);
        let inst: Vec<_> = mesh.instances_of(node).collect();
        assert_eq!(inst.len(), 1, "{node}");
        let inst = inst[0];
        assert_eq!(
            mesh.materials[inst.material as usize].name,
            quads.materials[patch.material as usize].name,
            "{node}"
        );
        // Each quad's four corners are vertices of the mesh (world space).
        let shape = patch
            .shape
            .transformed(&quads.objects[patch.object as usize].initial_pose);
        for c in shape.corners() {
            assert!(
                inst.positions.iter().any(|&p| close(p, c)),
                "{}: corner {c} missing",
                patch.name
            );
        }
        if !patch.name.contains('/') {
            assert!((area(&inst.positions, &inst.indices) - patch.shape.area()).abs() < 1e-4);
            // Two triangles per quad, facing the quad's way.
            assert_eq!(inst.indices.len(), 2);
            for &t in &inst.indices {
                let n = tri_normal(&inst.positions, t).normalize();
                assert!(n.dot(patch.shape.normal()) > 0.9999, "{}: {n}", patch.name);
            }
        }
        let uv = inst.lightmap_uvs.as_ref().expect("TEXCOORD_1");
        assert!(
            uv.iter()
                .all(|u| u.cmpge(Vec2::ZERO).all() && u.cmple(Vec2::ONE).all())
        );
        if !patch.name.contains('/') {
            power += mesh.materials[inst.material as usize].emission
                * area(&inst.positions, &inst.indices);
        }
    }
    assert!(
        close(
            power / 100.0,
            quads.emitted_power(&quads.initial_poses()) / 100.0
        ),
        "{power}"
    );
    // The box sits where the quad scene's initial pose puts it.
    let boxed = mesh.instances_of("box").next().expect("box");
    let lo = boxed
        .positions
        .iter()
        .fold(Vec3::INFINITY, |a, &p| a.min(p));
    assert!(
        close(lo, pose.translation - Vec3::new(0.8, 0.85, 0.8)),
        "{lo}"
    );
}

#[test]
fn cornell_dynamic_box_is_a_dynamic_object_with_local_geometry() {
    let scene = import_file("cornell-dynamic.glb");
    assert_eq!(scene.objects.len(), 2);
    let object = &scene.objects[1];
    assert_eq!(object.name, "box");
    assert!(close(object.pose.translation, Vec3::new(2.78, 0.85, 2.796)));
    let expected = Quat::from_rotation_y(20f32.to_radians());
    assert!(object.pose.rotation.angle_between(expected) < 1e-5);
    assert_eq!(object.pose.scale, 1.0);
    let inst = scene.instances_of("box").next().expect("box");
    assert_eq!(inst.object, 1);
    // Local space: centred on the origin, the box's half extents.
    let hi = inst
        .positions
        .iter()
        .fold(Vec3::NEG_INFINITY, |a, &p| a.max(p));
    let lo = inst.positions.iter().fold(Vec3::INFINITY, |a, &p| a.min(p));
    assert!(
        close(hi, Vec3::new(0.8, 0.85, 0.8)) && close(lo, -hi),
        "{lo} {hi}"
    );
    // Everything else is static.
    assert!(scene.instances.iter().filter(|i| i.object == 0).count() == 6);
    // The same file with the box named as dynamic in the options, but the
    // extras removed, gives the same objects: see
    // dynamic_nodes_option_marks_nodes_dynamic.
}

#[test]
fn dynamic_nodes_option_marks_nodes_dynamic() {
    let path = meshes_dir().join("cornell-large.glb");
    let options = ImportOptions {
        dynamic_nodes: vec!["box".into()],
        ..Default::default()
    };
    let scene = import(&path, &options).expect("import");
    assert_eq!(scene.objects.len(), 2);
    assert_eq!(scene.objects[1].name, "box");
    assert!(close(
        scene.objects[1].pose.translation,
        Vec3::new(2.78, 0.85, 2.796)
    ));
}

#[test]
fn node_selection_and_emission_scale() {
    let path = meshes_dir().join("cornell-large.glb");
    let options = ImportOptions {
        nodes: vec!["light".into(), "box".into()],
        emission_scale: 2.0,
        ..Default::default()
    };
    let scene = import(&path, &options).expect("import");
    let mut names: Vec<_> = scene
        .instances
        .iter()
        .filter_map(|i| i.node_name.clone())
        .collect();
    names.sort();
    assert_eq!(names, ["box", "light"]);
    assert!(close(
        scene.material("light").expect("light").emission,
        Vec3::splat(32.0)
    ));

    let options = ImportOptions {
        nodes: vec!["lamp".into()],
        dynamic_nodes: vec!["crate".into()],
        ..Default::default()
    };
    let message = import(&path, &options)
        .expect_err("unknown names")
        .to_string();
    assert!(message.contains("no node is called \"lamp\""), "{message}");
    assert!(message.contains("no node is called \"crate\""), "{message}");
}

#[test]
fn furnace_sphere_is_closed_and_faces_its_centre() {
    let scene = import_file("furnace-sphere.glb");
    assert_eq!(scene.instances.len(), 1);
    let inst = &scene.instances[0];
    assert!(inst.lightmap_uvs.is_none(), "charts are to be generated");
    let m = &scene.materials[inst.material as usize];
    assert!(close(m.albedo, Vec3::splat(0.5)) && close(m.emission, Vec3::ONE));
    for &t in &inst.indices {
        let [a, b, c] = t.map(|i| inst.positions[i as usize]);
        let centroid = (a + b + c) / 3.0;
        assert!(
            tri_normal(&inst.positions, t).dot(centroid) < 0.0,
            "{t:?} faces out"
        );
    }
    // Watertight: every directed edge appears once and its reverse once.
    let mut edges = std::collections::HashMap::new();
    for &[a, b, c] in &inst.indices {
        for e in [(a, b), (b, c), (c, a)] {
            *edges.entry(e).or_insert(0) += 1;
        }
    }
    for (&(a, b), &n) in &edges {
        assert_eq!(n, 1, "edge {a}-{b} used {n} times");
        assert_eq!(edges.get(&(b, a)), Some(&1), "edge {a}-{b} is on a hole");
    }
}

#[test]
fn atrium_has_textured_floor_emissive_panel_and_instanced_columns() {
    let scene = import_file("atrium.glb");
    let floor = scene.material("floor").expect("floor");
    let tex = floor.base_color_texture.as_ref().expect("floor texture");
    assert_eq!(tex.tex_coord, 0);
    let decoded = floor.texture.as_ref().expect("the floor texture decoded");
    assert_eq!((decoded.width, decoded.height), (8, 8));
    match &tex.source {
        ImageSource::Embedded { mime_type, bytes } => {
            assert_eq!(mime_type, "image/png");
            assert!(bytes.starts_with(b"\x89PNG"));
        }
        other => panic!("{other:?}"),
    }
    assert!(close(
        scene.material("panel").expect("panel").emission,
        Vec3::new(20.0, 19.0, 17.0)
    ));
    let columns = scene
        .instances
        .iter()
        .filter(|i| i.mesh_name.as_deref() == Some("column"));
    assert_eq!(columns.count(), 8);
    let arches = scene
        .instances
        .iter()
        .filter(|i| i.mesh_name.as_deref() == Some("arch"));
    assert_eq!(arches.count(), 6);
    assert!(scene.instances.iter().all(|i| i.lightmap_uvs.is_some()));
    let floor_inst = scene.instances_of("floor").next().expect("floor");
    assert!(floor_inst.uv0.is_some());
    // Everything lies inside the hall.
    for i in &scene.instances {
        for p in &i.positions {
            assert!(
                p.x.abs() <= 10.0 + 1e-4 && p.z.abs() <= 10.0 + 1e-4 && (0.0..=9.0).contains(&p.y)
            );
        }
    }
}

fn triangle_primitive(positions: [Vec3; 3], material: Option<usize>) -> GlbPrimitive {
    GlbPrimitive {
        positions: positions.to_vec(),
        normals: None,
        uv0: None,
        uv1: None,
        indices: vec![[0, 1, 2]],
        material,
    }
}

fn one_mesh_scene(primitives: Vec<GlbPrimitive>, node: GlbNode) -> GlbScene {
    GlbScene {
        materials: vec![GlbMaterial {
            name: "grey".into(),
            base_color: Vec3::splat(0.5),
            emission: Vec3::ZERO,
            base_color_texture: None,
        }],
        images: Vec::new(),
        meshes: vec![GlbMesh {
            name: "thing".into(),
            primitives,
        }],
        nodes: vec![node],
        roots: vec![0],
    }
}

const TRI: [Vec3; 3] = [Vec3::ZERO, Vec3::X, Vec3::Y];

#[test]
fn node_transforms_are_applied_with_parents_and_mirrors_keep_front_faces() {
    // parent: T(1, 2, 3) · R_y(90°) · S(2); child: T(1, 0, 0), mesh.
    let mut parent = GlbNode::new("parent", None);
    parent.translation = Vec3::new(1.0, 2.0, 3.0);
    parent.rotation = Quat::from_rotation_y(std::f32::consts::FRAC_PI_2);
    parent.scale = Vec3::splat(2.0);
    parent.children = vec![1];
    let mut child = GlbNode::new("child", Some(0));
    child.translation = Vec3::X;
    // A mirrored sibling: scale x by -1.
    let mut mirror = GlbNode::new("mirror", Some(0));
    mirror.scale = Vec3::new(-1.0, 1.0, 1.0);
    let doc = GlbScene {
        nodes: vec![parent, child, mirror],
        roots: vec![0, 2],
        ..one_mesh_scene(
            vec![triangle_primitive(TRI, Some(0))],
            GlbNode::new("unused", None),
        )
    };
    let bytes = doc.to_glb().expect("write");
    let scene =
        import_slice(&bytes, None, "hierarchy.glb", &ImportOptions::default()).expect("import");
    let child = scene.instances_of("child").next().expect("child");
    // Local (0,0,0) → child (1,0,0) → scale (2,0,0) → R_y(90°) (0,0,-2) → (1,2,1).
    // Local (1,0,0) → (2,0,0) → (4,0,0) → (0,0,-4) → (1,2,-1).
    // Local (0,1,0) → (1,1,0) → (2,2,0) → (0,2,-2) → (1,4,1).
    let expected = [
        Vec3::new(1.0, 2.0, 1.0),
        Vec3::new(1.0, 2.0, -1.0),
        Vec3::new(1.0, 4.0, 1.0),
    ];
    for (got, want) in child.positions.iter().zip(expected) {
        assert!(close(*got, want), "{got} vs {want}");
    }
    // The mirrored triangle still faces where the transformed normal (+z,
    // mirroring x keeps z) points: winding was flipped.
    let mirror = scene.instances_of("mirror").next().expect("mirror");
    assert!(close(mirror.positions[1], -Vec3::X));
    assert!(tri_normal(&mirror.positions, mirror.indices[0]).z > 0.0);
}

#[test]
fn dynamic_child_keeps_local_geometry_and_a_rigid_pose() {
    let mut parent = GlbNode::new("room", None);
    parent.translation = Vec3::new(10.0, 0.0, 0.0);
    parent.children = vec![1];
    let mut crate_node = GlbNode::new("crate", Some(0));
    crate_node.translation = Vec3::new(0.0, 1.0, 0.0);
    crate_node.rotation = Quat::from_rotation_z(0.5);
    crate_node.scale = Vec3::splat(3.0);
    crate_node.extras = Some(serde_json::json!({ "lightwire": { "dynamic": true } }));
    let doc = GlbScene {
        nodes: vec![parent, crate_node],
        roots: vec![0],
        ..one_mesh_scene(
            vec![triangle_primitive(TRI, Some(0))],
            GlbNode::new("unused", None),
        )
    };
    let bytes = doc.to_glb().expect("write");
    let scene =
        import_slice(&bytes, None, "dynamic.glb", &ImportOptions::default()).expect("import");
    assert_eq!(scene.objects.len(), 2);
    let pose = scene.objects[1].pose;
    assert!(close(pose.translation, Vec3::new(10.0, 1.0, 0.0)));
    assert!(pose.rotation.angle_between(Quat::from_rotation_z(0.5)) < 1e-5);
    let inst = scene.instances_of("crate").next().expect("crate");
    assert_eq!(inst.object, 1);
    // The node's scale stays in the local geometry; the pose maps it to the
    // world position parent · node · p.
    for (local, p) in inst.positions.iter().zip(TRI) {
        let world = Vec3::new(10.0, 1.0, 0.0) + Quat::from_rotation_z(0.5) * (3.0 * p);
        assert!(close(*local, 3.0 * p), "{local}");
        assert!(close(pose.transform_point(*local), world));
    }
}

#[test]
fn writer_output_reimports_identically() {
    let positions = vec![
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(2.0, 0.0, 0.0),
        Vec3::new(2.0, 0.0, -3.0),
        Vec3::new(0.0, 0.0, -3.0),
    ];
    let primitive = GlbPrimitive {
        positions: positions.clone(),
        normals: Some(vec![Vec3::Y; 4]),
        uv0: Some(vec![
            Vec2::new(0.0, 0.0),
            Vec2::new(2.0, 0.0),
            Vec2::new(2.0, 3.0),
            Vec2::new(0.0, 3.0),
        ]),
        uv1: Some(vec![
            Vec2::new(0.1, 0.1),
            Vec2::new(0.9, 0.1),
            Vec2::new(0.9, 0.9),
            Vec2::new(0.1, 0.9),
        ]),
        indices: vec![[0, 2, 1], [0, 3, 2]],
        material: Some(1),
    };
    let doc = GlbScene {
        materials: vec![
            GlbMaterial {
                name: "dim".into(),
                base_color: Vec3::new(0.2, 0.3, 0.4),
                emission: Vec3::new(0.25, 0.5, 0.0),
                base_color_texture: None,
            },
            GlbMaterial {
                name: "bright".into(),
                base_color: Vec3::new(0.6, 0.6, 0.6),
                emission: Vec3::new(40.0, 20.0, 10.0),
                base_color_texture: None,
            },
        ],
        images: Vec::new(),
        meshes: vec![GlbMesh {
            name: "slab".into(),
            primitives: vec![primitive.clone()],
        }],
        nodes: vec![GlbNode::new("slab", Some(0))],
        roots: vec![0],
    };
    let bytes = doc.to_glb().expect("write");
    assert_eq!(bytes, doc.to_glb().expect("write again"), "deterministic");
    let scene =
        import_slice(&bytes, None, "roundtrip.glb", &ImportOptions::default()).expect("import");
    assert_eq!(scene.materials.len(), 2);
    for (got, want) in scene.materials.iter().zip(&doc.materials) {
        assert_eq!(got.name, want.name);
        assert_eq!(got.albedo, want.base_color);
        assert!(
            ((got.emission - want.emission) / want.emission.max(Vec3::ONE))
                .abs()
                .max_element()
                < 1e-6
        );
    }
    let inst = &scene.instances[0];
    assert_eq!(inst.node_name.as_deref(), Some("slab"));
    assert_eq!(inst.mesh_name.as_deref(), Some("slab"));
    assert_eq!(inst.material, 1);
    assert_eq!(inst.positions, primitive.positions);
    assert_eq!(inst.indices, primitive.indices);
    assert_eq!(inst.normals, primitive.normals);
    assert_eq!(inst.uv0, primitive.uv0);
    assert_eq!(inst.lightmap_uvs, primitive.uv1);
}

#[test]
fn albedo_of_one_is_clamped_below_one() {
    let mut doc = one_mesh_scene(
        vec![triangle_primitive(TRI, Some(0))],
        GlbNode::new("n", Some(0)),
    );
    doc.materials[0].base_color = Vec3::new(1.0, 0.5, 1.0);
    let scene = import_slice(
        &doc.to_glb().expect("write"),
        None,
        "white.glb",
        &ImportOptions::default(),
    )
    .expect("import");
    assert_eq!(scene.materials[0].albedo, Vec3::new(0.99, 0.5, 0.99));
    // A primitive without a material gets glTF's default (white), clamped.
    let doc = one_mesh_scene(
        vec![triangle_primitive(TRI, None)],
        GlbNode::new("n", Some(0)),
    );
    let scene = import_slice(
        &doc.to_glb().expect("write"),
        None,
        "default.glb",
        &ImportOptions::default(),
    )
    .expect("import");
    let m = &scene.materials[scene.instances[0].material as usize];
    assert_eq!((m.name.as_str(), m.albedo), ("default", Vec3::splat(0.99)));
}

// ---- bad input -----------------------------------------------------------

/// Edits the JSON chunk of a GLB.
fn edit_json(glb: &[u8], edit: impl FnOnce(&mut serde_json::Value)) -> Vec<u8> {
    let parsed = gltf::binary::Glb::from_slice(glb).expect("glb");
    let mut json: serde_json::Value = serde_json::from_slice(&parsed.json).expect("json");
    edit(&mut json);
    let bin = parsed.bin.map(|b| b.into_owned()).unwrap_or_default();
    pack_glb(json.to_string().as_bytes(), &bin).expect("pack")
}

/// Imports bytes that must fail; returns the message.
fn error_of(bytes: &[u8], origin: &str) -> String {
    match import_slice(bytes, None, origin, &ImportOptions::default()) {
        Ok(_) => panic!("{origin} was accepted"),
        Err(e) => e.to_string(),
    }
}

/// One triangle (or more primitives) on node "n", mesh "thing".
fn single(primitives: Vec<GlbPrimitive>) -> Vec<u8> {
    one_mesh_scene(primitives, GlbNode::new("n", Some(0)))
        .to_glb()
        .expect("write")
}

fn assert_names_everything(message: &str, file: &str, primitive: usize) {
    for part in [
        file.to_string(),
        "node #0 \"n\"".to_string(),
        "mesh #0 \"thing\"".to_string(),
        format!("primitive #{primitive}"),
    ] {
        assert!(message.contains(&part), "missing {part:?} in: {message}");
    }
}

#[test]
fn missing_file_is_an_io_error_naming_it() {
    let path = temp_dir("missing").join("nowhere.glb");
    let err = import(&path, &ImportOptions::default()).expect_err("missing");
    assert!(matches!(err, SceneError::Io { .. }), "{err:?}");
    assert!(err.to_string().contains("nowhere.glb"), "{err}");
}

#[test]
fn gltf_whose_bin_is_missing_names_the_buffer_file() {
    let doc = one_mesh_scene(
        vec![triangle_primitive(TRI, Some(0))],
        GlbNode::new("n", Some(0)),
    );
    let (json, bin) = doc.to_json_and_bin(Some("thing.bin")).expect("write");
    let dir = temp_dir("missing-bin");
    let gltf_path = dir.join("thing.gltf");
    std::fs::write(&gltf_path, &json).expect("write gltf");
    // With the .bin next to it, it imports.
    std::fs::write(dir.join("thing.bin"), &bin).expect("write bin");
    let scene = import(&gltf_path, &ImportOptions::default()).expect("import .gltf + .bin");
    assert_eq!(scene.triangle_count(), 1);
    // Without it, the error names the .gltf, the buffer and the .bin.
    std::fs::remove_file(dir.join("thing.bin")).expect("remove bin");
    let message = import(&gltf_path, &ImportOptions::default())
        .expect_err("no bin")
        .to_string();
    for part in ["thing.gltf", "buffer #0", "\"thing.bin\""] {
        assert!(message.contains(part), "missing {part:?} in: {message}");
    }
}

#[test]
fn bad_accessor_type_is_named() {
    let glb = single(vec![triangle_primitive(TRI, Some(0))]);
    // POSITION (accessor 0) as UNSIGNED_SHORT.
    let bad = edit_json(&glb, |j| j["accessors"][0]["componentType"] = 5123.into());
    let message = error_of(&bad, "ushort.glb");
    assert_names_everything(&message, "ushort.glb", 0);
    assert!(
        message.contains("POSITION accessor #0") && message.contains("must be FLOAT"),
        "{message}"
    );
    // POSITION as VEC2.
    let bad = edit_json(&glb, |j| j["accessors"][0]["type"] = "VEC2".into());
    let message = error_of(&bad, "vec2.glb");
    assert_names_everything(&message, "vec2.glb", 0);
    assert!(message.contains("must be VEC3"), "{message}");
    // Indices as FLOAT.
    let bad = edit_json(&glb, |j| j["accessors"][1]["componentType"] = 5126.into());
    let message = error_of(&bad, "float-indices.glb");
    assert_names_everything(&message, "float-indices.glb", 0);
    assert!(message.contains("indices accessor #1"), "{message}");
}

#[test]
fn accessor_past_its_buffer_view_is_named() {
    let glb = single(vec![triangle_primitive(TRI, Some(0))]);
    let bad = edit_json(&glb, |j| j["accessors"][0]["count"] = 4.into());
    let message = error_of(&bad, "long.glb");
    assert_names_everything(&message, "long.glb", 0);
    assert!(message.contains("past the end of buffer view"), "{message}");
}

#[test]
fn out_of_range_index_is_named_with_its_triangle() {
    let glb = single(vec![triangle_primitive(TRI, Some(0))]);
    // Two vertices left: index 2 is out of range.
    let bad = edit_json(&glb, |j| j["accessors"][0]["count"] = 2.into());
    let message = error_of(&bad, "short.glb");
    assert_names_everything(&message, "short.glb", 0);
    assert!(
        message.contains("triangle 0 has indices [0, 1, 2], but there are only 2 vertices"),
        "{message}"
    );
}

#[test]
fn non_triangle_primitive_is_named() {
    let glb = single(vec![triangle_primitive(TRI, Some(0))]);
    let bad = edit_json(&glb, |j| j["meshes"][0]["primitives"][0]["mode"] = 1.into());
    let message = error_of(&bad, "lines.glb");
    assert_names_everything(&message, "lines.glb", 0);
    assert!(
        message.contains("Lines") && message.contains("only TRIANGLES"),
        "{message}"
    );
}

#[test]
fn zero_area_and_duplicate_triangles_are_dropped_with_one_warning_each() {
    // Triangle 0 is sound; 1 has its corners on a line; 2 repeats an index;
    // 3 is triangle 0 again, same turning, from another corner (z-fighting);
    // 4 is triangle 0 turned the other way (a two-sided face: kept); 5 is a
    // sliver whose height is 1e-7 of its length.
    let mut p = triangle_primitive(TRI, Some(0));
    p.positions.extend([
        Vec3::new(0.0, 0.0, 1.0),
        Vec3::new(1.0, 1.0, 1.0),
        Vec3::new(2.0, 2.0, 1.0),
        Vec3::new(0.0, 0.0, 2.0),
        Vec3::new(10.0, 0.0, 2.0),
        Vec3::new(5.0, 1e-6, 2.0),
    ]);
    p.indices
        .extend([[3, 4, 5], [0, 0, 1], [1, 2, 0], [0, 2, 1], [6, 7, 8]]);
    let imported = import_slice(
        &single(vec![p]),
        None,
        "flat.glb",
        &ImportOptions::default(),
    )
    .unwrap_or_else(|e| panic!("refused: {e}"));
    assert_eq!(imported.instances.len(), 1);
    let inst = &imported.instances[0];
    assert_eq!(inst.indices, vec![[0, 1, 2], [0, 2, 1]]);
    assert_eq!(inst.triangle_numbers, vec![0, 4], "numbers in the glTF");
    let warnings: Vec<String> = imported.warnings.iter().map(|w| w.to_string()).collect();
    assert_eq!(warnings.len(), 2, "{warnings:#?}");
    for (w, kind, count) in [
        (&warnings[0], "zero-area", 3),
        (&warnings[1], "duplicate", 1),
    ] {
        assert!(w.contains(&format!("dropped {count} {kind}")), "{w}");
        assert!(
            w.contains(&format!(
                "node #0 \"n\", mesh #0 \"thing\", primitive #0: {count} of 6"
            )),
            "{w}"
        );
    }
}

#[test]
fn a_primitive_of_only_zero_area_triangles_leaves_no_instance_behind() {
    let mut flat = triangle_primitive(TRI, Some(0));
    flat.positions[2] = Vec3::new(2.0, 0.0, 0.0);
    let imported = import_slice(
        &single(vec![triangle_primitive(TRI, Some(0)), flat]),
        None,
        "flat.glb",
        &ImportOptions::default(),
    )
    .unwrap_or_else(|e| panic!("refused: {e}"));
    assert_eq!(imported.triangle_count(), 1);
    assert!(imported.instances.iter().all(|i| !i.indices.is_empty()));
    assert!(
        imported.warnings[0]
            .to_string()
            .contains("primitive #1: 1 of 1")
    );
}

#[test]
fn nan_and_infinite_positions_are_named() {
    let marker = 123.25f32;
    let mut p = triangle_primitive(TRI, Some(0));
    p.positions[1].x = marker;
    let glb = single(vec![p]);
    // Replace the marker in the binary chunk (the JSON holds it as text).
    let needle = marker.to_le_bytes();
    let at = glb
        .windows(4)
        .position(|w| w == needle)
        .expect("marker in bin");
    for (value, what) in [(f32::NAN, "NaN"), (f32::INFINITY, "inf")] {
        let mut bad = glb.clone();
        bad[at..at + 4].copy_from_slice(&value.to_le_bytes());
        let message = error_of(&bad, "nan.glb");
        assert_names_everything(&message, "nan.glb", 0);
        assert!(
            message.contains("POSITION of vertex 1") && message.contains(what),
            "{message}"
        );
        assert!(message.contains("not a finite number"), "{message}");
    }
}

fn with_uv1(positions: Vec<Vec3>, uv1: Vec<Vec2>, indices: Vec<[u32; 3]>) -> GlbPrimitive {
    GlbPrimitive {
        uv0: Some(uv1.clone()),
        uv1: Some(uv1),
        normals: None,
        positions,
        indices,
        material: Some(0),
    }
}

#[test]
fn lightmap_uvs_outside_the_unit_square_are_named() {
    let p = with_uv1(
        TRI.to_vec(),
        vec![
            Vec2::new(0.0, 0.0),
            Vec2::new(1.5, 0.0),
            Vec2::new(0.0, -0.25),
        ],
        vec![[0, 1, 2]],
    );
    let message = error_of(&single(vec![p]), "uv-range.glb");
    assert_names_everything(&message, "uv-range.glb", 0);
    assert!(message.contains("TEXCOORD_1 of vertex 1"), "{message}");
    assert!(message.contains("TEXCOORD_1 of vertex 2"), "{message}");
    assert!(!message.contains("vertex 0"), "{message}");
}

#[test]
fn overlapping_lightmap_uvs_are_named_also_across_primitives() {
    // Two triangles of one primitive on the same UVs.
    let quad = vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::new(0.0, 0.0, 1.0)];
    let uv = vec![
        Vec2::new(0.1, 0.1),
        Vec2::new(0.9, 0.1),
        Vec2::new(0.1, 0.9),
        Vec2::new(0.9, 0.9),
    ];
    let p = with_uv1(quad.clone(), uv.clone(), vec![[0, 1, 2], [0, 3, 2]]);
    let message = error_of(&single(vec![p]), "overlap.glb");
    assert_names_everything(&message, "overlap.glb", 0);
    assert!(
        message.contains("triangle 0 overlaps triangle 1 in TEXCOORD_1"),
        "{message}"
    );
    // Edge-sharing triangles are fine.
    let fine = with_uv1(quad.clone(), uv.clone(), vec![[0, 1, 2], [1, 3, 2]]);
    let ok = import_slice(
        &single(vec![fine]),
        None,
        "fine.glb",
        &ImportOptions::default(),
    );
    assert!(ok.is_ok(), "{:?}", ok.err());
    // Primitive 1's triangle lies on primitive 0's: one lightmap per mesh.
    let a = with_uv1(TRI.to_vec(), uv[..3].to_vec(), vec![[0, 1, 2]]);
    let b = with_uv1(
        TRI.iter().map(|p| *p + Vec3::Z).collect(),
        uv[..3].to_vec(),
        vec![[0, 1, 2]],
    );
    let message = error_of(&single(vec![a, b]), "two.glb");
    assert_names_everything(&message, "two.glb", 0);
    assert!(
        message.contains("overlaps triangle 0 of primitive #1"),
        "{message}"
    );
}

#[test]
fn zero_area_lightmap_triangle_is_named() {
    let p = with_uv1(
        TRI.to_vec(),
        vec![
            Vec2::new(0.1, 0.1),
            Vec2::new(0.5, 0.5),
            Vec2::new(0.9, 0.9),
        ],
        vec![[0, 1, 2]],
    );
    let message = error_of(&single(vec![p]), "uv-flat.glb");
    assert_names_everything(&message, "uv-flat.glb", 0);
    assert!(message.contains("zero area in TEXCOORD_1"), "{message}");
}

#[test]
fn all_problems_of_a_file_are_reported_together() {
    let lines = triangle_primitive(TRI, Some(0));
    let uv_out = with_uv1(
        TRI.to_vec(),
        vec![Vec2::ZERO, Vec2::new(2.0, 0.0), Vec2::Y],
        vec![[0, 1, 2]],
    );
    let glb = single(vec![lines, uv_out]);
    let bad = edit_json(&glb, |j| {
        j["meshes"][0]["primitives"][0]["mode"] = 1.into();
        // And a second node whose extras say dynamic: "yes".
        j["nodes"][0]["extras"] = serde_json::json!({ "lightwire": { "dynamic": "yes" } });
    });
    let err = import_slice(&bad, None, "many.glb", &ImportOptions::default()).expect_err("bad");
    let SceneError::Invalid { issues, .. } = &err else {
        panic!("{err:?}");
    };
    assert_eq!(issues.len(), 3, "{err}");
    let message = err.to_string();
    assert!(
        message.contains("primitive #0") && message.contains("only TRIANGLES"),
        "{message}"
    );
    assert!(
        message.contains("primitive #1") && message.contains("TEXCOORD_1 of vertex 1"),
        "{message}"
    );
    assert!(
        message.contains("extras.lightwire.dynamic = \"yes\""),
        "{message}"
    );
}

#[test]
fn malformed_json_is_a_syntax_error_with_position() {
    let glb = single(vec![triangle_primitive(TRI, Some(0))]);
    let parsed = gltf::binary::Glb::from_slice(&glb).expect("glb");
    let mut text = parsed.json.to_vec();
    text.truncate(text.len() / 2);
    let bad = pack_glb(
        &text,
        &parsed.bin.map(|b| b.into_owned()).unwrap_or_default(),
    )
    .expect("pack");
    let err = import_slice(&bad, None, "cut.glb", &ImportOptions::default()).expect_err("cut");
    assert!(matches!(err, SceneError::Syntax { .. }), "{err:?}");
    assert!(err.to_string().starts_with("cut.glb:1:"), "{err}");
}

/// 100 352 triangles with valid, non-overlapping lightmap UVs (a 224 × 224
/// grid) import; the UV overlap check is the costly part. (Timing is in
/// the report of the change, not asserted.)
#[test]
fn a_hundred_thousand_triangle_mesh_imports() {
    let n = 224;
    let mut p = GlbPrimitive {
        positions: Vec::new(),
        normals: None,
        uv0: Some(Vec::new()),
        uv1: Some(Vec::new()),
        indices: Vec::new(),
        material: Some(0),
    };
    for j in 0..=n {
        for i in 0..=n {
            let (s, t) = (i as f32 / n as f32, j as f32 / n as f32);
            p.positions.push(Vec3::new(10.0 * s, 0.0, -10.0 * t));
            for uv in [&mut p.uv0, &mut p.uv1].into_iter().flatten() {
                uv.push(Vec2::new(s, t));
            }
        }
    }
    let row = n as u32 + 1;
    for j in 0..n as u32 {
        for i in 0..n as u32 {
            let a = j * row + i;
            p.indices.push([a, a + 1, a + row + 1]);
            p.indices.push([a, a + row + 1, a + row]);
        }
    }
    let glb = single(vec![p]);
    let start = std::time::Instant::now();
    let scene = import_slice(&glb, None, "big.glb", &ImportOptions::default()).expect("import");
    eprintln!(
        "imported {} triangles in {:?}",
        scene.triangle_count(),
        start.elapsed()
    );
    assert_eq!(scene.triangle_count(), 2 * n * n);
}

// ---- the Khronos validator (lightwire_testkit::validator) -----------------

#[test]
fn khronos_validator_accepts_the_committed_meshes_and_refuses_a_broken_file() {
    let files: Vec<PathBuf> = content::FILES
        .iter()
        .map(|(n, _)| meshes_dir().join(n))
        .collect();
    let refs: Vec<&Path> = files.iter().map(PathBuf::as_path).collect();
    let (ok, text) = khronos_validate(&refs);
    assert!(ok, "{text}");
    assert_eq!(text.matches(" errors 0 ").count(), files.len(), "{text}");
    // A file with TEXCOORD_1 but no TEXCOORD_0 (the writer refuses to make
    // one; edit the JSON) must fail, or the check above proves nothing.
    let glb = std::fs::read(meshes_dir().join("cornell-large.glb")).expect("read");
    let bad = edit_json(&glb, |j| {
        if let Some(attrs) = j["meshes"][0]["primitives"][0]["attributes"].as_object_mut() {
            attrs.remove("TEXCOORD_0");
        }
    });
    let path = temp_dir("validator").join("broken.glb");
    std::fs::write(&path, bad).expect("write");
    let (ok, text) = khronos_validate(&[&path]);
    assert!(!ok, "the validator accepted a broken file: {text}");
    assert!(
        text.contains("MESH_PRIMITIVE_INDEXED_SEMANTIC_CONTINUITY"),
        "{text}"
    );
}

#[test]
fn gltf_schema_errors_name_the_json_path() {
    let glb = single(vec![triangle_primitive(TRI, Some(0))]);
    let bad = edit_json(&glb, |j| {
        j["meshes"][0]["primitives"][0]["indices"] = 99.into()
    });
    let message = error_of(&bad, "dangling.glb");
    assert!(message.starts_with("dangling.glb: 1 problem"), "{message}");
    assert!(
        message.contains("meshes[0].primitives[0].indices"),
        "{message}"
    );
}

#[test]
fn singular_transforms_are_named() {
    let mut flat = GlbNode::new("n", Some(0));
    flat.scale = Vec3::new(1.0, 0.0, 1.0);
    let bytes = one_mesh_scene(vec![triangle_primitive(TRI, Some(0))], flat)
        .to_glb()
        .expect("write");
    let message = error_of(&bytes, "flat-node.glb");
    assert!(
        message.contains("node #0 \"n\": its transform is singular"),
        "{message}"
    );
    // A dynamic node with zero scale and no mesh of its own: its pose.
    let mut holder = GlbNode::new("holder", None);
    holder.scale = Vec3::ZERO;
    holder.extras = Some(serde_json::json!({ "lightwire": { "dynamic": true } }));
    let doc = GlbScene {
        nodes: vec![holder],
        roots: vec![0],
        ..one_mesh_scene(
            vec![triangle_primitive(TRI, Some(0))],
            GlbNode::new("unused", None),
        )
    };
    let message = error_of(&doc.to_glb().expect("write"), "zero.glb");
    assert!(
        message.contains("node #0 \"holder\"")
            && message.contains("cannot be a dynamic object's pose"),
        "{message}"
    );
}

/// One textured triangle: material 0 reads image 0 through TEXCOORD_0,
/// which the primitive has when `uv0`.
fn textured(png: Vec<u8>, uv0: bool) -> GlbScene {
    let mut primitive = triangle_primitive(TRI, Some(0));
    primitive.uv0 = uv0.then(|| vec![Vec2::ZERO, Vec2::X, Vec2::Y]);
    let mut doc = one_mesh_scene(vec![primitive], GlbNode::new("n", Some(0)));
    doc.materials[0].base_color_texture = Some(0);
    doc.images.push(GlbImage {
        name: "checker".into(),
        png,
    });
    doc
}

fn tiny_png() -> Vec<u8> {
    let mut png = Vec::new();
    let encoder = image::codecs::png::PngEncoder::new(&mut png);
    image::ImageEncoder::write_image(
        encoder,
        &[188, 188, 188],
        1,
        1,
        image::ExtendedColorType::Rgb8,
    )
    .expect("PNG");
    png
}

#[test]
fn a_base_colour_texture_is_decoded_to_linear_colour() {
    let glb = textured(tiny_png(), true).to_glb().expect("write");
    let scene = import_slice(&glb, None, "t.glb", &ImportOptions::default()).expect("imports");
    let texture = scene.materials[0].texture.as_ref().expect("decoded");
    // sRGB 188 is linear 0.5.
    let c = texture.sample(Vec2::new(0.5, 0.5));
    assert!((c - Vec3::splat(0.5)).abs().max_element() < 0.005, "{c}");
}

#[test]
fn an_undecodable_texture_is_named_with_its_material_and_image() {
    let glb = textured(b"not an image at all".to_vec(), true)
        .to_glb()
        .expect("write");
    let message = error_of(&glb, "t.glb");
    for part in [
        "t.glb",
        "material #0 \"grey\"",
        "image #0 \"checker\"",
        "cannot decode",
    ] {
        assert!(message.contains(part), "missing {part:?} in: {message}");
    }
}

#[test]
fn a_textured_primitive_without_its_texture_coordinates_is_named() {
    let glb = textured(tiny_png(), false).to_glb().expect("write");
    let message = error_of(&glb, "t.glb");
    assert_names_everything(&message, "t.glb", 0);
    assert!(message.contains("TEXCOORD_0"), "{message}");
}

#[test]
fn a_texture_beside_the_gltf_loads_and_a_missing_one_is_named() {
    let dir = temp_dir("texture-uri");
    let (json, bin) = textured(tiny_png(), true)
        .to_json_and_bin(Some("thing.bin"))
        .expect("write");
    // The image by URI instead of in the buffer.
    let mut json: serde_json::Value = serde_json::from_str(&json).expect("json");
    json["images"][0] = serde_json::json!({ "uri": "checker.png", "name": "checker" });
    let gltf_path = dir.join("thing.gltf");
    std::fs::write(&gltf_path, json.to_string()).expect("write gltf");
    std::fs::write(dir.join("thing.bin"), &bin).expect("write bin");
    std::fs::write(dir.join("checker.png"), tiny_png()).expect("write png");
    let scene = import(&gltf_path, &ImportOptions::default()).expect("imports with its png");
    assert!(scene.materials[0].texture.is_some());
    std::fs::remove_file(dir.join("checker.png")).expect("remove png");
    let message = import(&gltf_path, &ImportOptions::default())
        .expect_err("no png")
        .to_string();
    for part in ["thing.gltf", "image #0 \"checker\"", "\"checker.png\""] {
        assert!(message.contains(part), "missing {part:?} in: {message}");
    }
}

/// Issue 59: a glTF's `KHR_lights_punctual` lights join the scene at their
/// nodes' world transforms (a light shines along its node's `-z`), their
/// photometric units read at 683 lm/W (683 cd is 1 W/sr, 683 lux 1
/// W/m²) times the import's `light_scale`.
#[test]
fn khr_lights_punctual_lights_import_at_their_nodes_in_radiometric_units() {
    let gltf = r#"{
      "asset": { "version": "2.0" },
      "extensionsUsed": ["KHR_lights_punctual"],
      "extensions": { "KHR_lights_punctual": { "lights": [
        { "type": "point", "color": [1, 0.5, 0.5], "intensity": 683, "range": 10 },
        { "type": "spot", "intensity": 1366, "spot": { "innerConeAngle": 0.2, "outerConeAngle": 0.6 } },
        { "type": "directional", "intensity": 683 }
      ] } },
      "buffers": [{ "byteLength": 60, "uri": "data:application/octet-stream;base64,AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAACAPwAAAAAAAIC/AAAAAAAAAAAAAIC/AAABAAIAAAACAAMA" }],
      "bufferViews": [
        { "buffer": 0, "byteOffset": 0, "byteLength": 48 },
        { "buffer": 0, "byteOffset": 48, "byteLength": 12 }
      ],
      "accessors": [
        { "bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [0, 0, -1], "max": [1, 0, 0] },
        { "bufferView": 1, "componentType": 5123, "count": 6, "type": "SCALAR" }
      ],
      "meshes": [{ "name": "floor", "primitives": [{ "attributes": { "POSITION": 0 }, "indices": 1 }] }],
      "nodes": [
        { "name": "floor", "mesh": 0 },
        { "name": "bulb", "translation": [0.5, 2, -0.5], "extensions": { "KHR_lights_punctual": { "light": 0 } } },
        { "name": "spot", "translation": [0.5, 3, -0.5], "rotation": [-0.70710678, 0, 0, 0.70710678],
          "extensions": { "KHR_lights_punctual": { "light": 1 } } },
        { "name": "sun", "rotation": [-0.70710678, 0, 0, 0.70710678], "extensions": { "KHR_lights_punctual": { "light": 2 } } }
      ],
      "scenes": [{ "nodes": [0, 1, 2, 3] }]
    }"#;
    let options = ImportOptions {
        light_scale: 2.0,
        ..ImportOptions::default()
    };
    let imported = import_slice(gltf.as_bytes(), None, "lights.gltf", &options).expect("import");
    let lights = &imported.lights;
    assert_eq!(lights.len(), 3, "{lights:?}");
    let near = |a: glam::Vec3, b: glam::Vec3| (a - b).length() < 1e-5;
    assert_eq!(lights[0].name, "bulb");
    assert!(near(lights[0].position, glam::Vec3::new(0.5, 2.0, -0.5)));
    assert!(
        near(lights[0].intensity, glam::Vec3::new(2.0, 1.0, 1.0)),
        "{:?}",
        lights[0]
    );
    assert_eq!(lights[0].range, Some(10.0));
    let lightwire_scene::LightKind::Spot {
        direction,
        inner,
        outer,
    } = lights[1].kind
    else {
        panic!("a spot: {:?}", lights[1])
    };
    assert!(near(direction, glam::Vec3::NEG_Y), "{direction}");
    assert!((inner - 0.2).abs() < 1e-6 && (outer - 0.6).abs() < 1e-6);
    assert!(near(lights[1].intensity, glam::Vec3::splat(4.0)));
    let lightwire_scene::LightKind::Directional { direction, .. } = lights[2].kind else {
        panic!("directional: {:?}", lights[2])
    };
    assert!(near(direction, glam::Vec3::NEG_Y), "{direction}");
    assert!(near(lights[2].intensity, glam::Vec3::splat(2.0)));
}

/// Issue 59: a light under a dynamic node rides with that node's object,
/// at its world transform where the object starts; no warning.
#[test]
fn a_light_under_a_dynamic_node_rides_with_its_object() {
    let gltf = r#"{
      "asset": { "version": "2.0" },
      "extensionsUsed": ["KHR_lights_punctual"],
      "extensions": { "KHR_lights_punctual": { "lights": [
        { "type": "point", "intensity": 683 }
      ] } },
      "buffers": [{ "byteLength": 60, "uri": "data:application/octet-stream;base64,AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAACAPwAAAAAAAIC/AAAAAAAAAAAAAIC/AAABAAIAAAACAAMA" }],
      "bufferViews": [
        { "buffer": 0, "byteOffset": 0, "byteLength": 48 },
        { "buffer": 0, "byteOffset": 48, "byteLength": 12 }
      ],
      "accessors": [
        { "bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [0, 0, -1], "max": [1, 0, 0] },
        { "bufferView": 1, "componentType": 5123, "count": 6, "type": "SCALAR" }
      ],
      "meshes": [{ "name": "plate", "primitives": [{ "attributes": { "POSITION": 0 }, "indices": 1 }] }],
      "nodes": [
        { "name": "floor", "mesh": 0 },
        { "name": "cart", "translation": [2, 0, 0], "mesh": 0, "children": [2],
          "extras": { "lightwire": { "dynamic": true } } },
        { "name": "lamp", "translation": [0, 1, 0], "extensions": { "KHR_lights_punctual": { "light": 0 } } }
      ],
      "scenes": [{ "nodes": [0, 1] }]
    }"#;
    let imported = import_slice(
        gltf.as_bytes(),
        None,
        "cart.gltf",
        &ImportOptions::default(),
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let lamp = &imported.lights[0];
    let object = lamp.object as usize;
    assert_ne!(object, 0, "the lamp rides with the cart: {lamp:?}");
    assert_eq!(imported.objects[object].name, "cart");
    assert!((lamp.position - glam::Vec3::new(2.0, 1.0, 0.0)).length() < 1e-5);
    assert!(
        imported
            .warnings
            .iter()
            .all(|w| !w.problem.contains("light")),
        "{:?}",
        imported.warnings
    );
}
