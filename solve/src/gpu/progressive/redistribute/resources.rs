//! The redistribution passes, their targets and buffers (built on the
//! first move), and the hemicube rows a cross job keeps for the next move.

use super::{CrossTile, GATHER_RESOLUTION, MARK_WORDS, SHOWN_WIDTH};
use crate::gpu::binding::{Pass, Resources};
use crate::gpu::buffers::texture;
use crate::gpu::hemicube::{self, FACES};
use crate::gpu::progressive::pipelines::{
    GATHER_MOVING, RECONSTRUCT_DYN, REGATHER_MOVING, RESET_MOVING, SHADE_BACK, SHADE_STATIC,
    SHADE_TOTAL, SHOOTER_ENERGY_DYN, SMOOTH_MOVING, cut_constants,
};
use crate::gpu::progressive::{BatchUniform, GpuShooter, ProgressiveSolver, shooters, slot};
use crate::gpu::shaders;

/// Pipelines and targets of the redistribution passes, built on the first
/// move so that static scenes never pay for them.
pub(in crate::gpu) struct DynamicPasses {
    pub(super) reset: (wgpu::ComputePipeline, wgpu::BindGroup),
    pub(super) energy: (wgpu::ComputePipeline, wgpu::BindGroup),
    pub(super) gather: (wgpu::ComputePipeline, wgpu::BindGroup),
    pub(super) regather: (wgpu::ComputePipeline, wgpu::BindGroup),
    pub(super) smooth: (wgpu::ComputePipeline, wgpu::BindGroup),
    pub(super) reconstruct: (wgpu::ComputePipeline, wgpu::BindGroup),
    /// Fill the shown textures the hemicubes of a cross batch and of the
    /// regathering read (`shade_static`, `shade_total`).
    pub(super) shade_static: (wgpu::ComputePipeline, wgpu::BindGroup),
    pub(super) shade_total: (wgpu::ComputePipeline, wgpu::BindGroup),
    /// The tiles' gathering hemicubes (`ELEMENT_IDS` into `front_view`).
    pub(super) rad_front: (hemicube::Pipelines, wgpu::BindGroup),
    pub(super) rad_back: (hemicube::Pipelines, wgpu::BindGroup),
    pub(super) back_shooters: wgpu::Buffer,
    pub(super) back_batch: wgpu::Buffer,
    /// The back hemicubes' `poses`: both pose sets as the item buffers'
    /// (`write_poses`), the moving objects' matrices zero, written per
    /// cross job.
    pub(super) back_poses: wgpu::Buffer,
    /// Direct light of M's elements at their new position (`moving_direct`
    /// in redistribute.wgsl), written per move.
    pub(in crate::gpu::progressive) moving_direct: wgpu::Buffer,
    /// What M's elements show beyond what their tiles shot (the smoothing
    /// between tile centres, gathered corrections: `add_shown`); kept out
    /// of the old shot radiosity the next move takes back.
    pub(in crate::gpu::progressive) smoothed: wgpu::Buffer,
    /// The shot radiosity static elements held when they were covered
    /// (`held` in redistribute.wgsl, `progressive/regather.rs`).
    pub(in crate::gpu::progressive) held: wgpu::Buffer,
    pub(super) front_view: wgpu::TextureView,
    /// The back hemicubes as drawn (`BACK_ELEMENTS`: element and distance
    /// per pixel); `shade_back` shades them for the projection into a
    /// texture only its bind groups hold (shot radiosity and distance,
    /// Rgba16Float).
    pub(super) back_ids_view: wgpu::TextureView,
    pub(super) back_depth_view: wgpu::TextureView,
    pub(super) shade_back: (wgpu::ComputePipeline, wgpu::BindGroup),
    /// The item buffers of the last cross job's new-pose slots.
    pub(super) kept: Kept,
    /// Its back hemicubes' new-pose slots (`back_ids_view` rows).
    pub(super) kept_back: Kept,
    /// The tiles whose gathering hemicubes `front_view` holds, slot by
    /// slot, drawn at this move's new pose by its cross job; empty when
    /// none of this move. The gather after the move reads them again
    /// unless they are not its tiles (a move of several jobs).
    pub(super) front_ids_of: Vec<CrossTile>,
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
pub(super) struct Kept {
    /// Rows as the drawn texture's: slot `k` in rows `k res .. (k + 1) res`.
    view: wgpu::TextureView,
    /// What the rows were drawn from: the job's new-pose shooters (slot
    /// order, compared bit for bit) and every object's matrix at that pose
    /// (zero: absent, or left out of a back hemicube). Empty: nothing kept.
    pub(super) shooters: Vec<GpuShooter>,
    pub(super) poses: Vec<[[f32; 4]; 4]>,
}

impl Kept {
    /// Whether the kept rows were drawn from `shooters` with the objects
    /// at `poses`.
    pub(super) fn holds(&self, shooters: &[GpuShooter], poses: &[[[f32; 4]; 4]]) -> bool {
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
pub(super) fn encode_kept_rows(
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

/// The textures of the redistribution passes.
struct DynamicTargets {
    /// The moving tiles' gathering hemicubes (element ids).
    front_view: wgpu::TextureView,
    /// The back hemicubes as drawn, as shaded, and their depth.
    back_ids_view: wgpu::TextureView,
    back_view: wgpu::TextureView,
    back_depth_view: wgpu::TextureView,
    /// What the static set shows the back and the front hemicubes.
    shown_back: wgpu::TextureView,
    shown_front: wgpu::TextureView,
}

impl DynamicTargets {
    /// Targets for `cap` hemicube slots, at top-face resolution `res` for
    /// the gathering hemicubes' and `back_res` for the back ones, and
    /// shown textures for `elements` elements.
    fn new(device: &wgpu::Device, (res, back_res, cap): (u32, u32, u32), elements: u32) -> Self {
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
        // What the static set shows the hemicubes, a texel per element
        // (`shade_static` in redistribute.wgsl).
        let shown_size = (SHOWN_WIDTH, elements.div_ceil(SHOWN_WIDTH).max(1));
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
        Self {
            front_view,
            back_ids_view,
            back_view,
            back_depth_view,
            shown_back,
            shown_front,
        }
    }
}

/// The buffers of the redistribution passes.
struct DynamicBuffers {
    back_shooters: wgpu::Buffer,
    back_batch: wgpu::Buffer,
    back_poses: wgpu::Buffer,
    marks: wgpu::Buffer,
    old_shot: wgpu::Buffer,
    gathered: wgpu::Buffer,
    regathered: wgpu::Buffer,
    moving_direct: wgpu::Buffer,
    smoothed: wgpu::Buffer,
    held: wgpu::Buffer,
}

impl DynamicBuffers {
    /// Buffers for `elements` elements; the back hemicubes' poses of
    /// `poses_size` bytes, as the item buffers'.
    fn new(device: &wgpu::Device, elements: u32, poses_size: u64) -> Self {
        let buffer = |label: &str, size: u64, usage: wgpu::BufferUsages| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage,
                mapped_at_creation: false,
            })
        };
        let storage = wgpu::BufferUsages::STORAGE;
        // A vec4 per element.
        let per_element = u64::from(elements.max(1)) * 16;
        Self {
            back_shooters: buffer(
                "back shooters",
                shooters::uniform_bytes(),
                wgpu::BufferUsages::UNIFORM | storage | wgpu::BufferUsages::COPY_DST,
            ),
            back_batch: buffer(
                "back batch",
                std::mem::size_of::<BatchUniform>() as u64,
                wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            ),
            // The back hemicubes see the scene without the moving objects
            // (thesis Alg. 4.5): their matrices are zero there
            // (`back_poses`), so their triangles collapse before the
            // rasterizer.
            back_poses: buffer(
                "poses without the moving objects",
                poses_size,
                storage | wgpu::BufferUsages::COPY_DST,
            ),
            marks: buffer(
                "cross slots marked per element",
                u64::from(elements.max(1)) * MARK_WORDS * 4,
                storage,
            ),
            old_shot: buffer("old shot radiosity", per_element, storage),
            gathered: buffer("gathered irradiance of moving tiles", per_element, storage),
            regathered: buffer(
                "irradiance moving tiles gathered again after a move",
                per_element,
                storage,
            ),
            moving_direct: buffer(
                "direct light of moving elements",
                per_element,
                storage | wgpu::BufferUsages::COPY_DST,
            ),
            smoothed: buffer(
                "interpolation of moving tiles beyond their constant",
                per_element,
                // Read and written by `add_shown` (gathered corrections).
                storage | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
            ),
            held: buffer(
                "shot radiosity held by covered static elements",
                per_element,
                // Read and written by the regathering on the CPU.
                storage | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
            ),
        }
    }
}

impl ProgressiveSolver {
    /// Top-face resolution of a moving tile's gathering hemicubes
    /// (`GATHER_RESOLUTION` in redistribute.wgsl).
    pub(super) fn gather_resolution(&self) -> u32 {
        self.options.hemicube_resolution.clamp(1, GATHER_RESOLUTION)
    }

    pub(super) fn dynamic_passes(&mut self) -> &DynamicPasses {
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
        let targets = DynamicTargets::new(device, (res, back_res, cap), self.element_count);
        let buffers = DynamicBuffers::new(device, self.element_count, self.buffers.poses.size());
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
        let resources = self.dynamic_resources(&targets, &buffers, &sampler);
        let compute = |pass: Pass, constants: &[(&str, f64)]| {
            self.redistribution_pass(&module, &resources, pass, constants)
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
        let rad_front = self.gathering_hemicube_passes(&hemicube_module, &resources);
        let rad_back = self.back_hemicube_passes(&hemicube_module, &buffers);
        DynamicPasses {
            reset,
            energy,
            gather,
            regather,
            smooth,
            reconstruct,
            shade_static,
            shade_total,
            rad_front,
            rad_back,
            back_shooters: buffers.back_shooters,
            back_batch: buffers.back_batch,
            back_poses: buffers.back_poses,
            moving_direct: buffers.moving_direct,
            smoothed: buffers.smoothed,
            held: buffers.held,
            front_view: targets.front_view,
            back_ids_view: targets.back_ids_view,
            back_depth_view: targets.back_depth_view,
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

    /// Every buffer and target the redistribution passes bind, by slot:
    /// the progressive solver's and their own.
    fn dynamic_resources<'a>(
        &'a self,
        targets: &'a DynamicTargets,
        buffers: &'a DynamicBuffers,
        sampler: &'a wgpu::Sampler,
    ) -> Resources<'a> {
        self.buffers
            .resources()
            .buffer(slot::OLD_SHOT, &buffers.old_shot)
            .buffer(slot::MARKS, &buffers.marks)
            .buffer(slot::GATHERED, &buffers.gathered)
            .buffer(slot::REGATHERED, &buffers.regathered)
            .buffer(slot::MOVING_DIRECT, &buffers.moving_direct)
            .buffer(slot::SMOOTHED, &buffers.smoothed)
            .buffer(slot::HELD, &buffers.held)
            .view(slot::FRONT_IDS, &targets.front_view)
            .view(slot::SHOWN_FRONT, &targets.shown_front)
            .view(slot::BACK_RAD, &targets.back_view)
            .view(slot::BACK_RAD_OUT, &targets.back_view)
            .view(slot::BACK_IDS, &targets.back_ids_view)
            .view(slot::SHOWN_BACK, &targets.shown_back)
            .sampler(slot::BACK_SAMPLER, sampler)
            .buffer(slot::BACK_SHOOTERS, &buffers.back_shooters)
            .buffer(slot::BACK, &buffers.back_batch)
            .view(slot::SHOWN_BACK_OUT, &targets.shown_back)
            .view(slot::SHOWN_FRONT_OUT, &targets.shown_front)
    }

    /// The compute pipeline of `pass` in `module` (redistribute.wgsl) and
    /// its bind group, with `constants` and the shooters' cut constants.
    fn redistribution_pass(
        &self,
        module: &wgpu::ShaderModule,
        resources: &Resources<'_>,
        pass: Pass,
        constants: &[(&str, f64)],
    ) -> (wgpu::ComputePipeline, wgpu::BindGroup) {
        let cuts = cut_constants(self.triangles);
        let constants: Vec<(&str, f64)> = constants.iter().chain(&cuts).copied().collect();
        pass.compute(&self.device, module, &constants, |s| resources.get(s))
    }

    /// The tiles' gathering hemicubes at the batch's shooters: the element
    /// seen per pixel.
    fn gathering_hemicube_passes(
        &self,
        hemicube_module: &wgpu::ShaderModule,
        resources: &Resources<'_>,
    ) -> (hemicube::Pipelines, wgpu::BindGroup) {
        let device = &self.device;
        let ids = &hemicube::ELEMENT_IDS;
        let ids_layout = ids.layout(device);
        let front_pipeline =
            hemicube::Pipelines::new(device, (hemicube_module, self.draws), ids, &ids_layout);
        let front_group = ids.bind(device, &ids_layout, |s| resources.get(s));
        (front_pipeline, front_group)
    }

    /// The back hemicubes at their own shooters, of the scene without the
    /// moving objects (thesis Alg. 4.5; `back_poses`): the element seen per
    /// pixel and its distance.
    fn back_hemicube_passes(
        &self,
        hemicube_module: &wgpu::ShaderModule,
        buffers: &DynamicBuffers,
    ) -> (hemicube::Pipelines, wgpu::BindGroup) {
        let device = &self.device;
        let back_resources = self
            .buffers
            .resources()
            .buffer(hemicube::slot::POSES, &buffers.back_poses)
            .buffer(hemicube::slot::SHOOTERS, &buffers.back_shooters)
            .buffer(hemicube::slot::BATCH, &buffers.back_batch);
        let back = &hemicube::BACK_ELEMENTS;
        let back_layout = back.layout(device);
        let back_pipeline =
            hemicube::Pipelines::new(device, (hemicube_module, self.draws), back, &back_layout);
        let back_group = back.bind(device, &back_layout, |s| back_resources.get(s));
        (back_pipeline, back_group)
    }
}
