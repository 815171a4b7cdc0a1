//! `lightwire bench eye`: a baked or served lightmap read where a player
//! looks, against the path tracer at the same points
//! ([`lightwire_solve::eye`]).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use glam::DVec3;
use lightwire_scene::LoadOptions;
use lightwire_scene::load::load_scene;
use lightwire_solve::eye::{
    EyeReport, VisiblePoint, compare, lightmap_at, texel_at, visible_points,
};
use lightwire_solve::pathtrace::{PathTracer, Silent, SurfacePoint};
use serde::Serialize;

/// What `lightwire bench eye` measures and how.
pub struct Settings {
    /// Points in view to draw (those on emitters are then left out).
    pub points: usize,
    /// Paths per point of the path tracer.
    pub spp: u32,
    /// Seeds the eyes and directions (the path tracer's points are seeded
    /// from it too).
    pub seed: u64,
    /// Eyes stay this far (m) inside the static world's bounding box.
    pub margin: f64,
    pub load: LoadOptions,
}

/// One point: where, what the lightmap says and what the path tracer says.
#[derive(Serialize)]
pub struct PointResult {
    #[serde(flatten)]
    pub at: VisiblePoint,
    /// Where the lightmap was read: atlas image coordinates, texel
    /// `(x, y)`'s centre at `(x, y)` (bilinear between the four around).
    pub texel: Option<[f32; 2]>,
    pub lightmap: [f32; 3],
    pub truth: [f32; 3],
    pub truth_std_error: [f32; 3],
}

/// The report `--json` writes.
#[derive(Serialize)]
pub struct EyeResult {
    pub scene: String,
    pub lightmap: String,
    pub spp: u32,
    pub seconds: f64,
    #[serde(flatten)]
    pub report: EyeReport,
    /// Every point compared (the report's `points` counts them).
    pub samples: Vec<PointResult>,
}

/// Reads the lightmap EXR at `lightmap` (the atlas of `scene` loaded with
/// `settings.load`), draws the points in view and compares.
pub fn run(scene_path: &Path, lightmap: &Path, settings: &Settings) -> Result<EyeResult> {
    let started = Instant::now();
    let (scene, atlas) = load_scene(scene_path, settings.load)?;
    let (image, (w, h)) = read_exr(lightmap)?;
    if (w, h) != (atlas.width, atlas.height) {
        bail!(
            "{}: the image is {w}x{h} but {}'s atlas is {}x{} (bake it with the same --density-scale and --charts)",
            lightmap.display(),
            scene_path.display(),
            atlas.width,
            atlas.height
        );
    }
    let poses = scene.initial_poses();
    let tracer = PathTracer::new(&scene, &poses);
    let points = visible_points(
        &scene,
        tracer.raycaster(),
        settings.points,
        settings.margin,
        settings.seed,
    );
    if points.len() < settings.points {
        eprintln!(
            "  only {} of {} points in view found (few eyes in the open)",
            points.len(),
            settings.points
        );
    }
    let seen = points.len();
    // Emitters are left out, as the element metric leaves them out: nearly
    // exact in every solver and far brighter than the rest, they would
    // hide the error.
    let (points, surface): (Vec<VisiblePoint>, Vec<SurfacePoint>) = points
        .into_iter()
        .map(|p| {
            let at = tracer
                .surface_point(p.patch, p.st[0], p.st[1])
                .unwrap_or(SurfacePoint {
                    position: DVec3::from_array(p.position),
                    normal: DVec3::from_array(p.normal),
                    albedo: glam::Vec3::ZERO,
                    emission: glam::Vec3::ZERO,
                });
            (p, at)
        })
        .filter(|(_, at)| at.emission == glam::Vec3::ZERO)
        .unzip();
    eprintln!(
        "  path tracing {} points in view at {} paths each ({} on emitters left out)",
        surface.len(),
        settings.spp,
        seen - surface.len()
    );
    let truth = tracer.estimate_points(&surface, settings.spp, settings.seed, &Silent);
    let values: Vec<glam::Vec3> = points
        .iter()
        .map(|p| lightmap_at(&atlas, &image, p.patch, p.st))
        .collect();
    let report = compare(&values, &truth);
    Ok(EyeResult {
        scene: scene.name.clone(),
        lightmap: lightmap.display().to_string(),
        spp: settings.spp,
        seconds: started.elapsed().as_secs_f64(),
        report,
        samples: points
            .iter()
            .zip(&values)
            .zip(&truth)
            .map(|((p, v), t)| PointResult {
                at: *p,
                texel: texel_at(&atlas, p.patch, p.st).map(|xy| xy.to_array()),
                lightmap: v.to_array(),
                truth: t.mean.to_array(),
                truth_std_error: t.std_error.to_array(),
            })
            .collect(),
    })
}

/// An image's RGB texels, row-major, and its width and height.
pub type Rgb = (Vec<[f32; 3]>, (u32, u32));

/// The RGB of an OpenEXR image, row-major, and its size.
pub fn read_exr(path: &Path) -> Result<Rgb> {
    let image = exr::prelude::read_first_rgba_layer_from_file(
        path,
        |size, _| {
            (
                size.width(),
                vec![[0.0f32; 3]; size.width() * size.height()],
            )
        },
        |(w, px): &mut (usize, Vec<[f32; 3]>), at, (r, g, b, _a): (f32, f32, f32, f32)| {
            px[at.y() * *w + at.x()] = [r, g, b]
        },
    )
    .with_context(|| format!("reading {} as OpenEXR", path.display()))?;
    let size = image.layer_data.size;
    let (_, pixels) = image.layer_data.channel_data.pixels;
    Ok((pixels, (size.width() as u32, size.height() as u32)))
}

/// Prints a result as one block.
pub fn print(result: &EyeResult) {
    let r = &result.report;
    println!(
        "{}: {} points in view, {} against the path tracer at {} paths ({:.1} s)",
        result.scene, r.points, result.lightmap, result.spp, result.seconds
    );
    println!(
        "  NRMSE {:.1}%  median {:.1}%  p95 {:.1}%  >10% off: {:.0}%  >25% off: {:.0}%  (the path tracer's own noise: {:.1}%)",
        100.0 * r.nrmse,
        100.0 * r.median_rel,
        100.0 * r.p95_rel,
        100.0 * r.over_10,
        100.0 * r.over_25,
        100.0 * r.truth_noise
    );
    println!(
        "  the path tracer's relative standard error at those points: median {:.1}%, p95 {:.1}% (the floor under the median and p95)",
        100.0 * r.noise_rel[0],
        100.0 * r.noise_rel[1]
    );
    println!(
        "  over resampled points (5-95%) the NRMSE reads {:.1}-{:.1}%; the worst point carries {:.0}% of the squared error",
        100.0 * r.nrmse_interval[0],
        100.0 * r.nrmse_interval[1],
        100.0 * r.worst_share
    );
}

/// Where `--json` goes by default: beside the lightmap.
pub fn default_json(lightmap: &Path) -> PathBuf {
    lightmap.with_file_name("eye.json")
}
