//! The example transform scripts in `scenes/scripts/`: each parses, and
//! sampled at 100 Hz over its period it keeps the box of every Cornell
//! scene inside that scene's room (all eight corners, turned and moved);
//! the light scripts name their scene's lights and play valid states (the
//! day's sun comes in through the window, the switch steps as it says).

use std::path::{Path, PathBuf};

use lightwire_client::script::Script;
use lightwire_client::{Pose, SceneInfo};
use lightwire_protocol::{LightInfo, LightState, LightType, ObjectInfo, PixelFormat, SurfaceInfo};
use lightwire_testkit::repo;
use serde_json::Value;

/// The light scripts of `scenes/scripts/` and the scene each plays.
const LIGHT_SCRIPTS: [(&str, &str); 2] = [("day", "window-sun"), ("switch", "cornell-point")];

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
    for o in json["objects"].as_array().into_iter().flatten() {
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
        lights: json["lights"]
            .as_array()
            .into_iter()
            .flatten()
            .map(light_info)
            .collect(),
    }
}

/// A scene file's light as `lightwire serve` describes it: its largest
/// channel as the intensity, the channels over it as the colour; a point
/// light pointing down.
fn light_info(l: &Value) -> LightInfo {
    let color = if l["color"].is_null() {
        [1.0; 3]
    } else {
        vec3(&l["color"])
    };
    let intensity = l["intensity"].as_f64().expect("intensity") as f32;
    let channels = color.map(|c| c * intensity);
    let largest = channels.into_iter().fold(0.0, f32::max);
    let kind = match l["type"].as_str().expect("type") {
        "point" => LightType::Point,
        "spot" => LightType::Spot,
        _ => LightType::Directional,
    };
    let or = |key: &str, default: [f32; 3]| {
        if l[key].is_null() {
            default
        } else {
            vec3(&l[key])
        }
    };
    LightInfo {
        name: l["name"].as_str().expect("name").into(),
        kind,
        range: None,
        cone: [0.0; 2],
        angular_radius: 0.0,
        state: LightState {
            on: largest > 0.0,
            color: channels.map(|c| c / largest),
            intensity: largest,
            position: or("position", [0.0; 3]),
            direction: or("direction", [0.0, -1.0, 0.0]),
        },
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
            if !script.has_poses() {
                // A light script: checked against its scene below.
                let name = path.file_stem().expect("name").to_string_lossy();
                assert!(
                    LIGHT_SCRIPTS.iter().any(|(s, _)| *s == name),
                    "{}: a script without keyframes must be in LIGHT_SCRIPTS",
                    path.display()
                );
                continue;
            }
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

/// Samples light track `track` of `script` every 10 ms over one period,
/// from the state `base`: (t, state), every state valid.
fn samples(script: &Script, track: usize, base: &LightState) -> Vec<(f64, LightState)> {
    let steps = (script.duration() * 100.0).round() as usize;
    (0..=steps)
        .map(|i| {
            let t = i as f64 / 100.0;
            let state = script.light_at(track, t, base);
            state
                .validate()
                .unwrap_or_else(|e| panic!("t = {t}: {e}: {state:?}"));
            (t, state)
        })
        .collect()
}

#[test]
fn the_light_scripts_name_their_scenes_lights_and_play_valid_states() {
    for (name, scene) in LIGHT_SCRIPTS {
        let path = repo().join(format!("scenes/scripts/{name}.json"));
        let script = Script::load(&path).unwrap_or_else(|e| panic!("{e}"));
        let info = scene_info(&repo().join(format!("scenes/{scene}.json")));
        let indices = script
            .light_indices(&info)
            .unwrap_or_else(|e| panic!("{e}"));
        assert!(script.looping, "{name}: examples loop");
        assert!(!indices.is_empty(), "{name} plays no light");
        for (track, light) in indices.into_iter().enumerate() {
            samples(&script, track, &info.lights[light as usize].state);
        }
        // Against any other scene, the names are refused with the lights
        // it has.
        let other = scene_info(&repo().join("scenes/cornell-low.json"));
        let err = script
            .light_indices(&other)
            .expect_err("no such light")
            .to_string();
        assert!(
            err.contains("has no light") && err.contains("lights."),
            "{err}"
        );
    }
}

/// The day's sun comes in through the window of window-sun (in the south
/// wall, z = 5, x 2..4, y 1..2.2) whenever it is up, lands on the floor
/// for most of the day, and is dimmer and warmer at its ends than at noon.
#[test]
fn the_days_sun_shines_through_the_window_and_warms_at_the_ends() {
    let script =
        Script::load(&repo().join("scenes/scripts/day.json")).unwrap_or_else(|e| panic!("{e}"));
    let info = scene_info(&repo().join("scenes/window-sun.json"));
    let sun = info.lights[0].state;
    assert_eq!(info.lights[0].name, "sun");
    let day = samples(&script, 0, &sun);
    let up: Vec<&(f64, LightState)> = day.iter().filter(|(_, s)| s.on).collect();
    assert!(
        up.len() * 10 > day.len() * 7,
        "up {} of {} samples",
        up.len(),
        day.len()
    );
    let mut on_floor = 0;
    for (t, s) in &up {
        let d = s.direction;
        assert!(
            d[1] < 0.0 && d[2] < 0.0,
            "t = {t}: {d:?} does not come down through the south window"
        );
        // From the window's centre along the light: where does it land?
        let k = 1.6 / -d[1];
        let (x, z) = (3.0 + d[0] * k, 5.0 + d[2] * k);
        if (0.0..=6.0).contains(&x) && (0.0..=5.0).contains(&z) {
            on_floor += 1;
        }
    }
    assert!(
        on_floor * 2 > up.len(),
        "the patch is on the floor for {on_floor} of {} samples",
        up.len()
    );
    // The scene file's own sun is one of the day's states.
    let close = |a: [f32; 3], b: [f32; 3]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-3);
    assert!(
        day.iter().any(|(_, s)| close(s.direction, sun.direction)
            && close(s.color, sun.color)
            && (s.intensity - sun.intensity).abs() < 1e-3),
        "the day passes the scene's sun"
    );
    let warmth = |s: &LightState| s.color[2] / s.color[0];
    let noon = up
        .iter()
        .map(|(_, s)| s)
        .max_by(|a, b| a.intensity.total_cmp(&b.intensity))
        .expect("noon");
    let (morning, evening) = (up[0].1, up[up.len() - 1].1);
    for end in [morning, evening] {
        assert!(
            end.intensity < noon.intensity / 4.0,
            "{end:?} vs noon {noon:?}"
        );
        assert!(
            warmth(&end) < warmth(noon) / 2.0,
            "{end:?} vs noon {noon:?}"
        );
    }
}

/// The switch steps the bulb of cornell-point off, on and dimmer, as its
/// description says, keeping its colour and position.
#[test]
fn the_switch_steps_the_bulb_off_on_and_dimmer() {
    let script =
        Script::load(&repo().join("scenes/scripts/switch.json")).unwrap_or_else(|e| panic!("{e}"));
    let info = scene_info(&repo().join("scenes/cornell-point.json"));
    let bulb = info.lights[0].state;
    assert_eq!(script.duration(), 10.0);
    for (t, on, intensity) in [
        (0.0, true, 8.0),
        (1.99, true, 8.0),
        (2.0, false, 8.0),
        (3.99, false, 8.0),
        (4.0, true, 8.0),
        (6.5, true, 3.0),
        (8.5, true, 1.0),
        (10.5, true, 8.0),
        (12.5, false, 8.0),
    ] {
        let s = script.light_at(0, t, &bulb);
        assert_eq!(
            (s.on, s.intensity, s.color, s.position),
            (on, intensity, bulb.color, bulb.position),
            "t = {t}"
        );
    }
}
