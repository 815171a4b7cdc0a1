//! `lightwire bench solve|dynamic|meshes|codec|eye|lights`: the benchmarks that write the
//! reports BENCHMARKS.md quotes.

use std::path::PathBuf;

use anyhow::{Context, Result};
use lightwire_scene::{Charts, LoadOptions, Scene, SolverHints};
use lightwire_server::bench;
use lightwire_solve::gpu;

use crate::args::{ChartsArg, form_factor_threshold, shared_batch_ratio};

/// `lightwire bench`'s subcommands.
#[derive(clap::Subcommand)]
pub(crate) enum BenchCommand {
    /// Per scene: the progressive solver's time to 10%, 1% and 0.1%
    /// unshot power and shots per second; the reference and the gather
    /// solver on the same atlas, timed to the same fractions of power
    /// changed per sweep or bounce; NRMSE and p95 relative error against
    /// the reference over the non-emitting elements.
    Solve(SolveArgs),
    /// Per scene with a dynamic object (thesis Tables 5.1, 5.2): the box
    /// rotates a few degrees per frame; milliseconds per frame of gather,
    /// full progressive, incremental and cross redistribution, their NRMSE
    /// and p95 relative error (non-emitting elements) against a
    /// high-quality reference, and atlas PNGs with x5 difference images.
    Dynamic(DynamicArgs),
    /// Triangle meshes of growing size (wallner Table 1): tessellated
    /// Cornell boxes of about the given triangle counts, written as .glb,
    /// opened as scenes (load time, atlas, elements) and solved by the
    /// progressive solver to 1% unshot power or the time limit.
    Meshes(MeshesArgs),
    /// Per scene and transform script: records the solver's lightmap at
    /// every version (the script sampled at --rate), then runs the stream
    /// codecs over the recording side by side: bytes per version, encode
    /// and decode time, and the deviation a viewer sees.
    Codec(CodecArgs),
    /// Where a player looks: a lightmap (`lightwire bake`'s lightmap.exr,
    /// or the service's /api/scenes/{id}/lightmap.exr) read as a client
    /// reads it, bilinearly, at random points in view, against the path
    /// tracer at the same points: NRMSE, median and p95 relative error,
    /// the share of points more than 10% and 25% off.
    Eye(EyeArgs),
    /// Per scene with a light (issue 60): the first light switched off,
    /// on, dimmed, recoloured and moved while a session follows it, with
    /// each light's light kept apart and with shooting alone; ms to the
    /// first, the settled and the idle state, each one's NRMSE against
    /// the reference lit by the new light, a fresh session's beside them.
    Lights(LightsArgs),
}

/// `lightwire bench lights`'s arguments.
#[derive(clap::Args)]
pub(crate) struct LightsArgs {
    /// Scene files, each with a point, spot or directional light;
    /// default: cornell-point and window-sun in scenes/.
    #[arg(long = "scene")]
    scenes: Vec<PathBuf>,
    /// Multiply every texel density by this factor.
    #[arg(long, default_value_t = 1.0)]
    density_scale: f32,
    #[command(flatten)]
    charts: ChartsArg,
    /// Also write the results as JSON here.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Use the adapter whose name contains this.
    #[arg(long)]
    adapter: Option<String>,
    /// Skip the table of first answers by virtual lights and shadow-map
    /// points on the move.
    #[arg(long)]
    no_sweep: bool,
    /// Write each first answer of the sweep here as an atlas PNG with a
    /// x5 difference image from the reference.
    #[arg(long)]
    images: Option<PathBuf>,
    /// Only the sweep (skip the changes' table).
    #[arg(long, conflicts_with = "no_sweep")]
    sweep_only: bool,
}

impl LightsArgs {
    fn run(self) -> Result<()> {
        let scenes = if self.scenes.is_empty() {
            bench::lights::default_scenes(std::path::Path::new("scenes"))
        } else {
            self.scenes
        };
        let gpu = gpu::Device::new(self.adapter.as_deref())?;
        eprintln!("adapter: {}", gpu.describe());
        let mut results = Vec::new();
        let mut sweeps = Vec::new();
        let defaults = gpu::DynamicOptions::default();
        for path in &scenes {
            // With the service's basis and first answer, with the basis
            // and no first answer, and shooting alone with the first
            // answer.
            let variants = [
                (defaults.light_basis, defaults.first_bounce),
                (defaults.light_basis, None),
                (0, defaults.first_bounce),
            ];
            for (light_basis, first_bounce) in variants.into_iter().filter(|_| !self.sweep_only) {
                let settings = bench::lights::Settings {
                    density_scale: self.density_scale,
                    charts: self.charts.charts,
                    light_basis,
                    first_bounce,
                    images: None,
                };
                let result = bench::lights::run(&gpu, path, &settings)
                    .with_context(|| format!("bench lights on {}", path.display()))?;
                bench::lights::print(&result);
                results.push(result);
            }
            if !self.no_sweep {
                let settings = bench::lights::Settings {
                    density_scale: self.density_scale,
                    charts: self.charts.charts,
                    light_basis: 0,
                    first_bounce: defaults.first_bounce,
                    images: self.images.clone(),
                };
                let rows =
                    bench::lights::sweep(&gpu, path, &settings, &bench::lights::sweep_settings())
                        .with_context(|| format!("bench lights' sweep on {}", path.display()))?;
                bench::lights::print_sweep(&rows);
                sweeps.extend(rows);
            }
        }
        if let Some(json) = &self.json {
            if let Some(dir) = json.parent().filter(|d| !d.as_os_str().is_empty()) {
                std::fs::create_dir_all(dir)
                    .with_context(|| format!("creating {}", dir.display()))?;
            }
            let all = serde_json::json!({ "changes": results, "first_answer": sweeps });
            std::fs::write(json, serde_json::to_string_pretty(&all)? + "\n")
                .with_context(|| format!("writing {}", json.display()))?;
        }
        Ok(())
    }
}

/// `lightwire bench eye`'s arguments.
#[derive(clap::Args)]
pub(crate) struct EyeArgs {
    /// The scene file the lightmap was made from.
    #[arg(long)]
    scene: PathBuf,
    /// The lightmap: an OpenEXR image of the scene's atlas.
    #[arg(long)]
    lightmap: PathBuf,
    /// Points in view.
    #[arg(long, default_value_t = 300)]
    points: usize,
    /// Path tracer paths per point.
    #[arg(long, default_value_t = 4096)]
    spp: u32,
    /// Seeds the points and the paths.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Eyes stay this far (m) inside the static world's bounding box.
    #[arg(long, default_value_t = 0.1)]
    margin: f64,
    /// The density scale the lightmap was baked at.
    #[arg(long, default_value_t = 1.0)]
    density_scale: f32,
    #[command(flatten)]
    charts: ChartsArg,
    /// Also write every point (where, lightmap, truth) as JSON here
    /// [default: eye.json beside the lightmap].
    #[arg(long)]
    json: Option<PathBuf>,
}

impl EyeArgs {
    fn run(self) -> Result<()> {
        if self.points == 0 || self.spp < 2 {
            anyhow::bail!("--points must be at least 1 and --spp at least 2");
        }
        let settings = bench::eye::Settings {
            points: self.points,
            spp: self.spp,
            seed: self.seed,
            margin: self.margin,
            load: LoadOptions {
                density_scale: self.density_scale,
                charts: self.charts.charts,
            },
        };
        let result = bench::eye::run(&self.scene, &self.lightmap, &settings)?;
        bench::eye::print(&result);
        let json = self
            .json
            .unwrap_or_else(|| bench::eye::default_json(&self.lightmap));
        bench::write_json(&json, std::slice::from_ref(&result))?;
        println!("  points: {}", json.display());
        Ok(())
    }
}

impl BenchCommand {
    pub(crate) fn run(self) -> Result<()> {
        match self {
            Self::Solve(args) => args.run(),
            Self::Dynamic(args) => args.run(),
            Self::Meshes(args) => args.run(),
            Self::Codec(args) => bench_codec_command(args),
            Self::Eye(args) => args.run(),
            Self::Lights(args) => args.run(),
        }
    }
}

/// `lightwire bench solve`'s arguments.
#[derive(clap::Args)]
pub(crate) struct SolveArgs {
    /// Scene files; default: the four thesis scenes and cornell-blocks
    /// in scenes/.
    #[arg(long = "scene")]
    scenes: Vec<PathBuf>,
    /// Multiply every texel density by this factor.
    #[arg(long, default_value_t = 1.0)]
    density_scale: f32,
    /// Also write the results as JSON here.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Use the adapter whose name contains this.
    #[arg(long)]
    adapter: Option<String>,
    /// Progressive solver: top-face resolution of the hemicubes.
    #[arg(long, default_value_t = 64)]
    hemicube_resolution: u32,
    /// Gather solver: top-face resolution of the hemicubes.
    #[arg(long, default_value_t = 32)]
    gather_resolution: u32,
    /// Progressive solver: a batch fills the shooter slots its patch
    /// leaves free with the next patches holding at least this share
    /// of its unshot power; 0: one patch per batch [default: 0.5].
    #[arg(long, value_parser = shared_batch_ratio)]
    shared_batch_ratio: Option<f32>,
    /// Progressive solver: shoot every triangle as its own patch, not
    /// in clusters of near-coplanar triangles.
    #[arg(long)]
    no_clusters: bool,
    #[command(flatten)]
    charts: ChartsArg,
}

/// `lightwire bench dynamic`'s arguments.
#[derive(clap::Args)]
pub(crate) struct DynamicArgs {
    /// Scene files, each with a dynamic object; default: the four
    /// thesis scenes in scenes/ (cornell-blocks, static only, is
    /// skipped).
    #[arg(long = "scene")]
    scenes: Vec<PathBuf>,
    /// Multiply every texel density by this factor.
    #[arg(long, default_value_t = 1.0)]
    density_scale: f32,
    /// Frames each redistribution method follows.
    #[arg(long, default_value_t = 10)]
    frames: u32,
    /// Frames the gather solver follows (it solves from scratch).
    #[arg(long, default_value_t = 2)]
    gather_frames: u32,
    /// Rotation of the box per frame, degrees.
    #[arg(long, default_value_t = 2.0)]
    degrees: f32,
    /// Methods to run, comma-separated: gather, progressive,
    /// incremental, cross (default: all four).
    #[arg(long, value_delimiter = ',', default_values_t = bench::dynamic::Method::ALL)]
    methods: Vec<bench::dynamic::Method>,
    /// Directory for the images (a subdirectory per scene).
    #[arg(long, default_value = "bench-out/dynamic")]
    out: PathBuf,
    /// Also write the results as JSON here.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Use the adapter whose name contains this.
    #[arg(long)]
    adapter: Option<String>,
    /// Break each redistribution method's frames down by stage (a
    /// table per scene and method, and `profile` in the JSON).
    #[arg(long)]
    profile: bool,
    /// Clock of the breakdown's GPU stages: gpu (timestamp queries,
    /// CPU timing where the adapter has none) or cpu (submit and wait
    /// per stage).
    #[arg(long, value_enum, default_value = "gpu")]
    profile_clock: gpu::profile::Clock,
    /// Cross redistribution: moving patches are cut into tiles of at
    /// most this many texels per side [default: 5].
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=64))]
    cross_tile: Option<u32>,
    /// Cross redistribution: rays per side of the grid through each
    /// tile for the cross projection (thesis Alg. 4.5 gridSize); wins
    /// over the scene file's `solver.cross_grid` [default: 4].
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=i64::from(SolverHints::MAX_CROSS_GRID)))]
    cross_grid: Option<u32>,
    /// Cross redistribution: a receiver whose form factor to a tile is
    /// below this samples the tile's projection through a grid of half
    /// the side (0: never); wins over the scene file's
    /// `solver.cross_coarse_below` [default: 0.005].
    #[arg(long, value_parser = form_factor_threshold)]
    cross_coarse_below: Option<f32>,
    /// Progressive refinement (the full method's solves, every
    /// session's refinement): a batch fills the shooter slots its
    /// patch leaves free with the next patches holding at least this
    /// share of its unshot power; 0: one patch per batch [default: 0.5].
    #[arg(long, value_parser = shared_batch_ratio)]
    shared_batch_ratio: Option<f32>,
    /// Top-face resolution of the progressive solver's item-buffer
    /// hemicubes, in pixels (every method but gather) [default: 64].
    #[arg(long, value_parser = clap::value_parser!(u32).range(2..=512))]
    hemicube_resolution: Option<u32>,
    /// Cross redistribution: top-face resolution of the back hemicubes
    /// of shot radiosity (thesis §4.5.2); wins over the scene file's
    /// `solver.back_resolution` [default: 32].
    #[arg(long, value_parser = clap::value_parser!(u32).range(
        i64::from(SolverHints::MIN_BACK_RESOLUTION)..=i64::from(SolverHints::MAX_BACK_RESOLUTION)
    ))]
    back_resolution: Option<u32>,
    /// Gathered correction rounds whenever the session holds still
    /// (0: none) [default: 3]; frames end before them, and the last
    /// frame's corrected state is timed and judged apart.
    #[arg(long, value_parser = clap::value_parser!(u32).range(0..=8))]
    corrections: Option<u32>,
    #[command(flatten)]
    charts: ChartsArg,
}

/// `lightwire bench meshes`'s arguments.
#[derive(clap::Args)]
pub(crate) struct MeshesArgs {
    /// Triangle counts (each rounded to 24 k², k cells per quad side).
    #[arg(long, value_delimiter = ',', default_values_t = [1_000usize, 10_000, 100_000])]
    triangles: Vec<usize>,
    /// Multiply the default texel density (about 16,384 texels on the
    /// surface) by this factor.
    #[arg(long, default_value_t = 1.0)]
    density_scale: f32,
    /// Stop a solve after this many seconds.
    #[arg(long, default_value_t = 600)]
    max_seconds: u64,
    /// Directory for the generated .glb files.
    #[arg(long, default_value = "bench-out/meshes")]
    out: PathBuf,
    /// Also write the results as JSON here.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Use the adapter whose name contains this.
    #[arg(long)]
    adapter: Option<String>,
    /// A batch fills the shooter slots its patch leaves free with the
    /// next patches holding at least this share of its unshot power;
    /// 0: one patch per batch [default: 0.5].
    #[arg(long, value_parser = shared_batch_ratio)]
    shared_batch_ratio: Option<f32>,
    /// Shoot every triangle as its own patch, not in clusters of
    /// near-coplanar triangles (the solver before clusters).
    #[arg(long)]
    no_clusters: bool,
    #[command(flatten)]
    charts: ChartsArg,
}

impl SolveArgs {
    fn run(self) -> Result<()> {
        bench_solve_command(
            self.scenes,
            self.density_scale,
            self.json,
            self.adapter.as_deref(),
            (self.hemicube_resolution, self.gather_resolution),
            (self.shared_batch_ratio, !self.no_clusters),
            self.charts.charts,
        )
    }
}

impl DynamicArgs {
    fn run(self) -> Result<()> {
        let defaults = gpu::ProgressiveOptions::default();
        let progressive = gpu::ProgressiveOptions {
            cross_tile: self.cross_tile.unwrap_or(defaults.cross_tile),
            cross_grid: self.cross_grid.unwrap_or(defaults.cross_grid),
            cross_coarse_below: self
                .cross_coarse_below
                .unwrap_or(defaults.cross_coarse_below),
            shared_batch_ratio: self
                .shared_batch_ratio
                .unwrap_or(defaults.shared_batch_ratio),
            hemicube_resolution: self
                .hemicube_resolution
                .unwrap_or(defaults.hemicube_resolution),
            back_resolution: self.back_resolution.unwrap_or(defaults.back_resolution),
            ..defaults
        };
        let settings = bench::dynamic::Settings {
            frames: self.frames,
            gather_frames: self.gather_frames,
            degrees_per_frame: self.degrees,
            methods: self.methods,
            density_scale: self.density_scale,
            charts: self.charts.charts,
            progressive,
            stated: SolverHints {
                cross_grid: self.cross_grid,
                back_resolution: self.back_resolution,
                cross_coarse_below: self.cross_coarse_below,
            },
            gather: gpu::GatherOptions::default(),
            corrections: self
                .corrections
                .unwrap_or(gpu::DynamicOptions::default().corrections),
            out: self.out,
            profile: self.profile.then_some(self.profile_clock),
        };
        bench_dynamic_command(self.scenes, settings, self.json, self.adapter.as_deref())
    }
}

impl MeshesArgs {
    fn run(self) -> Result<()> {
        let settings = bench::meshes::Settings {
            density_scale: self.density_scale,
            limit: std::time::Duration::from_secs(self.max_seconds),
            progressive: gpu::ProgressiveOptions {
                shared_batch_ratio: self
                    .shared_batch_ratio
                    .unwrap_or(gpu::ProgressiveOptions::default().shared_batch_ratio),
                cluster_triangles: !self.no_clusters,
                ..Default::default()
            },
            charts: self.charts.charts,
        };
        bench_meshes_command(
            &self.triangles,
            settings,
            &self.out,
            self.json,
            self.adapter.as_deref(),
        )
    }
}

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

fn bench_dynamic_command(
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

fn bench_codec_command(args: CodecArgs) -> Result<()> {
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

fn bench_solve_command(
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
fn bench_meshes_command(
    triangles: &[usize],
    settings: bench::meshes::Settings,
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
