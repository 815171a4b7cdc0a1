//! `lightwire`: the Lightwire server command. This file parses the command
//! line and dispatches; each subcommand lives in its own module.

mod bake;
mod bench;
mod serve;
mod validate;

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use lightwire_scene::{Charts, SolverHints};
use lightwire_solve::gpu;

use bake::{SolveSettings, SolverKind, bake_command};
use bench::{
    CodecArgs, bench_codec_command, bench_dynamic_command, bench_meshes_command,
    bench_solve_command,
};
use serve::{RelayFlags, ServeFlags, relay_command, serve_command};
use validate::validate_command;

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
        /// How a mesh's triangles get charts: each its own (`triangles`),
        /// two that form a parallelogram one (`pairs`), or pairs merged
        /// into the largest parallelograms they tile (`parallelograms`); or
        /// the static meshes on lightmap UVs: their own, else generated ones
        /// (`lightmap-uvs`, the default), or always generated (`generated`).
        #[arg(long, value_enum, default_value_t = Charts::default())]
        charts: Charts,
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
        /// Progressive: gathered correction rounds after refinement (each
        /// gathers once and refines what that changed; 0 = refinement only)
        /// [default: 2].
        #[arg(long)]
        corrections: Option<u32>,
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
        /// Progressive solver: a batch fills the shooter slots its patch
        /// leaves free with the next patches holding at least this share
        /// of its unshot power; 0: one patch per batch [default: 0.5].
        #[arg(long, value_parser = shared_batch_ratio)]
        shared_batch_ratio: Option<f32>,
        /// Progressive solver: shoot every triangle as its own patch, not
        /// in clusters of near-coplanar triangles.
        #[arg(long)]
        no_clusters: bool,
        /// How a mesh's triangles get charts: each its own (`triangles`),
        /// two that form a parallelogram one (`pairs`), or pairs merged
        /// into the largest parallelograms they tile (`parallelograms`); or
        /// the static meshes on lightmap UVs: their own, else generated ones
        /// (`lightmap-uvs`, the default), or always generated (`generated`).
        #[arg(long, value_enum, default_value_t = Charts::default())]
        charts: Charts,
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
        #[arg(long, value_delimiter = ',', default_values_t = lightwire_server::bench::dynamic::Method::ALL)]
        methods: Vec<lightwire_server::bench::dynamic::Method>,
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
        /// How a mesh's triangles get charts: each its own (`triangles`),
        /// two that form a parallelogram one (`pairs`), or pairs merged
        /// into the largest parallelograms they tile (`parallelograms`); or
        /// the static meshes on lightmap UVs: their own, else generated ones
        /// (`lightmap-uvs`, the default), or always generated (`generated`).
        #[arg(long, value_enum, default_value_t = Charts::default())]
        charts: Charts,
    },
    /// Triangle meshes of growing size (wallner Table 1): tessellated
    /// Cornell boxes of about the given triangle counts, written as .glb,
    /// opened as scenes (load time, atlas, elements) and solved by the
    /// progressive solver to 1% unshot power or the time limit.
    Meshes {
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
        /// How a mesh's triangles get charts: each its own (`triangles`),
        /// two that form a parallelogram one (`pairs`), or pairs merged
        /// into the largest parallelograms they tile (`parallelograms`); or
        /// the static meshes on lightmap UVs: their own, else generated ones
        /// (`lightmap-uvs`, the default), or always generated (`generated`).
        #[arg(long, value_enum, default_value_t = Charts::default())]
        charts: Charts,
    },
    /// Per scene and transform script: records the solver's lightmap at
    /// every version (the script sampled at --rate), then runs the stream
    /// codecs over the recording side by side: bytes per version, encode
    /// and decode time, and the deviation a viewer sees.
    Codec(CodecArgs),
}

/// A number from 0 to 1; `what` names it in the error.
fn zero_to_one(text: &str, what: &str) -> Result<f32, String> {
    match text.parse::<f32>() {
        Ok(x) if (0.0..=1.0).contains(&x) => Ok(x),
        _ => Err(format!("{text:?} is not {what}: give a number from 0 to 1")),
    }
}

/// `--shared-batch-ratio`: a share of a patch's power.
fn shared_batch_ratio(text: &str) -> Result<f32, String> {
    zero_to_one(text, "a share of a patch's power")
}

/// `--cross-coarse-below`: a form factor.
fn form_factor_threshold(text: &str) -> Result<f32, String> {
    zero_to_one(text, "a form factor")
}

fn main() -> ExitCode {
    // SAFETY: first thing in main, before any thread starts.
    unsafe { lightwire_adapter::quiet_device_select() };
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Bake {
            scene,
            solver,
            out,
            density_scale,
            charts,
            tolerance,
            adapter,
            hemicube_resolution,
            indirect_only,
            spp,
            corrections,
        } => bake_command(
            scene,
            solver,
            out,
            lightwire_scene::LoadOptions {
                density_scale,
                charts,
            },
            SolveSettings {
                tolerance,
                adapter,
                hemicube_resolution,
                indirect_only,
                spp,
                corrections,
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
                    shared_batch_ratio,
                    no_clusters,
                    charts,
                },
        } => bench_solve_command(
            scenes,
            density_scale,
            json,
            adapter.as_deref(),
            (hemicube_resolution, gather_resolution),
            (shared_batch_ratio, !no_clusters),
            charts,
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
                    profile,
                    profile_clock,
                    cross_tile,
                    cross_grid,
                    cross_coarse_below,
                    shared_batch_ratio,
                    hemicube_resolution,
                    back_resolution,
                    corrections,
                    charts,
                },
        } => bench_dynamic_command(
            scenes,
            lightwire_server::bench::dynamic::Settings {
                frames,
                gather_frames,
                degrees_per_frame: degrees,
                methods,
                density_scale,
                charts,
                progressive: {
                    let defaults = gpu::ProgressiveOptions::default();
                    gpu::ProgressiveOptions {
                        cross_tile: cross_tile.unwrap_or(defaults.cross_tile),
                        cross_grid: cross_grid.unwrap_or(defaults.cross_grid),
                        cross_coarse_below: cross_coarse_below
                            .unwrap_or(defaults.cross_coarse_below),
                        shared_batch_ratio: shared_batch_ratio
                            .unwrap_or(defaults.shared_batch_ratio),
                        hemicube_resolution: hemicube_resolution
                            .unwrap_or(defaults.hemicube_resolution),
                        back_resolution: back_resolution.unwrap_or(defaults.back_resolution),
                        ..defaults
                    }
                },
                stated: SolverHints {
                    cross_grid,
                    back_resolution,
                    cross_coarse_below,
                },
                gather: gpu::GatherOptions::default(),
                corrections: corrections.unwrap_or(gpu::DynamicOptions::default().corrections),
                out,
                profile: profile.then_some(profile_clock),
            },
            json,
            adapter.as_deref(),
        ),
        Command::Bench {
            what: BenchCommand::Codec(args),
        } => bench_codec_command(args),
        Command::Bench {
            what:
                BenchCommand::Meshes {
                    triangles,
                    density_scale,
                    max_seconds,
                    out,
                    json,
                    adapter,
                    shared_batch_ratio,
                    no_clusters,
                    charts,
                },
        } => bench_meshes_command(
            &triangles,
            lightwire_server::bench::meshes::Settings {
                density_scale,
                limit: std::time::Duration::from_secs(max_seconds),
                progressive: gpu::ProgressiveOptions {
                    shared_batch_ratio: shared_batch_ratio
                        .unwrap_or(gpu::ProgressiveOptions::default().shared_batch_ratio),
                    cluster_triangles: !no_clusters,
                    ..Default::default()
                },
                charts,
            },
            &out,
            json,
            adapter.as_deref(),
        ),
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
