//! `lightwire bench solve|dynamic|codec`: the benchmarks that write the
//! reports BENCHMARKS.md quotes.

use std::path::PathBuf;

use anyhow::{Context, Result};
use lightwire_scene::{Charts, LoadOptions, Scene};
use lightwire_server::bench;
use lightwire_solve::gpu;

/// `lightwire bench codec`'s arguments.
#[derive(clap::Args)]
pub(crate) struct CodecArgs {
    /// Scene files, each with a dynamic object; default: the four
    /// thesis scenes in scenes/.
    #[arg(long = "scene")]
    scenes: Vec<PathBuf>,
    /// Script names, comma-separated: scenes/scripts/<scene>/<name>.json
    /// if the scene has its own, else scenes/scripts/<name>.json.
    #[arg(long, value_delimiter = ',', default_value = "rotate,orbit")]
    scripts: Vec<String>,
    /// Directory of the scripts.
    #[arg(long, default_value = "scenes/scripts")]
    script_dir: PathBuf,
    /// Versions recorded after the starting pose.
    #[arg(long, default_value_t = 90)]
    versions: u32,
    /// Script samples (versions) per second.
    #[arg(long, default_value_t = 30.0)]
    rate: f64,
    /// How the solver follows moves: full, incremental or cross.
    #[arg(long, default_value = "cross")]
    method: gpu::Redistribution,
    /// Multiply every texel density by this factor.
    #[arg(long, default_value_t = 1.0)]
    density_scale: f32,
    /// Error budgets of the v2 codec, comma-separated.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "0,0.00390625,0.0078125,0.015625,0.03125"
    )]
    epsilons: Vec<f32>,
    /// The v1 codec's epsilon (its default in lightwire serve).
    #[arg(long, default_value_t = 1.0 / 256.0)]
    v1_epsilon: f32,
    /// Tile sizes, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "8")]
    tile_sizes: Vec<u16>,
    /// zstd levels, comma-separated (1..=22).
    #[arg(long, value_delimiter = ',', default_value = "3")]
    levels: Vec<i32>,
    /// Where recordings are cached.
    #[arg(long, default_value = "bench-out/codec")]
    out: PathBuf,
    /// Also write the results as JSON here.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Use the adapter whose name contains this.
    #[arg(long)]
    adapter: Option<String>,
}

/// The default scenes of the benchmarks: the four thesis scenes (§5.1)
/// and `cornell-blocks` (issue 15; static only, so `bench dynamic` leaves
/// it out).
fn bench_scenes() -> Vec<PathBuf> {
    [
        "cornell-small",
        "cornell-low",
        "cornell-large",
        "indirect-light",
        "cornell-blocks",
    ]
    .iter()
    .map(|name| PathBuf::from(format!("scenes/{name}.json")))
    .collect()
}

/// Whether the scene file has a dynamic object for `bench dynamic` to move.
fn has_dynamic_object(path: &std::path::Path, density_scale: f32) -> Result<bool> {
    let scene = Scene::load_with(path, LoadOptions::scaled(density_scale))
        .with_context(|| format!("loading {}", path.display()))?;
    Ok(scene.dynamic_objects().next().is_some())
}

pub(crate) fn bench_dynamic_command(
    mut scenes: Vec<PathBuf>,
    settings: bench::dynamic::Settings,
    json: Option<PathBuf>,
    adapter: Option<&str>,
) -> Result<()> {
    if scenes.is_empty() {
        // The default list: every benchmark scene that has something to move.
        for path in bench_scenes() {
            if has_dynamic_object(&path, settings.density_scale)? {
                scenes.push(path);
            } else {
                eprintln!(
                    "skipping {}: static only (no dynamic object)",
                    path.display()
                );
            }
        }
    } else {
        // Named scenes: refuse a static one before benchmarking anything.
        for path in &scenes {
            if !has_dynamic_object(path, settings.density_scale)? {
                anyhow::bail!(
                    "{} has no dynamic object to move (add one under \"objects\"); bench dynamic needs one",
                    path.display()
                );
            }
        }
    }
    let gpu = gpu::Device::new(adapter)?;
    eprintln!("adapter: {}", gpu.describe());
    let mut results = Vec::new();
    println!(
        "| scene | elements (dynamic) | method | ms/frame (median) | min | max | ms to first state | NRMSE | p95 rel | NRMSE where it changed (texels) | ms to corrected | NRMSE corrected | vs |"
    );
    println!("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |");
    for path in &scenes {
        let result = bench::dynamic::dynamic_scene(&gpu, path, &settings)
            .with_context(|| format!("benchmarking {}", path.display()))?;
        for m in &result.methods {
            println!(
                "| {} | {} ({}) | {} | {:.1} | {:.1} | {:.1} | {:.1} | {:.2}% | {:.1}% | {:.2}% ({}) | {:.0} | {:.2}% | {} |",
                result.scene,
                result.elements,
                result.dynamic_elements,
                m.name,
                m.ms_per_frame,
                m.ms_min,
                m.ms_max,
                m.ms_to_state,
                m.nrmse * 100.0,
                m.p95_rel * 100.0,
                m.nrmse_changed * 100.0,
                result.changed_texels,
                m.ms_to_corrected,
                m.nrmse_corrected * 100.0,
                result.reference
            );
        }
        results.push(result);
    }
    eprintln!("images: {}", settings.out.display());
    for result in &results {
        print!("{}", bench::dynamic::profile_table(result));
    }
    if let Some(json) = json {
        bench::write_json(&json, &results)?;
    }
    Ok(())
}

pub(crate) fn bench_codec_command(args: CodecArgs) -> Result<()> {
    let settings = bench::codec::Settings {
        versions: args.versions,
        rate: args.rate,
        method: args.method,
        density_scale: args.density_scale,
        epsilons: args.epsilons,
        v1_epsilon: args.v1_epsilon,
        tile_sizes: args.tile_sizes,
        levels: args.levels,
        out: args.out,
    };
    let CodecArgs {
        mut scenes,
        scripts,
        script_dir,
        json,
        adapter,
        ..
    } = args;
    if !(settings.rate.is_finite() && settings.rate > 0.0) {
        anyhow::bail!("--rate {} must be > 0", settings.rate);
    }
    if settings.versions == 0 {
        anyhow::bail!("--versions must be at least 1");
    }
    if let Some(e) = settings
        .epsilons
        .iter()
        .chain([&settings.v1_epsilon])
        .find(|e| !(e.is_finite() && (0.0..1.0).contains(*e)))
    {
        anyhow::bail!("epsilon {e} must be >= 0 and < 1");
    }
    if let Some(t) = settings.tile_sizes.iter().find(|t| **t == 0) {
        anyhow::bail!("tile size {t} must be positive");
    }
    if let Some(l) = settings.levels.iter().find(|l| !(1..=22).contains(*l)) {
        anyhow::bail!("zstd level {l} must be within 1..=22");
    }
    if scenes.is_empty() {
        for path in bench_scenes() {
            if has_dynamic_object(&path, settings.density_scale)? {
                scenes.push(path);
            }
        }
    }
    // Every script must exist before anything is recorded.
    let mut plan = Vec::new();
    for path in &scenes {
        let scene = Scene::load_with(path, LoadOptions::scaled(settings.density_scale))
            .with_context(|| format!("loading {}", path.display()))?;
        for name in &scripts {
            let script = bench::codec::script_path(&script_dir, &scene.name, name);
            if !script.is_file() {
                anyhow::bail!(
                    "no script {name:?} for {}: {} does not exist",
                    scene.name,
                    script.display()
                );
            }
            plan.push((path.clone(), name.clone(), script));
        }
    }
    let gpu = gpu::Device::new(adapter.as_deref())?;
    eprintln!("adapter: {}", gpu.describe());
    let configs = bench::codec::configs(&settings);
    let mut results = Vec::new();
    println!(
        "| scene | script | codec | epsilon | tile | zstd | bytes/version (mean) | p95 | max | Mbit/s at 30/s | encode µs (median) | decode µs (median) | max deviation | RMS deviation | keyframe bytes | settle bytes |"
    );
    println!(
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"
    );
    for (scene, name, script) in &plan {
        let recording = bench::codec::record(&gpu, scene, name, script, &settings)
            .with_context(|| format!("recording {} under {}", scene.display(), script.display()))?;
        for config in &configs {
            let r = bench::codec::run(&recording, *config)?;
            println!(
                "| {} | {} | {} | {:.5} | {} | {} | {:.0} | {} | {} | {:.3} | {:.0} | {:.0} | {:.4} | {:.5} | {} | {} |",
                r.scene,
                r.script,
                r.codec,
                r.epsilon,
                r.tile_size,
                r.zstd_level,
                r.bytes_mean,
                r.bytes_p95,
                r.bytes_max,
                r.mbit_s_at_30,
                r.encode_us_median,
                r.decode_us_median,
                r.max_deviation,
                r.rms_deviation,
                r.keyframe_bytes,
                r.settle_bytes
            );
            results.push(r);
        }
    }
    if let Some(json) = json {
        bench::write_json(&json, &results)?;
    }
    Ok(())
}

pub(crate) fn bench_solve_command(
    mut scenes: Vec<PathBuf>,
    density_scale: f32,
    json: Option<PathBuf>,
    adapter: Option<&str>,
    (hemicube_resolution, gather_resolution): (u32, u32),
    (shared_batch_ratio, cluster_triangles): (Option<f32>, bool),
    charts: Charts,
) -> Result<()> {
    if scenes.is_empty() {
        scenes = bench_scenes();
    }
    let gpu = gpu::Device::new(adapter)?;
    eprintln!("adapter: {}", gpu.describe());
    let defaults = gpu::ProgressiveOptions::default();
    let options = gpu::ProgressiveOptions {
        hemicube_resolution,
        shared_batch_ratio: shared_batch_ratio.unwrap_or(defaults.shared_batch_ratio),
        cluster_triangles,
        ..defaults
    };
    let gather_options = gpu::GatherOptions {
        hemicube_resolution: gather_resolution,
        ..Default::default()
    };
    let mut results = Vec::new();
    let fmt = |t: Option<f64>| t.map_or("-".to_string(), |t| format!("{t:.3}"));
    println!(
        "| scene | elements | solver | s to 10% | s to 1% | s to 0.1% | shots/s | NRMSE vs reference | p95 rel vs reference | reference s to same NRMSE | speed-up at equal NRMSE |"
    );
    println!("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |");
    for path in &scenes {
        let load = LoadOptions {
            density_scale,
            charts,
        };
        let result = bench::solve_scene(&gpu, path, load, options, gather_options)
            .with_context(|| format!("benchmarking {}", path.display()))?;
        for s in &result.solvers {
            let t: Vec<Option<f64>> = s.seconds_to.values().copied().collect();
            // BTreeMap orders "0.001" < "0.01" < "0.1"; print 10% first.
            // The speed-up compares the reference's time to this solver's
            // NRMSE with this solver's time to 0.1% (where it was measured).
            let speedup = match (s.reference_seconds_to_same_nrmse, t[0]) {
                (Some(r), Some(own)) if own > 0.0 => format!("{:.1}x", r / own),
                _ => "-".into(),
            };
            println!(
                "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
                result.scene,
                result.elements,
                s.name,
                fmt(t[2]),
                fmt(t[1]),
                fmt(t[0]),
                s.shots_per_second.map_or("-".into(), |v| format!("{v:.0}")),
                s.nrmse_vs_reference
                    .map_or("-".into(), |v| format!("{:.2}%", v * 100.0)),
                s.p95_rel_vs_reference
                    .map_or("-".into(), |v| format!("{:.1}%", v * 100.0)),
                fmt(s.reference_seconds_to_same_nrmse),
                speedup,
            );
        }
        results.push(result);
    }
    if let Some(json) = json {
        bench::write_json(&json, &results)?;
    }
    Ok(())
}

/// `lightwire bench meshes`: one tessellated Cornell box per triangle count.
pub(crate) fn bench_meshes_command(
    triangles: &[usize],
    settings: lightwire_server::bench::meshes::Settings,
    out: &std::path::Path,
    json: Option<PathBuf>,
    adapter: Option<&str>,
) -> Result<()> {
    let gpu = gpu::Device::new(adapter)?;
    eprintln!("adapter: {}", gpu.describe());
    let fmt = |t: Option<f64>| t.map_or("-".to_string(), |t| format!("{t:.2}"));
    println!(
        "| triangles | patches | .glb bytes | load s | atlas | texels/m | elements (texels) | setup s | s to 10% | s to 1% | shots | batches | unshot at end |"
    );
    println!("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |");
    let mut results = Vec::new();
    for &n in triangles {
        let r = lightwire_server::bench::meshes::run_mesh(&gpu, n, &settings, out)
            .with_context(|| format!("benchmarking a mesh of about {n} triangles"))?;
        println!(
            "| {} | {} | {} | {:.3} | {} x {} | {:.2} | {} ({}) | {:.2} | {} | {} | {} | {} | {:.2}% |",
            r.triangles,
            r.patches,
            r.file_bytes,
            r.load_seconds,
            r.atlas[0],
            r.atlas[1],
            r.texel_density,
            r.elements,
            r.texels,
            r.setup_seconds,
            fmt(r.seconds_to_10pct),
            fmt(r.seconds_to_1pct),
            r.shots,
            r.batches,
            r.unshot_at_end * 100.0
        );
        results.push(r);
    }
    if let Some(path) = json {
        std::fs::write(&path, serde_json::to_string_pretty(&results)?)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}
