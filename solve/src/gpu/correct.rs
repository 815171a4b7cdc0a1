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
//! The sweep is built at the progressive solver's poses and does not
//! follow moves: corrections serve solves at fixed poses (`bake`, `bench
//! solve`) and a live session's state whenever it holds still
//! (`gpu::DynamicSolver`).
//!
//! A sweep draws hemicubes (the gather solver, thesis §4.2) where elements
//! x patches is at most [`MAX_DEFAULT_SWEEP`], and casts rays beyond
//! ([`Correction::by_rays`]: `direct::gather`, cosine-distributed rays
//! against the bounding volume hierarchy, the emitters by next-event
//! estimation): on the garage level (63,617 elements, 9,188 patches) a
//! ray-cast sweep takes 7-9 s on two cores, and two rounds took the
//! lightmap from 18.1% to 11.7% NRMSE against the path tracer where a
//! player looks (BENCHMARKS.md, section 9).

use glam::Vec3;

use super::device::{Device, GpuError};
use super::gather::{GatherOptions, GatherSolver};
use super::placement::world_areas;
use super::progressive::ProgressiveSolver;
use crate::direct::{Lookup, gather};
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
    sweep: Sweep,
    /// World area per element.
    areas: Vec<f32>,
    /// Object per element.
    objects: Vec<u32>,
    emitted: f64,
}

/// Most `elements x patches` a correction sweeps with hemicubes (beyond,
/// it casts rays, [`Correction::by_rays`]): a gather sweep renders every
/// patch into one hemicube per element, so its cost grows with both,
/// about a microsecond per unit on lavapipe (the
/// 864-triangle box of `bench meshes` at x0.5, 18,000 x 864, took about
/// 15 s a round): at this bound a round takes a minute or two. The quad
/// scenes and the mesh box (`scenes/meshes/cornell-dynamic.glb`) are
/// below 10^7; the atrium at full density is 2.8 x 10^8, the tessellated
/// boxes with 9,600 and 101,400 triangles 8.7 x 10^8 and 4 x 10^10 (a
/// round of hours: a service on it would sit in the sweep).
pub const MAX_DEFAULT_SWEEP: u64 = 100_000_000;

/// Whether a correction of `scene` over `atlas` sweeps with hemicubes
/// (see [`MAX_DEFAULT_SWEEP`]); otherwise with rays.
pub fn corrections_affordable(scene: &Scene, atlas: &Atlas) -> bool {
    (atlas.elements.len() as u64).saturating_mul(scene.patches.len() as u64) <= MAX_DEFAULT_SWEEP
}

/// Cosine-distributed rays per receiver of a ray-cast sweep, as a
/// `RAY_SIDE` x `RAY_SIDE` stratified grid (`raycast::CosineGrid`).
pub const RAY_SIDE: usize = 16;
/// Samples per emitting patch for a ray-cast sweep's direct light,
/// `RAY_GRID` x `RAY_GRID` (`direct::Emitters::irradiance`).
pub const RAY_GRID: usize = 16;
/// Receivers a ray-cast sweep gathers per [`Correction::sweep_pass`] (a
/// live session's slice between moves; [`Correction::round`] gathers all
/// in one): on the garage about a tenth of a second on two cores.
const RAY_CHUNK: usize = 512;

/// How a correction's sweep integrates each receiver's hemisphere.
enum Sweep {
    /// The gather solver's hemicubes (thesis §4.2), on the GPU: its cost
    /// grows with elements x patches ([`MAX_DEFAULT_SWEEP`]).
    Hemicube(Box<GatherSolver>),
    /// Rays from each valid element's sample point against the bounding
    /// volume hierarchy (`direct::gather`), on the CPU: its cost grows
    /// with elements x rays x log(patches), so it serves the levels a
    /// hemicube sweep cannot.
    Rays(RaySweep),
}

/// A ray-cast sweep in progress.
#[derive(Default)]
struct RaySweep {
    /// The radiosity the rays read where they land (negative light as
    /// none, invalid texels filled from their valid neighbours, as
    /// published).
    seen: Vec<[f32; 4]>,
    /// The valid elements that stand for surface, which gather.
    receivers: Vec<usize>,
    /// Receivers gathered so far.
    next: usize,
    /// Receivers per [`Correction::sweep_pass`].
    chunk: usize,
    /// `G(B)` per element: the sweep's start where no receiver gathered.
    gathered: Vec<Vec3>,
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
        let emitted = gather.emitted_power();
        Ok(Self::with_sweep(
            Sweep::Hemicube(Box::new(gather)),
            (scene, atlas, poses),
            emitted,
        ))
    }

    /// `sweep` with the world area and object of every element of `scene`
    /// at `poses`, and the power its sources put in (`emitted`: the
    /// emission and the lights' reflected direct light), which residuals
    /// are measured against.
    fn with_sweep(
        sweep: Sweep,
        (scene, atlas, poses): (&Scene, &Atlas, &[Pose]),
        emitted: f64,
    ) -> Self {
        let local: Vec<f32> = atlas.elements.iter().map(|e| e.area).collect();
        let objects: Vec<u32> = atlas
            .elements
            .iter()
            .map(|e| scene.patches[e.patch as usize].object)
            .collect();
        let areas = world_areas(&local, &objects, poses);
        Self {
            sweep,
            areas,
            objects,
            emitted,
        }
    }

    /// A correction whose sweep casts rays on the CPU instead of drawing
    /// hemicubes ([`RAY_SIDE`]² cosine-distributed rays per receiver, the
    /// emitters by next-event estimation with [`RAY_GRID`]² samples each,
    /// `direct::gather`), for `solver`'s scene at its poses. A hemicube
    /// sweep draws every patch once per element; rays find what they meet
    /// in the bounding volume hierarchy, so a level of 11,000 triangles
    /// and 63,000 elements takes seconds (BENCHMARKS.md, section 9) where
    /// a hemicube sweep would take many minutes.
    pub fn by_rays(solver: &ProgressiveSolver) -> Self {
        let (scene, atlas, poses, _) = solver.world();
        Self::with_sweep(
            Sweep::Rays(RaySweep::default()),
            (scene, atlas, poses),
            solver.emitted_power(),
        )
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
        // All receivers in one pass here: a pass builds the bounding
        // volume hierarchy again.
        if let Sweep::Rays(rays) = &mut self.sweep {
            rays.chunk = usize::MAX;
        }
        while !self.sweep_pass(solver)? {}
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
        match &mut self.sweep {
            Sweep::Hemicube(gather) => gather.start_from(&b),
            Sweep::Rays(rays) => {
                let (_, atlas, _, _) = solver.world();
                let valid = solver.validity();
                let mut seen: Vec<Vec3> = b.iter().map(|v| v.max(Vec3::ZERO)).collect();
                valid.dilate(atlas, &mut seen);
                *rays = RaySweep {
                    seen: seen.iter().map(|v| [v.x, v.y, v.z, 0.0]).collect(),
                    receivers: (0..b.len())
                        .filter(|&i| !valid.is_invalid(i) && atlas.elements[i].covers_surface())
                        .collect(),
                    next: 0,
                    chunk: RAY_CHUNK,
                    gathered: b.clone(),
                };
            }
        }
        Ok(b)
    }

    /// One pass of the sweep [`Correction::begin`] started (a hemicube
    /// sweep's pass, or [`RAY_CHUNK`] receivers' rays); returns whether the
    /// sweep is complete. `solver` must be the one `begin` read, at the
    /// same poses.
    pub fn sweep_pass(&mut self, solver: &ProgressiveSolver) -> Result<bool, GpuError> {
        match &mut self.sweep {
            Sweep::Hemicube(gather) => {
                let before = gather.total_bounces();
                gather.step(std::time::Duration::ZERO)?;
                Ok(gather.total_bounces() > before)
            }
            Sweep::Rays(rays) => {
                let (scene, atlas, poses, absent) = solver.world();
                let end = rays
                    .next
                    .saturating_add(rays.chunk)
                    .min(rays.receivers.len());
                let chunk = &rays.receivers[rays.next..end];
                let lit = gather(
                    scene,
                    atlas,
                    (poses, absent),
                    &rays.seen,
                    chunk,
                    RAY_SIDE,
                    RAY_GRID,
                    Lookup::Bilinear,
                );
                for (&i, g) in chunk.iter().zip(lit) {
                    rays.gathered[i] = g;
                }
                rays.next = end;
                Ok(rays.next == rays.receivers.len())
            }
        }
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
        let gathered = match &mut self.sweep {
            Sweep::Hemicube(gather) => gather.total_radiosity()?,
            Sweep::Rays(rays) => std::mem::take(&mut rays.gathered),
        };
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
