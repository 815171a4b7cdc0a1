//! The solver as the tick loop sees it.
//!
//! A [`LiveSolver`] follows poses and, in slices of at most a tick's budget
//! where it can, produces complete radiosity states. The tick loop never
//! sees a half-done state: [`StepReport::completed`] says when
//! [`LiveSolver::radiosity`] holds a new complete one.

use std::time::{Duration, Instant};

use glam::Vec3;

use crate::atlas::Atlas;
use crate::reference::{ReferenceSolver, Silent, SolveOptions};
use crate::scene::{Pose, Scene};

/// What one call to [`LiveSolver::step`] did.
#[derive(Debug, Clone, Copy)]
pub struct StepReport {
    /// A new complete state is ready in [`LiveSolver::radiosity`].
    pub completed: bool,
    /// Unshot (or residual) power over emitted power of the current state.
    pub unshot_fraction: f64,
    /// Time spent on work caused by moved objects.
    pub redistribution: Duration,
    /// Time spent in total.
    pub solve: Duration,
}

/// A solver that follows moving objects.
pub trait LiveSolver: Send {
    /// A short name for logs and metrics.
    fn name(&self) -> &'static str;
    /// New poses for every object (indexed like `Scene::objects`).
    fn set_poses(&mut self, poses: &[Pose]);
    /// Does up to about `budget` of work.
    fn step(&mut self, budget: Duration) -> StepReport;
    /// The latest complete state: radiosity per element.
    fn radiosity(&self) -> &[Vec3];
}

/// The CPU reference solver, re-solved from scratch whenever poses change.
///
/// It cannot be sliced: a re-solve runs to convergence within one `step`
/// whatever the budget, so the tick it happens in is long (the tick loop
/// then skips the ticks it missed rather than catching up). It exists so
/// that the service works and is testable before and without a GPU; at
/// service densities it is only practical for small scenes.
pub struct ReferenceLive {
    scene: Scene,
    atlas: Atlas,
    poses: Vec<Pose>,
    dirty: bool,
    radiosity: Vec<Vec3>,
    residual: f64,
}

impl ReferenceLive {
    pub fn new(scene: Scene, atlas: Atlas) -> Self {
        let poses = scene.initial_poses();
        Self {
            radiosity: vec![Vec3::ZERO; atlas.elements.len()],
            scene,
            atlas,
            poses,
            dirty: true,
            residual: 1.0,
        }
    }
}

impl LiveSolver for ReferenceLive {
    fn name(&self) -> &'static str {
        "reference"
    }

    fn set_poses(&mut self, poses: &[Pose]) {
        if poses != self.poses.as_slice() {
            self.poses = poses.to_vec();
            self.dirty = true;
        }
    }

    fn step(&mut self, _budget: Duration) -> StepReport {
        let started = Instant::now();
        if !self.dirty {
            return StepReport {
                completed: false,
                unshot_fraction: self.residual,
                redistribution: Duration::ZERO,
                solve: Duration::ZERO,
            };
        }
        self.dirty = false;
        let solution = match ReferenceSolver::new(&self.scene, &self.atlas, &self.poses, &Silent) {
            Ok(solver) => solver.solve(SolveOptions::default(), &Silent),
            Err(e) => {
                // Checked when the runtime starts; unreachable for a scene
                // that started, but never take the service down for it.
                tracing::error!("reference solver refused the scene: {e}");
                return StepReport {
                    completed: false,
                    unshot_fraction: 1.0,
                    redistribution: Duration::ZERO,
                    solve: started.elapsed(),
                };
            }
        };
        self.radiosity = solution.radiosity;
        self.residual = solution.residual_fraction;
        let spent = started.elapsed();
        StepReport {
            completed: true,
            unshot_fraction: self.residual,
            redistribution: spent,
            solve: spent,
        }
    }

    fn radiosity(&self) -> &[Vec3] {
        &self.radiosity
    }
}
