//! `GET /api/scenes/{id}/lights`: a scene's point, spot and directional
//! lights and its sky, as a scene file writes them (`scenes/README.md`,
//! `"lights"` and `"sky"`), for what draws them (the dashboard's gizmos,
//! `gizmos.js`). The wire's `SceneInfo` does not carry the sky; a relay,
//! which holds only that, has none to give.
//!
//! The route lists the lights as the newest published version was lit
//! with them ([`lights_as_lit`]: the states drivers' `SetLight`s gave
//! them, as `Lights` tells), each with `on` and the `seq` of the
//! `SetLight` that set it (0: the scene file's state); an off light keeps
//! the colour and intensity it has when switched on. Each also carries
//! under `file` its state as the scene file gives it, which no `SetLight`
//! changes: what the dashboard anchors a sun's day path and the intensity
//! slider's scale on, so that pages agree whenever they connected.
//!
//! Each light has only the keys of its type, in the scene file's units:
//! its colour is the channels over the largest and its intensity the
//! largest (W/sr; W/m² for a directional light), so `color` times
//! `intensity` is the radiant intensity the solvers use; directions are
//! unit; cones and a sun's disc are in degrees. Pasted into a scene file,
//! the list gives the same lights again.

use lightwire_protocol::{LightState, LightStatus};
use lightwire_scene::{Light, LightKind, Scene, Sky};
use serde::Serialize;

/// The answer: every light, and the sky (`null` when the scene has none).
#[derive(Debug, Serialize)]
pub struct SceneLights {
    pub lights: Vec<LightEntry>,
    pub sky: Option<SkyEntry>,
}

/// One light, as a scene file's `"lights"` entry.
#[derive(Debug, Serialize)]
pub struct LightEntry {
    pub name: String,
    /// `"point"`, `"spot"` or `"directional"`.
    #[serde(rename = "type")]
    pub kind: &'static str,
    /// Where a point or spot light is (metres); none for a directional one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub position: Option<[f32; 3]>,
    /// A spot's axis, or where a directional light's light travels (unit).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub direction: Option<[f32; 3]>,
    /// Linear colour, the largest channel 1 (white for a black light).
    pub color: [f32; 3],
    /// The largest channel's radiant intensity on the axis, W/sr; a
    /// directional light's irradiance at normal incidence, W/m².
    pub intensity: f32,
    /// glTF's `range` of a point or spot light, if it has one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub range: Option<f32>,
    /// A spot's full-intensity cone, degrees from its axis.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub inner_cone_deg: Option<f32>,
    /// A spot's cut-off, degrees from its axis.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub outer_cone_deg: Option<f32>,
    /// A directional light's disc, degrees across.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub angular_diameter_deg: Option<f32>,
    /// Whether the light is on ([`lights_as_lit`] only; a scene file has
    /// no such key, its black lights are off).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub on: Option<bool>,
    /// The seq of the `SetLight` that set this state, 0 for the scene
    /// file's ([`lights_as_lit`] only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub seq: Option<u64>,
    /// The light's state as the scene file gives it, whatever `SetLight`s
    /// did since ([`lights_as_lit`] only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub file: Option<FileState>,
}

/// A light's state in the scene file, in its entry's keys and units (what
/// a `Welcome` tells before any `SetLight`): a black light is off, white
/// and of intensity 0; `position` only for a point or spot light,
/// `direction` only for a spot or directional one.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FileState {
    pub on: bool,
    pub color: [f32; 3],
    pub intensity: f32,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub position: Option<[f32; 3]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub direction: Option<[f32; 3]>,
}

impl FileState {
    /// `light`'s state as `entry` (its [`light_entry`]) gives it.
    fn of(light: &Light, entry: &LightEntry) -> FileState {
        FileState {
            on: light.intensity.max_element() > 0.0,
            color: entry.color,
            intensity: entry.intensity,
            position: entry.position,
            direction: entry.direction,
        }
    }
}

/// The sky: radiance (W/(m² sr) per channel) at the zenith and the
/// horizon.
#[derive(Debug, Serialize)]
pub struct SkyEntry {
    pub zenith: [f32; 3],
    pub horizon: [f32; 3],
    /// The ground's albedo below the horizon (black: `[0, 0, 0]`).
    pub ground_albedo: [f32; 3],
}

/// `scene`'s lights and sky.
pub fn scene_lights(scene: &Scene) -> SceneLights {
    SceneLights {
        lights: scene.lights.iter().map(light_entry).collect(),
        sky: scene.sky.as_ref().map(sky_entry),
    }
}

/// `scene`'s lights in the states `lit` gives them (a publication's
/// `Lights`; a light it does not list is as the scene file has it, seq 0),
/// each with its scene file's state under `file`, and its sky.
pub fn lights_as_lit(scene: &Scene, lit: &[LightStatus]) -> SceneLights {
    let lights = scene
        .lights
        .iter()
        .enumerate()
        .map(|(k, base)| {
            let mut entry = match lit.iter().find(|s| s.light as usize == k) {
                Some(s) => {
                    // Its colour and intensity as when on, and whether it is.
                    let shining = LightState {
                        on: true,
                        ..s.state
                    };
                    let mut entry = light_entry(&super::wire::light_from_wire(base, &shining));
                    entry.on = Some(s.state.on);
                    entry.seq = Some(s.seq);
                    entry
                }
                None => {
                    let mut entry = light_entry(base);
                    entry.on = Some(base.intensity.max_element() > 0.0);
                    entry.seq = Some(0);
                    entry
                }
            };
            entry.file = Some(FileState::of(base, &light_entry(base)));
            entry
        })
        .collect();
    SceneLights {
        lights,
        sky: scene.sky.as_ref().map(sky_entry),
    }
}

/// One light as a scene file gives it.
pub fn light_entry(light: &Light) -> LightEntry {
    let peak = light.intensity.max_element().max(0.0);
    let color = if peak > 0.0 {
        (light.intensity / peak).to_array()
    } else {
        [1.0; 3]
    };
    let mut entry = LightEntry {
        name: light.name.clone(),
        kind: "point",
        position: Some(light.position.to_array()),
        direction: None,
        color,
        intensity: peak,
        range: light.range,
        inner_cone_deg: None,
        outer_cone_deg: None,
        angular_diameter_deg: None,
        on: None,
        seq: None,
        file: None,
    };
    match light.kind {
        LightKind::Point => {}
        LightKind::Spot {
            direction,
            inner,
            outer,
        } => {
            entry.kind = "spot";
            entry.direction = Some(direction.to_array());
            entry.inner_cone_deg = Some(inner.to_degrees());
            entry.outer_cone_deg = Some(outer.to_degrees());
        }
        LightKind::Directional {
            direction,
            angular_radius,
        } => {
            entry.kind = "directional";
            entry.position = None;
            entry.range = None;
            entry.direction = Some(direction.to_array());
            entry.angular_diameter_deg = Some((2.0 * angular_radius).to_degrees());
        }
    }
    entry
}

fn sky_entry(sky: &Sky) -> SkyEntry {
    SkyEntry {
        zenith: sky.zenith.to_array(),
        horizon: sky.horizon.to_array(),
        ground_albedo: sky.ground_albedo.to_array(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    /// A glowing plate (a scene needs some light) with `lights` and `sky`
    /// (JSON) as a scene file.
    fn plate(lights: &str, sky: &str) -> Scene {
        let text = format!(
            r#"{{ "name": "t", "lightmap": {{ "texel_density": 2 }},
                "materials": [{{ "name": "m", "albedo": [0.5, 0.5, 0.5], "emission": [1, 1, 1] }}],
                "surfaces": [{{ "name": "floor", "material": "m",
                    "quad": {{ "origin": [0, 0, 0], "u": [0, 0, 1], "v": [1, 0, 0] }} }}],
                "lights": {lights}, "sky": {sky} }}"#
        );
        Scene::parse(&text, "t.json").unwrap_or_else(|e| panic!("{e}\n{text}"))
    }

    /// Every kind of light, served and pasted into a scene file again, is
    /// the same light (1e-5 relative); so is the sky; a directional light
    /// has no position or range, a point light no direction.
    #[test]
    fn the_lights_read_back_as_a_scene_file_are_the_same() {
        let scene = plate(
            r#"[
              { "name": "bulb", "type": "point", "position": [0.4, 0.9, 1.1], "color": [1, 0.8, 0.6], "intensity": 5, "range": 6 },
              { "name": "dim", "type": "point", "position": [0, 1, 0], "color": [0.5, 0.25, 0.1], "intensity": 3 },
              { "name": "spot", "type": "spot", "position": [1, 0.95, 1], "direction": [0.2, -1, 0.1], "intensity": 12,
                "inner_cone_deg": 20, "outer_cone_deg": 35 },
              { "name": "sun", "type": "directional", "direction": [0.3, -0.8, -0.5], "color": [1, 0.95, 0.85], "intensity": 700,
                "angular_diameter_deg": 0.53 }
            ]"#,
            r#"{ "zenith": [2, 3, 5], "horizon": [4, 4, 4.5] }"#,
        );
        let served = serde_json::to_value(scene_lights(&scene)).expect("JSON");
        let entries = served["lights"].as_array().expect("a list");
        assert_eq!(entries.len(), 4);
        assert!(entries[0].get("direction").is_none(), "{}", entries[0]);
        assert!(entries[3].get("position").is_none(), "{}", entries[3]);
        assert!(entries[3].get("range").is_none(), "{}", entries[3]);
        assert_eq!(entries[1]["color"][0], 1.0, "normalised: {}", entries[1]);
        assert_eq!(entries[2]["type"], "spot");

        let again = plate(&served["lights"].to_string(), &served["sky"].to_string());
        let close = |a: Vec3, b: Vec3| (a - b).length() <= 1e-5 * b.length().max(1.0);
        assert_eq!(again.lights.len(), scene.lights.len());
        for (got, want) in again.lights.iter().zip(&scene.lights) {
            assert_eq!(got.name, want.name);
            assert!(close(got.intensity, want.intensity), "{got:?} vs {want:?}");
            assert!(close(got.position, want.position), "{got:?} vs {want:?}");
            assert_eq!(got.range, want.range);
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
                    assert!(close(d, direction), "{d} vs {direction}");
                    assert!((i - inner).abs() < 1e-6 && (o - outer).abs() < 1e-6);
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
                    assert!(close(d, direction), "{d} vs {direction}");
                    assert!((r - angular_radius).abs() < 1e-7, "{r} vs {angular_radius}");
                }
                (got, want) => panic!("{got:?} where {want:?} was served"),
            }
        }
        let (sky, want) = (again.sky.expect("a sky"), scene.sky.expect("a sky"));
        assert!(close(sky.zenith, want.zenith) && close(sky.horizon, want.horizon));
    }

    /// A light switched off, dimmed and moved by a `SetLight` is listed
    /// where it is now, off, with its seq, and its scene file's state
    /// under `file`; one no status names is the file's.
    #[test]
    fn the_lights_are_listed_as_the_newest_version_was_lit() {
        let scene = plate(
            r#"[
              { "name": "bulb", "type": "point", "position": [0.4, 0.9, 1.1], "color": [1, 0.8, 0.6], "intensity": 5 },
              { "name": "sun", "type": "directional", "direction": [0, -1, 0], "intensity": 700 }
            ]"#,
            "null",
        );
        let described = crate::bake::light_info(&scene.lights[0]).state;
        let moved = LightState {
            on: false,
            position: [0.1, 0.5, 0.2],
            intensity: 2.0,
            ..described
        };
        let lit = [LightStatus {
            light: 0,
            seq: 9,
            state: moved,
        }];
        let served = serde_json::to_value(lights_as_lit(&scene, &lit)).expect("JSON");
        let bulb = &served["lights"][0];
        assert_eq!(bulb["on"], false, "{bulb}");
        assert_eq!(bulb["seq"], 9);
        assert_eq!(bulb["intensity"], 2.0, "as when on: {bulb}");
        let at: Vec<f64> = (0..3)
            .map(|i| bulb["position"][i].as_f64().expect("a number"))
            .collect();
        assert!(
            (at[0] - 0.1).abs() < 1e-6 && (at[1] - 0.5).abs() < 1e-6,
            "{bulb}"
        );
        let sun = &served["lights"][1];
        assert_eq!(
            (&sun["on"], &sun["seq"]),
            (&true.into(), &0.into()),
            "{sun}"
        );
        // The scene file's states stay under `file`, in the entries' keys.
        assert_eq!(
            bulb["file"],
            serde_json::to_value(FileState {
                on: true,
                color: [1.0, 0.8, 0.6],
                intensity: 5.0,
                position: Some([0.4, 0.9, 1.1]),
                direction: None,
            })
            .expect("JSON"),
            "{bulb}"
        );
        assert_eq!(
            sun["file"],
            serde_json::json!({ "on": true, "color": [1.0, 1.0, 1.0], "intensity": 700.0,
                                "direction": [0.0, -1.0, 0.0] }),
            "{sun}"
        );
        let file = serde_json::to_value(scene_lights(&scene)).expect("JSON");
        assert!(
            file["lights"][0].get("on").is_none() && file["lights"][0].get("file").is_none(),
            "a scene file has no on or file"
        );
    }

    #[test]
    fn a_scene_without_lights_or_sky_serves_an_empty_list_and_null() {
        let scene = plate("[]", "null");
        let served = serde_json::to_value(scene_lights(&scene)).expect("JSON");
        assert_eq!(served, serde_json::json!({ "lights": [], "sky": null }));
    }
}
