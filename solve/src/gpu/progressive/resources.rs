//! The GPU buffers and targets a progressive solver keeps for its lifetime,
//! and which slot of the shaders each one is bound at.

use wgpu::util::DeviceExt;

use super::shoot::{BatchUniform, Selection};
use super::slot;
use crate::gpu::binding::Resources;
use crate::gpu::buffers::{non_empty, texture};
use crate::gpu::hemicube::{self, FACES, GpuVertex};
use crate::gpu::placement::{ELEMENT_BYTES, LocalElement, PatchFrame, PatchRange};

/// What the buffers start with, prepared on the CPU.
pub(super) struct Upload<'a> {
    /// Elements in object space (at least one: buffers may not be empty).
    pub(super) locals: &'a [LocalElement],
    /// `E` per element, `B` and `B^u` at the start (absent objects dark).
    pub(super) emission: &'a [[f32; 4]],
    pub(super) start: &'a [[f32; 4]],
    /// First element, element count and chart size of every patch.
    pub(super) patch_ranges: &'a [PatchRange],
    /// Every patch's frame for the occlusion test (`PatchTable::frames`).
    pub(super) patch_frames: &'a [PatchFrame],
    /// Patch ids of the triangle clusters, each cluster's contiguous
    /// (`clusters.rs`; may be empty).
    pub(super) members: &'a [u32],
    /// The patches' triangles for the hemicube rasterizer.
    pub(super) vertices: &'a [GpuVertex],
    pub(super) objects: usize,
    /// Shooter slots per batch.
    pub(super) capacity: u32,
    /// Top-face resolution of the item buffers.
    pub(super) resolution: u32,
}

/// Buffers and targets of a progressive solver; the redistribution passes
/// bind them too.
pub(super) struct Buffers {
    /// Elements in object space (`LocalElement`), as uploaded; the invalid
    /// flags are rewritten after a move when contacts change.
    pub(super) local_elements: wgpu::Buffer,
    /// Elements placed at the current poses (`place_elements`).
    pub(super) elements: wgpu::Buffer,
    /// `B`, `B^u` and `E` per element; `B` and `B^u` are read and written
    /// after a cross move (regather.rs).
    pub(super) radiosity: wgpu::Buffer,
    pub(super) unshot: wgpu::Buffer,
    pub(super) emission: wgpu::Buffer,
    /// Irradiance received so far, for the energy bookkeeping.
    pub(super) irradiance: wgpu::Buffer,
    pub(super) patches: wgpu::Buffer,
    /// Every patch's `PatchFrame` (receive.wgsl's `patch_frames`).
    pub(super) patch_frames: wgpu::Buffer,
    /// What a cluster shooter's range names: patch ids (`clusters.rs`).
    pub(super) members: wgpu::Buffer,
    pub(super) patch_power: wgpu::Buffer,
    /// The reduction's answer, and a mappable copy of it.
    pub(super) selection: wgpu::Buffer,
    pub(super) selection_readback: wgpu::Buffer,
    pub(super) shooters: wgpu::Buffer,
    /// The intermediate texture T: up to two values per shooter.
    pub(super) energy: wgpu::Buffer,
    pub(super) batch: wgpu::Buffer,
    /// Object matrices: current set, then old set (zero = absent).
    pub(super) poses: wgpu::Buffer,
    /// `OBJECT_MOVING` / `OBJECT_ABSENT` per object (common.wgsl).
    pub(super) flags: wgpu::Buffer,
    pub(super) vertices: wgpu::Buffer,
    /// Item buffers: a row of five faces per shooter slot.
    pub(super) item_view: wgpu::TextureView,
    pub(super) depth_view: wgpu::TextureView,
}

impl Buffers {
    pub(super) fn new(device: &wgpu::Device, up: &Upload<'_>) -> Self {
        let storage = wgpu::BufferUsages::STORAGE;
        let copy_dst = wgpu::BufferUsages::COPY_DST;
        let copy_src = wgpu::BufferUsages::COPY_SRC;
        let init = |label: &str, contents: &[u8], usage: wgpu::BufferUsages| {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents,
                usage,
            })
        };
        let empty = |label: &str, size: u64, usage: wgpu::BufferUsages| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage,
                mapped_at_creation: false,
            })
        };
        let selection_bytes = std::mem::size_of::<Selection>() as u64;
        let (item_view, depth_view) = item_targets(device, up.resolution, up.capacity);
        Self {
            local_elements: init(
                "local elements",
                bytemuck::cast_slice(up.locals),
                storage | copy_dst,
            ),
            elements: empty(
                "elements",
                up.locals.len() as u64 * ELEMENT_BYTES,
                storage | copy_dst,
            ),
            radiosity: init(
                "radiosity",
                bytemuck::cast_slice(up.start),
                storage | copy_src | copy_dst,
            ),
            unshot: init(
                "unshot",
                bytemuck::cast_slice(up.start),
                storage | copy_src | copy_dst,
            ),
            emission: init("emission", bytemuck::cast_slice(up.emission), storage),
            irradiance: init(
                "irradiance",
                bytemuck::cast_slice(&vec![[0.0f32; 4]; up.emission.len()]),
                storage | copy_src,
            ),
            patches: init("patches", bytemuck::cast_slice(up.patch_ranges), storage),
            patch_frames: init(
                "patch frames",
                bytemuck::cast_slice(up.patch_frames),
                storage,
            ),
            members: init(
                "cluster members",
                bytemuck::cast_slice(&non_empty(up.members.to_vec())),
                storage,
            ),
            patch_power: empty(
                "patch power",
                (up.patch_ranges.len().max(1) * 4) as u64,
                storage | copy_src,
            ),
            selection: empty("selection", selection_bytes, storage | copy_src),
            // The selection, then every patch's unshot power (what a batch
            // shared by several patches picks from, `shoot.rs`).
            selection_readback: empty(
                "selection readback",
                selection_bytes + (up.patch_ranges.len().max(1) * 4) as u64,
                wgpu::BufferUsages::MAP_READ | copy_dst,
            ),
            shooters: empty(
                "shooters",
                super::shooters::uniform_bytes(),
                wgpu::BufferUsages::UNIFORM | storage | copy_dst,
            ),
            energy: empty("shooter energy", u64::from(up.capacity) * 2 * 16, storage),
            batch: empty(
                "batch",
                std::mem::size_of::<BatchUniform>() as u64,
                wgpu::BufferUsages::UNIFORM | copy_dst,
            ),
            poses: empty(
                "poses",
                (up.objects.max(1) * 2 * 64) as u64,
                storage | copy_dst,
            ),
            flags: empty(
                "object flags",
                (up.objects.max(1) * 4) as u64,
                storage | copy_dst,
            ),
            vertices: init(
                "hemicube vertices",
                bytemuck::cast_slice(up.vertices),
                storage,
            ),
            item_view,
            depth_view,
        }
    }

    /// Every buffer and target by the slot it is bound at, in the compute
    /// modules and in hemicube.wgsl (which name the shared ones alike).
    pub(super) fn resources(&self) -> Resources<'_> {
        Resources::new()
            .buffer(slot::ELEMENTS, &self.elements)
            .buffer(slot::PLACED, &self.elements)
            .buffer(slot::LOCAL_ELEMENTS, &self.local_elements)
            .buffer(slot::RADIOSITY, &self.radiosity)
            .buffer(slot::UNSHOT, &self.unshot)
            .buffer(slot::EMISSION, &self.emission)
            .buffer(slot::IRRADIANCE, &self.irradiance)
            .buffer(slot::PATCHES, &self.patches)
            .buffer(slot::PATCH_FRAMES, &self.patch_frames)
            .buffer(slot::MEMBERS, &self.members)
            .buffer(slot::PATCH_POWER, &self.patch_power)
            .buffer(slot::SELECTION, &self.selection)
            .buffer(slot::SHOOTERS, &self.shooters)
            .buffer(slot::ENERGY, &self.energy)
            .buffer(slot::BATCH, &self.batch)
            .buffer(slot::POSES, &self.poses)
            .buffer(slot::OBJECT_FLAGS, &self.flags)
            .view(slot::ITEM, &self.item_view)
            .buffer(hemicube::slot::VERTICES, &self.vertices)
    }
}

/// The item buffers, a row of five faces of top-face resolution `res` per
/// shooter slot of `capacity`, and their depth target.
fn item_targets(
    device: &wgpu::Device,
    res: u32,
    capacity: u32,
) -> (wgpu::TextureView, wgpu::TextureView) {
    let size = (FACES * res, res * capacity);
    let attach = wgpu::TextureUsages::RENDER_ATTACHMENT;
    let item_view = texture(
        device,
        "hemicube item buffers",
        size,
        wgpu::TextureFormat::R32Uint,
        1,
        // Copies: cross moves keep their new-pose rows for the next
        // (redistribute/resources.rs `Kept`).
        attach
            | wgpu::TextureUsages::TEXTURE_BINDING
            | wgpu::TextureUsages::COPY_SRC
            | wgpu::TextureUsages::COPY_DST,
    );
    let depth_view = texture(
        device,
        "hemicube depth",
        size,
        wgpu::TextureFormat::Depth32Float,
        1,
        attach,
    );
    (item_view, depth_view)
}
