//! glTF 2.0 input: triangle meshes, their materials and which nodes move.
//!
//! This is the layer below the scene: it reads a `.glb` or `.gltf` (with its
//! `.bin` buffers) and returns an [`ImportedScene`] of triangle lists, one per
//! mesh primitive instanced by a node, with materials converted to Lightwire's
//! units. It does not build a [`super::Scene`]: the atlas and the solvers do
//! not take triangles yet (Wallner §2 is the plan: per-triangle charts packed
//! into an atlas).
//!
//! Conventions (also in `scenes/README.md`, "glTF input"):
//!
//! - **Units.** glTF lengths are metres and y is up, as in Lightwire scenes.
//! - **Space.** Every instance belongs to an object of
//!   [`ImportedScene::objects`]; its positions are in that object's space.
//!   Object 0 is the static world, whose space is world space (node
//!   transforms, parents included, applied). A dynamic object is rooted at a
//!   node; its [`Pose`] is the rigid part (rotation and translation) of that
//!   node's world transform, and its instances keep everything else
//!   (the node's scale and the transforms of its descendants) in their
//!   positions, so that `pose.transform_point(p)` is the world position and a
//!   later stage can move the object by replacing the pose.
//! - **Winding.** Front faces are counter-clockwise (glTF §3.7.2.1); a node
//!   whose transform mirrors (negative determinant) has its triangles'
//!   winding flipped so the front faces stay front faces after transforming.
//! - **Materials.** `baseColorFactor` RGB is the albedo, clamped to
//!   [`ALBEDO_MAX`] with a warning; emission in W/m² per channel is
//!   `emissiveFactor × KHR_materials_emissive_strength ×`
//!   [`ImportOptions::emission_scale`]. The base colour texture is decoded
//!   ([`ImportedMaterial::texture`], PNG or JPEG, embedded, a data URI or a
//!   file beside the glTF) and multiplies the factor per lightmap texel
//!   (`scene/texture.rs`).
//!   A material whose `extras` hold `{"lightwire": {"albedo": [r, g, b],
//!   "emission": [r, g, b]}}` (a baked `scene.glb`, see [`write`]) takes
//!   its albedo and emission from there, and its base colour texture,
//!   which is the baked light, is not referenced.
//! - **Lightmap UVs.** `TEXCOORD_1`, when present, is validated per mesh: the
//!   primitives of one mesh share one lightmap space [0, 1]² (as Bevy, three.js
//!   and Godot use the second UV set), so no two of its triangles may
//!   overlap; two meshes, or two nodes instancing one mesh, get separate
//!   lightmaps.
//!
//! Errors are collected, not returned at the first one: a file with several
//! problems reports them all, each naming the node, mesh and primitive (index
//! and name), like the JSON validator does.

mod accessor;
pub mod content;
mod overlap;
pub mod write;

use std::collections::{BTreeMap, HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::{Mat3, Mat4, Vec2, Vec3};

use super::texture::{Filter, Texture, Wrap};
use super::{Pose, SceneError, SceneIssue};

pub use overlap::{UvOverlap, find_uv_overlaps};
pub(crate) use overlap::{intersection_area, signed_area};

/// Albedo channels above this are clamped (with a warning): a surface that
/// reflects everything makes the radiosity system singular in a closed room.
pub const ALBEDO_MAX: f32 = 0.99;

/// A `TEXCOORD_1` coordinate may lie this far outside [0, 1] (f32 rounding in
/// exporters) before it is an error.
pub const UV_RANGE_SLACK: f32 = 1e-6;

/// A triangle is degenerate when twice its area, `|e1 × e2|`, is at most this
/// times its longest edge squared: its corners lie on a line to within f32
/// precision (repeated indices included).
pub const DEGENERATE_RATIO: f32 = 1e-6;

/// Two `TEXCOORD_1` triangles overlap when their intersection is larger than
/// the smaller of this area (one texel of a 4096 × 4096 lightmap, in UV units)
/// and [`OVERLAP_RELATIVE`] × the smaller triangle's UV area.
pub const OVERLAP_AREA: f64 = 1.0 / (4096.0 * 4096.0);

/// See [`OVERLAP_AREA`].
pub const OVERLAP_RELATIVE: f64 = 0.25;

/// Whether a triangle's corners lie on a line to within f32 precision:
/// twice its area at most [`DEGENERATE_RATIO`] times its longest edge
/// squared (repeated corners and NaN included).
pub fn is_degenerate(a: Vec3, b: Vec3, c: Vec3) -> bool {
    let twice_area = (b - a).cross(c - a).length();
    let longest = (b - a)
        .length_squared()
        .max((c - b).length_squared())
        .max((a - c).length_squared());
    twice_area.is_nan() || twice_area <= DEGENERATE_RATIO * longest
}

/// Problems of one kind reported per primitive before the rest are counted
/// in one line.
const MAX_LISTED: usize = 8;

/// What to import and how.
#[derive(Debug, Clone)]
pub struct ImportOptions {
    /// Import only these nodes (by name) and their descendants; empty means
    /// every node of the glTF's scene.
    pub nodes: Vec<String>,
    /// Nodes (by name) that are dynamic objects, in addition to those whose
    /// `extras` hold `{"lightwire": {"dynamic": true}}`.
    pub dynamic_nodes: Vec<String>,
    /// Multiplies every emission (W/m² per unit of
    /// `emissiveFactor × emissive_strength`).
    pub emission_scale: f32,
    /// New values for materials by name (`"*"`: every material not named),
    /// applied before anything else reads them.
    pub materials: BTreeMap<String, MaterialOverride>,
    /// Multiplies every `KHR_lights_punctual` light after its photometric
    /// units become radiometric ([`LUMENS_PER_WATT`]).
    pub light_scale: f32,
}

impl Default for ImportOptions {
    fn default() -> Self {
        Self {
            nodes: Vec::new(),
            dynamic_nodes: Vec::new(),
            emission_scale: 1.0,
            materials: BTreeMap::new(),
            light_scale: 1.0,
        }
    }
}

/// Lumens per watt at which glTF's photometric light units become
/// Lightwire's radiometric ones, as physically based engines read them:
/// 683 cd is 1 W/sr, 683 lux is 1 W/m².
pub const LUMENS_PER_WATT: f32 = 683.0;

/// A material's albedo or emission as the importing scene wants them; a
/// `None` keeps the glTF's.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct MaterialOverride {
    /// Replaces the base colour factor and texture (each channel in [0, 1)).
    pub albedo: Option<Vec3>,
    /// Replaces the emission, in W/m² (not multiplied by `emission_scale`).
    pub emission: Option<Vec3>,
}

/// The triangle meshes of a glTF file, in Lightwire's units.
#[derive(Debug, Clone)]
pub struct ImportedScene {
    /// Materials, indexed like the glTF's; a primitive without a material gets
    /// an extra `default` material (glTF's default: white, no emission) at the
    /// end.
    pub materials: Vec<ImportedMaterial>,
    /// Index 0 is the static world (identity pose); the rest are dynamic.
    pub objects: Vec<ImportedObject>,
    /// One per (node, mesh primitive), in depth-first node order.
    pub instances: Vec<MeshInstance>,
    /// The nodes' `KHR_lights_punctual` lights, in world space and
    /// radiometric units, named after their nodes; `object` is the
    /// index into `objects` of the dynamic node a light sits under.
    pub lights: Vec<crate::Light>,
    /// The sky a file Lightwire exported keeps in its asset's `extras`.
    pub sky: Option<crate::Sky>,
    /// What the import dropped or changed and went on (zero-area and
    /// duplicate triangles, clamped albedos): one entry per kind, counts per
    /// primitive. Loading succeeds with these; `lightwire validate` prints
    /// them.
    pub warnings: Vec<SceneIssue>,
}

impl ImportedScene {
    /// Triangles over all instances.
    pub fn triangle_count(&self) -> usize {
        self.instances.iter().map(|i| i.indices.len()).sum()
    }

    /// Instances created by the node called `name`.
    pub fn instances_of<'a>(&'a self, name: &'a str) -> impl Iterator<Item = &'a MeshInstance> {
        self.instances
            .iter()
            .filter(move |i| i.node_name.as_deref() == Some(name))
    }

    /// Looks up a material by name.
    pub fn material(&self, name: &str) -> Option<&ImportedMaterial> {
        self.materials.iter().find(|m| m.name == name)
    }
}

/// A Lambertian material converted from glTF's metallic-roughness one.
#[derive(Debug, Clone, PartialEq)]
pub struct ImportedMaterial {
    /// The glTF name, or `material #i` when it has none.
    pub name: String,
    /// `baseColorFactor` RGB (linear), clamped to [0, [`ALBEDO_MAX`]].
    pub albedo: Vec3,
    /// Radiant exitance in W/m² per channel.
    pub emission: Vec3,
    /// Where the base colour texture is.
    pub base_color_texture: Option<TextureRef>,
    /// The base colour texture, decoded to linear RGB with its sampler's
    /// wrapping and filter; the albedo is `albedo ×` the texture.
    pub texture: Option<Arc<Texture>>,
}

/// A reference to an image, not decoded.
#[derive(Debug, Clone, PartialEq)]
pub struct TextureRef {
    /// glTF image index.
    pub image: usize,
    /// Which `TEXCOORD_n` set samples it.
    pub tex_coord: u32,
    /// Where the encoded image is.
    pub source: ImageSource,
}

/// Where an image's bytes are.
#[derive(Debug, Clone, PartialEq)]
pub enum ImageSource {
    /// Embedded in a buffer (always so in the files Lightwire writes).
    Embedded { mime_type: String, bytes: Vec<u8> },
    /// A URI relative to the glTF file, or a data URI.
    Uri { uri: String },
}

/// The static world or a dynamic node and everything below it.
#[derive(Debug, Clone, PartialEq)]
pub struct ImportedObject {
    /// `static` for object 0, else the node's name.
    pub name: String,
    /// The glTF node the object is rooted at (`None` for the static world).
    pub node: Option<usize>,
    /// Rigid part of the root node's world transform (scale 1).
    pub pose: Pose,
}

/// One mesh primitive as instanced by one node.
#[derive(Debug, Clone)]
pub struct MeshInstance {
    pub node: usize,
    pub node_name: Option<String>,
    pub mesh: usize,
    pub mesh_name: Option<String>,
    pub primitive: usize,
    /// Index into [`ImportedScene::objects`].
    pub object: u32,
    /// Index into [`ImportedScene::materials`].
    pub material: u32,
    /// Positions in the object's space (see the module doc).
    pub positions: Vec<Vec3>,
    /// Unit normals in the object's space, when the primitive has `NORMAL`.
    pub normals: Option<Vec<Vec3>>,
    /// Counter-clockwise triangles (front face) into `positions`.
    pub indices: Vec<[u32; 3]>,
    /// Each triangle's number in the glTF primitive (patch names use it):
    /// the importer drops zero-area and duplicate triangles, so the `k`-th
    /// triangle kept is not always the glTF's `k`-th.
    pub triangle_numbers: Vec<u32>,
    /// `TEXCOORD_0`, for textures.
    pub uv0: Option<Vec<Vec2>>,
    /// `TEXCOORD_1`, the lightmap UVs, validated to lie in [0, 1] and not
    /// overlap within the mesh.
    pub lightmap_uvs: Option<Vec<Vec2>>,
}

impl MeshInstance {
    /// The texture coordinate set `TEXCOORD_<set>`, if read (sets 0 and 1).
    pub fn uvs(&self, set: u32) -> Option<&[Vec2]> {
        match set {
            0 => self.uv0.as_deref(),
            1 => self.lightmap_uvs.as_deref(),
            _ => None,
        }
    }
}

/// The name of the static world object.
pub const STATIC_NAME: &str = "static";

/// Reads, checks and converts a `.glb` or `.gltf` file.
pub fn import(path: &Path, options: &ImportOptions) -> Result<ImportedScene, SceneError> {
    let bytes = std::fs::read(path).map_err(|e| SceneError::Io {
        path: path.display().to_string(),
        message: e.to_string(),
    })?;
    import_slice(&bytes, path.parent(), &path.display().to_string(), options)
}

/// [`import`] from bytes; `base` resolves relative buffer and image URIs
/// (`None`: only embedded and data URIs), `origin` names the source in errors.
pub fn import_slice(
    bytes: &[u8],
    base: Option<&Path>,
    origin: &str,
    options: &ImportOptions,
) -> Result<ImportedScene, SceneError> {
    let invalid = |issues: Vec<SceneIssue>| SceneError::Invalid {
        origin: origin.to_string(),
        issues,
    };
    let one = |location: &str, problem: String| {
        invalid(vec![SceneIssue {
            location: location.to_string(),
            problem,
        }])
    };
    let gltf = match ::gltf::Gltf::from_slice(bytes) {
        Ok(g) => g,
        Err(::gltf::Error::Deserialize(e)) => {
            return Err(SceneError::Syntax {
                origin: origin.to_string(),
                line: e.line(),
                column: e.column(),
                message: super::strip_position(&e.to_string()),
            });
        }
        Err(::gltf::Error::Validation(errors)) => {
            return Err(invalid(
                errors
                    .into_iter()
                    .map(|(path, error)| SceneIssue {
                        location: path.to_string(),
                        problem: error.to_string(),
                    })
                    .collect(),
            ));
        }
        Err(::gltf::Error::Binary(e)) => {
            return Err(one("glb container", e.to_string()));
        }
        Err(e) => return Err(one("file", e.to_string())),
    };
    let mut importer = Importer {
        options,
        base: base.map(Path::to_path_buf),
        issues: Vec::new(),
        buffers: Vec::new(),
        primitives: HashMap::new(),
        uv_checked: HashMap::new(),
        dropped: BTreeMap::new(),
        clamped: Vec::new(),
    };
    importer.load_buffers(&gltf, base);
    let mut scene = importer.convert(&gltf.document);
    scene.sky = asset_sky(&gltf.document);
    scene.warnings = importer.take_warnings();
    if importer.issues.is_empty() {
        Ok(scene)
    } else {
        Err(invalid(importer.issues))
    }
}

/// The sky a file Lightwire exported keeps in its asset's `extras`
/// (`{"lightwire": {"sky": {"zenith": [r, g, b], "horizon": [r, g, b],
/// "ground_albedo": [r, g, b]}}}`,
/// W/(m² sr)); glTF has no sky of its own. None without one, or where the
/// numbers are not finite and >= 0.
fn asset_sky(document: &::gltf::Document) -> Option<crate::Sky> {
    let raw = document.as_json().asset.extras.as_ref()?;
    let value: serde_json::Value = serde_json::from_str(raw.get()).ok()?;
    let sky = &value["lightwire"]["sky"];
    let rgb = |key: &str| -> Option<Vec3> {
        let a = sky[key].as_array()?;
        let v: Vec<f32> = a
            .iter()
            .filter_map(|x| x.as_f64().map(|x| x as f32))
            .collect();
        (v.len() == 3 && v.iter().all(|x| x.is_finite() && *x >= 0.0))
            .then(|| Vec3::new(v[0], v[1], v[2]))
    };
    let zenith = rgb("zenith")?;
    let sky = crate::Sky::new(zenith, rgb("horizon").unwrap_or(zenith));
    // The ground's albedo; its radiance follows from the lights, which the
    // scene built from this file sets (`Sky::with_ground`).
    Some(crate::Sky {
        ground_albedo: rgb("ground_albedo")
            .filter(|a| a.max_element() < 1.0)
            .unwrap_or(Vec3::ZERO),
        ..sky
    })
}

/// A primitive's data in mesh space, read and checked once however many
/// nodes instance it.
#[derive(Debug, Clone)]
struct PrimitiveData {
    positions: Vec<Vec3>,
    normals: Option<Vec<Vec3>>,
    indices: Vec<[u32; 3]>,
    /// Each kept triangle's number in the glTF primitive.
    triangle_numbers: Vec<u32>,
    uv0: Option<Vec<Vec2>>,
    uv1: Option<Vec<Vec2>>,
    material: Option<usize>,
}

struct Importer<'o> {
    options: &'o ImportOptions,
    /// Where relative URIs point.
    base: Option<PathBuf>,
    issues: Vec<SceneIssue>,
    /// Loaded buffers; `None` where loading failed (already reported).
    buffers: Vec<Option<Vec<u8>>>,
    /// (mesh, primitive) → data, `None` when it had problems.
    primitives: HashMap<(usize, usize), Option<PrimitiveData>>,
    /// Meshes whose lightmap UVs were checked for overlaps.
    uv_checked: HashMap<usize, ()>,
    /// Triangles dropped per primitive (location → counts).
    dropped: BTreeMap<String, Dropped>,
    /// Materials whose base colour was clamped to [`ALBEDO_MAX`].
    clamped: Vec<String>,
}

/// Triangles one primitive lost at import.
#[derive(Debug, Clone, Copy, Default)]
struct Dropped {
    /// Zero-area or sliver: the corners on a line ([`DEGENERATE_RATIO`]).
    degenerate: usize,
    /// The same three corners as an earlier triangle of the primitive, in
    /// the same turning order: it would z-fight with it and count its light
    /// twice.
    duplicate: usize,
    /// The primitive's triangles before dropping.
    of: usize,
}

/// What [`Importer::convert`] gathers while it walks the node hierarchy.
struct Gathered {
    materials: Vec<ImportedMaterial>,
    /// The index the default material gets, after the glTF's.
    default_material: usize,
    /// Whether a primitive without a material uses the default one.
    used_default: bool,
    objects: Vec<ImportedObject>,
    instances: Vec<MeshInstance>,
    lights: Vec<crate::Light>,
}

impl Gathered {
    /// The imported scene, with the default material at the end when a
    /// primitive uses it.
    fn into_scene(self) -> ImportedScene {
        let Gathered {
            mut materials,
            used_default,
            objects,
            instances,
            lights,
            ..
        } = self;
        if used_default {
            materials.push(ImportedMaterial {
                name: "default".to_string(),
                albedo: Vec3::splat(ALBEDO_MAX),
                emission: Vec3::ZERO,
                base_color_texture: None,
                texture: None,
            });
        }
        ImportedScene {
            materials,
            objects,
            instances,
            lights,
            sky: None,
            warnings: Vec::new(),
        }
    }
}

/// A primitive's accessors as read, not yet checked against each other.
struct Accessors {
    positions: Vec<Vec3>,
    normals: Option<Vec<Vec3>>,
    uv0: Option<Vec<Vec2>>,
    uv1: Option<Vec<Vec2>>,
    /// Three indices per triangle (the vertices in order when the
    /// primitive is not indexed).
    flat: Vec<u32>,
}

fn named(kind: &str, index: usize, name: Option<&str>) -> String {
    match name {
        Some(n) => format!("{kind} #{index} \"{n}\""),
        None => format!("{kind} #{index}"),
    }
}

/// Where a primitive is, for messages: `node #2 "floor", mesh #0 "slab", primitive #1`.
fn primitive_location(node: &::gltf::Node, mesh: &::gltf::Mesh, primitive: usize) -> String {
    format!(
        "{}, {}, primitive #{primitive}",
        named("node", node.index(), node.name()),
        named("mesh", mesh.index(), mesh.name())
    )
}

impl Importer<'_> {
    fn report(&mut self, location: &str, problem: impl Into<String>) {
        self.issues.push(SceneIssue {
            location: location.to_string(),
            problem: problem.into(),
        });
    }

    fn load_buffers(&mut self, gltf: &::gltf::Gltf, base: Option<&Path>) {
        let mut blob = gltf.blob.clone();
        for buffer in gltf.document.buffers() {
            let location = named("buffer", buffer.index(), buffer.name());
            let source = buffer.source();
            let described = match source {
                ::gltf::buffer::Source::Bin => "the GLB binary chunk".to_string(),
                ::gltf::buffer::Source::Uri(uri) if uri.starts_with("data:") => {
                    "a data URI".to_string()
                }
                ::gltf::buffer::Source::Uri(uri) => match base {
                    Some(b) => format!("\"{uri}\" ({})", b.join(uri).display()),
                    None => format!("\"{uri}\""),
                },
            };
            match ::gltf::buffer::Data::from_source_and_blob(source, base, &mut blob) {
                Ok(data) if data.len() < buffer.length() => {
                    self.report(
                        &location,
                        format!(
                            "{described} holds {} bytes but the buffer declares byteLength {}",
                            data.len(),
                            buffer.length()
                        ),
                    );
                    self.buffers.push(None);
                }
                Ok(data) => self.buffers.push(Some(data.0)),
                Err(e) => {
                    self.report(&location, format!("cannot load {described}: {e}"));
                    self.buffers.push(None);
                }
            }
        }
    }

    fn convert(&mut self, doc: &::gltf::Document) -> ImportedScene {
        let materials: Vec<ImportedMaterial> = doc.materials().map(|m| self.material(&m)).collect();

        let Some(scene) = doc.default_scene().or_else(|| doc.scenes().next()) else {
            self.report("file", "has no scene (no node is placed in the world)");
            return ImportedScene {
                materials,
                objects: Vec::new(),
                instances: Vec::new(),
                lights: Vec::new(),
                sky: None,
                warnings: Vec::new(),
            };
        };
        self.check_option_names(doc);

        let mut gathered = Gathered {
            default_material: materials.len(),
            used_default: false,
            materials,
            objects: vec![ImportedObject {
                name: STATIC_NAME.to_string(),
                node: None,
                pose: Pose::IDENTITY,
            }],
            instances: Vec::new(),
            lights: Vec::new(),
        };
        self.walk_nodes(doc, &scene, &mut gathered);
        gathered.into_scene()
    }

    /// Reports node names in the options that no node has.
    fn check_option_names(&mut self, doc: &::gltf::Document) {
        // Names the options refer to must exist.
        let names: HashMap<&str, usize> = doc
            .nodes()
            .filter_map(|n| n.name().map(|s| (s, n.index())))
            .collect();
        for (what, list) in [
            ("nodes", &self.options.nodes),
            ("dynamic_nodes", &self.options.dynamic_nodes),
        ] {
            for name in list {
                if !names.contains_key(name.as_str()) {
                    self.issues.push(SceneIssue {
                        location: format!("import options, {what}"),
                        problem: format!("no node is called \"{name}\""),
                    });
                }
            }
        }
    }

    /// Walks the node hierarchy of `scene` depth-first: makes the dynamic
    /// objects and instances the meshes of the selected nodes. Reports a
    /// node reached twice or whose world transform is not finite, and
    /// leaves it and its descendants out.
    fn walk_nodes(
        &mut self,
        doc: &::gltf::Document,
        scene: &::gltf::Scene,
        gathered: &mut Gathered,
    ) {
        // Depth-first with an explicit stack: (node, parent world transform,
        // selected, the object and its world-from-object inverse).
        struct Frame<'a> {
            node: ::gltf::Node<'a>,
            parent: Mat4,
            selected: bool,
            object: u32,
            object_from_world: Mat4,
        }
        let roots: Vec<::gltf::Node> = scene.nodes().collect();
        let mut stack: Vec<Frame> = roots
            .into_iter()
            .rev()
            .map(|node| Frame {
                node,
                parent: Mat4::IDENTITY,
                selected: self.options.nodes.is_empty(),
                object: 0,
                object_from_world: Mat4::IDENTITY,
            })
            .collect();
        let mut visited = vec![false; doc.nodes().len()];
        while let Some(frame) = stack.pop() {
            let node = frame.node;
            let location = named("node", node.index(), node.name());
            if std::mem::replace(&mut visited[node.index()], true) {
                self.report(&location, "is reached twice in the node hierarchy");
                continue;
            }
            let local = Mat4::from_cols_array_2d(&node.transform().matrix());
            let world = frame.parent * local;
            if !world.is_finite() {
                self.report(&location, "its world transform has a NaN or infinite entry");
                continue;
            }
            let selected = frame.selected
                || node
                    .name()
                    .is_some_and(|n| self.options.nodes.iter().any(|s| s == n));
            let mut object = frame.object;
            let mut object_from_world = frame.object_from_world;
            if selected && self.is_dynamic(&node) {
                let made =
                    self.dynamic_object(&node, &location, world, object, &mut gathered.objects);
                if let Some(made) = made {
                    (object, object_from_world) = made;
                }
            }

            if selected {
                if let Some(mesh) = node.mesh() {
                    let to_object = object_from_world * world;
                    self.instance_mesh(&node, &mesh, &location, to_object, object, gathered);
                }
                if let Some(light) = node.light() {
                    self.light(&node, &light, &location, world, object, gathered);
                }
            }
            for child in node.children().collect::<Vec<_>>().into_iter().rev() {
                stack.push(Frame {
                    node: child,
                    parent: world,
                    selected,
                    object,
                    object_from_world,
                });
            }
        }
    }

    /// A node's `KHR_lights_punctual` light at its world transform `world`
    /// (a glTF light shines along its node's `-z`), in radiometric units
    /// times the import's `light_scale`, riding with `object` (a light
    /// under a dynamic node moves with it); one whose numbers are not
    /// finite or negative is reported.
    fn light(
        &mut self,
        node: &::gltf::Node,
        light: &::gltf::khr_lights_punctual::Light,
        location: &str,
        world: Mat4,
        object: u32,
        gathered: &mut Gathered,
    ) {
        use ::gltf::khr_lights_punctual::Kind;
        let scale = self.options.light_scale / LUMENS_PER_WATT;
        let color = Vec3::from_array(light.color());
        let intensity = color * light.intensity() * scale;
        let position = world.transform_point3(Vec3::ZERO);
        let direction = world.transform_vector3(Vec3::NEG_Z).normalize_or_zero();
        let range = light.range();
        if !intensity.is_finite()
            || intensity.min_element() < 0.0
            || !position.is_finite()
            || range.is_some_and(|r| !(r.is_finite() && r > 0.0))
        {
            self.report(
                location,
                format!(
                    "light {}: colour {color}, intensity {} or range {range:?} is not a finite number >= 0 (a range > 0)",
                    light.index(),
                    light.intensity()
                ),
            );
            return;
        }
        if direction == Vec3::ZERO && !matches!(light.kind(), Kind::Point) {
            self.report(
                location,
                "its light has no direction (a degenerate transform)",
            );
            return;
        }
        let kind = match light.kind() {
            Kind::Point => crate::LightKind::Point,
            Kind::Directional => crate::LightKind::Directional {
                direction,
                // glTF has no field for it; Lightwire's export keeps it
                // in the light's extras (`write::light_node`).
                angular_radius: light
                    .extras()
                    .as_ref()
                    .and_then(|raw| serde_json::from_str::<serde_json::Value>(raw.get()).ok())
                    .and_then(|v| v["lightwire"]["angular_radius"].as_f64())
                    .map_or(0.0, |r| {
                        (r as f32).clamp(
                            0.0,
                            (crate::validate::lights::MAX_ANGULAR_DIAMETER_DEG / 2.0).to_radians(),
                        )
                    }),
            },
            Kind::Spot {
                inner_cone_angle,
                outer_cone_angle,
            } => {
                let outer = outer_cone_angle.clamp(1e-4, std::f32::consts::FRAC_PI_2);
                crate::LightKind::Spot {
                    direction,
                    inner: inner_cone_angle.clamp(0.0, outer * 0.999),
                    outer,
                }
            }
        };
        gathered.lights.push(crate::Light {
            name: node
                .name()
                .map_or_else(|| format!("node#{}", node.index()), str::to_string),
            kind,
            position: if matches!(kind, crate::LightKind::Directional { .. }) {
                Vec3::ZERO
            } else {
                position
            },
            intensity,
            range: if matches!(kind, crate::LightKind::Directional { .. }) {
                None
            } else {
                range
            },
            object,
        });
    }

    /// Makes a node marked dynamic, with world transform `world`, a dynamic
    /// object of its own, posed by the rigid part of `world`. Returns the
    /// new object and its object-from-world transform; none (and a report)
    /// when the node lies inside the dynamic object `outer` (not the static
    /// world, 0) or has no name.
    fn dynamic_object(
        &mut self,
        node: &::gltf::Node,
        location: &str,
        world: Mat4,
        outer: u32,
        objects: &mut Vec<ImportedObject>,
    ) -> Option<(u32, Mat4)> {
        if outer != 0 {
            let outer = objects[outer as usize].name.clone();
            self.report(
                location,
                format!(
                    "is marked dynamic inside dynamic object \"{outer}\"; nested dynamic objects are not supported"
                ),
            );
            None
        } else if let Some(name) = node.name() {
            if objects.iter().any(|o| o.name == name) {
                self.report(
                    location,
                    format!("another dynamic object is also called \"{name}\""),
                );
            } else if name == STATIC_NAME {
                self.report(
                    location,
                    format!("\"{STATIC_NAME}\" is reserved for the static world"),
                );
            }
            let (_, rotation, translation) = world.to_scale_rotation_translation();
            let rotation = rotation.normalize();
            if !rotation.is_finite() || !translation.is_finite() {
                self.report(
                    location,
                    "its world transform has no rotation (it is singular), so it cannot be a dynamic object's pose",
                );
            }
            let pose = Pose {
                translation,
                rotation,
                scale: 1.0,
            };
            let object = objects.len() as u32;
            let object_from_world =
                Mat4::from_rotation_translation(rotation, translation).inverse();
            objects.push(ImportedObject {
                name: name.to_string(),
                node: Some(node.index()),
                pose,
            });
            Some((object, object_from_world))
        } else {
            self.report(
                location,
                "is marked dynamic but has no name; dynamic objects are driven by name",
            );
            None
        }
    }

    /// Instances each primitive of a node's mesh in `object`, whose space
    /// the node's transform `to_object` maps to, and checks the mesh's
    /// lightmap UVs. Reports a transform that flattens the mesh.
    fn instance_mesh(
        &mut self,
        node: &::gltf::Node,
        mesh: &::gltf::Mesh,
        location: &str,
        to_object: Mat4,
        object: u32,
        gathered: &mut Gathered,
    ) {
        let det = Mat3::from_mat4(to_object).determinant();
        if det.abs() <= f32::MIN_POSITIVE || !det.is_finite() {
            self.report(
                location,
                format!(
                    "its transform is singular (determinant {det:e}): it flattens mesh #{} to zero area",
                    mesh.index()
                ),
            );
            return;
        }
        for primitive in mesh.primitives() {
            let Some(data) = self.primitive(node, mesh, &primitive) else {
                continue;
            };
            if data.indices.is_empty() {
                // Every triangle was dropped (counted in the warnings).
                continue;
            }
            let material = match data.material {
                Some(m) => m as u32,
                None => {
                    gathered.used_default = true;
                    gathered.default_material as u32
                }
            };
            let instance = self.instance(
                node, mesh, &primitive, data, to_object, det, object, material,
            );
            if let Some(instance) = instance {
                self.check_texture_uvs(node, mesh, &primitive, &gathered.materials, &instance);
                gathered.instances.push(instance);
            }
        }
        self.check_mesh_uvs(node, mesh);
    }

    fn is_dynamic(&mut self, node: &::gltf::Node) -> bool {
        let by_option = node
            .name()
            .is_some_and(|n| self.options.dynamic_nodes.iter().any(|d| d == n));
        let Some(raw) = node.extras() else {
            return by_option;
        };
        let location = named("node", node.index(), node.name());
        let value: serde_json::Value = match serde_json::from_str(raw.get()) {
            Ok(v) => v,
            Err(e) => {
                self.report(&location, format!("extras are not valid JSON: {e}"));
                return by_option;
            }
        };
        match value.get("lightwire").map(|l| l.get("dynamic")) {
            None | Some(None) => by_option,
            Some(Some(serde_json::Value::Bool(b))) => by_option || *b,
            Some(Some(other)) => {
                self.report(
                    &location,
                    format!("extras.lightwire.dynamic = {other} must be true or false"),
                );
                by_option
            }
        }
    }

    fn material(&mut self, m: &::gltf::Material) -> ImportedMaterial {
        let index = m.index().unwrap_or(0);
        let name = m
            .name()
            .map(str::to_string)
            .unwrap_or_else(|| format!("material #{index}"));
        let location = named("material", index, m.name());
        let pbr = m.pbr_metallic_roughness();
        let [r, g, b, _] = pbr.base_color_factor();
        let mut raw = Vec3::new(r, g, b);
        let mut strength = m.emissive_strength().unwrap_or(1.0);
        let mut emissive = Vec3::from(m.emissive_factor());
        // A baked scene Lightwire wrote (`write::GlbScene::to_glb_lit`): its
        // base colour is the baked light, the physical material is in the
        // extras.
        let baked = self.baked_material(m, &location);
        if let Some((albedo, emission)) = baked {
            raw = albedo;
            emissive = emission;
            strength = 1.0;
        }
        let chosen = (self.options.materials.get(&name))
            .or_else(|| self.options.materials.get("*"))
            .copied()
            .unwrap_or_default();
        if let Some(a) = chosen.albedo {
            raw = a;
        }
        let albedo = raw.clamp(Vec3::ZERO, Vec3::splat(ALBEDO_MAX));
        if albedo != raw {
            self.clamped.push(name.clone());
        }
        let mut emission = emissive * strength * self.options.emission_scale;
        if let Some(e) = chosen.emission {
            emission = e;
        }
        if !emission.is_finite() || emission.min_element() < 0.0 {
            self.report(
                &location,
                format!("emission {emission:?} W/m² (emissiveFactor × emissive_strength × emission_scale) must be finite and >= 0"),
            );
        }
        let base_color_texture = pbr
            .base_color_texture()
            .filter(|_| baked.is_none() && chosen.albedo.is_none());
        let base_color_texture = base_color_texture.map(|info| {
            let image = info.texture().source();
            let source = match image.source() {
                ::gltf::image::Source::View { view, mime_type } => {
                    let bytes = self
                        .buffers
                        .get(view.buffer().index())
                        .and_then(|b| b.as_ref())
                        .and_then(|b| {
                            b.get(view.offset()..view.offset().checked_add(view.length())?)
                        })
                        .map(<[u8]>::to_vec);
                    match bytes {
                        Some(bytes) => ImageSource::Embedded {
                            mime_type: mime_type.to_string(),
                            bytes,
                        },
                        None => {
                            self.report(
                                &named("image", image.index(), image.name()),
                                format!(
                                    "buffer view #{} is not inside a loaded buffer",
                                    view.index()
                                ),
                            );
                            ImageSource::Embedded {
                                mime_type: mime_type.to_string(),
                                bytes: Vec::new(),
                            }
                        }
                    }
                }
                ::gltf::image::Source::Uri { uri, .. } => ImageSource::Uri {
                    uri: uri.to_string(),
                },
            };
            TextureRef {
                image: image.index(),
                tex_coord: info.tex_coord(),
                source,
            }
        });
        let texture = pbr
            .base_color_texture()
            .filter(|_| baked.is_none())
            .zip(base_color_texture.as_ref())
            .and_then(|(info, r)| self.decode_texture(&location, &info.texture(), r))
            .map(Arc::new);
        ImportedMaterial {
            name,
            albedo,
            emission,
            base_color_texture,
            texture,
        }
    }

    /// Decodes a base colour texture with its sampler's wrapping and filter;
    /// reports (and returns `None`) when its bytes cannot be had or decoded.
    fn decode_texture(
        &mut self,
        location: &str,
        texture: &::gltf::Texture,
        r: &TextureRef,
    ) -> Option<Texture> {
        use ::gltf::texture::{MagFilter, WrappingMode};
        let image = texture.source();
        let location = format!(
            "{location}, {}",
            named("image", image.index(), image.name())
        );
        let bytes = match &r.source {
            ImageSource::Embedded { bytes, .. } => bytes.clone(),
            ImageSource::Uri { uri } => {
                let described = match (&self.base, uri.starts_with("data:")) {
                    (_, true) => "its data URI".to_string(),
                    (Some(b), false) => format!("\"{uri}\" ({})", b.join(uri).display()),
                    (None, false) => format!("\"{uri}\""),
                };
                // A buffer's URI and an image's resolve alike (a data URI
                // or a path relative to the glTF file).
                let source = ::gltf::buffer::Source::Uri(uri);
                match ::gltf::buffer::Data::from_source_and_blob(
                    source,
                    self.base.as_deref(),
                    &mut None,
                ) {
                    Ok(data) => data.0,
                    Err(e) => {
                        self.report(&location, format!("cannot load {described}: {e}"));
                        return None;
                    }
                }
            }
        };
        if bytes.is_empty() {
            // An embedded image outside its buffer, already reported.
            return None;
        }
        let sampler = texture.sampler();
        let wrap = |mode: WrappingMode| match mode {
            WrappingMode::Repeat => Wrap::Repeat,
            WrappingMode::MirroredRepeat => Wrap::MirroredRepeat,
            WrappingMode::ClampToEdge => Wrap::ClampToEdge,
        };
        let filter = match sampler.mag_filter() {
            Some(MagFilter::Nearest) => Filter::Nearest,
            Some(MagFilter::Linear) | None => Filter::Linear,
        };
        let name = named("image", image.index(), image.name());
        match Texture::decode(
            &name,
            &bytes,
            [wrap(sampler.wrap_s()), wrap(sampler.wrap_t())],
            filter,
        ) {
            Ok(t) => Some(t),
            Err(e) => {
                self.report(&location, e);
                None
            }
        }
    }

    /// A primitive whose material has a base colour texture must have the
    /// texture coordinates it reads.
    fn check_texture_uvs(
        &mut self,
        node: &::gltf::Node,
        mesh: &::gltf::Mesh,
        primitive: &::gltf::Primitive,
        materials: &[ImportedMaterial],
        instance: &MeshInstance,
    ) {
        let Some(r) = materials
            .get(instance.material as usize)
            .and_then(|m| m.base_color_texture.as_ref())
        else {
            return;
        };
        if instance.uvs(r.tex_coord).is_none() {
            let material = &materials[instance.material as usize].name;
            let problem = if r.tex_coord > 1 {
                format!(
                    "material \"{material}\"'s base colour texture reads TEXCOORD_{}; only TEXCOORD_0 and TEXCOORD_1 are read",
                    r.tex_coord
                )
            } else {
                format!(
                    "material \"{material}\" has a base colour texture read through TEXCOORD_{}, which this primitive does not have",
                    r.tex_coord
                )
            };
            self.report(&primitive_location(node, mesh, primitive.index()), problem);
        }
    }

    /// The albedo and emission (W/m²) of a material whose `extras` hold
    /// `{"lightwire": {"albedo": [r, g, b], "emission": [r, g, b]}}`, as a
    /// baked `scene.glb` writes them; `None` for any other material.
    fn baked_material(&mut self, m: &::gltf::Material, location: &str) -> Option<(Vec3, Vec3)> {
        let value: serde_json::Value = serde_json::from_str(m.extras().as_ref()?.get()).ok()?;
        let lightwire = value.get("lightwire")?;
        if lightwire.get("albedo").is_none() && lightwire.get("emission").is_none() {
            return None;
        }
        let rgb = |key: &str| -> Option<Vec3> {
            let a = lightwire.get(key)?.as_array()?;
            let c: Vec<f32> = a
                .iter()
                .filter_map(|x| x.as_f64())
                .map(|x| x as f32)
                .collect();
            (a.len() == 3 && c.len() == 3).then(|| Vec3::new(c[0], c[1], c[2]))
        };
        match (rgb("albedo"), rgb("emission")) {
            (Some(albedo), Some(emission)) => Some((albedo, emission)),
            _ => {
                self.report(
                    location,
                    "extras.lightwire must hold \"albedo\" and \"emission\", three numbers each",
                );
                None
            }
        }
    }

    /// Reads and checks a primitive in mesh space (once per primitive).
    fn primitive(
        &mut self,
        node: &::gltf::Node,
        mesh: &::gltf::Mesh,
        primitive: &::gltf::Primitive,
    ) -> Option<PrimitiveData> {
        let key = (mesh.index(), primitive.index());
        if let Some(done) = self.primitives.get(&key) {
            return done.clone();
        }
        let location = primitive_location(node, mesh, primitive.index());
        let before = self.issues.len();
        let data = self.read_primitive(&location, primitive);
        let data = if self.issues.len() == before {
            data
        } else {
            None
        };
        self.primitives.insert(key, data.clone());
        data
    }

    fn read_primitive(
        &mut self,
        location: &str,
        primitive: &::gltf::Primitive,
    ) -> Option<PrimitiveData> {
        use ::gltf::mesh::Mode;
        if primitive.mode() != Mode::Triangles {
            self.report(
                location,
                format!(
                    "mode {:?} is not supported; only TRIANGLES (4) primitives can be lit (export triangles)",
                    primitive.mode()
                ),
            );
            return None;
        }
        let Accessors {
            positions,
            normals,
            uv0,
            uv1,
            flat,
        } = self.read_accessors(location, primitive)?;
        let n = positions.len();
        for (what, len) in [
            ("NORMAL", normals.as_ref().map(Vec::len)),
            ("TEXCOORD_0", uv0.as_ref().map(Vec::len)),
            ("TEXCOORD_1", uv1.as_ref().map(Vec::len)),
        ] {
            if let Some(len) = len {
                if len != n {
                    self.report(
                        location,
                        format!("{what} has {len} elements but POSITION has {n}"),
                    );
                }
            }
        }
        if flat.len() % 3 != 0 {
            self.report(
                location,
                format!(
                    "{} indices (or vertices, when not indexed) is not a multiple of 3",
                    flat.len()
                ),
            );
            return None;
        }
        let indices: Vec<[u32; 3]> = flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        if !self.check_triangles(location, &positions, &indices) {
            return None;
        }
        let (indices, triangle_numbers) = self.drop_unlit(location, &positions, indices);
        // Lightmap UVs inside [0, 1].
        if let Some(uv) = &uv1 {
            self.check_uv_range(location, uv);
        }
        Some(PrimitiveData {
            positions,
            normals,
            indices,
            triangle_numbers,
            uv0,
            uv1,
            material: primitive.material().index(),
        })
    }

    /// Reads a primitive's positions, normals, texture coordinates and
    /// indices. Reports every accessor that cannot be read; none without
    /// positions or readable indices.
    fn read_accessors(
        &mut self,
        location: &str,
        primitive: &::gltf::Primitive,
    ) -> Option<Accessors> {
        use ::gltf::mesh::Semantic;
        let reader = accessor::Reader {
            buffers: &self.buffers,
        };
        let mut problems = Vec::new();
        let positions = match primitive.get(&Semantic::Positions) {
            None => {
                problems.push("has no POSITION attribute".to_string());
                None
            }
            Some(a) => reader
                .vec3(&a, "POSITION")
                .map_err(|e| problems.push(e))
                .ok(),
        };
        let normals = primitive
            .get(&Semantic::Normals)
            .and_then(|a| reader.vec3(&a, "NORMAL").map_err(|e| problems.push(e)).ok());
        let uv0 = primitive.get(&Semantic::TexCoords(0)).and_then(|a| {
            reader
                .vec2(&a, "TEXCOORD_0")
                .map_err(|e| problems.push(e))
                .ok()
        });
        let uv1 = primitive.get(&Semantic::TexCoords(1)).and_then(|a| {
            reader
                .vec2(&a, "TEXCOORD_1")
                .map_err(|e| problems.push(e))
                .ok()
        });
        let flat = match primitive.indices() {
            Some(a) => reader.indices(&a).map_err(|e| problems.push(e)).ok(),
            None => positions
                .as_ref()
                .map(|p| (0..p.len() as u32).collect::<Vec<u32>>()),
        };
        for p in problems {
            self.report(location, p);
        }
        Some(Accessors {
            positions: positions?,
            normals,
            uv0,
            uv1,
            flat: flat?,
        })
    }

    /// Reports non-finite positions and out-of-range indices, a few of each
    /// kind. Returns whether the positions are finite and the indices in
    /// range.
    fn check_triangles(
        &mut self,
        location: &str,
        positions: &[Vec3],
        indices: &[[u32; 3]],
    ) -> bool {
        let n = positions.len();
        // Non-finite positions: the first few by vertex index, then a count.
        let bad: Vec<usize> = (0..n).filter(|&i| !positions[i].is_finite()).collect();
        self.listed(location, &bad, |i| {
            format!(
                "POSITION of vertex {i} is {:?}: not a finite number",
                positions[i]
            )
        });
        // Out-of-range indices.
        let out: Vec<usize> = (0..indices.len())
            .filter(|&t| indices[t].iter().any(|&v| v as usize >= n))
            .collect();
        self.listed(location, &out, |t| {
            format!(
                "triangle {t} has indices {:?}, but there are only {n} vertices",
                indices[t]
            )
        });
        if !bad.is_empty() || !out.is_empty() {
            return false;
        }
        true
    }

    /// Drops the triangles no lightmap can hold, as lightmappers do (xatlas,
    /// Unity, Godot): zero-area and sliver ones (corners on a line to within
    /// [`DEGENERATE_RATIO`] of the longest edge, in mesh space) and exact
    /// duplicates (the same three corner positions in the same turning
    /// order as an earlier triangle: z-fighting copies; a back-to-back pair,
    /// opposite turning, is a two-sided face and stays). Counts what it
    /// dropped for [`Importer::take_warnings`]. Returns the kept triangles
    /// and their numbers in the primitive.
    fn drop_unlit(
        &mut self,
        location: &str,
        positions: &[Vec3],
        indices: Vec<[u32; 3]>,
    ) -> (Vec<[u32; 3]>, Vec<u32>) {
        let mut dropped = Dropped {
            of: indices.len(),
            ..Dropped::default()
        };
        let mut seen: HashSet<[[u32; 3]; 3]> = HashSet::new();
        let mut kept = Vec::with_capacity(indices.len());
        let mut numbers = Vec::with_capacity(indices.len());
        for (t, tri) in indices.into_iter().enumerate() {
            let [a, b, c] = tri.map(|v| positions[v as usize]);
            if is_degenerate(a, b, c) {
                dropped.degenerate += 1;
                continue;
            }
            // The corners as bit patterns, rotated so the smallest comes
            // first: equal keys are the same triangle turning the same way.
            let mut key = [a, b, c].map(|p| p.to_array().map(f32::to_bits));
            let first = (0..3).min_by_key(|&i| key[i]).unwrap_or(0);
            key.rotate_left(first);
            if !seen.insert(key) {
                dropped.duplicate += 1;
                continue;
            }
            kept.push(tri);
            numbers.push(t as u32);
        }
        if dropped.degenerate + dropped.duplicate > 0 {
            self.dropped.insert(location.to_string(), dropped);
        }
        (kept, numbers)
    }

    /// The warnings of this import: one line per kind of dropped triangle
    /// (counts per primitive), then the clamped base colours.
    fn take_warnings(&mut self) -> Vec<SceneIssue> {
        let mut out = Vec::new();
        for (kind, duplicates) in [
            ("zero-area or sliver (corners on a line)", false),
            (
                "duplicate (same corners as another triangle, same facing)",
                true,
            ),
        ] {
            let count = |d: &Dropped| {
                if duplicates {
                    d.duplicate
                } else {
                    d.degenerate
                }
            };
            let per: Vec<(&String, usize, usize)> = self
                .dropped
                .iter()
                .filter(|(_, d)| count(d) > 0)
                .map(|(at, d)| (at, count(d), d.of))
                .collect();
            if per.is_empty() {
                continue;
            }
            let total: usize = per.iter().map(|p| p.1).sum();
            let listed: Vec<String> = per
                .iter()
                .take(MAX_LISTED)
                .map(|(at, n, of)| format!("{at}: {n} of {of}"))
                .collect();
            let more = per.len().saturating_sub(MAX_LISTED);
            out.push(SceneIssue {
                location: "triangles".to_string(),
                problem: format!(
                    "dropped {total} {kind} triangle(s) that no lightmap can hold: {}{}",
                    listed.join("; "),
                    if more > 0 {
                        format!("; and {more} more primitives")
                    } else {
                        String::new()
                    }
                ),
            });
        }
        if !self.clamped.is_empty() {
            let listed: Vec<&str> = self
                .clamped
                .iter()
                .take(MAX_LISTED)
                .map(String::as_str)
                .collect();
            out.push(SceneIssue {
                location: "materials".to_string(),
                problem: format!(
                    "{} base colour(s) clamped to {ALBEDO_MAX} per channel (a surface that reflects everything makes a closed room's light never settle): {}{}",
                    self.clamped.len(),
                    listed.join(", "),
                    if self.clamped.len() > MAX_LISTED {
                        format!(", and {} more", self.clamped.len() - MAX_LISTED)
                    } else {
                        String::new()
                    }
                ),
            });
        }
        out
    }

    /// Reports lightmap UVs (`TEXCOORD_1`) outside [0, 1], a few of them.
    fn check_uv_range(&mut self, location: &str, uv: &[Vec2]) {
        let lo = -UV_RANGE_SLACK;
        let hi = 1.0 + UV_RANGE_SLACK;
        let outside: Vec<usize> = (0..uv.len())
            .filter(|&i| {
                !(uv[i].cmpge(Vec2::splat(lo)).all() && uv[i].cmple(Vec2::splat(hi)).all())
            })
            .collect();
        self.listed(location, &outside, |i| {
            format!(
                "TEXCOORD_1 of vertex {i} is {:?}: lightmap UVs must lie in [0, 1]",
                uv[i]
            )
        });
    }

    /// Reports the first [`MAX_LISTED`] items and a count of the rest.
    fn listed(&mut self, location: &str, items: &[usize], describe: impl Fn(usize) -> String) {
        for &i in items.iter().take(MAX_LISTED) {
            self.report(location, describe(i));
        }
        if items.len() > MAX_LISTED {
            self.report(
                location,
                format!("... and {} more like these", items.len() - MAX_LISTED),
            );
        }
    }

    /// Overlap check of `TEXCOORD_1` across all primitives of a mesh (once
    /// per mesh).
    fn check_mesh_uvs(&mut self, node: &::gltf::Node, mesh: &::gltf::Mesh) {
        if self.uv_checked.insert(mesh.index(), ()).is_some() {
            return;
        }
        let mut tris: Vec<[Vec2; 3]> = Vec::new();
        // (primitive, triangle index within it) for each entry of `tris`.
        let mut origin: Vec<(usize, usize)> = Vec::new();
        for primitive in mesh.primitives() {
            let Some(Some(data)) = self.primitives.get(&(mesh.index(), primitive.index())) else {
                continue;
            };
            let Some(uv) = &data.uv1 else { continue };
            for (t, tri) in data.indices.iter().enumerate() {
                tris.push(tri.map(|v| uv[v as usize]));
                origin.push((primitive.index(), t));
            }
        }
        if tris.is_empty() {
            return;
        }
        let zero: Vec<usize> = (0..tris.len())
            .filter(|&i| {
                let [a, b, c] = tris[i];
                let twice_area = (b - a).perp_dot(c - a).abs();
                twice_area.is_nan() || twice_area <= 1e-12
            })
            .collect();
        let at = |(p, _): (usize, usize)| primitive_location(node, mesh, p);
        for &i in zero.iter().take(MAX_LISTED) {
            let t = origin[i].1;
            self.report(
                &at(origin[i]),
                format!(
                    "triangle {t} has zero area in TEXCOORD_1 ({:?}): it would get no lightmap texels",
                    tris[i]
                ),
            );
        }
        if zero.len() > MAX_LISTED {
            self.report(
                &named("mesh", mesh.index(), mesh.name()),
                format!(
                    "... and {} more triangles with zero TEXCOORD_1 area",
                    zero.len() - MAX_LISTED
                ),
            );
        }
        let overlaps = match find_uv_overlaps(&tris, MAX_LISTED + 1) {
            Ok(o) => o,
            Err(work) => {
                self.report(
                    &named("mesh", mesh.index(), mesh.name()),
                    format!(
                        "TEXCOORD_1 of its {} triangles cannot be checked for overlaps: the layout needs {work} grid entries or candidate pairs, over the limit (very long thin or heavily piled-up UV triangles)",
                        tris.len()
                    ),
                );
                return;
            }
        };
        for o in overlaps.iter().take(MAX_LISTED) {
            let (pa, ta) = origin[o.a];
            let (pb, tb) = origin[o.b];
            let other = if pa == pb {
                format!("triangle {tb}")
            } else {
                format!("triangle {tb} of primitive #{pb}")
            };
            self.report(
                &at((pa, ta)),
                format!(
                    "triangle {ta} overlaps {other} in TEXCOORD_1 by {:.3e} (UV units², {:.1}% of the smaller): lightmap UVs must not overlap",
                    o.area,
                    100.0 * o.fraction
                ),
            );
        }
        if overlaps.len() > MAX_LISTED {
            self.report(
                &named("mesh", mesh.index(), mesh.name()),
                "... and more overlapping TEXCOORD_1 triangles",
            );
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn instance(
        &mut self,
        node: &::gltf::Node,
        mesh: &::gltf::Mesh,
        primitive: &::gltf::Primitive,
        data: PrimitiveData,
        to_object: Mat4,
        det: f32,
        object: u32,
        material: u32,
    ) -> Option<MeshInstance> {
        let positions: Vec<Vec3> = data
            .positions
            .iter()
            .map(|&p| to_object.transform_point3(p))
            .collect();
        if let Some(i) = positions.iter().position(|p| !p.is_finite()) {
            self.report(
                &primitive_location(node, mesh, primitive.index()),
                format!(
                    "vertex {i} at {:?} is not finite after the node transform",
                    data.positions[i]
                ),
            );
            return None;
        }
        let normal_matrix = Mat3::from_mat4(to_object).inverse().transpose();
        let normals = data.normals.map(|ns| {
            ns.iter()
                .map(|&n| (normal_matrix * n).normalize_or_zero())
                .collect()
        });
        let mut indices = data.indices;
        if det < 0.0 {
            // A mirroring transform turns counter-clockwise into clockwise
            // (glTF §5.25, node: "the winding order ... is reversed").
            for t in &mut indices {
                t.swap(1, 2);
            }
        }
        Some(MeshInstance {
            node: node.index(),
            node_name: node.name().map(str::to_string),
            mesh: mesh.index(),
            mesh_name: mesh.name().map(str::to_string),
            primitive: primitive.index(),
            object,
            material,
            positions,
            normals,
            indices,
            triangle_numbers: data.triangle_numbers,
            uv0: data.uv0,
            lightmap_uvs: data.uv1,
        })
    }
}
