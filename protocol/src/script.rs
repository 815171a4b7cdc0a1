//! Transform scripts: keyframed poses over time, for `drive` and `load`.
//!
//! A script is a JSON file (examples and a walkthrough in
//! `scenes/scripts/README.md`):
//!
//! ```json
//! {
//!   "description": "the box circles the room's centre",
//!   "object": "box",
//!   "loop": true,
//!   "keyframes": [
//!     { "t": 0, "translation": [2.78, 0.85, 2.796], "rotation": { "axis": [0, 1, 0], "degrees": 0 }, "scale": 1 },
//!     { "t": 2, "translation": [3.6, 0.85, 2.796], "rotation": { "axis": [0, 1, 0], "degrees": 90 } },
//!     { "t": 2.5, "translation": [1.5, 0.85, 1.5], "interpolation": "step" }
//!   ]
//! }
//! ```
//!
//! - `t`: seconds from the start, strictly increasing.
//! - `translation` (metres, world space), `rotation` and `scale` (> 0):
//!   each may be left out and is then carried over from the previous
//!   keyframe; the first keyframe needs a `translation` (rotation defaults
//!   to identity, scale to 1).
//! - `rotation`: `{ "axis": [x, y, z], "degrees": a }` or a quaternion
//!   `[x, y, z, w]` (normalised on load; it must not be zero).
//! - `interpolation` says how the pose gets *to* this keyframe from the
//!   previous one: `"linear"` (default: translation and scale interpolate
//!   linearly, rotation by slerp along the shorter arc, so one segment
//!   turns less than 180°: split a full turn into three or more
//!   keyframes) or `"step"` (hold the previous pose, jump at `t`).
//! - `loop`: when true the script repeats with period = the last
//!   keyframe's `t` (make the last pose equal the first for a seamless
//!   loop); otherwise the last pose holds and the script is finished.
//! - `object`: the object's name (optional; `--object` overrides it).
//!
//! Bad scripts are refused with the file and the place: JSON syntax as
//! `file:line:column`, values as `file: keyframes[3].scale: ...`.

use std::path::Path;

use crate::{Pose, SceneInfo};
use glam::{Quat, Vec3};
use serde::Deserialize;

/// Why a script was refused: the file and where in it.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{origin}{location}: {reason}")]
pub struct ScriptError {
    /// The file name (or the origin given to [`Script::parse`]).
    pub origin: String,
    /// `:line:column` for syntax, `: keyframes[i].field` for values.
    pub location: String,
    /// What is wrong.
    pub reason: String,
}

/// How the pose reaches a keyframe from the previous one.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Interpolation {
    /// Lerp translation and scale, slerp rotation.
    #[default]
    Linear,
    /// Hold the previous pose, jump at this keyframe's time.
    Step,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ScriptFile {
    #[serde(default)]
    #[allow(dead_code)] // documentation for humans
    description: Option<String>,
    #[serde(default)]
    object: Option<String>,
    #[serde(default, rename = "loop")]
    looping: bool,
    keyframes: Vec<KeyframeFile>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct KeyframeFile {
    t: f64,
    #[serde(default)]
    translation: Option<[f32; 3]>,
    #[serde(default)]
    rotation: Option<RotationFile>,
    #[serde(default)]
    scale: Option<f32>,
    #[serde(default)]
    interpolation: Interpolation,
}

#[derive(Deserialize)]
#[serde(untagged)]
enum RotationFile {
    Quaternion([f32; 4]),
    AxisAngle { axis: [f32; 3], degrees: f32 },
}

/// One keyframe, complete (carried-over fields filled in).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Key {
    /// Seconds from the start.
    pub t: f64,
    /// World-space translation.
    pub translation: Vec3,
    /// Unit rotation.
    pub rotation: Quat,
    /// Uniform scale (> 0).
    pub scale: f32,
    /// How the pose gets here from the previous key.
    pub interpolation: Interpolation,
}

/// A validated script; sample it with [`Script::pose_at`].
#[derive(Clone, Debug, PartialEq)]
pub struct Script {
    /// The object it drives, if the file names one.
    pub object: Option<String>,
    /// Whether it repeats.
    pub looping: bool,
    keys: Vec<Key>,
}

impl Script {
    /// Reads and validates a script file.
    pub fn load(path: &Path) -> Result<Script, ScriptError> {
        let origin = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| ScriptError {
            origin: origin.clone(),
            location: String::new(),
            reason: format!("cannot read the script: {e}"),
        })?;
        Script::parse(&text, &origin)
    }

    /// Validates a script's text; `origin` names it in errors.
    pub fn parse(text: &str, origin: &str) -> Result<Script, ScriptError> {
        let file: ScriptFile = serde_json::from_str(text).map_err(|e| ScriptError {
            origin: origin.to_string(),
            location: format!(":{}:{}", e.line(), e.column()),
            reason: e
                .to_string()
                .split(" at line ")
                .next()
                .unwrap_or_default()
                .to_string(),
        })?;
        let fail = |location: String, reason: String| ScriptError {
            origin: origin.to_string(),
            location: format!(": {location}"),
            reason,
        };
        if file.keyframes.is_empty() {
            return Err(fail(
                "keyframes".into(),
                "needs at least one keyframe".into(),
            ));
        }
        if let Some(name) = &file.object {
            if name.trim().is_empty() {
                return Err(fail("object".into(), "is empty".into()));
            }
        }
        let mut keys: Vec<Key> = Vec::with_capacity(file.keyframes.len());
        for (i, k) in file.keyframes.iter().enumerate() {
            let at = |field: &str| format!("keyframes[{i}].{field}");
            if !k.t.is_finite() || k.t < 0.0 {
                return Err(fail(
                    at("t"),
                    format!("{} must be a finite time >= 0 s", k.t),
                ));
            }
            let previous = keys.last();
            if let Some(p) = previous {
                if k.t <= p.t {
                    return Err(fail(
                        at("t"),
                        format!(
                            "{} s is not after keyframes[{}].t = {} s; times must increase",
                            k.t,
                            i - 1,
                            p.t
                        ),
                    ));
                }
            }
            let translation = match (k.translation, previous) {
                (Some(t), _) => {
                    if !t.iter().all(|v| v.is_finite()) {
                        return Err(fail(at("translation"), format!("{t:?} is not finite")));
                    }
                    Vec3::from_array(t)
                }
                (None, Some(p)) => p.translation,
                (None, None) => {
                    return Err(fail(
                        at("translation"),
                        "the first keyframe needs a translation".into(),
                    ));
                }
            };
            let rotation = match (&k.rotation, previous) {
                (Some(RotationFile::Quaternion(q)), _) => {
                    let q = Quat::from_array(*q);
                    if !q.is_finite() || q.length() < 1e-6 {
                        return Err(fail(
                            at("rotation"),
                            format!("quaternion {q} must be finite and not zero"),
                        ));
                    }
                    q.normalize()
                }
                (Some(RotationFile::AxisAngle { axis, degrees }), _) => {
                    let axis = Vec3::from_array(*axis);
                    if !axis.is_finite() || axis.length() < 1e-6 {
                        return Err(fail(
                            at("rotation.axis"),
                            format!("{axis} must be finite and not zero"),
                        ));
                    }
                    if !degrees.is_finite() {
                        return Err(fail(
                            at("rotation.degrees"),
                            format!("{degrees} is not finite"),
                        ));
                    }
                    Quat::from_axis_angle(axis.normalize(), degrees.to_radians())
                }
                (None, Some(p)) => p.rotation,
                (None, None) => Quat::IDENTITY,
            };
            let scale = match (k.scale, previous) {
                (Some(s), _) if !(s.is_finite() && s > 0.0) => {
                    return Err(fail(at("scale"), format!("{s} must be finite and > 0")));
                }
                (Some(s), _) => s,
                (None, Some(p)) => p.scale,
                (None, None) => 1.0,
            };
            keys.push(Key {
                t: k.t,
                translation,
                rotation,
                scale,
                interpolation: k.interpolation,
            });
        }
        let duration = keys.last().map_or(0.0, |k| k.t);
        if file.looping && keys.len() > 1 && duration <= 0.0 {
            return Err(fail(
                "loop".into(),
                "a looping script needs a last keyframe after t = 0".into(),
            ));
        }
        Ok(Script {
            object: file.object,
            looping: file.looping,
            keys,
        })
    }

    /// The keyframes, complete.
    pub fn keys(&self) -> &[Key] {
        &self.keys
    }

    /// The last keyframe's time: the loop period, or when a non-looping
    /// script is finished.
    pub fn duration(&self) -> f64 {
        self.keys.last().map_or(0.0, |k| k.t)
    }

    /// Whether a non-looping script has played out at time `t`.
    pub fn is_finished(&self, t: f64) -> bool {
        !self.looping && t >= self.duration()
    }

    /// The pose at `t` seconds from the start (see the module docs for
    /// the interpolation). Before the first keyframe its pose holds.
    pub fn pose_at(&self, t: f64) -> Pose {
        let duration = self.duration();
        let t = if self.looping && duration > 0.0 {
            t.rem_euclid(duration)
        } else {
            t
        };
        let i = self.keys.partition_point(|k| k.t <= t);
        let key = |k: &Key| to_pose(k.translation, k.rotation, k.scale);
        if i == 0 {
            return key(&self.keys[0]);
        }
        let a = &self.keys[i - 1];
        let Some(b) = self.keys.get(i) else {
            return key(a);
        };
        match b.interpolation {
            Interpolation::Step => key(a),
            Interpolation::Linear => {
                let u = ((t - a.t) / (b.t - a.t)).clamp(0.0, 1.0) as f32;
                to_pose(
                    a.translation.lerp(b.translation, u),
                    a.rotation.slerp(b.rotation, u),
                    a.scale + (b.scale - a.scale) * u,
                )
            }
        }
    }
}

impl Script {
    /// Samples the script (100 Hz over one period, or its length) and says
    /// when the object's surfaces first leave the bounding box of the scene's
    /// static surfaces (the room), if they do.
    pub fn leaves_the_room(&self, scene: &SceneInfo, object: u32) -> Option<String> {
        let world = |pose: &Pose, p: [f32; 3]| {
            Vec3::from_array(pose.translation)
                + Quat::from_array(pose.rotation).normalize() * (pose.scale * Vec3::from_array(p))
        };
        let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        for s in &scene.surfaces {
            let Some(owner) = scene.objects.get(s.object as usize) else {
                continue;
            };
            if owner.dynamic {
                continue;
            }
            for c in s.corners {
                let p = world(&owner.pose, c);
                lo = lo.min(p);
                hi = hi.max(p);
            }
        }
        if !lo.is_finite() || !hi.is_finite() {
            return None;
        }
        let slack = 1e-3 * (hi - lo).length();
        let corners: Vec<[f32; 3]> = scene
            .surfaces
            .iter()
            .filter(|s| s.object == object)
            .flat_map(|s| s.corners)
            .collect();
        let steps = (self.duration() * 100.0).ceil().clamp(1.0, 100_000.0) as usize;
        for i in 0..=steps {
            let t = self.duration() * i as f64 / steps as f64;
            let pose = self.pose_at(t);
            for &c in &corners {
                let p = world(&pose, c);
                if p.cmplt(lo - slack).any() || p.cmpgt(hi + slack).any() {
                    return Some(format!(
                        "at t = {t:.2} s a corner of the object is at {p}, outside the room's bounds {lo} .. {hi}"
                    ));
                }
            }
        }
        None
    }
}

fn to_pose(translation: Vec3, rotation: Quat, scale: f32) -> Pose {
    Pose {
        translation: translation.to_array(),
        rotation: rotation.normalize().to_array(),
        scale,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<Script, ScriptError> {
        Script::parse(text, "test.json")
    }

    fn close(a: [f32; 3], b: [f32; 3]) -> bool {
        a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-5)
    }

    #[test]
    fn translation_and_scale_interpolate_linearly_and_fields_carry_over() {
        let s = parse(
            r#"{ "keyframes": [
                { "t": 0, "translation": [0, 0, 0], "scale": 1 },
                { "t": 2, "translation": [2, 4, 0], "scale": 3 },
                { "t": 3 }
            ] }"#,
        )
        .expect("valid");
        let p = s.pose_at(0.5);
        assert!(close(p.translation, [0.5, 1.0, 0.0]), "{p:?}");
        assert!((p.scale - 1.5).abs() < 1e-6);
        // The third keyframe carries the second's pose: it holds.
        assert!(close(s.pose_at(2.5).translation, [2.0, 4.0, 0.0]));
        assert_eq!(s.pose_at(2.5).scale, 3.0);
        // Not looping: before the start and after the end the ends hold.
        assert!(close(s.pose_at(-1.0).translation, [0.0; 3]));
        assert!(close(s.pose_at(10.0).translation, [2.0, 4.0, 0.0]));
        assert!(s.is_finished(3.0) && !s.is_finished(2.9));
    }

    #[test]
    fn rotation_slerps_at_constant_angular_speed_along_the_short_arc() {
        let s = parse(
            r#"{ "keyframes": [
                { "t": 0, "translation": [0, 0, 0], "rotation": { "axis": [0, 1, 0], "degrees": 0 } },
                { "t": 1, "rotation": { "axis": [0, 1, 0], "degrees": 120 } },
                { "t": 2, "rotation": [0, 1, 0, 0] }
            ] }"#,
        )
        .expect("valid");
        for (t, degrees) in [(0.25, 30.0f32), (0.5, 60.0), (1.5, 150.0)] {
            let q = Quat::from_array(s.pose_at(t).rotation);
            let expected = Quat::from_rotation_y(degrees.to_radians());
            assert!(
                q.dot(expected).abs() > 1.0 - 1e-5,
                "t = {t}: {q} is not {degrees} degrees about y"
            );
            let norm = q.length();
            assert!((norm - 1.0).abs() < 1e-5, "unit quaternion: {norm}");
            s.pose_at(t).validate().expect("the server accepts it");
        }
    }

    #[test]
    fn step_keyframes_jump_and_loops_wrap() {
        let s = parse(
            r#"{ "loop": true, "keyframes": [
                { "t": 0, "translation": [1, 0, 0] },
                { "t": 1, "translation": [2, 0, 0], "interpolation": "step" },
                { "t": 2, "translation": [1, 0, 0], "interpolation": "step" }
            ] }"#,
        )
        .expect("valid");
        assert!(close(s.pose_at(0.99).translation, [1.0, 0.0, 0.0]));
        assert!(close(s.pose_at(1.0).translation, [2.0, 0.0, 0.0]));
        assert!(close(s.pose_at(1.99).translation, [2.0, 0.0, 0.0]));
        // Period 2 s: t = 5.5 is t = 1.5 of the third loop.
        assert!(close(s.pose_at(5.5).translation, [2.0, 0.0, 0.0]));
        assert!(close(s.pose_at(4.2).translation, [1.0, 0.0, 0.0]));
        assert!(!s.is_finished(1e6), "a loop never finishes");
    }

    #[test]
    fn bad_scripts_name_the_file_and_the_place() {
        let cases = [
            (
                "{ \"keyframes\": [ { \"t\": 0, } ] }",
                "test.json:1:",
                "trailing comma",
            ),
            (
                r#"{ "keyframes": [] }"#,
                "test.json: keyframes",
                "at least one",
            ),
            (
                r#"{ "keyframes": [ { "t": 0 } ] }"#,
                "keyframes[0].translation",
                "needs a translation",
            ),
            (
                r#"{ "keyframes": [ { "t": 1, "translation": [0,0,0] }, { "t": 1 } ] }"#,
                "keyframes[1].t",
                "must increase",
            ),
            (
                r#"{ "keyframes": [ { "t": 0, "translation": [0,0,0], "scale": 0 } ] }"#,
                "keyframes[0].scale",
                "> 0",
            ),
            (
                r#"{ "keyframes": [ { "t": 0, "translation": [0,0,0], "rotation": [0,0,0,0] } ] }"#,
                "keyframes[0].rotation",
                "not zero",
            ),
            (
                r#"{ "keyframes": [ { "t": 0, "translation": [0,0,0], "rotation": { "axis": [0,0,0], "degrees": 5 } } ] }"#,
                "keyframes[0].rotation.axis",
                "not zero",
            ),
            (
                r#"{ "keyframes": [ { "t": -1, "translation": [0,0,0] } ] }"#,
                "keyframes[0].t",
                ">= 0",
            ),
            (
                r#"{ "keyframes": [ { "t": 0, "translation": [0,0,0], "speed": 2 } ] }"#,
                "test.json:1:",
                "unknown field `speed`",
            ),
            (
                r#"{ "keyframes": [ { "t": 0, "translation": [0,0,0], "interpolation": "cubic" } ] }"#,
                "test.json:1:",
                "unknown variant `cubic`",
            ),
            (
                r#"{ "loop": true, "keyframes": [ { "t": 0, "translation": [0,0,0] }, { "t": 0 } ] }"#,
                "keyframes[1].t",
                "must increase",
            ),
        ];
        for (text, location, reason) in cases {
            let err = parse(text).expect_err(text).to_string();
            assert!(
                err.contains(location),
                "{text}\n  -> {err}\n  lacks {location}"
            );
            assert!(err.contains(reason), "{text}\n  -> {err}\n  lacks {reason}");
        }
    }
}
