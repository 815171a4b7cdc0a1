//! The scene file's `"lights"` (point, spot and directional) and `"sky"`,
//! checked.

use super::Checker;
use crate::file::{LightJson, SkyJson};
use crate::light::{Light, LightKind, Sky};

/// Checks every light and returns the valid ones: a unique name, a type of
/// `point`, `spot` or `directional`, a finite colour and intensity (>= 0);
/// a point or spot light's finite position and range > 0 if any; a spot's
/// or directional light's direction of non-zero length; a spot's cones
/// with `0 <= inner < outer <= 90` degrees, a directional light's angular
/// diameter from 0 to 20 degrees; and no key of another type.
pub(super) fn check_lights(
    c: &mut Checker,
    raw: &[LightJson],
    objects: &[crate::Object],
) -> Vec<Light> {
    c.unique("light", raw.iter().map(|l| l.name.as_str()));
    let mut out = Vec::new();
    for (i, l) in raw.iter().enumerate() {
        let loc = format!("light #{i} \"{}\"", l.name);
        let directional = l.kind == "directional";
        let position = match (&l.position, directional) {
            (Some(p), false) => c.vec3(&loc, "position", p),
            (None, false) => {
                c.report(&loc, format!("a {} light needs a position", l.kind));
                None
            }
            (Some(_), true) => {
                c.report(
                    &loc,
                    "a directional light has no position (it is infinitely far)",
                );
                None
            }
            (None, true) => Some(glam::Vec3::ZERO),
        };
        let color = c.vec3(&loc, "color", &l.color);
        if color.is_some_and(|v| v.min_element() < 0.0) {
            c.report(&loc, "color must be >= 0 per channel");
        }
        let intensity = c.finite(&loc, "intensity", l.intensity);
        if intensity.is_some_and(|v| v < 0.0) {
            c.report(
                &loc,
                "intensity must be >= 0 (W/sr; W/m² for a directional light)",
            );
        }
        let range = match l.range {
            None => Some(None),
            Some(r) => match c.finite(&loc, "range", r) {
                Some(r) if r > 0.0 => Some(Some(r)),
                Some(r) => {
                    c.report(
                        &loc,
                        format!("range = {r} must be > 0 (or absent: no cut-off)"),
                    );
                    None
                }
                None => None,
            },
        };
        let own: &[&str] = match l.kind.as_str() {
            "point" => &["range"],
            "spot" => &["range", "direction", "inner_cone_deg", "outer_cone_deg"],
            "directional" => &["direction", "angular_diameter_deg"],
            _ => &[],
        };
        for (key, given) in [
            ("range", l.range.is_some()),
            ("direction", l.direction.is_some()),
            ("inner_cone_deg", l.inner_cone_deg.is_some()),
            ("outer_cone_deg", l.outer_cone_deg.is_some()),
            ("angular_diameter_deg", l.angular_diameter_deg.is_some()),
        ] {
            if given && !own.is_empty() && !own.contains(&key) {
                c.report(&loc, format!("{key} is not for a {} light", l.kind));
            }
        }
        let kind = match l.kind.as_str() {
            "point" => Some(LightKind::Point),
            "spot" => spot(c, &loc, l),
            "directional" => sun(c, &loc, l),
            other => {
                c.report(
                    &loc,
                    format!(
                        "type \"{other}\" is not a light type: \"point\", \"spot\" or \"directional\""
                    ),
                );
                None
            }
        };
        let object = match &l.object {
            None => Some(crate::STATIC_OBJECT),
            Some(name) => {
                let found = objects.iter().position(|o| o.dynamic && o.name == *name);
                if found.is_none() {
                    let dynamic: Vec<&str> = objects
                        .iter()
                        .filter(|o| o.dynamic)
                        .map(|o| o.name.as_str())
                        .collect();
                    c.report(
                        &loc,
                        format!(
                            "object \"{name}\" is not a dynamic object of the scene (its dynamic objects: {})",
                            if dynamic.is_empty() { "none".to_string() } else { dynamic.join(", ") }
                        ),
                    );
                }
                found.map(|o| o as u32)
            }
        };
        if let (
            Some(position),
            Some(color),
            Some(intensity),
            Some(range),
            Some(kind),
            Some(object),
        ) = (position, color, intensity, range, kind, object)
        {
            out.push(Light {
                name: l.name.clone(),
                kind,
                position,
                intensity: color * intensity,
                range,
                object,
            });
        }
    }
    out
}

/// A light's direction: given, finite, of non-zero length; unit.
fn direction(c: &mut Checker, loc: &str, l: &LightJson) -> Option<glam::Vec3> {
    let Some(direction) = &l.direction else {
        c.report(loc, format!("a {} light needs a direction", l.kind));
        return None;
    };
    let direction = c.vec3(loc, "direction", direction)?;
    if direction.length() <= 1e-6 {
        c.report(loc, format!("direction {direction} has no length"));
        return None;
    }
    Some(direction.normalize())
}

/// Largest angular diameter of a directional light's disc (degrees).
pub const MAX_ANGULAR_DIAMETER_DEG: f32 = 20.0;

fn sun(c: &mut Checker, loc: &str, l: &LightJson) -> Option<LightKind> {
    let direction = direction(c, loc, l)?;
    let diameter = c.finite(
        loc,
        "angular_diameter_deg",
        l.angular_diameter_deg.unwrap_or(0.0),
    )?;
    if !(0.0..=MAX_ANGULAR_DIAMETER_DEG).contains(&diameter) {
        c.report(
            loc,
            format!(
                "angular_diameter_deg = {diameter} must be from 0 to {MAX_ANGULAR_DIAMETER_DEG} (the sun's is 0.53)"
            ),
        );
        return None;
    }
    Some(LightKind::Directional {
        direction,
        angular_radius: (0.5 * diameter).to_radians(),
    })
}

/// The scene file's sky: finite radiances, each channel >= 0.
pub(super) fn check_sky(c: &mut Checker, raw: Option<&SkyJson>, lights: &[Light]) -> Option<Sky> {
    let raw = raw?;
    let zenith = c.vec3("sky", "zenith", &raw.zenith)?;
    let horizon = match &raw.horizon {
        Some(h) => c.vec3("sky", "horizon", h)?,
        None => zenith,
    };
    if zenith.min_element() < 0.0 || horizon.min_element() < 0.0 {
        c.report("sky", "radiance must be >= 0 per channel (W/(m² sr))");
        return None;
    }
    let albedo = match &raw.ground_albedo {
        Some(a) => c.vec3("sky", "ground_albedo", a)?,
        None => glam::Vec3::ZERO,
    };
    if albedo.min_element() < 0.0 || albedo.max_element() >= 1.0 {
        c.report(
            "sky",
            format!("ground_albedo {albedo:?} must be in [0, 1) per channel"),
        );
        return None;
    }
    Some(Sky::new(zenith, horizon).with_ground(albedo, lights))
}

fn spot(c: &mut Checker, loc: &str, l: &LightJson) -> Option<LightKind> {
    let direction = direction(c, loc, l)?;
    let inner = c.finite(loc, "inner_cone_deg", l.inner_cone_deg.unwrap_or(0.0))?;
    let outer = c.finite(loc, "outer_cone_deg", l.outer_cone_deg.unwrap_or(45.0))?;
    if !(0.0..90.0).contains(&inner) || inner >= outer || outer > 90.0 {
        c.report(
            loc,
            format!(
                "cones inner_cone_deg = {inner}, outer_cone_deg = {outer}: need 0 <= inner < outer <= 90"
            ),
        );
        return None;
    }
    Some(LightKind::Spot {
        direction,
        inner: inner.to_radians(),
        outer: outer.to_radians(),
    })
}

#[cfg(test)]
mod tests {
    use crate::{LightKind, Scene};

    /// A plate lit only by `lights` (JSON array items).
    fn scene(lights: &str) -> Result<Scene, String> {
        let text = format!(
            r#"{{ "name": "t", "lightmap": {{ "texel_density": 4 }},
                "materials": [{{ "name": "m", "albedo": [0.5, 0.5, 0.5] }}],
                "surfaces": [{{ "name": "floor", "material": "m",
                    "quad": {{ "origin": [0, 0, 0], "u": [0, 0, 1], "v": [1, 0, 0] }} }}],
                "lights": [{lights}] }}"#
        );
        Scene::parse(&text, "t.json").map_err(|e| e.to_string())
    }

    #[test]
    fn a_scene_lit_only_by_a_point_or_a_spot_light_loads() {
        let s = scene(
            r#"{ "name": "bulb", "type": "point", "position": [0.5, 1, 0.5], "color": [1, 0.5, 0.25], "intensity": 2 },
               { "name": "spot", "type": "spot", "position": [0.5, 2, 0.5], "direction": [0, -2, 0],
                 "intensity": 1, "inner_cone_deg": 10, "outer_cone_deg": 30, "range": 5 }"#,
        )
        .expect("loads");
        assert_eq!(s.lights.len(), 2);
        assert_eq!(s.lights[0].intensity, glam::Vec3::new(2.0, 1.0, 0.5));
        assert_eq!(s.lights[0].kind, LightKind::Point);
        let LightKind::Spot {
            direction,
            inner,
            outer,
        } = s.lights[1].kind
        else {
            panic!("a spot")
        };
        assert_eq!(direction, glam::Vec3::NEG_Y);
        assert!((inner - 10f32.to_radians()).abs() < 1e-6);
        assert!((outer - 30f32.to_radians()).abs() < 1e-6);
        assert_eq!(s.lights[1].range, Some(5.0));
    }

    #[test]
    fn a_sun_and_a_sky_load() {
        let text = r#"{ "name": "t", "lightmap": { "texel_density": 4 },
            "materials": [{ "name": "m", "albedo": [0.5, 0.5, 0.5] }],
            "surfaces": [{ "name": "floor", "material": "m",
                "quad": { "origin": [0, 0, 0], "u": [0, 0, 1], "v": [1, 0, 0] } }],
            "lights": [{ "name": "sun", "type": "directional", "direction": [1, -1, 0],
                         "intensity": 800, "angular_diameter_deg": 0.53 }],
            "sky": { "zenith": [0.1, 0.2, 0.4], "horizon": [0.3, 0.3, 0.3] } }"#;
        let s = Scene::parse(text, "t.json").expect("loads");
        let LightKind::Directional {
            direction,
            angular_radius,
        } = s.lights[0].kind
        else {
            panic!("directional")
        };
        assert!((direction - glam::Vec3::new(1.0, -1.0, 0.0).normalize()).length() < 1e-6);
        assert!((angular_radius - 0.265f32.to_radians()).abs() < 1e-7);
        let sky = s.sky.expect("a sky");
        assert_eq!(sky.horizon, glam::Vec3::splat(0.3));
        // A sky alone lights a scene.
        let sky_only = text.replace(
            r#""lights": [{ "name": "sun", "type": "directional", "direction": [1, -1, 0],
                         "intensity": 800, "angular_diameter_deg": 0.53 }],"#,
            "",
        );
        assert!(
            Scene::parse(&sky_only, "t.json")
                .expect("loads")
                .lights
                .is_empty()
        );
        let bad_sky = text.replace("[0.1, 0.2, 0.4]", "[0.1, -0.2, 0.4]");
        let err = Scene::parse(&bad_sky, "t.json")
            .expect_err("negative sky")
            .to_string();
        assert!(err.contains("sky: radiance must be >= 0"), "{err}");
        // The ground below the horizon: black unless stated, and an albedo
        // must be below 1.
        assert_eq!(sky.ground, glam::Vec3::ZERO);
        let grounded = text.replace(
            r#""horizon": [0.3, 0.3, 0.3] }"#,
            r#""horizon": [0.3, 0.3, 0.3], "ground_albedo": [0.2, 0.2, 0.2] }"#,
        );
        let g = Scene::parse(&grounded, "t.json")
            .expect("loads")
            .sky
            .expect("a sky");
        assert!(
            g.ground.x > 0.2 * 800.0 * 0.5f32.sqrt() / std::f32::consts::PI,
            "{g:?}"
        );
        let white = grounded.replace("[0.2, 0.2, 0.2]", "[1, 0.2, 0.2]");
        let err = Scene::parse(&white, "t.json")
            .expect_err("white ground")
            .to_string();
        assert!(
            err.contains("sky: ground_albedo") && err.contains("[0, 1)"),
            "{err}"
        );
    }

    #[test]
    fn bad_lights_are_reported_by_name_and_what_is_wrong() {
        for (light, says) in [
            (
                r#"{ "name": "a", "type": "point", "position": [0, 1, 0], "intensity": -1 }"#,
                "light #0 \"a\": intensity must be >= 0",
            ),
            (
                r#"{ "name": "a", "type": "lamp", "position": [0, 1, 0], "intensity": 1 }"#,
                "type \"lamp\" is not a light type",
            ),
            (
                r#"{ "name": "a", "type": "spot", "position": [0, 1, 0], "intensity": 1 }"#,
                "a spot light needs a direction",
            ),
            (
                r#"{ "name": "a", "type": "spot", "position": [0, 1, 0], "direction": [0, 0, 0], "intensity": 1 }"#,
                "has no length",
            ),
            (
                r#"{ "name": "a", "type": "spot", "position": [0, 1, 0], "direction": [0, -1, 0], "intensity": 1,
                     "inner_cone_deg": 40, "outer_cone_deg": 30 }"#,
                "need 0 <= inner < outer <= 90",
            ),
            (
                r#"{ "name": "a", "type": "point", "position": [0, 1, 0], "direction": [0, -1, 0], "intensity": 1 }"#,
                "direction is not for a point light",
            ),
            (
                r#"{ "name": "a", "type": "directional", "direction": [0, -1, 0], "position": [0, 1, 0], "intensity": 1 }"#,
                "a directional light has no position",
            ),
            (
                r#"{ "name": "a", "type": "directional", "intensity": 1 }"#,
                "a directional light needs a direction",
            ),
            (
                r#"{ "name": "a", "type": "directional", "direction": [0, -1, 0], "intensity": 1, "angular_diameter_deg": 30 }"#,
                "angular_diameter_deg = 30 must be from 0 to 20",
            ),
            (
                r#"{ "name": "a", "type": "directional", "direction": [0, -1, 0], "intensity": 1, "range": 3 }"#,
                "range is not for a directional light",
            ),
            (
                r#"{ "name": "a", "type": "point", "intensity": 1 }"#,
                "a point light needs a position",
            ),
            (
                r#"{ "name": "a", "type": "point", "position": [0, 1, 0], "intensity": 1, "range": 0 }"#,
                "range = 0 must be > 0",
            ),
            (
                r#"{ "name": "a", "type": "point", "position": [0, 1, 0], "intensity": 1, "color": [1, -1, 1] }"#,
                "color must be >= 0",
            ),
        ] {
            let err = scene(light).expect_err(light);
            assert!(err.contains(says), "{light}: {err}");
        }
        let twice = r#"{ "name": "a", "type": "point", "position": [0, 1, 0], "intensity": 1 },
                       { "name": "a", "type": "point", "position": [0, 2, 0], "intensity": 1 }"#;
        assert!(
            scene(twice)
                .expect_err("duplicate")
                .contains("duplicate name")
        );
    }

    #[test]
    fn a_scene_with_no_light_of_any_kind_is_refused_with_the_ways_to_add_one() {
        let dark = r#"{ "name": "a", "type": "point", "position": [0, 1, 0], "intensity": 0 }"#;
        let err = scene(dark).expect_err("dark");
        assert!(err.contains("has no light"), "{err}");
        assert!(
            err.contains("emission > 0")
                && err.contains("directional light")
                && err.contains("sky"),
            "{err}"
        );
    }

    /// A light with `"object"` rides with that dynamic object (placed with
    /// it by `Scene::lights_at`); one naming no dynamic object is refused
    /// with the object's name and the scene's dynamic objects.
    #[test]
    fn a_light_rides_with_the_dynamic_object_it_names() {
        let text = |object: &str| {
            format!(
                r#"{{ "name": "t", "lightmap": {{ "texel_density": 4 }},
                "materials": [{{ "name": "m", "albedo": [0.5, 0.5, 0.5] }}],
                "objects": [{{ "name": "cart", "pose": {{ "translation": [0, 0, 0] }} }}],
                "surfaces": [
                    {{ "name": "floor", "material": "m",
                       "quad": {{ "origin": [0, 0, 0], "u": [0, 0, 1], "v": [1, 0, 0] }} }},
                    {{ "name": "cart", "material": "m", "object": "cart",
                       "box": {{ "center": [0, 0.2, 0], "size": [0.2, 0.2, 0.2] }} }}],
                "lights": [{{ "name": "lamp", "type": "point", "position": [0, 0.5, 0],
                    "intensity": 1, "object": "{object}" }}] }}"#
            )
        };
        let scene = Scene::parse(&text("cart"), "t.json").unwrap_or_else(|e| panic!("{e}"));
        let cart = scene.object_by_name("cart").expect("cart");
        assert_eq!(scene.lights[0].object, cart);
        let mut poses = scene.initial_poses();
        poses[cart as usize].translation = glam::Vec3::new(1.0, 0.0, 2.0);
        let placed = scene.lights_at(&scene.lights, &poses);
        assert!((placed[0].position - glam::Vec3::new(1.0, 0.5, 2.0)).length() < 1e-6);
        let err = Scene::parse(&text("wagon"), "t.json")
            .expect_err("no such object")
            .to_string();
        assert!(
            err.contains("lamp") && err.contains("\"wagon\"") && err.contains("cart"),
            "{err}"
        );
    }
}
