//! `lightwire`: the Lightwire server command.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand, ValueEnum};

use lightwire_server::atlas::Atlas;
use lightwire_server::bake::{self, BakeStats};
use lightwire_server::bench;
use lightwire_server::gpu;
use lightwire_server::load::load_scene;
use lightwire_server::pathtrace::{self, PathTracer};
use lightwire_server::reference::{self, ReferenceSolver, SolveOptions};
use lightwire_server::scene::{LoadOptions, Scene};

#[derive(Parser)]
#[command(
    name = "lightwire",
    version,
    about = "Lightwire: a networked radiosity service"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Solve a scene once and write lightmap.exr, lightmap.png, atlas.json
    /// and stats.json.
    Bake {
        /// The scene file (JSON, see scenes/README.md).
        #[arg(long)]
        scene: PathBuf,
        /// Which solver computes the lightmap.
        #[arg(long, value_enum, default_value_t = SolverKind::Reference)]
        solver: SolverKind,
        /// Output directory (created if missing).
        #[arg(long)]
        out: PathBuf,
        /// Multiply every texel density of the scene by this factor.
        #[arg(long, default_value_t = 1.0)]
        density_scale: f32,
        /// Reference: stop when one sweep adds less than this fraction of
        /// the emitted power. Progressive: stop when the unshot power is
        /// below this fraction of the emitted power. Gather: stop when one
        /// bounce changes less than this fraction of the emitted power.
        #[arg(long, default_value_t = 1e-4)]
        tolerance: f64,
        /// GPU solvers: use the adapter whose name contains this
        /// (case-insensitive); default: prefer a discrete GPU.
        #[arg(long)]
        adapter: Option<String>,
        /// GPU solvers: top-face resolution of the hemicubes [default: 64
        /// for progressive, 32 for gather].
        #[arg(long)]
        hemicube_resolution: Option<u32>,
        /// GPU solvers: write indirect light only (gems §39.4).
        #[arg(long)]
        indirect_only: bool,
        /// Path tracer: paths per element [default: 256].
        #[arg(long)]
        spp: Option<u32>,
    },
    /// Benchmarks (run the release build).
    Bench {
        #[command(subcommand)]
        what: BenchCommand,
    },
    /// Serve scenes over HTTP and WebSocket: live lightmaps, REST, metrics.
    Serve(ServeFlags),
    /// Relay scenes of solvers to many viewers: subscribes to each upstream
    /// scene as a client and serves it with the same protocol, forwarding
    /// drivers' transforms; keeps serving the last version while an
    /// upstream is down.
    Relay(RelayFlags),
    /// Check scene files and print what they contain.
    Validate {
        /// Scene files.
        #[arg(required = true)]
        scenes: Vec<PathBuf>,
        /// Multiply every texel density by this factor.
        #[arg(long, default_value_t = 1.0)]
        density_scale: f32,
    },
}

#[derive(Subcommand)]
enum BenchCommand {
    /// Per scene: the progressive solver's time to 10%, 1% and 0.1%
    /// unshot power and shots per second; the reference and the gather
    /// solver on the same atlas, timed to the same fractions of power
    /// changed per sweep or bounce; NRMSE and p95 relative error against
    /// the reference over the non-emitting elements.
    Solve {
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
    },
    /// Per scene with a dynamic object (thesis Tables 5.1, 5.2): the box
    /// rotates a few degrees per frame; milliseconds per frame of gather,
    /// full progressive, incremental and cross redistribution, their NRMSE
    /// and p95 relative error (non-emitting elements) against a
    /// high-quality reference, and atlas PNGs with x5 difference images.
    Dynamic {
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
    },
    /// Per scene and transform script: records the solver's lightmap at
    /// every version (the script sampled at --rate), then runs the stream
    /// codecs over the recording side by side: bytes per version, encode
    /// and decode time, and the deviation a viewer sees.
    Codec(CodecArgs),
}

/// `lightwire bench codec`'s arguments.
#[derive(clap::Args)]
struct CodecArgs {
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

#[derive(Clone, Copy, ValueEnum)]
enum SolverKind {
    /// CPU: analytic form factors, ray-cast visibility, Jacobi iteration.
    Reference,
    /// GPU: progressive refinement with hemicube item buffers (thesis
    /// Alg. 4.2).
    Progressive,
    /// GPU: gather radiosity, a radiosity hemicube per element and bounce
    /// (thesis Alg. 4.1).
    Gather,
    /// CPU: Monte Carlo path tracing with next-event estimation at every
    /// element's sample point; also writes std_error.json.
    Pathtrace,
}

/// Solver settings from the command line.
struct SolveSettings {
    tolerance: f64,
    adapter: Option<String>,
    hemicube_resolution: Option<u32>,
    indirect_only: bool,
    spp: Option<u32>,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Bake {
            scene,
            solver,
            out,
            density_scale,
            tolerance,
            adapter,
            hemicube_resolution,
            indirect_only,
            spp,
        } => bake_command(
            scene,
            solver,
            out,
            density_scale,
            SolveSettings {
                tolerance,
                adapter,
                hemicube_resolution,
                indirect_only,
                spp,
            },
        ),
        Command::Validate {
            scenes,
            density_scale,
        } => validate_command(&scenes, density_scale),
        Command::Bench {
            what:
                BenchCommand::Solve {
                    scenes,
                    density_scale,
                    json,
                    adapter,
                    hemicube_resolution,
                    gather_resolution,
                },
        } => bench_solve_command(
            scenes,
            density_scale,
            json,
            adapter.as_deref(),
            (hemicube_resolution, gather_resolution),
        ),
        Command::Bench {
            what:
                BenchCommand::Dynamic {
                    scenes,
                    density_scale,
                    frames,
                    gather_frames,
                    degrees,
                    methods,
                    out,
                    json,
                    adapter,
                },
        } => bench_dynamic_command(
            scenes,
            bench::dynamic::Settings {
                frames,
                gather_frames,
                degrees_per_frame: degrees,
                methods,
                density_scale,
                progressive: gpu::ProgressiveOptions::default(),
                gather: gpu::GatherOptions::default(),
                out,
            },
            json,
            adapter.as_deref(),
        ),
        Command::Bench {
            what: BenchCommand::Codec(args),
        } => bench_codec_command(args),
        Command::Serve(flags) => serve_command(flags),
        Command::Relay(flags) => relay_command(flags),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn load(path: &std::path::Path, density_scale: f32) -> Result<(Scene, Atlas)> {
    Ok(load_scene(path, LoadOptions { density_scale })?)
}

fn validate_command(paths: &[PathBuf], density_scale: f32) -> Result<()> {
    let mut failed = 0;
    for path in paths {
        match load(path, density_scale) {
            Ok((scene, atlas)) => {
                let dynamic = atlas.dynamic_element_count(&scene);
                println!(
                    "{}: ok: scene \"{}\", {} surfaces, {} objects, atlas {}x{}, {} static + {} dynamic elements",
                    path.display(),
                    scene.name,
                    scene.patches.len(),
                    scene.objects.len(),
                    atlas.width,
                    atlas.height,
                    atlas.elements.len() - dynamic,
                    dynamic
                );
            }
            Err(e) => {
                eprintln!("error: {e:#}");
                failed += 1;
            }
        }
    }
    if failed > 0 {
        anyhow::bail!("{failed} of {} scene files are invalid", paths.len());
    }
    Ok(())
}

/// Prints solver progress to stderr: every 10% of the form factors or of
/// the path-traced elements, and every tenth sweep.
struct StderrProgress {
    started: Instant,
    last_decile: AtomicUsize,
}

impl StderrProgress {
    /// The decile `done` of `total` reached, if it is a new one.
    fn new_decile(&self, done: usize, total: usize) -> Option<usize> {
        let decile = done * 10 / total.max(1);
        (self.last_decile.fetch_max(decile, Ordering::Relaxed) < decile).then_some(decile)
    }
}

impl pathtrace::Progress for StderrProgress {
    fn points(&self, done: usize, total: usize) {
        if let Some(decile) = self.new_decile(done, total) {
            eprintln!(
                "  path tracing: {:3}% ({done}/{total} elements, {:.1} s)",
                decile * 10,
                self.started.elapsed().as_secs_f64()
            );
        }
    }
}

impl reference::Progress for StderrProgress {
    fn form_factors(&self, done: usize, total: usize) {
        if let Some(decile) = self.new_decile(done, total) {
            eprintln!(
                "  form factors: {:3}% ({done}/{total} rows, {:.1} s)",
                decile * 10,
                self.started.elapsed().as_secs_f64()
            );
        }
    }
    fn iteration(&self, iteration: usize, residual: f64) {
        if iteration.is_multiple_of(10) || iteration == 1 {
            eprintln!("  sweep {iteration}: residual {residual:.3e} of emitted power");
        }
    }
}

fn bake_command(
    path: PathBuf,
    solver: SolverKind,
    out: PathBuf,
    density_scale: f32,
    settings: SolveSettings,
) -> Result<()> {
    let tolerance = settings.tolerance;
    if settings.indirect_only && matches!(solver, SolverKind::Reference | SolverKind::Pathtrace) {
        anyhow::bail!("--indirect-only needs --solver progressive or gather");
    }
    if !(tolerance > 0.0 && tolerance < 1.0) {
        anyhow::bail!("--tolerance {tolerance} must be between 0 and 1");
    }
    match (settings.spp, solver) {
        (Some(spp), SolverKind::Pathtrace) if spp < 2 => {
            anyhow::bail!("--spp {spp}: the standard error needs at least 2 paths per element")
        }
        (Some(_), SolverKind::Pathtrace) | (None, _) => {}
        (Some(_), _) => anyhow::bail!("--spp needs --solver pathtrace"),
    }
    let started = Instant::now();
    let (scene, atlas) = load(&path, density_scale)?;
    let poses = scene.initial_poses();
    let dynamic = atlas.dynamic_element_count(&scene);
    eprintln!(
        "baking {} ({} elements, atlas {}x{})",
        scene.name,
        atlas.elements.len(),
        atlas.width,
        atlas.height
    );
    let (values, stats) = match solver {
        SolverKind::Reference => {
            let progress = StderrProgress {
                started,
                last_decile: AtomicUsize::new(0),
            };
            let solver = ReferenceSolver::new(&scene, &atlas, &poses, &progress)?;
            let options = SolveOptions {
                tolerance,
                ..SolveOptions::default()
            };
            let solution = solver.solve(options, &progress);
            let balance = solver.energy_balance(&solution);
            eprintln!(
                "  converged after {} sweeps (residual {:.2e})",
                solution.iterations, solution.residual_fraction
            );
            let stats = BakeStats {
                scene: scene.name.clone(),
                solver: "reference".into(),
                elements: atlas.elements.len(),
                static_elements: atlas.elements.len() - dynamic,
                dynamic_elements: dynamic,
                atlas_width: atlas.width,
                atlas_height: atlas.height,
                iterations: solution.iterations,
                residual_fraction: solution.residual_fraction,
                seconds: started.elapsed().as_secs_f64(),
                form_factor_seconds: solver.form_factor_seconds,
                solve_seconds: solution.seconds,
                emitted_power: balance.emitted.element_sum(),
                absorbed_power: balance.absorbed.element_sum(),
                escaped_power: balance.escaped.element_sum(),
            };
            (solution.radiosity, stats)
        }
        SolverKind::Progressive => {
            let gpu = gpu::Device::new(settings.adapter.as_deref())?;
            eprintln!("  adapter: {}", gpu.describe());
            let defaults = gpu::ProgressiveOptions::default();
            let options = gpu::ProgressiveOptions {
                hemicube_resolution: settings
                    .hemicube_resolution
                    .unwrap_or(defaults.hemicube_resolution),
                indirect_only: settings.indirect_only,
                ..defaults
            };
            let solve_started = Instant::now();
            let mut solver = gpu::ProgressiveSolver::new(&gpu, &scene, &atlas, &poses, options)?;
            let report = solver.solve(tolerance)?;
            let values = solver.radiosity()?;
            let solve_seconds = solve_started.elapsed().as_secs_f64();
            let balance = solver.energy_balance()?;
            eprintln!(
                "  {} shots in {} batches, unshot {:.2e} of emitted power, {:.2} s",
                report.shots, report.batches, report.unshot_fraction, solve_seconds
            );
            let stats = BakeStats {
                scene: scene.name.clone(),
                solver: "progressive".into(),
                elements: atlas.elements.len(),
                static_elements: atlas.elements.len() - dynamic,
                dynamic_elements: dynamic,
                atlas_width: atlas.width,
                atlas_height: atlas.height,
                iterations: report.shots as usize,
                residual_fraction: report.unshot_fraction,
                seconds: started.elapsed().as_secs_f64(),
                form_factor_seconds: 0.0,
                solve_seconds,
                emitted_power: balance.emitted,
                absorbed_power: balance.absorbed,
                escaped_power: (balance.shot - balance.received).max(0.0),
            };
            (values, stats)
        }
        SolverKind::Gather => {
            let gpu = gpu::Device::new(settings.adapter.as_deref())?;
            eprintln!("  adapter: {}", gpu.describe());
            let defaults = gpu::GatherOptions::default();
            let options = gpu::GatherOptions {
                hemicube_resolution: settings
                    .hemicube_resolution
                    .unwrap_or(defaults.hemicube_resolution),
                indirect_only: settings.indirect_only,
                ..defaults
            };
            let solve_started = Instant::now();
            let mut solver = gpu::GatherSolver::new(&gpu, &scene, &atlas, &poses, options)?;
            let report = solver.solve(tolerance)?;
            let values = solver.radiosity()?;
            let solve_seconds = solve_started.elapsed().as_secs_f64();
            let balance = solver.energy_balance()?;
            eprintln!(
                "  {} bounces ({} hemicubes at {}x{}), last bounce changed {:.2e} of emitted power, {:.2} s",
                report.bounces,
                report.hemicubes,
                solver.hemicube_resolution(),
                solver.hemicube_resolution(),
                report.change_fraction,
                solve_seconds
            );
            let stats = BakeStats {
                scene: scene.name.clone(),
                solver: "gather".into(),
                elements: atlas.elements.len(),
                static_elements: atlas.elements.len() - dynamic,
                dynamic_elements: dynamic,
                atlas_width: atlas.width,
                atlas_height: atlas.height,
                iterations: report.bounces as usize,
                residual_fraction: report.change_fraction,
                seconds: started.elapsed().as_secs_f64(),
                form_factor_seconds: 0.0,
                solve_seconds,
                emitted_power: balance.emitted,
                absorbed_power: balance.absorbed,
                escaped_power: (balance.emitted - balance.absorbed).max(0.0),
            };
            (values, stats)
        }
        SolverKind::Pathtrace => {
            let spp = settings.spp.unwrap_or(pathtrace::DEFAULT_SPP);
            let progress = StderrProgress {
                started,
                last_decile: AtomicUsize::new(0),
            };
            let solve_started = Instant::now();
            let tracer = PathTracer::new(&scene, &poses);
            let estimates = tracer.estimate_elements(&atlas, spp, &progress);
            let solve_seconds = solve_started.elapsed().as_secs_f64();
            let errors = pathtrace::std_error_file(&scene, &atlas, spp, &estimates);
            eprintln!(
                "  {spp} paths per element in {solve_seconds:.2} s; noise NRMSE {:.2}%, relative standard error mean {:.2}%, max {:.1}%",
                errors.summary.noise_nrmse * 100.0,
                errors.summary.mean_relative_std_error * 100.0,
                errors.summary.max_relative_std_error * 100.0
            );
            std::fs::create_dir_all(&out)
                .with_context(|| format!("creating output directory {}", out.display()))?;
            bake::write_json(&out.join("std_error.json"), &errors)?;
            let balance = pathtrace::energy_balance(&scene, &atlas, &poses, &estimates);
            let stats = BakeStats {
                scene: scene.name.clone(),
                solver: "pathtrace".into(),
                elements: atlas.elements.len(),
                static_elements: atlas.elements.len() - dynamic,
                dynamic_elements: dynamic,
                atlas_width: atlas.width,
                atlas_height: atlas.height,
                iterations: spp as usize,
                residual_fraction: errors.summary.noise_nrmse,
                seconds: started.elapsed().as_secs_f64(),
                form_factor_seconds: 0.0,
                solve_seconds,
                emitted_power: balance.emitted,
                absorbed_power: balance.absorbed,
                escaped_power: (balance.emitted - balance.absorbed).max(0.0),
            };
            (estimates.iter().map(|e| e.mean).collect(), stats)
        }
    };
    bake::write_outputs(&out, &scene, &atlas, &poses, &values, &stats)
        .with_context(|| format!("writing bake of {}", path.display()))?;
    eprintln!(
        "wrote {}/lightmap.exr, lightmap.png, atlas.json, stats.json in {:.1} s",
        out.display(),
        stats.seconds
    );
    Ok(())
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
    let scene = Scene::load_with(path, LoadOptions { density_scale })
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
        "| scene | elements (dynamic) | method | ms/frame (median) | min | max | NRMSE | p95 rel | vs |"
    );
    println!("| --- | --- | --- | --- | --- | --- | --- | --- | --- |");
    for path in &scenes {
        let result = bench::dynamic::dynamic_scene(&gpu, path, &settings)
            .with_context(|| format!("benchmarking {}", path.display()))?;
        for m in &result.methods {
            println!(
                "| {} | {} ({}) | {} | {:.1} | {:.1} | {:.1} | {:.2}% | {:.1}% | {} |",
                result.scene,
                result.elements,
                result.dynamic_elements,
                m.name,
                m.ms_per_frame,
                m.ms_min,
                m.ms_max,
                m.nrmse * 100.0,
                m.p95_rel * 100.0,
                result.reference
            );
        }
        results.push(result);
    }
    eprintln!("images: {}", settings.out.display());
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
        let scene = Scene::load_with(
            path,
            LoadOptions {
                density_scale: settings.density_scale,
            },
        )
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
) -> Result<()> {
    if scenes.is_empty() {
        scenes = bench_scenes();
    }
    let gpu = gpu::Device::new(adapter)?;
    eprintln!("adapter: {}", gpu.describe());
    let options = gpu::ProgressiveOptions {
        hemicube_resolution,
        ..Default::default()
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
        let result = bench::solve_scene(&gpu, path, density_scale, options, gather_options)
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

/// Flags of `lightwire serve`.
#[derive(clap::Args)]
struct ServeFlags {
    /// Scene files to serve (repeatable; each scene's name is its id).
    #[arg(long = "scene", num_args = 1.., action = clap::ArgAction::Append)]
    scenes: Vec<PathBuf>,
    /// Address to listen on [default: 127.0.0.1:8080].
    #[arg(long)]
    listen: Option<std::net::SocketAddr>,
    /// TOML config file (flags override it, it overrides defaults).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Serve without authentication: every client is an admin.
    #[arg(long)]
    dev: bool,
    /// Ticks per second per scene [default: 60].
    #[arg(long)]
    tick_hz: Option<f64>,
    /// Solver time per tick in milliseconds [default: 8].
    #[arg(long)]
    budget_ms: Option<f64>,
    /// Multiply every texel density [default: 1].
    #[arg(long)]
    density_scale: Option<f32>,
    /// Solver per scene [default: progressive].
    #[arg(long, value_enum)]
    solver: Option<lightwire_server::service::config::SolverChoice>,
    /// GPU solver: how moves are followed, full | incremental | cross
    /// [default: cross] (per scene: `scene_redistribution` in the config).
    #[arg(long)]
    redistribution: Option<lightwire_server::gpu::Redistribution>,
    /// GPU adapter whose name contains this (default: prefer a discrete GPU).
    #[arg(long)]
    adapter: Option<String>,
}

fn serve_command(flags: ServeFlags) -> Result<()> {
    use lightwire_server::service;

    init_logging();
    let mut config = load_config(flags.config.as_deref())?;
    if !flags.scenes.is_empty() {
        config.scenes = flags.scenes;
    }
    if let Some(listen) = flags.listen {
        config.listen = listen;
    }
    config.dev_mode |= flags.dev;
    if let Some(v) = flags.tick_hz {
        config.tick_hz = v;
    }
    if let Some(v) = flags.budget_ms {
        config.budget_ms = v;
    }
    if let Some(v) = flags.density_scale {
        config.density_scale = v;
    }
    if let Some(v) = flags.solver {
        config.solver = v;
    }
    if let Some(v) = flags.redistribution {
        config.redistribution = v;
    }
    if flags.adapter.is_some() {
        config.adapter = flags.adapter;
    }
    config.validate()?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    runtime.block_on(async move {
        let listener = tokio::net::TcpListener::bind(config.listen)
            .await
            .with_context(|| format!("cannot listen on {}", config.listen))?;
        let addr = listener.local_addr()?;
        config.listen = addr;
        if config.dev_mode && config.tokens.is_empty() {
            tracing::warn!(
                "DEVELOPMENT MODE: no tokens; every client is an admin and may move objects"
            );
            eprintln!(
                "*** DEVELOPMENT MODE: no authentication. Do not expose {addr} to a network. ***"
            );
        }
        // The line tools and tests wait for: where to connect.
        println!("lightwire listening on http://{addr} (dashboard: http://{addr}/)");
        let (stop_tx, stop_rx) = tokio::sync::watch::channel(false);
        tokio::spawn(async move {
            wait_for_signal().await;
            tracing::info!("shutting down: finishing ticks, closing connections");
            let _ = stop_tx.send(true);
        });
        service::serve(config, listener, stop_rx).await
    })
}

/// Flags of `lightwire relay`. Tokens for its own clients come from the
/// config file or `LIGHTWIRE_TOKENS`, as for `serve`; the token it presents
/// upstream from `upstream_token` or `LIGHTWIRE_UPSTREAM_TOKEN` (not a
/// flag, so that it does not show in `ps`).
#[derive(clap::Args)]
struct RelayFlags {
    /// A solver scene to relay: ws://HOST:PORT/ws/scenes/ID (repeatable;
    /// served here under the same path).
    #[arg(long = "upstream", num_args = 1.., action = clap::ArgAction::Append)]
    upstreams: Vec<String>,
    /// Address to listen on [default: 127.0.0.1:8080].
    #[arg(long)]
    listen: Option<std::net::SocketAddr>,
    /// TOML config file, the same format as `serve`'s (flags override it,
    /// it overrides defaults).
    #[arg(long)]
    config: Option<PathBuf>,
    /// No authentication for the relay's own clients: every client is an
    /// admin (the upstream still checks the relay's upstream token).
    #[arg(long)]
    dev: bool,
}

/// Logs to stderr, `RUST_LOG` or `info`.
fn init_logging() {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .with_writer(std::io::stderr)
        .init();
}

/// The configuration of `serve` and `relay` before their flags: the TOML
/// file when given (else the defaults), then `LIGHTWIRE_*` variables.
fn load_config(path: Option<&std::path::Path>) -> Result<lightwire_server::service::Config> {
    use lightwire_server::service::Config;
    let mut config = match path {
        Some(path) => Config::from_file(path)?,
        None => Config::default(),
    };
    config.apply_env(std::env::vars())?;
    Ok(config)
}

fn relay_command(flags: RelayFlags) -> Result<()> {
    init_logging();
    let mut config = load_config(flags.config.as_deref())?;
    if !flags.upstreams.is_empty() {
        config.upstreams = flags.upstreams;
    }
    if let Some(listen) = flags.listen {
        config.listen = listen;
    }
    config.dev_mode |= flags.dev;
    config.validate_relay()?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    runtime.block_on(async move {
        let listener = tokio::net::TcpListener::bind(config.listen)
            .await
            .with_context(|| format!("cannot listen on {}", config.listen))?;
        let addr = listener.local_addr()?;
        config.listen = addr;
        if config.dev_mode && config.tokens.is_empty() {
            eprintln!(
                "*** DEVELOPMENT MODE: no authentication. Do not expose {addr} to a network. ***"
            );
        }
        // The line tools and tests wait for: where to connect.
        println!(
            "lightwire relay listening on http://{addr} (relaying {})",
            config.upstreams.join(", ")
        );
        let (stop_tx, stop_rx) = tokio::sync::watch::channel(false);
        tokio::spawn(async move {
            wait_for_signal().await;
            tracing::info!("shutting down: closing connections");
            let _ = stop_tx.send(true);
        });
        lightwire_server::relay::relay(config, listener, stop_rx).await
    })
}

/// Resolves on SIGINT or SIGTERM.
async fn wait_for_signal() {
    let ctrl_c = tokio::signal::ctrl_c();
    #[cfg(unix)]
    {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut term) => {
                tokio::select! {
                    _ = ctrl_c => {}
                    _ = term.recv() => {}
                }
            }
            Err(_) => {
                let _ = ctrl_c.await;
            }
        }
    }
    #[cfg(not(unix))]
    {
        let _ = ctrl_c.await;
    }
}
