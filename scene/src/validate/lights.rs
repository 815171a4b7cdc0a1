//! The scene file's `"lights"`: point and spot lights, checked.

use super::Checker;
use crate::file::LightJson;
use crate::light::{Light, LightKind};

/// Checks every light and returns the valid ones: a unique name, a type of
/// `point` or `spot`, a finite position, colour and intensity (>= 0), a
/// range > 0 if any; for a spot a direction of non-zero length and cones
/// with `0 <= inner < outer <= 90` degrees (and no spot keys on a point).
pub(super) fn check_lights(c: &mut Checker, raw: &[LightJson]) -> Vec<Light> {
    c.unique("light", raw.iter().map(|l| l.name.as_str()));
    let mut out = Vec::new();
    for (i, l) in raw.iter().enumerate() {
        let loc = format!("light #{i} \"{}\"", l.name);
        let position = c.vec3(&loc, "position", &l.position);
        let color = c.vec3(&loc, "color", &l.color);
        if color.is_some_and(|v| v.min_element() < 0.0) {
            c.report(&loc, "color must be >= 0 per channel");
        }
        let intensity = c.finite(&loc, "intensity", l.intensity);
        if intensity.is_some_and(|v| v < 0.0) {
            c.report(&loc, "intensity must be >= 0 (W/sr)");
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
        let kind = match l.kind.as_str() {
            "point" => {
                for (key, given) in [
                    ("direction", l.direction.is_some()),
                    ("inner_cone_deg", l.inner_cone_deg.is_some()),
                    ("outer_cone_deg", l.outer_cone_deg.is_some()),
                ] {
                    if given {
                        c.report(
                            &loc,
                            format!("{key} is for a spot light; a point light has none"),
                        );
                    }
                }
                Some(LightKind::Point)
            }
            "spot" => spot(c, &loc, l),
            other => {
                c.report(
                    &loc,
                    format!("type \"{other}\" is not a light type: \"point\" or \"spot\""),
                );
                None
            }
        };
        if let (Some(position), Some(color), Some(intensity), Some(range), Some(kind)) =
            (position, color, intensity, range, kind)
        {
            out.push(Light {
                name: l.name.clone(),
                kind,
                position,
                intensity: color * intensity,
                range,
            });
        }
    }
    out
}

fn spot(c: &mut Checker, loc: &str, l: &LightJson) -> Option<LightKind> {
    let Some(direction) = &l.direction else {
        c.report(loc, "a spot light needs a direction");
        return None;
    };
    let direction = c.vec3(loc, "direction", direction)?;
    if direction.length() <= 1e-6 {
        c.report(loc, format!("direction {direction} has no length"));
        return None;
    }
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
        direction: direction.normalize(),
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
                "direction is for a spot light",
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
            err.contains("emission > 0") && err.contains("point or spot light"),
            "{err}"
        );
    }
}
