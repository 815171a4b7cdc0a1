//! `lightwire-scene`: what is lit and where its light is stored.
//!
//! This crate owns scene files and their validation, glTF import and export,
//! textures, the lightmap atlas with its charts, lightmap UVs and seams
//! ([`atlas`], [`unwrap`]), and the resampling of the atlas onto a mesh's own
//! lightmap UVs ([`uvmap`]). It is the bottom layer above the wire protocol:
//! it may not use the GPU, the solvers (`lightwire-solve`), tokio or the
//! network service (`lightwire-server`); the compiler enforces that, because
//! it does not depend on them.
//!
//! # Scenes: what is lit, what it is made of, and what moves
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
//! Patches are the unit the atlas charts and the solvers pick shooters from:
//! parallelograms (quads, boxes) and triangles (meshes).

pub mod atlas;
pub mod bvh;
pub mod error;
pub mod file;
pub mod gltf;
pub mod light;
pub mod load;
pub mod near_lights;
mod pairs;
pub mod texture;
pub mod unwrap;
pub mod uv;
pub mod uvmap;
mod validate;

use std::path::Path;

use glam::{Quat, Vec2, Vec3};

pub use error::{SceneError, SceneIssue};
pub use light::{Light, LightKind, Sky};

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
    /// The imported glTF meshes that brought their own lightmap UVs
    /// (`TEXCOORD_1`); the solved light is resampled into them
    /// (`crate::uvmap`, `lightwire bake`).
    pub uv_meshes: Vec<UvMesh>,
    /// Solver settings the scene file states (`"solver"`), measured for it
    /// at its own texel density: empty when it states none or when the
    /// scene was loaded at another density (`LoadOptions::density_scale`).
    pub solver: SolverHints,
    /// Point, spot and directional lights (`light.rs`), besides the
    /// emitting surfaces.
    pub lights: Vec<Light>,
    /// The sky, if the scene is lit by one.
    pub sky: Option<Sky>,
    /// What loading dropped or changed and went on past (zero-area and
    /// duplicate triangles of a mesh, clamped albedos), one entry per kind
    /// and source; `lightwire validate` and `bake` print them, `serve` logs
    /// them.
    pub warnings: Vec<SceneIssue>,
}

/// Solver settings measured for one scene (its file's `"solver"`; see
/// scenes/README.md): `None` keeps the solver's default.
/// `gpu::ProgressiveOptions::with_hints` applies them.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SolverHints {
    /// Rays per side of the cross projection's grid on a tile (thesis
    /// Alg. 4.5 gridSize), 1 to [`SolverHints::MAX_CROSS_GRID`].
    pub cross_grid: Option<u32>,
    /// Top-face resolution of the cross projection's back hemicubes, in
    /// pixels, [`SolverHints::MIN_BACK_RESOLUTION`] to
    /// [`SolverHints::MAX_BACK_RESOLUTION`].
    pub back_resolution: Option<u32>,
    /// Form factor to a tile below which a receiver samples the tile's
    /// projection through the grid of half the side, 0 to 1.
    pub cross_coarse_below: Option<f32>,
}

impl SolverHints {
    pub const MAX_CROSS_GRID: u32 = 16;
    pub const MIN_BACK_RESOLUTION: u32 = 2;
    pub const MAX_BACK_RESOLUTION: u32 = 256;

    /// Each setting of `self`, else of `other`.
    pub fn or(self, other: SolverHints) -> SolverHints {
        SolverHints {
            cross_grid: self.cross_grid.or(other.cross_grid),
            back_resolution: self.back_resolution.or(other.back_resolution),
            cross_coarse_below: self.cross_coarse_below.or(other.cross_coarse_below),
        }
    }

    /// Whether no setting is stated.
    pub fn is_empty(&self) -> bool {
        *self == SolverHints::default()
    }
}

impl std::fmt::Display for SolverHints {
    /// `cross_grid 3, back_resolution 16` (the stated ones), or `none`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut parts = Vec::new();
        if let Some(g) = self.cross_grid {
            parts.push(format!("cross_grid {g}"));
        }
        if let Some(r) = self.back_resolution {
            parts.push(format!("back_resolution {r}"));
        }
        if let Some(t) = self.cross_coarse_below {
            parts.push(format!("cross_coarse_below {t}"));
        }
        if parts.is_empty() {
            f.write_str("none")
        } else {
            f.write_str(&parts.join(", "))
        }
    }
}

/// One node's instance of a glTF mesh with its own lightmap UVs
/// (`TEXCOORD_1`): the triangles of all its primitives that have them,
/// which share one lightmap space [0, 1]² (`gltf` module doc). The solvers
/// do not read it: they light charts of their own (`atlas.rs`), and
/// `lightwire bake` resamples that light into this layout
/// (`crate::uvmap`), which is where an engine that brought the mesh
/// expects its lightmap.
#[derive(Debug, Clone, PartialEq)]
pub struct UvMesh {
    /// `node/mesh`, as its patches' names begin (`node#i`, `mesh#j` when
    /// unnamed).
    pub name: String,
    /// Index into [`Scene::objects`].
    pub object: u32,
    /// [`Patch::surface_index`] of the patches its triangles became.
    pub surface_index: usize,
    /// Triangles in the object's space, counter-clockwise seen from the
    /// front (as its patches).
    pub triangles: Vec<[Vec3; 3]>,
    /// Their lightmap UVs, corner by corner.
    pub uvs: Vec<[Vec2; 3]>,
    /// Whether Lightwire generated these UVs (`unwrap.rs`) for a mesh that
    /// brought none, or `--charts generated` asked: no asset holds them,
    /// so no lightmap is resampled into them for a client.
    pub generated: bool,
    /// How many charts the generated UVs cut the mesh into (0 for UVs an
    /// asset or a scene file brought).
    pub charts: usize,
    /// Edges (object space, end to end) where the asset's vertex normals
    /// say the surface is smooth (`unwrap::smooth_edges`): where such an
    /// edge is a seam between two islands, its two sides are stitched
    /// although their faces meet at an angle (`atlas/stitch.rs`). Empty for
    /// a scene file's `mesh` (it has no normals).
    pub smooth_edges: Vec<[Vec3; 2]>,
    /// The side of the square block generated UVs were packed for
    /// (`unwrap::Unwrap::side`, texels; 0 for UVs an asset or a scene file
    /// brought): the block is never smaller, so that charts laid out finer
    /// than the mesh's density near a light (`near_lights.rs`) keep their
    /// texels.
    pub packed_side: f32,
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

/// A transform script's key as a pose (scripts drive objects: `lightwire
/// bench`, the round-trip example and tests).
impl From<&lightwire_protocol::script::Key> for Pose {
    fn from(key: &lightwire_protocol::script::Key) -> Self {
        Self {
            translation: key.translation,
            rotation: key.rotation,
            scale: key.scale,
        }
    }
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
    /// A base colour texture on a triangle (glTF imports): the albedo is the
    /// material's times the texture's (`texture.rs`).
    pub albedo_map: Option<texture::AlbedoMap>,
    /// Whether the patch is part of a triangle mesh: a triangle, or two
    /// that form a parallelogram and share one chart (`pairs.rs`). Mesh
    /// patches may shoot in clusters (`gpu/progressive/clusters.rs`).
    pub mesh: bool,
    /// A quad merged from a grid of equal cells of a mesh (`pairs.rs`):
    /// how many along `u` and `v`; `[1, 1]` otherwise. Its chart puts a
    /// whole number of texel spacings in every cell, as each cell's own
    /// chart would (`atlas.rs`), so that where it meets a smaller merged
    /// chart of the same tessellation (a T-junction) their edge texels
    /// fall on the same points and are stitched as a seam (unless a cell
    /// is shorter than a texel spacing, `atlas::pack::chart_size`).
    pub cells: [u32; 2],
    /// A triangle of a glTF mesh that brought its own lightmap UVs
    /// (`TEXCOORD_1`), lit on them (`--charts lightmap-uvs`), or a
    /// parallelogram of such triangles over which they are affine
    /// (`pairs.rs`): which of [`Scene::uv_meshes`] and its UVs at
    /// `origin`, `origin + u`, `origin + u + v`. `None` everywhere else, and for every patch under
    /// the other [`Charts`] modes, whose charts are Lightwire's own.
    pub lightmap: Option<PatchLightmap>,
}

/// Where a triangle (or a parallelogram of them) lies in its mesh's own
/// lightmap (`Patch::lightmap`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PatchLightmap {
    /// Index into [`Scene::uv_meshes`].
    pub mesh: u32,
    /// `TEXCOORD_1` at patch parameters (0, 0), (1, 0) and (1, 1): the
    /// triangle's corners in the order of [`PatchShape::triangle`]'s, or
    /// three of a quad's (the fourth is affine, `uv[0] + uv[2] - uv[1]`).
    pub uv: [Vec2; 3],
}

impl Patch {
    /// The albedo of the part `region = [s0, t0, s1, t1]` of the patch (the
    /// lightmap element there): the material's, times the texture averaged
    /// over the region when the patch has one. `st` is where to look the
    /// texture up when the region holds no surface.
    pub fn region_albedo(&self, material: &Material, region: [f32; 4], st: [f32; 2]) -> Vec3 {
        match &self.albedo_map {
            None => material.albedo,
            Some(map) => {
                let texture = map
                    .region_average(region, self.shape.is_triangle())
                    .unwrap_or_else(|| map.sample(st[0], st[1]));
                material.albedo * texture
            }
        }
    }

    /// The albedo at the point `(s, t)` of the patch.
    pub fn albedo_at(&self, material: &Material, s: f32, t: f32) -> Vec3 {
        match &self.albedo_map {
            None => material.albedo,
            Some(map) => material.albedo * map.sample(s, t),
        }
    }
}

/// The geometry of a patch in object-local space.
///
/// Both shapes are spanned by an `origin` and two edge vectors `u`, `v`, and
/// points on them are written `origin + s u + t v` with patch parameters
/// `(s, t)`: a quad covers the square `s, t ∈ [0, 1]`, a triangle the half of
/// it below the diagonal, `0 <= t <= s <= 1` (the quad's first triangle
/// `origin`, `origin+u`, `origin+u+v`). The atlas charts both over the same
/// square (`atlas.rs`), and a triangle goes over the wire as a quad whose
/// last corner repeats its third (PROTOCOL.md), so a client that draws a quad
/// as the triangles (0, 1, 2) and (0, 2, 3) with the chart's corners as
/// texture coordinates draws a triangle right without knowing it is one.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PatchShape {
    /// Parallelogram with corners `origin`, `origin+u`, `origin+u+v`,
    /// `origin+v`; it faces `u × v`.
    Quad { origin: Vec3, u: Vec3, v: Vec3 },
    /// Triangle with corners `origin`, `origin+u`, `origin+u+v`; it faces
    /// `u × v`. [`PatchShape::triangle`] builds one from three corners with
    /// the largest angle at `origin+u`, so that `u` and `v` are the two
    /// shorter edges and the chart's axes follow them.
    Triangle { origin: Vec3, u: Vec3, v: Vec3 },
}

impl PatchShape {
    /// The triangle with corners `a`, `b`, `c` (counter-clockwise seen from
    /// the front), rotated (winding kept) so that its largest angle, the
    /// corner opposite its longest edge, is the middle corner `p1`:
    /// `origin = p0`, `u = p1 - p0`, `v = p2 - p1`.
    pub fn triangle(a: Vec3, b: Vec3, c: Vec3) -> PatchShape {
        let corners = [a, b, c];
        let [p0, p1, p2] = PatchShape::triangle_order(a, b, c).map(|k| corners[k]);
        PatchShape::Triangle {
            origin: p0,
            u: p1 - p0,
            v: p2 - p1,
        }
    }

    /// Which of `a`, `b`, `c` [`PatchShape::triangle`] makes `p0`, `p1`,
    /// `p2`: a rotation of `[0, 1, 2]` that puts the largest angle in the
    /// middle. Per-vertex data (texture coordinates) follows the same order.
    pub fn triangle_order(a: Vec3, b: Vec3, c: Vec3) -> [usize; 3] {
        let opposite_a = (b - c).length_squared();
        let opposite_b = (c - a).length_squared();
        let opposite_c = (a - b).length_squared();
        if opposite_b >= opposite_a && opposite_b >= opposite_c {
            [0, 1, 2]
        } else if opposite_c >= opposite_a {
            [1, 2, 0]
        } else {
            [2, 0, 1]
        }
    }

    /// Origin and edge vectors: the point at `(s, t)` is `origin + s u + t v`.
    pub fn frame(&self) -> (Vec3, Vec3, Vec3) {
        match *self {
            PatchShape::Quad { origin, u, v } | PatchShape::Triangle { origin, u, v } => {
                (origin, u, v)
            }
        }
    }

    /// Whether this is a triangle.
    pub fn is_triangle(&self) -> bool {
        matches!(self, PatchShape::Triangle { .. })
    }

    /// Whether patch parameters `(s, t)` lie on the shape (edges included).
    pub fn contains(&self, s: f32, t: f32) -> bool {
        let square = (0.0..=1.0).contains(&s) && (0.0..=1.0).contains(&t);
        match self {
            PatchShape::Quad { .. } => square,
            PatchShape::Triangle { .. } => square && t <= s,
        }
    }

    /// Patch parameters of the centroid.
    pub fn centre_param(&self) -> [f32; 2] {
        match self {
            PatchShape::Quad { .. } => [0.5, 0.5],
            PatchShape::Triangle { .. } => [2.0 / 3.0, 1.0 / 3.0],
        }
    }

    /// The centroid.
    pub fn centre(&self) -> Vec3 {
        let (o, u, v) = self.frame();
        let [s, t] = self.centre_param();
        o + u * s + v * t
    }

    /// Unit normal of the front face.
    pub fn normal(&self) -> Vec3 {
        let (_, u, v) = self.frame();
        u.cross(v).normalize()
    }

    /// Area in object-local units.
    pub fn area(&self) -> f32 {
        let (_, u, v) = self.frame();
        match self {
            PatchShape::Quad { .. } => u.cross(v).length(),
            PatchShape::Triangle { .. } => 0.5 * u.cross(v).length(),
        }
    }

    /// Corners in counter-clockwise order seen from the front (four for a
    /// quad, three for a triangle).
    pub fn corners(&self) -> Vec<Vec3> {
        match *self {
            PatchShape::Quad { origin, u, v } => {
                vec![origin, origin + u, origin + u + v, origin + v]
            }
            PatchShape::Triangle { origin, u, v } => vec![origin, origin + u, origin + u + v],
        }
    }

    /// Four corners as a client that draws quads takes them (the wire's
    /// `SurfaceInfo`, `atlas.json`): a quad's, or a triangle's three with
    /// the third repeated, so that the quad's second triangle is empty and
    /// its first, drawn with the chart corners as texture coordinates, is
    /// the triangle.
    pub fn quad_corners(&self) -> [Vec3; 4] {
        let (o, u, v) = self.frame();
        match self {
            PatchShape::Quad { .. } => [o, o + u, o + u + v, o + v],
            PatchShape::Triangle { .. } => [o, o + u, o + u + v, o + u + v],
        }
    }

    /// The same shape moved by `pose`.
    pub fn transformed(&self, pose: &Pose) -> PatchShape {
        let (origin, u, v) = self.frame();
        let (origin, u, v) = (
            pose.transform_point(origin),
            pose.transform_vector(u),
            pose.transform_vector(v),
        );
        match self {
            PatchShape::Quad { .. } => PatchShape::Quad { origin, u, v },
            PatchShape::Triangle { .. } => PatchShape::Triangle { origin, u, v },
        }
    }
}

/// How a mesh's triangles are given charts (`pairs.rs`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Charts {
    /// Every triangle its own patch and square chart, half of it dead
    /// (tests of the triangle paths).
    Triangles,
    /// Two triangles that form a parallelogram share one quad chart.
    Pairs,
    /// Pairs, and then quads of one surface that extend each other into a
    /// larger parallelogram merge, as long as any two do: a tessellated
    /// wall is one chart, as a hand-written quad is.
    Parallelograms,
    /// Parallelograms, except that the static triangles of a mesh are lit
    /// on its lightmap UVs: its own (glTF `TEXCOORD_1`, a scene file's
    /// `lightmap_uvs`), else generated ones (`unwrap.rs`). Its lightmap is
    /// one block of the atlas, each texel an element of every patch it
    /// overlaps (`atlas/uv.rs`), and triangles over which the UVs are
    /// affine merge into parallelograms there too (`pairs.rs`). The
    /// default: an engine puts the streamed light on its own mesh.
    #[default]
    #[serde(rename = "lightmap-uvs")]
    LightmapUvs,
    /// As `lightmap-uvs`, but every static mesh is lit on lightmap UVs
    /// Lightwire generates (`unwrap.rs`: near-planar charts cut by normal,
    /// packed with gaps), its own `TEXCOORD_1` ignored (an asset whose
    /// lightmap UVs overlap or are too coarse).
    Generated,
    /// As `generated`, with the charts of the `uvunwrap` crate
    /// (segmentation, conformal flattening, packing by shape) instead of
    /// Lightwire's own projection: measured against it in BENCHMARKS.md.
    Uvunwrap,
}

impl Charts {
    /// The unwrapper that generates lightmap UVs under these charts.
    pub fn unwrapper(self) -> unwrap::Unwrapper {
        match self {
            Charts::Uvunwrap => unwrap::Unwrapper::Uvunwrap,
            _ => unwrap::Unwrapper::Projected,
        }
    }
}

/// Options applied while loading, for tests and benchmarks that want a
/// coarser or finer version of a scene file.
#[derive(Debug, Clone, Copy)]
pub struct LoadOptions {
    /// Multiplies every texel density (scene-wide and per-surface).
    pub density_scale: f32,
    /// How a mesh's triangles get charts (`--charts`).
    pub charts: Charts,
}

impl LoadOptions {
    /// The defaults with another density scale.
    pub fn scaled(density_scale: f32) -> Self {
        Self {
            density_scale,
            ..Self::default()
        }
    }

    /// Another density scale, and every triangle of a mesh its own patch
    /// and chart, also where two form a parallelogram (tests of the
    /// triangle paths, `--charts triangles`).
    pub fn unpaired(density_scale: f32) -> Self {
        Self {
            density_scale,
            charts: Charts::Triangles,
        }
    }
}

impl Default for LoadOptions {
    fn default() -> Self {
        Self {
            density_scale: 1.0,
            charts: Charts::default(),
        }
    }
}

impl Scene {
    /// Reads, parses and validates a scene file: scene JSON, or a `.glb` /
    /// `.gltf` file on its own (see `validate::scene_from_gltf` for its
    /// defaults).
    pub fn load(path: &Path) -> Result<Scene, SceneError> {
        Self::load_with(path, LoadOptions::default())
    }

    /// [`Scene::load`] with [`LoadOptions`].
    pub fn load_with(path: &Path, options: LoadOptions) -> Result<Scene, SceneError> {
        let extension = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase());
        if matches!(extension.as_deref(), Some("glb" | "gltf")) {
            return validate::scene_from_gltf(path, options).map_err(|issues| {
                SceneError::Invalid {
                    origin: path.display().to_string(),
                    issues,
                }
            });
        }
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
        // A scene file's `imports` are relative to its directory.
        let base = Path::new(origin).parent();
        validate::validate(raw, options, base).map_err(invalid)
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

    /// Whether patches `p` and `q` leave the same light for the same
    /// irradiance: the same albedo and emission, and neither textured (a
    /// texture's albedo varies over its patch). Radiosity is continuous
    /// across an edge only between such patches, so only their texels are
    /// stitched into seams (`atlas.rs`, `atlas/stitch.rs`): a dark sticky
    /// note set into a white frame of the same plane leaves an eighth of
    /// its light, and stitched to the frame it read the frame's.
    pub fn reflects_alike(&self, p: usize, q: usize) -> bool {
        let (Some(a), Some(b)) = (self.patches.get(p), self.patches.get(q)) else {
            return false;
        };
        if a.albedo_map.is_some() || b.albedo_map.is_some() {
            return a.material == b.material;
        }
        a.material == b.material
            || match (
                self.materials.get(a.material as usize),
                self.materials.get(b.material as usize),
            ) {
                (Some(m), Some(n)) => m.albedo == n.albedo && m.emission == n.emission,
                _ => false,
            }
    }

    /// The initial pose of every object, indexed like [`Scene::objects`].
    pub fn initial_poses(&self) -> Vec<Pose> {
        self.objects.iter().map(|o| o.initial_pose).collect()
    }

    /// `lights` (in this scene's frame: each with its object at its
    /// initial pose) placed with their objects at `poses`
    /// ([`Light::placed`]); a light of the static world, or of an object
    /// `poses` has no pose for, stays where it is.
    pub fn lights_at(&self, lights: &[Light], poses: &[Pose]) -> Vec<Light> {
        lights
            .iter()
            .map(|light| {
                let o = light.object as usize;
                match (self.objects.get(o), poses.get(o)) {
                    (Some(object), Some(pose)) if light.object != STATIC_OBJECT => {
                        light.placed(&object.initial_pose, pose)
                    }
                    _ => light.clone(),
                }
            })
            .collect()
    }

    /// Whether any light rides with a dynamic object.
    pub fn has_riding_lights(&self) -> bool {
        self.lights.iter().any(|l| l.object != STATIC_OBJECT)
    }

    /// The same scene with every quad cut into two triangles along its
    /// diagonal from `origin` to `origin + u + v`: patch `name` becomes
    /// `name/0` (frame `origin`, `u`, `v`: the quad's own, so that `(s, t)`
    /// with `t <= s` names the same point on both) and `name/1` (frame
    /// `origin + u + v`, `-u`, `-v`: the quad's point `(s, t)`, `t > s`, is
    /// its `(1 - s, 1 - t)`). On a square chart both triangles' texels are
    /// the quad's. Triangles stay as they are. For tests and benchmarks
    /// that compare a mesh with the quads it came from.
    pub fn triangulated(&self) -> Scene {
        let mut out = self.clone();
        out.patches = self
            .patches
            .iter()
            .flat_map(|p| match p.shape {
                PatchShape::Quad { origin, u, v } => vec![
                    Patch {
                        name: format!("{}/0", p.name),
                        shape: PatchShape::Triangle { origin, u, v },
                        ..p.clone()
                    },
                    Patch {
                        name: format!("{}/1", p.name),
                        shape: PatchShape::Triangle {
                            origin: origin + u + v,
                            u: -u,
                            v: -v,
                        },
                        ..p.clone()
                    },
                ],
                PatchShape::Triangle { .. } => vec![p.clone()],
            })
            .collect();
        out
    }

    /// Per object, whether its patches form a closed surface facing out:
    /// every patch edge (in object space, to 1e-5 of the object's size) is
    /// met by an edge of another of its patches running the other way, and
    /// the enclosed volume is positive (normals point out). A point outside
    /// such an object sees only front faces of it, so whatever the object
    /// hides from that point, a front face hides. A box is closed; a
    /// mesh is closed when it is watertight without T-junctions; a single
    /// quad, an open box or a box facing in are not.
    pub fn closed_objects(&self) -> Vec<bool> {
        (0..self.objects.len() as u32)
            .map(|o| self.is_closed(o))
            .collect()
    }

    /// Whether object `o` is closed, as [`Scene::closed_objects`] says.
    pub fn is_closed(&self, o: u32) -> bool {
        use std::collections::HashMap;
        let shapes: Vec<&PatchShape> = self
            .patches
            .iter()
            .filter(|p| p.object == o)
            .map(|p| &p.shape)
            .collect();
        let corners: Vec<Vec<Vec3>> = shapes.iter().map(|s| s.corners()).collect();
        let size = corners
            .iter()
            .flatten()
            .fold(0.0f32, |m, c| m.max(c.abs().max_element()));
        if corners.is_empty() || size <= 0.0 {
            return false;
        }
        let step = 1e-5 * size;
        let key = |c: Vec3| (c / step).round().as_i64vec3().to_array();
        // Directed edge counts: +1 for a->b, -1 for b->a under the
        // key (smaller corner first).
        let mut edges: HashMap<([i64; 3], [i64; 3]), i32> = HashMap::new();
        let mut volume = 0.0f64;
        for cs in &corners {
            for i in 0..cs.len() {
                let (a, b) = (key(cs[i]), key(cs[(i + 1) % cs.len()]));
                if a == b {
                    return false;
                }
                let (k, d) = if a < b { ((a, b), 1) } else { ((b, a), -1) };
                *edges.entry(k).or_insert(0) += d;
            }
            // Signed volume of the fan from the origin.
            for i in 1..cs.len() - 1 {
                let (a, b, c) = (cs[0].as_dvec3(), cs[i].as_dvec3(), cs[i + 1].as_dvec3());
                volume += a.dot(b.cross(c)) / 6.0;
            }
        }
        edges.values().all(|&n| n == 0) && volume > 0.0
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

#[cfg(test)]
mod tests {
    use super::*;

    fn scene_with(surfaces: &str) -> Scene {
        let text = format!(
            r#"{{ "name": "t", "lightmap": {{ "texel_density": 4 }},
                "materials": [{{ "name": "m", "albedo": [0.5, 0.5, 0.5], "emission": [1, 1, 1] }}],
                "objects": [{{ "name": "o" }}],
                "surfaces": [{surfaces}] }}"#
        );
        Scene::parse(&text, "test.json").expect("a valid scene")
    }

    #[test]
    fn a_box_facing_out_is_closed_and_stays_closed_triangulated() {
        let scene = scene_with(
            r#"{ "name": "b", "material": "m", "object": "o",
                 "box": { "center": [0, 0, 0], "size": [1.6, 1.7, 0.4], "rotation": [0.1, 0.2, 0.3, 0.927] } }"#,
        );
        // The static world (object 0) has no patches.
        assert_eq!(scene.closed_objects(), vec![false, true]);
        assert_eq!(scene.triangulated().closed_objects(), vec![false, true]);
    }

    #[test]
    fn open_or_inward_surfaces_are_not_closed() {
        let inward = scene_with(
            r#"{ "name": "b", "material": "m", "object": "o",
                 "box": { "center": [0, 0, 0], "size": [1, 1, 1], "facing": "in" } }"#,
        );
        assert!(!inward.closed_objects()[1], "a box facing in");
        let mut open = scene_with(
            r#"{ "name": "b", "material": "m", "object": "o",
                 "box": { "center": [0, 0, 0], "size": [1, 1, 1] } }"#,
        );
        open.patches.pop();
        assert!(!open.closed_objects()[1], "a box without a face");
        let quad = scene_with(
            r#"{ "name": "q", "material": "m", "object": "o",
                 "quad": { "origin": [0, 0, 0], "u": [1, 0, 0], "v": [0, 1, 0] } }"#,
        );
        assert!(!quad.closed_objects()[1], "a single quad");
    }

    #[test]
    fn bad_lightmap_uvs_of_a_mesh_are_reported_where_they_are() {
        let problems = |uvs: &str| -> String {
            let text = format!(
                r#"{{ "name": "t", "lightmap": {{ "texel_density": 4 }},
                    "materials": [{{ "name": "m", "albedo": [0.5, 0.5, 0.5], "emission": [1, 1, 1] }}],
                    "surfaces": [{{ "name": "floor", "material": "m", "mesh": {{
                        "positions": [[0, 0, 0], [2, 0, 0], [2, 0, -2], [0, 0, -2]],
                        "indices": [0, 1, 2, 0, 2, 3], "lightmap_uvs": {uvs} }} }}] }}"#
            );
            match Scene::parse(&text, "t.json") {
                Ok(_) => String::new(),
                Err(e) => e.to_string(),
            }
        };
        let fine = problems("[[0, 1], [1, 1], [1, 0], [0, 0]]");
        assert!(fine.is_empty(), "{fine}");
        let count = problems("[[0, 1], [1, 1], [1, 0]]");
        assert!(
            count.contains("surface #0 \"floor\"") && count.contains("3 entries for 4 positions"),
            "{count}"
        );
        let outside = problems("[[0, 1], [1.5, 1], [1, 0], [0, 0]]");
        assert!(
            outside.contains("mesh.lightmap_uvs[1] is [1.5, 1.0]: lightmap UVs must lie in [0, 1]"),
            "{outside}"
        );
        let zero = problems("[[0, 1], [0.5, 0.5], [1, 0], [0, 0]]");
        assert!(
            zero.contains("mesh triangle 0 has zero area in mesh.lightmap_uvs"),
            "{zero}"
        );
        let overlap = problems("[[0, 1], [1, 1], [1, 0], [0.2, 0.9]]");
        assert!(
            overlap.contains("mesh triangle 0 overlaps triangle 1 in mesh.lightmap_uvs"),
            "{overlap}"
        );
    }
}
