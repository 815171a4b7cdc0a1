//! Baking: solve a scene once and write the lightmap and its metadata.
//!
//! Output files (all in one directory):
//! - `lightmap.exr`: linear HDR radiosity, RGB f32, one pixel per atlas texel
//!   (uncovered texels are 0);
//! - `lightmap.png`: the same, tone-mapped for viewing (see [`tone_map`]);
//! - `atlas.json`: the atlas size and, per surface, its name, object, texel
//!   rectangle and world-space corners;
//! - `stats.json`: element counts, iterations, residual, timings, solver;
//! - `uv-lightmaps/NN-node_mesh.exr` and `.png`: for every glTF mesh
//!   instance that brought its own lightmap UVs (`TEXCOORD_1`), the light
//!   resampled into them (`lightwire_scene::uvmap`), listed in `atlas.json`;
//! - `scene.glb`: the scene as glTF 2.0 with the lightmap on it
//!   ([`scene_glb`]), which any glTF viewer shows lit and an engine loads
//!   with its lightmap UVs (`TEXCOORD_1`).
//!
//! `lightwire serve` and `lightwire relay` serve the same `scene.glb` of
//! the version they hold (`service::http`), built by the same
//! [`scene_glb`] from the scene description clients get.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{Context, Result, bail};
use glam::{Quat, Vec2, Vec3};
use lightwire_protocol::{
    DEFAULT_TILE_SIZE, LightInfo, LightState, LightType, MaterialInfo, ObjectInfo, PixelFormat,
    SceneInfo, SurfaceInfo, tone,
};
use serde::Serialize;

use lightwire_scene::atlas::{Atlas, Chart};
use lightwire_scene::gltf::write::{
    GlbLightmap, GlbMaterial, GlbMesh, GlbNode, GlbPrimitive, GlbScene,
};
use lightwire_scene::{Light, LightKind, Patch, Pose, Scene};

/// Per-surface entry of `atlas.json`.
#[derive(Debug, Serialize)]
pub struct AtlasSurface {
    pub name: String,
    pub object: String,
    pub material: String,
    pub rect: Chart,
    /// World-space corners at the baked poses: origin, origin+u,
    /// origin+u+v, origin+v (a triangle repeats its third corner).
    pub corners: [[f32; 3]; 4],
    /// The corners' lightmap coordinates when they do not follow from
    /// `rect` (a patch lit on its mesh's own lightmap UVs), as the
    /// wire's `SurfaceInfo::uvs`.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub uvs: Vec<[f32; 2]>,
}

/// The lightmap coordinates of patch `p`'s four corners (as
/// `PatchShape::quad_corners` lists them: a triangle's third repeated) when
/// it is lit on its mesh's own lightmap UVs, normalized as the wire's
/// `SurfaceInfo::uvs`; empty otherwise (they follow from its chart's
/// rectangle).
pub fn corner_uvs(atlas: &Atlas, p: usize) -> Vec<[f32; 2]> {
    let Some(map) = atlas.lightmap_maps.get(p).copied().flatten() else {
        return Vec::new();
    };
    let c = atlas.charts[p];
    let size = Vec2::new(atlas.width as f32, atlas.height as f32);
    let base = Vec2::new(c.x as f32 + 0.5, c.y as f32 + 0.5);
    let last = if atlas.triangles.get(p).copied().unwrap_or(true) {
        Vec2::ONE
    } else {
        Vec2::Y
    };
    [Vec2::ZERO, Vec2::X, Vec2::ONE, last]
        .map(|st| ((base + map.to_chart(st)) / size).to_array())
        .to_vec()
}

/// `atlas.json`.
#[derive(Debug, Serialize)]
pub struct AtlasFile {
    pub scene: String,
    pub width: u32,
    pub height: u32,
    pub padding: u32,
    pub surfaces: Vec<AtlasSurface>,
    /// The lightmaps in the asset's own UVs (`uvmap`), one per glTF mesh
    /// instance with `TEXCOORD_1`; absent when there are none.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub uv_lightmaps: Vec<UvLightmapEntry>,
    /// The meshes lit on their own lightmap UVs (`--charts lightmap-uvs`):
    /// where each one's `[0, 1]²` lies in the atlas (an engine drawing its
    /// own mesh maps `TEXCOORD_1` into it, as Bevy's `Lightmap::uv_rect`
    /// does); absent when there are none.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub lightmap_blocks: Vec<LightmapBlock>,
}

/// A mesh's lightmap block in the atlas, in `atlas.json`.
#[derive(Debug, Serialize)]
pub struct LightmapBlock {
    /// `node/mesh` (`scene::UvMesh::name`), or the scene file's surface.
    pub mesh: String,
    /// The block in atlas texels: its `[0, 1]²` spans `[x, x + size] x [y,
    /// y + size]` (texel edges, not centres).
    pub x: u32,
    pub y: u32,
    pub size: u32,
    /// The same as normalized atlas coordinates: `[u0, v0, u1, v1]`.
    pub uv_rect: [f32; 4],
}

/// Per glTF mesh instance with its own lightmap UVs, in `atlas.json`.
#[derive(Debug, Serialize)]
pub struct UvLightmapEntry {
    /// `node/mesh` (`scene::UvMesh::name`).
    pub mesh: String,
    pub object: String,
    /// The linear lightmap and its tone-mapped view, relative to the bake's
    /// directory.
    pub exr: String,
    pub png: String,
    pub width: u32,
    pub height: u32,
    /// Pixels whose centre lies on a UV triangle, and those filled around
    /// them (`uvmap::PADDING`).
    pub covered: usize,
    pub padded: usize,
}

/// The directory of a bake's lightmaps in the assets' own UVs.
pub const UV_LIGHTMAPS: &str = "uv-lightmaps";

/// `stats.json`.
#[derive(Debug, Serialize)]
pub struct BakeStats {
    pub scene: String,
    pub solver: String,
    pub elements: usize,
    pub static_elements: usize,
    pub dynamic_elements: usize,
    pub atlas_width: u32,
    pub atlas_height: u32,
    pub iterations: usize,
    pub residual_fraction: f64,
    /// Wall-clock seconds for the whole solve (form factors included).
    pub seconds: f64,
    pub form_factor_seconds: f64,
    pub solve_seconds: f64,
    /// Emitted, absorbed and escaped power in W (sum over channels). The
    /// emitted power is the emitting surfaces' and what the lights and the
    /// sky deliver onto the surfaces (their direct light: a sun's or a
    /// sky's power is the part that falls on the scene); `light_power` is
    /// that second part.
    pub emitted_power: f64,
    pub light_power: f64,
    pub absorbed_power: f64,
    pub escaped_power: f64,
}

impl BakeStats {
    /// The statistics of a bake of `scene` by `solver`: the scene and atlas
    /// fields filled in, every measurement zero for the solver to set.
    pub fn new(scene: &Scene, atlas: &Atlas, solver: &str) -> Self {
        let dynamic = atlas.dynamic_element_count(scene);
        Self {
            scene: scene.name.clone(),
            solver: solver.to_string(),
            elements: atlas.elements.len(),
            static_elements: atlas.elements.len() - dynamic,
            dynamic_elements: dynamic,
            atlas_width: atlas.width,
            atlas_height: atlas.height,
            iterations: 0,
            residual_fraction: 0.0,
            seconds: 0.0,
            form_factor_seconds: 0.0,
            solve_seconds: 0.0,
            emitted_power: 0.0,
            light_power: 0.0,
            absorbed_power: 0.0,
            escaped_power: 0.0,
        }
    }
}

/// `surface(patch, its chart, its corners' lightmap UVs)` ([`corner_uvs`])
/// of every patch, in patch order.
fn per_surface<T>(
    scene: &Scene,
    atlas: &Atlas,
    surface: impl Fn(&Patch, &Chart, Vec<[f32; 2]>) -> T,
) -> Vec<T> {
    scene
        .patches
        .iter()
        .zip(&atlas.charts)
        .enumerate()
        .map(|(k, (p, chart))| surface(p, chart, corner_uvs(atlas, k)))
        .collect()
}

/// Describes the atlas for `atlas.json`.
pub fn atlas_file(scene: &Scene, atlas: &Atlas, poses: &[Pose]) -> AtlasFile {
    AtlasFile {
        scene: scene.name.clone(),
        width: atlas.width,
        height: atlas.height,
        padding: lightwire_scene::atlas::PADDING,
        surfaces: per_surface(scene, atlas, |p, chart, uvs| AtlasSurface {
            name: p.name.clone(),
            object: scene.objects[p.object as usize].name.clone(),
            material: scene.materials[p.material as usize].name.clone(),
            rect: *chart,
            corners: p
                .shape
                .transformed(&poses[p.object as usize])
                .quad_corners()
                .map(|c| c.to_array()),
            uvs,
        }),
        uv_lightmaps: Vec::new(),
        lightmap_blocks: scene
            .uv_meshes
            .iter()
            .zip(&atlas.blocks)
            .filter_map(|(mesh, block)| {
                let b = (*block)?;
                let (w, h) = (atlas.width as f32, atlas.height as f32);
                Some(LightmapBlock {
                    mesh: mesh.name.clone(),
                    x: b.x,
                    y: b.y,
                    size: b.w,
                    uv_rect: [
                        b.x as f32 / w,
                        b.y as f32 / h,
                        (b.x + b.w) as f32 / w,
                        (b.y + b.h) as f32 / h,
                    ],
                })
            })
            .collect(),
    }
}

/// A file name for mesh `k` called `name`: its index, then the name with
/// anything but letters, digits, `-` and `_` made `_`.
pub fn uv_lightmap_stem(k: usize, name: &str) -> String {
    let clean: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect();
    format!("{k:02}-{clean}")
}

/// Writes every glTF mesh instance's lightmap in its own UVs
/// (`uvmap::resample`, one mesh at a time) into `dir/uv-lightmaps/` as EXR
/// and PNG (tone-mapped with the atlas's white point, as `lightmap.png`,
/// so that meshes side by side match), and returns their `atlas.json`
/// entries. A mesh some of whose triangles lie on no patch (which a scene
/// Lightwire loaded does not have) is left out with a warning rather than
/// written with holes.
fn write_uv_lightmaps(
    dir: &Path,
    scene: &Scene,
    atlas: &Atlas,
    image: &[[f32; 3]],
) -> Result<Vec<UvLightmapEntry>> {
    if scene.uv_meshes.iter().all(|m| m.generated) {
        return Ok(Vec::new());
    }
    let sub = dir.join(UV_LIGHTMAPS);
    std::fs::create_dir_all(&sub).with_context(|| format!("creating {}", sub.display()))?;
    let locator = lightwire_scene::uvmap::Locator::new(&scene.patches);
    let white = white_point(image);
    let mut entries = Vec::with_capacity(scene.uv_meshes.len());
    for (k, mesh) in scene.uv_meshes.iter().enumerate() {
        if mesh.generated {
            // No asset holds these UVs: `scene.glb` carries the light.
            continue;
        }
        let size = lightwire_scene::uvmap::default_size(scene, mesh);
        let map = lightwire_scene::uvmap::resample(&locator, atlas, image, mesh, size);
        if map.unplaced > 0 {
            eprintln!(
                "warning: {}: {} of its triangles lie on no patch of the scene; its lightmap in its own UVs is not written",
                mesh.name, map.unplaced
            );
            continue;
        }
        let stem = uv_lightmap_stem(k, &mesh.name);
        let (exr, png) = (
            format!("{UV_LIGHTMAPS}/{stem}.exr"),
            format!("{UV_LIGHTMAPS}/{stem}.png"),
        );
        write_exr(&dir.join(&exr), map.width, map.height, &map.pixels)?;
        write_png_with(&dir.join(&png), map.width, map.height, &map.pixels, white)?;
        entries.push(UvLightmapEntry {
            mesh: mesh.name.clone(),
            object: scene.objects[mesh.object as usize].name.clone(),
            exr,
            png,
            width: map.width,
            height: map.height,
            covered: map.covered,
            padded: map.padded,
        });
    }
    Ok(entries)
}

/// Writes a row-major RGB f32 image as an OpenEXR file.
pub fn write_exr(path: &Path, width: u32, height: u32, pixels: &[[f32; 3]]) -> Result<()> {
    exr::prelude::write_rgb_file(path, width as usize, height as usize, |x, y| {
        let p = pixels[y * width as usize + x];
        (p[0], p[1], p[2])
    })
    .with_context(|| format!("writing {}", path.display()))
}

/// The exposure white point of an image: the 95th percentile of covered
/// texels' luminance (the one tone curve, [`lightwire_protocol::tone`]).
pub use lightwire_protocol::tone::white_point;

/// Maps HDR radiosity to packed 8-bit sRGB with the one tone curve
/// ([`lightwire_protocol::tone`]): exposure so that the 95th percentile of
/// covered texels' luminance maps to 1 ([`white_point`]), then
/// `1 - exp(-x)` and the sRGB transfer function.
pub fn tone_map(pixels: &[[f32; 3]]) -> Vec<u8> {
    tone::tone_map_image(pixels, white_point(pixels))
}

/// Writes the tone-mapped PNG.
pub fn write_png(path: &Path, width: u32, height: u32, pixels: &[[f32; 3]]) -> Result<()> {
    write_png_with(path, width, height, pixels, white_point(pixels))
}

/// Writes a PNG tone-mapped with a given white point (to show several
/// images, or a difference image, at one exposure).
pub fn write_png_with(
    path: &Path,
    width: u32,
    height: u32,
    pixels: &[[f32; 3]],
    white: f32,
) -> Result<()> {
    image::save_buffer(
        path,
        &tone::tone_map_image(pixels, white),
        width,
        height,
        image::ColorType::Rgb8,
    )
    .with_context(|| format!("writing {}", path.display()))
}

/// Writes a value as pretty JSON.
pub fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<()> {
    let text = serde_json::to_string_pretty(value)?;
    std::fs::write(path, text + "\n").with_context(|| format!("writing {}", path.display()))
}

/// Writes all bake outputs for per-element radiosity `values`.
/// Writes `lightmap.exr`, `lightmap.png`, `atlas.json`, `stats.json`,
/// `scene.glb` and, for glTF meshes with their own lightmap UVs, their
/// lightmaps in `uv-lightmaps/`, all of the image a client would receive
/// ([`crate::publish::lightmap`]).
pub fn write_outputs(
    dir: &Path,
    scene: &Scene,
    atlas: &Atlas,
    poses: &[Pose],
    values: &[Vec3],
    stats: &BakeStats,
) -> Result<()> {
    std::fs::create_dir_all(dir)
        .with_context(|| format!("creating output directory {}", dir.display()))?;
    // What a client would receive for this state (crate::publish).
    let validity = lightwire_solve::validity::Validity::compute(scene, atlas, poses);
    let image = crate::publish::lightmap(atlas, &validity, &mut values.to_vec());
    write_exr(&dir.join("lightmap.exr"), atlas.width, atlas.height, &image)?;
    write_png(&dir.join("lightmap.png"), atlas.width, atlas.height, &image)?;
    write_json(&dir.join("stats.json"), stats)?;
    let glb = scene_glb_lit(
        &describe(scene, atlas, poses),
        &image,
        None,
        (&scene.lights_at(&scene.lights, poses), scene.sky.as_ref()),
    )?;
    let path = dir.join(SCENE_GLB);
    std::fs::write(&path, glb).with_context(|| format!("writing {}", path.display()))?;
    let mut atlas_json = atlas_file(scene, atlas, poses);
    atlas_json.uv_lightmaps = write_uv_lightmaps(dir, scene, atlas, &image)?;
    write_json(&dir.join("atlas.json"), &atlas_json)?;
    Ok(())
}

/// The file name of the exported scene, in a bake's directory and on the
/// server (`/api/scenes/{id}/scene.glb`).
pub const SCENE_GLB: &str = "scene.glb";

/// The linear lightmap's file name, which `scene.glb` names: beside it in
/// a bake's directory, and relative to its URL on the server
/// (`/api/scenes/{id}/lightmap.exr`).
pub const LIGHTMAP_EXR: &str = "lightmap.exr";

/// A scene at `poses` as clients see it (the wire's [`SceneInfo`]: objects
/// with poses, materials, per surface its object-space corners as a client
/// draws them and its chart), the input of [`scene_glb`];
/// `service::wire::scene_info` is this at the initial poses.
pub fn describe(scene: &Scene, atlas: &Atlas, poses: &[Pose]) -> SceneInfo {
    SceneInfo {
        id: scene.name.clone(),
        atlas_width: atlas.width,
        atlas_height: atlas.height,
        tile_size: DEFAULT_TILE_SIZE,
        format: PixelFormat::Rgb9e5,
        objects: scene
            .objects
            .iter()
            .zip(poses)
            .map(|(o, p)| ObjectInfo {
                name: o.name.clone(),
                dynamic: o.dynamic,
                pose: lightwire_protocol::Pose {
                    translation: p.translation.to_array(),
                    rotation: p.rotation.to_array(),
                    scale: p.scale,
                },
            })
            .collect(),
        materials: scene
            .materials
            .iter()
            .map(|m| MaterialInfo {
                name: m.name.clone(),
                albedo: m.albedo.to_array(),
                emission: m.emission.to_array(),
            })
            .collect(),
        surfaces: per_surface(scene, atlas, |p, c, uvs| SurfaceInfo {
            name: p.name.clone(),
            object: p.object,
            material: p.material,
            corners: p.shape.quad_corners().map(|c| c.to_array()),
            rect: [c.x, c.y, c.w, c.h],
            uvs,
        }),
        lights: scene.lights.iter().map(light_info).collect(),
    }
}

/// A light as the wire describes it ([`LightInfo`]): its colour the
/// channels of its intensity over the largest (white for a black light,
/// which is off), its intensity the largest channel, so that `color ×
/// intensity` is what the solvers use; a point light's direction, which
/// nothing uses, straight down.
pub fn light_info(light: &Light) -> LightInfo {
    let largest = light.intensity.max_element();
    let (on, color) = if largest > 0.0 {
        (true, (light.intensity / largest).to_array())
    } else {
        (false, [1.0; 3])
    };
    let (kind, direction, cone, angular_radius) = match light.kind {
        LightKind::Point => (LightType::Point, Vec3::NEG_Y, [0.0; 2], 0.0),
        LightKind::Spot {
            direction,
            inner,
            outer,
        } => (LightType::Spot, direction, [inner, outer], 0.0),
        LightKind::Directional {
            direction,
            angular_radius,
        } => (LightType::Directional, direction, [0.0; 2], angular_radius),
    };
    LightInfo {
        name: light.name.clone(),
        kind,
        range: light.range,
        cone,
        angular_radius,
        state: LightState {
            on,
            color,
            intensity: largest.max(0.0),
            position: light.position.to_array(),
            direction: direction.to_array(),
        },
    }
}

/// `scene.glb`: the scene described by `info` with the lightmap `rgb`
/// (linear radiosity, row-major, one pixel per atlas texel, invalid texels
/// already filled) on it. Deterministic: the same input gives the same
/// bytes.
///
/// - One node and one mesh per object, named after it, with one primitive
///   per material the object uses (in material order). The static world's
///   node has the identity transform; a dynamic object's node has its pose
///   in `info` (rotation, translation, uniform scale) and the `extras`
///   `{"lightwire": {"dynamic": true}}`, so that importing the file again
///   (`scene::gltf::import`, `lightwire bake --scene scene.glb`) gives the
///   same dynamic objects.
/// - A surface is a quad drawn as the triangles (0, 1, 2) and (0, 2, 3) of
///   its corners, a triangle (a quad whose third corner repeats, PROTOCOL.md
///   §3) as (0, 1, 2) alone; vertices are not shared between surfaces.
///   Per vertex: POSITION (object space), NORMAL (the surface's),
///   `TEXCOORD_0` (metres along the surface's first and second edge, for an
///   engine's own textures) and `TEXCOORD_1`, the chart's corner texel
///   centres (`SurfaceInfo::corner_uvs`), so the lightmap lines up exactly as in the
///   clients.
/// - The light: every material is `KHR_materials_unlit` with the
///   tone-mapped lightmap (the one tone curve, [`tone_map`]) as its base
///   colour on `TEXCOORD_1`, so that any viewer shows the baked light
///   (three.js, Babylon.js, Blender, model-viewer read the extension; one
///   that does not shows the same texture lit by its own lights). The
///   physical material — albedo, emission in W/m² — is in the material's
///   `extras` and emission also in `emissiveFactor` (see
///   `scene::gltf::write`). `MOZ_lightmap` would keep the PBR material
///   but is read by few viewers, and it multiplies the map by the base
///   colour, which expects irradiance rather than the radiosity clients
///   stream.
/// - The asset's `extras` `{"lightwire": {"scene", "atlas": [w, h],
///   "lightmap": "lightmap.exr", "version"}}` name the linear lightmap (a
///   relative URI: beside the file in a bake, the snapshot route on the
///   server) and, on the server, the version shown.
///
/// Everything in `info` is checked (a relay's comes from its upstream):
/// indices, chart rectangles inside the atlas, finite corners and poses.
pub fn scene_glb(info: &SceneInfo, rgb: &[[f32; 3]], version: Option<u64>) -> Result<Vec<u8>> {
    scene_glb_lit(info, rgb, version, (&[], None))
}

/// [`scene_glb`] with the scene's point, spot and directional lights
/// (placed where the objects' poses in `info` put them) as
/// `KHR_lights_punctual` nodes after the objects' (a light riding with a
/// dynamic object as a child of its node; 683 lm/W, a sun's
/// angular radius in the light's `extras`,
/// `lightwire_scene::gltf::write::light_node`) and its sky in the asset's
/// `extras` (`{"lightwire": {"sky": {"zenith", "horizon"}}}`), so that
/// `lightwire bake --scene scene.glb` lights the same scene.
pub fn scene_glb_lit(
    info: &SceneInfo,
    rgb: &[[f32; 3]],
    version: Option<u64>,
    (lights, sky): (&[lightwire_scene::Light], Option<&lightwire_scene::Sky>),
) -> Result<Vec<u8>> {
    let (aw, ah) = (info.atlas_width, info.atlas_height);
    if aw == 0 || ah == 0 || rgb.len() as u64 != u64::from(aw) * u64::from(ah) {
        bail!("a lightmap of {} texels for a {aw}x{ah} atlas", rgb.len());
    }
    let materials: Vec<GlbMaterial> = info
        .materials
        .iter()
        .map(|m| GlbMaterial {
            name: m.name.clone(),
            base_color: Vec3::from_array(m.albedo),
            emission: Vec3::from_array(m.emission),
            base_color_texture: None,
        })
        .collect();
    // Per object, per material: the primitive being filled.
    let mut parts: Vec<BTreeMap<u32, GlbPrimitive>> = vec![BTreeMap::new(); info.objects.len()];
    for (i, s) in info.surfaces.iter().enumerate() {
        let what = || format!("surface {i} (\"{}\")", s.name);
        let [x, y, w, h] = s.rect.map(u64::from);
        if s.object as usize >= info.objects.len() || s.material as usize >= materials.len() {
            bail!("{} names a missing object or material", what());
        }
        if w < 2 || h < 2 || x + w > u64::from(aw) || y + h > u64::from(ah) {
            bail!(
                "{} has chart {:?} (x, y, width, height), not inside the {aw}x{ah} atlas",
                what(),
                s.rect
            );
        }
        let corners = s.corners.map(Vec3::from_array);
        if !corners.iter().all(|c| c.is_finite()) {
            bail!("{} has a corner that is not a finite number", what());
        }
        if !(s.uvs.is_empty()
            || s.uvs.len() == 4 && s.uvs.iter().flatten().all(|x| (0.0..=1.0).contains(x)))
        {
            bail!(
                "{} has {} lightmap coordinates: give none or four, each in [0, 1]",
                what(),
                s.uvs.len()
            );
        }
        // PROTOCOL.md §3: a triangle is a quad with its third corner repeated.
        let triangle = corners[2] == corners[3];
        let normal = (corners[1] - corners[0])
            .cross(corners[2] - corners[1])
            .normalize_or_zero();
        let (a, b) = (
            (corners[1] - corners[0]).length(),
            (corners[2] - corners[1]).length(),
        );
        let metres = [
            Vec2::ZERO,
            Vec2::new(a, 0.0),
            Vec2::new(a, b),
            Vec2::new(0.0, b),
        ];
        // PROTOCOL.md §3; glTF's UV origin is the image's first row, as
        // the atlas's, so v is not flipped.
        let uvs = s.corner_uvs(aw, ah).map(Vec2::from);
        let p = parts[s.object as usize]
            .entry(s.material)
            .or_insert_with(|| GlbPrimitive {
                positions: Vec::new(),
                normals: Some(Vec::new()),
                uv0: Some(Vec::new()),
                uv1: Some(Vec::new()),
                indices: Vec::new(),
                material: Some(s.material as usize),
            });
        let base =
            u32::try_from(p.positions.len()).context("too many vertices in one primitive")?;
        let n = if triangle { 3 } else { 4 };
        p.positions.extend_from_slice(&corners[..n]);
        for (list, values) in [(&mut p.uv0, &metres), (&mut p.uv1, &uvs)] {
            if let Some(list) = list {
                list.extend_from_slice(&values[..n]);
            }
        }
        if let Some(normals) = &mut p.normals {
            normals.extend(std::iter::repeat_n(normal, n));
        }
        p.indices.push([base, base + 1, base + 2]);
        if !triangle {
            p.indices.push([base, base + 2, base + 3]);
        }
    }
    let mut meshes = Vec::new();
    let mut nodes = Vec::new();
    for (o, prims) in info.objects.iter().zip(parts) {
        let mesh = (!prims.is_empty()).then(|| {
            meshes.push(GlbMesh {
                name: o.name.clone(),
                primitives: prims.into_values().collect(),
            });
            meshes.len() - 1
        });
        let mut node = GlbNode::new(o.name.clone(), mesh);
        let p = &o.pose;
        let (t, r) = (
            Vec3::from_array(p.translation),
            Quat::from_array(p.rotation),
        );
        if !(t.is_finite() && r.is_finite() && p.scale.is_finite() && p.scale > 0.0) {
            bail!("object \"{}\" has a pose that is not finite", o.name);
        }
        node.translation = t;
        node.rotation = r.normalize();
        node.scale = Vec3::splat(p.scale);
        if o.dynamic {
            node.extras = Some(serde_json::json!({ "lightwire": { "dynamic": true } }));
        }
        nodes.push(node);
    }
    let mut roots: Vec<usize> = (0..nodes.len()).collect();
    for light in lights {
        // A light riding with a dynamic object goes under its node, where
        // the object's pose puts it: reimported, it rides with it again.
        let parent = (light.object != lightwire_scene::STATIC_OBJECT)
            .then_some(light.object as usize)
            .filter(|&o| o < info.objects.len());
        let node = match parent {
            Some(o) => {
                let p = &info.objects[o].pose;
                let (t, r) = (
                    Vec3::from_array(p.translation),
                    Quat::from_array(p.rotation).normalize(),
                );
                let inverse = r.inverse();
                let mut local = light.clone();
                local.position = inverse * (light.position - t) / p.scale;
                if let lightwire_scene::LightKind::Spot { direction, .. }
                | lightwire_scene::LightKind::Directional { direction, .. } = &mut local.kind
                {
                    *direction = (inverse * *direction).normalize_or(*direction);
                }
                local
            }
            None => light.clone(),
        };
        nodes.push(lightwire_scene::gltf::write::light_node(&node));
        let index = nodes.len() - 1;
        match parent {
            Some(o) => nodes[o].children.push(index),
            None => roots.push(index),
        }
    }
    let doc = GlbScene {
        materials,
        images: Vec::new(),
        meshes,
        roots,
        nodes,
    };
    let mut png = Vec::new();
    {
        use image::ImageEncoder;
        image::codecs::png::PngEncoder::new(&mut png)
            .write_image(&tone_map(rgb), aw, ah, image::ExtendedColorType::Rgb8)
            .context("encoding the lightmap PNG")?;
    }
    let mut extras = serde_json::json!({
        "scene": info.id,
        "atlas": [aw, ah],
        "lightmap": LIGHTMAP_EXR,
    });
    if let Some(v) = version {
        extras["version"] = v.into();
    }
    if let Some(sky) = sky {
        extras["sky"] = serde_json::json!({
            "zenith": sky.zenith.to_array(),
            "horizon": sky.horizon.to_array(),
            "ground_albedo": sky.ground_albedo.to_array(),
        });
    }
    let lightmap = GlbLightmap {
        name: "lightmap".to_string(),
        png,
        asset_extras: Some(serde_json::json!({ "lightwire": extras })),
    };
    doc.to_glb_lit(&lightmap)
        .map_err(|e| anyhow::anyhow!("writing {SCENE_GLB} of \"{}\": {e}", info.id))
}
