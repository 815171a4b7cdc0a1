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
//! - A cross session lights its static set first, without the moving
//!   objects, and then inserts them (thesis §4.5.2). On a level
//!   ([`Seed::Auto`]: where a hemicube correction sweep is too slow) the
//!   ray solver does the first part (`crate::rays`, a slice of texels per
//!   step) and the progressive solver adopts its light as converged
//!   ([`ProgressiveSolver::adopt`]): the garage level's first state came
//!   after more than four minutes of refinement, now after about 15 s
//!   (BENCHMARKS.md §9).
//!
//! - Whenever the scene holds still at poses it was not corrected at (the
//!   first solve, and every move once its state is complete and refined),
//!   the session corrects its state by gathering
//!   ([`DynamicOptions::corrections`], `gpu::correct`): the light then
//!   comes to the gather solver's accuracy instead of progressive
//!   refinement's, whatever error the moves before left (issue 57: a box
//!   moved about and put back must show what a fresh session shows). The
//!   rounds run a slice at a time, each ends in a published state, and
//!   the next move cancels them; a benchmark of moves waits for
//!   [`DynamicSolver::is_settled`], a viewer of a still scene for
//!   [`DynamicSolver::is_idle`].
//!
//! - Lights change like poses ([`DynamicSolver::set_lights`], issue 60),
//!   taken up when the running unit ends. Once the scene holds still and
//!   is corrected, the session solves each light's light apart
//!   ([`super::basis`], in the background, `1 + lights` sessions) and its
//!   state becomes their composition; a light switched, dimmed or
//!   recoloured in place is then one composition, published in the step
//!   that takes it up and equal to a fresh session's. Anything else (a
//!   light that moves, a change while the basis is missing) is followed by
//!   shooting the signed change of the light's direct light
//!   ([`ProgressiveSolver::set_light`], thesis §2.2.5). For a light that
//!   moves or turns, the step that takes it up, from a refined state,
//!   publishes a first answer at once: the state so far, which holds the
//!   change's direct light whole, plus the bounces of that change by
//!   virtual point lights and imperfect shadow maps ([`super::vpl`], ism
//!   §4.1, §4.11; issue 60 item 3). Cross then
//!   takes the moving objects out and back in (they are passive, so they
//!   would neither receive the change nor pass it on), refinement carries
//!   the change and its state replaces the first answer, a change cut
//!   short by the next is published as far as it got, and the
//!   corrections and the basis follow once the scene holds still. With
//!   every source off a complete state is dark.
//!
//! Negative light. Redistribution shoots negative radiosity (thesis
//! §2.2.5): shadows appear as negative deltas. Intermediate states can hold
//! negative texels; completed states can only hold the small residue of
//! discretization differences between what was shot and what is taken back
//! (tests bound it), and [`DynamicSolver::radiosity`] clamps each channel
//! at zero, so nothing negative is ever published.

use std::time::{Duration, Instant};

use glam::Vec3;

use super::basis::Basis;
use super::correct::Correction;
use super::gather::GatherOptions;
use super::profile::{Profiler, Stage, Unit};
use super::progressive::{Move, ProgressiveOptions, ProgressiveSolver, Redistribution};
use super::vpl::{self, BounceOptions, BounceReport, FirstBounce};
use super::{Device, GpuError};
use crate::rays::{self, RaySolver};
use lightwire_scene::atlas::Atlas;
use lightwire_scene::{Light, Pose, Scene};

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
    /// Gathered correction rounds ([`Correction`]) whenever the scene
    /// holds still at poses it was not corrected at: after the first solve
    /// and after every move once its state is complete and refined.
    /// Progressive refinement alone leaves the light 2-3.5% off the
    /// reference (NRMSE over the non-emitting elements; its hemicubes see
    /// each shooter from one eye with yes-or-no visibility), and the
    /// redistribution methods carry that error, and their own, from move
    /// to move. Rounds bring a state that holds still to the gather
    /// solver's accuracy (about 1%), whatever moves came before, so a
    /// scene put back where it was shows what a fresh session shows. They
    /// run a slice at a time (a sweep pass, a refinement batch), each
    /// round ends in a published state, rounds stop early once the
    /// residual is below [`CORRECTED_RESIDUAL`], and the next move cancels
    /// them. With cross the moving objects take their residual as shown
    /// light only (their light is each move's business). Three rounds: on
    /// cornell-large at the file's density, after 19 jumps of
    /// `teleport-stress.json` and back, two left one texel 6.1% off a
    /// fresh session's, three 2.9% (the residual before the third round
    /// was 1.8e-3 of the emitted power), at 5.2 and 8.4 s from the return
    /// to the corrected state (`examples/round_trip.rs`). 0: none.
    pub corrections: u32,
    /// How a cross session lights its static set before the moving
    /// objects go in.
    pub seed: Seed,
    /// Keep each light's light apart ([`super::basis`]) when the scene
    /// has lights and `(1 + lights) × elements` is at most this (0:
    /// never): a light switched, dimmed or recoloured in place is then
    /// exact at once, for `1 + lights` solves in the background once the
    /// scene holds still, and `12 (1 + lights) elements` bytes.
    pub light_basis: usize,
    /// A light that moves or turns (followed by shooting) is first
    /// published as the state so far plus the bounces of its unshot light
    /// by virtual point lights and imperfect shadow maps ([`super::vpl`],
    /// ism §4.1, §4.11), in the step that takes it up; the refined state
    /// follows. None: the first state published is the refined one.
    pub first_bounce: Option<BounceOptions>,
    /// The progressive solver underneath.
    pub progressive: ProgressiveOptions,
}

/// How a cross session computes the static set's light it starts from
/// (the full and incremental methods always refine).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Seed {
    /// Rays where a hemicube correction sweep is unaffordable
    /// ([`super::corrections_affordable`]: a level), refinement elsewhere.
    #[default]
    Auto,
    /// Progressive refinement to the last publication level (thesis
    /// §4.5.2). On the garage level that took more than four minutes
    /// before the first state, every shot drawing the whole level.
    Refinement,
    /// The ray solver (`crate::rays`): every valid static texel casts its
    /// rays once, a slice per step, bounces run over the kept hits until
    /// what they would still add is below the last publication level, and
    /// the progressive solver adopts the result as converged
    /// ([`ProgressiveSolver::adopt`]). Seconds on the garage level.
    Rays,
}

/// Receivers whose rays a seeding step casts (a slice between ticks):
/// about a tenth of a second on the garage level on two cores.
const SEED_CHUNK: usize = 256;

impl Default for DynamicOptions {
    fn default() -> Self {
        Self {
            method: Redistribution::default(),
            publish_at: [1e-2, 1e-3],
            reanchor_every: 10,
            corrections: 3,
            seed: Seed::Auto,
            // 48 MB of basis at most; every scene of `scenes/` with
            // lights but the pandora level's 56 lamps.
            light_basis: 4_000_000,
            first_bounce: Some(BounceOptions::default()),
            progressive: ProgressiveOptions::default(),
        }
    }
}

/// Residual (power over emitted power) below which a correction round
/// ends the rounds at the current poses: the residual is then no larger
/// than the unshot power refinement leaves (the last publication level,
/// [`DynamicOptions::publish_at`]).
pub const CORRECTED_RESIDUAL: f64 = 1e-3;

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
    /// Cross with [`Seed::Rays`]: the ray solver lights the static scene
    /// without the moving objects (the first solve), a slice per step;
    /// the progressive solver then adopts its light and the objects go in
    /// as after [`Phase::Refining`].
    Seeding(Box<RaySolver>),
    /// Cross: moving objects are being inserted again.
    Inserting(Move, bool),
    /// Cross after a light changed: the moving objects are being taken
    /// out, so that refinement carries the change over the static set
    /// ([`Phase::Refining`]) and they gather their light anew when they go
    /// back in, as at the first solve.
    Removing(Move),
    /// Gathered corrections at poses that hold still, `left` rounds to go
    /// after the running one; see [`Round`].
    Correcting { round: Round, left: u32 },
    /// Once the scene holds still and is corrected: each light's light is
    /// solved apart, a group a time ([`super::basis`]), and the state is
    /// then their composition.
    Basis(Box<Building>),
}

/// Where a correction round of [`Phase::Correcting`] is. Each stage runs a
/// slice at a time (a sweep pass, a refinement batch), so that a move that
/// arrives waits for one slice, not for a round.
enum Round {
    /// The gather sweep is being built for the current poses (the first
    /// round at these poses).
    Building,
    /// The sweep runs a pass at a time from `from`, the radiosity it
    /// started from.
    Sweeping {
        correction: Box<Correction>,
        from: Vec<Vec3>,
    },
    /// The residual was handed over; refinement spreads it.
    Spreading {
        correction: Box<Correction>,
        residual: f64,
    },
}

/// Whether nothing in `scene` gives light: no emitting material, every
/// light black, no sky (or a black one).
fn gives_no_light(scene: &Scene) -> bool {
    scene
        .materials
        .iter()
        .all(|m| m.emission == glam::Vec3::ZERO)
        && scene.lights.iter().all(|l| l.intensity == glam::Vec3::ZERO)
        && scene
            .sky
            .as_ref()
            .is_none_or(|s| s.zenith == glam::Vec3::ZERO && s.horizon == glam::Vec3::ZERO)
}

/// What waits for the running unit to finish: the newest poses, the
/// newest lights if they were set, and the newest tag.
struct Pending<T> {
    poses: Vec<Pose>,
    lights: Option<Vec<Light>>,
    tag: T,
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
    /// Poses, lights and their tag waiting for the running unit to finish.
    pending: Option<Pending<T>>,
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
    /// Whether the state at the current poses has had its gathered
    /// corrections (or needs none): a move clears it.
    corrected: bool,
    /// Residual of each correction round run at the current poses (power
    /// over emitted power, before the round).
    residuals: Vec<f64>,
    /// Where the time goes (disabled unless profiling, `gpu::profile`).
    profile: Profiler,
    /// Each light's light apart, while it holds for the current poses and
    /// light positions ([`super::basis`]).
    basis: Option<Basis>,
    /// The tag being worked on is of a light change that no completed
    /// state shows yet.
    unpublished: bool,
    /// The bounces of a light change's unshot light, for a scene with
    /// lights ([`DynamicOptions::first_bounce`]).
    bounce: Option<FirstBounce>,
    /// The last state published, while it is a first answer (the light
    /// so far and the bounces of the change) rather than the solver's.
    preview: Option<Vec<Vec3>>,
    /// What the last first answer placed and where its time went.
    bounce_report: Option<BounceReport>,
    /// The lights as last set, each where its object's initial pose puts
    /// it; `scene.lights` holds them placed at the solver's poses
    /// (`Scene::lights_at`: a lamp riding with a moving box).
    lights: Vec<Light>,
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
        let lights = scene.lights.clone();
        let mut placed = scene.clone();
        placed.lights = scene.lights_at(&lights, poses);
        let scene = &placed;
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
        let seed_by_rays = match options.seed {
            Seed::Auto => !super::corrections_affordable(scene, atlas),
            Seed::Refinement => false,
            Seed::Rays => true,
        };
        let phase = if options.method == Redistribution::Cross
            && seed_by_rays
            && !options.progressive.indirect_only
        {
            Phase::Seeding(Box::new(RaySolver::prepare(
                scene,
                atlas,
                (poses, &dynamic),
                solver.validity().clone(),
                (rays::SIDE, crate::direct::GRID),
            )))
        } else {
            phase
        };
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
            corrected: options.corrections == 0,
            residuals: Vec::new(),
            profile: Profiler::disabled(),
            basis: None,
            unpublished: false,
            bounce: options
                .first_bounce
                .filter(|_| !scene.lights.is_empty())
                .map(|o| FirstBounce::new(gpu, atlas.elements.len(), o)),
            preview: None,
            bounce_report: None,
            lights,
        })
    }

    /// What the last first answer placed and where its time went (none
    /// before the first).
    pub fn bounce_report(&self) -> Option<BounceReport> {
        self.bounce_report
    }

    /// Makes later light changes' first answers with `options` (none: no
    /// first answer), as [`DynamicOptions::first_bounce`] does; for
    /// benchmarks that compare settings on one session.
    pub fn set_first_bounce(&mut self, options: Option<BounceOptions>) {
        self.options.first_bounce = options;
        self.bounce = options
            .filter(|_| !self.scene.lights.is_empty())
            .map(|o| FirstBounce::new(&self.gpu, self.atlas.elements.len(), o));
    }

    /// Whether the last state published is a first answer (the light so
    /// far and the bounces of a light's change), not yet the solver's.
    pub fn is_first_answer(&self) -> bool {
        self.preview.is_some()
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
        let lights = self.pending.take().and_then(|p| p.lights);
        self.pending = Some(Pending {
            poses: poses.to_vec(),
            lights,
            tag,
        });
    }

    /// New states for every light of the scene (issue 60: switched,
    /// dimmed, recoloured, moved or turned), tagged `tag`; they replace any
    /// lights still waiting, and the tag of poses still waiting. When the
    /// running unit is done, each light that differs is changed at the
    /// solver ([`ProgressiveSolver::set_light`]: the signed change of its
    /// direct light, reflected, becomes unshot radiosity), then the
    /// waiting poses are moved to, if any; refinement carries the change
    /// and, once the scene holds still, the gathered corrections run as
    /// after a move. The state that completes then reflects `tag`. A
    /// light that rides with a dynamic object (`Light::object`) is given
    /// with its object at its initial pose, as the scene has it, and is
    /// placed at the poses; a move of its object alone moves it too.
    pub fn set_lights(&mut self, lights: &[Light], tag: T) {
        let poses = match self.pending.take() {
            Some(p) => p.poses,
            None => self.solver.poses().to_vec(),
        };
        self.pending = Some(Pending {
            poses,
            lights: Some(lights.to_vec()),
            tag,
        });
    }

    /// The lights of the state being worked on (or last completed),
    /// placed: a light riding with a dynamic object where the object's
    /// pose puts it.
    pub fn lights(&self) -> &[Light] {
        &self.scene.lights
    }

    /// The lights to follow for `poses`: `set` (as set, with their objects
    /// at their initial poses) or the lights as last set, placed at
    /// `poses`; none when no lights were set and none rides with an object.
    fn placed_lights(&mut self, set: Option<Vec<Light>>, poses: &[Pose]) -> Option<Vec<Light>> {
        if set.is_none() && !self.scene.has_riding_lights() {
            return None;
        }
        if let Some(lights) = set {
            self.lights = lights;
        }
        Some(self.scene.lights_at(&self.lights, poses))
    }

    /// Changes at the solver every light that differs from `lights`;
    /// returns the change of reflected direct light per element if any
    /// did.
    fn change_lights(&mut self, lights: &[Light]) -> Result<Option<Vec<Vec3>>, GpuError> {
        let mut changed: Option<Vec<Vec3>> = None;
        for (k, light) in lights.iter().enumerate().take(self.scene.lights.len()) {
            if self.scene.lights[k] != *light {
                if let Some(delta) = self.solver.set_light(k, light.clone())? {
                    match &mut changed {
                        Some(sum) => sum.iter_mut().zip(&delta).for_each(|(s, d)| *s += *d),
                        None => changed = Some(delta),
                    }
                }
                self.scene.lights[k] = light.clone();
            }
        }
        if changed.is_some() && gives_no_light(&self.scene) {
            // Every source is off: the solution is no light at all, at
            // once (a move waiting too then starts from it). Shooting the
            // change takes the light back only as well as its hemicubes
            // match those that brought it (on cornell-point 2% of the
            // brightest texel stayed), and the corrections, whose
            // residual is measured against the emitted power, have none
            // to measure against.
            self.solver
                .adopt(&vec![glam::Vec3::ZERO; self.atlas.elements.len()])?;
        }
        Ok(changed)
    }

    /// Whether nothing is running or waiting (the solution is as refined as
    /// it will get until poses change): the last move's state is complete
    /// and refined, and its gathered corrections have run.
    pub fn is_idle(&self) -> bool {
        self.is_settled() && self.corrected && !self.wants_basis()
    }

    /// Whether a basis of each light's light is wanted and missing.
    fn wants_basis(&self) -> bool {
        self.basis.is_none()
            && super::basis::wanted(&self.scene, &self.atlas, self.options.light_basis)
    }

    /// The basis the state is composed of, while it holds (for tests and
    /// benchmarks: its size).
    pub fn basis(&self) -> Option<&Basis> {
        self.basis.as_ref()
    }

    /// Whether the work poses caused is done: nothing waits, and the state
    /// is complete and refined to the last publication level. Only the
    /// gathered corrections of a scene that holds still may be left
    /// ([`DynamicOptions::corrections`]); a benchmark of moves stops here.
    pub fn is_settled(&self) -> bool {
        matches!(self.phase, Phase::Idle) && self.pending.is_none() && !self.wants_refinement()
    }

    /// Residual of each correction round run at the current poses, as a
    /// fraction of the emitted power before the round (empty until a round
    /// has run there).
    pub fn correction_residuals(&self) -> &[f64] {
        &self.residuals
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
        if let Some(preview) = &self.preview {
            return Ok(preview.clone());
        }
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
        self.profile.set_unit(match self.phase {
            Phase::Idle | Phase::Moving(_) => Unit::Move,
            Phase::Converging { .. }
            | Phase::Refining { .. }
            | Phase::Seeding(_)
            | Phase::Settling
            | Phase::Correcting { .. }
            | Phase::Basis(_) => Unit::Refinement,
            Phase::Inserting(..) => Unit::Insertion,
            Phase::Removing(_) => Unit::Move,
        });
        match std::mem::replace(&mut self.phase, Phase::Idle) {
            Phase::Idle => self.start_unit(report),
            Phase::Converging { after_move } => self.converge(after_move, report),
            Phase::Moving(mut mv) => {
                let more = self.solver.move_step(&mut mv)?;
                if more {
                    self.phase = Phase::Moving(mv);
                } else if self.options.method == Redistribution::Cross {
                    self.complete(report)?;
                } else {
                    self.next_level = 0;
                    self.phase = Phase::Converging { after_move: true };
                }
                Ok((true, true))
            }
            Phase::Settling => self.settle(report),
            Phase::Refining { level, after_move } => self.refine(level, after_move),
            Phase::Seeding(rays) => self.seed(rays),
            Phase::Inserting(mut mv, after_move) => {
                if self.solver.move_step(&mut mv)? {
                    self.phase = Phase::Inserting(mv, after_move);
                } else {
                    // The first state is published uncorrected: light
                    // reaches the clients seconds sooner, and the
                    // corrected one follows once the scene holds still.
                    self.complete(report)?;
                }
                Ok((true, after_move))
            }
            Phase::Removing(mut mv) => {
                if self.solver.move_step(&mut mv)? {
                    self.phase = Phase::Removing(mv);
                } else {
                    self.phase = Phase::Refining {
                        level: self.options.publish_at[1],
                        after_move: true,
                    };
                }
                Ok((true, true))
            }
            Phase::Basis(mut building) => {
                // A move or a light that changes cancels the build: the
                // state is complete without it.
                if self.pending.is_some() {
                    return Ok((true, false));
                }
                let poses = self.solver.poses().to_vec();
                let built = building.step(&self.gpu, &self.atlas, &poses, self.options)?;
                match built {
                    Some(basis) => {
                        self.solver.adopt(&basis.compose(&self.scene.lights))?;
                        self.basis = Some(basis);
                        self.complete(report)?;
                    }
                    None => self.phase = Phase::Basis(building),
                }
                Ok((true, false))
            }
            Phase::Correcting { round, left } => {
                // A move cancels the rounds: what a round already handed
                // over stays unshot for refinement after the move, as any
                // unshot light does (the residual is a change of the light
                // like any other, thesis §2.2.5).
                if self.pending.is_some() {
                    return Ok((true, false));
                }
                let batches = self.profile.start();
                self.correct(round, left, report)?;
                self.profile.stop(batches, Stage::Batches);
                Ok((true, false))
            }
        }
    }

    /// While idle: starts the next unit, if any (a move to the poses
    /// waiting, refinement, or gathered corrections), in that order.
    fn start_unit(&mut self, report: &mut DynamicStep) -> Result<(bool, bool), GpuError> {
        if let Some(Pending { poses, lights, tag }) = self.pending.take() {
            // Whether the light the change starts from is refined: a
            // change that cuts the last one's refinement short (a stream,
            // the sun turning every frame) is published as far as it got
            // instead of a first answer each (on window-sun's day, first
            // answers every frame took the light latency's median from 47
            // to 76 ms and the stream from 243 to 789 kbit/s per viewer).
            let refined = !self.wants_refinement();
            let lights = self.placed_lights(lights, &poses);
            // Whether a light moves or turns (item 3's first answer is for
            // those; a switch, dim or recolour without the basis is shot
            // and published refined: a first answer from dark read 12-15%
            // short of the bounces, where the refined state is within 1%
            // a second later).
            let moved = lights.as_ref().is_some_and(|new| {
                new.iter()
                    .zip(&self.scene.lights)
                    .any(|(n, o)| n.position != o.position || n.kind != o.kind)
            });
            if let (true, Some(lights)) = (poses.as_slice() == self.solver.poses(), &lights) {
                if let Some(composed) = self
                    .basis
                    .as_ref()
                    .filter(|b| b.covers(lights))
                    .map(|b| b.compose(lights))
                {
                    // A light switched, dimmed or recoloured in place: the
                    // state is the basis's composition for the new lights,
                    // at once. `set_light` keeps the solver's account of
                    // the lights (what they deliver, its direct light);
                    // adopting the composition then replaces its light and
                    // leaves nothing unshot.
                    self.change_lights(lights)?;
                    self.solver.adopt(&composed)?;
                    self.working = tag;
                    self.complete(report)?;
                    return Ok((true, true));
                }
            }
            let change = match lights {
                Some(lights) => self.change_lights(&lights)?,
                None => None,
            };
            let Some(change) = change.filter(|_| poses.as_slice() == self.solver.poses()) else {
                self.start_move(poses, tag)?;
                return Ok((true, true));
            };
            // Only lights changed: refinement carries the change, and the
            // state it completes reflects the tag; from a refined state,
            // the first answer is published at once.
            self.working = tag;
            let answered = refined && moved && self.first_answer(&change, report)?;
            self.unpublished = !answered;
            self.basis = None;
            if self.options.corrections > 0 {
                self.corrected = false;
            }
            let dynamic: Vec<bool> = self.scene.objects.iter().map(|o| o.dynamic).collect();
            self.phase = match self.options.method {
                // Cross: the moving objects are passive, so they would
                // neither receive the change nor pass it on; on
                // cornell-point, a bulb switched off and on again came
                // back 9% short by the first correction's residual and
                // 1.3% of the texels more than 2% dark after three. They
                // go out and back in, as at the first solve (thesis
                // §4.5.2), their light gathered at the new lights.
                Redistribution::Cross if dynamic.contains(&true) => {
                    let mv = self
                        .solver
                        .begin_move(&poses, &dynamic, Redistribution::Cross)?;
                    Phase::Removing(mv)
                }
                Redistribution::Cross => Phase::Settling,
                _ => {
                    self.next_level = 0;
                    Phase::Converging { after_move: true }
                }
            };
            return Ok((true, true));
        }
        if self.wants_refinement() {
            self.phase = match self.options.method {
                Redistribution::Cross => Phase::Settling,
                _ => Phase::Converging { after_move: false },
            };
            return Ok((true, false));
        }
        if !self.corrected {
            self.residuals.clear();
            self.phase = Phase::Correcting {
                round: Round::Building,
                left: self.options.corrections.saturating_sub(1),
            };
            return Ok((true, false));
        }
        if self.wants_basis() && !self.solver.absent().contains(&true) {
            self.phase = Phase::Basis(Box::new(Building::new(&self.scene, &self.lights)));
            return Ok((true, false));
        }
        Ok((false, false))
    }

    /// A batch of [`Phase::Converging`]: publishes each level of
    /// [`DynamicOptions::publish_at`] the unshot power crosses.
    fn converge(
        &mut self,
        after_move: bool,
        report: &mut DynamicStep,
    ) -> Result<(bool, bool), GpuError> {
        let levels = self.options.publish_at;
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
            self.complete(report)?;
        }
        if shot.batches > 0 && self.next_level < levels.len() {
            self.phase = Phase::Converging {
                after_move: after_move && !crossed,
            };
        } else if shot.batches == 0 && !crossed {
            // Nothing left to shoot: converged as far as it goes.
            self.next_level = levels.len();
            self.complete(report)?;
        }
        Ok((true, after_move))
    }

    /// A batch of [`Phase::Settling`], which completes at the last
    /// publication level.
    fn settle(&mut self, report: &mut DynamicStep) -> Result<(bool, bool), GpuError> {
        let levels = self.options.publish_at;
        // Newer poses cut refinement short: what is left stays
        // unshot, and the state the next move publishes carries
        // what was shot so far (any state reflects the poses).
        if self.pending.is_some() {
            // A light change not yet shown is published as far as it got
            // first (its direct light whole, its bounces as far as shot):
            // under a stream of changes (the sun turning a little every
            // frame) each would otherwise be cut short before any state
            // showed it.
            if self.unpublished {
                self.complete(report)?;
            }
            return Ok((true, false));
        }
        let batches = self.profile.start();
        let shot = self.solver.step(Duration::ZERO)?;
        self.profile.stop(batches, Stage::Batches);
        if shot.batches > 0 && shot.unshot_fraction > levels[1] {
            self.phase = Phase::Settling;
        } else {
            self.complete(report)?;
        }
        Ok((true, false))
    }

    /// A slice of [`Phase::Seeding`]: rays for a slice of receivers, or
    /// one bounce; once what the bounces would still add is below the last
    /// publication level, the progressive solver adopts the light and the
    /// objects are inserted ([`Phase::Refining`] finds nothing unshot).
    fn seed(&mut self, mut rays: Box<RaySolver>) -> Result<(bool, bool), GpuError> {
        let level = self.options.publish_at[1];
        if !rays.is_cast() {
            rays.cast_next(&self.scene, &self.atlas, self.solver.poses(), SEED_CHUNK);
            self.phase = Phase::Seeding(rays);
        } else if rays.sweeps() < 2 || rays.residual_fraction() > level {
            rays.sweep(&self.atlas);
            self.phase = Phase::Seeding(rays);
        } else {
            self.solver.adopt(rays.radiosity())?;
            self.phase = Phase::Refining {
                level,
                after_move: false,
            };
        }
        Ok((true, false))
    }

    /// A batch of [`Phase::Refining`]; once the unshot power is down to
    /// `level`, the moving objects are inserted at the newest poses.
    fn refine(&mut self, level: f64, after_move: bool) -> Result<(bool, bool), GpuError> {
        let batches = self.profile.start();
        let shot = self.solver.step(Duration::ZERO)?;
        self.profile.stop(batches, Stage::Batches);
        if shot.batches > 0 && shot.unshot_fraction > level {
            self.phase = Phase::Refining { level, after_move };
        } else {
            // Insert at the newest poses: a move that arrived
            // meanwhile costs nothing extra.
            let poses = match self.pending.take() {
                Some(Pending { poses, lights, tag }) => {
                    if let Some(lights) = lights {
                        self.change_lights(&lights)?;
                    }
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

    /// One slice of a correction round (see [`Round`]).
    fn correct(
        &mut self,
        round: Round,
        left: u32,
        report: &mut DynamicStep,
    ) -> Result<(), GpuError> {
        // Cross holds the moving objects' light as each move left it (see
        // the module doc): they are frozen, as in refinement.
        let frozen: Vec<bool> = match self.options.method {
            Redistribution::Cross => self.scene.objects.iter().map(|o| o.dynamic).collect(),
            _ => Vec::new(),
        };
        let round = match round {
            Round::Building => {
                // Hemicubes where a sweep is affordable, rays beyond
                // (`Correction::by_rays`): a level is corrected too.
                let mut correction =
                    Box::new(if super::corrections_affordable(&self.scene, &self.atlas) {
                        Correction::new(
                            &self.gpu,
                            &self.scene,
                            &self.atlas,
                            self.solver.poses(),
                            GatherOptions::default(),
                        )?
                    } else {
                        Correction::by_rays(&self.solver)
                    });
                let from = correction.begin(&self.solver)?;
                Round::Sweeping { correction, from }
            }
            Round::Sweeping {
                mut correction,
                from,
            } => {
                if correction.sweep_pass(&self.solver)? {
                    let residual = correction.hand_over(&mut self.solver, &from, &frozen)?;
                    self.residuals.push(residual);
                    Round::Spreading {
                        correction,
                        residual,
                    }
                } else {
                    Round::Sweeping { correction, from }
                }
            }
            Round::Spreading {
                mut correction,
                residual,
            } => {
                let shot = self.solver.step(Duration::ZERO)?;
                if shot.batches > 0 && shot.unshot_fraction > self.options.publish_at[1] {
                    Round::Spreading {
                        correction,
                        residual,
                    }
                } else {
                    // A round is a complete state: publish it.
                    self.complete(report)?;
                    if left == 0 || residual <= CORRECTED_RESIDUAL {
                        self.corrected = true;
                        return Ok(());
                    }
                    let from = correction.begin(&self.solver)?;
                    self.phase = Phase::Correcting {
                        round: Round::Sweeping { correction, from },
                        left: left - 1,
                    };
                    return Ok(());
                }
            }
        };
        self.phase = Phase::Correcting { round, left };
        Ok(())
    }

    fn start_move(&mut self, poses: Vec<Pose>, tag: T) -> Result<(), GpuError> {
        self.working = tag;
        if poses.as_slice() == self.solver.poses() {
            // Same poses: the state already reflects them.
            self.reflected = self.working.clone();
            return Ok(());
        }
        if self.options.corrections > 0 {
            self.corrected = false;
        }
        self.basis = None;
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

    fn complete(&mut self, report: &mut DynamicStep) -> Result<(), GpuError> {
        if gives_no_light(&self.scene) {
            // With every source off a complete state is dark, whatever a
            // move's redistribution left while the light was going (on
            // cornell-point, a bulb switched off as the box moved left
            // light the move's projection carried until the corrections).
            self.solver
                .adopt(&vec![glam::Vec3::ZERO; self.atlas.elements.len()])?;
        }
        self.preview = None;
        self.reflected = self.working.clone();
        self.unpublished = false;
        self.versions += 1;
        report.completed = true;
        Ok(())
    }

    /// Publishes the first answer to a light change that refinement will
    /// carry ([`DynamicOptions::first_bounce`]): the solver's state so far
    /// (the change's direct light whole) plus the bounces of its unshot
    /// light, [`super::vpl`]. `change` is the change of reflected direct
    /// light per element, which the passive objects of a cross session
    /// send (refinement does not shoot their unshot light). Nothing
    /// without lights giving light, or with the first bounce off. Returns
    /// whether it published.
    fn first_answer(
        &mut self,
        change: &[Vec3],
        report: &mut DynamicStep,
    ) -> Result<bool, GpuError> {
        let Some(bounce) = &self.bounce else {
            return Ok(false);
        };
        if gives_no_light(&self.scene) {
            return Ok(false);
        }
        let solver = &self.solver;
        let mut source = solver.unshot_light()?;
        let (validity, absent) = (solver.validity(), solver.absent());
        let receives = |i: usize| {
            let object = self.atlas.elements[i].object as usize;
            !validity.is_invalid(i) && !absent.get(object).copied().unwrap_or(false)
        };
        for (i, s) in source.iter_mut().enumerate() {
            if solver.is_passive_element(i) && receives(i) {
                *s = change[i];
            }
        }
        let (areas, albedo) = solver.areas_and_albedo();
        let receivers = vpl::receivers(&self.atlas, solver.poses(), albedo, receives);
        let (light, times) = bounce.run(&self.gpu, &receivers, &source, areas)?;
        let state: Vec<Vec3> = solver
            .radiosity()?
            .iter()
            .zip(&light)
            .map(|(b, l)| (*b + *l).max(Vec3::ZERO))
            .collect();
        self.complete(report)?;
        self.preview = Some(state);
        self.bounce_report = Some(times);
        Ok(true)
    }
}

/// A basis being built, a group at a time, a slice per call.
struct Building {
    groups: Vec<Option<Scene>>,
    done: Vec<Vec<Vec3>>,
    current: Option<Box<DynamicSolver<()>>>,
    built_for: Vec<Light>,
}

impl Building {
    /// Starts building the basis of `scene` (its lights as they are now,
    /// placed; `lights` are the same as set, each where its object's
    /// initial pose puts it, which the groups' sessions place again).
    fn new(scene: &Scene, lights: &[Light]) -> Self {
        let mut set = scene.clone();
        set.lights = lights.to_vec();
        Self {
            groups: super::basis::groups(&set),
            done: Vec::new(),
            current: None,
            built_for: scene.lights.clone(),
        }
    }

    /// One slice of the build at `poses`: a step of the running group's
    /// session, or the start of the next group. Returns the basis once
    /// every group is solved.
    fn step(
        &mut self,
        gpu: &Device,
        atlas: &Atlas,
        poses: &[Pose],
        options: DynamicOptions,
    ) -> Result<Option<Basis>, GpuError> {
        if let Some(session) = &mut self.current {
            if session.is_idle() {
                self.done.push(session.radiosity()?);
                self.current = None;
            } else {
                session.step(std::time::Duration::ZERO)?;
                return Ok(None);
            }
        }
        let next = self.done.len();
        if next == self.groups.len() {
            let mut solved = std::mem::take(&mut self.done).into_iter();
            let rest = solved.next().unwrap_or_default();
            return Ok(Some(Basis::new(
                rest,
                solved.collect(),
                self.built_for.clone(),
            )));
        }
        match &self.groups[next] {
            None => self.done.push(vec![Vec3::ZERO; atlas.elements.len()]),
            Some(scene) => {
                let options = DynamicOptions {
                    light_basis: 0,
                    first_bounce: None,
                    ..options
                };
                self.current = Some(Box::new(DynamicSolver::new(
                    gpu,
                    scene,
                    atlas,
                    poses,
                    (),
                    options,
                )?));
            }
        }
        Ok(None)
    }
}
