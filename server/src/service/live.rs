//! The solver as the tick loop sees it.
//!
//! A [`LiveSolver`] follows poses and, in slices of at most a tick's budget
//! where it can, produces complete radiosity states. The tick loop never
//! sees a half-done state: [`StepReport::completed`] says when
//! [`LiveSolver::radiosity`] holds a new complete one.
//!
//! A solver knows nothing of the wire. Each set of poses comes with a tag
//! of the caller's type `T` that the solver keeps, without looking inside,
//! and hands back with the complete state that reflects those poses
//! ([`LiveSolver::reflected`]); the tick loop tags poses with the transform
//! seqs they carry ([`super::runtime`]).
//!
//! A solver does not decide what a failure means for the service: `step`
//! returns a [`SolverFailure`] (a lost GPU device, an error caught by the
//! error scopes around the GPU work, a failed readback) and the tick loop
//! ([`super::runtime`]) marks the scene not ready, keeps serving the last
//! version and rebuilds the solver.

use std::time::{Duration, Instant};

use glam::Vec3;

use lightwire_scene::atlas::Atlas;
use lightwire_scene::{Light, Pose, Scene};
use lightwire_solve::reference::{ReferenceSolver, Silent, SolveOptions};
use lightwire_solve::validity::Validity;

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

/// A solver that follows moving objects, with a tag of type `T` per set of
/// poses.
pub trait LiveSolver<T>: Send {
    /// A short name for logs and metrics.
    fn name(&self) -> &'static str;
    /// New poses for every object (indexed like `Scene::objects`), tagged
    /// `tag`. A solver may defer them until its current work completes (the
    /// latest call wins).
    fn set_poses(&mut self, poses: &[Pose], tag: T);
    /// New states for every light (indexed like `Scene::lights`: switched,
    /// dimmed, recoloured, moved, turned), tagged `tag`, which replaces the
    /// tag of poses still waiting. Deferred like poses; the state that
    /// reflects the tag is lit by these lights.
    fn set_lights(&mut self, lights: &[Light], tag: T);
    /// Does up to about `budget` of work. An error means the solver is
    /// unusable (its state may be corrupt); it is not called again.
    fn step(&mut self, budget: Duration) -> Result<StepReport, SolverFailure>;
    /// The latest complete state: radiosity per element, as solved (the
    /// tick loop publishes it through [`crate::publish`]).
    fn radiosity(&self) -> &[Vec3];
    /// Which elements of the latest complete state are valid (not inside
    /// or under geometry at its poses); valid for the state of
    /// [`LiveSolver::radiosity`] until the next call to `step`.
    fn validity(&self) -> &Validity;
    /// The tag of the poses that [`LiveSolver::radiosity`] reflects. Poses
    /// equal to those of the state it has are reflected by it as soon as
    /// the solver takes them up, without a new state.
    fn reflected(&self) -> &T;
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
pub struct ReferenceLive<T> {
    scene: Scene,
    atlas: Atlas,
    poses: Vec<Pose>,
    /// The tag of `poses`, and of the poses `radiosity` reflects.
    tag: T,
    reflected: T,
    dirty: bool,
    radiosity: Vec<Vec3>,
    validity: Validity,
    residual: f64,
    injected: bool,
}

impl<T: Clone> ReferenceLive<T> {
    /// A solver at `poses`, tagged `tag`; it solves on its first step.
    pub fn new(scene: Scene, atlas: Atlas, poses: &[Pose], tag: T) -> Self {
        Self {
            radiosity: vec![Vec3::ZERO; atlas.elements.len()],
            validity: Validity::all_valid(&atlas),
            reflected: tag.clone(),
            tag,
            scene,
            atlas,
            poses: poses.to_vec(),
            dirty: true,
            residual: 1.0,
            injected: false,
        }
    }
}

impl<T: Clone + Send> LiveSolver<T> for ReferenceLive<T> {
    fn name(&self) -> &'static str {
        "reference"
    }

    fn set_poses(&mut self, poses: &[Pose], tag: T) {
        self.tag = tag;
        if poses != self.poses.as_slice() {
            self.poses = poses.to_vec();
            self.dirty = true;
        } else if !self.dirty {
            // Nothing moved: the current state already reflects this tag.
            self.reflected = self.tag.clone();
        }
    }

    fn set_lights(&mut self, lights: &[Light], tag: T) {
        self.tag = tag;
        if lights != self.scene.lights.as_slice() {
            self.scene.lights = lights.to_vec();
            self.dirty = true;
        } else if !self.dirty {
            self.reflected = self.tag.clone();
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
        self.validity = Validity::compute(&self.scene, &self.atlas, &self.poses);
        self.residual = solution.residual_fraction;
        self.reflected = self.tag.clone();
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

    fn validity(&self) -> &Validity {
        &self.validity
    }

    fn reflected(&self) -> &T {
        &self.reflected
    }
    fn is_idle(&self) -> bool {
        !self.dirty
    }

    fn inject_failure(&mut self) {
        self.injected = true;
    }
}

/// The GPU solver session ([`lightwire_solve::gpu::DynamicSolver`]): progressive
/// refinement (thesis Alg. 4.2) that follows moves by the configured
/// method (full recompute, incremental or cross redistribution), with poses
/// coalesced while a unit of work runs (latest wins) and work sliced into
/// GPU batches that fit the tick budget (thesis §4.5.3). A state is read
/// back and handed to the tick loop only when the session reports it
/// complete (double buffering): at each of the publication levels of
/// [`lightwire_solve::gpu::DynamicOptions::publish_at`], after each
/// redistribution, and after each gathered correction round once the scene
/// holds still ([`lightwire_solve::gpu::DynamicOptions::corrections`]).
///
/// Each step runs inside the device's error scopes
/// ([`lightwire_solve::gpu::Device::capture`]) and is followed by a check of the
/// device's health (lost, uncaptured errors): any of these, or a failed
/// step, readback or device poll, is a [`SolverFailure`].
pub struct GpuLive<T> {
    device: lightwire_solve::gpu::Device,
    /// The session; its `reflected` is the tag of `radiosity`.
    session: lightwire_solve::gpu::DynamicSolver<T>,
    /// The last complete state, read back.
    radiosity: Vec<Vec3>,
    name: &'static str,
}

impl<T: Clone> GpuLive<T> {
    /// A session on `device` starting from `poses`, tagged `tag`. Errors of
    /// the device outside error scopes are recorded from here on, not
    /// panicked on.
    pub fn new(
        device: lightwire_solve::gpu::Device,
        scene: &Scene,
        atlas: &Atlas,
        poses: &[Pose],
        tag: T,
        method: lightwire_solve::gpu::Redistribution,
    ) -> Result<Self, lightwire_solve::gpu::GpuError> {
        device.record_uncaptured_errors();
        // The scene's measured solver settings, if it states any.
        if !scene.solver.is_empty() {
            tracing::info!(scene = %scene.name, settings = %scene.solver, "solver settings from the scene file");
        }
        let options = lightwire_solve::gpu::DynamicOptions {
            method,
            progressive: lightwire_solve::gpu::ProgressiveOptions::default()
                .with_hints(&scene.solver),
            ..Default::default()
        };
        if !lightwire_solve::gpu::corrections_affordable(scene, atlas) {
            tracing::info!(
                scene = %scene.name,
                elements = atlas.elements.len(),
                patches = scene.patches.len(),
                "first light and gathered corrections by rays on the CPU: hemicubes over this \
                 many elements and patches would be too slow (more than {} of their product)",
                lightwire_solve::gpu::MAX_DEFAULT_SWEEP
            );
        }
        let (session, error) = device.capture(|| {
            lightwire_solve::gpu::DynamicSolver::new(&device, scene, atlas, poses, tag, options)
        });
        let session = session?;
        if let Some(e) = error.or_else(|| device.failure()) {
            return Err(lightwire_solve::gpu::GpuError::Device(format!(
                "setting up the solver: {e}"
            )));
        }
        Ok(Self {
            radiosity: vec![Vec3::ZERO; atlas.elements.len()],
            name: method.name(),
            device,
            session,
        })
    }

    fn work(&mut self, budget: Duration) -> Result<StepReport, SolverFailure> {
        let started = Instant::now();
        let step = self
            .session
            .step(budget)
            .map_err(|e| SolverFailure(format!("GPU solver step failed: {e}")))?;
        if step.completed {
            self.radiosity = self
                .session
                .radiosity()
                .map_err(|e| SolverFailure(format!("reading back radiosity failed: {e}")))?;
        }
        Ok(StepReport {
            completed: step.completed,
            unshot_fraction: self.session.unshot_fraction(),
            redistribution: step.redistribution,
            solve: started.elapsed(),
        })
    }
}

impl<T: Clone + Send> LiveSolver<T> for GpuLive<T> {
    fn name(&self) -> &'static str {
        self.name
    }

    fn set_poses(&mut self, poses: &[Pose], tag: T) {
        self.session.set_poses(poses, tag);
    }

    fn set_lights(&mut self, lights: &[Light], tag: T) {
        self.session.set_lights(lights, tag);
    }

    fn step(&mut self, budget: Duration) -> Result<StepReport, SolverFailure> {
        if let Some(e) = self.device.failure() {
            return Err(SolverFailure(e));
        }
        let device = self.device.clone();
        let (report, scoped) = device.capture(|| self.work(budget));
        // Let wgpu run its maintenance (it calls the device-lost callback
        // there) even on ticks that waited for nothing.
        let polled = device.device.poll(wgpu::PollType::Poll);
        // A lost device explains everything after it: say that first.
        if let Some(e) = device.failure() {
            return Err(SolverFailure(e));
        }
        if let Some(e) = scoped {
            return Err(SolverFailure(e));
        }
        let report = report?;
        // A poll that fails is a failure of this step like any other, not
        // something to pass over.
        polled.map_err(|e| SolverFailure(format!("polling the GPU device failed: {e}")))?;
        Ok(report)
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
    fn validity(&self) -> &Validity {
        self.session.progressive().validity()
    }
    fn reflected(&self) -> &T {
        self.session.reflected()
    }
    fn is_idle(&self) -> bool {
        self.session.is_idle()
    }
}
