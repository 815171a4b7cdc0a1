//! Following moved objects by redistributing light instead of solving
//! again (thesis ch. 3 and 4).
//!
//! A move splits the patches into the moved set M and the static set C
//! (thesis §3.1). The transport that changes is cut into four parts,
//! R(C, M), R(M, C), R(M, M) and R(C, C) (eq. 3.1.2), and two methods
//! implement them on the GPU, both built from the progressive solver's
//! batches (shooters, hemicube item buffers, a reconstruction pass):
//!
//! - **Incremental radiosity with reshooting** (thesis §4.4, Alg. 4.3):
//!   every patch of M shoots its old shot radiosity negated from its old
//!   position (the first half of R_p(M, C)); M is reset to its emission;
//!   every patch of C shoots once with a hemicube at the old and at the new
//!   poses: to M it reshoots its total radiosity (R_p(C, M), eq. 4.4.1), to
//!   C it shoots by the four visibility cases of Alg. 4.3 (R_p(C, C)).
//!   Ordinary progressive iterations then do R_p(M, M) and the second half
//!   of R_p(M, C). Cost: two hemicubes per shooter of every patch.
//! - **Cross redistribution radiosity** (thesis §3.3, §4.5, Alg. 4.4-4.5):
//!   only M gets hemicubes, one set per tile of its patches (at most
//!   `cross_tile`² texels; the thesis likewise gives the box far fewer
//!   elements for cross, §5.1): front item buffers at the old and new
//!   positions, a front hemicube of C's shot radiosity at the new position
//!   that the tile gathers from (R_g(C, M)), and back hemicubes of C's
//!   shot radiosity with depth at both positions, through which every
//!   element of C sees what M's old position stopped blocking and what its
//!   new position blocks (the non-incremental cross projection R_x(C, C),
//!   eq. 3.3.1, with reprojection; a closed object's tiles need no back
//!   item buffers, `cross.rs`). Each tile then shoots its new total
//!   radiosity and its negated old shot radiosity (area-weighted averages
//!   over its texels). A tile's hemicube gathers reflected light only: the
//!   emitters' direct light is computed per texel on the CPU when the move
//!   starts ([`crate::direct::element_direct_light`]), so a face under a
//!   lamp falls off towards its edges as it should instead of showing its
//!   tiles' centres. After the last batch, and after the static texels
//!   near the move have gathered again (`progressive/regather.rs`), every
//!   tile gathers once more, from C's total radiosity: B^s lacks what M's
//!   new position changes on C (its shadow on the floor beside it above
//!   all), and the faces that see it read 10-30% too bright from B^s
//!   alone. The texels of M read these second gathers as samples at the
//!   tile centres, bilinear between them (`smooth_moving`), so faces show
//!   no bands at tile boundaries; what that adds beyond what the tile shot
//!   is kept apart and left out of the old shot radiosity the next move
//!   takes back, which therefore equals what the tile shot. A texel at a
//!   contact (a box's row on the floor) sees light change within its own
//!   footprint, which no tile value shows: it gathers on its own too, on
//!   the CPU (`progressive/regather.rs`).
//!
//! Cross projection uses C's shot radiosity B^s; it cancels exactly only
//! while B^s of C does not change. So progressive iterations never run
//! with M in the scene: [`crate::gpu::DynamicSolver`] removes M (a cross
//! redistribution to "absent") before refining and inserts it again after
//! (thesis §4.5.2), and moves in between leave B^s of C untouched.
//!
//! A move is a list of [`Job`]s, each one GPU batch; the list can be
//! interrupted between jobs (thesis §4.5.3) and the state is consistent
//! only when it is empty, which is what double buffering publishes.
//!
//! The module in parts, one concept per file:
//!
//! - this file: the methods, a move and its jobs, and the move's public
//!   interface (`begin_move`, `move_step`, `finish_move`), which places M
//!   and runs each job by its kind;
//! - `plan.rs`: what a move's jobs are (shooter grids sized by power for
//!   incremental, tiles for cross, the patches that face nothing);
//! - `resources.rs`: the redistribution passes, their targets and
//!   buffers, built on the first move, and the hemicube rows kept from
//!   one move for the next (`Kept`);
//! - `incremental.rs`: the batches of incremental redistribution;
//! - `cross.rs`: the batches of cross redistribution;
//! - `gather.rs`: the light M's texels gather (direct light per texel, the
//!   tiles' gathers after the move, the smoothing between tile centres)
//!   and the end of a move;
//! - `lights.rs`: the lights' and the sky's direct light the move changes
//!   (shadows on the static set, the moved faces under incremental);
//! - `redistribute.wgsl`: the compute passes of all of this.

use std::collections::VecDeque;
use std::fmt;
use std::str::FromStr;

use super::{BatchUniform, GpuError, GpuShooter, ProgressiveSolver};
use crate::gpu::buffers::{WORKGROUP, encode_compute};
use crate::gpu::placement::world_areas;
use crate::gpu::profile::Stage;
use lightwire_scene::Pose;

mod cross;
mod gather;
mod incremental;
mod lights;
mod plan;
mod resources;

pub(in crate::gpu) use resources::DynamicPasses;

/// How the solver follows a move of the dynamic objects.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Redistribution {
    /// Progressive refinement from scratch at the new poses (the baseline).
    Full,
    /// Incremental radiosity with reshooting (thesis §4.4, Alg. 4.3).
    Incremental,
    /// Cross redistribution radiosity (thesis §4.5, Alg. 4.4-4.5).
    #[default]
    Cross,
}

impl Redistribution {
    /// Every method, in the order benchmarks list them.
    pub const ALL: [Redistribution; 3] = [Self::Full, Self::Incremental, Self::Cross];

    /// The name used in scene files, flags and reports.
    pub fn name(self) -> &'static str {
        match self {
            Self::Full => "full",
            Self::Incremental => "incremental",
            Self::Cross => "cross",
        }
    }
}

impl fmt::Display for Redistribution {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Redistribution {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| {
                format!("unknown redistribution method {s:?} (expected full, incremental or cross)")
            })
    }
}

/// `Batch.mode` values of redistribute.wgsl.
const KIND_NEGATIVE: u32 = 1;
const KIND_STATIC: u32 = 2;
const KIND_CROSS: u32 = 3;
const HAS_NEW: u32 = 0x100;
const HAS_OLD: u32 = 0x200;
const RESET_UNSHOT: u32 = 0x400;
/// Cross: the tiles have no back hemicubes (a closed object's).
const ONE_SIDED: u32 = 0x800;
/// Cross: the old-pose slots are the last job's new-pose ones (`Kept`), so
/// `reconstruct_dyn` reads which reach an element from `marks`.
const KEPT_MARKS: u32 = 0x1000;
/// Words of `marks` per element (`MARK_WORDS` in redistribute.wgsl): a bit
/// per new-pose slot, at most half of a batch's.
const MARK_WORDS: u64 = (super::shooters::MAX_BATCH as u64 / 2).div_ceil(32);
/// Texels per row of the shown textures (`SHOWN_WIDTH` in common.wgsl).
pub(in crate::gpu) const SHOWN_WIDTH: u32 = 2048;

/// `Batch.mode` of a batch that only draws hemicubes and reads them (the
/// back hemicubes, the regathering): no kind of reconstruction.
const HEMICUBES_ONLY: u32 = 0;
/// Top-face resolution of the hemicubes a moving tile gathers from, at
/// most (in the move and again after it): they see reflected light only
/// (no emitter), which varies slowly, so a quarter of the pixels of the
/// default 64² does; on lavapipe the pass costs about what its pixels do.
const GATHER_RESOLUTION: u32 = 32;

/// One GPU batch of a move.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Job {
    /// Incremental: a patch of M shoots its negated old shot radiosity.
    Negative { patch: u32, shooters: u32 },
    /// Incremental: a patch of C shoots with old and new hemicubes; its
    /// shooters `from..` that fit the batch (two hemicubes each), the rest
    /// in the job that follows.
    Static {
        patch: u32,
        shooters: u32,
        from: u32,
    },
    /// Cross: tiles `first..first + count` of [`Move::tiles`] shoot, one
    /// shooter per tile.
    Cross { first: u32, count: u32 },
}

/// A shooting tile of a moving patch for cross redistribution: texels
/// `[a0, b0, a1, b1)` of the patch's chart. The tile is the thesis's
/// reduced "element on the rotating box" (§5.1: 918 box elements become 90
/// for cross redistribution on the large Cornell box, 270 become 24 on the
/// low-quality one): it gathers, shoots and casts shadows as one.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CrossTile {
    pub patch: u32,
    pub texels: [u32; 4],
}

/// A move in progress: what changed, and the batches still to run.
#[derive(Debug, Clone)]
pub struct Move {
    /// The method this move is redistributed with.
    pub method: Redistribution,
    /// Poses and presence before the move.
    old_poses: Vec<Pose>,
    old_absent: Vec<bool>,
    /// The objects in M.
    moving: Vec<bool>,
    jobs: VecDeque<Job>,
    /// Cross: the shooting tiles of M.
    tiles: Vec<CrossTile>,
    /// Whether M's direct light is still to be computed and written
    /// (`write_moving_direct`): the first cross job does it on the CPU
    /// while the GPU draws its hemicubes.
    direct_due: bool,
    /// The elements whose validity the move changed (covered or
    /// uncovered by M), ascending.
    flipped: Vec<usize>,
    /// Batches run so far.
    pub batches: u32,
}

impl Move {
    /// Batches left.
    pub fn remaining(&self) -> usize {
        self.jobs.len()
    }
    /// Whether some object changed at all.
    pub fn is_empty_move(&self) -> bool {
        !self.moving.iter().any(|m| *m)
    }
    /// Cross: the patches the move's tiles were cut from, each once, in
    /// order.
    pub fn tiled_patches(&self) -> Vec<u32> {
        let mut patches: Vec<u32> = self.tiles.iter().map(|t| t.patch).collect();
        patches.dedup();
        patches
    }
}

impl ProgressiveSolver {
    /// The current pose of every object.
    pub fn poses(&self) -> &[Pose] {
        &self.poses
    }

    /// Which objects are currently removed from the simulation.
    pub fn absent(&self) -> &[bool] {
        &self.absent
    }

    /// Starts following a change of poses and/or presence: the objects
    /// whose pose or presence differs form M. Places M at its new pose on
    /// the GPU, saves M's shot radiosity and resets M (reshooting), and
    /// plans the batches of `method` (which must not be `Full`: that is a
    /// new solver). Run the batches with [`ProgressiveSolver::move_step`].
    pub fn begin_move(
        &mut self,
        poses: &[Pose],
        absent: &[bool],
        method: Redistribution,
    ) -> Result<Move, GpuError> {
        let setup = self.profile.start();
        let objects = self.poses.len();
        if poses.len() != objects || absent.len() != objects {
            return Err(GpuError::TooLarge(format!(
                "a move needs {objects} poses and presence flags, got {} and {}",
                poses.len(),
                absent.len()
            )));
        }
        let moving: Vec<bool> = (0..objects)
            .map(|o| poses[o] != self.poses[o] || absent[o] != self.absent[o])
            .collect();
        let old_poses = std::mem::replace(&mut self.poses, poses.to_vec());
        let old_absent = std::mem::replace(&mut self.absent, absent.to_vec());
        let mut mv = Move {
            method,
            old_poses,
            old_absent,
            moving,
            jobs: VecDeque::new(),
            tiles: Vec::new(),
            direct_due: false,
            flipped: Vec::new(),
            batches: 0,
        };
        if mv.is_empty_move() {
            return Ok(mv);
        }
        // Contacts move with the objects (crate::validity).
        mv.flipped = self.update_validity(&mv.old_poses, &mv.moving);
        // Incremental: total power per patch before the move (one
        // readback), to size the shooter grids. Cross tiles do not depend
        // on power.
        let patch_power = if method == Redistribution::Incremental {
            self.patch_power()?
        } else {
            Vec::new()
        };
        self.place_moving(&mv, poses);
        // Cross: written by the first job once its hemicubes are queued.
        mv.direct_due = method != Redistribution::Incremental;
        match method {
            Redistribution::Incremental => self.plan_incremental(&mut mv, &patch_power),
            Redistribution::Cross | Redistribution::Full => self.plan_cross(&mut mv),
        }
        self.profile.stop(setup, Stage::MoveSetup);
        Ok(mv)
    }

    /// Places every element at the new `poses` on the GPU, marks M, and
    /// saves and resets M's radiosity (`reset_moving`; for incremental,
    /// its unshot radiosity as well).
    fn place_moving(&mut self, mv: &Move, poses: &[Pose]) {
        self.patches = self.table.place(&self.poses);
        self.areas = world_areas(&self.local_areas, &self.element_objects, &self.poses);
        self.write_poses(poses, &mv.old_poses, &mv.old_absent);
        self.write_flags(&mv.moving);
        let reset_mode = match mv.method {
            Redistribution::Incremental => RESET_UNSHOT,
            _ => 0,
        };
        let uniform = self.batch_uniform(u32::MAX, 0, u32::MAX, reset_mode);
        self.queue
            .write_buffer(&self.buffers.batch, 0, bytemuck::bytes_of(&uniform));
        // The gathering hemicubes drawn before are of other poses.
        self.dynamic_passes();
        if let Some(d) = self.dynamic.as_mut() {
            d.front_ids_of.clear();
        }
        let mut encoder = self.device.create_command_encoder(&Default::default());
        // The reset reads the elements only for their objects, so it may
        // run after placement.
        self.encode_place(&mut encoder);
        if let Some(d) = &self.dynamic {
            encode_compute(
                &mut encoder,
                &d.reset,
                self.element_count.div_ceil(WORKGROUP),
            );
        }
        self.queue.submit([encoder.finish()]);
    }

    /// Runs the next batch of `mv`; returns whether batches remain. When
    /// the last one has run, M is no longer marked and the next shooter is
    /// selected, so that progressive refinement can continue.
    pub fn move_step(&mut self, mv: &mut Move) -> Result<bool, GpuError> {
        if let Some(job) = mv.jobs.pop_front() {
            let direct_due = std::mem::take(&mut mv.direct_due);
            if let Some(rest) = self.run_job(mv, job, direct_due)? {
                mv.jobs.push_front(rest);
            }
            mv.batches += 1;
        }
        if mv.jobs.is_empty() {
            self.end_move(mv)?;
            return Ok(false);
        }
        Ok(true)
    }

    /// Runs every batch of `mv`.
    pub fn finish_move(&mut self, mv: &mut Move) -> Result<(), GpuError> {
        while self.move_step(mv)? {}
        Ok(())
    }

    /// Runs one batch of `job`; returns what is left of it for the next
    /// batch (a static patch whose shooters did not all fit).
    /// Runs `job` of `mv`; with `direct_due`, computes and writes M's
    /// direct light (`write_moving_direct`) before the first pass that
    /// reads it.
    fn run_job(&mut self, mv: &Move, job: Job, direct_due: bool) -> Result<Option<Job>, GpuError> {
        let mut rest = None;
        let setup = self.profile.start();
        let old_patches = self.table.place(&mv.old_poses);
        let old_areas = world_areas(&self.local_areas, &self.element_objects, &mv.old_poses);
        let mut encoder = self.device.create_command_encoder(&Default::default());
        match job {
            Job::Negative { patch, shooters } => {
                let old = &old_patches[patch as usize];
                self.run_negative(&mut encoder, setup, (patch, shooters), (old, &old_areas));
            }
            Job::Static {
                patch,
                shooters,
                from,
            } => {
                rest = self.run_static(&mut encoder, setup, (patch, shooters, from));
            }
            Job::Cross { first, count } => {
                let tiles = &mv.tiles[first as usize..(first + count) as usize];
                let old = (&old_patches[..], &old_areas[..]);
                self.run_cross(&mut encoder, setup, mv, tiles, old, direct_due);
            }
        }
        self.queue.submit([encoder.finish()]);
        Ok(rest)
    }

    /// Submits what `encoder` holds and leaves a new encoder in its place:
    /// the GPU starts on it while the CPU prepares what comes next.
    fn submit_queued(&self, encoder: &mut wgpu::CommandEncoder) {
        let queued = std::mem::replace(
            encoder,
            self.device.create_command_encoder(&Default::default()),
        );
        self.queue.submit([queued.finish()]);
    }

    /// Writes a batch's shooters and its uniform.
    fn upload(&self, shooters: &[GpuShooter], uniform: BatchUniform) {
        self.queue
            .write_buffer(&self.buffers.shooters, 0, bytemuck::cast_slice(shooters));
        self.queue
            .write_buffer(&self.buffers.batch, 0, bytemuck::bytes_of(&uniform));
    }
}
