//! One interface over the batch solvers: the CPU reference solver, the path
//! tracer and the progressive and gather GPU solvers, as `lightwire bake`
//! and `lightwire bench solve` drive them (a scene at fixed poses, solved
//! once).
//!
//! [`build`] makes any of them from a [`SolverKind`] and [`SolverSettings`];
//! [`BatchSolver`] is what every caller needs of one: run to a tolerance or
//! step under a budget, the radiosity per element, where the power went
//! ([`Power`]), the numbers of `stats.json` ([`SolveStats`]) and the line a
//! bake prints. Each solver keeps its own convergence measure:
//!
//! | solver | residual fraction | iterations | step |
//! | --- | --- | --- | --- |
//! | reference | power added by the last Jacobi sweep | sweeps | all the work in the first step |
//! | progressive | unshot power | shooters shot | batches until the budget is spent |
//! | gather | power changed by the last bounce | bounces | passes until the budget is spent |
//! | pathtrace | noise NRMSE of the estimates | paths per element | all the work in the first step |
//! | rays | power still to come, extrapolated from the last two bounces | bounces | casting the rays, then bounces until the budget is spent |
//!
//! The progressive batch solver ends with gathered corrections
//! ([`gpu::Correction`], [`SolverSettings::corrections`]): after
//! refinement, each round gathers once and refines what that changed; its
//! shots count as iterations. Stepping runs refinement only.
//!
//! All fractions are of the emitted power. The live service drives its
//! solvers through `service::live` instead, which also moves objects.

use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use glam::Vec3;

use crate::gpu::{self, Device, GatherSolver, ProgressiveSolver};
use crate::pathtrace::{self, Estimate, PathTracer, StdErrorFile};
use crate::rays::{self, RaySolver};
use crate::reference::{self, ReferenceSolver, Solution, SolveOptions};
use lightwire_scene::atlas::Atlas;
use lightwire_scene::{Pose, Scene};

/// Which solver computes the lightmap (`lightwire bake --solver`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum SolverKind {
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
    /// CPU: gathering over kept rays, each element's cosine rays cast once
    /// against the bounding volume hierarchy and the emitters by
    /// next-event estimation, then Jacobi bounces over what the rays hit
    /// (`rays`): for levels, where hemicubes per element are too slow.
    Rays,
}

impl SolverKind {
    /// The solver's name, as `stats.json` gives it.
    pub fn name(self) -> &'static str {
        match self {
            Self::Reference => "reference",
            Self::Progressive => "progressive",
            Self::Gather => "gather",
            Self::Pathtrace => "pathtrace",
            Self::Rays => "rays",
        }
    }

    /// Whether the solver runs on the GPU.
    pub fn is_gpu(self) -> bool {
        matches!(self, Self::Progressive | Self::Gather)
    }
}

/// How to build a solver; what a solver does not use is ignored.
#[derive(Debug, Clone, Default)]
pub struct SolverSettings {
    /// GPU solvers: the adapter whose name contains this; default: prefer
    /// a discrete GPU.
    pub adapter: Option<String>,
    /// GPU solvers: top-face resolution of the hemicubes (default: the
    /// solver's own).
    pub hemicube_resolution: Option<u32>,
    /// GPU solvers: publish indirect light only (gems §39.4).
    pub indirect_only: bool,
    /// Path tracer: paths per element (default [`pathtrace::DEFAULT_SPP`]).
    pub spp: Option<u32>,
    /// Progressive: gathered correction rounds after refinement
    /// ([`gpu::Correction`]; default [`DEFAULT_CORRECTIONS`]), swept with
    /// hemicubes or, where that is too slow, with rays
    /// ([`gpu::corrections_affordable`]).
    pub corrections: Option<u32>,
}

/// Gathered correction rounds the progressive batch solver runs by
/// default: on the Cornell scenes the first takes the NRMSE against the
/// reference from 2-4% to about 1%, the second to the gather solver's own
/// accuracy (docs/benchmarks-history.md, "Issue 15: gathered corrections").
pub const DEFAULT_CORRECTIONS: u32 = 2;

/// Receives progress while a solver is built and runs; every method does
/// nothing unless overridden.
pub trait Progress: Sync {
    /// A GPU solver is about to run on this adapter.
    fn adapter(&self, _description: &str) {}
    /// Something the user should know about how the solve runs.
    fn note(&self, _text: &str) {}
    /// Reference: `done` of `total` form-factor rows computed.
    fn form_factors(&self, _done: usize, _total: usize) {}
    /// Reference: one more Jacobi sweep; `residual` is its power fraction.
    fn iteration(&self, _iteration: usize, _residual: f64) {}
    /// Path tracer: `done` of `total` elements estimated.
    fn points(&self, _done: usize, _total: usize) {}
    /// Ray solver: `done` of `total` elements' rays cast.
    fn rays(&self, _done: usize, _total: usize) {}
}

/// Progress that goes nowhere.
pub struct Silent;

impl Progress for Silent {}

/// A [`Progress`] as the reference solver and the path tracer take it.
struct Forward<'a>(&'a dyn Progress);

impl reference::Progress for Forward<'_> {
    fn form_factors(&self, done: usize, total: usize) {
        self.0.form_factors(done, total);
    }
    fn iteration(&self, iteration: usize, residual: f64) {
        self.0.iteration(iteration, residual);
    }
}

impl pathtrace::Progress for Forward<'_> {
    fn points(&self, done: usize, total: usize) {
        self.0.points(done, total);
    }
}

/// Where a solution's power goes, in W with the RGB channels summed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Power {
    /// The emitting surfaces' power and what the lights and the sky
    /// deliver onto the surfaces (`Σ A D` of their direct light: a sun's
    /// or a sky's is the part that falls on the scene).
    pub emitted: f64,
    /// The lights' and the sky's part of `emitted`.
    pub lights: f64,
    pub absorbed: f64,
    /// Power that left the scene (never negative).
    pub escaped: f64,
}

/// A solve's numbers for `stats.json` (`stats.json` of a bake).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolveStats {
    /// Sweeps, shooters shot, bounces or paths per element.
    pub iterations: usize,
    /// The solver's convergence measure (see the module doc).
    pub residual_fraction: f64,
    /// Seconds computing form factors (reference only; 0 otherwise).
    pub form_factor_seconds: f64,
    /// Seconds solving: the reference's Jacobi sweeps; for the others,
    /// building the solver, running it and, after
    /// [`BatchSolver::solve`], reading the radiosity back.
    pub solve_seconds: f64,
}

/// A solver that solves one scene at fixed poses.
pub trait BatchSolver {
    /// The solver's name, as in [`SolverKind::name`].
    fn name(&self) -> &'static str;

    /// Runs until the solver's residual fraction is at most `tolerance`
    /// (the path tracer ignores it: it traces its fixed paths per element).
    fn solve(&mut self, tolerance: f64) -> Result<()>;

    /// Works for about `budget` (at least one unit of work, so that every
    /// call makes progress): progressive batches or gather passes. The
    /// reference solver (to its default tolerance) and the path tracer do
    /// all their work in the first step. Returns false, having done
    /// nothing, when there is nothing left to do.
    fn step(&mut self, budget: Duration) -> Result<bool>;

    /// The solver's convergence measure now (1 before any work, except
    /// for the progressive solver, which knows its unshot power from the
    /// start).
    fn residual_fraction(&self) -> f64;

    /// Work done so far: shooters shot (progressive), hemicubes rendered
    /// (gather), Jacobi sweeps (reference), paths traced (path tracer).
    fn work(&self) -> u64;

    /// Radiosity per element (W/m² per channel), in atlas element order.
    fn radiosity(&self) -> Result<Vec<Vec3>>;

    /// Where the power went.
    fn energy_balance(&self) -> Result<Power>;

    /// The numbers of `stats.json`.
    fn stats(&self) -> SolveStats;

    /// One line on how the solve went, for a person.
    fn summary(&self) -> String;

    /// Writes the solver's own output files into `dir` (created if
    /// missing): `std_error.json` for the path tracer, nothing for the
    /// others.
    fn write_extra_outputs(&self, _dir: &Path) -> Result<()> {
        Ok(())
    }
}

/// Builds the solver `kind` for `scene` at `poses` (one per object) on
/// `atlas`. The GPU solvers create their device from
/// [`SolverSettings::adapter`] and report it to `progress`; the reference
/// solver computes its form factors here.
pub fn build<'a>(
    kind: SolverKind,
    scene: &'a Scene,
    atlas: &'a Atlas,
    poses: &'a [Pose],
    settings: &SolverSettings,
    progress: &'a dyn Progress,
) -> Result<Box<dyn BatchSolver + 'a>> {
    Ok(match kind {
        SolverKind::Reference => Box::new(Reference::new(scene, atlas, poses, progress)?),
        SolverKind::Progressive => {
            let gpu = Device::new(settings.adapter.as_deref())?;
            progress.adapter(&gpu.describe());
            let defaults = gpu::ProgressiveOptions::default();
            let options = gpu::ProgressiveOptions {
                hemicube_resolution: settings
                    .hemicube_resolution
                    .unwrap_or(defaults.hemicube_resolution),
                indirect_only: settings.indirect_only,
                ..defaults.with_hints(&scene.solver)
            };
            let mut solver = Progressive::new(&gpu, scene, atlas, poses, options)?;
            let rounds = settings.corrections.unwrap_or(DEFAULT_CORRECTIONS);
            if rounds > 0 {
                let started = Instant::now();
                let correction = if gpu::corrections_affordable(scene, atlas) {
                    progress.note(&format!(
                        "after refinement, {rounds} gathered correction round(s): each draws the \
                         {1} patches into a hemicube at every one of the {0} elements, then \
                         refines (no progress is shown within a round)",
                        atlas.elements.len(),
                        scene.patches.len()
                    ));
                    // The gather sweep at its own default resolution: 64
                    // changed nothing measurable on cornell-large or
                    // cornell-blocks.
                    gpu::Correction::new(&gpu, scene, atlas, poses, gpu::GatherOptions::default())?
                } else {
                    progress.note(&format!(
                        "after refinement, {rounds} gathered correction round(s) by rays: \
                         {} elements x {} patches is above {} for hemicubes, so each of the \
                         {0} elements casts {} rays on the CPU, then refinement spreads the \
                         difference (no progress is shown within a round)",
                        atlas.elements.len(),
                        scene.patches.len(),
                        gpu::MAX_DEFAULT_SWEEP,
                        gpu::RAY_SIDE * gpu::RAY_SIDE,
                    ));
                    gpu::Correction::by_rays(&solver.solver)
                };
                solver = solver.with_corrections(correction, rounds);
                solver.seconds += started.elapsed().as_secs_f64();
            }
            solver._device = Some(gpu);
            Box::new(solver)
        }
        SolverKind::Gather => {
            let gpu = Device::new(settings.adapter.as_deref())?;
            progress.adapter(&gpu.describe());
            let defaults = gpu::GatherOptions::default();
            let options = gpu::GatherOptions {
                hemicube_resolution: settings
                    .hemicube_resolution
                    .unwrap_or(defaults.hemicube_resolution),
                indirect_only: settings.indirect_only,
                ..defaults
            };
            let mut solver = Gather::new(&gpu, scene, atlas, poses, options)?;
            solver._device = Some(gpu);
            Box::new(solver)
        }
        SolverKind::Pathtrace => Box::new(PathTraced::new(
            scene,
            atlas,
            poses,
            settings.spp.unwrap_or(pathtrace::DEFAULT_SPP),
            progress,
        )),
        SolverKind::Rays => Box::new(Rays::new(scene, atlas, poses, progress)),
    })
}

/// [`ReferenceSolver`] as a [`BatchSolver`].
pub struct Reference<'a> {
    solver: ReferenceSolver,
    progress: &'a dyn Progress,
    solution: Option<Solution>,
}

impl<'a> Reference<'a> {
    /// Computes the form factors (reporting to `progress`).
    pub fn new(
        scene: &Scene,
        atlas: &Atlas,
        poses: &[Pose],
        progress: &'a dyn Progress,
    ) -> Result<Self> {
        let solver = ReferenceSolver::new(scene, atlas, poses, &Forward(progress))?;
        Ok(Self {
            solver,
            progress,
            solution: None,
        })
    }

    /// The solver itself (form factors, sweeps to a given NRMSE).
    pub fn solver(&self) -> &ReferenceSolver {
        &self.solver
    }

    fn solution(&self) -> Result<&Solution> {
        self.solution
            .as_ref()
            .context("the reference solver has not solved yet")
    }
}

impl BatchSolver for Reference<'_> {
    fn name(&self) -> &'static str {
        SolverKind::Reference.name()
    }

    fn solve(&mut self, tolerance: f64) -> Result<()> {
        let options = SolveOptions {
            tolerance,
            ..SolveOptions::default()
        };
        self.solution = Some(self.solver.solve(options, &Forward(self.progress)));
        Ok(())
    }

    fn step(&mut self, _budget: Duration) -> Result<bool> {
        if self.solution.is_some() {
            return Ok(false);
        }
        self.solve(SolveOptions::default().tolerance)?;
        Ok(true)
    }

    fn residual_fraction(&self) -> f64 {
        self.solution.as_ref().map_or(1.0, |s| s.residual_fraction)
    }

    fn work(&self) -> u64 {
        self.solution.as_ref().map_or(0, |s| s.iterations as u64)
    }

    fn radiosity(&self) -> Result<Vec<Vec3>> {
        Ok(self.solution()?.radiosity.clone())
    }

    fn energy_balance(&self) -> Result<Power> {
        let balance = self.solver.energy_balance(self.solution()?);
        Ok(Power {
            emitted: balance.emitted.element_sum(),
            lights: balance.lights.element_sum(),
            absorbed: balance.absorbed.element_sum(),
            escaped: balance.escaped.element_sum(),
        })
    }

    fn stats(&self) -> SolveStats {
        SolveStats {
            iterations: self.solution.as_ref().map_or(0, |s| s.iterations),
            residual_fraction: self.residual_fraction(),
            form_factor_seconds: self.solver.form_factor_seconds,
            solve_seconds: self.solution.as_ref().map_or(0.0, |s| s.seconds),
        }
    }

    fn summary(&self) -> String {
        let stats = self.stats();
        format!(
            "converged after {} sweeps (residual {:.2e})",
            stats.iterations, stats.residual_fraction
        )
    }
}

/// [`ProgressiveSolver`] as a [`BatchSolver`].
pub struct Progressive {
    solver: ProgressiveSolver,
    /// The device, when [`build`] created it for this solver alone.
    _device: Option<Device>,
    shots: u64,
    batches: u64,
    /// Building, solving and stepping so far.
    seconds: f64,
    /// The radiosity read back at the end of [`BatchSolver::solve`].
    radiosity: Option<Vec<Vec3>>,
    /// Gathered corrections still to run after refinement, and what the
    /// rounds run so far did.
    correction: Option<(gpu::Correction, u32)>,
    corrections: Vec<gpu::CorrectionReport>,
}

impl Progressive {
    /// Uploads the scene to `gpu` (timed as part of the solve).
    pub fn new(
        gpu: &Device,
        scene: &Scene,
        atlas: &Atlas,
        poses: &[Pose],
        options: gpu::ProgressiveOptions,
    ) -> Result<Self> {
        let started = Instant::now();
        let solver = ProgressiveSolver::new(gpu, scene, atlas, poses, options)?;
        Ok(Self {
            solver,
            _device: None,
            shots: 0,
            batches: 0,
            seconds: started.elapsed().as_secs_f64(),
            radiosity: None,
            correction: None,
            corrections: Vec::new(),
        })
    }

    /// Adds `rounds` gathered corrections after refinement, by
    /// `correction` (built at this solver's poses).
    pub fn with_corrections(mut self, correction: gpu::Correction, rounds: u32) -> Self {
        self.correction = Some((correction, rounds));
        self
    }

    /// Runs the correction rounds not run yet, each refining until the
    /// unshot power is at most `tolerance` of the emitted power.
    pub fn correct(&mut self, tolerance: f64) -> Result<&[gpu::CorrectionReport]> {
        let started = Instant::now();
        if let Some((correction, rounds)) = &mut self.correction {
            while (self.corrections.len() as u32) < *rounds {
                let report = correction.round(&mut self.solver, tolerance)?;
                self.shots += report.shots;
                self.batches += report.batches;
                self.corrections.push(report);
            }
        }
        self.radiosity = None;
        self.seconds += started.elapsed().as_secs_f64();
        Ok(&self.corrections)
    }

    fn add(&mut self, report: gpu::StepReport, started: Instant) {
        self.shots += report.shots;
        self.batches += report.batches;
        self.seconds += started.elapsed().as_secs_f64();
    }
}

impl BatchSolver for Progressive {
    fn name(&self) -> &'static str {
        SolverKind::Progressive.name()
    }

    fn solve(&mut self, tolerance: f64) -> Result<()> {
        let started = Instant::now();
        let report = self.solver.solve(tolerance)?;
        self.add(report, started);
        self.correct(tolerance)?;
        let started = Instant::now();
        self.radiosity = Some(self.solver.radiosity()?);
        self.seconds += started.elapsed().as_secs_f64();
        Ok(())
    }

    /// Refinement only: the corrections run in [`BatchSolver::solve`] or
    /// [`Progressive::correct`].
    fn step(&mut self, budget: Duration) -> Result<bool> {
        let started = Instant::now();
        let report = self.solver.step(budget)?;
        self.radiosity = None;
        self.add(report, started);
        Ok(report.batches > 0)
    }

    fn residual_fraction(&self) -> f64 {
        self.solver.unshot_fraction()
    }

    fn work(&self) -> u64 {
        self.shots
    }

    fn radiosity(&self) -> Result<Vec<Vec3>> {
        match &self.radiosity {
            Some(values) => Ok(values.clone()),
            None => Ok(self.solver.radiosity()?),
        }
    }

    fn energy_balance(&self) -> Result<Power> {
        let balance = self.solver.energy_balance()?;
        Ok(Power {
            emitted: balance.emitted,
            lights: balance.lights,
            absorbed: balance.absorbed,
            escaped: (balance.shot - balance.received).max(0.0),
        })
    }

    fn stats(&self) -> SolveStats {
        SolveStats {
            iterations: self.shots as usize,
            residual_fraction: self.residual_fraction(),
            form_factor_seconds: 0.0,
            solve_seconds: self.seconds,
        }
    }

    fn summary(&self) -> String {
        let corrections = if self.corrections.is_empty() {
            String::new()
        } else {
            let residuals: Vec<String> = self
                .corrections
                .iter()
                .map(|c| format!("{:.2e}", c.residual_fraction))
                .collect();
            format!(
                " ({} gathered corrections, residuals {} of emitted power)",
                self.corrections.len(),
                residuals.join(", ")
            )
        };
        format!(
            "{} shots in {} batches{corrections}, unshot {:.2e} of emitted power, {:.2} s",
            self.shots,
            self.batches,
            self.residual_fraction(),
            self.seconds
        )
    }
}

/// [`GatherSolver`] as a [`BatchSolver`].
pub struct Gather {
    solver: GatherSolver,
    /// The device, when [`build`] created it for this solver alone.
    _device: Option<Device>,
    /// Building, solving and stepping so far.
    seconds: f64,
    /// The radiosity read back at the end of [`BatchSolver::solve`].
    radiosity: Option<Vec<Vec3>>,
}

impl Gather {
    /// Uploads the scene to `gpu` and integrates the direct light (timed
    /// as part of the solve).
    pub fn new(
        gpu: &Device,
        scene: &Scene,
        atlas: &Atlas,
        poses: &[Pose],
        options: gpu::GatherOptions,
    ) -> Result<Self> {
        let started = Instant::now();
        let solver = GatherSolver::new(gpu, scene, atlas, poses, options)?;
        Ok(Self {
            solver,
            _device: None,
            seconds: started.elapsed().as_secs_f64(),
            radiosity: None,
        })
    }
}

impl BatchSolver for Gather {
    fn name(&self) -> &'static str {
        SolverKind::Gather.name()
    }

    fn solve(&mut self, tolerance: f64) -> Result<()> {
        let started = Instant::now();
        self.solver.solve(tolerance)?;
        self.radiosity = Some(self.solver.radiosity()?);
        self.seconds += started.elapsed().as_secs_f64();
        Ok(())
    }

    fn step(&mut self, budget: Duration) -> Result<bool> {
        let started = Instant::now();
        let report = self.solver.step(budget)?;
        self.radiosity = None;
        self.seconds += started.elapsed().as_secs_f64();
        Ok(report.hemicubes > 0)
    }

    fn residual_fraction(&self) -> f64 {
        self.solver.change_fraction()
    }

    fn work(&self) -> u64 {
        self.solver.total_hemicubes()
    }

    fn radiosity(&self) -> Result<Vec<Vec3>> {
        match &self.radiosity {
            Some(values) => Ok(values.clone()),
            None => Ok(self.solver.radiosity()?),
        }
    }

    fn energy_balance(&self) -> Result<Power> {
        let balance = self.solver.energy_balance()?;
        Ok(Power {
            emitted: balance.emitted,
            lights: balance.lights,
            absorbed: balance.absorbed,
            escaped: (balance.emitted - balance.absorbed).max(0.0),
        })
    }

    fn stats(&self) -> SolveStats {
        SolveStats {
            iterations: self.solver.total_bounces() as usize,
            residual_fraction: self.residual_fraction(),
            form_factor_seconds: 0.0,
            solve_seconds: self.seconds,
        }
    }

    fn summary(&self) -> String {
        let resolution = self.solver.hemicube_resolution();
        format!(
            "{} bounces ({} hemicubes at {resolution}x{resolution}), last bounce changed {:.2e} of emitted power, {:.2} s",
            self.solver.total_bounces(),
            self.solver.total_hemicubes(),
            self.residual_fraction(),
            self.seconds
        )
    }
}

/// [`PathTracer`] at every element's sample point as a [`BatchSolver`].
pub struct PathTraced<'a> {
    tracer: PathTracer,
    scene: &'a Scene,
    atlas: &'a Atlas,
    poses: &'a [Pose],
    spp: u32,
    progress: &'a dyn Progress,
    /// Building the tracer and tracing.
    seconds: f64,
    /// The estimates and their `std_error.json`, once traced.
    traced: Option<(Vec<Estimate>, StdErrorFile)>,
}

impl<'a> PathTraced<'a> {
    /// Builds the tracer's ray caster (timed as part of the solve);
    /// `spp` paths per element.
    pub fn new(
        scene: &'a Scene,
        atlas: &'a Atlas,
        poses: &'a [Pose],
        spp: u32,
        progress: &'a dyn Progress,
    ) -> Self {
        let started = Instant::now();
        let tracer = PathTracer::new(scene, poses);
        Self {
            tracer,
            scene,
            atlas,
            poses,
            spp,
            progress,
            seconds: started.elapsed().as_secs_f64(),
            traced: None,
        }
    }

    fn traced(&self) -> Result<&(Vec<Estimate>, StdErrorFile)> {
        self.traced
            .as_ref()
            .context("the path tracer has not traced yet")
    }
}

impl BatchSolver for PathTraced<'_> {
    fn name(&self) -> &'static str {
        SolverKind::Pathtrace.name()
    }

    fn solve(&mut self, _tolerance: f64) -> Result<()> {
        let started = Instant::now();
        let estimates =
            self.tracer
                .estimate_elements(self.atlas, self.spp, &Forward(self.progress));
        self.seconds += started.elapsed().as_secs_f64();
        let errors = pathtrace::std_error_file(self.scene, self.atlas, self.spp, &estimates);
        self.traced = Some((estimates, errors));
        Ok(())
    }

    fn step(&mut self, _budget: Duration) -> Result<bool> {
        if self.traced.is_some() {
            return Ok(false);
        }
        self.solve(0.0)?;
        Ok(true)
    }

    fn residual_fraction(&self) -> f64 {
        self.traced
            .as_ref()
            .map_or(1.0, |(_, errors)| errors.summary.noise_nrmse)
    }

    fn work(&self) -> u64 {
        self.traced.as_ref().map_or(0, |(estimates, _)| {
            estimates.len() as u64 * u64::from(self.spp)
        })
    }

    fn radiosity(&self) -> Result<Vec<Vec3>> {
        Ok(self.traced()?.0.iter().map(|e| e.mean).collect())
    }

    fn energy_balance(&self) -> Result<Power> {
        let (estimates, _) = self.traced()?;
        let power = pathtrace::energy_balance(self.scene, self.atlas, self.poses, estimates);
        Ok(Power {
            emitted: power.emitted,
            lights: power.lights,
            absorbed: power.absorbed,
            escaped: (power.emitted - power.absorbed).max(0.0),
        })
    }

    fn stats(&self) -> SolveStats {
        SolveStats {
            iterations: self.spp as usize,
            residual_fraction: self.residual_fraction(),
            form_factor_seconds: 0.0,
            solve_seconds: self.seconds,
        }
    }

    fn summary(&self) -> String {
        match &self.traced {
            None => format!("{} paths per element, not traced yet", self.spp),
            Some((_, errors)) => format!(
                "{} paths per element in {:.2} s; noise NRMSE {:.2}%, relative standard error mean {:.2}%, max {:.1}%",
                self.spp,
                self.seconds,
                errors.summary.noise_nrmse * 100.0,
                errors.summary.mean_relative_std_error * 100.0,
                errors.summary.max_relative_std_error * 100.0
            ),
        }
    }

    fn write_extra_outputs(&self, dir: &Path) -> Result<()> {
        let (_, errors) = self.traced()?;
        std::fs::create_dir_all(dir)
            .with_context(|| format!("creating output directory {}", dir.display()))?;
        let path = dir.join("std_error.json");
        let text = serde_json::to_string_pretty(errors)?;
        std::fs::write(&path, text + "\n").with_context(|| format!("writing {}", path.display()))
    }
}

/// [`RaySolver`] as a [`BatchSolver`]: the rays are cast in the first
/// step (or solve), which reports them to [`Progress::rays`].
pub struct Rays<'a> {
    scene: &'a Scene,
    atlas: &'a Atlas,
    poses: &'a [Pose],
    progress: &'a dyn Progress,
    solver: Option<RaySolver>,
    /// Casting and bouncing so far.
    seconds: f64,
}

impl<'a> Rays<'a> {
    /// Nothing cast yet.
    pub fn new(
        scene: &'a Scene,
        atlas: &'a Atlas,
        poses: &'a [Pose],
        progress: &'a dyn Progress,
    ) -> Self {
        Self {
            scene,
            atlas,
            poses,
            progress,
            solver: None,
            seconds: 0.0,
        }
    }

    /// The solver, its rays cast now if they were not.
    fn cast(&mut self) -> &mut RaySolver {
        let (scene, atlas, poses, progress) = (self.scene, self.atlas, self.poses, self.progress);
        let seconds = &mut self.seconds;
        self.solver.get_or_insert_with(|| {
            let started = Instant::now();
            let solver = RaySolver::new(
                scene,
                atlas,
                poses,
                (rays::SIDE, crate::direct::GRID),
                &|done, total| progress.rays(done, total),
            );
            *seconds += started.elapsed().as_secs_f64();
            solver
        })
    }

    fn solver(&self) -> Result<&RaySolver> {
        self.solver
            .as_ref()
            .context("the ray solver has not cast its rays yet")
    }
}

impl BatchSolver for Rays<'_> {
    fn name(&self) -> &'static str {
        SolverKind::Rays.name()
    }

    fn solve(&mut self, tolerance: f64) -> Result<()> {
        let (atlas, progress) = (self.atlas, self.progress);
        let solver = self.cast();
        let started = Instant::now();
        solver.solve(atlas, tolerance, None, &|k, r| progress.iteration(k, r));
        self.seconds += started.elapsed().as_secs_f64();
        Ok(())
    }

    /// The first step casts the rays; each later one bounces until
    /// `budget` is spent, and there is nothing left to do once a bounce
    /// changes nothing.
    fn step(&mut self, budget: Duration) -> Result<bool> {
        if self.solver.is_none() {
            self.cast();
            return Ok(true);
        }
        if self.residual_fraction() <= 0.0 {
            return Ok(false);
        }
        let (atlas, progress) = (self.atlas, self.progress);
        let started = Instant::now();
        self.cast()
            .solve(atlas, 0.0, Some(budget), &|k, r| progress.iteration(k, r));
        self.seconds += started.elapsed().as_secs_f64();
        Ok(true)
    }

    fn residual_fraction(&self) -> f64 {
        self.solver
            .as_ref()
            .map_or(1.0, RaySolver::residual_fraction)
    }

    fn work(&self) -> u64 {
        self.solver.as_ref().map_or(0, |s| s.sweeps() as u64)
    }

    fn radiosity(&self) -> Result<Vec<Vec3>> {
        Ok(self.solver()?.radiosity().to_vec())
    }

    fn energy_balance(&self) -> Result<Power> {
        let (emitted, absorbed, lights) = self.solver()?.power();
        Ok(Power {
            emitted,
            lights,
            absorbed,
            escaped: (emitted - absorbed).max(0.0),
        })
    }

    fn stats(&self) -> SolveStats {
        SolveStats {
            iterations: self.work() as usize,
            residual_fraction: self.residual_fraction(),
            form_factor_seconds: 0.0,
            solve_seconds: self.seconds,
        }
    }

    fn summary(&self) -> String {
        match &self.solver {
            None => "no rays cast yet".to_string(),
            Some(s) => format!(
                "{} bounces over {} kept ray hits ({:.0} MB), {:.2e} of the emitted power still to come, {:.2} s",
                s.sweeps(),
                s.kept_entries(),
                s.kept_entries() as f64 * 8.0 / 1e6,
                s.residual_fraction(),
                self.seconds
            ),
        }
    }
}

#[cfg(test)]
mod tests {
    use clap::ValueEnum;

    use super::*;
    use lightwire_scene::LoadOptions;
    use lightwire_scene::load::load_scene;

    /// `stats.json` names a solver as `--solver` does.
    #[test]
    fn every_kind_is_named_as_on_the_command_line() {
        for kind in SolverKind::value_variants() {
            let value = kind.to_possible_value().map(|v| v.get_name().to_string());
            assert_eq!(value.as_deref(), Some(kind.name()));
        }
    }

    /// The CPU solvers do all their work in their first step and report
    /// it: nothing is left for a second step, and the power adds up.
    #[test]
    fn cpu_solvers_do_everything_in_the_first_step() -> Result<()> {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/plates.json");
        let (scene, atlas) = load_scene(&path, LoadOptions::default())?;
        let poses = scene.initial_poses();
        let settings = SolverSettings {
            spp: Some(4),
            ..SolverSettings::default()
        };
        for kind in [SolverKind::Reference, SolverKind::Pathtrace] {
            let mut solver = build(kind, &scene, &atlas, &poses, &settings, &Silent)?;
            assert_eq!(solver.name(), kind.name());
            assert!(solver.radiosity().is_err(), "{}", kind.name());
            assert!(solver.step(Duration::ZERO)?, "{}", kind.name());
            assert!(!solver.step(Duration::ZERO)?, "{}", kind.name());
            assert_eq!(solver.radiosity()?.len(), atlas.elements.len());
            assert!(solver.residual_fraction() < 1.0, "{}", kind.name());
            let power = solver.energy_balance()?;
            assert!(power.emitted > 0.0 && power.escaped >= 0.0, "{power:?}");
        }
        Ok(())
    }
}
