//! The example transform scripts in `scenes/scripts/`: each parses, and
//! sampled at 100 Hz over its period it keeps the box of every Cornell
//! scene inside that scene's room (all eight corners, turned and moved).

use std::path::{Path, PathBuf};

use lightwire_client::script::Script;
use lightwire_client::{Pose, SceneInfo};
use lightwire_protocol::{ObjectInfo, PixelFormat, SurfaceInfo};
use lightwire_testkit::repo;
use serde_json::Value;

fn vec3(v: &Value) -> [f32; 3] {
    let a = v.as_array().expect("a 3-vector");
    [0, 1, 2].map(|i| a[i].as_f64().expect("a number") as f32)
}

/// The geometry of a scene file as a `Welcome` would describe it (quads
/// and boxes; the atlas rectangles do not matter here).
fn scene_info(path: &Path) -> SceneInfo {
    let json: Value =
        serde_json::from_str(&std::fs::read_to_string(path).expect("scene file")).expect("json");
    let mut objects = vec![ObjectInfo {
        name: "static".into(),
        dynamic: false,
        pose: Pose::IDENTITY,
    }];
    for o in json["objects"].as_array().expect("objects") {
        objects.push(ObjectInfo {
            name: o["name"].as_str().expect("name").into(),
            dynamic: true,
            pose: Pose {
                translation: vec3(&o["pose"]["translation"]),
                ..Pose::IDENTITY
            },
        });
    }
    let mut surfaces = Vec::new();
    for s in json["surfaces"].as_array().expect("surfaces") {
        let object = s["object"].as_str().map_or(0, |name| {
            objects
                .iter()
                .position(|o| o.name == name)
                .expect("object exists") as u32
        });
        let quads: Vec<[[f32; 3]; 4]> = if let Some(q) = s.get("quad") {
            let (o, u, v) = (vec3(&q["origin"]), vec3(&q["u"]), vec3(&q["v"]));
            let at = |a: f32, b: f32| [0, 1, 2].map(|i| o[i] + a * u[i] + b * v[i]);
            vec![[at(0.0, 0.0), at(1.0, 0.0), at(1.0, 1.0), at(0.0, 1.0)]]
        } else {
            // A box: its bottom and top faces hold all eight corners.
            let (c, size) = (vec3(&s["box"]["center"]), vec3(&s["box"]["size"]));
            let h = size.map(|v| v / 2.0);
            let corner =
                |sx: f32, sy: f32, sz: f32| [c[0] + sx * h[0], c[1] + sy * h[1], c[2] + sz * h[2]];
            [-1.0, 1.0]
                .map(|sy| {
                    [
                        corner(-1.0, sy, -1.0),
                        corner(1.0, sy, -1.0),
                        corner(1.0, sy, 1.0),
                        corner(-1.0, sy, 1.0),
                    ]
                })
                .to_vec()
        };
        for corners in quads {
            surfaces.push(SurfaceInfo {
                name: s["name"].as_str().expect("name").into(),
                object,
                material: 0,
                corners,
                rect: [0; 4],
                uvs: Vec::new(),
            });
        }
    }
    SceneInfo {
        id: json["name"].as_str().expect("name").into(),
        atlas_width: 1,
        atlas_height: 1,
        tile_size: 8,
        format: PixelFormat::Rgb9e5,
        objects,
        materials: vec![],
        surfaces,
        lights: Vec::new(),
    }
}

#[test]
fn every_example_script_keeps_the_box_inside_every_cornell_room() {
    let scripts: Vec<PathBuf> = std::fs::read_dir(repo().join("scenes/scripts"))
        .expect("scenes/scripts")
        .map(|e| e.expect("entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "json"))
        .collect();
    let names: Vec<String> = scripts
        .iter()
        .map(|p| p.file_stem().expect("name").to_string_lossy().into_owned())
        .collect();
    for expected in ["orbit", "rotate", "teleport-stress", "jitter"] {
        assert!(
            names.iter().any(|n| n == expected),
            "scenes/scripts/{expected}.json is missing"
        );
    }
    for scene in ["cornell-low", "cornell-small", "cornell-large"] {
        let info = scene_info(&repo().join(format!("scenes/{scene}.json")));
        let object = info
            .objects
            .iter()
            .position(|o| o.name == "box")
            .expect("the box") as u32;
        for path in &scripts {
            let script = Script::load(path).unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(script.object.as_deref(), Some("box"), "{}", path.display());
            assert!(script.looping, "{}: examples loop", path.display());
            if let Some(exit) = script.leaves_the_room(&info, object) {
                panic!("{} in {scene}: {exit}", path.display());
            }
        }
    }
}

#[test]
fn a_script_that_leaves_the_room_is_caught() {
    let info = scene_info(&repo().join("scenes/cornell-low.json"));
    let script = Script::parse(
        r#"{ "keyframes": [
            { "t": 0, "translation": [2.78, 0.85, 2.796] },
            { "t": 1, "translation": [5.0, 0.85, 2.796] }
        ] }"#,
        "escape.json",
    )
    .expect("valid");
    let exit = script
        .leaves_the_room(&info, 1)
        .expect("x = 5.0 + 0.8 > 5.56");
    assert!(exit.contains("outside the room"), "{exit}");
}

#[test]
fn the_indirect_light_scripts_keep_its_box_inside_its_room() {
    let dir = repo().join("scenes/scripts/indirect-light");
    let info = scene_info(&repo().join("scenes/indirect-light.json"));
    let object = info
        .objects
        .iter()
        .position(|o| o.name == "box")
        .expect("the box") as u32;
    for name in ["rotate", "orbit"] {
        let path = dir.join(format!("{name}.json"));
        let script = Script::load(&path).unwrap_or_else(|e| panic!("{e}"));
        assert!(script.looping, "{}: examples loop", path.display());
        if let Some(exit) = script.leaves_the_room(&info, object) {
            panic!("{} in indirect-light: {exit}", path.display());
        }
    }
}
