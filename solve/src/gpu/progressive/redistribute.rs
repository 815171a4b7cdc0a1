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
//!   item buffers, `run_job`). Each tile then shoots its new total
//!   radiosity and its negated old shot radiosity (area-weighted averages
//!   over its texels). A tile's hemicube gathers reflected light only: the
//!   emitters' direct light is computed per texel on the CPU when the move
//!   starts ([`element_direct_light`]), so a face under a lamp falls off
//!   towards its edges as it should instead of showing its tiles' centres.
//!   After the last batch, and after the static texels near the move have
//!   gathered again (`regather.rs`), every tile gathers once more, from C's
//!   total radiosity: B^s lacks what M's new position changes on C (its
//!   shadow on the floor beside it above all), and the faces that see it
//!   read 10-30% too bright from B^s alone. The texels of M read these
//!   second gathers as samples at the tile centres, bilinear between them
//!   (`smooth_moving`), so faces show no bands at tile boundaries; what
//!   that adds beyond what the tile shot is kept apart and left out of the
//!   old shot radiosity the next move takes back, which therefore equals
//!   what the tile shot. A texel at a contact (a box's row on the floor)
//!   sees light change within its own footprint, which no tile value
//!   shows: it gathers on its own too, on the CPU (`regather.rs`).
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

use std::collections::VecDeque;
use std::fmt;
use std::str::FromStr;

use glam::Vec3;

use super::pipelines::{
    GATHER_MOVING, RECONSTRUCT_DYN, REGATHER_MOVING, RESET_MOVING, SHADE_BACK, SHADE_STATIC,
    SHADE_TOTAL, SHOOTER_ENERGY_DYN, SMOOTH_MOVING,
};
use super::shooters::contact_limit;
use super::slot;
use super::{BatchUniform, GpuError, GpuShooter, ProgressiveSolver};
use crate::direct::element_direct_light;
use crate::gpu::buffers::{WORKGROUP, encode_compute, encode_compute_grid, texture, v4};
use crate::gpu::hemicube::{self, FACES};
use crate::gpu::placement::{WorldPatch, pose_matrices, world_areas};
use crate::gpu::profile::Stage;
use crate::gpu::shaders;
use lightwire_scene::Pose;

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
/// Samples per emitting patch of the moving elements' direct light,
/// `DIRECT_GRID`² (as regather.rs: a shadow ray each, the unoccluded form
/// factor exact whatever the count).
const DIRECT_GRID: usize = 8;
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

/// Pipelines and targets of the redistribution passes, built on the first
/// move so that static scenes never pay for them.
pub(in crate::gpu) struct DynamicPasses {
    reset: (wgpu::ComputePipeline, wgpu::BindGroup),
    energy: (wgpu::ComputePipeline, wgpu::BindGroup),
    gather: (wgpu::ComputePipeline, wgpu::BindGroup),
    regather: (wgpu::ComputePipeline, wgpu::BindGroup),
    smooth: (wgpu::ComputePipeline, wgpu::BindGroup),
    reconstruct: (wgpu::ComputePipeline, wgpu::BindGroup),
    /// Fill the shown textures the hemicubes of a cross batch and of the
    /// regathering read (`shade_static`, `shade_total`).
    shade_static: (wgpu::ComputePipeline, wgpu::BindGroup),
    shade_total: (wgpu::ComputePipeline, wgpu::BindGroup),
    /// The tiles' gathering hemicubes (`ELEMENT_IDS` into `front_view`).
    rad_front: (hemicube::Pipelines, wgpu::BindGroup),
    rad_back: (hemicube::Pipelines, wgpu::BindGroup),
    back_shooters: wgpu::Buffer,
    back_batch: wgpu::Buffer,
    /// The back hemicubes' `poses`: both pose sets as the item buffers'
    /// (`write_poses`), the moving objects' matrices zero, written per
    /// cross job.
    back_poses: wgpu::Buffer,
    /// Direct light of M's elements at their new position (`moving_direct`
    /// in redistribute.wgsl), written per move.
    pub(super) moving_direct: wgpu::Buffer,
    /// What M's elements show beyond what their tiles shot (the smoothing
    /// between tile centres, gathered corrections: `add_shown`); kept out
    /// of the old shot radiosity the next move takes back.
    pub(super) smoothed: wgpu::Buffer,
    /// The shot radiosity static elements held when they were covered
    /// (`held` in redistribute.wgsl, `regather.rs`).
    pub(super) held: wgpu::Buffer,
    front_view: wgpu::TextureView,
    /// The back hemicubes as drawn (`BACK_ELEMENTS`: element and distance
    /// per pixel); `shade_back` shades them for the projection into a
    /// texture only its bind groups hold (shot radiosity and distance,
    /// Rgba16Float).
    back_ids_view: wgpu::TextureView,
    back_depth_view: wgpu::TextureView,
    shade_back: (wgpu::ComputePipeline, wgpu::BindGroup),
    /// The item buffers of the last cross job's new-pose slots.
    kept: Kept,
    /// Its back hemicubes' new-pose slots (`back_ids_view` rows).
    kept_back: Kept,
    /// The tiles whose gathering hemicubes `front_view` holds, slot by
    /// slot, drawn at this move's new pose by its cross job; empty when
    /// none of this move. The gather after the move reads them again
    /// unless they are not its tiles (a move of several jobs).
    front_ids_of: Vec<CrossTile>,
}

/// Hemicube rows kept from one cross job for the next move. A move's old
/// pose is the last move's new one, so the item buffers and the back
/// hemicubes a job needs at its tiles' old pose are those the last move's
/// job drew at their new pose whenever the tiles, hence their shooters,
/// and the pose of every object are the same (the static scene and the
/// hemicube settings never change): those rows are then copied back
/// instead of drawn again, which saves half of a move's item buffers and
/// back hemicubes. They are a copy, since progressive refinement between
/// moves draws over the item texture and every job over the back one.
/// The back hemicubes hold element ids, not light, so a kept one shows the
/// light of the job that reads it (`shade_back`).
struct Kept {
    /// Rows as the drawn texture's: slot `k` in rows `k res .. (k + 1) res`.
    view: wgpu::TextureView,
    /// What the rows were drawn from: the job's new-pose shooters (slot
    /// order, compared bit for bit) and every object's matrix at that pose
    /// (zero: absent, or left out of a back hemicube). Empty: nothing kept.
    shooters: Vec<GpuShooter>,
    poses: Vec<[[f32; 4]; 4]>,
}

impl Kept {
    /// Whether the kept rows were drawn from `shooters` with the objects
    /// at `poses`.
    fn holds(&self, shooters: &[GpuShooter], poses: &[[[f32; 4]; 4]]) -> bool {
        !self.shooters.is_empty()
            && bytemuck::cast_slice::<_, u8>(&self.shooters)
                == bytemuck::cast_slice::<_, u8>(shooters)
            && bytemuck::cast_slice::<_, u8>(&self.poses) == bytemuck::cast_slice::<_, u8>(poses)
    }

    /// Rows of `slots` slots of `res` pixels, five faces wide, of `format`.
    fn rows(
        device: &wgpu::Device,
        label: &str,
        (slots, res): (u32, u32),
        format: wgpu::TextureFormat,
    ) -> Self {
        Self {
            view: texture(
                device,
                label,
                (FACES * res, res * slots),
                format,
                1,
                wgpu::TextureUsages::COPY_SRC | wgpu::TextureUsages::COPY_DST,
            ),
            shooters: Vec::new(),
            poses: Vec::new(),
        }
    }
}

/// Copies `slots` hemicube rows of `res` pixels from row `from` of `src` to
/// row `to` of `dst` (hemicube textures of one format, five faces wide).
fn copy_slots(
    encoder: &mut wgpu::CommandEncoder,
    (src, from): (&wgpu::TextureView, u32),
    (dst, to): (&wgpu::TextureView, u32),
    slots: u32,
    res: u32,
) {
    fn at(view: &wgpu::TextureView, row: u32) -> wgpu::TexelCopyTextureInfo<'_> {
        wgpu::TexelCopyTextureInfo {
            texture: view.texture(),
            mip_level: 0,
            origin: wgpu::Origin3d { x: 0, y: row, z: 0 },
            aspect: wgpu::TextureAspect::All,
        }
    }
    encoder.copy_texture_to_texture(
        at(src, from * res),
        at(dst, to * res),
        wgpu::Extent3d {
            width: FACES * res,
            height: slots * res,
            depth_or_array_layers: 1,
        },
    );
}

/// A cross job's hemicube rows in `view` (`total` slots of `res` pixels,
/// the old pose's from `old_from` on): with `reused`, the old pose's rows
/// copied from `kept` and only the new pose's drawn, else all drawn
/// (`draw` draws slots `0..n`); with `keep`, the new pose's rows then
/// copied to `kept` for the next move.
fn encode_kept_rows(
    encoder: &mut wgpu::CommandEncoder,
    keep: bool,
    (kept, reused): (&Kept, bool),
    (view, old_from, total, res): (&wgpu::TextureView, u32, u32, u32),
    draw: impl FnOnce(&mut wgpu::CommandEncoder, u32),
) {
    if reused {
        copy_slots(
            encoder,
            (&kept.view, 0),
            (view, old_from),
            total - old_from,
            res,
        );
        draw(encoder, old_from);
    } else {
        draw(encoder, total);
    }
    if keep {
        copy_slots(encoder, (view, 0), (&kept.view, 0), old_from, res);
    }
}

impl ProgressiveSolver {
    /// Top-face resolution of a moving tile's gathering hemicubes
    /// (`GATHER_RESOLUTION` in redistribute.wgsl).
    fn gather_resolution(&self) -> u32 {
        self.options.hemicube_resolution.clamp(1, GATHER_RESOLUTION)
    }

    fn dynamic_passes(&mut self) -> &DynamicPasses {
        if self.dynamic.is_none() {
            self.dynamic = Some(self.build_dynamic_passes());
        }
        // Just built when it was missing.
        self.dynamic.as_ref().expect("dynamic passes exist")
    }

    fn build_dynamic_passes(&self) -> DynamicPasses {
        let device = &self.device;
        // Sized as the item buffers, whose depth target the gathering
        // hemicubes share (attachments of one pass match in size); they
        // draw into its corner at their own resolution.
        let res = self.options.hemicube_resolution.max(1);
        let back_res = self.options.back_resolution.max(1);
        let cap = self.batch_capacity;
        let attach = wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING;
        let rgba = wgpu::TextureFormat::Rgba16Float;
        let front_view = texture(
            device,
            "moving tiles' gathering hemicubes (element ids)",
            (FACES * res, res * cap),
            wgpu::TextureFormat::R32Uint,
            1,
            attach,
        );
        let back_size = (FACES * back_res, back_res * cap);
        let back_ids_view = texture(
            device,
            "back hemicubes (element ids and distances)",
            back_size,
            wgpu::TextureFormat::Rg32Uint,
            1,
            attach | wgpu::TextureUsages::COPY_SRC | wgpu::TextureUsages::COPY_DST,
        );
        let back_view = texture(
            device,
            "back hemicubes (shot radiosity and distance)",
            back_size,
            rgba,
            1,
            wgpu::TextureUsages::STORAGE_BINDING | wgpu::TextureUsages::TEXTURE_BINDING,
        );
        let back_depth_view = texture(
            device,
            "back hemicube depth",
            back_size,
            wgpu::TextureFormat::Depth32Float,
            1,
            wgpu::TextureUsages::RENDER_ATTACHMENT,
        );
        let back_shooters = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("back shooters"),
            size: super::shooters::uniform_bytes(),
            usage: wgpu::BufferUsages::UNIFORM
                | wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        // What the static set shows the hemicubes, a texel per element
        // (`shade_static` in redistribute.wgsl).
        let shown_size = (SHOWN_WIDTH, self.element_count.div_ceil(SHOWN_WIDTH).max(1));
        let shown_usage =
            wgpu::TextureUsages::STORAGE_BINDING | wgpu::TextureUsages::TEXTURE_BINDING;
        let shown_back = texture(
            device,
            "shown to back hemicubes",
            shown_size,
            wgpu::TextureFormat::Rgba32Float,
            1,
            shown_usage,
        );
        let shown_front = texture(
            device,
            "shown to front hemicubes",
            shown_size,
            wgpu::TextureFormat::Rgba32Float,
            1,
            shown_usage,
        );
        let back_batch = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("back batch"),
            size: std::mem::size_of::<BatchUniform>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let marks = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("cross slots marked per element"),
            size: u64::from(self.element_count.max(1)) * MARK_WORDS * 4,
            usage: wgpu::BufferUsages::STORAGE,
            mapped_at_creation: false,
        });
        let old_shot = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("old shot radiosity"),
            size: u64::from(self.element_count.max(1)) * 16,
            usage: wgpu::BufferUsages::STORAGE,
            mapped_at_creation: false,
        });
        let gathered = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("gathered irradiance of moving tiles"),
            size: u64::from(self.element_count.max(1)) * 16,
            usage: wgpu::BufferUsages::STORAGE,
            mapped_at_creation: false,
        });
        let regathered = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("irradiance moving tiles gathered again after a move"),
            size: u64::from(self.element_count.max(1)) * 16,
            usage: wgpu::BufferUsages::STORAGE,
            mapped_at_creation: false,
        });
        let moving_direct = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("direct light of moving elements"),
            size: u64::from(self.element_count.max(1)) * 16,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let smoothed = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("interpolation of moving tiles beyond their constant"),
            size: u64::from(self.element_count.max(1)) * 16,
            // Read and written by `add_shown` (gathered corrections).
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let held = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("shot radiosity held by covered static elements"),
            size: u64::from(self.element_count.max(1)) * 16,
            // Read and written by the regathering on the CPU.
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("back hemicube"),
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            ..Default::default()
        });
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("redistribute.wgsl"),
            source: wgpu::ShaderSource::Wgsl(shaders::redistribute().into()),
        });
        let hemicube_module = self.draws.module(device, "hemicube.wgsl (radiosity)");
        let grid = [
            ("CROSS_GRID", f64::from(self.options.cross_grid.max(1))),
            (
                "CROSS_COARSE_BELOW",
                f64::from(self.options.cross_coarse_below.max(0.0)),
            ),
        ];
        let tile = [("CROSS_TILE", f64::from(self.options.cross_tile.max(1)))];
        let gather_res = [("GATHER_RESOLUTION", f64::from(self.gather_resolution()))];
        let resources = self
            .buffers
            .resources()
            .buffer(slot::OLD_SHOT, &old_shot)
            .buffer(slot::MARKS, &marks)
            .buffer(slot::GATHERED, &gathered)
            .buffer(slot::REGATHERED, &regathered)
            .buffer(slot::MOVING_DIRECT, &moving_direct)
            .buffer(slot::SMOOTHED, &smoothed)
            .buffer(slot::HELD, &held)
            .view(slot::FRONT_IDS, &front_view)
            .view(slot::SHOWN_FRONT, &shown_front)
            .view(slot::BACK_RAD, &back_view)
            .view(slot::BACK_RAD_OUT, &back_view)
            .view(slot::BACK_IDS, &back_ids_view)
            .view(slot::SHOWN_BACK, &shown_back)
            .sampler(slot::BACK_SAMPLER, &sampler)
            .buffer(slot::BACK_SHOOTERS, &back_shooters)
            .buffer(slot::BACK, &back_batch)
            .view(slot::SHOWN_BACK_OUT, &shown_back)
            .view(slot::SHOWN_FRONT_OUT, &shown_front);
        let cuts = super::pipelines::cut_constants(self.triangles);
        let compute = |pass: crate::gpu::binding::Pass, constants: &[(&str, f64)]| {
            let constants: Vec<(&str, f64)> = constants.iter().chain(&cuts).copied().collect();
            pass.compute(device, &module, &constants, |s| resources.get(s))
        };
        let reset = compute(RESET_MOVING, &[]);
        let energy = compute(SHOOTER_ENERGY_DYN, &[]);
        let gather = compute(GATHER_MOVING, &gather_res);
        let regather = compute(REGATHER_MOVING, &gather_res);
        let smooth = compute(SMOOTH_MOVING, &tile);
        let reconstruct = compute(RECONSTRUCT_DYN, &grid);
        let shade_static = compute(SHADE_STATIC, &[]);
        let shade_total = compute(SHADE_TOTAL, &[]);
        let shade_back = compute(SHADE_BACK, &[]);
        // The tiles' gathering hemicubes at the batch's shooters and the
        // back ones at their own shooters: the element seen per pixel (and
        // for the back ones its distance).
        let ids = &hemicube::ELEMENT_IDS;
        let ids_layout = ids.layout(device);
        let front_pipeline =
            hemicube::Pipelines::new(device, (&hemicube_module, self.draws), ids, &ids_layout);
        let front_group = ids.bind(device, &ids_layout, |s| resources.get(s));
        // The back hemicubes see the scene without the moving objects
        // (thesis Alg. 4.5): their matrices are zero there (`back_poses`),
        // so their triangles collapse before the rasterizer.
        let back_poses = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("poses without the moving objects"),
            size: self.buffers.poses.size(),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let back_resources = self
            .buffers
            .resources()
            .buffer(hemicube::slot::POSES, &back_poses)
            .buffer(hemicube::slot::SHOOTERS, &back_shooters)
            .buffer(hemicube::slot::BATCH, &back_batch);
        let back = &hemicube::BACK_ELEMENTS;
        let back_layout = back.layout(device);
        let back_pipeline =
            hemicube::Pipelines::new(device, (&hemicube_module, self.draws), back, &back_layout);
        let back_group = back.bind(device, &back_layout, |s| back_resources.get(s));
        DynamicPasses {
            reset,
            energy,
            gather,
            regather,
            smooth,
            reconstruct,
            shade_static,
            shade_total,
            rad_front: (front_pipeline, front_group),
            rad_back: (back_pipeline, back_group),
            back_shooters,
            back_batch,
            back_poses,
            moving_direct,
            smoothed,
            held,
            front_view,
            back_ids_view,
            back_depth_view,
            shade_back,
            kept: Kept::rows(
                device,
                "kept item buffers",
                (cap.div_ceil(2), res),
                wgpu::TextureFormat::R32Uint,
            ),
            kept_back: Kept::rows(
                device,
                "kept back hemicubes",
                (cap.div_ceil(2), back_res),
                wgpu::TextureFormat::Rg32Uint,
            ),
            front_ids_of: Vec::new(),
        }
    }

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
            batches: 0,
        };
        if mv.is_empty_move() {
            return Ok(mv);
        }
        // Contacts move with the objects (crate::validity).
        self.update_validity(&mv.old_poses, &mv.moving);
        // Incremental: total power per patch before the move (one
        // readback), to size the shooter grids. Cross tiles do not depend
        // on power.
        let mut patch_power = vec![0.0f64; self.patches.len()];
        if method == Redistribution::Incremental {
            let radiosity = self.total_radiosity()?;
            for (e, b) in radiosity.iter().enumerate() {
                let p = self.element_patch(e);
                patch_power[p] += f64::from(self.areas[e]) * f64::from(b.abs().element_sum());
            }
        }

        self.patches = self.table.place(&self.poses);
        self.areas = world_areas(&self.local_areas, &self.element_objects, &self.poses);
        self.write_poses(poses, &mv.old_poses, &mv.old_absent);
        self.write_flags(&mv.moving);
        let reset_mode = match method {
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
        // Cross: written by the first job once its hemicubes are queued.
        mv.direct_due = method != Redistribution::Incremental;
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

        // Incremental patches are cut into as many shooters as a
        // progressive batch gives them (a static patch's hemicubes, two per
        // shooter, then take more than one batch when they do not fit);
        // cross batches hold two or four hemicubes per tile
        // (`cross_slots`).
        let full = self.batch_capacity;
        let in_m = |p: usize| mv.moving[self.table.objects[p] as usize];
        match method {
            Redistribution::Incremental => {
                for (p, power) in patch_power.iter().enumerate() {
                    if in_m(p) && !mv.old_absent[self.table.objects[p] as usize] {
                        mv.jobs.push_back(Job::Negative {
                            patch: p as u32,
                            shooters: self.grid_count(p, *power, full),
                        });
                    }
                }
                let mut statics: Vec<usize> = (0..self.patches.len())
                    .filter(|&p| !in_m(p) && patch_power[p] > 0.0)
                    .collect();
                statics.sort_by(|a, b| patch_power[*b].total_cmp(&patch_power[*a]));
                for p in statics {
                    mv.jobs.push_back(Job::Static {
                        patch: p as u32,
                        shooters: self.grid_count(p, patch_power[p], full),
                        from: 0,
                    });
                }
            }
            Redistribution::Cross | Redistribution::Full => {
                let side = self.options.cross_tile.max(1);
                let tiling = self.tiling();
                let old_patches = self.table.place(&mv.old_poses);
                for p in 0..self.patches.len() {
                    if !in_m(p) {
                        continue;
                    }
                    let object = self.table.objects[p] as usize;
                    // A closed object's face with no receiver in front of
                    // it wherever it is (a box's bottom on the floor)
                    // gathers, shoots and shadows nothing: no tiles.
                    if self.cross_slots(object) == 2
                        && (mv.old_absent[object]
                            || self.faces_nothing(p, &old_patches, &mv.old_absent))
                        && (self.absent[object]
                            || self.faces_nothing(p, &self.patches, &self.absent))
                    {
                        continue;
                    }
                    let wp = self.patches[p];
                    // At least 2 x 2 tiles where the chart allows: one tile
                    // per face is too coarse a shadow caster and receiver.
                    let tiles = |n: u32| n.div_ceil(side).max(n.min(2));
                    let (gx, gy) = (tiles(wp.w), tiles(wp.h));
                    for j in 0..gy {
                        for i in 0..gx {
                            let texels = [
                                i * wp.w / gx,
                                j * wp.h / gy,
                                (i + 1) * wp.w / gx,
                                (j + 1) * wp.h / gy,
                            ];
                            // A tile wholly above a triangle's diagonal
                            // stands for no surface: it neither gathers
                            // nor shoots (`smooth_moving` reads only the
                            // tiles that gathered).
                            if tiling.covers_surface(&wp, &texels) {
                                mv.tiles.push(CrossTile {
                                    patch: p as u32,
                                    texels,
                                });
                            }
                        }
                    }
                }
                // A job's tiles belong to one object: presence (whether the
                // old and the new position exist) is a per-batch flag.
                let object = |t: &CrossTile| self.table.objects[t.patch as usize];
                mv.tiles.sort_by_key(|t| object(t));
                let mut first = 0;
                while (first as usize) < mv.tiles.len() {
                    let o = object(&mv.tiles[first as usize]);
                    let per_job = (self.batch_capacity / self.cross_slots(o as usize)).max(1);
                    let count = mv.tiles[first as usize..]
                        .iter()
                        .take(per_job as usize)
                        .take_while(|t| object(t) == o)
                        .count() as u32;
                    mv.jobs.push_back(Job::Cross { first, count });
                    first += count;
                }
            }
        }
        self.profile.stop(setup, Stage::MoveSetup);
        Ok(mv)
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
            if std::mem::take(&mut mv.direct_due) {
                // A move without jobs (nothing of M faces anything).
                self.write_moving_direct(&mv.moving);
            }
            let mut encoder = self.device.create_command_encoder(&Default::default());
            if mv.method == Redistribution::Cross && !mv.is_empty_move() {
                // While M is still marked: the tiles' gathered light, read
                // between tile centres, becomes the texels' radiosity. (An
                // empty move, e.g. the removal of no moving objects in a
                // static scene, gathered nothing and may come before any
                // pass was built.)
                self.profile.open(&mut encoder);
                self.encode_smoothing(&mut encoder);
                self.queue.submit([encoder.finish()]);
                encoder = self.device.create_command_encoder(&Default::default());
                // What the static texels near the move now reflect is
                // unshot (before the next shooter is chosen); then the
                // tiles gather again from the static set as it now is,
                // those texels included, and their texels show that.
                let contacts = self.regather(&mv.moving, true)?;
                self.regather_tiles(mv, &mut encoder);
                if let Some(contacts) = contacts {
                    // The texels at a contact gather on the CPU while the
                    // tiles gather again on the GPU; only the smoothing
                    // reads what they gather.
                    self.submit_queued(&mut encoder);
                    self.gather_contacts(&contacts);
                    self.profile.open(&mut encoder);
                }
                self.encode_smoothing(&mut encoder);
                self.queue.submit([encoder.finish()]);
                encoder = self.device.create_command_encoder(&Default::default());
            } else if mv.method == Redistribution::Cross {
                // Without contacts to gather.
                self.regather(&mv.moving, false)?;
            } else {
                // Incremental reshooting reaches them (tests/dynamic.rs).
                self.regather.clear();
            }
            self.write_flags(&[]);
            self.profile.open(&mut encoder);
            self.encode_selection(&mut encoder);
            self.profile.mark(&mut encoder, Stage::Selection);
            self.queue.submit([encoder.finish()]);
            self.profile.sync();
            let readback = self.profile.start();
            self.refresh_selection()?;
            self.profile.stop(readback, Stage::SelectionReadback);
            return Ok(false);
        }
        Ok(true)
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

    /// Runs every batch of `mv`.
    pub fn finish_move(&mut self, mv: &mut Move) -> Result<(), GpuError> {
        while self.move_step(mv)? {}
        Ok(())
    }

    /// Number of shooters for a patch holding `power`, at most `capacity`.
    fn grid_count(&self, patch: usize, power: f64, capacity: u32) -> u32 {
        let (gx, gy) = self.tiling().grid(&self.patches[patch], power, capacity);
        gx * gy
    }

    fn element_patch(&self, element: usize) -> usize {
        // Patches own contiguous element ranges in order.
        self.patches
            .partition_point(|p| p.first as usize <= element)
            .saturating_sub(1)
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
                let wp = old_patches[patch as usize];
                let grid = self.shooter_grid_for_count(&wp, shooters);
                let list = self.tiling().shooters(
                    patch,
                    &wp,
                    &old_areas,
                    grid,
                    self.job_split_limit(grid),
                );
                let n = list.len() as u32;
                self.upload(&list, self.batch_uniform(patch, n, 0, KIND_NEGATIVE));
                let d = self.dynamic.as_ref().expect("built in begin_move");
                self.profile.stop(setup, Stage::JobSetup);
                self.profile.open(&mut encoder);
                encode_compute(&mut encoder, &d.energy, n);
                self.profile.mark(&mut encoder, Stage::ShooterEnergy);
                self.encode_item_buffers(&mut encoder, n);
                self.profile.mark(&mut encoder, Stage::ItemBuffers);
                encode_compute(
                    &mut encoder,
                    &d.reconstruct,
                    self.element_count.div_ceil(WORKGROUP),
                );
                self.profile.mark(&mut encoder, Stage::Reconstruct);
            }
            Job::Static {
                patch,
                shooters,
                from,
            } => {
                let wp = self.patches[patch as usize];
                let grid = self.shooter_grid_for_count(&wp, shooters);
                let all = self.tiling().shooters(
                    patch,
                    &wp,
                    &self.areas,
                    grid,
                    self.job_split_limit(grid),
                );
                let half = (self.batch_capacity / 2) as usize;
                let from = (from as usize).min(all.len());
                let to = (from + half).min(all.len());
                if to < all.len() {
                    rest = Some(Job::Static {
                        patch,
                        shooters,
                        from: to as u32,
                    });
                }
                let mut list = all[from..to].to_vec();
                let n = list.len() as u32;
                list.extend_from_within(..);
                self.upload(&list, self.batch_uniform(patch, n, n, KIND_STATIC));
                let d = self.dynamic.as_ref().expect("built in begin_move");
                self.profile.stop(setup, Stage::JobSetup);
                self.profile.open(&mut encoder);
                encode_compute(&mut encoder, &d.energy, n);
                self.profile.mark(&mut encoder, Stage::ShooterEnergy);
                self.encode_item_buffers(&mut encoder, 2 * n);
                self.profile.mark(&mut encoder, Stage::ItemBuffers);
                encode_compute(
                    &mut encoder,
                    &d.reconstruct,
                    self.element_count.div_ceil(WORKGROUP),
                );
                self.profile.mark(&mut encoder, Stage::Reconstruct);
            }
            Job::Cross { first, count } => {
                let tiles = &mv.tiles[first as usize..(first + count) as usize];
                // All tiles of a job are on one object (see begin_move).
                let object = self.table.objects[tiles[0].patch as usize] as usize;
                let patch = tiles[0].patch;
                let has_new = !self.absent[object];
                let has_old = !mv.old_absent[object];
                // Slots: [new front, new back, old front, old back], n each.
                // The back hemicubes make the moving patches two-sided
                // occluders for the cross projection: a static element
                // behind a moving patch loses the light the patch blocks
                // from its front side. A closed object needs none: a point
                // outside it sees only its front faces, and one of those
                // blocks whatever it blocks; a point inside (the floor
                // under a box resting on it) is invalid, and its light
                // goes to zero when the move completes (regather.rs).
                // Its slots are [new front, old front] (ONE_SIDED).
                let slots = self.cross_slots(object);
                let one_sided = slots == 2;
                let mut list = Vec::with_capacity((slots * count) as usize);
                let tiling = self.tiling();
                for (placed, areas) in [(&self.patches, &self.areas), (&old_patches, &old_areas)] {
                    let front = front_shooters(&tiling, tiles, placed, areas);
                    let back: Vec<GpuShooter> = if one_sided {
                        Vec::new()
                    } else {
                        front.iter().map(|s| self.flipped(s)).collect()
                    };
                    list.extend(front);
                    list.extend(back);
                }
                let total = list.len() as u32;
                let old_from = total / 2;
                // The see-through radiosity hemicubes look the other way:
                // what a patch hides from a receiver lies on its far side.
                let through: Vec<GpuShooter> = list.iter().map(|s| self.flipped(s)).collect();
                let mut mode = KIND_CROSS;
                if one_sided {
                    mode |= ONE_SIDED;
                }
                if has_new {
                    mode |= HAS_NEW;
                }
                if has_old {
                    mode |= HAS_OLD;
                }
                // The old pose's item buffers and back hemicubes are the last
                // move's new ones when nothing else changed (`Kept`), and so
                // is which of their slots reach each element.
                let new_poses = pose_matrices(&self.poses, &self.absent);
                let old_poses = pose_matrices(&mv.old_poses, &mv.old_absent);
                let keep = self.options.keep_old_pose_hemicubes;
                let d = self.dynamic.as_ref().expect("built in begin_move");
                let items_kept = keep && d.kept.holds(&list[old_from as usize..], &old_poses);
                if items_kept {
                    mode |= KEPT_MARKS;
                }
                self.upload(&list, self.batch_uniform(patch, count, old_from, mode));
                let mut back_uniform = self.batch_uniform(patch, count, old_from, HEMICUBES_ONLY);
                back_uniform.resolution = self.options.back_resolution.max(1);
                self.queue
                    .write_buffer(&d.back_shooters, 0, bytemuck::cast_slice(&through));
                self.queue
                    .write_buffer(&d.back_batch, 0, bytemuck::bytes_of(&back_uniform));
                let objects = self.poses.len().max(1);
                let without_moving = |poses: &[Pose], absent: &[bool]| {
                    let absent: Vec<bool> = (0..objects)
                        .map(|o| {
                            absent.get(o).copied().unwrap_or(false)
                                || mv.moving.get(o).copied().unwrap_or(false)
                        })
                        .collect();
                    let mut m = pose_matrices(poses, &absent);
                    m.resize(objects, [[0.0; 4]; 4]);
                    m
                };
                let mut back_poses = without_moving(&self.poses, &self.absent);
                back_poses.extend(without_moving(&mv.old_poses, &mv.old_absent));
                self.queue
                    .write_buffer(&d.back_poses, 0, bytemuck::cast_slice(&back_poses));
                self.profile.stop(setup, Stage::JobSetup);
                self.profile.open(&mut encoder);
                let res = self.options.hemicube_resolution.max(1);
                encode_kept_rows(
                    &mut encoder,
                    keep,
                    (&d.kept, items_kept),
                    (&self.buffers.item_view, old_from, total, res),
                    |encoder, slots| self.encode_item_buffers(encoder, slots),
                );
                self.profile.mark(&mut encoder, Stage::ItemBuffers);
                // Counted with the front hemicubes (or the back ones).
                encode_compute(
                    &mut encoder,
                    &d.shade_static,
                    self.element_count.div_ceil(WORKGROUP),
                );
                if has_new {
                    self.encode_gathering_hemicubes(&mut encoder, d, count);
                    self.profile.mark(&mut encoder, Stage::FrontHemicubes);
                }
                let back_res = back_uniform.resolution;
                let (new_back, old_back) = back_poses.split_at(objects);
                let back_kept = keep && d.kept_back.holds(&through[old_from as usize..], old_back);
                encode_kept_rows(
                    &mut encoder,
                    keep,
                    (&d.kept_back, back_kept),
                    (&d.back_ids_view, old_from, total, back_res),
                    |encoder, slots| {
                        hemicube::encode(
                            encoder,
                            (&d.rad_back.0, &d.rad_back.1),
                            &hemicube::Target {
                                view: &d.back_ids_view,
                                depth: &d.back_depth_view,
                                resolution: back_res,
                            },
                            slots,
                            self.triangle_vertices,
                            self.draws,
                        )
                    },
                );
                self.profile.mark(&mut encoder, Stage::BackHemicubes);
                if direct_due {
                    // The tiles' gather reads M's direct light: computed
                    // on the CPU while the GPU draws the hemicubes queued
                    // so far (which do not read it).
                    self.submit_queued(&mut encoder);
                    let direct = self.profile.start();
                    self.write_moving_direct(&mv.moving);
                    self.profile.stop(direct, Stage::DirectLight);
                    self.profile.open(&mut encoder);
                }
                let d = self.dynamic.as_ref().expect("built in begin_move");
                encode_compute(&mut encoder, &d.gather, count);
                self.profile.mark(&mut encoder, Stage::TileGather);
                // Every slot shaded with the light of now, kept or drawn
                // (counted with the projection: on lavapipe a timestamp
                // right after a pass that writes a storage texture is
                // taken only once the next pass has run).
                encode_compute_grid(
                    &mut encoder,
                    &d.shade_back,
                    (
                        (FACES * back_res).div_ceil(8),
                        (total * back_res).div_ceil(8),
                    ),
                );
                encode_compute(
                    &mut encoder,
                    &d.reconstruct,
                    self.element_count.div_ceil(WORKGROUP),
                );
                self.profile.mark(&mut encoder, Stage::CrossProjection);
                self.kept_item_jobs += u64::from(items_kept);
                self.kept_back_jobs += u64::from(back_kept);
                let new_back = new_back.to_vec();
                let d = self.dynamic.as_mut().expect("built in begin_move");
                if keep {
                    d.kept.shooters = list[..old_from as usize].to_vec();
                    d.kept.poses = new_poses;
                    d.kept_back.shooters = through[..old_from as usize].to_vec();
                    d.kept_back.poses = new_back;
                }
                d.front_ids_of.clear();
                if has_new {
                    d.front_ids_of.extend_from_slice(tiles);
                }
            }
        }
        self.queue.submit([encoder.finish()]);
        Ok(rest)
    }

    /// Whether no element receives in front of patch `p`'s plane with the
    /// patches placed as `placed` and the objects flagged in `absent` left
    /// out: `reconstruct_dyn`'s test of a receiver against a front slot
    /// (`dot(x - corner, n) > 0`, `x` the receiving point, nudged off its
    /// surface and towards its patch's centre as `place_elements` does)
    /// then fails for every receiver, the patch's front hemicubes see
    /// nothing, and its texels gather no light, direct or reflected. A
    /// box resting on the floor: the floor's receiving points lie a hair
    /// above its bottom's plane, the walls' above it. Patches wholly
    /// behind the plane are passed over by their corners; those within a
    /// hair of it by their elements.
    fn faces_nothing(&self, p: usize, placed: &[WorldPatch], absent: &[bool]) -> bool {
        let (o, n) = (placed[p].origin, placed[p].normal);
        let hair = 2.0 * self.surface_offset;
        placed.iter().enumerate().all(|(q, wp)| {
            if q == p || absent[self.table.objects[q] as usize] {
                return true;
            }
            let reach = wp
                .corners()
                .iter()
                .map(|c| (*c - o).dot(n))
                .fold(f32::NEG_INFINITY, f32::max);
            if reach > hair {
                return false;
            }
            reach < -hair
                || (wp.first..wp.first + wp.w * wp.h).all(|i| {
                    let e = &self.atlas.elements[i as usize];
                    !e.covers_surface()
                        || (wp.receiving_point(e.st, self.surface_offset) - o).dot(n) <= 0.0
                })
        })
    }

    /// Hemicube slots per tile of object `o` in a cross batch: front and
    /// back at the new and the old position, or the fronts only for a
    /// closed object (see `run_job`).
    fn cross_slots(&self, o: usize) -> u32 {
        if self.closed.get(o).copied().unwrap_or(false) {
            2
        } else {
            4
        }
    }

    /// Whether object `o` is flagged in `moving` and present now.
    fn is_present_moving(&self, moving: &[bool], o: usize) -> bool {
        moving.get(o).copied().unwrap_or(false) && !self.absent[o]
    }

    /// The elements that take part in a move's light of their own: valid,
    /// surface-covering elements of the objects flagged in `moving` that
    /// are present now (their direct light, `write_moving_direct`; their
    /// contacts, regather.rs).
    pub(super) fn present_moving_elements(&self, moving: &[bool]) -> Vec<usize> {
        (0..self.element_count as usize)
            .filter(|&i| {
                self.is_present_moving(moving, self.element_objects[i] as usize)
                    && !self.validity.is_invalid(i)
                    && self.atlas.elements[i].covers_surface()
            })
            .collect()
    }

    /// The direct light of every valid element of the objects flagged in
    /// `moving` that are present at the current poses, per element on the
    /// CPU ([`element_direct_light`]), into `moving_direct` (zero for the
    /// rest of their patches). Cross redistribution's tiles gather only
    /// reflected light and add this per texel: a tile's hemicube gave all
    /// its texels the direct light of its centre, and a face under a lamp
    /// read flat where the light falls off towards its edges (the top of
    /// cornell-large's box 4.65-4.9 everywhere against 4.1-5.0).
    fn write_moving_direct(&self, moving: &[bool]) {
        let elements = self.present_moving_elements(moving);
        if elements.is_empty() {
            return;
        }
        let light = element_direct_light(
            &self.scene,
            &self.atlas,
            (&self.poses, &self.absent),
            &elements,
            DIRECT_GRID,
        );
        let mut values = vec![[0.0f32; 4]; self.element_count as usize];
        for (&i, h) in elements.iter().zip(light) {
            values[i] = [h.x, h.y, h.z, 0.0];
        }
        let d = self.dynamic.as_ref().expect("built in begin_move");
        for (patch, p) in self.patches.iter().enumerate() {
            if !self.is_present_moving(moving, self.table.objects[patch] as usize) {
                continue;
            }
            let range = p.first as usize..(p.first + p.w * p.h) as usize;
            self.queue.write_buffer(
                &d.moving_direct,
                p.first as u64 * 16,
                bytemuck::cast_slice(&values[range]),
            );
        }
    }

    /// Encodes `smooth_moving` (profiled as smoothing).
    fn encode_smoothing(&self, encoder: &mut wgpu::CommandEncoder) {
        let d = self.dynamic.as_ref().expect("built in begin_move");
        encode_compute(encoder, &d.smooth, self.element_count.div_ceil(WORKGROUP));
        self.profile.mark(encoder, Stage::Smoothing);
    }

    /// Encodes the regathering of a cross move's tiles at their new
    /// positions (`regather_moving` in redistribute.wgsl): front hemicubes
    /// of the static set's total radiosity, as many tiles per pass as the
    /// batch holds. Tiles of objects that are absent now (a removal) have
    /// nothing to gather. Profiled as front hemicubes and tile gather.
    fn regather_tiles(&mut self, mv: &Move, encoder: &mut wgpu::CommandEncoder) {
        let tiles: Vec<CrossTile> = mv
            .tiles
            .iter()
            .filter(|t| !self.absent[self.table.objects[t.patch as usize] as usize])
            .copied()
            .collect();
        let tiling = self.tiling();
        let capacity = self.batch_capacity.max(1) as usize;
        let d = self.dynamic.as_ref().expect("built in begin_move");
        self.profile.open(encoder);
        // Whether a chunk has drawn over the job's hemicubes.
        let mut drawn = false;
        for (c, chunk) in tiles.chunks(capacity).enumerate() {
            let list = front_shooters(&tiling, chunk, &self.patches, &self.areas);
            let n = list.len() as u32;
            let uniform = self.batch_uniform(chunk[0].patch, n, u32::MAX, HEMICUBES_ONLY);
            // Each chunk's shooters and uniform must be in place when its
            // passes run: submit what came before first.
            self.submit_queued(encoder);
            self.upload(&list, uniform);
            if c == 0 {
                // The radiosity does not change between the chunks.
                encode_compute(
                    encoder,
                    &d.shade_total,
                    self.element_count.div_ceil(WORKGROUP),
                );
            }
            // The move's job drew these tiles' hemicubes already (what
            // they see is read per pixel, from the shown texture
            // `shade_total` just wrote).
            if drawn || d.front_ids_of != chunk {
                drawn = true;
                self.encode_gathering_hemicubes(encoder, d, n);
                self.profile.mark(encoder, Stage::FrontHemicubes);
            }
            encode_compute(encoder, &d.regather, n);
            self.profile.mark(encoder, Stage::TileGather);
        }
    }

    /// The moving tiles' gathering hemicubes (element ids, `ELEMENT_IDS`)
    /// for the first `slots` shooters uploaded.
    fn encode_gathering_hemicubes(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        d: &DynamicPasses,
        slots: u32,
    ) {
        hemicube::encode(
            encoder,
            (&d.rad_front.0, &d.rad_front.1),
            &hemicube::Target {
                view: &d.front_view,
                depth: &self.buffers.depth_view,
                resolution: self.gather_resolution(),
            },
            slots,
            self.triangle_vertices,
            self.draws,
        );
    }

    /// Most tiles a redistribution job's grid may be split into at
    /// contacts: one and a half times the grid within the half of the
    /// batch a job gets, or the grid itself without `split_contacts`.
    fn job_split_limit(&self, grid: (u32, u32)) -> usize {
        if self.options.split_contacts {
            contact_limit(grid, self.batch_capacity)
        } else {
            (grid.0 * grid.1) as usize
        }
    }

    /// A grid of about `count` shooters over a patch.
    fn shooter_grid_for_count(&self, patch: &WorldPatch, count: u32) -> (u32, u32) {
        let aspect = (patch.u.length() / patch.v.length().max(1e-12)) as f64;
        let gx = ((f64::from(count.max(1)) * aspect).sqrt().round() as u32).clamp(1, patch.w);
        let gy = (count.max(1) / gx).clamp(1, patch.h);
        (gx, gy)
    }

    /// The hemicube on the other side of a shooter: the eye as far behind
    /// the surface as it was in front, looking along -n (thesis Alg. 4.4
    /// lines 10-11 place one on the back), behind the centroid of its
    /// region (of its part on the triangle, for a tile a triangle's
    /// diagonal cuts). Flipping twice gives the front. The region and its
    /// cut stay as they are.
    fn flipped(&self, s: &GpuShooter) -> GpuShooter {
        let n = Vec3::from_slice(&s.n[..3]);
        let eye = s.centre() - n * (self.near * 2.0);
        let t2 = Vec3::from_slice(&s.t2[..3]);
        GpuShooter {
            eye: v4(eye, s.eye[3]),
            t2: v4(-t2, s.t2[3]),
            n: v4(-n, s.n[3]),
            ..*s
        }
    }

    fn upload(&self, shooters: &[GpuShooter], uniform: BatchUniform) {
        self.queue
            .write_buffer(&self.buffers.shooters, 0, bytemuck::cast_slice(shooters));
        self.queue
            .write_buffer(&self.buffers.batch, 0, bytemuck::bytes_of(&uniform));
    }
}

/// One shooter per cross tile at the placement `placed` (areas `areas`);
/// `gather_moving` and `regather_moving` walk the tile's texels by the
/// first element and chart width every shooter carries (`Tiling::shooter`).
fn front_shooters(
    tiling: &super::shooters::Tiling<'_>,
    tiles: &[CrossTile],
    placed: &[WorldPatch],
    areas: &[f32],
) -> Vec<GpuShooter> {
    tiles
        .iter()
        .map(|t| tiling.shooter(t.patch, &placed[t.patch as usize], areas, t.texels))
        .collect()
}
