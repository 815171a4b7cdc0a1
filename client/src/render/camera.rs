//! The pinhole camera of `view`, how a user writes it, and the default
//! framing.
//!
//! A user writes a camera as `eye=x,y,z;target=x,y,z;up=x,y,z;fov=deg`
//! ([`CameraSpec`]); every key is optional. What is left out comes from the
//! default view, which looks at the centre of the scene's bounding box from
//! the +z side, slightly from above (the dashboard's start view: the Cornell
//! scenes are open towards +z), from just far enough that every corner of
//! the box is inside the frame ([`CameraSpec::resolve`]). The resolved
//! camera prints in the same syntax ([`Camera`]'s `Display`), so a printed
//! camera can be pasted back and tweaked.
//!
//! Conventions: world space is right-handed with y up (scenes/README.md);
//! `fov` is the vertical field of view in degrees. The projection is
//! reversed-Z with an infinite far plane (depth 1 at the near plane, 0 at
//! infinity), which keeps depth precise over the whole scene without a far
//! plane to choose.

use std::fmt;
use std::str::FromStr;

use glam::{Mat4, Vec3};

/// The vertical field of view when none is given, in degrees (the
/// dashboard's).
pub const DEFAULT_FOV_DEGREES: f32 = 45.0;
/// How far above the horizontal the default view looks down, in radians
/// (the dashboard's start pitch).
const DEFAULT_PITCH: f32 = 0.12;
/// The default framing fills this fraction of the frame's half-extent, so
/// the scene's outermost corners do not touch the image border.
const FRAME_FILL: f32 = 0.95;

/// A resolved pinhole camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Where the eye is (world space).
    pub eye: Vec3,
    /// The point at the centre of the image.
    pub target: Vec3,
    /// Which way is up in the image (need not be orthogonal to the view
    /// direction, only not parallel to it).
    pub up: Vec3,
    /// Vertical field of view, degrees, in (0, 180).
    pub fov_degrees: f32,
}

/// What is wrong with a camera, as the user wrote it.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CameraError {
    /// The `--camera` text does not parse.
    #[error(
        "camera \"{text}\": {why} (expected e.g. \"eye=2.78,2.7,12;target=2.78,2.7,0;fov=45\"; keys: eye, target, up, fov)"
    )]
    Syntax { text: String, why: String },
    /// The numbers parse but do not make a camera.
    #[error("camera: {0}")]
    Invalid(String),
}

/// A camera as given by the user: any key may be missing, see
/// [`CameraSpec::resolve`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CameraSpec {
    pub eye: Option<Vec3>,
    pub target: Option<Vec3>,
    pub up: Option<Vec3>,
    /// Vertical field of view in degrees.
    pub fov: Option<f32>,
}

/// Parses `x,y,z` (three finite numbers). The error says what was wrong.
pub fn parse_vec3(text: &str) -> Result<Vec3, String> {
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    if parts.len() != 3 {
        return Err(format!(
            "\"{text}\" has {} numbers, expected three: x,y,z",
            parts.len()
        ));
    }
    let mut v = [0.0f32; 3];
    for (slot, part) in v.iter_mut().zip(&parts) {
        *slot = part
            .parse::<f32>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| format!("\"{part}\" in \"{text}\" is not a finite number"))?;
    }
    Ok(Vec3::from_array(v))
}

impl FromStr for CameraSpec {
    type Err = CameraError;

    fn from_str(text: &str) -> Result<Self, CameraError> {
        let syntax = |why: String| CameraError::Syntax {
            text: text.to_string(),
            why,
        };
        let mut spec = CameraSpec::default();
        for item in text.split(';').map(str::trim).filter(|s| !s.is_empty()) {
            let (key, value) = item
                .split_once('=')
                .ok_or_else(|| syntax(format!("\"{item}\" is not key=value")))?;
            let (key, value) = (key.trim(), value.trim());
            let duplicate = || syntax(format!("\"{key}\" is given twice"));
            match key {
                "eye" | "target" | "up" => {
                    let v = parse_vec3(value).map_err(|why| syntax(format!("{key}: {why}")))?;
                    let slot = match key {
                        "eye" => &mut spec.eye,
                        "target" => &mut spec.target,
                        _ => &mut spec.up,
                    };
                    if slot.replace(v).is_some() {
                        return Err(duplicate());
                    }
                }
                "fov" => {
                    let fov = value
                        .parse::<f32>()
                        .map_err(|_| syntax(format!("fov: \"{value}\" is not a number")))?;
                    if spec.fov.replace(fov).is_some() {
                        return Err(duplicate());
                    }
                }
                _ => return Err(syntax(format!("unknown key \"{key}\""))),
            }
        }
        Ok(spec)
    }
}

impl CameraSpec {
    /// Fills the keys `other` has over those of `self` (flags such as
    /// `--eye` override the same key of `--camera`).
    pub fn overridden_by(self, other: CameraSpec) -> CameraSpec {
        CameraSpec {
            eye: other.eye.or(self.eye),
            target: other.target.or(self.target),
            up: other.up.or(self.up),
            fov: other.fov.or(self.fov),
        }
    }

    /// A complete camera for a scene whose surfaces span `bounds` (world
    /// space, `None` for a scene without surfaces) and an image of
    /// `aspect` = width / height.
    ///
    /// Missing keys: `up` is +y, `fov` 45 degrees, `target` the centre of
    /// `bounds`; without `eye`, the eye looks at the target from the +z side
    /// and slightly above (the dashboard's start view), at the smallest
    /// distance for which all eight corners of `bounds` project inside the
    /// frame (with a 5% margin). A camera whose target or eye would need
    /// bounds that do not exist is an error, as is one that cannot form a
    /// view (eye on the target, up along the view direction, fov outside
    /// (0, 180)).
    pub fn resolve(
        &self,
        bounds: Option<(Vec3, Vec3)>,
        aspect: f32,
    ) -> Result<Camera, CameraError> {
        let fov_degrees = self.fov.unwrap_or(DEFAULT_FOV_DEGREES);
        if !(fov_degrees > 0.0 && fov_degrees < 180.0) {
            return Err(CameraError::Invalid(format!(
                "fov {fov_degrees} is not between 0 and 180 degrees"
            )));
        }
        let up = self.up.unwrap_or(Vec3::Y);
        let no_bounds = || {
            CameraError::Invalid(
                "the scene has no surfaces to frame; give both eye and target".into(),
            )
        };
        let target = match self.target {
            Some(t) => t,
            None => {
                let (lo, hi) = bounds.ok_or_else(no_bounds)?;
                (lo + hi) * 0.5
            }
        };
        let eye = match self.eye {
            Some(e) => e,
            None => {
                let (lo, hi) = bounds.ok_or_else(no_bounds)?;
                let back = Vec3::new(0.0, DEFAULT_PITCH.sin(), DEFAULT_PITCH.cos());
                let distance = framing_distance(target, back, up, fov_degrees, aspect, lo, hi)
                    .ok_or_else(|| {
                        CameraError::Invalid(
                            "up is parallel to the default view direction; give an eye".into(),
                        )
                    })?;
                target + back * distance
            }
        };
        let camera = Camera {
            eye,
            target,
            up,
            fov_degrees,
        };
        camera.check()?;
        Ok(camera)
    }
}

/// The smallest distance from `target` along `back` (unit, pointing from
/// the target to the eye) at which every corner of the box `lo..hi`
/// projects inside [`FRAME_FILL`] of the frame. `None` when `up` is parallel
/// to `back`.
fn framing_distance(
    target: Vec3,
    back: Vec3,
    up: Vec3,
    fov_degrees: f32,
    aspect: f32,
    lo: Vec3,
    hi: Vec3,
) -> Option<f32> {
    let forward = -back;
    let right = forward.cross(up).try_normalize()?;
    let image_up = right.cross(forward);
    let tan_y = (fov_degrees.to_radians() * 0.5).tan() * FRAME_FILL;
    let tan_x = tan_y * aspect;
    let mut distance = 0.0f32;
    for i in 0..8 {
        let corner = Vec3::new(
            if i & 1 == 0 { lo.x } else { hi.x },
            if i & 2 == 0 { lo.y } else { hi.y },
            if i & 4 == 0 { lo.z } else { hi.z },
        );
        let rel = corner - target;
        // The corner's depth in front of an eye at `target + back * d` is
        // `d - rel.back`; it is in frame when |rel.right| <= depth * tan_x
        // and |rel.image_up| <= depth * tan_y.
        let along = rel.dot(back);
        distance = distance
            .max(along + rel.dot(right).abs() / tan_x)
            .max(along + rel.dot(image_up).abs() / tan_y);
    }
    // A degenerate (flat, point) scene still gets a positive distance.
    Some(distance.max((hi - lo).length() * 0.5).max(1e-3))
}

impl Camera {
    /// Checks that the camera forms a view.
    pub fn check(&self) -> Result<(), CameraError> {
        let finite = self.eye.is_finite() && self.target.is_finite() && self.up.is_finite();
        if !finite {
            return Err(CameraError::Invalid("a coordinate is not finite".into()));
        }
        if !(self.fov_degrees > 0.0 && self.fov_degrees < 180.0) {
            return Err(CameraError::Invalid(format!(
                "fov {} is not between 0 and 180 degrees",
                self.fov_degrees
            )));
        }
        let forward = self.target - self.eye;
        if forward.length() <= f32::EPSILON * self.eye.length().max(1.0) {
            return Err(CameraError::Invalid(format!(
                "eye and target are the same point ({})",
                fmt_vec3(self.eye)
            )));
        }
        if forward.normalize().cross(self.up).length()
            < 1e-4 * self.up.length().max(f32::MIN_POSITIVE)
            || self.up.length() == 0.0
        {
            return Err(CameraError::Invalid(format!(
                "up ({}) is zero or parallel to the view direction; give another up",
                fmt_vec3(self.up)
            )));
        }
        Ok(())
    }

    /// The world-to-view matrix (right-handed, looking down -z).
    pub fn view(&self) -> Mat4 {
        glam::camera::rh::view::look_at_mat4(self.eye, self.target, self.up)
    }

    /// View-to-clip for an image of `aspect` = width / height: reversed-Z,
    /// infinite far plane, near plane at `near`.
    pub fn projection(&self, aspect: f32, near: f32) -> Mat4 {
        // The WebGPU convention: NDC z in [0, 1], y up.
        glam::camera::rh::proj::directx::perspective_infinite_reverse(
            self.fov_degrees.to_radians(),
            aspect,
            near,
        )
    }
}

fn fmt_vec3(v: Vec3) -> String {
    format!("{},{},{}", v.x, v.y, v.z)
}

impl fmt::Display for Camera {
    /// The `--camera` syntax, with shortest round-tripping numbers.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "eye={};target={};up={};fov={}",
            fmt_vec3(self.eye),
            fmt_vec3(self.target),
            fmt_vec3(self.up),
            self.fov_degrees
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_full_camera_parses_and_prints_back() {
        let spec: CameraSpec = "eye=1,2,3; target=0,0.5,-1 ;up=0,0,1;fov=30"
            .parse()
            .unwrap();
        let camera = spec.resolve(None, 1.0).unwrap();
        assert_eq!(camera.eye, Vec3::new(1.0, 2.0, 3.0));
        assert_eq!(camera.up, Vec3::Z);
        let printed = camera.to_string();
        assert_eq!(printed, "eye=1,2,3;target=0,0.5,-1;up=0,0,1;fov=30");
        let again: CameraSpec = printed.parse().unwrap();
        assert_eq!(again.resolve(None, 1.0).unwrap(), camera);
    }

    #[test]
    fn bad_cameras_say_what_is_wrong() {
        let cases = [
            ("eye=1,2", "has 2 numbers, expected three"),
            ("eye=1,2,x", "\"x\" in \"1,2,x\" is not a finite number"),
            ("eye=1,2,inf", "is not a finite number"),
            ("fov=wide", "fov: \"wide\" is not a number"),
            ("eye=1,2,3;eye=1,2,3", "\"eye\" is given twice"),
            ("pos=1,2,3", "unknown key \"pos\""),
            ("eye", "\"eye\" is not key=value"),
        ];
        for (text, expected) in cases {
            let err = text.parse::<CameraSpec>().unwrap_err().to_string();
            assert!(err.contains(expected), "{text}: {err}");
            assert!(err.contains(text), "the error quotes the input: {err}");
        }
        let resolve = |text: &str| text.parse::<CameraSpec>().unwrap().resolve(None, 1.0);
        let err = resolve("eye=1,1,1;target=1,1,1").unwrap_err().to_string();
        assert!(err.contains("eye and target are the same point"), "{err}");
        let err = resolve("eye=0,5,0;target=0,0,0").unwrap_err().to_string();
        assert!(err.contains("parallel to the view direction"), "{err}");
        let err = resolve("eye=0,0,5;target=0,0,0;fov=180")
            .unwrap_err()
            .to_string();
        assert!(err.contains("fov 180 is not between 0 and 180"), "{err}");
        let err = resolve("fov=50").unwrap_err().to_string();
        assert!(err.contains("no surfaces to frame"), "{err}");
    }

    #[test]
    fn flags_override_the_camera_string() {
        let base: CameraSpec = "eye=1,2,3;fov=30".parse().unwrap();
        let flags = CameraSpec {
            fov: Some(60.0),
            ..Default::default()
        };
        let merged = base.overridden_by(flags);
        assert_eq!(merged.eye, Some(Vec3::new(1.0, 2.0, 3.0)));
        assert_eq!(merged.fov, Some(60.0));
    }

    /// Projects a world point to normalised device coordinates.
    fn ndc(camera: &Camera, aspect: f32, p: Vec3) -> Vec3 {
        let clip = camera.projection(aspect, 0.01) * camera.view() * p.extend(1.0);
        clip.truncate() / clip.w
    }

    #[test]
    fn the_default_camera_frames_every_corner_of_the_scene() {
        // The Cornell box's bounds; a wide and a tall image.
        let (lo, hi) = (Vec3::ZERO, Vec3::new(5.56, 5.488, 5.592));
        for aspect in [4.0 / 3.0, 0.5] {
            let camera = CameraSpec::default()
                .resolve(Some((lo, hi)), aspect)
                .unwrap();
            assert_eq!(camera.target, (lo + hi) * 0.5);
            assert!(
                camera.eye.z > hi.z && camera.eye.y > camera.target.y,
                "from +z, above"
            );
            let mut extent: f32 = 0.0;
            for i in 0..8 {
                let c = Vec3::new(
                    if i & 1 == 0 { lo.x } else { hi.x },
                    if i & 2 == 0 { lo.y } else { hi.y },
                    if i & 4 == 0 { lo.z } else { hi.z },
                );
                let p = ndc(&camera, aspect, c);
                assert!(p.x.abs() <= 0.951 && p.y.abs() <= 0.951, "{c} -> {p}");
                assert!(p.z > 0.0 && p.z < 1.0, "in front of the near plane");
                extent = extent.max(p.x.abs()).max(p.y.abs());
            }
            // Tight: some corner touches the 95% margin.
            assert!(extent > 0.94, "framing is tight: {extent}");
        }
    }
}
