//! Baking: solve a scene once and write the lightmap and its metadata.
//!
//! Output files (all in one directory):
//! - `lightmap.exr`: linear HDR radiosity, RGB f32, one pixel per atlas texel
//!   (uncovered texels are 0);
//! - `lightmap.png`: the same, tone-mapped for viewing (see [`tone_map`]);
//! - `atlas.json`: the atlas size and, per surface, its name, object, texel
//!   rectangle and world-space corners;
//! - `stats.json`: element counts, iterations, residual, timings, solver.

use std::path::Path;

use anyhow::{Context, Result};
use glam::Vec3;
use lightwire_protocol::tone;
use serde::Serialize;

use crate::atlas::{Atlas, Chart};
use crate::scene::{Pose, Scene};

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
}

/// `atlas.json`.
#[derive(Debug, Serialize)]
pub struct AtlasFile {
    pub scene: String,
    pub width: u32,
    pub height: u32,
    pub padding: u32,
    pub surfaces: Vec<AtlasSurface>,
}

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
    /// Emitted, absorbed and escaped power in W (sum over channels).
    pub emitted_power: f64,
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
            absorbed_power: 0.0,
            escaped_power: 0.0,
        }
    }
}

/// Describes the atlas for `atlas.json`.
pub fn atlas_file(scene: &Scene, atlas: &Atlas, poses: &[Pose]) -> AtlasFile {
    AtlasFile {
        scene: scene.name.clone(),
        width: atlas.width,
        height: atlas.height,
        padding: crate::atlas::PADDING,
        surfaces: scene
            .patches
            .iter()
            .zip(&atlas.charts)
            .map(|(p, chart)| AtlasSurface {
                name: p.name.clone(),
                object: scene.objects[p.object as usize].name.clone(),
                material: scene.materials[p.material as usize].name.clone(),
                rect: *chart,
                corners: p
                    .shape
                    .transformed(&poses[p.object as usize])
                    .quad_corners()
                    .map(|c| c.to_array()),
            })
            .collect(),
    }
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
/// Writes `lightmap.exr`, `lightmap.png`, `atlas.json` and `stats.json`;
/// invalid texels ([`crate::validity`]) are filled from their neighbours
/// first.
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
    // Texels inside or under geometry take their visible neighbours' light,
    // so that a client's bilinear filter never blends them in.
    let mut values = values.to_vec();
    crate::validity::Validity::compute(scene, atlas, poses).dilate(atlas, &mut values);
    let image = atlas.to_image(&values);
    write_exr(&dir.join("lightmap.exr"), atlas.width, atlas.height, &image)?;
    write_png(&dir.join("lightmap.png"), atlas.width, atlas.height, &image)?;
    write_json(&dir.join("atlas.json"), &atlas_file(scene, atlas, poses))?;
    write_json(&dir.join("stats.json"), stats)?;
    Ok(())
}
