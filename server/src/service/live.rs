//! The solver as the tick loop sees it.
//!
//! A [`LiveSolver`] follows poses and, in slices of at most a tick's budget
//! where it can, produces complete radiosity states. The tick loop never
//! sees a half-done state: [`StepReport::completed`] says when
//! [`LiveSolver::radiosity`] holds a new complete one.
//!
//! A solver does not decide what a failure means for the service: `step`
//! returns a [`SolverFailure`] (a lost GPU device, an error caught by the
//! error scopes around the GPU work, a failed readback) and the tick loop
//! ([`super::runtime`]) marks the scene not ready, keeps serving the last
//! version and rebuilds the solver.

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

/// Why a solver cannot go on; the tick loop drops it and builds a new one.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct SolverFailure(pub String);

/// A solver that follows moving objects.
pub trait LiveSolver: Send {
    /// A short name for logs and metrics.
    fn name(&self) -> &'static str;
    /// New poses for every object (indexed like `Scene::objects`), with the
    /// transform seq per object they carry. A solver may defer them until
    /// its current work completes (the latest call wins).
    fn set_poses(&mut self, poses: &[Pose], seqs: &[u64]);
    /// Does up to about `budget` of work. An error means the solver is
    /// unusable (its state may be corrupt); it is not called again.
    fn step(&mut self, budget: Duration) -> Result<StepReport, SolverFailure>;
    /// The latest complete state: radiosity per element.
    fn radiosity(&self) -> &[Vec3];
    /// The transform seq per object that [`LiveSolver::radiosity`] reflects.
    fn reflected(&self) -> &[u64];
    /// Whether the solver has nothing left to do for the poses it has
    /// (its state is complete and refined as far as it refines), so that
    /// [`LiveSolver::radiosity`] will not change until poses do.
    fn is_idle(&self) -> bool;
    /// Why the solver is unusable, if something outside `step` has
    /// noticed (a device-lost callback): the tick loop's reason when a
    /// step panicked.
    fn failure(&self) -> Option<String> {
        None
    }
    /// Test hook (`LIGHTWIRE_TEST_FAIL_SOLVER`, see [`super::config`]):
    /// make the solver fail the way a real failure would, from its next
    /// step on. The GPU solver destroys its device.
    fn inject_failure(&mut self);
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
    injected: bool,
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
            injected: false,
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

    fn step(&mut self, _budget: Duration) -> Result<StepReport, SolverFailure> {
        let started = Instant::now();
        if self.injected {
            return Err(SolverFailure(
                "test-injected failure (LIGHTWIRE_TEST_FAIL_SOLVER)".into(),
            ));
        }
        if !self.dirty {
            return Ok(StepReport {
                completed: false,
                unshot_fraction: self.residual,
                redistribution: Duration::ZERO,
                solve: Duration::ZERO,
            });
        }
        self.dirty = false;
        let solution = match ReferenceSolver::new(&self.scene, &self.atlas, &self.poses, &Silent) {
            Ok(solver) => solver.solve(SolveOptions::default(), &Silent),
            // Checked when the runtime starts; unreachable for a scene
            // that started, but never take the service down for it.
            Err(e) => {
                return Err(SolverFailure(format!(
                    "reference solver refused the scene: {e}"
                )));
            }
        };
        self.radiosity = solution.radiosity;
        // Texels inside or under geometry take their neighbours' light.
        crate::validity::Validity::compute(&self.scene, &self.atlas, &self.poses)
            .dilate(&self.atlas, &mut self.radiosity);
        self.residual = solution.residual_fraction;
        self.reflected = self.seqs.clone();
        let spent = started.elapsed();
        Ok(StepReport {
            completed: true,
            unshot_fraction: self.residual,
            redistribution: spent,
            solve: spent,
        })
    }

    fn radiosity(&self) -> &[Vec3] {
        &self.radiosity
    }

    fn reflected(&self) -> &[u64] {
        &self.reflected
    }
    fn is_idle(&self) -> bool {
        !self.dirty
    }

    fn inject_failure(&mut self) {
        self.injected = true;
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
///
/// Each step runs inside the device's error scopes
/// ([`crate::gpu::Device::capture`]) and is followed by a check of the
/// device's health (lost, uncaptured errors): any of these, or a failed
/// step or readback, is a [`SolverFailure`].
pub struct GpuLive {
    device: crate::gpu::Device,
    session: crate::gpu::DynamicSolver,
    atlas: Atlas,
    /// The last complete state and the seqs it reflects.
    radiosity: Vec<Vec3>,
    reflected: Vec<u64>,
    name: &'static str,
}

impl GpuLive {
    /// A session on `device` starting from `poses`. Errors of the device
    /// outside error scopes are recorded from here on, not panicked on.
    pub fn new(
        device: crate::gpu::Device,
        scene: &Scene,
        atlas: Atlas,
        poses: &[Pose],
        method: crate::gpu::Redistribution,
    ) -> Result<Self, crate::gpu::GpuError> {
        device.record_uncaptured_errors();
        let options = crate::gpu::DynamicOptions {
            method,
            ..Default::default()
        };
        let (session, error) = device
            .capture(|| crate::gpu::DynamicSolver::new(&device, scene, &atlas, poses, options));
        let session = session?;
        if let Some(e) = error.or_else(|| device.failure()) {
            return Err(crate::gpu::GpuError::Device(format!(
                "setting up the solver: {e}"
            )));
        }
        Ok(Self {
            radiosity: vec![Vec3::ZERO; atlas.elements.len()],
            reflected: vec![0; poses.len()],
            name: method.name(),
            device,
            session,
            atlas,
        })
    }

    fn work(&mut self, budget: Duration) -> Result<StepReport, SolverFailure> {
        let started = Instant::now();
        let step = self
            .session
            .step(budget)
            .map_err(|e| SolverFailure(format!("GPU solver step failed: {e}")))?;
        if step.completed {
            let mut r = self
                .session
                .radiosity()
                .map_err(|e| SolverFailure(format!("reading back radiosity failed: {e}")))?;
            // Texels inside or under geometry at the state's poses take
            // their neighbours' light.
            self.session
                .progressive()
                .validity()
                .dilate(&self.atlas, &mut r);
            self.radiosity = r;
            self.reflected = self.session.reflected().to_vec();
        } else if self.session.reflected() != self.reflected.as_slice() {
            // The session took a transform that changed no pose as
            // reflected by the state it already has (it completes nothing
            // for it), so the last state reflects it too.
            self.reflected = self.session.reflected().to_vec();
        }
        Ok(StepReport {
            completed: step.completed,
            unshot_fraction: self.session.unshot_fraction(),
            redistribution: step.redistribution,
            solve: started.elapsed(),
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

    fn step(&mut self, budget: Duration) -> Result<StepReport, SolverFailure> {
        if let Some(e) = self.device.failure() {
            return Err(SolverFailure(e));
        }
        let device = self.device.clone();
        let (report, scoped) = device.capture(|| self.work(budget));
        // Let wgpu run its maintenance (it calls the device-lost callback
        // there) even on ticks that waited for nothing.
        let _ = device.device.poll(wgpu::PollType::Poll);
        // A lost device explains everything after it: say that first.
        if let Some(e) = device.failure() {
            return Err(SolverFailure(e));
        }
        if let Some(e) = scoped {
            return Err(SolverFailure(e));
        }
        report
    }

    fn failure(&self) -> Option<String> {
        self.device.failure()
    }

    fn inject_failure(&mut self) {
        self.device.device.destroy();
    }

    fn radiosity(&self) -> &[Vec3] {
        &self.radiosity
    }
    fn reflected(&self) -> &[u64] {
        &self.reflected
    }
    fn is_idle(&self) -> bool {
        self.session.is_idle()
    }
}
