//! Issue 15's accuracy target for the GPU batch solvers: on cornell-blocks
//! and cornell-large at the files' densities, the progressive solver (as
//! `lightwire bake` runs it, with its gathered corrections) and the gather
//! solver agree with the CPU reference solver within 1% NRMSE
//! ([`lightwire_solve::accuracy::accuracy`]: area-weighted, over the
//! visible non-emitting elements).
//!
//! One reference solve per scene serves both solvers; it is the slow part
//! (about 40 s per scene in a release build). Measured on 2026-12-02
//! (docs/benchmarks-history.md, "Issue 15: gathered corrections"): progressive 0.55%
//! (cornell-blocks) and 0.74% (cornell-large), against 4.09% and 2.37%
//! without the corrections; gather 0.56% and 0.78%.

mod common;

use lightwire_solve::reference::{ReferenceSolver, Silent, SolveOptions};
use lightwire_solve::solver::{self, SolverKind, SolverSettings};

/// Solves `name` at its file's density with the reference, the progressive
/// and the gather solver, and asserts each GPU solver's NRMSE against the
/// reference.
fn against_reference(name: &str) {
    let (scene, atlas) = common::load(name, 1.0);
    let poses = scene.initial_poses();
    let reference =
        ReferenceSolver::new(&scene, &atlas, &poses, &Silent).unwrap_or_else(|e| panic!("{e}"));
    let expected = reference.solve(SolveOptions::default(), &Silent).radiosity;
    for kind in [SolverKind::Progressive, SolverKind::Gather] {
        let settings = SolverSettings::default();
        let mut solver = solver::build(kind, &scene, &atlas, &poses, &settings, &solver::Silent)
            .unwrap_or_else(|e| panic!("{}: {e}", kind.name()));
        solver
            .solve(1e-4)
            .unwrap_or_else(|e| panic!("{}: {e}", kind.name()));
        let values = solver
            .radiosity()
            .unwrap_or_else(|e| panic!("{}: {e}", kind.name()));
        let error = common::visible_accuracy(&scene, &atlas, &poses, &values, &expected);
        eprintln!(
            "{name}: {} elements, {}: {error} ({})",
            atlas.elements.len(),
            kind.name(),
            solver.summary()
        );
        assert!(error.nrmse <= 0.01, "{name}, {}: {error}", kind.name());
    }
}

#[test]
fn cornell_blocks_progressive_and_gather_within_one_percent_of_the_reference() {
    against_reference("cornell-blocks.json");
}

#[test]
fn cornell_large_progressive_and_gather_within_one_percent_of_the_reference() {
    against_reference("cornell-large.json");
}
