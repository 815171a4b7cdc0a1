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
        } else if !self.dirty {
            // Nothing moved: the current state already reflects these seqs.
            self.reflected = self.seqs.clone();
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
        // Texels inside or under geometry take their neighbours' light.
        crate::validity::Validity::compute(&self.scene, &self.atlas, &self.poses)
            .dilate(&self.atlas, &mut self.radiosity);
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

/// The GPU solver session ([`crate::gpu::DynamicSolver`]): progressive
/// refinement (thesis Alg. 4.2) that follows moves by the configured
/// method (full recompute, incremental or cross redistribution), with poses
/// coalesced while a unit of work runs (latest wins) and work sliced into
/// GPU batches that fit the tick budget (thesis §4.5.3). A state is read
/// back and handed to the tick loop only when the session reports it
/// complete (double buffering): at each of the publication levels of
/// [`crate::gpu::DynamicOptions::publish_at`] and after each
/// redistribution.
pub struct GpuLive {
    session: crate::gpu::DynamicSolver,
    atlas: Atlas,
    /// The last complete state and the seqs it reflects.
    radiosity: Vec<Vec3>,
    reflected: Vec<u64>,
    name: &'static str,
}

impl GpuLive {
    pub fn new(
        device: crate::gpu::Device,
        scene: Scene,
        atlas: Atlas,
        method: crate::gpu::Redistribution,
    ) -> Result<Self, crate::gpu::GpuError> {
        let poses = scene.initial_poses();
        let options = crate::gpu::DynamicOptions {
            method,
            ..Default::default()
        };
        let session = crate::gpu::DynamicSolver::new(&device, &scene, &atlas, &poses, options)?;
        Ok(Self {
            radiosity: vec![Vec3::ZERO; atlas.elements.len()],
            reflected: vec![0; poses.len()],
            name: method.name(),
            session,
            atlas,
        })
    }
}

impl LiveSolver for GpuLive {
    fn name(&self) -> &'static str {
        self.name
    }

    fn set_poses(&mut self, poses: &[Pose], seqs: &[u64]) {
        self.session.set_poses(poses, seqs);
    }

    fn step(&mut self, budget: Duration) -> StepReport {
        let started = Instant::now();
        let mut completed = false;
        let mut idle_echo = false;
        let mut redistribution = Duration::ZERO;
        match self.session.step(budget) {
            Ok(step) => {
                redistribution = step.redistribution;
                idle_echo = !step.completed;
                if step.completed {
                    match self.session.radiosity() {
                        Ok(mut r) => {
                            // Texels inside or under geometry at the
                            // state's poses take their neighbours' light.
                            self.session
                                .progressive()
                                .validity()
                                .dilate(&self.atlas, &mut r);
                            self.radiosity = r;
                            self.reflected = self.session.reflected().to_vec();
                            completed = true;
                        }
                        Err(e) => tracing::error!("reading back radiosity failed: {e}"),
                    }
                }
            }
            Err(e) => tracing::error!("GPU solver step failed: {e}"),
        }
        if idle_echo && self.session.reflected() != self.reflected.as_slice() {
            // The session took a transform that changed no pose as
            // reflected by the state it already has (it completes nothing
            // for it), so the last state reflects it too.
            self.reflected = self.session.reflected().to_vec();
        }
        StepReport {
            completed,
            unshot_fraction: self.session.unshot_fraction(),
            redistribution,
            solve: started.elapsed(),
        }
    }

    fn radiosity(&self) -> &[Vec3] {
        &self.radiosity
    }
    fn reflected(&self) -> &[u64] {
        &self.reflected
    }
}
