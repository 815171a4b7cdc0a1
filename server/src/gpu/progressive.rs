//! GPU progressive refinement radiosity (thesis Alg. 4.2, gems §39.2).
//!
//! One *batch* is one SHOOTINGITERATION of the thesis: the patch with the
//! most unshot power (found by the previous batch's reduction) is split into
//! shooters, every shooter gets a hemicube item buffer, and every element
//! gathers from all shooters at once. See the module doc of [`crate::gpu`]
//! for the data flow.

use std::time::{Duration, Instant};

use bytemuck::{Pod, Zeroable};
use glam::Vec3;
use wgpu::util::DeviceExt;

use super::device::{Device, GpuError};
use super::shaders;
use crate::atlas::Atlas;
use crate::scene::{PatchShape, Pose, Scene};
use crate::validity::Validity;

/// WGSL shared by both shaders, prepended to each.
mod redistribute;
mod regather;
pub use redistribute::{Move, Redistribution};

/// Hemicube faces per shooter: top and four sides.
pub(super) const FACES: u32 = 5;
/// Patch id of item-buffer pixels that see no surface.
const NO_PATCH: u32 = u32::MAX;
/// Receiving points are moved this fraction of the scene's extent off
/// edges and off their surface (like the reference solver's offset).
pub(super) const SURFACE_OFFSET: f32 = 1e-5;
/// Workgroup size of the per-element and per-shooter compute shaders.
pub(super) const WORKGROUP: u32 = 64;

/// Tuning of [`ProgressiveSolver`].
#[derive(Debug, Clone, Copy)]
pub struct ProgressiveOptions {
    /// Top-face resolution of the hemicube item buffers in pixels (thesis
    /// §4.3.1: with the disk approximation the form factor does not depend
    /// on it, only visibility does, so it can be low).
    pub hemicube_resolution: u32,
    /// Most shooters one patch is split into (thesis §4.3.3); the count
    /// for a patch grows with the square root of its share of the emitted
    /// power.
    pub max_shooters: u32,
    /// Form-factor subdivision: a shooter of area `A` at distance `r` is
    /// split into `ceil(subdivision * sqrt(A) / r)²` sub-disks (thesis
    /// §4.3.3, adaptive form factor subdivision).
    ///
    /// The disk approximation (thesis eq. 2.2.7) is biased low: each
    /// sub-disk of area `a` at distance `r` loses about `a / (π r²)` of its
    /// form factor to the `+ a` in the denominator, so a closed room
    /// receives less than is shot. Measured on a closed albedo-0.9 box
    /// (`furnace.json` repainted), power received per power shot:
    /// 0.9974 at 4, 0.9992 at 8, 0.9998 at 16, 1.0000 with the exact form
    /// factor; a room that needs ten bounces multiplies that loss tenfold.
    pub subdivision: f32,
    /// Upper bound on sub-disks per axis; closer shooters use the exact
    /// (infinitely subdivided) form factor: Lambert's contour integral,
    /// four arctangents for an unclipped quad.
    pub max_subdivision: u32,
    /// Publish indirect light only (gems §39.4): [`ProgressiveSolver::radiosity`]
    /// returns `B - E - D`, where `D` is the first bounce of the emitted
    /// light, for clients that draw direct light and shadows themselves.
    /// Every emitting patch shoots its emission once before anything else;
    /// `D` is what that delivered. (Emitters that light each other mix a
    /// little of their received light into `D`.)
    pub indirect_only: bool,
    /// Side length of the cross projection's sampling grid on each moving
    /// shooter (thesis Alg. 4.5 gridSize).
    pub cross_grid: u32,
    /// Cross redistribution shoots from tiles of at most this many texels
    /// per side on each moving patch, not from every texel: a tile gathers
    /// the static scene's light once (its texels share it), shoots once
    /// and casts its shadow once. The thesis does the same by giving the
    /// rotating box far fewer elements under cross redistribution (§5.1:
    /// 918 → 90 on the large Cornell box, 270 → 24 on the low-quality
    /// one); 4 gives about those counts on our scenes. 1 shoots per texel.
    pub cross_tile: u32,
    /// Top-face resolution of the back hemicubes of shot radiosity used by
    /// the cross projection (thesis §4.5.2 renders them as low as 16, with
    /// multisampling as a blur).
    pub back_resolution: u32,
    /// Split shooter tiles that straddle a contact (valid and invalid
    /// elements), up to 1.5 times the tiles of the power-based grid
    /// (`ProgressiveSolver::split_contacts`). Off for sessions that follow
    /// moves by incremental reshooting: with it, incremental on
    /// indirect-light read 20.3% NRMSE after five frames instead of 3.9%
    /// (`bench dynamic`; not understood yet, see BENCHMARKS.md).
    pub split_contacts: bool,
}

impl Default for ProgressiveOptions {
    fn default() -> Self {
        Self {
            hemicube_resolution: 64,
            max_shooters: 128,
            subdivision: 8.0,
            max_subdivision: 2,
            indirect_only: false,
            cross_grid: 4,
            cross_tile: 4,
            back_resolution: 16,
            split_contacts: true,
        }
    }
}

/// What a call to [`ProgressiveSolver::step`] or `solve` did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepReport {
    /// Shooters shot during the call.
    pub shots: u64,
    /// Batches (one patch each) during the call.
    pub batches: u64,
    /// Unshot power as a fraction of the emitted power, afterwards.
    pub unshot_fraction: f64,
}

/// Power bookkeeping (W, summed over the RGB channels).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EnergyBalance {
    /// `Σ A_e E_e`.
    pub emitted: f64,
    /// Power taken out of the unshot buffers by shots so far.
    pub shot: f64,
    /// Power that arrived at elements: `Σ A_e H_e`.
    pub received: f64,
    /// Power absorbed by elements: `Σ A_e (1 - ρ_e) H_e`.
    pub absorbed: f64,
    /// Power still waiting to be shot.
    pub unshot: f64,
}

/// One element in its object's space (`LocalElement` in progressive.wgsl);
/// `place_elements` derives the world-space `Element` from it and the pose.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(super) struct LocalElement {
    position: [f32; 4],
    normal: [f32; 4],
    lookup: [f32; 4],
    albedo: [f32; 4],
    nudge: [f32; 4],
}
const _: () = assert!(std::mem::size_of::<LocalElement>() == 80);

/// Size of a world-space element (`Element` in progressive.wgsl: position
/// and area, normal and patch, lookup point and object, albedo).
pub(super) const ELEMENT_BYTES: u64 = 64;

/// One patch corner for the hemicube rasterizer (`Vertex` in hemicube.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(super) struct GpuVertex {
    pos: [f32; 4],
    st: [f32; 4],
}
const _: () = assert!(std::mem::size_of::<GpuVertex>() == 32);

/// One shooter (`Shooter` in common.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(super) struct GpuShooter {
    pub(super) corner: [f32; 4],
    pub(super) su: [f32; 4],
    pub(super) sv: [f32; 4],
    pub(super) eye: [f32; 4],
    pub(super) t1: [f32; 4],
    pub(super) t2: [f32; 4],
    pub(super) n: [f32; 4],
    pub(super) tile: [u32; 4],
}
const _: () = assert!(std::mem::size_of::<GpuShooter>() == 128);

/// Per-batch constants (`Batch` in common.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(super) struct BatchUniform {
    patch_id: u32,
    shooters: u32,
    resolution: u32,
    first_element: u32,
    chart_w: u32,
    element_count: u32,
    near: f32,
    far: f32,
    subdivision: f32,
    max_subdivision: u32,
    old_from_slot: u32,
    mode: u32,
}
const _: () = assert!(std::mem::size_of::<BatchUniform>() == 48);

/// The reduction's answer (`Selection` in progressive.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable, Debug)]
pub(super) struct Selection {
    patch_id: u32,
    power: f32,
    total: f32,
    _pad: f32,
}
const _: () = assert!(std::mem::size_of::<Selection>() == 16);

/// A patch placed in the world, as the CPU needs it to place shooters.
#[derive(Debug, Clone, Copy)]
pub(super) struct WorldPatch {
    pub(super) origin: Vec3,
    pub(super) u: Vec3,
    pub(super) v: Vec3,
    pub(super) normal: Vec3,
    pub(super) first: u32,
    pub(super) w: u32,
    pub(super) h: u32,
}

impl WorldPatch {
    /// The point an element at patch parameters `st` receives at: its
    /// sample moved `offset` towards the patch centre and `offset` off the
    /// surface, as `place_elements` (progressive.wgsl) moves it.
    pub(super) fn receiving_point(&self, st: [f32; 2], offset: f32) -> Vec3 {
        let [s, t] = st;
        let sample = self.origin + self.u * s + self.v * t;
        let centre = self.origin + (self.u + self.v) * 0.5;
        let inward = (centre - sample).normalize_or_zero();
        sample + (inward + self.normal) * offset
    }

    pub(super) fn corners(&self) -> [Vec3; 4] {
        [
            self.origin,
            self.origin + self.u,
            self.origin + self.u + self.v,
            self.origin + self.v,
        ]
    }
}

/// Every patch placed at its object's pose; `layout` gives each patch's
/// first element and chart size.
pub(super) fn place_patches(
    shapes: &[PatchShape],
    objects: &[u32],
    layout: &[[u32; 3]],
    poses: &[Pose],
) -> Vec<WorldPatch> {
    shapes
        .iter()
        .enumerate()
        .map(|(p, shape)| {
            let PatchShape::Quad { origin, u, v } = shape.transformed(&poses[objects[p] as usize]);
            let [first, w, h] = layout[p];
            WorldPatch {
                origin,
                u,
                v,
                normal: u.cross(v).normalize(),
                first,
                w,
                h,
            }
        })
        .collect()
}

/// World areas of elements: scale-1 areas times their object's scale².
pub(super) fn world_areas(local: &[f32], objects: &[u32], poses: &[Pose]) -> Vec<f32> {
    local
        .iter()
        .zip(objects)
        .map(|(a, o)| {
            let s = poses[*o as usize].scale;
            a * s * s
        })
        .collect()
}

/// A hemicube render pipeline of hemicube.wgsl: item buffers
/// (`vs_main`/`fs_main`, R32Uint) or shot radiosity (`vs_rad`/`fs_rad`,
/// Rgba16Float, optionally multisampled as a blur, thesis §4.5.2).
fn hemicube_pipeline(
    device: &wgpu::Device,
    module: &wgpu::ShaderModule,
    (vs, fs): (&str, &str),
    format: wgpu::TextureFormat,
    samples: u32,
) -> wgpu::RenderPipeline {
    device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some(fs),
        layout: None,
        vertex: wgpu::VertexState {
            module,
            entry_point: Some(vs),
            compilation_options: Default::default(),
            buffers: &[],
        },
        primitive: wgpu::PrimitiveState {
            topology: wgpu::PrimitiveTopology::TriangleList,
            // Surfaces are opaque from both sides.
            cull_mode: None,
            ..Default::default()
        },
        depth_stencil: Some(wgpu::DepthStencilState {
            format: wgpu::TextureFormat::Depth32Float,
            depth_write_enabled: Some(true),
            depth_compare: Some(wgpu::CompareFunction::Less),
            stencil: Default::default(),
            bias: Default::default(),
        }),
        multisample: wgpu::MultisampleState {
            count: samples,
            ..Default::default()
        },
        fragment: Some(wgpu::FragmentState {
            module,
            entry_point: Some(fs),
            compilation_options: Default::default(),
            targets: &[Some(wgpu::ColorTargetState {
                format,
                blend: None,
                write_mask: wgpu::ColorWrites::ALL,
            })],
        }),
        multiview_mask: None,
        cache: None,
    })
}

/// Progressive refinement radiosity on the GPU: elements, B, B^u and the
/// per-patch unshot power live in GPU buffers for the solver's lifetime;
/// the CPU only places shooters and reads one 16-byte selection per batch.
///
/// Objects can move ([`ProgressiveSolver::redistribute`]): elements are kept
/// in object space and placed at the current poses by a compute pass, and
/// the hemicube rasterizer places triangles with one of two pose sets (the
/// current and the old one), so that a redistribution sees the scene before
/// and after a move.
pub struct ProgressiveSolver {
    device: wgpu::Device,
    queue: wgpu::Queue,
    options: ProgressiveOptions,
    /// Shooters per batch the item-buffer target can hold.
    batch_capacity: u32,
    /// Patches in object space (the scene's shapes) and their objects.
    shapes: Vec<PatchShape>,
    patch_objects: Vec<u32>,
    /// First element and chart size of every patch.
    layout: Vec<[u32; 3]>,
    /// Patches placed at the current poses.
    patches: Vec<WorldPatch>,
    /// The current pose of every object.
    poses: Vec<Pose>,
    /// Elements inside or under geometry at `poses` (crate::validity):
    /// they do not receive, and shooters look from their tiles' valid part.
    validity: Validity,
    /// Elements re-tested for validity in moves since the last cross move
    /// completed (those near the moved objects): cross redistribution has
    /// them gather their light when the move completes (regather.rs).
    regather: Vec<usize>,
    /// The scene and atlas, to re-test validity after a move.
    scene: Scene,
    atlas: Atlas,
    /// Objects removed from the simulation (thesis §4.5.2).
    absent: Vec<bool>,
    /// Element areas at scale 1 and their objects, for shooter areas.
    local_areas: Vec<f32>,
    element_objects: Vec<u32>,
    /// World areas of the elements at the current poses.
    areas: Vec<f32>,
    albedo: Vec<Vec3>,
    element_count: u32,
    emitted: f64,
    near: f32,
    far: f32,
    /// Latest selection read back: what the next batch shoots.
    selection: Selection,
    shots: u64,
    batches: u64,
    shot_power: f64,
    /// `E + D` per element when publishing indirect light only.
    direct: Option<Vec<Vec3>>,

    radiosity: wgpu::Buffer,
    irradiance: wgpu::Buffer,
    shooters: wgpu::Buffer,
    batch: wgpu::Buffer,
    selection_readback: wgpu::Buffer,
    selection_buffer: wgpu::Buffer,
    item_view: wgpu::TextureView,
    depth_view: wgpu::TextureView,
    /// Object matrices: current set, then old set (zero = absent).
    pose_buffer: wgpu::Buffer,
    /// `OBJECT_MOVING` / `OBJECT_ABSENT` per object (common.wgsl).
    flags_buffer: wgpu::Buffer,

    shooter_energy: (wgpu::ComputePipeline, wgpu::BindGroup),
    reconstruct: (wgpu::ComputePipeline, wgpu::BindGroup),
    patch_power: (wgpu::ComputePipeline, wgpu::BindGroup),
    select: (wgpu::ComputePipeline, wgpu::BindGroup),
    place: (wgpu::ComputePipeline, wgpu::BindGroup),
    hemicube: (wgpu::RenderPipeline, wgpu::BindGroup),
    triangle_vertices: u32,
    /// Redistribution passes and targets, built on first use.
    dynamic: Option<redistribute::DynamicPasses>,
    /// What `dynamic` is built from.
    buffers: SharedBuffers,
}

/// Buffers the redistribution passes bind besides those above.
struct SharedBuffers {
    elements: wgpu::Buffer,
    /// Elements in object space (`LocalElement`), as uploaded.
    local_elements: wgpu::Buffer,
    unshot: wgpu::Buffer,
    emission: wgpu::Buffer,
    energy: wgpu::Buffer,
    patches: wgpu::Buffer,
    vertices: wgpu::Buffer,
}

/// A compute pipeline with an automatic layout and its bind group.
pub(super) fn compute(
    device: &wgpu::Device,
    module: &wgpu::ShaderModule,
    entry: &str,
    resources: &[(u32, wgpu::BindingResource<'_>)],
) -> (wgpu::ComputePipeline, wgpu::BindGroup) {
    compute_with(device, module, entry, &[], resources)
}

/// [`compute`] with pipeline-overridable constants.
fn compute_with(
    device: &wgpu::Device,
    module: &wgpu::ShaderModule,
    entry: &str,
    constants: &[(&str, f64)],
    resources: &[(u32, wgpu::BindingResource<'_>)],
) -> (wgpu::ComputePipeline, wgpu::BindGroup) {
    let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some(entry),
        layout: None,
        module,
        entry_point: Some(entry),
        compilation_options: wgpu::PipelineCompilationOptions {
            constants,
            ..Default::default()
        },
        cache: None,
    });
    let bind_group = bind(device, entry, &pipeline.get_bind_group_layout(0), resources);
    (pipeline, bind_group)
}

/// A bind group from (binding, resource) pairs.
pub(super) fn bind(
    device: &wgpu::Device,
    label: &str,
    layout: &wgpu::BindGroupLayout,
    resources: &[(u32, wgpu::BindingResource<'_>)],
) -> wgpu::BindGroup {
    let entries: Vec<wgpu::BindGroupEntry<'_>> = resources
        .iter()
        .map(|(binding, resource)| wgpu::BindGroupEntry {
            binding: *binding,
            resource: resource.clone(),
        })
        .collect();
    device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some(label),
        layout,
        entries: &entries,
    })
}

pub(super) fn v4(v: Vec3, w: f32) -> [f32; 4] {
    [v.x, v.y, v.z, w]
}

/// The object-to-world matrix of a pose.
fn pose_matrix(pose: &Pose) -> [[f32; 4]; 4] {
    glam::Mat4::from_scale_rotation_translation(
        Vec3::splat(pose.scale),
        pose.rotation,
        pose.translation,
    )
    .to_cols_array_2d()
}

impl ProgressiveSolver {
    /// Uploads the scene at `poses` (one per object) and finds the first
    /// shooting patch. Every element starts with `B = B^u = E`.
    pub fn new(
        gpu: &Device,
        scene: &Scene,
        atlas: &Atlas,
        poses: &[Pose],
        options: ProgressiveOptions,
    ) -> Result<Self, GpuError> {
        Self::with_absent(gpu, scene, atlas, poses, &[], options)
    }

    /// Like [`ProgressiveSolver::new`], with the objects flagged in `absent`
    /// removed from the simulation (for cross redistribution, which solves
    /// the static scene first and inserts the moving objects afterwards,
    /// thesis §4.5.2).
    pub fn with_absent(
        gpu: &Device,
        scene: &Scene,
        atlas: &Atlas,
        poses: &[Pose],
        absent: &[bool],
        options: ProgressiveOptions,
    ) -> Result<Self, GpuError> {
        let device = gpu.device.clone();
        let queue = gpu.queue.clone();
        let limits = &gpu.limits;
        let res = options.hemicube_resolution.max(1);
        if FACES * res > limits.max_texture_dimension_2d {
            return Err(GpuError::TooLarge(format!(
                "a hemicube resolution of {res} needs a {} pixel wide item buffer; the adapter allows {}",
                FACES * res,
                limits.max_texture_dimension_2d
            )));
        }
        // Redistribution batches render two hemicubes per shooter, so the
        // capacity is even.
        let batch_capacity = (options
            .max_shooters
            .max(2)
            .min(limits.max_texture_dimension_2d / res)
            / 2)
            * 2;
        let n = atlas.elements.len();
        let element_bytes = n as u64 * std::mem::size_of::<LocalElement>() as u64;
        if element_bytes > limits.max_storage_buffer_binding_size
            || n > (limits.max_compute_workgroups_per_dimension as usize) * WORKGROUP as usize
        {
            return Err(GpuError::TooLarge(format!(
                "{n} elements do not fit the adapter's storage buffer or dispatch limits"
            )));
        }
        let object_count = poses.len().max(1);
        let absent: Vec<bool> = (0..poses.len())
            .map(|o| absent.get(o).copied().unwrap_or(false))
            .collect();

        let shapes: Vec<PatchShape> = scene.patches.iter().map(|p| p.shape).collect();
        let patch_objects: Vec<u32> = scene.patches.iter().map(|p| p.object).collect();
        let layout: Vec<[u32; 3]> = atlas
            .charts
            .iter()
            .enumerate()
            .map(|(p, c)| [atlas.patch_elements[p], c.w, c.h])
            .collect();
        let patches = place_patches(&shapes, &patch_objects, &layout, poses);

        // Scene extent at the given poses, for depth ranges and offsets.
        let mut lo = Vec3::splat(f32::INFINITY);
        let mut hi = Vec3::splat(f32::NEG_INFINITY);
        for wp in &patches {
            for corner in wp.corners() {
                lo = lo.min(corner);
                hi = hi.max(corner);
            }
        }
        let extent = (hi - lo).length().max(1e-6);

        // Two triangles per patch, in object space.
        let mut vertices: Vec<GpuVertex> = Vec::with_capacity(shapes.len() * 6);
        for (p, shape) in shapes.iter().enumerate() {
            let PatchShape::Quad { origin, u, v } = *shape;
            let corners = [
                (origin, [0.0, 0.0]),
                (origin + u, [1.0, 0.0]),
                (origin + u + v, [1.0, 1.0]),
                (origin + v, [0.0, 1.0]),
            ];
            let object = f32::from_bits(patch_objects[p]);
            for i in [0, 1, 2, 0, 2, 3] {
                let (c, st) = corners[i];
                vertices.push(GpuVertex {
                    pos: v4(c, f32::from_bits(p as u32)),
                    st: [st[0], st[1], object, 0.0],
                });
            }
        }

        let validity = Validity::compute(scene, atlas, poses);
        let mut locals = Vec::with_capacity(n);
        let mut local_areas = Vec::with_capacity(n);
        let mut element_objects = Vec::with_capacity(n);
        let mut albedo = Vec::with_capacity(n);
        let mut emission = Vec::with_capacity(n);
        for (i, e) in atlas.elements.iter().enumerate() {
            let p = e.patch as usize;
            let PatchShape::Quad { origin, u, v } = shapes[p];
            let chart = atlas.charts[p];
            let normal = u.cross(v).normalize();
            let [s, t] = e.st;
            let sample = origin + u * s + v * t;
            let centre = origin + (u + v) * 0.5;
            // Edge samples look up visibility a quarter cell inside their
            // own patch, so the item buffer shows their patch, not the
            // neighbour sharing the edge.
            let inset = |x: f32, cells: u32| {
                let q = 0.25 / (cells.max(2) - 1) as f32;
                x.clamp(q, 1.0 - q)
            };
            let lookup = origin + u * inset(s, chart.w) + v * inset(t, chart.h);
            locals.push(LocalElement {
                position: v4(sample, e.area),
                normal: v4(normal, f32::from_bits(e.patch)),
                lookup: v4(lookup, f32::from_bits(e.object)),
                albedo: v4(e.albedo, invalid_flag(validity.is_invalid(i))),
                // Receiving points are moved a hair towards the patch centre
                // and off the surface (like the reference solver's offset).
                nudge: v4(
                    (centre - sample).normalize_or_zero(),
                    extent * SURFACE_OFFSET,
                ),
            });
            local_areas.push(e.area);
            element_objects.push(e.object);
            albedo.push(e.albedo);
            emission.push(v4(e.emission, 0.0));
        }
        let areas = world_areas(&local_areas, &element_objects, poses);
        let emitted: f64 = atlas
            .elements
            .iter()
            .zip(&areas)
            .map(|(e, a)| f64::from(*a) * f64::from(e.emission.element_sum()))
            .sum();
        let patch_ranges: Vec<[u32; 4]> = patches
            .iter()
            .enumerate()
            .map(|(p, wp)| [wp.first, atlas.patch_elements[p + 1] - wp.first, wp.w, wp.h])
            .collect();

        let storage = wgpu::BufferUsages::STORAGE;
        let init = |label: &str, contents: &[u8], usage: wgpu::BufferUsages| {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents,
                usage,
            })
        };
        // Buffers may not be empty; pad with a zero element.
        let non_empty = |v: Vec<[f32; 4]>| if v.is_empty() { vec![[0.0; 4]] } else { v };
        let emission = non_empty(emission);
        if locals.is_empty() {
            locals.push(LocalElement::zeroed());
        }
        // Written after a move when contacts change (`update_validity`).
        let local_buffer = init(
            "local elements",
            bytemuck::cast_slice(&locals),
            storage | wgpu::BufferUsages::COPY_DST,
        );
        let element_buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("elements"),
            size: locals.len() as u64 * ELEMENT_BYTES,
            usage: storage | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        // Absent objects start dark: they neither hold nor shoot light.
        let start: Vec<[f32; 4]> = emission
            .iter()
            .zip(
                atlas
                    .elements
                    .iter()
                    .map(|e| e.object as usize)
                    .chain(std::iter::once(0)),
            )
            .map(|(e, o)| {
                if absent.get(o).copied().unwrap_or(false) {
                    [0.0; 4]
                } else {
                    *e
                }
            })
            .collect();
        // Read and written after a cross move (regather.rs).
        let radiosity = init(
            "radiosity",
            bytemuck::cast_slice(&start),
            storage | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
        );
        let unshot = init(
            "unshot",
            bytemuck::cast_slice(&start),
            storage | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
        );
        let emission_buffer = init("emission", bytemuck::cast_slice(&emission), storage);
        let irradiance = init(
            "irradiance",
            bytemuck::cast_slice(&vec![[0.0f32; 4]; emission.len()]),
            storage | wgpu::BufferUsages::COPY_SRC,
        );
        let patch_buffer = init("patches", bytemuck::cast_slice(&patch_ranges), storage);
        let patch_power = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("patch power"),
            size: (patches.len().max(1) * 4) as u64,
            usage: storage,
            mapped_at_creation: false,
        });
        let selection_buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("selection"),
            size: std::mem::size_of::<Selection>() as u64,
            usage: storage | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let selection_readback = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("selection readback"),
            size: std::mem::size_of::<Selection>() as u64,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let shooters = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("shooters"),
            size: u64::from(batch_capacity) * std::mem::size_of::<GpuShooter>() as u64,
            usage: storage | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        // The intermediate texture T: up to two values per shooter.
        let energy = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("shooter energy"),
            size: u64::from(batch_capacity) * 2 * 16,
            usage: storage,
            mapped_at_creation: false,
        });
        let batch = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("batch"),
            size: std::mem::size_of::<BatchUniform>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let pose_buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("poses"),
            size: (object_count * 2 * 64) as u64,
            usage: storage | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let flags_buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("object flags"),
            size: (object_count * 4) as u64,
            usage: storage | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let triangle_vertices = vertices.len() as u32;
        if vertices.is_empty() {
            vertices.push(GpuVertex::zeroed());
        }
        let vertex_buffer = init(
            "hemicube vertices",
            bytemuck::cast_slice(&vertices),
            storage,
        );

        let size = wgpu::Extent3d {
            width: FACES * res,
            height: res * batch_capacity,
            depth_or_array_layers: 1,
        };
        let item = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("hemicube item buffers"),
            size,
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::R32Uint,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
            view_formats: &[],
        });
        let depth = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("hemicube depth"),
            size,
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::Depth32Float,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
            view_formats: &[],
        });
        let item_view = item.create_view(&Default::default());
        let depth_view = depth.create_view(&Default::default());

        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("progressive.wgsl"),
            source: wgpu::ShaderSource::Wgsl(shaders::compute().into()),
        });
        let hemicube_module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("hemicube.wgsl"),
            source: wgpu::ShaderSource::Wgsl(shaders::hemicube().into()),
        });
        fn b(buffer: &wgpu::Buffer) -> wgpu::BindingResource<'_> {
            buffer.as_entire_binding()
        }
        let shooter_energy = compute(
            &device,
            &module,
            "shooter_energy",
            &[
                (0, b(&element_buffer)),
                (2, b(&unshot)),
                (7, b(&shooters)),
                (8, b(&energy)),
                (9, b(&batch)),
            ],
        );
        let reconstruct = compute(
            &device,
            &module,
            "reconstruct",
            &[
                (0, b(&element_buffer)),
                (1, b(&radiosity)),
                (2, b(&unshot)),
                (3, b(&irradiance)),
                (4, b(&patch_buffer)),
                (7, b(&shooters)),
                (8, b(&energy)),
                (9, b(&batch)),
                (10, wgpu::BindingResource::TextureView(&item_view)),
                (11, b(&flags_buffer)),
                (12, b(&pose_buffer)),
                (13, b(&local_buffer)),
            ],
        );
        let patch_power_pass = compute(
            &device,
            &module,
            "patch_power_main",
            &[
                (0, b(&element_buffer)),
                (2, b(&unshot)),
                (4, b(&patch_buffer)),
                (5, b(&patch_power)),
                (11, b(&flags_buffer)),
            ],
        );
        let select = compute(
            &device,
            &module,
            "select_shooter",
            &[(5, b(&patch_power)), (6, b(&selection_buffer))],
        );
        let place = compute(
            &device,
            &module,
            "place_elements",
            &[
                (12, b(&pose_buffer)),
                (13, b(&local_buffer)),
                (14, b(&element_buffer)),
            ],
        );
        let hemicube_pipeline = hemicube_pipeline(
            &device,
            &hemicube_module,
            ("vs_main", "fs_main"),
            wgpu::TextureFormat::R32Uint,
            1,
        );
        let hemicube_group = bind(
            &device,
            "hemicube",
            &hemicube_pipeline.get_bind_group_layout(0),
            &[
                (0, b(&vertex_buffer)),
                (1, b(&shooters)),
                (2, b(&batch)),
                (3, b(&pose_buffer)),
            ],
        );

        let mut solver = Self {
            device,
            queue,
            options,
            batch_capacity,
            shapes,
            patch_objects,
            layout,
            patches,
            poses: poses.to_vec(),
            validity,
            regather: Vec::new(),
            scene: scene.clone(),
            atlas: atlas.clone(),
            absent,
            local_areas,
            element_objects,
            areas,
            albedo,
            element_count: n as u32,
            emitted,
            near: extent * 1e-4,
            far: extent * 4.0,
            selection: Selection::zeroed(),
            shots: 0,
            batches: 0,
            shot_power: 0.0,
            direct: None,
            radiosity,
            irradiance,
            shooters,
            batch,
            selection_readback,
            selection_buffer,
            item_view,
            depth_view,
            pose_buffer,
            flags_buffer,
            shooter_energy,
            reconstruct,
            patch_power: patch_power_pass,
            select,
            place,
            hemicube: (hemicube_pipeline, hemicube_group),
            triangle_vertices,
            dynamic: None,
            buffers: SharedBuffers {
                elements: element_buffer,
                local_elements: local_buffer,
                unshot,
                emission: emission_buffer,
                energy,
                patches: patch_buffer,
                vertices: vertex_buffer,
            },
        };
        let current = solver.poses.clone();
        solver.write_poses(&current, &current, &[]);
        solver.write_flags(&[]);
        let mut encoder = solver.device.create_command_encoder(&Default::default());
        solver.encode_place(&mut encoder);
        solver.encode_selection(&mut encoder);
        solver.queue.submit([encoder.finish()]);
        solver.selection = solver.read_selection()?;
        if options.indirect_only {
            solver.shoot_direct(scene, poses)?;
        }
        Ok(solver)
    }

    /// Writes both pose sets and the object flags: `current` (zero for
    /// absent objects), `old` (zero for objects absent before), and which
    /// objects are `moving`.
    fn write_poses(&self, current: &[Pose], old: &[Pose], old_absent: &[bool]) {
        let objects = current.len();
        let mut matrices = vec![[[0.0f32; 4]; 4]; objects.max(1) * 2];
        for o in 0..objects {
            if !self.absent[o] {
                matrices[o] = pose_matrix(&current[o]);
            }
            if !old_absent.get(o).copied().unwrap_or(false) {
                matrices[objects.max(1) + o] = pose_matrix(&old[o]);
            }
        }
        self.queue
            .write_buffer(&self.pose_buffer, 0, bytemuck::cast_slice(&matrices));
    }

    /// Writes the per-object flags (`moving` marks the set M).
    fn write_flags(&self, moving: &[bool]) {
        let flags: Vec<u32> = (0..self.absent.len().max(1))
            .map(|o| {
                let mut f = 0;
                if moving.get(o).copied().unwrap_or(false) {
                    f |= 1;
                }
                if self.absent.get(o).copied().unwrap_or(false) {
                    f |= 2;
                }
                f
            })
            .collect();
        self.queue
            .write_buffer(&self.flags_buffer, 0, bytemuck::cast_slice(&flags));
    }

    /// Places every element at the current poses (`place_elements`).
    fn encode_place(&self, encoder: &mut wgpu::CommandEncoder) {
        let mut pass = encoder.begin_compute_pass(&Default::default());
        pass.set_pipeline(&self.place.0);
        pass.set_bind_group(0, &self.place.1, &[]);
        pass.dispatch_workgroups(self.element_count.div_ceil(WORKGROUP).max(1), 1, 1);
    }

    /// Emitted power `Σ A_e E_e` (W, channels summed).
    pub fn emitted_power(&self) -> f64 {
        self.emitted
    }

    /// Unshot power as a fraction of the emitted power.
    pub fn unshot_fraction(&self) -> f64 {
        if self.emitted > 0.0 {
            f64::from(self.selection.total.max(0.0)) / self.emitted
        } else {
            0.0
        }
    }

    /// Shooters shot since the solver was created.
    pub fn total_shots(&self) -> u64 {
        self.shots
    }

    /// Runs whole batches until `budget` is spent (at least one batch, so
    /// that every call makes progress) or nothing is left to shoot.
    pub fn step(&mut self, budget: Duration) -> Result<StepReport, GpuError> {
        let started = Instant::now();
        let (shots, batches) = (self.shots, self.batches);
        loop {
            if !self.batch_once()? || started.elapsed() >= budget {
                break;
            }
        }
        Ok(StepReport {
            shots: self.shots - shots,
            batches: self.batches - batches,
            unshot_fraction: self.unshot_fraction(),
        })
    }

    /// Runs batches until the unshot power is at most `threshold` of the
    /// emitted power (or nothing is left to shoot).
    pub fn solve(&mut self, threshold: f64) -> Result<StepReport, GpuError> {
        let (shots, batches) = (self.shots, self.batches);
        while self.unshot_fraction() > threshold {
            if !self.batch_once()? {
                break;
            }
        }
        Ok(StepReport {
            shots: self.shots - shots,
            batches: self.batches - batches,
            unshot_fraction: self.unshot_fraction(),
        })
    }

    /// Radiosity per element (W/m² per channel), in atlas element order:
    /// `B`, or `B - E - D` with [`ProgressiveOptions::indirect_only`].
    /// Invalid elements ([`ProgressiveSolver::validity`]) hold what they
    /// happen to hold; whoever publishes fills them ([`Validity::dilate`]).
    pub fn radiosity(&self) -> Result<Vec<Vec3>, GpuError> {
        let total = self.total_radiosity()?;
        Ok(match &self.direct {
            None => total,
            Some(direct) => total
                .iter()
                .zip(direct)
                .map(|(b, d)| (*b - *d).max(Vec3::ZERO))
                .collect(),
        })
    }

    /// Which elements are invalid at the current poses.
    pub fn validity(&self) -> &Validity {
        &self.validity
    }

    /// Re-tests validity near the objects flagged in `moving` after the
    /// poses changed from `old` to the current ones, and uploads the
    /// elements whose state changed.
    pub(super) fn update_validity(&mut self, old: &[Pose], moving: &[bool]) {
        let objects: Vec<u32> = (0..moving.len() as u32)
            .filter(|&o| moving[o as usize])
            .collect();
        if objects.is_empty() {
            return;
        }
        let before = self.validity.clone();
        // A texel's reach: the coarsest texel spacing of the scene.
        let margin = 1.0
            / self
                .scene
                .patches
                .iter()
                .map(|p| p.texel_density)
                .fold(f32::INFINITY, f32::min);
        let poses = self.poses.clone();
        let near =
            self.validity
                .update_near(&self.scene, &self.atlas, (old, &poses), &objects, margin);
        self.regather.extend(near);
        if self.regather.len() > self.element_count as usize {
            // Moves that never complete must not grow the list.
            self.regather.sort_unstable();
            self.regather.dedup();
        }
        for i in 0..before.mask().len() {
            let now = self.validity.is_invalid(i);
            if now != before.is_invalid(i) {
                let flag = invalid_flag(now).to_le_bytes();
                // albedo.w of LocalElement (80 bytes) and of Element (64).
                self.queue.write_buffer(
                    &self.buffers.local_elements,
                    i as u64 * std::mem::size_of::<LocalElement>() as u64 + 60,
                    &flag,
                );
                self.queue.write_buffer(
                    &self.buffers.elements,
                    i as u64 * ELEMENT_BYTES + 60,
                    &flag,
                );
            }
        }
    }

    /// Shoots every emitting patch once, in patch order, and remembers what
    /// that delivered (plus the emission itself) as the direct part.
    fn shoot_direct(&mut self, scene: &Scene, poses: &[Pose]) -> Result<(), GpuError> {
        let after = self.selection;
        for (p, patch) in scene.patches.iter().enumerate() {
            let material = &scene.materials[patch.material as usize];
            let scale = poses[patch.object as usize].scale;
            let power = material.emission.element_sum() * patch.shape.area() * scale * scale;
            if power <= 0.0 {
                continue;
            }
            self.selection = Selection {
                patch_id: p as u32,
                power,
                ..after
            };
            self.batch_once()?;
        }
        // `B` now holds E plus the first bounce of E.
        self.direct = Some(self.total_radiosity()?);
        Ok(())
    }

    /// Radiosity B per element (W/m² per channel), direct light included.
    pub fn total_radiosity(&self) -> Result<Vec<Vec3>, GpuError> {
        Ok(self
            .read_vec4(&self.radiosity)?
            .into_iter()
            .map(|v| Vec3::new(v[0], v[1], v[2]))
            .collect())
    }

    /// Where the power went so far (reads the irradiance back).
    pub fn energy_balance(&self) -> Result<EnergyBalance, GpuError> {
        let h = self.read_vec4(&self.irradiance)?;
        let (received, absorbed) = received_and_absorbed(&h, &self.areas, &self.albedo);
        Ok(EnergyBalance {
            emitted: self.emitted,
            shot: self.shot_power,
            received,
            absorbed,
            unshot: f64::from(self.selection.total.max(0.0)),
        })
    }

    /// Number of shooters for a patch holding `power` (thesis §4.3.3: the
    /// more it shoots, the finer it is split), as a grid over its chart of
    /// at most `capacity` shooters.
    fn shooter_grid(&self, patch: &WorldPatch, power: f64, capacity: u32) -> (u32, u32) {
        let share = if self.emitted > 0.0 {
            (power / self.emitted).clamp(0.0, 1.0)
        } else {
            1.0
        };
        let wanted = ((f64::from(capacity) * share.sqrt()).ceil() as u32).clamp(1, capacity);
        let aspect = (patch.u.length() / patch.v.length().max(1e-12)) as f64;
        let gx = ((f64::from(wanted) * aspect).sqrt().round() as u32).clamp(1, patch.w);
        let gy = (wanted / gx).clamp(1, patch.h);
        (gx, gy)
    }

    /// GENERATESHOOTINGPATCHES (thesis Alg. 4.2): patch `patch_id`, placed
    /// as `patch` (at the current or the old pose, with world element
    /// areas `areas`), split into a `gx` x `gy` grid of shooters.
    ///
    /// Tiles that straddle a contact are then split further, up to `limit`
    /// tiles in all (see [`Self::split_contacts`]).
    fn tile_shooters(
        &self,
        patch_id: u32,
        patch: &WorldPatch,
        areas: &[f32],
        (gx, gy): (u32, u32),
        limit: usize,
    ) -> Vec<GpuShooter> {
        // Tiles split the chart's texels; a tile's region is the union of
        // its elements' regions (cell boundaries halfway between samples).
        // With three or more tiles along an axis, the outermost texel rows
        // and columns (the samples on the patch edges) get tiles of their
        // own: receivers on a neighbouring wall next to the edge take most
        // of their light from the strip along it (the form factor is
        // concentrated near r = 0 there), so that strip must shoot its own
        // unshot radiosity rather than an average with the interior.
        let split = |i: u32, g: u32, n: u32| {
            if g >= 3 && n >= 3 {
                match i {
                    0 => 0,
                    i if i >= g => n,
                    i => 1 + (i - 1) * (n - 2) / (g - 2),
                }
            } else {
                i * n / g
            }
        };
        let mut tiles = Vec::with_capacity((gx * gy) as usize);
        for j in 0..gy {
            for i in 0..gx {
                let (a0, a1) = (split(i, gx, patch.w), split(i + 1, gx, patch.w));
                let (b0, b1) = (split(j, gy, patch.h), split(j + 1, gy, patch.h));
                tiles.push([a0, b0, a1, b1]);
            }
        }
        self.split_contacts(patch, &mut tiles, limit);
        tiles
            .into_iter()
            .map(|t| self.shooter(patch_id, patch, areas, t))
            .collect()
    }

    /// Halves tiles that hold both valid and invalid elements (a floor
    /// tile reaching under a block, a ceiling tile reaching over a lamp
    /// hung below it), the largest first, along its longer side, until none
    /// is left or there are `limit` tiles (thesis §4.3.3 splits shooters by
    /// power only).
    ///
    /// Such a tile shoots the average of its elements from one hemicube:
    /// whatever the block hides from that eye is lost for the whole tile,
    /// although the tile's elements beside the block see it, and its
    /// rectangle includes the part under the block that holds no light.
    /// Measured on cornell-blocks x0.5 closed by a front wall (release,
    /// `examples/accuracy_by_surface`): a shot delivered 98.3% of its power
    /// with the power-only split, 99.3% with at most twice the tiles split
    /// here, 99.7% with every patch shot from 128 tiles (ten times the
    /// time). NRMSE against the reference at x0.5 with at most 1, 1.5, 2
    /// and 3 times the tiles: cornell-blocks 5.22%, 3.85%, 3.70%, 3.54%;
    /// cornell-large 3.32%, 1.83%, 1.75%, 1.73%; cornell-low 3.44%,
    /// 2.20%, 2.18%, 2.17%; hence [`contact_limit`]'s 1.5.
    fn split_contacts(&self, patch: &WorldPatch, tiles: &mut Vec<[u32; 4]>, limit: usize) {
        let size = |t: &[u32; 4]| (t[2] - t[0]) * (t[3] - t[1]);
        let mixed = |t: &[u32; 4]| {
            let (mut valid, mut invalid) = (false, false);
            for b in t[1]..t[3] {
                for a in t[0]..t[2] {
                    if self
                        .validity
                        .is_invalid((patch.first + b * patch.w + a) as usize)
                    {
                        invalid = true;
                    } else {
                        valid = true;
                    }
                }
            }
            valid && invalid
        };
        while tiles.len() < limit {
            let Some(k) = (0..tiles.len())
                .filter(|&k| size(&tiles[k]) > 1 && mixed(&tiles[k]))
                .max_by_key(|&k| (size(&tiles[k]), std::cmp::Reverse(k)))
            else {
                break;
            };
            let [a0, b0, a1, b1] = tiles[k];
            if a1 - a0 >= b1 - b0 {
                let m = (a0 + a1) / 2;
                tiles[k] = [a0, b0, m, b1];
                tiles.push([m, b0, a1, b1]);
            } else {
                let m = (b0 + b1) / 2;
                tiles[k] = [a0, b0, a1, m];
                tiles.push([a0, m, a1, b1]);
            }
        }
    }

    /// The shooter covering chart texels `[a0, a1) x [b0, b1)` of a patch.
    fn shooter(
        &self,
        patch_id: u32,
        patch: &WorldPatch,
        areas: &[f32],
        [a0, b0, a1, b1]: [u32; 4],
    ) -> GpuShooter {
        let param = |a: u32, n: u32| ((a as f32 - 0.5) / (n.max(2) - 1) as f32).clamp(0.0, 1.0);
        let normal = patch.normal;
        let t1 = patch.u.normalize();
        let t2 = normal.cross(t1);
        let (s0, s1) = (param(a0, patch.w), param(a1, patch.w));
        let (u0, u1) = (param(b0, patch.h), param(b1, patch.h));
        let corner = patch.origin + patch.u * s0 + patch.v * u0;
        let su = patch.u * (s1 - s0);
        let sv = patch.v * (u1 - u0);
        let mut area = 0.0;
        // The hemicube eye sits over the area-weighted centroid of the
        // tile's valid elements, not over the tile's centre: a floor tile
        // that straddles a block's footprint must see the room from the
        // part of it that is in the room, or it shoots its whole power into
        // the inside of the block (a 10 x 10 texel tile half under a block
        // lost all of its shot).
        let (mut valid_area, mut centroid) = (0.0f32, Vec3::ZERO);
        for b in b0..b1 {
            for a in a0..a1 {
                let e = (patch.first + b * patch.w + a) as usize;
                area += areas[e];
                if !self.validity.is_invalid(e) {
                    let [es, et] = self.atlas.elements[e].st;
                    valid_area += areas[e];
                    centroid += (patch.origin + patch.u * es + patch.v * et) * areas[e];
                }
            }
        }
        let base = if valid_area > 0.0 {
            centroid / valid_area
        } else {
            // A tile wholly under geometry (split off at a contact) still
            // shoots what its elements hold: redistribution leaves unshot
            // radiosity, positive or negative, on texels a moved object
            // then covers. From an eye under the block all of it would be
            // lost (incremental on indirect-light read 20% NRMSE instead
            // of 4%), so it looks from the valid element of its patch
            // nearest to the tile's centre, as a tile that reached it did
            // before it was split.
            let centre = [(a0 + a1) as f32 * 0.5, (b0 + b1) as f32 * 0.5];
            (0..patch.w * patch.h)
                .filter(|&k| !self.validity.is_invalid((patch.first + k) as usize))
                .min_by(|&k, &l| {
                    let d = |k: u32| {
                        let (a, b) = ((k % patch.w) as f32 + 0.5, (k / patch.w) as f32 + 0.5);
                        (a - centre[0]).powi(2) + (b - centre[1]).powi(2)
                    };
                    d(k).total_cmp(&d(l))
                })
                .map_or(corner + (su + sv) * 0.5, |k| {
                    let [es, et] = self.atlas.elements[(patch.first + k) as usize].st;
                    patch.origin + patch.u * es + patch.v * et
                })
        };
        let eye = base + normal * (self.near * 2.0);
        GpuShooter {
            corner: v4(corner, area),
            su: v4(su, 0.0),
            sv: v4(sv, 0.0),
            eye: v4(eye, 0.0),
            t1: v4(t1, 0.0),
            t2: v4(t2, 0.0),
            n: v4(normal, f32::from_bits(patch_id)),
            tile: [a0, b0, a1, b1],
        }
    }

    /// The batch constants for `count` shooters of `patch_id`.
    fn batch_uniform(
        &self,
        patch_id: u32,
        count: u32,
        old_from_slot: u32,
        mode: u32,
    ) -> BatchUniform {
        let patch = self.patches.get(patch_id as usize);
        BatchUniform {
            patch_id,
            shooters: count,
            resolution: self.options.hemicube_resolution.max(1),
            first_element: patch.map_or(0, |p| p.first),
            chart_w: patch.map_or(0, |p| p.w),
            element_count: self.element_count,
            near: self.near,
            far: self.far,
            subdivision: self.options.subdivision,
            max_subdivision: self.options.max_subdivision.max(1),
            old_from_slot,
            mode,
        }
    }

    /// Rasterizes hemicube slots `0..slots` of the bound shooters into
    /// `target` (thesis §4.3.2: one large target, a viewport per face per
    /// shooter, all in one render pass).
    #[allow(clippy::too_many_arguments)]
    fn encode_hemicubes(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        (pipeline, group): (&wgpu::RenderPipeline, &wgpu::BindGroup),
        target: &wgpu::TextureView,
        resolve: Option<&wgpu::TextureView>,
        depth: &wgpu::TextureView,
        clear: wgpu::Color,
        res: u32,
        slots: u32,
    ) {
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("hemicubes"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: target,
                depth_slice: None,
                resolve_target: resolve,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Clear(clear),
                    store: if resolve.is_some() {
                        wgpu::StoreOp::Discard
                    } else {
                        wgpu::StoreOp::Store
                    },
                },
            })],
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: depth,
                depth_ops: Some(wgpu::Operations {
                    load: wgpu::LoadOp::Clear(1.0),
                    store: wgpu::StoreOp::Discard,
                }),
                stencil_ops: None,
            }),
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, group, &[]);
        for slot in 0..slots {
            for face in 0..FACES {
                let (x, y) = (face * res, slot * res);
                pass.set_viewport(x as f32, y as f32, res as f32, res as f32, 0.0, 1.0);
                pass.set_scissor_rect(x, y, res, res);
                let instance = slot * FACES + face;
                pass.draw(0..self.triangle_vertices, instance..instance + 1);
            }
        }
    }

    /// Item buffers for slots `0..slots` (cleared to "no patch").
    fn encode_item_buffers(&self, encoder: &mut wgpu::CommandEncoder, slots: u32) {
        self.encode_hemicubes(
            encoder,
            (&self.hemicube.0, &self.hemicube.1),
            &self.item_view,
            None,
            &self.depth_view,
            wgpu::Color {
                r: f64::from(NO_PATCH),
                g: 0.0,
                b: 0.0,
                a: 0.0,
            },
            self.options.hemicube_resolution.max(1),
            slots,
        );
    }

    /// A compute pass of one pipeline.
    fn encode_compute(
        encoder: &mut wgpu::CommandEncoder,
        (pipeline, group): &(wgpu::ComputePipeline, wgpu::BindGroup),
        workgroups: u32,
    ) {
        let mut pass = encoder.begin_compute_pass(&Default::default());
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, group, &[]);
        pass.dispatch_workgroups(workgroups.max(1), 1, 1);
    }

    /// One SHOOTINGITERATION (thesis Alg. 4.2). Returns false when there
    /// was nothing to shoot.
    fn batch_once(&mut self) -> Result<bool, GpuError> {
        let sel = self.selection;
        if sel.patch_id as usize >= self.patches.len() || sel.power <= 0.0 {
            return Ok(false);
        }
        let patch = self.patches[sel.patch_id as usize];
        let grid = self.shooter_grid(&patch, f64::from(sel.power), self.batch_capacity);
        let limit = if self.options.split_contacts {
            contact_limit(grid, self.batch_capacity)
        } else {
            (grid.0 * grid.1) as usize
        };
        let shooters = self.tile_shooters(sel.patch_id, &patch, &self.areas, grid, limit);
        let count = shooters.len() as u32;
        let uniform = self.batch_uniform(sel.patch_id, count, u32::MAX, 0);
        self.queue
            .write_buffer(&self.shooters, 0, bytemuck::cast_slice(&shooters));
        self.queue
            .write_buffer(&self.batch, 0, bytemuck::bytes_of(&uniform));

        let mut encoder = self.device.create_command_encoder(&Default::default());
        Self::encode_compute(&mut encoder, &self.shooter_energy, count);
        self.encode_item_buffers(&mut encoder, count);
        Self::encode_compute(
            &mut encoder,
            &self.reconstruct,
            self.element_count.div_ceil(WORKGROUP),
        );
        self.encode_selection(&mut encoder);
        self.queue.submit([encoder.finish()]);
        self.selection = self.read_selection()?;
        self.shots += u64::from(count);
        self.batches += 1;
        self.shot_power += f64::from(sel.power);
        Ok(true)
    }

    /// Per-patch unshot power and the arg-max reduction, then a copy of the
    /// 16-byte answer for the CPU (gems §39.2.3).
    fn encode_selection(&self, encoder: &mut wgpu::CommandEncoder) {
        {
            let mut pass = encoder.begin_compute_pass(&Default::default());
            pass.set_pipeline(&self.patch_power.0);
            pass.set_bind_group(0, &self.patch_power.1, &[]);
            pass.dispatch_workgroups(self.patches.len().max(1) as u32, 1, 1);
            pass.set_pipeline(&self.select.0);
            pass.set_bind_group(0, &self.select.1, &[]);
            pass.dispatch_workgroups(1, 1, 1);
        }
        encoder.copy_buffer_to_buffer(
            &self.selection_buffer,
            0,
            &self.selection_readback,
            0,
            std::mem::size_of::<Selection>() as u64,
        );
    }

    fn read_selection(&self) -> Result<Selection, GpuError> {
        let bytes = map_read(&self.device, &self.selection_readback)?;
        Ok(bytemuck::pod_read_unaligned(&bytes))
    }

    /// Copies a vec4 buffer with one entry per element back to the CPU.
    fn read_vec4(&self, buffer: &wgpu::Buffer) -> Result<Vec<[f32; 4]>, GpuError> {
        read_vec4(&self.device, &self.queue, buffer, self.element_count)
    }
}

/// Copies the first `count` entries of a vec4 buffer (one per element)
/// back to the CPU through a staging buffer.
pub(super) fn read_vec4(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    buffer: &wgpu::Buffer,
    count: u32,
) -> Result<Vec<[f32; 4]>, GpuError> {
    let size = u64::from(count.max(1)) * 16;
    let staging = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("readback"),
        size,
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut encoder = device.create_command_encoder(&Default::default());
    encoder.copy_buffer_to_buffer(buffer, 0, &staging, 0, size);
    queue.submit([encoder.finish()]);
    let bytes = map_read(device, &staging)?;
    let mut values: Vec<[f32; 4]> = bytemuck::pod_collect_to_vec(&bytes);
    values.truncate(count as usize);
    Ok(values)
}

/// Power that arrived at the elements, `Σ A_i H_i`, and the part of it they
/// absorbed, `Σ A_i (1 - ρ_i) H_i` (W, channels summed), from the
/// irradiance `h` read back per element.
pub(super) fn received_and_absorbed(h: &[[f32; 4]], areas: &[f32], albedo: &[Vec3]) -> (f64, f64) {
    let (mut received, mut absorbed) = (0.0f64, 0.0f64);
    for ((hv, a), rho) in h.iter().zip(areas).zip(albedo) {
        let hv = Vec3::new(hv[0], hv[1], hv[2]);
        received += f64::from(*a) * f64::from(hv.element_sum());
        absorbed += f64::from(*a) * f64::from(((Vec3::ONE - *rho) * hv).element_sum());
    }
    (received, absorbed)
}

/// Waits for the GPU and copies a mappable buffer's contents out.
/// Most tiles a grid of `gx` x `gy` shooters may become once the tiles at
/// contacts are split ([`ProgressiveSolver::split_contacts`]): one and a
/// half times the grid, within `capacity`.
pub(super) fn contact_limit((gx, gy): (u32, u32), capacity: u32) -> usize {
    ((3 * gx * gy).div_ceil(2)).min(capacity) as usize
}

/// `albedo.w` of an element: 1 when it is invalid (`is_invalid` in
/// progressive.wgsl: it receives nothing).
fn invalid_flag(invalid: bool) -> f32 {
    if invalid { 1.0 } else { 0.0 }
}

pub(super) fn map_read(device: &wgpu::Device, buffer: &wgpu::Buffer) -> Result<Vec<u8>, GpuError> {
    let (tx, rx) = std::sync::mpsc::channel();
    buffer.map_async(wgpu::MapMode::Read, .., move |result| {
        // The receiver outlives the poll below; a send error cannot happen.
        let _ = tx.send(result);
    });
    device
        .poll(wgpu::PollType::wait_indefinitely())
        .map_err(|e| GpuError::Readback(e.to_string()))?;
    rx.recv()
        .map_err(|e| GpuError::Readback(e.to_string()))?
        .map_err(|e| GpuError::Readback(e.to_string()))?;
    let bytes = buffer
        .get_mapped_range(..)
        .map_err(|e| GpuError::Readback(e.to_string()))?
        .to_vec();
    buffer.unmap();
    Ok(bytes)
}
