//! Semantic checks that turn a [`SceneFile`] into a [`Scene`].
//!
//! Every check records a [`SceneIssue`] naming the entry (kind, index and
//! name) and the problem, and validation carries on, so that one run reports
//! all problems of a file instead of the first.

use std::collections::HashMap;

use glam::{Quat, Vec3};

use super::file::{BoxJson, Facing, PoseJson, QuadJson, SceneFile, Vec3Json};
use super::{LoadOptions, Material, Object, Patch, PatchShape, Pose, Scene, SceneIssue};

/// Largest atlas edge a scene may ask for.
pub const MAX_ATLAS_LIMIT: u32 = 16384;
/// Smallest atlas edge a scene may ask for.
pub const MIN_ATLAS_LIMIT: u32 = 16;
/// Name reserved for the static world.
pub const STATIC_NAME: &str = "static";

struct Checker {
    issues: Vec<SceneIssue>,
}

impl Checker {
    fn report(&mut self, location: &str, problem: impl Into<String>) {
        self.issues.push(SceneIssue {
            location: location.to_string(),
            problem: problem.into(),
        });
    }

    /// Converts to f32, reporting NaN, infinities and values that overflow
    /// single precision.
    fn finite(&mut self, location: &str, what: &str, x: f64) -> Option<f32> {
        let y = x as f32;
        if x.is_finite() && y.is_finite() {
            Some(y)
        } else {
            self.report(
                location,
                format!("{what} = {x:e} is not a finite number (single precision holds magnitudes up to 3.4e38)"),
            );
            None
        }
    }

    fn vec3(&mut self, location: &str, what: &str, v: &Vec3Json) -> Option<Vec3> {
        let x = self.finite(location, &format!("{what}[0]"), v[0]);
        let y = self.finite(location, &format!("{what}[1]"), v[1]);
        let z = self.finite(location, &format!("{what}[2]"), v[2]);
        Some(Vec3::new(x?, y?, z?))
    }

    /// A rotation must be a unit quaternion (within 1e-3; it is then
    /// renormalised).
    fn rotation(&mut self, location: &str, what: &str, q: &[f64; 4]) -> Option<Quat> {
        let mut c = [0.0f32; 4];
        let mut ok = true;
        for (i, x) in q.iter().enumerate() {
            match self.finite(location, &format!("{what}[{i}]"), *x) {
                Some(v) => c[i] = v,
                None => ok = false,
            }
        }
        if !ok {
            return None;
        }
        let quat = Quat::from_xyzw(c[0], c[1], c[2], c[3]);
        let len = quat.length();
        if (len - 1.0).abs() > 1e-3 {
            self.report(
                location,
                format!(
                    "{what} has length {len}; a rotation must be a unit quaternion [x, y, z, w]"
                ),
            );
            return None;
        }
        Some(quat.normalize())
    }

    fn pose(&mut self, location: &str, pose: &PoseJson) -> Option<Pose> {
        let translation = self.vec3(location, "pose.translation", &pose.translation);
        let rotation = self.rotation(location, "pose.rotation", &pose.rotation);
        let scale = self.finite(location, "pose.scale", pose.scale);
        if let Some(s) = scale {
            if s <= 0.0 {
                self.report(location, format!("pose.scale = {s} must be greater than 0"));
                return None;
            }
        }
        Some(Pose {
            translation: translation?,
            rotation: rotation?,
            scale: scale?,
        })
    }

    fn density(&mut self, location: &str, what: &str, d: f64, scale: f32) -> Option<f32> {
        let d = self.finite(location, what, d)?;
        if d <= 0.0 {
            self.report(
                location,
                format!("{what} = {d} must be greater than 0 texels per metre"),
            );
            return None;
        }
        Some(d * scale)
    }

    fn unique<'a>(&mut self, kind: &str, names: impl Iterator<Item = &'a str>) {
        let mut seen: HashMap<&str, usize> = HashMap::new();
        for (i, name) in names.enumerate() {
            if name.trim().is_empty() {
                self.report(&format!("{kind} #{i}"), "name is empty");
            } else if let Some(first) = seen.get(name) {
                self.report(
                    &format!("{kind} #{i} \"{name}\""),
                    format!("duplicate name: {kind} #{first} is also called \"{name}\""),
                );
            } else {
                seen.insert(name, i);
            }
        }
    }
}

/// Validates a parsed scene file. Returns every problem found.
pub fn validate(raw: SceneFile, options: LoadOptions) -> Result<Scene, Vec<SceneIssue>> {
    let mut c = Checker { issues: Vec::new() };

    if raw.name.trim().is_empty() {
        c.report("scene", "name is empty");
    }
    if !(options.density_scale.is_finite() && options.density_scale > 0.0) {
        c.report(
            "load options",
            format!("density scale {} must be > 0", options.density_scale),
        );
    }
    let texel_density = c.density(
        "lightmap",
        "texel_density",
        raw.lightmap.texel_density,
        options.density_scale,
    );
    let max_atlas_size = raw.lightmap.max_atlas_size;
    if !(MIN_ATLAS_LIMIT..=MAX_ATLAS_LIMIT).contains(&max_atlas_size) {
        c.report(
            "lightmap",
            format!("max_atlas_size = {max_atlas_size} must be between {MIN_ATLAS_LIMIT} and {MAX_ATLAS_LIMIT}"),
        );
    }

    // Materials.
    c.unique("material", raw.materials.iter().map(|m| m.name.as_str()));
    let mut materials = Vec::with_capacity(raw.materials.len());
    for (i, m) in raw.materials.iter().enumerate() {
        let loc = format!("material #{i} \"{}\"", m.name);
        let albedo = c.vec3(&loc, "albedo", &m.albedo);
        let emission = c.vec3(&loc, "emission", &m.emission);
        if let Some(a) = albedo {
            for (k, x) in a.to_array().iter().enumerate() {
                if !(0.0..1.0).contains(x) {
                    c.report(&loc, format!("albedo[{k}] = {x} is outside [0, 1): a surface cannot reflect all the light it receives"));
                }
            }
        }
        if let Some(e) = emission {
            for (k, x) in e.to_array().iter().enumerate() {
                if *x < 0.0 {
                    c.report(
                        &loc,
                        format!("emission[{k}] = {x} is negative; emission must be >= 0"),
                    );
                }
            }
        }
        materials.push(Material {
            name: m.name.clone(),
            albedo: albedo.unwrap_or(Vec3::ZERO),
            emission: emission.unwrap_or(Vec3::ZERO),
        });
    }

    // Objects: the static world first, then the dynamic ones in file order.
    c.unique("object", raw.objects.iter().map(|o| o.name.as_str()));
    let mut objects = vec![Object {
        name: STATIC_NAME.to_string(),
        dynamic: false,
        initial_pose: Pose::IDENTITY,
    }];
    for (i, o) in raw.objects.iter().enumerate() {
        let loc = format!("object #{i} \"{}\"", o.name);
        if o.name == STATIC_NAME {
            c.report(
                &loc,
                format!("the name \"{STATIC_NAME}\" is reserved for the static world"),
            );
        }
        let pose = c.pose(&loc, &o.pose).unwrap_or_default();
        objects.push(Object {
            name: o.name.clone(),
            dynamic: true,
            initial_pose: pose,
        });
    }

    // Surfaces.
    c.unique("surface", raw.surfaces.iter().map(|s| s.name.as_str()));
    let mut patches = Vec::new();
    for (i, s) in raw.surfaces.iter().enumerate() {
        let loc = format!("surface #{i} \"{}\"", s.name);
        let material = raw.materials.iter().position(|m| m.name == s.material);
        if material.is_none() {
            c.report(&loc, format!("unknown material \"{}\"", s.material));
        }
        let object = match &s.object {
            None => Some(0u32),
            Some(name) => match raw.objects.iter().position(|o| &o.name == name) {
                Some(k) => Some(k as u32 + 1),
                None => {
                    c.report(&loc, format!("unknown object \"{name}\" (dynamic objects are declared under \"objects\"; omit \"object\" for static surfaces)"));
                    None
                }
            },
        };
        let density = match s.texel_density {
            Some(d) => c.density(&loc, "texel_density", d, options.density_scale),
            None => texel_density,
        };
        let shapes: Vec<(String, PatchShape)> = match (&s.quad, &s.box_) {
            (Some(q), None) => quad(&mut c, &loc, q)
                .map(|q| vec![(s.name.clone(), q)])
                .unwrap_or_default(),
            (None, Some(b)) => boxed(&mut c, &loc, &s.name, b),
            (Some(_), Some(_)) => {
                c.report(
                    &loc,
                    "has both \"quad\" and \"box\"; give exactly one shape",
                );
                Vec::new()
            }
            (None, None) => {
                c.report(&loc, "has no shape; give \"quad\" or \"box\"");
                Vec::new()
            }
        };
        if let (Some(material), Some(object), Some(density)) = (material, object, density) {
            for (name, shape) in shapes {
                patches.push(Patch {
                    name,
                    surface_index: i,
                    object,
                    material: material as u32,
                    texel_density: density,
                    shape,
                });
            }
        }
    }

    if raw.surfaces.is_empty() {
        c.report("scene", "has no surfaces");
    } else if c.issues.is_empty()
        && !patches
            .iter()
            .any(|p| materials[p.material as usize].is_emitter())
    {
        c.report(
            "scene",
            "has no emitter: no surface uses a material with emission > 0, so everything would be black",
        );
    }

    if !c.issues.is_empty() {
        return Err(c.issues);
    }
    Ok(Scene {
        name: raw.name,
        description: raw.description,
        texel_density: texel_density.unwrap_or(1.0),
        max_atlas_size,
        materials,
        objects,
        patches,
    })
}

/// Relative tolerance for planarity and parallelogram checks.
const SHAPE_TOLERANCE: f32 = 1e-4;

fn quad(c: &mut Checker, loc: &str, q: &QuadJson) -> Option<PatchShape> {
    let (origin, u, v) = match (&q.origin, &q.u, &q.v, &q.corners) {
        (Some(o), Some(u), Some(v), None) => {
            let o = c.vec3(loc, "quad.origin", o);
            let u = c.vec3(loc, "quad.u", u);
            let v = c.vec3(loc, "quad.v", v);
            (o?, u?, v?)
        }
        (None, None, None, Some(corners)) => {
            let mut p = [Vec3::ZERO; 4];
            let mut ok = true;
            for (k, corner) in corners.iter().enumerate() {
                match c.vec3(loc, &format!("quad.corners[{k}]"), corner) {
                    Some(x) => p[k] = x,
                    None => ok = false,
                }
            }
            if !ok {
                return None;
            }
            let (u, v) = (p[1] - p[0], p[3] - p[0]);
            let n = u.cross(v);
            let scale = u.length().max(v.length());
            if n.length() > 0.0 {
                let deviation = p[2] - (p[0] + u + v);
                let off_plane = deviation.dot(n.normalize()).abs();
                if off_plane > SHAPE_TOLERANCE * scale {
                    c.report(loc, format!("quad is not planar: corners[2] lies {off_plane} m off the plane of the other three corners"));
                    return None;
                }
                if deviation.length() > SHAPE_TOLERANCE * scale {
                    c.report(
                        loc,
                        format!(
                            "quad is not a parallelogram: corners[2] is {} m away from corners[1] + corners[3] - corners[0]",
                            deviation.length()
                        ),
                    );
                    return None;
                }
            }
            (p[0], u, v)
        }
        _ => {
            c.report(
                loc,
                "quad needs either \"origin\", \"u\" and \"v\", or \"corners\" (four points)",
            );
            return None;
        }
    };
    let area = u.cross(v).length();
    let scale = u.length_squared().max(v.length_squared());
    if !(area > 1e-10 && area > 1e-6 * scale) {
        c.report(
            loc,
            format!("quad has zero area (|u × v| = {area}): its edges are degenerate or parallel"),
        );
        return None;
    }
    Some(PatchShape::Quad { origin, u, v })
}

fn boxed(c: &mut Checker, loc: &str, name: &str, b: &BoxJson) -> Vec<(String, PatchShape)> {
    let center = c.vec3(loc, "box.center", &b.center);
    let size = c.vec3(loc, "box.size", &b.size);
    let rotation = c.rotation(loc, "box.rotation", &b.rotation);
    let (Some(center), Some(size), Some(rotation)) = (center, size, rotation) else {
        return Vec::new();
    };
    for (k, s) in size.to_array().iter().enumerate() {
        if *s <= 0.0 {
            c.report(loc, format!("box.size[{k}] = {s} must be greater than 0"));
            return Vec::new();
        }
    }
    let ex = rotation * Vec3::X * size.x;
    let ey = rotation * Vec3::Y * size.y;
    let ez = rotation * Vec3::Z * size.z;
    let min = center - 0.5 * (ex + ey + ez);
    // (suffix, origin, u, v) with u × v pointing out of the box.
    let faces = [
        ("+x", min + ex, ey, ez),
        ("-x", min, ez, ey),
        ("+y", min + ey, ez, ex),
        ("-y", min, ex, ez),
        ("+z", min + ez, ex, ey),
        ("-z", min, ey, ex),
    ];
    faces
        .into_iter()
        .map(|(suffix, origin, u, v)| {
            let (u, v) = match b.facing {
                Facing::Out => (u, v),
                Facing::In => (v, u),
            };
            (
                format!("{name}/{suffix}"),
                PatchShape::Quad { origin, u, v },
            )
        })
        .collect()
}
