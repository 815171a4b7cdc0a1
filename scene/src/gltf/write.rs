//! A glTF 2.0 writer for triangle meshes: `.glb`, or `.gltf` with a `.bin`.
//!
//! The JSON is built with `gltf-json` (re-exported by the `gltf` crate) and
//! the binary container with `gltf::binary::Glb` (glTF 2.0 §4.4, "GLB File
//! Format Specification"). Everything is written in a fixed order with
//! explicit values, so the same input gives the same bytes: the committed
//! test content in `scenes/meshes/` is checked against a regeneration.
//!
//! What it writes: per primitive POSITION (with min/max), optional NORMAL,
//! TEXCOORD_0, TEXCOORD_1, and u32 indices, each in its own buffer view;
//! materials with `baseColorFactor`, an optional base colour texture (a PNG
//! embedded in the binary chunk, sampled with TEXCOORD_0, repeating),
//! `emissiveFactor` and `KHR_materials_emissive_strength`; nodes with names,
//! translation/rotation/scale, children and `extras`.
//!
//! A baked scene ([`GlbScene::to_glb_lit`], `bake::scene_glb`) adds a
//! lightmap that any viewer shows: every material is written
//! `KHR_materials_unlit` with the tone-mapped lightmap as its base colour
//! texture on `TEXCOORD_1` (white `baseColorFactor`, since an unlit colour
//! is factor × texture and the lightmap is already the surface's radiosity
//! `B = E + ρH`, albedo included), and the physical material (albedo,
//! emission in W/m²) in its `extras` as `{"lightwire": {"albedo": [r, g,
//! b], "emission": [r, g, b]}}`, which the importer reads back. Emission is
//! also written as usual, so a viewer without the extension still sees
//! the lights (the Khronos validator warns `MULTIPLE_EXTENSIONS` where
//! emission strength sits beside unlit: an unlit viewer ignores it).

use std::borrow::Cow;
use std::collections::BTreeMap;

use ::gltf::json;
use glam::{Quat, Vec2, Vec3};
use json::validation::Checked::Valid;
use json::validation::USize64;

/// Why a document could not be written.
#[derive(Debug, thiserror::Error)]
pub enum WriteError {
    #[error("{0}")]
    Invalid(String),
    #[error("glTF serialisation failed: {0}")]
    Json(String),
}

/// A document to write.
#[derive(Debug, Clone, Default)]
pub struct GlbScene {
    pub materials: Vec<GlbMaterial>,
    pub images: Vec<GlbImage>,
    pub meshes: Vec<GlbMesh>,
    pub nodes: Vec<GlbNode>,
    /// Indices of the nodes placed directly in the (single) scene.
    pub roots: Vec<usize>,
}

/// A material in Lightwire's units.
#[derive(Debug, Clone, PartialEq)]
pub struct GlbMaterial {
    pub name: String,
    /// Written as `baseColorFactor` (alpha 1).
    pub base_color: Vec3,
    /// W/m² per channel. Written as `emissiveFactor` = emission / m and
    /// `KHR_materials_emissive_strength` = m, m the largest channel, when
    /// m > 1 (glTF clamps `emissiveFactor` to [0, 1]); else as
    /// `emissiveFactor` alone.
    pub emission: Vec3,
    /// Index into [`GlbScene::images`], sampled with TEXCOORD_0.
    pub base_color_texture: Option<usize>,
}

/// A PNG image embedded in the binary chunk.
#[derive(Debug, Clone, PartialEq)]
pub struct GlbImage {
    pub name: String,
    pub png: Vec<u8>,
}

#[derive(Debug, Clone, PartialEq)]
pub struct GlbMesh {
    pub name: String,
    pub primitives: Vec<GlbPrimitive>,
}

/// A triangle list; attribute arrays, when present, have one entry per
/// position.
#[derive(Debug, Clone, PartialEq)]
pub struct GlbPrimitive {
    pub positions: Vec<Vec3>,
    pub normals: Option<Vec<Vec3>>,
    pub uv0: Option<Vec<Vec2>>,
    pub uv1: Option<Vec<Vec2>>,
    pub indices: Vec<[u32; 3]>,
    /// Index into [`GlbScene::materials`]; `None` is glTF's default material.
    pub material: Option<usize>,
}

#[derive(Debug, Clone, PartialEq)]
pub struct GlbNode {
    pub name: String,
    pub mesh: Option<usize>,
    pub translation: Vec3,
    pub rotation: Quat,
    /// Per-axis scale.
    pub scale: Vec3,
    pub children: Vec<usize>,
    /// Written as the node's `extras`, e.g. `{"lightwire": {"dynamic": true}}`.
    pub extras: Option<serde_json::Value>,
    /// A `KHR_lights_punctual` light at the node (shining along its `-z`).
    pub light: Option<GlbLight>,
}

/// A `KHR_lights_punctual` light, in glTF's photometric units.
#[derive(Debug, Clone, PartialEq)]
pub struct GlbLight {
    pub name: String,
    pub kind: GlbLightKind,
    /// Linear RGB in [0, 1].
    pub color: Vec3,
    /// Candela (point, spot) or lux (directional).
    pub intensity: f32,
    pub range: Option<f32>,
    /// Written as the light's `extras`.
    pub extras: Option<serde_json::Value>,
}

/// What kind of `KHR_lights_punctual` light.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum GlbLightKind {
    Point,
    /// Cone angles in radians from the axis.
    Spot {
        inner: f32,
        outer: f32,
    },
    Directional,
}

impl GlbNode {
    /// A node with the identity transform and no children.
    pub fn new(name: impl Into<String>, mesh: Option<usize>) -> Self {
        Self {
            name: name.into(),
            mesh,
            translation: Vec3::ZERO,
            rotation: Quat::IDENTITY,
            scale: Vec3::ONE,
            children: Vec::new(),
            extras: None,
            light: None,
        }
    }
}

/// A baked lightmap to show on every surface ([`GlbScene::to_glb_lit`]).
#[derive(Debug, Clone, PartialEq)]
pub struct GlbLightmap {
    /// The image's and texture's name in the file.
    pub name: String,
    /// The tone-mapped lightmap as an 8-bit sRGB PNG (glTF base colour
    /// textures are sRGB), one pixel per atlas texel.
    pub png: Vec<u8>,
    /// Written as the asset's `extras` (e.g. where the linear lightmap is).
    pub asset_extras: Option<serde_json::Value>,
}

/// The extension name for emission strength.
const EMISSIVE_STRENGTH: &str = "KHR_materials_emissive_strength";
/// The extension that shows a material's base colour as is, without lights.
const UNLIT: &str = "KHR_materials_unlit";

struct Builder {
    root: json::Root,
    bin: Vec<u8>,
}

impl Builder {
    /// Appends bytes as a new buffer view, 4-byte aligned.
    fn view(
        &mut self,
        bytes: &[u8],
        target: Option<json::buffer::Target>,
    ) -> json::Index<json::buffer::View> {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        let offset = self.bin.len();
        self.bin.extend_from_slice(bytes);
        self.root.push(json::buffer::View {
            buffer: json::Index::new(0),
            byte_length: USize64::from(bytes.len()),
            byte_offset: Some(USize64::from(offset)),
            byte_stride: None,
            extensions: None,
            extras: None,
            name: None,
            target: target.map(Valid),
        })
    }

    fn accessor(
        &mut self,
        bytes: &[u8],
        count: usize,
        component: json::accessor::ComponentType,
        type_: json::accessor::Type,
        target: json::buffer::Target,
        bounds: Option<(Vec<f32>, Vec<f32>)>,
    ) -> json::Index<json::Accessor> {
        let view = self.view(bytes, Some(target));
        let (min, max) = match bounds {
            Some((lo, hi)) => (Some(json::Value::from(lo)), Some(json::Value::from(hi))),
            None => (None, None),
        };
        self.root.push(json::Accessor {
            buffer_view: Some(view),
            byte_offset: None,
            count: USize64::from(count),
            component_type: Valid(json::accessor::GenericComponentType(component)),
            extensions: None,
            extras: None,
            type_: Valid(type_),
            min,
            max,
            name: None,
            normalized: false,
            sparse: None,
        })
    }

    fn floats(
        &mut self,
        values: &[f32],
        n: usize,
        type_: json::accessor::Type,
        bounds: bool,
    ) -> json::Index<json::Accessor> {
        let bytes: Vec<u8> = values.iter().flat_map(|x| x.to_le_bytes()).collect();
        let bounds = bounds.then(|| {
            let mut lo = vec![f32::INFINITY; n];
            let mut hi = vec![f32::NEG_INFINITY; n];
            for chunk in values.chunks_exact(n) {
                for k in 0..n {
                    lo[k] = lo[k].min(chunk[k]);
                    hi[k] = hi[k].max(chunk[k]);
                }
            }
            (lo, hi)
        });
        self.accessor(
            &bytes,
            values.len() / n,
            json::accessor::ComponentType::F32,
            type_,
            json::buffer::Target::ArrayBuffer,
            bounds,
        )
    }

    /// Appends a PNG as a buffer view, an image of it and a texture that
    /// samples it with `sampler`.
    fn texture(
        &mut self,
        name: &str,
        png: &[u8],
        sampler: json::Index<json::texture::Sampler>,
    ) -> json::Index<json::Texture> {
        let view = self.view(png, None);
        let source = self.root.push(json::Image {
            buffer_view: Some(view),
            mime_type: Some(json::image::MimeType("image/png".to_string())),
            name: Some(name.to_string()),
            uri: None,
            extensions: None,
            extras: None,
        });
        self.root.push(json::Texture {
            name: Some(name.to_string()),
            sampler: Some(sampler),
            source,
            extensions: None,
            extras: None,
        })
    }

    /// Images, their textures, one sampler (none without images). Returns
    /// the textures, indexed like `images`.
    fn images(&mut self, images: &[GlbImage]) -> Vec<json::Index<json::Texture>> {
        let mut textures = Vec::new();
        if !images.is_empty() {
            let sampler = self.root.push(json::texture::Sampler {
                mag_filter: Some(Valid(json::texture::MagFilter::Nearest)),
                min_filter: Some(Valid(json::texture::MinFilter::Nearest)),
                wrap_s: Valid(json::texture::WrappingMode::Repeat),
                wrap_t: Valid(json::texture::WrappingMode::Repeat),
                ..Default::default()
            });
            for image in images {
                textures.push(self.texture(&image.name, &image.png, sampler));
            }
        }
        textures
    }

    /// The lightmap's texture, with a sampler of its own.
    fn lightmap_texture(&mut self, l: &GlbLightmap) -> json::Index<json::Texture> {
        // The lightmap: filtered as a client filters it (bilinear, no
        // mipmaps, which would blend neighbouring charts; clamped at the
        // atlas border).
        let sampler = self.root.push(json::texture::Sampler {
            mag_filter: Some(Valid(json::texture::MagFilter::Linear)),
            min_filter: Some(Valid(json::texture::MinFilter::Linear)),
            wrap_s: Valid(json::texture::WrappingMode::ClampToEdge),
            wrap_t: Valid(json::texture::WrappingMode::ClampToEdge),
            ..Default::default()
        });
        self.texture(&l.name, &l.png, sampler)
    }

    /// A mesh: the accessors of each of its primitives, then the mesh.
    fn mesh(&mut self, mesh: &GlbMesh) {
        let mut primitives = Vec::new();
        for p in &mesh.primitives {
            primitives.push(self.primitive(p));
        }
        self.root.push(json::Mesh {
            extensions: None,
            extras: None,
            name: Some(mesh.name.clone()),
            primitives,
            weights: None,
        });
    }

    /// A primitive's accessors, in order: positions (with their bounds),
    /// normals, TEXCOORD_0, TEXCOORD_1 and the indices.
    fn primitive(&mut self, p: &GlbPrimitive) -> json::mesh::Primitive {
        use json::accessor::Type;
        use json::mesh::Semantic;
        let mut attributes = BTreeMap::new();
        let flat: Vec<f32> = p.positions.iter().flat_map(|v| v.to_array()).collect();
        attributes.insert(
            Valid(Semantic::Positions),
            self.floats(&flat, 3, Type::Vec3, true),
        );
        if let Some(ns) = &p.normals {
            let flat: Vec<f32> = ns.iter().flat_map(|v| v.to_array()).collect();
            attributes.insert(
                Valid(Semantic::Normals),
                self.floats(&flat, 3, Type::Vec3, false),
            );
        }
        for (set, uv) in [(0, &p.uv0), (1, &p.uv1)] {
            if let Some(uv) = uv {
                let flat: Vec<f32> = uv.iter().flat_map(|v| v.to_array()).collect();
                attributes.insert(
                    Valid(Semantic::TexCoords(set)),
                    self.floats(&flat, 2, Type::Vec2, false),
                );
            }
        }
        let bytes: Vec<u8> = p
            .indices
            .iter()
            .flatten()
            .flat_map(|i| i.to_le_bytes())
            .collect();
        let indices = self.accessor(
            &bytes,
            p.indices.len() * 3,
            json::accessor::ComponentType::U32,
            Type::Scalar,
            json::buffer::Target::ElementArrayBuffer,
            None,
        );
        json::mesh::Primitive {
            attributes,
            extensions: None,
            extras: None,
            indices: Some(indices),
            material: p.material.map(|m| json::Index::new(m as u32)),
            mode: Valid(json::mesh::Mode::Triangles),
            targets: None,
        }
    }

    /// Places the `roots` in the (single) scene, pads the binary buffer to
    /// 4 bytes and declares it (in the file `bin_uri`, for a `.gltf`), and
    /// serialises the JSON. Returns the JSON and the binary buffer.
    fn finish(
        mut self,
        roots: &[usize],
        bin_uri: Option<&str>,
    ) -> Result<(String, Vec<u8>), WriteError> {
        let scene = self.root.push(json::Scene {
            extensions: None,
            extras: None,
            name: None,
            nodes: roots.iter().map(|&r| json::Index::new(r as u32)).collect(),
        });
        self.root.scene = Some(scene);

        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        self.root.push(json::Buffer {
            byte_length: USize64::from(self.bin.len()),
            extensions: None,
            extras: None,
            name: None,
            uri: bin_uri.map(str::to_string),
        });
        let text =
            json::serialize::to_string(&self.root).map_err(|e| WriteError::Json(e.to_string()))?;
        Ok((text, self.bin))
    }
}

fn extras(value: &Option<serde_json::Value>) -> Result<json::Extras, WriteError> {
    value
        .as_ref()
        .map(|v| serde_json::value::to_raw_value(v).map_err(|e| WriteError::Json(e.to_string())))
        .transpose()
}

/// A material in glTF's terms: emission as `emissiveFactor`, with
/// `KHR_materials_emissive_strength` when a channel exceeds 1; with
/// `lightmap_texture`, shown unlit as the lightmap, its physical values in
/// its `extras` (see the module doc). Returns it and whether it uses the
/// emission strength.
fn json_material(
    m: &GlbMaterial,
    textures: &[json::Index<json::Texture>],
    lightmap_texture: Option<json::Index<json::Texture>>,
) -> Result<(json::Material, bool), WriteError> {
    let peak = m.emission.max_element();
    let (factor, strength) = if peak > 1.0 {
        (m.emission / peak, Some(peak))
    } else {
        (m.emission, None)
    };
    let mut material = json::Material {
        name: Some(m.name.clone()),
        emissive_factor: json::material::EmissiveFactor(factor.to_array()),
        ..Default::default()
    };
    material.pbr_metallic_roughness.base_color_factor =
        json::material::PbrBaseColorFactor([m.base_color.x, m.base_color.y, m.base_color.z, 1.0]);
    // Diffuse surfaces: no metal, fully rough.
    material.pbr_metallic_roughness.metallic_factor = json::material::StrengthFactor(0.0);
    material.pbr_metallic_roughness.roughness_factor = json::material::StrengthFactor(1.0);
    material.pbr_metallic_roughness.base_color_texture =
        m.base_color_texture.map(|t| json::texture::Info {
            index: textures[t],
            tex_coord: 0,
            extensions: None,
            extras: None,
        });
    let mut extensions = json::extensions::material::Material::default();
    if let Some(s) = strength {
        extensions.emissive_strength = Some(json::extensions::material::EmissiveStrength {
            emissive_strength: json::extensions::material::EmissiveStrengthFactor(s),
        });
    }
    if let Some(index) = lightmap_texture {
        // Shown as the baked light: unlit, white × the lightmap.
        extensions.unlit = Some(json::extensions::material::Unlit {});
        material.pbr_metallic_roughness.base_color_factor =
            json::material::PbrBaseColorFactor([1.0; 4]);
        material.pbr_metallic_roughness.base_color_texture = Some(json::texture::Info {
            index,
            tex_coord: 1,
            extensions: None,
            extras: None,
        });
        material.extras = extras(&Some(serde_json::json!({
            "lightwire": {
                "albedo": m.base_color.to_array(),
                "emission": m.emission.to_array(),
            }
        })))?;
    }
    if strength.is_some() || lightmap_texture.is_some() {
        material.extensions = Some(extensions);
    }
    Ok((material, strength.is_some()))
}

/// A node holding `light` as `KHR_lights_punctual` has it, so that
/// importing it again (`gltf::import`, at `light_scale` 1) gives the same
/// light: radiometric intensity times 683 lm/W (candela, lux) split into a
/// colour (the channels over the largest) and a scalar, the position as
/// the node's translation, the direction as the rotation that takes `-z`
/// to it; a directional light's angular radius, which glTF has no field
/// for, in the light's `extras` as `{"lightwire": {"angular_radius": r}}`
/// (radians).
pub fn light_node(light: &crate::Light) -> GlbNode {
    use crate::LightKind;
    let peak = light.intensity.max_element();
    let color = if peak > 0.0 {
        light.intensity / peak
    } else {
        Vec3::ONE
    };
    let mut node = GlbNode::new(light.name.clone(), None);
    let (kind, direction, extras) = match light.kind {
        LightKind::Point => (GlbLightKind::Point, None, None),
        LightKind::Spot {
            direction,
            inner,
            outer,
        } => (GlbLightKind::Spot { inner, outer }, Some(direction), None),
        LightKind::Directional {
            direction,
            angular_radius,
        } => (
            GlbLightKind::Directional,
            Some(direction),
            (angular_radius > 0.0)
                .then(|| serde_json::json!({ "lightwire": { "angular_radius": angular_radius } })),
        ),
    };
    if !matches!(kind, GlbLightKind::Directional) {
        node.translation = light.position;
    }
    if let Some(d) = direction {
        node.rotation = Quat::from_rotation_arc(Vec3::NEG_Z, d.normalize_or(Vec3::NEG_Z));
    }
    node.light = Some(GlbLight {
        name: light.name.clone(),
        kind,
        color,
        intensity: peak.max(0.0) * super::LUMENS_PER_WATT,
        range: light.range,
        extras,
    });
    node
}

/// The `KHR_lights_punctual` extension's name.
const LIGHTS_PUNCTUAL: &str = "KHR_lights_punctual";

/// A light in `KHR_lights_punctual`'s terms.
fn json_light(
    light: &GlbLight,
) -> Result<json::extensions::scene::khr_lights_punctual::Light, WriteError> {
    use json::extensions::scene::khr_lights_punctual::{Light, Spot, Type};
    if !(light.color.is_finite()
        && light.intensity.is_finite()
        && light.intensity >= 0.0
        && light.range.is_none_or(|r| r.is_finite() && r > 0.0))
    {
        return Err(WriteError::Invalid(format!(
            "light \"{}\": colour, intensity or range is not a finite number >= 0",
            light.name
        )));
    }
    let (type_, spot) = match light.kind {
        GlbLightKind::Point => (Type::Point, None),
        GlbLightKind::Directional => (Type::Directional, None),
        GlbLightKind::Spot { inner, outer } => (
            Type::Spot,
            Some(Spot {
                inner_cone_angle: inner,
                outer_cone_angle: outer,
            }),
        ),
    };
    Ok(Light {
        color: light.color.to_array(),
        extensions: None,
        extras: extras(&light.extras)?,
        intensity: light.intensity,
        name: Some(light.name.clone()),
        range: light.range,
        spot,
        type_: json::validation::Checked::Valid(type_),
    })
}

/// A node in glTF's terms: its transform's parts that are not the
/// identity, its children when it has any, and its `extras`.
fn json_node(node: &GlbNode) -> Result<json::Node, WriteError> {
    Ok(json::Node {
        name: Some(node.name.clone()),
        mesh: node.mesh.map(|m| json::Index::new(m as u32)),
        children: (!node.children.is_empty()).then(|| {
            node.children
                .iter()
                .map(|&c| json::Index::new(c as u32))
                .collect()
        }),
        translation: (node.translation != Vec3::ZERO).then(|| node.translation.to_array()),
        rotation: (node.rotation != Quat::IDENTITY)
            .then(|| json::scene::UnitQuaternion(node.rotation.to_array())),
        scale: (node.scale != Vec3::ONE).then(|| node.scale.to_array()),
        extras: extras(&node.extras)?,
        ..Default::default()
    })
}

impl GlbScene {
    fn check(&self, lit: bool) -> Result<(), WriteError> {
        let bad = |m: String| Err(WriteError::Invalid(m));
        for (mi, mesh) in self.meshes.iter().enumerate() {
            for (pi, p) in mesh.primitives.iter().enumerate() {
                let n = p.positions.len();
                let at = format!("mesh #{mi} \"{}\" primitive #{pi}", mesh.name);
                if n == 0 || p.indices.is_empty() {
                    return bad(format!("{at} is empty"));
                }
                for (what, len) in [
                    ("normals", p.normals.as_ref().map(Vec::len)),
                    ("uv0", p.uv0.as_ref().map(Vec::len)),
                    ("uv1", p.uv1.as_ref().map(Vec::len)),
                ] {
                    if len.is_some_and(|l| l != n) {
                        return bad(format!("{at}: {what} has a length other than {n}"));
                    }
                }
                if p.uv1.is_some() && p.uv0.is_none() {
                    // glTF 2.0 §3.7.2.1: TEXCOORD_n sets must be contiguous
                    // from 0 (the Khronos validator's
                    // MESH_PRIMITIVE_INDEXED_SEMANTIC_CONTINUITY).
                    return bad(format!("{at}: uv1 (TEXCOORD_1) needs uv0 (TEXCOORD_0) too"));
                }
                if p.indices.iter().flatten().any(|&i| i as usize >= n) {
                    return bad(format!("{at}: an index is out of range"));
                }
                if p.material.is_some_and(|m| m >= self.materials.len()) {
                    return bad(format!("{at}: no such material"));
                }
                if lit && (p.uv1.is_none() || p.material.is_none()) {
                    return bad(format!(
                        "{at}: a lit document needs TEXCOORD_1 (the lightmap's coordinates) and a material on every primitive"
                    ));
                }
            }
        }
        for (i, node) in self.nodes.iter().enumerate() {
            if node.mesh.is_some_and(|m| m >= self.meshes.len())
                || node.children.iter().any(|&c| c >= self.nodes.len())
            {
                return bad(format!(
                    "node #{i} \"{}\" refers to a missing mesh or node",
                    node.name
                ));
            }
        }
        if self.roots.iter().any(|&r| r >= self.nodes.len()) {
            return bad("a root refers to a missing node".to_string());
        }
        for m in &self.materials {
            if m.base_color_texture.is_some_and(|t| t >= self.images.len()) {
                return bad(format!("material \"{}\" refers to a missing image", m.name));
            }
            if lit && m.base_color_texture.is_some() {
                return bad(format!(
                    "material \"{}\" has a base colour texture; in a lit document the lightmap is the base colour",
                    m.name
                ));
            }
        }
        Ok(())
    }

    /// The glTF JSON and the binary buffer; `bin_uri` names the buffer's file
    /// (for `.gltf`) or is `None` (for `.glb`, the binary chunk).
    pub fn to_json_and_bin(&self, bin_uri: Option<&str>) -> Result<(String, Vec<u8>), WriteError> {
        self.build(bin_uri, None)
    }

    /// The document as a binary glTF with `lightmap` on every surface (see
    /// the module doc): every primitive needs a material and `uv1`, the
    /// lightmap coordinates, and no material may have a base colour texture
    /// of its own.
    pub fn to_glb_lit(&self, lightmap: &GlbLightmap) -> Result<Vec<u8>, WriteError> {
        let (text, bin) = self.build(None, Some(lightmap))?;
        pack_glb(text.as_bytes(), &bin)
    }
    fn build(
        &self,
        bin_uri: Option<&str>,
        lightmap: Option<&GlbLightmap>,
    ) -> Result<(String, Vec<u8>), WriteError> {
        self.check(lightmap.is_some())?;
        let mut b = Builder {
            root: json::Root::default(),
            bin: Vec::new(),
        };
        b.root.asset = json::Asset {
            generator: Some("Lightwire".to_string()),
            extras: extras(&lightmap.and_then(|l| l.asset_extras.clone()))?,
            ..Default::default()
        };
        let textures = b.images(&self.images);
        let lightmap_texture = lightmap.map(|l| b.lightmap_texture(l));

        let mut uses_strength = false;
        for m in &self.materials {
            let (material, strength) = json_material(m, &textures, lightmap_texture)?;
            uses_strength |= strength;
            b.root.push(material);
        }
        if uses_strength {
            b.root.extensions_used.push(EMISSIVE_STRENGTH.to_string());
        }
        if lightmap.is_some() && !self.materials.is_empty() {
            b.root.extensions_used.push(UNLIT.to_string());
        }

        for mesh in &self.meshes {
            b.mesh(mesh);
        }
        let mut lights = Vec::new();
        for node in &self.nodes {
            let mut json = json_node(node)?;
            if let Some(light) = &node.light {
                json.extensions = Some(json::extensions::scene::Node {
                    khr_lights_punctual: Some(
                        json::extensions::scene::khr_lights_punctual::KhrLightsPunctual {
                            light: json::Index::new(lights.len() as u32),
                        },
                    ),
                });
                lights.push(json_light(light)?);
            }
            b.root.push(json);
        }
        if !lights.is_empty() {
            b.root.extensions_used.push(LIGHTS_PUNCTUAL.to_string());
            b.root.extensions = Some(json::extensions::root::Root {
                khr_lights_punctual: Some(json::extensions::root::KhrLightsPunctual { lights }),
            });
        }
        b.finish(&self.roots, bin_uri)
    }

    /// The document as a binary glTF (`.glb`).
    pub fn to_glb(&self) -> Result<Vec<u8>, WriteError> {
        let (text, bin) = self.to_json_and_bin(None)?;
        pack_glb(text.as_bytes(), &bin)
    }
}

/// Packs a JSON chunk and a binary chunk into a GLB container (each padded
/// to 4 bytes: JSON with spaces, binary with zeros, glTF §4.4.3).
pub fn pack_glb(json_text: &[u8], bin: &[u8]) -> Result<Vec<u8>, WriteError> {
    let mut text = json_text.to_vec();
    while !text.len().is_multiple_of(4) {
        text.push(b' ');
    }
    let mut bin = bin.to_vec();
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let length = 12 + 8 + text.len() + if bin.is_empty() { 0 } else { 8 + bin.len() };
    let glb = ::gltf::binary::Glb {
        header: ::gltf::binary::Header {
            magic: *b"glTF",
            version: 2,
            length: u32::try_from(length).map_err(|_| {
                WriteError::Invalid(format!("{length} bytes is too large for a GLB"))
            })?,
        },
        json: Cow::Owned(text),
        bin: (!bin.is_empty()).then_some(Cow::Owned(bin)),
    };
    glb.to_vec().map_err(|e| WriteError::Json(e.to_string()))
}
