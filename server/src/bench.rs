//! `lightwire bench solve`: how fast each solver converges, on one machine,
//! in one run, so that the numbers are comparable.
//!
//! For every scene the progressive GPU solver runs batch by batch and the
//! wall-clock time is recorded when the unshot power first falls to 10%, 1%
//! and 0.1% of the emitted power. The reference solver then runs on the same
//! atlas (when the scene is small enough for its dense matrix); its times to
//! the same fractions are those at which one Jacobi sweep adds less than
//! that fraction of the emitted power (form factor time included), the
//! closest analogue of "unshot power" a Jacobi solver has. The row
//! `progressive+2corr` continues the same progressive run with the
//! default gathered corrections ([`lightwire_solve::gpu::Correction`], as `lightwire
//! bake` runs it): its 10% and 1% times are the progressive ones, its 0.1%
//! time includes the rounds (each refining to 0.1%; the gather sweep's
//! setup, like every solver's, is not counted). The gather GPU
//! solver (thesis Alg. 4.1) is Jacobi too, one bounce per sweep, and is
//! timed the same way: when the power changed by its last completed bounce,
//! `Σ A_i |ΔB_i|`, first falls to each fraction of the emitted power. The
//! progressive and gather lightmaps at 0.1% are compared with the converged
//! reference by [`lightwire_solve::accuracy::accuracy`] (over the elements that are not
//! inside or under geometry, [`lightwire_solve::validity`]): area-weighted NRMSE over the
//! non-emitting elements and the 95th percentile of the per-element
//! relative error.
//!
//! "At equal NRMSE" (issue 3): the reference solver is then timed again to
//! each GPU solver's NRMSE: its form factor time plus the Jacobi sweeps,
//! from `B = E`, until its own lightmap is that close to its converged one
//! ([`ReferenceSolver::sweeps_to_nrmse`]). A GPU solver's error against the
//! reference is mostly discretisation (hemicube visibility, disk form
//! factors), which the reference never has, so this asks how long the
//! reference takes to be as far from the answer as the GPU solver ends up.

pub mod codec;
pub mod dynamic;
pub mod eye;
pub mod lights;
pub mod meshes;

use std::path::Path;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use serde::Serialize;

use lightwire_scene::LoadOptions;
use lightwire_scene::atlas::Atlas;
use lightwire_solve::accuracy::accuracy_where;
use lightwire_solve::gpu::{Correction, Device, GatherOptions, ProgressiveOptions};
use lightwire_solve::load::load_scene;
use lightwire_solve::reference::{self, ReferenceSolver, SolveOptions};
use lightwire_solve::solver::{BatchSolver, DEFAULT_CORRECTIONS, Gather, Progressive};
use lightwire_solve::validity::Validity;

/// The unshot-power fractions at which times are recorded.
pub const FRACTIONS: [f64; 3] = [0.1, 0.01, 0.001];

/// One scene's results, in the `--json` shape the issue asks for.
#[derive(Debug, Serialize)]
pub struct SceneResult {
    pub scene: String,
    pub adapter: String,
    pub elements: usize,
    pub solvers: Vec<SolverResult>,
}

/// One solver's results on one scene.
#[derive(Debug, Serialize)]
pub struct SolverResult {
    pub name: String,
    /// Seconds until the fraction ("0.1", "0.01", "0.001") was reached;
    /// `null` if it never was.
    pub seconds_to: std::collections::BTreeMap<String, Option<f64>>,
    /// Progressive: shooters per second. Gather: hemicubes (elements
    /// gathered) per second. Reference: `null`.
    pub shots_per_second: Option<f64>,
    /// NRMSE against the converged reference solution, over the
    /// non-emitting elements, area-weighted ([`lightwire_solve::accuracy::accuracy`];
    /// `null` when the reference could not run).
    pub nrmse_vs_reference: Option<f64>,
    /// 95th percentile of the per-element relative error against the
    /// reference (same elements; `null` when the reference could not run).
    pub p95_rel_vs_reference: Option<f64>,
    /// Seconds the reference solver needs, form factors included, to come
    /// within `nrmse_vs_reference` of its own converged lightmap (`null`
    /// for the reference itself, or when it could not run).
    pub reference_seconds_to_same_nrmse: Option<f64>,
}

/// The converged reference, kept with its solver so that other solvers'
/// errors can be turned into reference time.
struct Reference {
    solver: ReferenceSolver,
    radiosity: Vec<glam::Vec3>,
    /// Texels inside or under geometry, left out of every comparison.
    validity: Validity,
}

/// A solver's error against the reference and the reference's time to it.
#[derive(Default)]
struct Comparison {
    nrmse: Option<f64>,
    p95_rel: Option<f64>,
    reference_seconds: Option<f64>,
}

impl Reference {
    /// Accuracy of `lightmap` against the reference, and the reference's
    /// time (form factors plus sweeps) to the same NRMSE.
    fn compare(&self, atlas: &Atlas, lightmap: &[glam::Vec3]) -> Comparison {
        let keep = self.validity.keep();
        let Some(error) = accuracy_where(atlas, lightmap, &self.radiosity, &keep) else {
            return Comparison::default();
        };
        let max_sweeps = SolveOptions::default().max_iterations;
        let seconds = self
            .solver
            .sweeps_to_nrmse(atlas, &self.radiosity, error.nrmse, max_sweeps, &keep)
            .map(|(_, sweeps)| self.solver.form_factor_seconds + sweeps);
        Comparison {
            nrmse: Some(error.nrmse),
            p95_rel: Some(error.p95_rel),
            reference_seconds: seconds,
        }
    }
}

fn seconds_map(times: &[Option<f64>; 3]) -> std::collections::BTreeMap<String, Option<f64>> {
    FRACTIONS
        .iter()
        .zip(times)
        .map(|(f, t)| (f.to_string(), *t))
        .collect()
}

/// Records when the reference solver's sweeps pass each fraction.
struct SweepClock {
    started: Instant,
    times: Mutex<[Option<f64>; 3]>,
}

impl reference::Progress for SweepClock {
    fn form_factors(&self, _: usize, _: usize) {}
    fn iteration(&self, _: usize, residual: f64) {
        let now = self.started.elapsed().as_secs_f64();
        if let Ok(mut times) = self.times.lock() {
            for (t, f) in times.iter_mut().zip(FRACTIONS) {
                if t.is_none() && residual <= f {
                    *t = Some(now);
                }
            }
        }
    }
}

/// Records the first time `fraction` is at most each of [`FRACTIONS`].
fn record(times: &mut [Option<f64>; 3], fraction: f64, now: f64) {
    for (t, f) in times.iter_mut().zip(FRACTIONS) {
        if t.is_none() && fraction <= f {
            *t = Some(now);
        }
    }
}

/// Steps `solver` with no budget (one batch or pass at a time) until its
/// residual fraction is at most the smallest of [`FRACTIONS`] or it has
/// nothing left to do; returns when each fraction was first reached and
/// the seconds it all took.
fn time_to_fractions(solver: &mut dyn BatchSolver) -> Result<([Option<f64>; 3], f64)> {
    let started = Instant::now();
    let mut times = [None; 3];
    loop {
        let fraction = solver.residual_fraction();
        record(&mut times, fraction, started.elapsed().as_secs_f64());
        if fraction <= FRACTIONS[2] || !solver.step(Duration::ZERO)? {
            break;
        }
    }
    Ok((times, started.elapsed().as_secs_f64()))
}

/// Benchmarks one scene file: progressive, reference, gather.
pub fn solve_scene(
    gpu: &Device,
    path: &Path,
    load: LoadOptions,
    options: ProgressiveOptions,
    gather_options: GatherOptions,
) -> Result<SceneResult> {
    let (scene, atlas) = load_scene(path, load)?;
    let poses = scene.initial_poses();

    // Progressive: setup (upload, pipeline compilation) is not counted.
    let mut solver = Progressive::new(gpu, &scene, &atlas, &poses, options)?;
    let (times, seconds) = time_to_fractions(&mut solver)?;
    let shots = solver.work();
    let progressive = solver.radiosity()?;

    // The same solution with gathered corrections (issue 15): the gather
    // sweep's setup is not counted; the rounds refine to the last fraction.
    let correction = Correction::new(gpu, &scene, &atlas, &poses, gather_options)?;
    let mut solver = solver.with_corrections(correction, DEFAULT_CORRECTIONS);
    let started = Instant::now();
    solver.correct(FRACTIONS[2])?;
    let corrected_seconds = seconds + started.elapsed().as_secs_f64();
    let corrected_shots = solver.work();
    let corrected = solver.radiosity()?;

    // Reference, when its dense matrix fits.
    let clock = SweepClock {
        started: Instant::now(),
        times: Mutex::new([None; 3]),
    };
    let reference = match ReferenceSolver::new(&scene, &atlas, &poses, &clock) {
        Ok(solver) => {
            let solution = solver.solve(
                SolveOptions {
                    tolerance: FRACTIONS[2],
                    ..SolveOptions::default()
                },
                &clock,
            );
            Some(Reference {
                solver,
                radiosity: solution.radiosity,
                validity: Validity::compute(&scene, &atlas, &poses),
            })
        }
        Err(e) => {
            eprintln!("  {}: reference skipped: {e}", scene.name);
            None
        }
    };
    let compared = reference
        .as_ref()
        .map_or_else(Comparison::default, |r| r.compare(&atlas, &progressive));
    let mut solvers = vec![SolverResult {
        name: "progressive".into(),
        seconds_to: seconds_map(&times),
        shots_per_second: (seconds > 0.0).then(|| shots as f64 / seconds),
        nrmse_vs_reference: compared.nrmse,
        p95_rel_vs_reference: compared.p95_rel,
        reference_seconds_to_same_nrmse: compared.reference_seconds,
    }];
    let compared = reference
        .as_ref()
        .map_or_else(Comparison::default, |r| r.compare(&atlas, &corrected));
    solvers.push(SolverResult {
        name: format!("progressive+{DEFAULT_CORRECTIONS}corr"),
        // The same refinement up to 1%; 0.1% includes the rounds.
        seconds_to: seconds_map(&[times[0], times[1], Some(corrected_seconds)]),
        shots_per_second: (corrected_seconds > 0.0)
            .then(|| corrected_shots as f64 / corrected_seconds),
        nrmse_vs_reference: compared.nrmse,
        p95_rel_vs_reference: compared.p95_rel,
        reference_seconds_to_same_nrmse: compared.reference_seconds,
    });
    if reference.is_some() {
        let times = clock.times.lock().map(|t| *t).unwrap_or([None; 3]);
        solvers.push(SolverResult {
            name: "reference".into(),
            seconds_to: seconds_map(&times),
            shots_per_second: None,
            nrmse_vs_reference: Some(0.0),
            p95_rel_vs_reference: Some(0.0),
            reference_seconds_to_same_nrmse: None,
        });
    }

    // Gather: setup is not counted either; pass by pass (a bounce's
    // change is known when its last pass completes).
    let mut solver = Gather::new(gpu, &scene, &atlas, &poses, gather_options)?;
    let (times, seconds) = time_to_fractions(&mut solver)?;
    let gather = solver.radiosity()?;
    let compared = reference
        .as_ref()
        .map_or_else(Comparison::default, |r| r.compare(&atlas, &gather));
    solvers.push(SolverResult {
        name: "gather".into(),
        seconds_to: seconds_map(&times),
        shots_per_second: (seconds > 0.0).then(|| solver.work() as f64 / seconds),
        nrmse_vs_reference: compared.nrmse,
        p95_rel_vs_reference: compared.p95_rel,
        reference_seconds_to_same_nrmse: compared.reference_seconds,
    });
    Ok(SceneResult {
        scene: scene.name.clone(),
        adapter: gpu.describe(),
        elements: atlas.elements.len(),
        solvers,
    })
}

/// Writes results as JSON (one object per scene, in an array).
pub fn write_json<T: Serialize>(path: &Path, results: &[T]) -> Result<()> {
    let text = serde_json::to_string_pretty(results)?;
    std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
}
