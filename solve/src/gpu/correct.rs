//! Gathered correction of a progressive solution (defect correction).
//!
//! Progressive refinement is fast, but each of its shots sees its receivers
//! through one hemicube eye per shooter tile with a yes-or-no visibility
//! lookup: the light it delivers is noisy from texel to texel near
//! occluders and slightly short overall (BENCHMARKS.md, issue 15: 2-4%
//! NRMSE against the reference on the Cornell scenes). Gathering (thesis
//! §4.2) integrates a whole hemicube per receiver and is accurate, but
//! needs a dozen full sweeps from `B = E`.
//!
//! A correction round uses each for what it does well. With `G` one gather
//! sweep (`G(B) = E + ρ (D + ∫ (B - E))`, the affine map whose fixed point
//! is the gather solution) and `B_p` the progressive solution, the residual
//! `r = G(B_p) - B_p` is what `B_p` lacks after one more accurate bounce.
//! The error `e = B* - B_p` solves `e = r + K e`, with `K` the linear part
//! of `G`. Shooting `r` as unshot radiosity with the progressive solver
//! solves the same equation with the progressive transport `K'` instead of
//! `K`, so what remains after a round is about `(K' - K) e`: the
//! progressive solver's relative error applied to an error that is already
//! small. Iterative refinement of a linear system, with the cheap operator
//! inside and the accurate one for the residual (as in Cohen and Wallace's
//! use of a final gather after progressive refinement, here iterated).
//!
//! Measured (BENCHMARKS.md, "Issue 15: gathered corrections"): two rounds
//! take cornell-blocks from 4.09% to 0.55% and cornell-large from 2.37% to
//! 0.74% at the files' densities, converging to the gather solver's own
//! accuracy in a fraction of its time.
//!
//! The gather solver is built at the progressive solver's poses and does
//! not follow moves: corrections serve solves at fixed poses (`bake`,
//! `bench solve`) and the first solve of a cross session
//! (`gpu::DynamicSolver`), whose static light then stays corrected while
//! moves redistribute the moving objects' share of it.

use glam::Vec3;

use super::device::{Device, GpuError};
use super::gather::{GatherOptions, GatherSolver};
use super::placement::world_areas;
use super::progressive::ProgressiveSolver;
use lightwire_scene::atlas::Atlas;
use lightwire_scene::{Pose, Scene};

/// What one correction round did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CorrectionReport {
    /// Power of the residual `Σ A |r|` (channels summed) as a fraction of
    /// the emitted power: how far the solution was from a gather sweep's
    /// fixed point before the round.
    pub residual_fraction: f64,
    /// Shooters the progressive solver shot to spread the residual, in
    /// this many batches.
    pub shots: u64,
    pub batches: u64,
}

/// Gather sweeps that correct a [`ProgressiveSolver`]'s solution.
pub struct Correction {
    gather: GatherSolver,
    /// World area per element.
    areas: Vec<f32>,
    /// Object per element.
    objects: Vec<u32>,
    emitted: f64,
}

/// Most `elements x patches` a correction takes on unless asked for: a
/// gather sweep renders every patch into one hemicube per element, so its
/// cost grows with both, about a microsecond per unit on lavapipe (the
/// 864-triangle box of `bench meshes` at x0.5, 18,000 x 864, took about
/// 15 s a round): at this bound a round takes a minute or two. The quad
/// scenes and the mesh box (`scenes/meshes/cornell-dynamic.glb`) are
/// below 10^7; the atrium at full density is 2.8 x 10^8, the tessellated
/// boxes with 9,600 and 101,400 triangles 8.7 x 10^8 and 4 x 10^10 (a
/// round of hours: a service on it would sit in the sweep).
pub const MAX_DEFAULT_SWEEP: u64 = 100_000_000;

/// Whether gathered corrections of `scene` over `atlas` run by default
/// (see [`MAX_DEFAULT_SWEEP`]).
pub fn corrections_affordable(scene: &Scene, atlas: &Atlas) -> bool {
    (atlas.elements.len() as u64).saturating_mul(scene.patches.len() as u64) <= MAX_DEFAULT_SWEEP
}

impl Correction {
    /// Builds the gather sweep for `scene` at `poses`, which must be the
    /// poses the corrected solver was built at. `options.indirect_only` is
    /// ignored: a correction needs the whole radiosity.
    pub fn new(
        gpu: &Device,
        scene: &Scene,
        atlas: &Atlas,
        poses: &[Pose],
        options: GatherOptions,
    ) -> Result<Self, GpuError> {
        let options = GatherOptions {
            indirect_only: false,
            ..options
        };
        let gather = GatherSolver::new(gpu, scene, atlas, poses, options)?;
        let local: Vec<f32> = atlas.elements.iter().map(|e| e.area).collect();
        let objects: Vec<u32> = atlas
            .elements
            .iter()
            .map(|e| scene.patches[e.patch as usize].object)
            .collect();
        let areas = world_areas(&local, &objects, poses);
        let emitted = gather.emitted_power();
        Ok(Self {
            gather,
            areas,
            objects,
            emitted,
        })
    }

    /// One round: a gather sweep from `solver`'s radiosity, its difference
    /// handed to `solver` as unshot radiosity, and progressive refinement
    /// until the unshot power is at most `threshold` of the emitted power.
    pub fn round(
        &mut self,
        solver: &mut ProgressiveSolver,
        threshold: f64,
    ) -> Result<CorrectionReport, GpuError> {
        self.round_except(solver, threshold, &[])
    }

    /// A round in which the elements of the objects flagged in `frozen`
    /// shoot no residual of their own: they take theirs as shown light only
    /// ([`ProgressiveSolver::add_shown`]; they still occlude and are seen
    /// by the gather sweep). A cross session freezes its moving objects:
    /// their light is each move's business, and refinement holds them
    /// passive (`gpu::DynamicSolver`).
    pub fn round_except(
        &mut self,
        solver: &mut ProgressiveSolver,
        threshold: f64,
        frozen: &[bool],
    ) -> Result<CorrectionReport, GpuError> {
        let b = self.begin(solver)?;
        self.gather.bounce()?;
        let residual_fraction = self.hand_over(solver, &b, frozen)?;
        let report = solver.solve(threshold)?;
        Ok(CorrectionReport {
            residual_fraction,
            shots: report.shots,
            batches: report.batches,
        })
    }

    /// The first part of a round cut into slices (`gpu::DynamicSolver`
    /// runs rounds between moves, a pass at a time): the sweep starts from
    /// `solver`'s radiosity, which is returned for [`Correction::hand_over`].
    pub fn begin(&mut self, solver: &ProgressiveSolver) -> Result<Vec<Vec3>, GpuError> {
        let b = solver.total_radiosity()?;
        self.gather.start_from(&b);
        Ok(b)
    }

    /// One pass of the sweep [`Correction::begin`] started; returns whether
    /// the sweep is complete.
    pub fn sweep_pass(&mut self) -> Result<bool, GpuError> {
        let before = self.gather.total_bounces();
        self.gather.step(std::time::Duration::ZERO)?;
        Ok(self.gather.total_bounces() > before)
    }

    /// Hands the residual of the completed sweep from `b` (what
    /// [`Correction::begin`] returned) to `solver` as unshot radiosity,
    /// except on the elements of the objects flagged in `frozen`, which
    /// show theirs without shooting it ([`ProgressiveSolver::add_shown`]);
    /// returns the residual's power as a fraction of the emitted power.
    /// Refinement (the solver's own steps) then spreads it.
    pub fn hand_over(
        &mut self,
        solver: &mut ProgressiveSolver,
        b: &[Vec3],
        frozen: &[bool],
    ) -> Result<f64, GpuError> {
        let gathered = self.gather.total_radiosity()?;
        let is_frozen = |o: u32| frozen.get(o as usize).copied().unwrap_or(false);
        let all: Vec<Vec3> = gathered.iter().zip(b).map(|(g, b)| *g - *b).collect();
        let valid = solver.validity();
        let power: f64 = all
            .iter()
            .enumerate()
            .filter(|(i, _)| !valid.is_invalid(*i))
            .map(|(i, r)| f64::from(self.areas[i]) * f64::from(r.abs().element_sum()))
            .sum();
        let (mut shot, mut shown) = (all.clone(), all);
        for (i, &o) in self.objects.iter().enumerate() {
            if is_frozen(o) {
                shot[i] = Vec3::ZERO;
            } else {
                shown[i] = Vec3::ZERO;
            }
        }
        solver.add_unshot(&shot)?;
        // Frozen objects show the corrected light without shooting it:
        // their light is each move's business.
        solver.add_shown(&shown, frozen)?;
        Ok(if self.emitted > 0.0 {
            power / self.emitted
        } else {
            0.0
        })
    }
}
