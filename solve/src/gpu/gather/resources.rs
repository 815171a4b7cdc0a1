//! What the gather solver keeps on the GPU: the records it shares with
//! gather.wgsl, what they hold at the start (prepared on the CPU), the
//! bindings and passes, and the buffers, targets and pipelines.

use bytemuck::{Pod, Zeroable};
use glam::{DVec3, Vec3};
use wgpu::util::DeviceExt;

use crate::direct::direct_light;
use crate::gpu::binding::{Kind, Pass, Resources, Slot};
use crate::gpu::buffers::{texture, v4};
use crate::gpu::hemicube::{corner_order, render_pipeline};
use crate::gpu::placement::{PatchRange, WorldPatch};
use crate::gpu::progressive::GpuShooter;
use crate::gpu::shaders;
use lightwire_scene::atlas::Atlas;
use lightwire_scene::{Pose, Scene};

/// One patch corner (`GatherVertex` in gather.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(in crate::gpu) struct GatherVertex {
    pos: [f32; 4],
    normal: [f32; 4],
    st: [f32; 4],
}
const _: () = assert!(std::mem::size_of::<GatherVertex>() == 48);

/// One element's emission, area, albedo and direct irradiance
/// (`GatherElement`).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(in crate::gpu) struct GatherElement {
    emission: [f32; 4],
    albedo: [f32; 4],
    direct: [f32; 4],
}
const _: () = assert!(std::mem::size_of::<GatherElement>() == 48);

/// Constants of one pass (`GatherParams` in gather.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(in crate::gpu) struct GatherParams {
    pub(super) first: u32,
    pub(super) count: u32,
    pub(super) resolution: u32,
    pub(super) columns: u32,
    pub(super) element_count: u32,
    pub(super) near: f32,
    pub(super) pad: [u32; 2],
}
const _: () = assert!(std::mem::size_of::<GatherParams>() == 32);

/// The bindings of gather.wgsl.
mod slot {
    use super::{Kind, Slot};

    pub(super) const VERTICES: Slot = Slot::new("vertices", 0, Kind::StorageRead);
    pub(super) const RECEIVERS: Slot = Slot::new("receivers", 1, Kind::StorageRead);
    pub(super) const PARAMS: Slot = Slot::new("params", 2, Kind::Uniform);
    pub(super) const RADIOSITY: Slot = Slot::new("radiosity", 3, Kind::StorageRead);
    pub(super) const PATCHES: Slot = Slot::new("patches", 4, Kind::StorageRead);
    pub(super) const UPDATED: Slot = Slot::new("updated", 5, Kind::Storage);
    pub(super) const HEMICUBES: Slot =
        Slot::new("hemicubes", 6, Kind::FloatTexture { filterable: false });
    pub(super) const MULTIPLIERS: Slot = Slot::new("multipliers", 7, Kind::StorageRead);
    pub(super) const ELEMENTS: Slot = Slot::new("elements", 8, Kind::StorageRead);
    pub(super) const CHANGE: Slot = Slot::new("change", 9, Kind::Storage);
    pub(super) const IRRADIANCE: Slot = Slot::new("irradiance", 10, Kind::Storage);
    pub(super) const TOTALS: Slot = Slot::new("totals", 11, Kind::Storage);
    pub(super) const DONORS: Slot = Slot::new("donors", 12, Kind::StorageRead);
}

use slot::*;

/// "Render all B_j to a hemicube placed on patch i" (thesis Alg. 4.1).
const RADIOSITY_HEMICUBES: Pass = Pass {
    entries: &["vs_gather", "fs_gather"],
    slots: &[VERTICES, RECEIVERS, PARAMS, RADIOSITY, PATCHES, DONORS],
};

/// Integrate each tile against the delta form factors.
const GATHER: Pass = Pass {
    entries: &["gather_main"],
    slots: &[
        PARAMS,
        RADIOSITY,
        UPDATED,
        HEMICUBES,
        MULTIPLIERS,
        ELEMENTS,
        CHANGE,
        IRRADIANCE,
    ],
};

/// The power a bounce changed, for the convergence test.
const TOTAL_CHANGE: Pass = Pass {
    entries: &["total_change"],
    slots: &[PARAMS, CHANGE, TOTALS],
};

/// Every pass of gather.wgsl, for the naga check in shaders.rs.
#[cfg(test)]
pub(in crate::gpu) const ALL_PASSES: [Pass; 3] = [RADIOSITY_HEMICUBES, GATHER, TOTAL_CHANGE];

/// Receiving points and hemicube frames of every element of `atlas` on
/// the patches placed as `patches`: the sample nudged towards the patch
/// centre and off the surface by `offset`, exactly as `place_elements`
/// (progressive.wgsl) places the progressive solver's receivers.
pub(super) fn receivers(patches: &[WorldPatch], atlas: &Atlas, offset: f32) -> Vec<GpuShooter> {
    let mut receivers = Vec::with_capacity(atlas.elements.len());
    for e in &atlas.elements {
        let wp = &patches[e.patch as usize];
        let [s, t] = e.st;
        let sample = wp.origin + wp.u * s + wp.v * t;
        let eye = wp.receiving_point(e.st, offset);
        let t1 = wp.u.normalize();
        let t2 = wp.normal.cross(t1);
        receivers.push(GpuShooter {
            corner: v4(sample, 0.0),
            su: [0.0; 4],
            sv: [0.0; 4],
            eye: v4(eye, 0.0),
            t1: v4(t1, 0.0),
            t2: v4(t2, 0.0),
            n: v4(wp.normal, f32::from_bits(e.patch)),
            tile: [0; 4],
        });
    }
    receivers
}

/// Every element's emission and world area `areas`, albedo, and the
/// direct light of the emission at its receiving point (`receivers`), by
/// next-event estimation (`crate::direct`), plus `lit`, the lights' and
/// the sky's (`crate::lights::element_irradiance`): the hemicubes gather
/// only the reflected part `B - E` of what they see.
pub(super) fn gather_elements(
    (scene, atlas, poses): (&Scene, &Atlas, &[Pose]),
    receivers: &[GpuShooter],
    areas: &[f32],
    lit: &[Vec3],
) -> Vec<GatherElement> {
    let points: Vec<(DVec3, DVec3)> = receivers
        .iter()
        .map(|r| {
            let eye = Vec3::new(r.eye[0], r.eye[1], r.eye[2]).as_dvec3();
            (eye, Vec3::new(r.n[0], r.n[1], r.n[2]).as_dvec3())
        })
        .collect();
    let direct = direct_light(scene, atlas, poses, &points);
    atlas
        .elements
        .iter()
        .zip(areas)
        .zip(&direct)
        .zip(lit)
        .map(|(((e, a), d), l)| GatherElement {
            emission: v4(e.emission, *a),
            albedo: v4(e.albedo, 0.0),
            direct: v4(*d + *l, 0.0),
        })
        .collect()
}

/// World-space triangles: two per quad, one per triangle patch.
pub(super) fn world_triangles(patches: &[WorldPatch]) -> Vec<GatherVertex> {
    let mut vertices = Vec::with_capacity(patches.len() * 6);
    for (p, wp) in patches.iter().enumerate() {
        let corners = [
            (wp.origin, [0.0, 0.0]),
            (wp.origin + wp.u, [1.0, 0.0]),
            (wp.origin + wp.u + wp.v, [1.0, 1.0]),
            (wp.origin + wp.v, [0.0, 1.0]),
        ];
        for &i in corner_order(wp.triangle) {
            let (c, st) = corners[i];
            let st = wp.vertex_st(st);
            vertices.push(GatherVertex {
                pos: v4(c, f32::from_bits(p as u32)),
                normal: v4(wp.normal, 0.0),
                st: [st[0], st[1], 0.0, 0.0],
            });
        }
    }
    vertices
}

/// What the buffers start with, prepared on the CPU; none may be empty.
pub(super) struct Upload<'a> {
    /// `R = B - E` per element at the start.
    pub(super) start: &'a [[f32; 4]],
    pub(super) vertices: &'a [GatherVertex],
    pub(super) receivers: &'a [GpuShooter],
    pub(super) elements: &'a [GatherElement],
    /// What an invalid texel (under or inside geometry) shows in the
    /// hemicubes: its nearest valid neighbour's light
    /// (`Validity::donors`).
    pub(super) donors: &'a [u32],
    pub(super) patch_ranges: &'a [PatchRange],
    pub(super) multipliers: &'a [f32],
}

/// The gather solver's buffers.
pub(super) struct GatherBuffers {
    /// `R = B - E` per element, ping-pong.
    pub(super) radiosity: [wgpu::Buffer; 2],
    pub(super) irradiance: wgpu::Buffer,
    change: wgpu::Buffer,
    vertices: wgpu::Buffer,
    receivers: wgpu::Buffer,
    elements: wgpu::Buffer,
    donors: wgpu::Buffer,
    patches: wgpu::Buffer,
    multipliers: wgpu::Buffer,
    pub(super) params: wgpu::Buffer,
    pub(super) totals: wgpu::Buffer,
    pub(super) totals_readback: wgpu::Buffer,
}

impl GatherBuffers {
    pub(super) fn new(device: &wgpu::Device, up: &Upload<'_>) -> Self {
        let storage = wgpu::BufferUsages::STORAGE;
        let init = |label: &str, contents: &[u8], usage: wgpu::BufferUsages| {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents,
                usage,
            })
        };
        let readable = storage | wgpu::BufferUsages::COPY_SRC;
        let start = up.start;
        Self {
            radiosity: [
                init(
                    "gather radiosity 0",
                    bytemuck::cast_slice(start),
                    readable | wgpu::BufferUsages::COPY_DST,
                ),
                init(
                    "gather radiosity 1",
                    bytemuck::cast_slice(start),
                    readable | wgpu::BufferUsages::COPY_DST,
                ),
            ],
            irradiance: init(
                "gather irradiance",
                bytemuck::cast_slice(&vec![[0.0f32; 4]; start.len()]),
                readable,
            ),
            change: init(
                "gather change",
                bytemuck::cast_slice(&vec![0.0f32; start.len()]),
                storage,
            ),
            vertices: init(
                "gather vertices",
                bytemuck::cast_slice(up.vertices),
                storage,
            ),
            receivers: init("receivers", bytemuck::cast_slice(up.receivers), storage),
            elements: init(
                "gather elements",
                bytemuck::cast_slice(up.elements),
                storage,
            ),
            donors: init("gather donors", bytemuck::cast_slice(up.donors), storage),
            patches: init(
                "gather patches",
                bytemuck::cast_slice(up.patch_ranges),
                storage,
            ),
            multipliers: init(
                "delta form factors",
                bytemuck::cast_slice(up.multipliers),
                storage,
            ),
            params: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("gather params"),
                size: std::mem::size_of::<GatherParams>() as u64,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
            totals: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("gather totals"),
                size: 16,
                usage: readable,
                mapped_at_creation: false,
            }),
            totals_readback: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("gather totals readback"),
                size: 16,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
        }
    }
}

/// The hemicube target of a pass, `width` x `height` pixels: the
/// radiosity seen (`Rgba32Float`) and its depth.
pub(super) fn targets(
    device: &wgpu::Device,
    size: (u32, u32),
) -> (wgpu::TextureView, wgpu::TextureView) {
    let target = |label: &str, format: wgpu::TextureFormat, usage: wgpu::TextureUsages| {
        texture(device, label, size, format, 1, usage)
    };
    let color_view = target(
        "gather hemicubes",
        wgpu::TextureFormat::Rgba32Float,
        wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
    );
    let depth_view = target(
        "gather depth",
        wgpu::TextureFormat::Depth32Float,
        wgpu::TextureUsages::RENDER_ATTACHMENT,
    );
    (color_view, depth_view)
}

/// The gather solver's pipelines and their bind groups.
pub(super) struct GatherPipelines {
    /// Renders radiosity hemicubes; bind group `k` reads `radiosity[k]`.
    pub(super) hemicube: wgpu::RenderPipeline,
    pub(super) hemicube_groups: [wgpu::BindGroup; 2],
    /// Integrates tiles; bind group `k` reads `radiosity[k]` and writes
    /// the other buffer.
    pub(super) gather: wgpu::ComputePipeline,
    pub(super) gather_groups: [wgpu::BindGroup; 2],
    pub(super) total_change: (wgpu::ComputePipeline, wgpu::BindGroup),
}

impl GatherPipelines {
    /// The passes of gather.wgsl bound to `buffers` and to the hemicube
    /// target `color_view`.
    pub(super) fn new(
        device: &wgpu::Device,
        buffers: &GatherBuffers,
        color_view: &wgpu::TextureView,
    ) -> Self {
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("gather.wgsl"),
            source: wgpu::ShaderSource::Wgsl(shaders::gather().into()),
        });
        let b = buffers;
        // Bind group `k` reads `radiosity[k]` and writes the other buffer.
        let resources = |k: usize| {
            Resources::new()
                .buffer(slot::VERTICES, &b.vertices)
                .buffer(slot::RECEIVERS, &b.receivers)
                .buffer(slot::PARAMS, &b.params)
                .buffer(slot::RADIOSITY, &b.radiosity[k])
                .buffer(slot::PATCHES, &b.patches)
                .buffer(slot::DONORS, &b.donors)
                .buffer(slot::UPDATED, &b.radiosity[1 - k])
                .view(slot::HEMICUBES, color_view)
                .buffer(slot::MULTIPLIERS, &b.multipliers)
                .buffer(slot::ELEMENTS, &b.elements)
                .buffer(slot::CHANGE, &b.change)
                .buffer(slot::IRRADIANCE, &b.irradiance)
                .buffer(slot::TOTALS, &b.totals)
        };
        let bound = [resources(0), resources(1)];
        // Reversed depth (see gather.wgsl): nearer is greater.
        let hemicube_layout = RADIOSITY_HEMICUBES.layout(device);
        let hemicube = render_pipeline(
            device,
            &module,
            &[],
            &RADIOSITY_HEMICUBES,
            &hemicube_layout,
            wgpu::TextureFormat::Rgba32Float,
            1,
            wgpu::CompareFunction::Greater,
        );
        let hemicube_groups =
            [0, 1].map(|k| RADIOSITY_HEMICUBES.bind(device, &hemicube_layout, |s| bound[k].get(s)));
        let (gather, gather0) = GATHER.compute(device, &module, &[], |s| bound[0].get(s));
        let gather1 = GATHER.bind(device, &gather.get_bind_group_layout(0), |s| {
            bound[1].get(s)
        });
        let total_change = TOTAL_CHANGE.compute(device, &module, &[], |s| bound[0].get(s));
        Self {
            hemicube,
            hemicube_groups,
            gather,
            gather_groups: [gather0, gather1],
            total_change,
        }
    }
}
