//! A solver session that follows moving objects (thesis §3.1, §4.5.3).
//!
//! [`DynamicSolver`] owns a [`ProgressiveSolver`] and turns a stream of
//! poses into a sequence of complete radiosity states:
//!
//! - Poses may arrive at any moment ([`DynamicSolver::set_poses`]); the
//!   latest per call wins and waits until the running unit of work is done,
//!   so every emitter redistributes its light in chronological order, which
//!   the shot-radiosity formulation requires (thesis §3.1, §3.3.4).
//! - Each set of poses comes with a tag of the caller's type `T`, which the
//!   session keeps and hands back with the complete state that reflects
//!   those poses ([`DynamicSolver::reflected`]). It never looks inside: what
//!   a tag stands for (a benchmark's frame number, which of its clients'
//!   messages the poses came from) is the caller's business.
//! - Work is cut into GPU batches; [`DynamicSolver::step`] runs batches
//!   until its time budget is spent, so a redistribution spans several
//!   ticks when it must (thesis §4.5.3: the loop over shooters is
//!   interruptible).
//! - A step reports `completed` only when a whole unit is done: a
//!   redistribution (and, for the full and incremental methods, the
//!   progressive iterations that bring the unshot power below the first
//!   publication level), or a refinement. In between, the GPU holds
//!   half-done states that nobody reads: the caller publishes only
//!   completed ones (double buffering).
//! - Spare budget continues progressive refinement toward the last level.
//!   With cross redistribution the moving objects are removed before and
//!   inserted after the refinement (thesis §4.5.2), so that the static
//!   scene's shot radiosity, which cross projection depends on, never
//!   changes while they are in the scene.
//!
//! Negative light. Redistribution shoots negative radiosity (thesis
//! §2.2.5): shadows appear as negative deltas. Intermediate states can hold
//! negative texels; completed states can only hold the small residue of
//! discretization differences between what was shot and what is taken back
//! (tests bound it), and [`DynamicSolver::radiosity`] clamps each channel
//! at zero, so nothing negative is ever published.

use std::time::{Duration, Instant};

use glam::Vec3;

use super::profile::{Profiler, Stage, Unit};
use super::progressive::{Move, ProgressiveOptions, ProgressiveSolver, Redistribution};
use super::{Device, GpuError};
use crate::atlas::Atlas;
use crate::scene::{Pose, Scene};

/// Tuning of a [`DynamicSolver`].
#[derive(Debug, Clone, Copy)]
pub struct DynamicOptions {
    /// How moves are followed.
    pub method: Redistribution,
    /// Unshot fractions of the emitted power at which full and incremental
    /// states are published, and to which refinement continues (the last).
    pub publish_at: [f64; 2],
    /// Incremental only: every this many moves, the move is followed by a
    /// full recompute instead (0: never). Incremental redistribution is
    /// exact in theory (thesis §4.4) but each move leaves a little
    /// discretization error (shooter tiles and item-buffer visibility of
    /// the take-back differ from those of the original shots) and that
    /// error random-walks: on cornell-low we measured an NRMSE against a
    /// from-scratch solve of 0.3% after one move, 0.8% after 10, 1.5%
    /// after 25, 2.1% after 50 and 4.8% after 200 moves. On this kind of
    /// scene a full recompute costs about as much as one incremental move
    /// (thesis Table 5.2 shows the same for the Cornell scenes), so
    /// re-anchoring every 10 moves keeps the error near its one-move level
    /// for about 10% more work.
    pub reanchor_every: u32,
    /// The progressive solver underneath.
    pub progressive: ProgressiveOptions,
}

impl Default for DynamicOptions {
    fn default() -> Self {
        Self {
            method: Redistribution::default(),
            publish_at: [1e-2, 1e-3],
            reanchor_every: 10,
            progressive: ProgressiveOptions::default(),
        }
    }
}

/// What one [`DynamicSolver::step`] did.
#[derive(Debug, Clone, Copy, Default)]
pub struct DynamicStep {
    /// A new complete state is ready ([`DynamicSolver::radiosity`]).
    pub completed: bool,
    /// Time spent on work caused by moves.
    pub redistribution: Duration,
    /// GPU batches run.
    pub batches: u32,
}

/// The unit of work in progress.
enum Phase {
    /// Nothing to do until poses arrive or refinement is wanted.
    Idle,
    /// Progressive iterations with every object present, until the unshot
    /// power crosses the next publication level (full, incremental).
    Converging { after_move: bool },
    /// A redistribution's batches.
    Moving(Move),
    /// Cross: moving objects are being removed before refinement.
    Removing(Move),
    /// Cross: progressive iterations on the static scene until `level`.
    Refining { level: f64, after_move: bool },
    /// Cross: moving objects are being inserted again.
    Inserting(Move, bool),
}

/// A GPU radiosity session that follows moving objects, with a tag of type
/// `T` per set of poses; see the module doc.
pub struct DynamicSolver<T> {
    gpu: Device,
    scene: Scene,
    atlas: Atlas,
    options: DynamicOptions,
    solver: ProgressiveSolver,
    phase: Phase,
    /// The objects that may move.
    dynamic: Vec<bool>,
    /// Poses (and their tag) waiting for the running unit to finish.
    pending: Option<(Vec<Pose>, T)>,
    /// Tags of the poses the solver is working on, and of the last
    /// completed state.
    working: T,
    reflected: T,
    /// Index of the next level of `publish_at` to publish at.
    next_level: usize,
    /// Cross: the static scene's unshot fraction after its last refinement.
    static_unshot: f64,
    /// Completed states so far.
    versions: u64,
    /// Incremental moves since the last full solve.
    since_anchor: u32,
    /// Where the time goes (disabled unless profiling, `gpu::profile`).
    profile: Profiler,
}

impl<T: Clone> DynamicSolver<T> {
    /// Uploads the scene at `poses`, tagged `tag` (the first complete
    /// state reflects them). No work is done yet: the first solve runs in
    /// [`DynamicSolver::step`]s like everything else.
    pub fn new(
        gpu: &Device,
        scene: &Scene,
        atlas: &Atlas,
        poses: &[Pose],
        tag: T,
        options: DynamicOptions,
    ) -> Result<Self, GpuError> {
        let dynamic: Vec<bool> = scene.objects.iter().map(|o| o.dynamic).collect();
        let (solver, phase) = match options.method {
            Redistribution::Cross => (
                ProgressiveSolver::with_absent(
                    gpu,
                    scene,
                    atlas,
                    poses,
                    &dynamic,
                    options.progressive,
                )?,
                Phase::Refining {
                    level: options.publish_at[0],
                    after_move: false,
                },
            ),
            _ => (
                ProgressiveSolver::new(gpu, scene, atlas, poses, options.progressive)?,
                Phase::Converging { after_move: false },
            ),
        };
        Ok(Self {
            gpu: gpu.clone(),
            scene: scene.clone(),
            atlas: atlas.clone(),
            options,
            solver,
            phase,
            dynamic,
            pending: None,
            working: tag.clone(),
            reflected: tag,
            next_level: 0,
            static_unshot: 1.0,
            versions: 0,
            since_anchor: 0,
            profile: Profiler::disabled(),
        })
    }

    /// Times the session's units and stages into `profile` from now on
    /// (`gpu::profile`; benchmarks only).
    pub fn set_profiler(&mut self, profile: Profiler) {
        self.solver.set_profiler(profile.clone());
        self.profile = profile;
    }

    /// The redistribution method.
    pub fn method(&self) -> Redistribution {
        self.options.method
    }

    /// New poses for every object, tagged `tag`; they replace any poses
    /// still waiting, and their tag (the latest wins).
    pub fn set_poses(&mut self, poses: &[Pose], tag: T) {
        self.pending = Some((poses.to_vec(), tag));
    }

    /// Whether nothing is running or waiting (the solution is as refined as
    /// it will get until poses change).
    pub fn is_idle(&self) -> bool {
        matches!(self.phase, Phase::Idle) && self.pending.is_none() && !self.wants_refinement()
    }

    /// Completed states so far.
    pub fn versions(&self) -> u64 {
        self.versions
    }

    /// The poses of the state being worked on (or last completed).
    pub fn poses(&self) -> &[Pose] {
        self.solver.poses()
    }

    /// The tag of the poses the last completed state reflects. A call to
    /// [`DynamicSolver::set_poses`] with the poses that state already has
    /// is reflected by it as soon as the session takes them up, without a
    /// new state.
    pub fn reflected(&self) -> &T {
        &self.reflected
    }

    /// How far from converged the session is: unshot power over emitted
    /// power, of the light the method still means to shoot. For full and
    /// incremental that is all unshot light. Cross redistribution never
    /// shoots the light that inserting the moving objects deposits in the
    /// static scene (their reflection and their shadows, one bounce: no
    /// progressive iterations run with them present, thesis §4.5.2), so
    /// for cross it is the static scene's unshot fraction: right now while
    /// it is being refined, else after its latest refinement. Counting the
    /// deposit would make a converged session look a few percent short.
    pub fn unshot_fraction(&self) -> f64 {
        match (self.options.method, &self.phase) {
            (Redistribution::Cross, Phase::Refining { .. }) => self.solver.unshot_fraction(),
            (Redistribution::Cross, _) => self.static_unshot,
            _ => self.solver.unshot_fraction(),
        }
    }

    /// The progressive solver underneath (for inspection in tests and
    /// benchmarks).
    pub fn progressive(&self) -> &ProgressiveSolver {
        &self.solver
    }

    /// Radiosity per element of the current GPU state, each channel clamped
    /// at zero (see the module doc on negative light). Read it after a step
    /// that reported `completed`.
    pub fn radiosity(&self) -> Result<Vec<Vec3>, GpuError> {
        Ok(self
            .solver
            .radiosity()?
            .into_iter()
            .map(|b| b.max(Vec3::ZERO))
            .collect())
    }

    /// Radiosity without the clamp, to measure negative light.
    pub fn raw_radiosity(&self) -> Result<Vec<Vec3>, GpuError> {
        self.solver.total_radiosity()
    }

    fn wants_refinement(&self) -> bool {
        let last = self.options.publish_at[1];
        match self.options.method {
            Redistribution::Cross => self.static_unshot > last,
            _ => self.solver.unshot_fraction() > last,
        }
    }

    /// Runs batches for about `budget` (at least one when there is work).
    pub fn step(&mut self, budget: Duration) -> Result<DynamicStep, GpuError> {
        let started = Instant::now();
        let mut report = DynamicStep::default();
        let mut redistributing = Duration::ZERO;
        loop {
            if report.batches > 0 && started.elapsed() >= budget {
                break;
            }
            let unit_started = Instant::now();
            let (ran, moved) = self.advance(&mut report)?;
            if moved {
                redistributing += unit_started.elapsed();
            }
            if !ran {
                break;
            }
            report.batches += 1;
            if report.completed {
                // Publish before starting anything new.
                break;
            }
        }
        report.redistribution = redistributing;
        Ok(report)
    }

    /// One batch (or the start of a unit). Returns (did something, was it
    /// caused by a move).
    fn advance(&mut self, report: &mut DynamicStep) -> Result<(bool, bool), GpuError> {
        let levels = self.options.publish_at;
        self.profile.set_unit(match self.phase {
            Phase::Idle | Phase::Moving(_) => Unit::Move,
            Phase::Removing(_) => Unit::Removal,
            Phase::Converging { .. } | Phase::Refining { .. } => Unit::Refinement,
            Phase::Inserting(..) => Unit::Insertion,
        });
        match std::mem::replace(&mut self.phase, Phase::Idle) {
            Phase::Idle => {
                if let Some((poses, tag)) = self.pending.take() {
                    self.start_move(poses, tag)?;
                    return Ok((true, true));
                }
                if self.wants_refinement() {
                    match self.options.method {
                        Redistribution::Cross => {
                            self.profile.set_unit(Unit::Removal);
                            let poses = self.solver.poses().to_vec();
                            let mv = self.solver.begin_move(
                                &poses,
                                &self.dynamic,
                                Redistribution::Cross,
                            )?;
                            self.phase = Phase::Removing(mv);
                        }
                        _ => self.phase = Phase::Converging { after_move: false },
                    }
                    return Ok((true, false));
                }
                Ok((false, false))
            }
            Phase::Converging { after_move } => {
                // A move may start at any batch boundary once the current
                // poses have been published.
                if self.pending.is_some() && self.next_level > 0 {
                    return Ok((true, false));
                }
                let batches = self.profile.start();
                let shot = self.solver.step(Duration::ZERO)?;
                self.profile.stop(batches, Stage::Batches);
                let unshot = shot.unshot_fraction;
                let mut crossed = false;
                while self.next_level < levels.len() && unshot <= levels[self.next_level] {
                    self.next_level += 1;
                    crossed = true;
                }
                if crossed {
                    self.complete(report);
                }
                if shot.batches > 0 && self.next_level < levels.len() {
                    self.phase = Phase::Converging {
                        after_move: after_move && !crossed,
                    };
                } else if shot.batches == 0 && !crossed {
                    // Nothing left to shoot: converged as far as it goes.
                    self.next_level = levels.len();
                    self.complete(report);
                }
                Ok((true, after_move))
            }
            Phase::Moving(mut mv) => {
                let more = self.solver.move_step(&mut mv)?;
                if more {
                    self.phase = Phase::Moving(mv);
                } else if self.options.method == Redistribution::Cross {
                    self.complete(report);
                } else {
                    self.next_level = 0;
                    self.phase = Phase::Converging { after_move: true };
                }
                Ok((true, true))
            }
            Phase::Removing(mut mv) => {
                if self.solver.move_step(&mut mv)? {
                    self.phase = Phase::Removing(mv);
                } else {
                    self.phase = Phase::Refining {
                        level: levels[1],
                        after_move: false,
                    };
                }
                Ok((true, false))
            }
            Phase::Refining { level, after_move } => {
                let batches = self.profile.start();
                let shot = self.solver.step(Duration::ZERO)?;
                self.profile.stop(batches, Stage::Batches);
                if shot.batches > 0 && shot.unshot_fraction > level {
                    self.phase = Phase::Refining { level, after_move };
                } else {
                    self.static_unshot = shot.unshot_fraction;
                    // Insert at the newest poses: a move that arrived
                    // meanwhile costs nothing extra.
                    let poses = match self.pending.take() {
                        Some((poses, tag)) => {
                            self.working = tag;
                            poses
                        }
                        None => self.solver.poses().to_vec(),
                    };
                    let present = vec![false; poses.len()];
                    self.profile.set_unit(Unit::Insertion);
                    let mv = self
                        .solver
                        .begin_move(&poses, &present, Redistribution::Cross)?;
                    self.phase = Phase::Inserting(mv, after_move);
                }
                Ok((true, after_move))
            }
            Phase::Inserting(mut mv, after_move) => {
                if self.solver.move_step(&mut mv)? {
                    self.phase = Phase::Inserting(mv, after_move);
                } else {
                    self.complete(report);
                }
                Ok((true, after_move))
            }
        }
    }

    fn start_move(&mut self, poses: Vec<Pose>, tag: T) -> Result<(), GpuError> {
        self.working = tag;
        if poses.as_slice() == self.solver.poses() {
            // Same poses: the state already reflects them.
            self.reflected = self.working.clone();
            return Ok(());
        }
        let mut method = self.options.method;
        if method == Redistribution::Incremental {
            self.since_anchor += 1;
            if self.options.reanchor_every > 0 && self.since_anchor >= self.options.reanchor_every {
                method = Redistribution::Full;
            }
        }
        match method {
            Redistribution::Full => {
                self.since_anchor = 0;
                let setup = self.profile.start();
                self.solver = ProgressiveSolver::new(
                    &self.gpu,
                    &self.scene,
                    &self.atlas,
                    &poses,
                    self.options.progressive,
                )?;
                self.profile.stop(setup, Stage::SolverSetup);
                self.solver.set_profiler(self.profile.clone());
                self.next_level = 0;
                self.phase = Phase::Converging { after_move: true };
            }
            method => {
                let absent = self.solver.absent().to_vec();
                let mv = self.solver.begin_move(&poses, &absent, method)?;
                self.phase = Phase::Moving(mv);
            }
        }
        Ok(())
    }

    fn complete(&mut self, report: &mut DynamicStep) {
        self.reflected = self.working.clone();
        self.versions += 1;
        report.completed = true;
    }
}
