//! `lightwire bake`: solve a scene once with any solver and write the
//! lightmap, its metadata and the solver's statistics.

use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use anyhow::{Context, Result};
use clap::ValueEnum;
use lightwire_server::bake::{self, BakeStats};
use lightwire_server::gpu;
use lightwire_server::pathtrace::{self, PathTracer};
use lightwire_server::reference::{self, ReferenceSolver, SolveOptions};

use crate::validate::load;

#[derive(Clone, Copy, ValueEnum)]
pub(crate) enum SolverKind {
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
pub(crate) struct SolveSettings {
    pub(crate) tolerance: f64,
    pub(crate) adapter: Option<String>,
    pub(crate) hemicube_resolution: Option<u32>,
    pub(crate) indirect_only: bool,
    pub(crate) spp: Option<u32>,
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

pub(crate) fn bake_command(
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
                iterations: solution.iterations,
                residual_fraction: solution.residual_fraction,
                seconds: started.elapsed().as_secs_f64(),
                form_factor_seconds: solver.form_factor_seconds,
                solve_seconds: solution.seconds,
                emitted_power: balance.emitted.element_sum(),
                absorbed_power: balance.absorbed.element_sum(),
                escaped_power: balance.escaped.element_sum(),
                ..BakeStats::new(&scene, &atlas, "reference")
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
                iterations: report.shots as usize,
                residual_fraction: report.unshot_fraction,
                seconds: started.elapsed().as_secs_f64(),
                solve_seconds,
                emitted_power: balance.emitted,
                absorbed_power: balance.absorbed,
                escaped_power: (balance.shot - balance.received).max(0.0),
                ..BakeStats::new(&scene, &atlas, "progressive")
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
                iterations: report.bounces as usize,
                residual_fraction: report.change_fraction,
                seconds: started.elapsed().as_secs_f64(),
                solve_seconds,
                emitted_power: balance.emitted,
                absorbed_power: balance.absorbed,
                escaped_power: (balance.emitted - balance.absorbed).max(0.0),
                ..BakeStats::new(&scene, &atlas, "gather")
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
                iterations: spp as usize,
                residual_fraction: errors.summary.noise_nrmse,
                seconds: started.elapsed().as_secs_f64(),
                solve_seconds,
                emitted_power: balance.emitted,
                absorbed_power: balance.absorbed,
                escaped_power: (balance.emitted - balance.absorbed).max(0.0),
                ..BakeStats::new(&scene, &atlas, "pathtrace")
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
