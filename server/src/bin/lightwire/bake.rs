//! `lightwire bake`: solve a scene once with any solver and write the
//! lightmap, its metadata, the solver's statistics and the lit scene as
//! glTF (`bake::write_outputs`).

use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use lightwire_server::bake::{self, BakeStats};
pub(crate) use lightwire_solve::solver::SolverKind;
use lightwire_solve::solver::{self, SolverSettings};

use lightwire_scene::LoadOptions;

use crate::args::ChartsArg;
use lightwire_solve::load::load_scene;

/// `lightwire bake`'s arguments.
#[derive(clap::Args)]
pub(crate) struct BakeArgs {
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
    #[command(flatten)]
    charts: ChartsArg,
    /// Reference: stop when one sweep adds less than this fraction of
    /// the emitted power. Progressive: stop when the unshot power is
    /// below this fraction of the emitted power. Gather: stop when one
    /// bounce changes less than this fraction of the emitted power. Rays:
    /// stop when the power the bounces still have to add (extrapolated
    /// from the last two) is below this fraction of the emitted power.
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
}

impl BakeArgs {
    pub(crate) fn run(self) -> Result<()> {
        bake_command(
            self.scene,
            self.solver,
            self.out,
            LoadOptions {
                density_scale: self.density_scale,
                charts: self.charts.charts,
            },
            SolveSettings {
                tolerance: self.tolerance,
                adapter: self.adapter,
                hemicube_resolution: self.hemicube_resolution,
                indirect_only: self.indirect_only,
                spp: self.spp,
                corrections: self.corrections,
            },
        )
    }
}

/// Solver settings from the command line.
pub(crate) struct SolveSettings {
    pub(crate) tolerance: f64,
    pub(crate) adapter: Option<String>,
    pub(crate) hemicube_resolution: Option<u32>,
    pub(crate) indirect_only: bool,
    pub(crate) spp: Option<u32>,
    pub(crate) corrections: Option<u32>,
}

/// How often a GPU solve prints how far it is.
const PROGRESS_EVERY: Duration = Duration::from_secs(5);

/// Prints solver progress to stderr: every 10% of the form factors, of
/// the path-traced elements or of the elements casting rays, and every
/// tenth sweep.
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

    /// `  WHAT:  NN% (done/total UNIT, S s)` once per new decile.
    fn decile_line(&self, what: &str, unit: &str, done: usize, total: usize) {
        if let Some(decile) = self.new_decile(done, total) {
            eprintln!(
                "  {what}: {:3}% ({done}/{total} {unit}, {:.1} s)",
                decile * 10,
                self.started.elapsed().as_secs_f64()
            );
        }
    }
}

impl solver::Progress for StderrProgress {
    fn adapter(&self, description: &str) {
        eprintln!("  adapter: {description}");
    }
    fn note(&self, text: &str) {
        eprintln!("  {text}");
    }
    fn points(&self, done: usize, total: usize) {
        self.decile_line("path tracing", "elements", done, total);
    }
    fn rays(&self, done: usize, total: usize) {
        self.decile_line("casting rays", "elements", done, total);
    }
    fn form_factors(&self, done: usize, total: usize) {
        self.decile_line("form factors", "rows", done, total);
    }
    fn iteration(&self, iteration: usize, residual: f64) {
        if iteration.is_multiple_of(10) || iteration == 1 {
            eprintln!("  sweep {iteration}: residual {residual:.3e} of emitted power");
        }
    }
}

fn bake_command(
    path: PathBuf,
    kind: SolverKind,
    out: PathBuf,
    load: LoadOptions,
    settings: SolveSettings,
) -> Result<()> {
    let tolerance = settings.tolerance;
    if settings.indirect_only && !kind.is_gpu() {
        anyhow::bail!("--indirect-only needs --solver progressive or gather");
    }
    if !(tolerance > 0.0 && tolerance < 1.0) {
        anyhow::bail!("--tolerance {tolerance} must be between 0 and 1");
    }
    match (settings.spp, kind) {
        (Some(spp), SolverKind::Pathtrace) if spp < 2 => {
            anyhow::bail!("--spp {spp}: the standard error needs at least 2 paths per element")
        }
        (Some(_), SolverKind::Pathtrace) | (None, _) => {}
        (Some(_), _) => anyhow::bail!("--spp needs --solver pathtrace"),
    }
    let started = Instant::now();
    let (scene, atlas) = load_scene(&path, load)?;
    for w in &scene.warnings {
        eprintln!("warning: {w}");
    }
    let poses = scene.initial_poses();
    eprintln!(
        "baking {} ({} elements, atlas {}x{})",
        scene.name,
        atlas.elements.len(),
        atlas.width,
        atlas.height
    );
    let progress = StderrProgress {
        started,
        last_decile: AtomicUsize::new(0),
    };
    let solver_settings = SolverSettings {
        adapter: settings.adapter,
        hemicube_resolution: settings.hemicube_resolution,
        indirect_only: settings.indirect_only,
        spp: settings.spp,
        corrections: settings.corrections,
    };
    let mut solver = solver::build(kind, &scene, &atlas, &poses, &solver_settings, &progress)?;
    if kind.is_gpu() {
        // The GPU solvers one batch (progressive) or one pass of hemicubes
        // (gather) at a time, so that a long solve says how far it is and
        // stops where `solve` would: after the batch or bounce that reaches
        // the tolerance, never in the middle of the next. `solve` below
        // then only finishes (corrections, readback).
        let mut last = Instant::now();
        while solver.residual_fraction() > tolerance {
            if !solver.step(Duration::ZERO)? {
                break;
            }
            if last.elapsed() >= PROGRESS_EVERY {
                last = Instant::now();
                let (done, residual) = match kind {
                    SolverKind::Gather => (
                        format!(
                            "{} bounces and {} hemicubes done",
                            solver.stats().iterations,
                            solver.work()
                        ),
                        "changed in the last bounce",
                    ),
                    _ => (format!("{} shots done", solver.work()), "unshot"),
                };
                eprintln!(
                    "  {}: {done}, {:.2e} of the emitted power {residual} (stop at {tolerance:.0e}), {:.1} s",
                    solver.name(),
                    solver.residual_fraction(),
                    started.elapsed().as_secs_f64()
                );
            }
        }
    }
    solver.solve(tolerance)?;
    let values = solver.radiosity()?;
    eprintln!("  {}", solver.summary());
    solver.write_extra_outputs(&out)?;
    let balance = solver.energy_balance()?;
    let solved = solver.stats();
    let stats = BakeStats {
        iterations: solved.iterations,
        residual_fraction: solved.residual_fraction,
        seconds: started.elapsed().as_secs_f64(),
        form_factor_seconds: solved.form_factor_seconds,
        solve_seconds: solved.solve_seconds,
        emitted_power: balance.emitted,
        light_power: balance.lights,
        absorbed_power: balance.absorbed,
        escaped_power: balance.escaped,
        ..BakeStats::new(&scene, &atlas, solver.name())
    };
    bake::write_outputs(&out, &scene, &atlas, &poses, &values, &stats)
        .with_context(|| format!("writing bake of {}", path.display()))?;
    eprintln!(
        "wrote {}/lightmap.exr, lightmap.png, atlas.json, stats.json, scene.glb in {:.1} s",
        out.display(),
        stats.seconds
    );
    // Generated UVs are in no asset: nothing is resampled into them.
    let own = scene.uv_meshes.iter().filter(|m| !m.generated).count();
    if own > 0 {
        eprintln!(
            "  and {}/{}/: the light in the asset's own TEXCOORD_1 of {own} mesh{} (listed in atlas.json)",
            out.display(),
            bake::UV_LIGHTMAPS,
            if own == 1 { "" } else { "es" }
        );
    }
    Ok(())
}
