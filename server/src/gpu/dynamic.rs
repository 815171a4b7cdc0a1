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
//!   With cross redistribution the moving objects stay in place, passive
//!   ([`ProgressiveSolver::set_passive`]): they occlude, but their elements
//!   neither receive nor shoot, since their light is each move's business
//!   (gathered at the new pose, shot with its tiles). What refinement then
//!   shoots is the static set's unshot light, chiefly what the last move
//!   deposited on it (the objects' reflected light and their shadows), so
//!   that deposit gets its second and later bounces. The thesis removes
//!   the objects for refinement and inserts them again (§4.5.2); that
//!   takes the deposit out of the unshot light with them, so it was never
//!   shot on (a cross session's static texels read about 1.5% darker than
//!   a from-scratch solve on cornell-large), and the shots made while the
//!   objects are out are blocked by nothing. Shooting with the objects in
//!   place keeps what cross projection needs: every shot of a static
//!   shooter was blocked by the objects where they stood, so the next
//!   move's removal unblocks all of its shot radiosity, as it does.
//!
//! - A cross session's first solve is corrected by gathering once the
//!   moving objects are in ([`DynamicOptions::corrections`]): the static
//!   light then starts at the gather solver's accuracy instead of
//!   progressive refinement's, and moves carry only changes to it. The
//!   first state is published before the rounds, the corrected one after.
//!
//! Negative light. Redistribution shoots negative radiosity (thesis
//! §2.2.5): shadows appear as negative deltas. Intermediate states can hold
//! negative texels; completed states can only hold the small residue of
//! discretization differences between what was shot and what is taken back
//! (tests bound it), and [`DynamicSolver::radiosity`] clamps each channel
//! at zero, so nothing negative is ever published.

use std::time::{Duration, Instant};

use glam::Vec3;

use super::correct::Correction;
use super::gather::GatherOptions;
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
    /// Cross only: gathered correction rounds ([`Correction`]) after the
    /// first solve, once the moving objects are in. Progressive refinement
    /// alone leaves the static light 2-3.5% off the reference (NRMSE over
    /// the non-emitting elements; its hemicubes see each shooter from one
    /// eye with yes-or-no visibility), and cross redistribution only
    /// carries changes, so a session kept that error for good. Two rounds
    /// bring the static light to the gather solver's accuracy (about 1%)
    /// once, at start; moves then redistribute the moving objects' share
    /// of it as before (BENCHMARKS.md, "a corrected first solve"). The
    /// moving objects are frozen during the rounds (their light is each
    /// move's business) and the rounds run even when poses are waiting:
    /// they happen once per session. 0: none.
    pub corrections: u32,
    /// The progressive solver underneath.
    pub progressive: ProgressiveOptions,
}

impl Default for DynamicOptions {
    fn default() -> Self {
        Self {
            method: Redistribution::default(),
            publish_at: [1e-2, 1e-3],
            reanchor_every: 10,
            corrections: 2,
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
    /// Cross: progressive iterations on the static scene with the moving
    /// objects passive in place, until the last publication level.
    Settling,
    /// Cross: progressive iterations on the static scene without the
    /// moving objects until `level` (the first solve).
    Refining { level: f64, after_move: bool },
    /// Cross: moving objects are being inserted again.
    Inserting(Move, bool),
    /// Cross: gathered corrections of the first solve, `left` rounds to go
    /// (the gather sweep is built for the first).
    Correcting {
        correction: Option<Box<Correction>>,
        left: u32,
    },
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
    /// Poses (and their tag) waiting for the running unit to finish.
    pending: Option<(Vec<Pose>, T)>,
    /// Tags of the poses the solver is working on, and of the last
    /// completed state.
    working: T,
    reflected: T,
    /// Index of the next level of `publish_at` to publish at.
    next_level: usize,
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
        let (mut solver, phase) = match options.method {
            Redistribution::Cross => (
                ProgressiveSolver::with_absent(
                    gpu,
                    scene,
                    atlas,
                    poses,
                    &dynamic,
                    options.progressive,
                )?,
                // The static set converges before the objects go in: their
                // gathers read it once, and light that refinement shoots
                // later onto them (passive) is not reflected until they
                // move.
                Phase::Refining {
                    level: options.publish_at[1],
                    after_move: false,
                },
            ),
            _ => (
                ProgressiveSolver::new(gpu, scene, atlas, poses, options.progressive)?,
                Phase::Converging { after_move: false },
            ),
        };
        if options.method == Redistribution::Cross {
            solver.set_passive(&dynamic)?;
        }
        Ok(Self {
            gpu: gpu.clone(),
            scene: scene.clone(),
            atlas: atlas.clone(),
            options,
            solver,
            phase,
            pending: None,
            working: tag.clone(),
            reflected: tag,
            next_level: 0,
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
    /// power. For cross that leaves out the moving objects' own unshot
    /// radiosity, which is never shot (their light is each move's; see the
    /// module doc).
    pub fn unshot_fraction(&self) -> f64 {
        self.solver.unshot_fraction()
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
        self.solver.unshot_fraction() > self.options.publish_at[1]
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
            Phase::Converging { .. }
            | Phase::Refining { .. }
            | Phase::Settling
            | Phase::Correcting { .. } => Unit::Refinement,
            Phase::Inserting(..) => Unit::Insertion,
        });
        match std::mem::replace(&mut self.phase, Phase::Idle) {
            Phase::Idle => {
                if let Some((poses, tag)) = self.pending.take() {
                    self.start_move(poses, tag)?;
                    return Ok((true, true));
                }
                if self.wants_refinement() {
                    self.phase = match self.options.method {
                        Redistribution::Cross => Phase::Settling,
                        _ => Phase::Converging { after_move: false },
                    };
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
            Phase::Settling => {
                // Newer poses cut refinement short: what is left stays
                // unshot, and the state the next move publishes carries
                // what was shot so far (any state reflects the poses).
                if self.pending.is_some() {
                    return Ok((true, false));
                }
                let batches = self.profile.start();
                let shot = self.solver.step(Duration::ZERO)?;
                self.profile.stop(batches, Stage::Batches);
                if shot.batches > 0 && shot.unshot_fraction > levels[1] {
                    self.phase = Phase::Settling;
                } else {
                    self.complete(report);
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
                    // The first state is published uncorrected: light
                    // reaches the clients seconds sooner, and the
                    // corrected one follows.
                    self.complete(report);
                    if !after_move
                        && self.options.corrections > 0
                        && super::corrections_affordable(&self.scene, &self.atlas)
                    {
                        self.phase = Phase::Correcting {
                            correction: None,
                            left: self.options.corrections,
                        };
                    }
                }
                Ok((true, after_move))
            }
            Phase::Correcting { correction, left } => {
                let mut correction = match correction {
                    Some(c) => c,
                    None => Box::new(Correction::new(
                        &self.gpu,
                        &self.scene,
                        &self.atlas,
                        self.solver.poses(),
                        GatherOptions::default(),
                    )?),
                };
                let frozen: Vec<bool> = self.scene.objects.iter().map(|o| o.dynamic).collect();
                let batches = self.profile.start();
                correction.round_except(&mut self.solver, levels[1], &frozen)?;
                self.profile.stop(batches, Stage::Batches);
                if left > 1 {
                    self.phase = Phase::Correcting {
                        correction: Some(correction),
                        left: left - 1,
                    };
                } else {
                    self.complete(report);
                }
                Ok((true, false))
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
