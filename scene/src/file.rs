//! The on-disk scene format, exactly as it is written in JSON.
//!
//! These types mirror `scenes/scene.schema.json` one to one. They are only
//! parsed here; [`super::validate`] turns them into a checked
//! [`super::Scene`]. Keeping the two apart means the rest of the server never
//! sees a raw, unchecked number from a file.

use serde::Deserialize;

/// Three numbers: a point, a direction or an RGB triple.
pub type Vec3Json = [f64; 3];
/// A rotation quaternion written as `[x, y, z, w]`.
pub type QuatJson = [f64; 4];

/// A whole scene file.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    /// Editors use this to find the schema; ignored by the loader.
    #[serde(rename = "$schema", default)]
    pub schema: Option<String>,
    /// Short identifier, also used as the scene id on the network.
    pub name: String,
    /// Free text shown in listings.
    #[serde(default)]
    pub description: String,
    /// How densely surfaces are sampled and how large the atlas may grow.
    pub lightmap: LightmapJson,
    /// Named materials referenced by surfaces.
    pub materials: Vec<MaterialJson>,
    /// Named dynamic objects (rigid groups). The static world is implicit.
    #[serde(default)]
    pub objects: Vec<ObjectJson>,
    /// Every surface in the scene (may be empty when `imports` bring them).
    #[serde(default)]
    pub surfaces: Vec<SurfaceJson>,
    /// glTF files whose triangle meshes, materials and dynamic nodes join
    /// the scene.
    #[serde(default)]
    pub imports: Vec<ImportJson>,
    /// Solver settings measured for this scene (see `SolverJson`).
    #[serde(default)]
    pub solver: SolverJson,
    /// Point, spot and directional lights of the static world, besides
    /// emitting surfaces.
    #[serde(default)]
    pub lights: Vec<LightJson>,
    /// Radiance from the directions the scene leaves open.
    #[serde(default)]
    pub sky: Option<SkyJson>,
}

/// A sky: radiance (W/(m² sr) per channel) at the zenith and at the
/// horizon, `+y` up.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SkyJson {
    pub zenith: Vec3Json,
    /// Default: the zenith's (a uniform sky).
    #[serde(default)]
    pub horizon: Option<Vec3Json>,
    /// The albedo of an endless ground below the horizon, each channel in
    /// [0, 1); default black.
    #[serde(default)]
    pub ground_albedo: Option<Vec3Json>,
}

/// A light (KHR_lights_punctual's point, spot and directional, in
/// radiometric units).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightJson {
    pub name: String,
    /// `"point"`, `"spot"` or `"directional"`.
    #[serde(rename = "type")]
    pub kind: String,
    /// Where a point or spot light is, in metres.
    #[serde(default)]
    pub position: Option<Vec3Json>,
    /// Linear colour, each channel >= 0; multiplies `intensity`.
    #[serde(default = "white")]
    pub color: Vec3Json,
    /// Radiant intensity on the axis, W/sr (>= 0); a directional light's
    /// irradiance at normal incidence, W/m².
    pub intensity: f64,
    /// Distance at which the light fades to nothing (glTF's `range`);
    /// absent: the inverse square law alone.
    #[serde(default)]
    pub range: Option<f64>,
    /// A spot's axis, or the direction a directional light's light
    /// travels (any length > 0).
    #[serde(default)]
    pub direction: Option<Vec3Json>,
    /// A directional light's disc, degrees across (default 0: hard
    /// shadows; the sun's is 0.53).
    #[serde(default)]
    pub angular_diameter_deg: Option<f64>,
    /// A spot's full-intensity cone, degrees from the axis (default 0).
    #[serde(default)]
    pub inner_cone_deg: Option<f64>,
    /// A spot's cut-off, degrees from the axis (default 45, at most 90).
    #[serde(default)]
    pub outer_cone_deg: Option<f64>,
    /// The dynamic object the light rides with (its name); absent: the
    /// static world. Its position and direction are given with the
    /// object at its initial pose.
    #[serde(default)]
    pub object: Option<String>,
}

fn white() -> Vec3Json {
    [1.0, 1.0, 1.0]
}

/// Settings of the GPU solver's cross redistribution chosen for this scene
/// by measurement (`lightwire bench dynamic`), each optional: what is left
/// out keeps the solver's default, and the command line overrides either.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SolverJson {
    /// Rays per side of the cross projection's grid on a tile.
    #[serde(default)]
    pub cross_grid: Option<u32>,
    /// Top-face resolution of the back hemicubes of shot radiosity.
    #[serde(default)]
    pub back_resolution: Option<u32>,
    /// Form factor below which a receiver samples a tile through the
    /// coarse grid.
    #[serde(default)]
    pub cross_coarse_below: Option<f64>,
}

/// A glTF 2.0 file (`.glb` or `.gltf`) imported into the scene: every
/// triangle of its meshes becomes a patch; its materials and dynamic nodes
/// join `materials` and `objects` under their glTF names.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImportJson {
    /// Path, relative to the scene file.
    pub file: String,
    /// Import only these nodes (and what is below them); all when empty.
    #[serde(default)]
    pub nodes: Vec<String>,
    /// Nodes that are dynamic objects, besides those marked in their
    /// `extras` (`{"lightwire": {"dynamic": true}}`).
    #[serde(default)]
    pub dynamic_nodes: Vec<String>,
    /// Multiplies every emission (W/m² per unit of `emissiveFactor` x
    /// `KHR_materials_emissive_strength`).
    #[serde(default = "unit_scale")]
    pub emission_scale: f64,
    /// Multiplies every `KHR_lights_punctual` light of the file after its
    /// photometric units become radiometric (683 lm/W).
    #[serde(default = "unit_scale")]
    pub light_scale: f64,
    /// Overrides the scene's texel density for these triangles.
    #[serde(default)]
    pub texel_density: Option<f64>,
    /// Replaces the albedo or emission of imported materials by name
    /// (`"*"`: every material not named): a level whose materials carry
    /// only texture names, or whose lamps are textures, gets its light and
    /// colours here.
    #[serde(default)]
    pub materials: std::collections::BTreeMap<String, MaterialOverrideJson>,
}

/// New values for an imported material; a field left out keeps the
/// glTF's.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialOverrideJson {
    /// Diffuse reflectance per channel, each in [0, 1); replaces the base
    /// colour factor and texture.
    #[serde(default)]
    pub albedo: Option<Vec3Json>,
    /// Self-emitted radiant exitance per channel in W/m², each >= 0 (not
    /// multiplied by `emission_scale`).
    #[serde(default)]
    pub emission: Option<Vec3Json>,
}

/// Lightmap resolution settings for the whole scene.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightmapJson {
    /// Texels per metre along each surface edge.
    pub texel_density: f64,
    /// The atlas may not be wider or taller than this many texels.
    #[serde(default = "default_max_atlas_size")]
    pub max_atlas_size: u32,
    /// Texels across a generated lightmap's distance to its lights (point
    /// and spot lights, emitting triangles), which also turns on finer
    /// texels at a sun's shadow edges (`near_lights.rs`); 0 leaves the
    /// density as given.
    #[serde(default = "default_light_detail")]
    pub light_detail: f64,
}

fn default_light_detail() -> f64 {
    f64::from(crate::near_lights::DEFAULT_DETAIL)
}

fn default_max_atlas_size() -> u32 {
    2048
}

/// A Lambertian material.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialJson {
    pub name: String,
    /// Diffuse reflectance per channel, each in [0, 1).
    pub albedo: Vec3Json,
    /// Self-emitted radiant exitance per channel in W/m², each >= 0.
    #[serde(default)]
    pub emission: Vec3Json,
}

/// A dynamic object: a rigid group of surfaces moved by one pose.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObjectJson {
    pub name: String,
    /// The pose the object starts in.
    #[serde(default)]
    pub pose: PoseJson,
}

/// Translation, rotation and uniform scale, applied as scale, then rotate,
/// then translate.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoseJson {
    #[serde(default)]
    pub translation: Vec3Json,
    #[serde(default = "identity_quat")]
    pub rotation: QuatJson,
    #[serde(default = "unit_scale")]
    pub scale: f64,
}

impl Default for PoseJson {
    fn default() -> Self {
        Self {
            translation: [0.0; 3],
            rotation: identity_quat(),
            scale: 1.0,
        }
    }
}

fn identity_quat() -> QuatJson {
    [0.0, 0.0, 0.0, 1.0]
}

fn unit_scale() -> f64 {
    1.0
}

/// One surface entry. Exactly one geometry key (`quad`, `box` or `mesh`) is
/// present.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SurfaceJson {
    pub name: String,
    /// Name of the material.
    pub material: String,
    /// Name of the dynamic object this surface belongs to; absent for the
    /// static world. Geometry of a dynamic surface is in object-local space.
    #[serde(default)]
    pub object: Option<String>,
    /// Overrides the scene's texel density for this surface.
    #[serde(default)]
    pub texel_density: Option<f64>,
    /// A parallelogram. Exactly one of `quad` and `box` must be given.
    #[serde(default)]
    pub quad: Option<QuadJson>,
    /// An oriented box expanded into six quads.
    #[serde(default, rename = "box")]
    pub box_: Option<BoxJson>,
    /// A triangle mesh; every triangle becomes a patch with its own chart.
    #[serde(default)]
    pub mesh: Option<MeshJson>,
}

/// A triangle mesh written inline: corner positions and, three per
/// triangle, indices into them (counter-clockwise seen from the front).
/// Without `indices`, every three positions are a triangle.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeshJson {
    pub positions: Vec<Vec3Json>,
    #[serde(default)]
    pub indices: Option<Vec<u32>>,
    /// Lightmap UVs, one `[u, v]` per position (as glTF's `TEXCOORD_1`).
    #[serde(default)]
    pub lightmap_uvs: Option<Vec<[f32; 2]>>,
}

/// A parallelogram, written either as `origin` plus edges `u` and `v`
/// (corners origin, origin+u, origin+u+v, origin+v; the front face is the
/// side `u × v` points to) or as four `corners` in counter-clockwise order
/// seen from the front, which must form a planar parallelogram.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct QuadJson {
    #[serde(default)]
    pub origin: Option<Vec3Json>,
    #[serde(default)]
    pub u: Option<Vec3Json>,
    #[serde(default)]
    pub v: Option<Vec3Json>,
    #[serde(default)]
    pub corners: Option<[Vec3Json; 4]>,
}

/// An oriented box, expanded into six quads.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoxJson {
    pub center: Vec3Json,
    /// Full extent along the box's local x, y and z axes.
    pub size: Vec3Json,
    #[serde(default = "identity_quat")]
    pub rotation: QuatJson,
    /// `out` for a solid box, `in` for a room seen from inside.
    #[serde(default)]
    pub facing: Facing,
}

/// Which way the faces of a box point.
#[derive(Debug, Default, Deserialize, Clone, Copy, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Facing {
    #[default]
    Out,
    In,
}
