//! `lightwire bench meshes`: triangle meshes of growing size, in the spirit
//! of wallner Table 1 (triangles, elements, time): for each triangle count
//! a tessellated Cornell box ([`content::cornell_tessellated`]) is written
//! as a `.glb`, opened as a scene ([`load_scene`]: import, validation, one
//! chart per triangle, packing) and solved by the progressive GPU solver
//! until its unshot power falls to 10% and 1% of the emitted power, or a
//! time limit passes. Load and solve are timed on the wall clock; the
//! solver's setup (upload, validity, pipelines) is timed apart.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use serde::Serialize;

use lightwire_scene::gltf::content;
use lightwire_scene::{Charts, LoadOptions};
use lightwire_solve::gpu::{Device, ProgressiveOptions};
use lightwire_solve::load::load_scene;
use lightwire_solve::solver::{BatchSolver, Progressive};

/// One mesh's results (`--json`).
#[derive(Debug, Serialize)]
pub struct MeshResult {
    pub triangles: usize,
    /// Patches: triangles, or pairs of them sharing a chart.
    pub patches: usize,
    pub file: PathBuf,
    pub file_bytes: u64,
    /// Import, validation, charts and packing.
    pub load_seconds: f64,
    pub atlas: [u32; 2],
    /// Texels that stand for surface (triangle charts also hold texels
    /// above their diagonal, counted in `texels`).
    pub elements: usize,
    pub texels: usize,
    pub texel_density: f32,
    /// New solver: upload, validity rays, pipelines.
    pub setup_seconds: f64,
    pub seconds_to_10pct: Option<f64>,
    pub seconds_to_1pct: Option<f64>,
    pub shots: u64,
    /// Batches (one submission each; a batch may shoot several patches).
    pub batches: u64,
    /// Unshot fraction when the run stopped (at 1% or at the time limit).
    pub unshot_at_end: f64,
    pub seconds: f64,
}

/// How each mesh is opened and solved.
#[derive(Debug, Clone, Copy)]
pub struct Settings {
    /// Multiplies the default texel density of a `.glb`.
    pub density_scale: f32,
    /// A solve stops after this long.
    pub limit: Duration,
    pub progressive: ProgressiveOptions,
    /// How a mesh's triangles get charts (`LoadOptions`).
    pub charts: Charts,
}

/// The cells per quad side that give about `triangles` triangles (`24 k²`).
pub fn cells_for(triangles: usize) -> usize {
    ((triangles as f64 / 24.0).sqrt().round() as usize).max(1)
}

/// Runs one mesh of about `triangles` triangles.
pub fn run_mesh(
    gpu: &Device,
    triangles: usize,
    settings: &Settings,
    out: &Path,
) -> Result<MeshResult> {
    let k = cells_for(triangles);
    let glb = content::cornell_tessellated(k)
        .to_glb()
        .context("writing the tessellated Cornell box")?;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let file = out.join(format!("cornell-{}.glb", 24 * k * k));
    std::fs::write(&file, &glb).with_context(|| format!("writing {}", file.display()))?;

    let started = Instant::now();
    let (scene, atlas) = load_scene(
        &file,
        LoadOptions {
            density_scale: settings.density_scale,
            charts: settings.charts,
        },
    )?;
    let load_seconds = started.elapsed().as_secs_f64();
    let poses = scene.initial_poses();

    let started = Instant::now();
    let mut solver = Progressive::new(gpu, &scene, &atlas, &poses, settings.progressive)?;
    let setup_seconds = started.elapsed().as_secs_f64();

    let started = Instant::now();
    let (mut to_10, mut to_1) = (None, None);
    let mut batches = 0;
    let mut last_report = Instant::now();
    loop {
        let fraction = solver.residual_fraction();
        let t = started.elapsed().as_secs_f64();
        if fraction <= 0.1 && to_10.is_none() {
            to_10 = Some(t);
        }
        if fraction <= 0.01 {
            to_1 = Some(t);
            break;
        }
        if started.elapsed() > settings.limit {
            break;
        }
        // A zero budget runs one batch.
        if !solver.step(Duration::ZERO)? {
            break;
        }
        batches += 1;
        if last_report.elapsed() > Duration::from_secs(10) {
            eprintln!(
                "  {} triangles: {:.1} s, unshot {:.2}%, {} shots",
                24 * k * k,
                t,
                fraction * 100.0,
                solver.work()
            );
            last_report = Instant::now();
        }
    }
    Ok(MeshResult {
        triangles: 24 * k * k,
        patches: scene.patches.len(),
        file_bytes: glb.len() as u64,
        file,
        load_seconds,
        atlas: [atlas.width, atlas.height],
        elements: atlas.elements.iter().filter(|e| e.covers_surface()).count(),
        texels: atlas.elements.len(),
        texel_density: scene.texel_density,
        setup_seconds,
        seconds_to_10pct: to_10,
        seconds_to_1pct: to_1,
        shots: solver.work(),
        batches,
        unshot_at_end: solver.residual_fraction(),
        seconds: started.elapsed().as_secs_f64(),
    })
}
