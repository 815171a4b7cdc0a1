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
    /// New poses for every object (indexed like `Scene::objects`), with the
    /// transform seq per object they carry. A solver may defer them until
    /// its current work completes (the latest call wins).
    fn set_poses(&mut self, poses: &[Pose], seqs: &[u64]);
    /// Does up to about `budget` of work.
    fn step(&mut self, budget: Duration) -> StepReport;
    /// The latest complete state: radiosity per element.
    fn radiosity(&self) -> &[Vec3];
    /// The transform seq per object that [`LiveSolver::radiosity`] reflects.
    fn reflected(&self) -> &[u64];
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
    seqs: Vec<u64>,
    reflected: Vec<u64>,
    dirty: bool,
    radiosity: Vec<Vec3>,
    residual: f64,
}

impl ReferenceLive {
    pub fn new(scene: Scene, atlas: Atlas) -> Self {
        let poses = scene.initial_poses();
        Self {
            radiosity: vec![Vec3::ZERO; atlas.elements.len()],
            seqs: vec![0; poses.len()],
            reflected: vec![0; poses.len()],
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

    fn set_poses(&mut self, poses: &[Pose], seqs: &[u64]) {
        self.seqs = seqs.to_vec();
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
        self.reflected = self.seqs.clone();
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

    fn reflected(&self) -> &[u64] {
        &self.reflected
    }
}

/// The GPU progressive solver (thesis Alg. 4.2), restarted from scratch
/// when poses change (the "full recompute" baseline of the dynamic-objects
/// work). Poses that arrive before the running solve has published are
/// held back (latest wins) and start the next solve, so a fast stream of
/// poses can never starve publication. Work is sliced: each `step` runs whole batches for about the
/// tick budget. A state is published when the unshot power first falls
/// below each of [`GpuLive::PUBLISH_AT`]; spare budget after that keeps
/// refining toward the last level.
pub struct GpuLive {
    device: crate::gpu::Device,
    scene: Scene,
    atlas: Atlas,
    options: crate::gpu::ProgressiveOptions,
    solver: crate::gpu::ProgressiveSolver,
    poses: Vec<Pose>,
    /// Seqs of the poses being solved, and of the published state.
    seqs: Vec<u64>,
    reflected: Vec<u64>,
    /// Poses (and seqs) waiting for the running solve to publish.
    pending: Option<(Vec<Pose>, Vec<u64>)>,
    radiosity: Vec<Vec3>,
    /// Index into `PUBLISH_AT` of the next level to publish at.
    next_level: usize,
    /// Time spent since the last pose change (redistribution).
    since_move: bool,
}

impl GpuLive {
    /// Unshot fractions at which a new complete state is published.
    pub const PUBLISH_AT: [f64; 2] = [1e-2, 1e-3];

    pub fn new(
        device: crate::gpu::Device,
        scene: Scene,
        atlas: Atlas,
    ) -> Result<Self, crate::gpu::GpuError> {
        let options = crate::gpu::ProgressiveOptions::default();
        let poses = scene.initial_poses();
        let solver = crate::gpu::ProgressiveSolver::new(&device, &scene, &atlas, &poses, options)?;
        Ok(Self {
            radiosity: vec![Vec3::ZERO; atlas.elements.len()],
            seqs: vec![0; poses.len()],
            reflected: vec![0; poses.len()],
            pending: None,
            device,
            scene,
            atlas,
            options,
            solver,
            poses,
            next_level: 0,
            since_move: false,
        })
    }
}

impl LiveSolver for GpuLive {
    fn name(&self) -> &'static str {
        "progressive"
    }

    fn set_poses(&mut self, poses: &[Pose], seqs: &[u64]) {
        self.pending = Some((poses.to_vec(), seqs.to_vec()));
    }

    fn step(&mut self, budget: Duration) -> StepReport {
        let started = Instant::now();
        // Start the next solve once the running one has published.
        if self.next_level > 0 {
            if let Some((poses, seqs)) = self.pending.take() {
                if poses == self.poses {
                    self.seqs = seqs;
                    self.reflected = self.seqs.clone();
                } else {
                    match crate::gpu::ProgressiveSolver::new(
                        &self.device,
                        &self.scene,
                        &self.atlas,
                        &poses,
                        self.options,
                    ) {
                        Ok(solver) => {
                            self.solver = solver;
                            self.poses = poses;
                            self.seqs = seqs;
                            self.next_level = 0;
                            self.since_move = true;
                        }
                        Err(e) => {
                            tracing::error!("GPU solver could not restart for new poses: {e}")
                        }
                    }
                }
            }
        }
        let mut completed = false;
        if self.next_level < Self::PUBLISH_AT.len() {
            match self.solver.step(budget) {
                Ok(report) => {
                    let mut crossed = false;
                    while self.next_level < Self::PUBLISH_AT.len()
                        && report.unshot_fraction <= Self::PUBLISH_AT[self.next_level]
                    {
                        self.next_level += 1;
                        crossed = true;
                    }
                    if crossed {
                        match self.solver.radiosity() {
                            Ok(r) => {
                                self.radiosity = r;
                                self.reflected = self.seqs.clone();
                                completed = true;
                            }
                            Err(e) => tracing::error!("reading back radiosity failed: {e}"),
                        }
                    }
                }
                Err(e) => tracing::error!("GPU solver step failed: {e}"),
            }
        }
        let spent = started.elapsed();
        let redistribution = if self.since_move {
            spent
        } else {
            Duration::ZERO
        };
        if completed {
            self.since_move = false;
        }
        StepReport {
            completed,
            unshot_fraction: self.solver.unshot_fraction(),
            redistribution,
            solve: spent,
        }
    }

    fn radiosity(&self) -> &[Vec3] {
        &self.radiosity
    }
    fn reflected(&self) -> &[u64] {
        &self.reflected
    }
}
