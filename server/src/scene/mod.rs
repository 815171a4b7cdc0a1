//! Scenes: what is lit, what it is made of, and what moves.
//!
//! A scene file (JSON, see `scenes/README.md`) is parsed into the raw types of
//! [`file`], then [`validate`] checks every number and name and expands
//! compound shapes (boxes) into [`Patch`]es. Everything downstream — the
//! atlas, the solvers, the network service — works on the validated
//! [`Scene`] and may assume it is sound: finite coordinates, non-degenerate
//! planar patches, albedo in [0, 1), non-negative emission, at least one
//! emitter, and names that resolve.
//!
//! Geometry of dynamic objects is stored in object-local space together with
//! the object's initial [`Pose`]; the static world (object 0) always has the
//! identity pose.
//!
//! Patches are the unit the atlas charts and the solvers pick shooters from.
//! Today every patch is a parallelogram; triangle meshes will add a
//! [`PatchShape`] variant and a chart rule in the atlas, nothing else.

pub mod error;
pub mod file;
pub mod gltf;
mod validate;

use std::path::Path;

use glam::{Quat, Vec3};

pub use error::{SceneError, SceneIssue};

/// The id of the static world in [`Scene::objects`].
pub const STATIC_OBJECT: u32 = 0;

/// A validated scene, ready to be charted and solved.
#[derive(Debug, Clone)]
pub struct Scene {
    /// Identifier from the file (also the network scene id).
    pub name: String,
    /// Free-form description from the file.
    pub description: String,
    /// Texels per metre used where a surface does not override it.
    pub texel_density: f32,
    /// Upper bound on atlas width and height in texels.
    pub max_atlas_size: u32,
    /// Materials, indexed by [`Patch::material`].
    pub materials: Vec<Material>,
    /// Objects; index 0 is the static world, the rest are dynamic.
    pub objects: Vec<Object>,
    /// Surfaces after expansion (a box becomes six patches).
    pub patches: Vec<Patch>,
}

/// A Lambertian material.
#[derive(Debug, Clone, PartialEq)]
pub struct Material {
    pub name: String,
    /// Diffuse reflectance per channel, in [0, 1).
    pub albedo: Vec3,
    /// Radiant exitance per channel in W/m², >= 0.
    pub emission: Vec3,
}

impl Material {
    /// Whether the material emits light in any channel.
    pub fn is_emitter(&self) -> bool {
        self.emission.max_element() > 0.0
    }
}

/// The static world or a named rigid group that can move.
#[derive(Debug, Clone, PartialEq)]
pub struct Object {
    pub name: String,
    /// False only for the static world.
    pub dynamic: bool,
    /// The pose given in the scene file.
    pub initial_pose: Pose,
}

/// A rigid transform with uniform scale: `p' = rotation * (scale * p) + translation`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    pub translation: Vec3,
    /// Unit quaternion.
    pub rotation: Quat,
    /// Uniform scale, > 0.
    pub scale: f32,
}

impl Default for Pose {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl Pose {
    pub const IDENTITY: Pose = Pose {
        translation: Vec3::ZERO,
        rotation: Quat::IDENTITY,
        scale: 1.0,
    };

    /// Maps an object-local point to world space.
    pub fn transform_point(&self, p: Vec3) -> Vec3 {
        self.rotation * (p * self.scale) + self.translation
    }

    /// Maps an object-local direction (an edge vector) to world space,
    /// including the scale.
    pub fn transform_vector(&self, v: Vec3) -> Vec3 {
        self.rotation * (v * self.scale)
    }

    /// Maps an object-local unit normal to a world-space unit normal.
    /// (Uniform scale keeps normals perpendicular.)
    pub fn transform_normal(&self, n: Vec3) -> Vec3 {
        (self.rotation * n).normalize()
    }
}

/// One chartable piece of surface.
#[derive(Debug, Clone, PartialEq)]
pub struct Patch {
    /// Unique name; boxes produce `box-name/+x`, `box-name/-y`, ...
    pub name: String,
    /// Index of the surface entry in the file this patch came from.
    pub surface_index: usize,
    /// Index into [`Scene::objects`].
    pub object: u32,
    /// Index into [`Scene::materials`].
    pub material: u32,
    /// Texels per metre for this patch.
    pub texel_density: f32,
    /// Geometry in object-local space.
    pub shape: PatchShape,
}

/// The geometry of a patch in object-local space.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PatchShape {
    /// Parallelogram with corners `origin`, `origin+u`, `origin+u+v`,
    /// `origin+v`; it faces `u × v`.
    Quad { origin: Vec3, u: Vec3, v: Vec3 },
}

impl PatchShape {
    /// Unit normal of the front face.
    pub fn normal(&self) -> Vec3 {
        match *self {
            PatchShape::Quad { u, v, .. } => u.cross(v).normalize(),
        }
    }

    /// Area in object-local units.
    pub fn area(&self) -> f32 {
        match *self {
            PatchShape::Quad { u, v, .. } => u.cross(v).length(),
        }
    }

    /// Corners in counter-clockwise order seen from the front.
    pub fn corners(&self) -> [Vec3; 4] {
        match *self {
            PatchShape::Quad { origin, u, v } => [origin, origin + u, origin + u + v, origin + v],
        }
    }

    /// The same shape moved by `pose`.
    pub fn transformed(&self, pose: &Pose) -> PatchShape {
        match *self {
            PatchShape::Quad { origin, u, v } => PatchShape::Quad {
                origin: pose.transform_point(origin),
                u: pose.transform_vector(u),
                v: pose.transform_vector(v),
            },
        }
    }
}

/// Options applied while loading, for tests and benchmarks that want a
/// coarser or finer version of a scene file.
#[derive(Debug, Clone, Copy)]
pub struct LoadOptions {
    /// Multiplies every texel density (scene-wide and per-surface).
    pub density_scale: f32,
}

impl Default for LoadOptions {
    fn default() -> Self {
        Self { density_scale: 1.0 }
    }
}

impl Scene {
    /// Reads, parses and validates a scene file.
    pub fn load(path: &Path) -> Result<Scene, SceneError> {
        Self::load_with(path, LoadOptions::default())
    }

    /// [`Scene::load`] with [`LoadOptions`].
    pub fn load_with(path: &Path, options: LoadOptions) -> Result<Scene, SceneError> {
        let text = std::fs::read_to_string(path).map_err(|e| SceneError::Io {
            path: path.display().to_string(),
            message: e.to_string(),
        })?;
        Self::parse_with(&text, &path.display().to_string(), options)
    }

    /// Parses and validates scene JSON; `origin` names the source in errors.
    pub fn parse(text: &str, origin: &str) -> Result<Scene, SceneError> {
        Self::parse_with(text, origin, LoadOptions::default())
    }

    /// [`Scene::parse`] with [`LoadOptions`].
    pub fn parse_with(text: &str, origin: &str, options: LoadOptions) -> Result<Scene, SceneError> {
        let raw: file::SceneFile = serde_json::from_str(text).map_err(|e| SceneError::Syntax {
            origin: origin.to_string(),
            line: e.line(),
            column: e.column(),
            message: strip_position(&e.to_string()),
        })?;
        let invalid = |issues| SceneError::Invalid {
            origin: origin.to_string(),
            issues,
        };
        validate::validate(raw, options).map_err(invalid)
    }

    /// Indices of the dynamic objects.
    pub fn dynamic_objects(&self) -> impl Iterator<Item = u32> + '_ {
        self.objects
            .iter()
            .enumerate()
            .filter(|(_, o)| o.dynamic)
            .map(|(i, _)| i as u32)
    }

    /// Looks up an object by name.
    pub fn object_by_name(&self, name: &str) -> Option<u32> {
        self.objects
            .iter()
            .position(|o| o.name == name)
            .map(|i| i as u32)
    }

    /// The initial pose of every object, indexed like [`Scene::objects`].
    pub fn initial_poses(&self) -> Vec<Pose> {
        self.objects.iter().map(|o| o.initial_pose).collect()
    }

    /// Total emitted power (W) per channel at the given poses. Uniform scale
    /// changes emitter area, so poses matter.
    pub fn emitted_power(&self, poses: &[Pose]) -> Vec3 {
        self.patches
            .iter()
            .map(|p| {
                let s = poses[p.object as usize].scale;
                self.materials[p.material as usize].emission * p.shape.area() * s * s
            })
            .sum()
    }
}

/// serde_json appends " at line L column C"; we report those separately.
fn strip_position(message: &str) -> String {
    match message.rfind(" at line ") {
        Some(i) => message[..i].to_string(),
        None => message.to_string(),
    }
}
