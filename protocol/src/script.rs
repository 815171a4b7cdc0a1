//! Transform scripts: keyframed poses and light states over time, for
//! `drive` and `load`.
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
//! # Light keys
//!
//! Besides (or instead of) an object's `keyframes`, a script may carry
//! keys for the scene's lights (PROTOCOL.md §1.7, `SetLight`), one track
//! per light name under `lights`:
//!
//! ```json
//! {
//!   "loop": true,
//!   "lights": {
//!     "sun": [
//!       { "t": 0, "direction": [-0.8, -0.1, -0.58], "intensity": 150, "color": [1, 0.6, 0.35], "on": true },
//!       { "t": 6, "direction": [0.25, -0.6, -0.76], "intensity": 800, "color": [1, 0.95, 0.85] },
//!       { "t": 12, "on": false, "interpolation": "step" }
//!     ]
//!   }
//! }
//! ```
//!
//! - A key's fields are those of a `LightState`: `on`, `color` (linear
//!   RGB, each channel in [0, 1]), `intensity` (W/sr, or W/m² for a
//!   directional light), `position` (metres, world space) and `direction`
//!   (normalised on load; it must not be zero). Each is checked as
//!   [`LightState::validate`] checks it.
//! - Each may be left out and is then carried over from the previous key
//!   of the same light; a field that no key so far gave is the light's
//!   state when the script starts (what the server's first `Lights` says;
//!   [`Script::light_at`] takes it as `base`). So a script gives only
//!   what it changes: a switch script needs no position, a sun's no
//!   colour.
//! - `t` and `interpolation` as for keyframes. **linear**: colour,
//!   intensity and position interpolate linearly, the direction by slerp
//!   along the shorter arc (so two consecutive directions must not be
//!   opposite: turn by less than 180° per segment); `on` switches at the
//!   key's `t` (dim with `intensity` to fade). **step**: the previous
//!   state holds until `t`, then jumps.
//! - `loop` covers the whole script: its period is the latest `t` of
//!   any keyframe or light key ([`Script::duration`]); a track that ends
//!   earlier holds its last state until the period starts over.
//! - A script needs `keyframes`, `lights`, or both; `object` names the
//!   object of `keyframes`, so a script without them names none. Light
//!   names are checked against a scene with [`Script::light_indices`].
//!
//! Bad scripts are refused with the file and the place: JSON syntax as
//! `file:line:column`, values as `file: keyframes[3].scale: ...` or
//! `file: lights.sun[2].intensity: ...`.

use std::collections::BTreeMap;
use std::path::Path;

use crate::{LightState, Pose, SceneInfo};
use glam::{Quat, Vec3};
use serde::Deserialize;

/// Why a script was refused: the file and where in it.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{origin}{location}: {reason}")]
pub struct ScriptError {
    /// The file name (or the origin given to [`Script::parse`]).
    pub origin: String,
    /// `:line:column` for syntax, `: keyframes[i].field` or
    /// `: lights.name[i].field` for values.
    pub location: String,
    /// What is wrong.
    pub reason: String,
}

/// How the pose (or a light's state) reaches a key from the previous one.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Interpolation {
    /// Lerp translation and scale, slerp rotation (a light: lerp colour,
    /// intensity and position, slerp the direction, switch `on` at the
    /// key's time).
    #[default]
    Linear,
    /// Hold the previous pose (state), jump at this key's time.
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
    #[serde(default)]
    keyframes: Option<Vec<KeyframeFile>>,
    #[serde(default)]
    lights: Option<BTreeMap<String, Vec<LightKeyFile>>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct LightKeyFile {
    t: f64,
    #[serde(default)]
    on: Option<bool>,
    #[serde(default)]
    color: Option<[f32; 3]>,
    #[serde(default)]
    intensity: Option<f32>,
    #[serde(default)]
    position: Option<[f32; 3]>,
    #[serde(default)]
    direction: Option<[f32; 3]>,
    #[serde(default)]
    interpolation: Interpolation,
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

/// One key of a light's track, with the fields carried over from the
/// keys before it; `None`: no key so far gave the field, so it is the
/// light's state when the script starts (the `base` of
/// [`Script::light_at`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LightKey {
    /// Seconds from the start.
    pub t: f64,
    /// Whether the light gives light.
    pub on: Option<bool>,
    /// Linear RGB, each channel in [0, 1].
    pub color: Option<[f32; 3]>,
    /// W/sr (point, spot) or W/m² (directional), in [0, 1e6].
    pub intensity: Option<f32>,
    /// World space, metres.
    pub position: Option<[f32; 3]>,
    /// Unit vector.
    pub direction: Option<Vec3>,
    /// How the state gets here from the previous key.
    pub interpolation: Interpolation,
}

impl LightKey {
    /// The complete state: this key's fields, `base`'s where it has none.
    pub fn resolve(&self, base: &LightState) -> LightState {
        LightState {
            on: self.on.unwrap_or(base.on),
            color: self.color.unwrap_or(base.color),
            intensity: self.intensity.unwrap_or(base.intensity),
            position: self.position.unwrap_or(base.position),
            direction: self.direction.map_or(base.direction, |d| d.to_array()),
        }
    }
}

/// The keys of one light, by its name in the scene.
#[derive(Clone, Debug, PartialEq)]
pub struct LightTrack {
    /// The light's name (`SceneInfo::lights[i].name`).
    pub name: String,
    keys: Vec<LightKey>,
}

impl LightTrack {
    /// The keys, in time order, with their fields carried over.
    pub fn keys(&self) -> &[LightKey] {
        &self.keys
    }

    /// The last key's time.
    pub fn duration(&self) -> f64 {
        self.keys.last().map_or(0.0, |k| k.t)
    }

    /// The state at script time `t` (already wrapped by a loop), fields
    /// no key gave taken from `base`. Before the first key its state holds.
    fn state_at(&self, t: f64, base: &LightState) -> LightState {
        let i = self.keys.partition_point(|k| k.t <= t);
        let Some(first) = self.keys.first() else {
            return *base;
        };
        if i == 0 {
            return first.resolve(base);
        }
        let a = &self.keys[i - 1];
        let Some(b) = self.keys.get(i) else {
            return a.resolve(base);
        };
        let (from, to) = (a.resolve(base), b.resolve(base));
        match b.interpolation {
            Interpolation::Step => from,
            Interpolation::Linear => {
                let u = ((t - a.t) / (b.t - a.t)).clamp(0.0, 1.0) as f32;
                let mix3 = |x: [f32; 3], y: [f32; 3]| [0, 1, 2].map(|c| mix(x[c], y[c], u));
                LightState {
                    // Switches at the key's time, like a step.
                    on: from.on,
                    color: mix3(from.color, to.color),
                    intensity: mix(from.intensity, to.intensity, u),
                    position: mix3(from.position, to.position),
                    direction: turn(from.direction, to.direction, u),
                }
            }
        }
    }
}

/// `a` to `b` by `u` in [0, 1], never outside [a, b] (so a colour or an
/// intensity between two valid ones stays valid despite rounding).
fn mix(a: f32, b: f32, u: f32) -> f32 {
    (a + (b - a) * u).clamp(a.min(b), a.max(b))
}

/// Unit direction `a` turned towards `b` by `u` of the angle between them
/// (slerp along the shorter arc), normalised. A zero or non-finite input
/// (a base that carries none: a point light's) is taken as it is.
fn turn(a: [f32; 3], b: [f32; 3], u: f32) -> [f32; 3] {
    let (a, b) = (Vec3::from_array(a), Vec3::from_array(b));
    match (a.try_normalize(), b.try_normalize()) {
        (Some(a), Some(b)) => a.slerp(b, u).try_normalize().unwrap_or(a).to_array(),
        _ if u < 1.0 => a.to_array(),
        _ => b.to_array(),
    }
}

/// A validated script; sample it with [`Script::pose_at`] and
/// [`Script::light_at`].
#[derive(Clone, Debug, PartialEq)]
pub struct Script {
    /// The object it drives, if the file names one.
    pub object: Option<String>,
    /// Whether it repeats.
    pub looping: bool,
    keys: Vec<Key>,
    lights: Vec<LightTrack>,
    /// The file (or the origin given to [`Script::parse`]), for errors.
    origin: String,
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
        if file.lights.as_ref().is_some_and(BTreeMap::is_empty) {
            return Err(fail(
                "lights".into(),
                "names no light; give at least one light's keys, or leave it out".into(),
            ));
        }
        let keyframes = match (file.keyframes, &file.lights) {
            (Some(k), _) if k.is_empty() => {
                return Err(fail(
                    "keyframes".into(),
                    "needs at least one keyframe".into(),
                ));
            }
            (Some(k), _) => k,
            (None, Some(_)) => Vec::new(),
            (None, None) => {
                return Err(fail(
                    "keyframes".into(),
                    "a script needs keyframes (an object's poses), lights (light keys), or both"
                        .into(),
                ));
            }
        };
        if let Some(name) = &file.object {
            if name.trim().is_empty() {
                return Err(fail("object".into(), "is empty".into()));
            }
            if keyframes.is_empty() {
                return Err(fail(
                    "object".into(),
                    format!("names {name:?}, but the script has no keyframes to move it along"),
                ));
            }
        }
        let mut keys: Vec<Key> = Vec::with_capacity(keyframes.len());
        for (i, k) in keyframes.iter().enumerate() {
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
        let mut lights = Vec::new();
        for (name, track) in file.lights.unwrap_or_default() {
            lights.push(light_track(name, &track, &fail)?);
        }
        let script = Script {
            object: file.object,
            looping: file.looping,
            keys,
            lights,
            origin: origin.to_string(),
        };
        let all_keys =
            script.keys.len() + script.lights.iter().map(|l| l.keys.len()).sum::<usize>();
        if script.looping && all_keys > 1 && script.duration() <= 0.0 {
            return Err(fail(
                "loop".into(),
                "a looping script needs a last keyframe after t = 0".into(),
            ));
        }
        Ok(script)
    }

    /// The keyframes, complete (empty for a script of light keys only).
    pub fn keys(&self) -> &[Key] {
        &self.keys
    }

    /// Whether the script moves an object (has `keyframes`).
    pub fn has_poses(&self) -> bool {
        !self.keys.is_empty()
    }

    /// The light tracks, by light name in alphabetical order (empty for a
    /// script without `lights`).
    pub fn lights(&self) -> &[LightTrack] {
        &self.lights
    }

    /// The latest key's time, of the keyframes and every light's keys:
    /// the loop period, or when a non-looping script is finished.
    pub fn duration(&self) -> f64 {
        self.lights
            .iter()
            .map(LightTrack::duration)
            .fold(self.keys.last().map_or(0.0, |k| k.t), f64::max)
    }

    /// Whether a non-looping script has played out at time `t`.
    pub fn is_finished(&self, t: f64) -> bool {
        !self.looping && t >= self.duration()
    }

    /// `t` seconds from the start as a time in the script: wrapped into
    /// the period if it loops.
    fn script_time(&self, t: f64) -> f64 {
        let duration = self.duration();
        if self.looping && duration > 0.0 {
            t.rem_euclid(duration)
        } else {
            t
        }
    }

    /// The pose at `t` seconds from the start (see the module docs for
    /// the interpolation). Before the first keyframe its pose holds. A
    /// script without keyframes ([`Script::has_poses`]) moves nothing:
    /// its pose is the identity, which callers should not send.
    pub fn pose_at(&self, t: f64) -> Pose {
        let t = self.script_time(t);
        let i = self.keys.partition_point(|k| k.t <= t);
        let key = |k: &Key| to_pose(k.translation, k.rotation, k.scale);
        let Some(first) = self.keys.first() else {
            return Pose::IDENTITY;
        };
        if i == 0 {
            return key(first);
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
    /// The state of light track `track` ([`Script::lights`]) at `t`
    /// seconds from the start, the fields no key gave taken from `base`
    /// (the light's state when the script started); see the module docs
    /// for the interpolation. Valid ([`LightState::validate`]) whenever
    /// `base` is. A track index out of range gives `base`.
    pub fn light_at(&self, track: usize, t: f64, base: &LightState) -> LightState {
        match self.lights.get(track) {
            Some(l) => l.state_at(self.script_time(t), base),
            None => *base,
        }
    }

    /// The index in `scene.lights` of each light track's light, in the
    /// order of [`Script::lights`]; a name the scene does not have is
    /// refused with the scene's light names.
    pub fn light_indices(&self, scene: &SceneInfo) -> Result<Vec<u32>, ScriptError> {
        self.lights
            .iter()
            .map(|track| {
                scene
                    .lights
                    .iter()
                    .position(|l| l.name == track.name)
                    .map(|i| i as u32)
                    .ok_or_else(|| ScriptError {
                        origin: self.origin.clone(),
                        location: format!(": {}", light_path(&track.name)),
                        reason: format!(
                            "scene \"{}\" has no light {:?}; {}",
                            scene.id,
                            track.name,
                            light_names(scene)
                        ),
                    })
            })
            .collect()
    }

    /// Samples the script (100 Hz over one period, or its length) and says
    /// when the object's surfaces first leave the bounding box of the scene's
    /// static surfaces (the room), if they do.
    pub fn leaves_the_room(&self, scene: &SceneInfo, object: u32) -> Option<String> {
        if self.keys.is_empty() {
            return None;
        }
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

/// "its lights: a, b" or "it has no lights", for errors about a light
/// name.
pub fn light_names(scene: &SceneInfo) -> String {
    if scene.lights.is_empty() {
        "it has no lights".into()
    } else {
        let names: Vec<String> = scene
            .lights
            .iter()
            .map(|l| format!("{:?}", l.name))
            .collect();
        format!("its lights: {}", names.join(", "))
    }
}

/// `lights.sun`, or `lights["a lamp"]` for a name that is not a plain
/// word.
fn light_path(name: &str) -> String {
    let plain = !name.is_empty()
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-');
    if plain {
        format!("lights.{name}")
    } else {
        format!("lights[{name:?}]")
    }
}

/// A state whose every field is valid, for checking a key's fields one
/// by one with [`LightState::validate`] (which checks each field on its
/// own).
const NEUTRAL: LightState = LightState {
    on: true,
    color: [1.0; 3],
    intensity: 1.0,
    position: [0.0; 3],
    direction: [0.0, -1.0, 0.0],
};

/// Validates one light's keys (carrying fields over) into a track.
fn light_track(
    name: String,
    track: &[LightKeyFile],
    fail: &dyn Fn(String, String) -> ScriptError,
) -> Result<LightTrack, ScriptError> {
    let path = light_path(&name);
    if name.trim().is_empty() {
        return Err(fail(path, "a light's name is empty".into()));
    }
    if track.is_empty() {
        return Err(fail(path, "needs at least one key".into()));
    }
    let mut keys: Vec<LightKey> = Vec::with_capacity(track.len());
    for (i, k) in track.iter().enumerate() {
        let at = |field: &str| format!("{path}[{i}].{field}");
        if !k.t.is_finite() || k.t < 0.0 {
            return Err(fail(
                at("t"),
                format!("{} must be a finite time >= 0 s", k.t),
            ));
        }
        let previous = keys.last().copied();
        if let Some(p) = previous {
            if k.t <= p.t {
                return Err(fail(
                    at("t"),
                    format!(
                        "{} s is not after {path}[{}].t = {} s; times must increase",
                        k.t,
                        i - 1,
                        p.t
                    ),
                ));
            }
        }
        let direction = match k.direction {
            None => None,
            Some(d) => {
                let v = Vec3::from_array(d);
                if !v.is_finite() {
                    return Err(fail(at("direction"), format!("{d:?} is not finite")));
                }
                match v.try_normalize() {
                    Some(unit) if v.length() >= 1e-6 => Some(unit),
                    _ => return Err(fail(at("direction"), format!("{d:?} must not be zero"))),
                }
            }
        };
        // Each given field as `LightState::validate` checks it (on a state
        // whose other fields are valid, so a failure is this field's).
        let given = LightState {
            on: k.on.unwrap_or(NEUTRAL.on),
            color: k.color.unwrap_or(NEUTRAL.color),
            intensity: k.intensity.unwrap_or(NEUTRAL.intensity),
            position: k.position.unwrap_or(NEUTRAL.position),
            direction: direction.map_or(NEUTRAL.direction, |d| d.to_array()),
        };
        if let Err(reason) = given.validate() {
            let field = ["color", "intensity", "position", "direction"]
                .into_iter()
                .find(|f| reason.starts_with(f))
                .unwrap_or("state");
            let value = match field {
                "color" => format!("{:?}", given.color),
                "intensity" => format!("{}", given.intensity),
                "position" => format!("{:?}", given.position),
                _ => format!("{:?}", given.direction),
            };
            let why = reason.strip_prefix(field).unwrap_or(reason).trim_start();
            return Err(fail(at(field), format!("{value} {why}")));
        }
        let key = LightKey {
            t: k.t,
            on: k.on.or(previous.and_then(|p| p.on)),
            color: k.color.or(previous.and_then(|p| p.color)),
            intensity: k.intensity.or(previous.and_then(|p| p.intensity)),
            position: k.position.or(previous.and_then(|p| p.position)),
            direction: direction.or(previous.and_then(|p| p.direction)),
            interpolation: k.interpolation,
        };
        if let (Some(a), Some(b)) = (previous.and_then(|p| p.direction), direction) {
            // Slerp along the shorter arc is undefined between opposite
            // directions: the script must say which way to turn.
            if key.interpolation == Interpolation::Linear && a.dot(b) < -0.9999 {
                return Err(fail(
                    at("direction"),
                    format!(
                        "{:?} is opposite {path}[{}]'s direction {:?}; a linear segment turns by less than 180 degrees, so add a key in between",
                        b.to_array(),
                        i - 1,
                        a.to_array()
                    ),
                ));
            }
        }
        keys.push(key);
    }
    Ok(LightTrack { name, keys })
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

    fn base() -> LightState {
        LightState {
            on: true,
            color: [1.0; 3],
            intensity: 8.0,
            position: [2.78, 4.488, 2.796],
            direction: [0.0, -1.0, 0.0],
        }
    }

    #[test]
    fn light_keys_carry_fields_over_and_take_the_rest_from_the_base() {
        let s = parse(
            r#"{ "lights": { "bulb": [
                { "t": 0, "intensity": 100 },
                { "t": 2, "intensity": 300, "color": [1, 0.5, 0] },
                { "t": 3, "on": false, "interpolation": "step" },
                { "t": 4, "on": true }
            ] } }"#,
        )
        .expect("valid");
        assert!(!s.has_poses() && s.keys().is_empty());
        assert_eq!(
            s.pose_at(1.0),
            Pose::IDENTITY,
            "no keyframes: nothing to move"
        );
        assert_eq!(s.lights().len(), 1);
        assert_eq!(s.lights()[0].name, "bulb");
        assert_eq!(s.duration(), 4.0);
        let b = base();
        let at = |t: f64| s.light_at(0, t, &b);
        // Before and at the first key: its intensity, the rest the base's.
        assert_eq!(
            at(-1.0),
            LightState {
                intensity: 100.0,
                ..b
            }
        );
        assert_eq!(
            at(0.0),
            LightState {
                intensity: 100.0,
                ..b
            }
        );
        // Half way to the second key: intensity and colour lerp (the
        // colour from the base's, which no key before gave).
        let half = at(1.0);
        assert!((half.intensity - 200.0).abs() < 1e-3, "{half:?}");
        assert!(close(half.color, [1.0, 0.75, 0.5]), "{half:?}");
        assert_eq!(
            (half.on, half.position, half.direction),
            (true, b.position, b.direction)
        );
        // The third key carries the second's fields: a step holds until
        // its time, then switches off.
        assert_eq!(
            at(2.99),
            LightState {
                intensity: 300.0,
                color: [1.0, 0.5, 0.0],
                ..b
            }
        );
        assert_eq!(
            at(3.0),
            LightState {
                on: false,
                intensity: 300.0,
                color: [1.0, 0.5, 0.0],
                ..b
            }
        );
        // `on` switches at the key's time under linear interpolation too.
        assert!(!at(3.99).on && at(4.0).on);
        // Not looping: the last state holds.
        assert_eq!(at(100.0), at(4.0));
        assert!(s.is_finished(4.0));
        for k in 0..=50 {
            let state = at(f64::from(k) * 0.1);
            state
                .validate()
                .unwrap_or_else(|e| panic!("t = {}: {e}: {state:?}", f64::from(k) * 0.1));
        }
    }

    #[test]
    fn light_directions_slerp_at_constant_angular_speed_and_stay_unit() {
        let s = parse(
            r#"{ "lights": { "sun": [
                { "t": 0, "direction": [2, 0, 0] },
                { "t": 3, "direction": [0, 0, -1] }
            ] } }"#,
        )
        .expect("valid");
        let b = base();
        // Normalised on load.
        assert_eq!(s.lights()[0].keys()[0].direction, Some(Vec3::X));
        for (t, degrees) in [
            (0.0, 0.0f32),
            (1.0, 30.0),
            (1.5, 45.0),
            (2.0, 60.0),
            (3.0, 90.0),
        ] {
            let d = Vec3::from_array(s.light_at(0, t, &b).direction);
            let expected = Vec3::new(degrees.to_radians().cos(), 0.0, -degrees.to_radians().sin());
            assert!(
                d.dot(expected) > 1.0 - 1e-5,
                "t = {t}: {d} is not {degrees} degrees round"
            );
            assert!((d.length() - 1.0).abs() < 1e-5);
        }
    }

    #[test]
    fn a_loop_spans_every_track_and_a_shorter_track_holds_its_last_state() {
        let s = parse(
            r#"{ "loop": true,
                "keyframes": [ { "t": 0, "translation": [0, 0, 0] }, { "t": 4, "translation": [4, 0, 0] } ],
                "lights": { "lamp": [ { "t": 0, "intensity": 0 }, { "t": 2, "intensity": 2 } ],
                            "sun": [ { "t": 1, "intensity": 10 }, { "t": 6, "intensity": 60 } ] } }"#,
        )
        .expect("valid");
        assert_eq!(s.duration(), 6.0, "the latest key of any track");
        let names: Vec<&str> = s.lights().iter().map(|l| l.name.as_str()).collect();
        assert_eq!(names, ["lamp", "sun"]);
        let b = base();
        assert!((s.light_at(0, 1.0, &b).intensity - 1.0).abs() < 1e-5);
        assert_eq!(
            s.light_at(0, 5.0, &b).intensity,
            2.0,
            "held after its last key"
        );
        assert!((s.light_at(1, 3.5, &b).intensity - 35.0).abs() < 1e-3);
        // The period is 6 s: t = 7 is t = 1 again, for poses and lights.
        assert!((s.light_at(0, 7.0, &b).intensity - 1.0).abs() < 1e-5);
        assert!(close(s.pose_at(7.0).translation, [1.0, 0.0, 0.0]));
        assert!(close(s.pose_at(5.0).translation, [4.0, 0.0, 0.0]));
        assert_eq!(s.light_at(9, 1.0, &b), b, "no such track: the base");
    }

    #[test]
    fn light_names_are_checked_against_the_scene() {
        use crate::{LightInfo, LightType, PixelFormat};
        let s = parse(r#"{ "lights": { "bulb": [ { "t": 0, "on": false } ], "sun": [ { "t": 0, "on": true } ] } }"#)
            .expect("valid");
        let mut scene = SceneInfo {
            id: "room".into(),
            atlas_width: 1,
            atlas_height: 1,
            tile_size: 8,
            format: PixelFormat::Rgb9e5,
            objects: vec![],
            materials: vec![],
            surfaces: vec![],
            lights: vec![],
        };
        let err = s.light_indices(&scene).expect_err("no lights").to_string();
        assert_eq!(
            err,
            "test.json: lights.bulb: scene \"room\" has no light \"bulb\"; it has no lights"
        );
        for name in ["sun", "bulb"] {
            scene.lights.push(LightInfo {
                name: name.into(),
                kind: LightType::Point,
                range: None,
                cone: [0.0; 2],
                angular_radius: 0.0,
                state: base(),
            });
        }
        assert_eq!(s.light_indices(&scene), Ok(vec![1, 0]));
        scene.lights.remove(0);
        let err = s.light_indices(&scene).expect_err("no sun").to_string();
        assert!(
            err.contains("lights.sun") && err.contains("its lights: \"bulb\""),
            "{err}"
        );
    }

    #[test]
    fn bad_light_keys_name_the_file_the_light_the_key_and_the_field() {
        let cases = [
            (
                r#"{ "lights": { "sun": [ { "t": 0 }, { "t": 1 }, { "t": 2, "intensity": -5 } ] } }"#,
                "test.json: lights.sun[2].intensity: -5 is out of range (0 to 1e6)",
            ),
            (
                r#"{ "lights": { "sun": [ { "t": 0, "color": [2, 1, 1] } ] } }"#,
                "test.json: lights.sun[0].color: [2.0, 1.0, 1.0] is out of range (each channel in [0, 1])",
            ),
            // Beyond f32: serde_json refuses it at its place (`1:50:
            // number out of range`) or reads infinity, which the key's
            // check refuses, depending on the features the workspace
            // enables; the file is named either way.
            (
                r#"{ "lights": { "sun": [ { "t": 0, "intensity": 1e39 } ] } }"#,
                "test.json:",
            ),
            (
                r#"{ "lights": { "my lamp": [ { "t": 0, "position": [0, 2e5, 0] } ] } }"#,
                "test.json: lights[\"my lamp\"][0].position: [0.0, 200000.0, 0.0] is out of range",
            ),
            (
                r#"{ "lights": { "sun": [ { "t": 0, "direction": [0, 0, 0] } ] } }"#,
                "test.json: lights.sun[0].direction: [0.0, 0.0, 0.0] must not be zero",
            ),
            (
                r#"{ "lights": { "sun": [ { "t": 0, "direction": [0, -1, 0] }, { "t": 1, "on": false }, { "t": 2, "direction": [0, 1, 0] } ] } }"#,
                "test.json: lights.sun[2].direction: [0.0, 1.0, 0.0] is opposite lights.sun[1]'s direction",
            ),
            (
                r#"{ "lights": { "sun": [ { "t": 1 }, { "t": 1 } ] } }"#,
                "test.json: lights.sun[1].t: 1 s is not after lights.sun[0].t = 1 s",
            ),
            (
                r#"{ "lights": { "sun": [ { "t": -2 } ] } }"#,
                "test.json: lights.sun[0].t: -2 must be a finite time >= 0 s",
            ),
            (
                r#"{ "lights": { "sun": [] } }"#,
                "test.json: lights.sun: needs at least one key",
            ),
            (
                r#"{ "lights": { "": [ { "t": 0 } ] } }"#,
                "test.json: lights[\"\"]: a light's name is empty",
            ),
            (
                r#"{ "lights": { "sun": [ { "t": 0, "brightness": 2 } ] } }"#,
                "test.json:1:",
            ),
            (
                r#"{ "lights": { "sun": [ { "t": 0, "on": 1 } ] } }"#,
                "test.json:1:",
            ),
            (
                r#"{ "object": "box", "lights": { "sun": [ { "t": 0 } ] } }"#,
                "test.json: object: names \"box\", but the script has no keyframes",
            ),
            (
                r#"{ "loop": true }"#,
                "test.json: keyframes: a script needs keyframes",
            ),
            (r#"{ "lights": {} }"#, "test.json: lights: names no light"),
        ];
        for (text, expected) in cases {
            let err = parse(text).expect_err(text).to_string();
            assert!(
                err.starts_with(expected),
                "{text}\n  -> {err}\n  expected {expected}"
            );
        }
        // Opposite directions are fine as a step (no turn to choose).
        parse(
            r#"{ "lights": { "sun": [ { "t": 0, "direction": [0, -1, 0] }, { "t": 1, "direction": [0, 1, 0], "interpolation": "step" } ] } }"#,
        )
        .expect("a step may flip");
    }
}
