//! GPU gather radiosity (thesis §4.2, Alg. 4.1): slow, simple, a reference
//! that shares the GPU with the progressive solver but not its method.
//!
//! Data flow. [`GatherSolver::new`] places every atlas element at the given
//! poses (the same receiving point as the progressive solver: the texel's
//! sample nudged off its surface and towards its patch centre) and uploads,
//! once: a hemicube frame per element, the patches as world-space
//! triangles, the patch element ranges, `E`, `ρ` and areas, two radiosity
//! buffers (both start at `B = E`, stored as `R = 0`, see below), the delta
//! form factors of one hemicube
//! tile, and the *direct* irradiance `D` of every element from the
//! emitters' emission, integrated on the CPU by next-event estimation
//! (`crate::direct`: a 16 x 16 grid of samples per emitting patch, a
//! shadow ray each). A hemicube of 32² pixels sees a small light as a few
//! pixels and aliases (29% NRMSE on cornell-small's direct light); the
//! hemicubes therefore gather only the reflected light `R = B - E`.
//!
//! The radiosity buffers hold `R`, not `B`: the hemicubes render the buffer
//! value as it is, with no read of the emission per fragment (that read
//! cost about a tenth of a sweep on cornell-large, BENCHMARKS.md). `E` is
//! added back on the CPU wherever `B` is read
//! ([`GatherSolver::total_radiosity`], [`GatherSolver::radiosity`]) and
//! taken off in [`GatherSolver::start_from`]; the change `Σ A_i |ΔB_i|` is
//! the same sum, `E` being constant.
//!
//! A *bounce* is one Jacobi sweep of
//! `B_i = E_i + ρ_i (D_i + Σ_j F_ij (B_j - E_j))`, which is
//! `B_i = E_i + ρ_i Σ_j F_ij B_j` (thesis eq. 2.2.4) with the emitters'
//! term `Σ_j F_ij E_j` integrated apart, run as a few *passes* of up to
//! [`GatherOptions::batch_elements`] elements each. A pass is one
//! submission:
//!
//! 1. For every element of the pass, render the reflected radiosity
//!    `R = B - E` of the scene into its tile of one large `Rgba32Float` target:
//!    the top face and the upper halves of the four side faces of a
//!    hemicube at the element (90° frusta, a viewport per face per element,
//!    like the item buffers of the progressive solver). A pixel shows the
//!    value of the element nearest to it on the seen patch's chart (thesis
//!    §4.1).
//! 2. `gather_main` (one workgroup per element) multiplies each pixel by its
//!    delta form factor (Cohen & Greenberg; thesis §2.2.2: top face
//!    `ΔA / (π (x² + y² + 1)²)`, side faces `y ΔA / (π (x² + y² + 1)²)`,
//!    `ΔA = (2 / res)²`), sums the tile by a parallel reduction, and writes
//!    `R = ρ (D + Σ)` (`B = E + ρ (D + Σ)`) into the other radiosity
//!    buffer.
//!
//! The last pass of a bounce also sums the change `Σ A_i |ΔB_i|` and reads
//! those 16 bytes back: the power the bounce added, as a fraction of the
//! emitted power, is the convergence measure (the analogue of the reference
//! solver's Jacobi residual). Then the two radiosity buffers swap roles.

use std::time::{Duration, Instant};

use bytemuck::{Pod, Zeroable};
use glam::{DVec3, Vec3};
use wgpu::util::DeviceExt;

use super::binding::{Kind, Pass, Resources, Slot};
use super::buffers::{map_read, read_vec4, received_and_absorbed, v4};
use super::device::{Device, GpuError};
use super::hemicube::{FACES, corner_order, render_pipeline};
use super::placement::{self, PatchRange, PatchTable, SURFACE_OFFSET, world_areas};
use super::progressive::GpuShooter;
use super::shaders;
use crate::direct::direct_light;
use crate::validity::Validity;
use lightwire_scene::atlas::Atlas;
use lightwire_scene::{Pose, Scene};

/// Upper bound on the memory of the hemicube target (colour and depth) of
/// one pass; fewer elements are batched at high resolutions.
const TARGET_BYTES: u64 = 64 << 20;

/// Bytes per hemicube pixel: `Rgba32Float` colour and `Depth32Float`.
const PIXEL_BYTES: u64 = 16 + 4;

/// Tuning of [`GatherSolver`].
#[derive(Debug, Clone, Copy)]
pub struct GatherOptions {
    /// Top-face resolution of the hemicubes in pixels (rounded up to an
    /// even number: the side faces are rendered as halves). Unlike the
    /// progressive solver's item buffers, the form factors *are* the pixel
    /// counts here, so this sets the accuracy; 32 is enough for the NRMSE
    /// bound on the Cornell boxes and costs 3 · 32² pixels per element.
    pub hemicube_resolution: u32,
    /// [`GatherSolver::solve`] stops after this many bounces even if the
    /// threshold was not reached.
    pub max_bounces: u32,
    /// Most elements per render pass (one tile each in the target); also
    /// capped by the adapter's texture size and a 64 MiB target.
    pub batch_elements: u32,
    /// Publish indirect light only (gems §39.4), as
    /// [`super::ProgressiveOptions::indirect_only`] defines it:
    /// [`GatherSolver::radiosity`] returns `B - E - D`, where `D` is the
    /// first bounce of the emitted light. Starting from `B = E`, the first
    /// Jacobi bounce gives exactly `E + D`, which is kept.
    pub indirect_only: bool,
}

impl Default for GatherOptions {
    fn default() -> Self {
        Self {
            hemicube_resolution: 32,
            max_bounces: 1000,
            batch_elements: 1024,
            indirect_only: false,
        }
    }
}

/// What a call to [`GatherSolver::step`], `bounce` or `solve` did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GatherReport {
    /// Bounces completed during the call.
    pub bounces: u64,
    /// Hemicubes rendered and integrated (one per element gathered) during
    /// the call.
    pub hemicubes: u64,
    /// Power changed by the last completed bounce, `Σ A_i |ΔB_i|`, as a
    /// fraction of the emitted power (1 before the first bounce).
    pub change_fraction: f64,
}

/// Power bookkeeping of the last completed bounce (W, RGB channels summed).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GatherBalance {
    /// `Σ A_i E_i`.
    pub emitted: f64,
    /// Power that arrived at elements: `Σ A_i H_i`.
    pub received: f64,
    /// Power absorbed by elements: `Σ A_i (1 - ρ_i) H_i`. At convergence
    /// `emitted - absorbed` is the power that escaped the scene.
    pub absorbed: f64,
}

/// One patch corner (`GatherVertex` in gather.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(super) struct GatherVertex {
    pos: [f32; 4],
    normal: [f32; 4],
    st: [f32; 4],
}
const _: () = assert!(std::mem::size_of::<GatherVertex>() == 48);

/// One element's emission, area, albedo and direct irradiance
/// (`GatherElement`).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(super) struct GatherElement {
    emission: [f32; 4],
    albedo: [f32; 4],
    direct: [f32; 4],
}
const _: () = assert!(std::mem::size_of::<GatherElement>() == 48);

/// Constants of one pass (`GatherParams` in gather.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(super) struct GatherParams {
    first: u32,
    count: u32,
    resolution: u32,
    columns: u32,
    element_count: u32,
    near: f32,
    pad: [u32; 2],
}
const _: () = assert!(std::mem::size_of::<GatherParams>() == 32);

/// Delta form factors of one tile, row-major over its `3 res x res`
/// pixels: the top face in columns `0..res`, then the upper halves of the
/// side faces 1, 2 (columns `res..2 res`, rows `0..res/2` and
/// `res/2..res`) and 3, 4 (columns `2 res..3 res`). Normalised to sum to
/// one, so that a closed scene conserves energy exactly (the raw sum
/// exceeds 1 by the discretisation error: 5e-4 at res 32, 1e-4 at 64).
fn delta_form_factors(res: u32) -> Vec<f32> {
    let half = res / 2;
    let da = (2.0 / f64::from(res)).powi(2);
    let centre = |i: u32| (f64::from(i) + 0.5) / f64::from(res) * 2.0 - 1.0;
    let mut values = Vec::with_capacity((3 * res * res) as usize);
    for row in 0..res {
        for col in 0..3 * res {
            let x = centre(col % res);
            let value = if col < res {
                // Top face at distance 1 along the normal, pixel (x, y).
                let y = -centre(row);
                da / (std::f64::consts::PI * (x * x + y * y + 1.0).powi(2))
            } else {
                // Side face: viewport row `row % half` of the upper half;
                // y is the height above the horizon (ndc y, in (0, 1)).
                let y = -centre(row % half);
                y * da / (std::f64::consts::PI * (x * x + y * y + 1.0).powi(2))
            };
            values.push(value);
        }
    }
    let sum: f64 = values.iter().sum();
    values.iter().map(|v| (v / sum) as f32).collect()
}

/// Viewport (x, y, size) and scissor height of face `face` of the tile at
/// `origin`: the side faces' viewports are full faces, scissored to their
/// upper half (below the horizon there is nothing to gather).
fn face_viewport(origin: (u32, u32), face: u32, res: u32) -> (u32, u32, u32) {
    let (x, y) = origin;
    if face == 0 {
        (x, y, res)
    } else {
        let k = face - 1;
        (x + res * (1 + k / 2), y + (k % 2) * (res / 2), res / 2)
    }
}

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
pub(super) const ALL_PASSES: [Pass; 3] = [RADIOSITY_HEMICUBES, GATHER, TOTAL_CHANGE];

/// Gather radiosity on the GPU (thesis Alg. 4.1): every bounce renders a
/// hemicube of the current radiosity at every element.
pub struct GatherSolver {
    device: wgpu::Device,
    queue: wgpu::Queue,
    options: GatherOptions,
    /// Even top-face resolution actually used.
    resolution: u32,
    /// Elements per pass and tiles per target row.
    capacity: u32,
    columns: u32,
    element_count: u32,
    triangle_vertices: u32,
    near: f32,
    emitted: f64,
    areas: Vec<f32>,
    albedo: Vec<Vec3>,
    /// `E` per element: the radiosity buffers hold `B - E`.
    emission: Vec<Vec3>,

    /// Which of `radiosity` holds the last completed bounce.
    current: usize,
    /// First element of the next pass of the running bounce.
    next_element: u32,
    bounces: u64,
    hemicubes: u64,
    change_fraction: f64,
    /// `E + D` per element when publishing indirect light only.
    direct: Option<Vec<Vec3>>,

    /// `R = B - E` per element, ping-pong.
    radiosity: [wgpu::Buffer; 2],
    irradiance: wgpu::Buffer,
    params: wgpu::Buffer,
    totals: wgpu::Buffer,
    totals_readback: wgpu::Buffer,
    color_view: wgpu::TextureView,
    depth_view: wgpu::TextureView,
    /// Renders radiosity hemicubes; bind group `k` reads `radiosity[k]`.
    hemicube: wgpu::RenderPipeline,
    hemicube_groups: [wgpu::BindGroup; 2],
    /// Integrates tiles; bind group `k` reads `radiosity[k]` and writes
    /// the other buffer.
    gather: wgpu::ComputePipeline,
    gather_groups: [wgpu::BindGroup; 2],
    total_change: (wgpu::ComputePipeline, wgpu::BindGroup),
}

impl GatherSolver {
    /// Uploads the scene at `poses` (one per object). Every element starts
    /// with `B = E`; nothing is gathered until the first bounce.
    pub fn new(
        gpu: &Device,
        scene: &Scene,
        atlas: &Atlas,
        poses: &[Pose],
        options: GatherOptions,
    ) -> Result<Self, GpuError> {
        let device = gpu.device.clone();
        let queue = gpu.queue.clone();
        let limits = &gpu.limits;
        let res = options.hemicube_resolution.max(2).div_ceil(2) * 2;
        let max_dim = limits.max_texture_dimension_2d;
        if 3 * res > max_dim {
            return Err(GpuError::TooLarge(format!(
                "a gather hemicube resolution of {res} needs a {} pixel wide tile; the adapter allows {max_dim}",
                3 * res
            )));
        }
        let tile_bytes = 3 * u64::from(res) * u64::from(res) * PIXEL_BYTES;
        let wanted = u64::from(options.batch_elements.max(1))
            .min((TARGET_BYTES / tile_bytes).max(1))
            .min(u64::from(limits.max_compute_workgroups_per_dimension))
            as u32;
        // A roughly square target, within the adapter's texture size.
        let columns = (max_dim / (3 * res))
            .min(((f64::from(wanted) / 3.0).sqrt().ceil() as u32).max(1))
            .max(1);
        let capacity = wanted.min(columns * (max_dim / res));
        let rows = capacity.div_ceil(columns);

        let n = atlas.elements.len();
        if (n as u64) * std::mem::size_of::<GatherElement>() as u64
            > limits.max_storage_buffer_binding_size
        {
            return Err(GpuError::TooLarge(format!(
                "{n} elements do not fit the adapter's storage buffers"
            )));
        }

        let table = PatchTable::new(scene, atlas);
        let patches = table.place(poses);
        let extent = placement::extent(&patches);
        let offset = extent * SURFACE_OFFSET;

        // Receiving points and hemicube frames: the sample nudged towards
        // the patch centre and off the surface by `offset`, exactly as
        // `place_elements` (progressive.wgsl) places the progressive
        // solver's receivers.
        let mut receivers = Vec::with_capacity(n);
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
        let local_areas: Vec<f32> = atlas.elements.iter().map(|e| e.area).collect();
        let objects: Vec<u32> = atlas.elements.iter().map(|e| e.object).collect();
        let areas = world_areas(&local_areas, &objects, poses);
        let albedo: Vec<Vec3> = atlas.elements.iter().map(|e| e.albedo).collect();
        let emission: Vec<Vec3> = atlas.elements.iter().map(|e| e.emission).collect();
        let emitted: f64 = atlas
            .elements
            .iter()
            .zip(&areas)
            .map(|(e, a)| f64::from(*a) * f64::from(e.emission.element_sum()))
            .sum();
        // The direct light of the emission at every receiving point, by
        // next-event estimation (`crate::direct`): the hemicubes gather
        // only the reflected part `B - E` of what they see.
        let points: Vec<(DVec3, DVec3)> = receivers
            .iter()
            .map(|r| {
                let eye = Vec3::new(r.eye[0], r.eye[1], r.eye[2]).as_dvec3();
                (eye, Vec3::new(r.n[0], r.n[1], r.n[2]).as_dvec3())
            })
            .collect();
        let direct = direct_light(scene, atlas, poses, &points);
        let mut elements: Vec<GatherElement> = atlas
            .elements
            .iter()
            .zip(&areas)
            .zip(&direct)
            .map(|((e, a), d)| GatherElement {
                emission: v4(e.emission, *a),
                albedo: v4(e.albedo, 0.0),
                direct: v4(*d, 0.0),
            })
            .collect();
        // `B = E` is `R = 0`.
        let start = vec![[0.0f32; 4]; n.max(1)];

        // World-space triangles: two per quad, one per triangle patch.
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
        let patch_ranges = table.ranges();
        let multipliers = delta_form_factors(res);

        // Buffers may not be empty.
        let triangle_vertices = vertices.len() as u32;
        if vertices.is_empty() {
            vertices.push(GatherVertex::zeroed());
        }
        if receivers.is_empty() {
            receivers.push(GpuShooter::zeroed());
            elements.push(GatherElement::zeroed());
        }
        let mut patch_ranges = patch_ranges;
        if patch_ranges.is_empty() {
            patch_ranges.push(PatchRange::zeroed());
        }

        let storage = wgpu::BufferUsages::STORAGE;
        let init = |label: &str, contents: &[u8], usage: wgpu::BufferUsages| {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents,
                usage,
            })
        };
        let readable = storage | wgpu::BufferUsages::COPY_SRC;
        let radiosity = [
            init(
                "gather radiosity 0",
                bytemuck::cast_slice(&start),
                readable | wgpu::BufferUsages::COPY_DST,
            ),
            init(
                "gather radiosity 1",
                bytemuck::cast_slice(&start),
                readable | wgpu::BufferUsages::COPY_DST,
            ),
        ];
        let irradiance = init(
            "gather irradiance",
            bytemuck::cast_slice(&vec![[0.0f32; 4]; start.len()]),
            readable,
        );
        let change = init(
            "gather change",
            bytemuck::cast_slice(&vec![0.0f32; start.len()]),
            storage,
        );
        let vertex_buffer = init("gather vertices", bytemuck::cast_slice(&vertices), storage);
        let receiver_buffer = init("receivers", bytemuck::cast_slice(&receivers), storage);
        let element_buffer = init("gather elements", bytemuck::cast_slice(&elements), storage);
        // What an invalid texel (under or inside geometry) shows in the
        // hemicubes: its nearest valid neighbour's light
        // (`Validity::donors`).
        let mut donors = Validity::compute(scene, atlas, poses).donors(atlas);
        if donors.is_empty() {
            donors.push(0);
        }
        let donor_buffer = init("gather donors", bytemuck::cast_slice(&donors), storage);
        let patch_buffer = init(
            "gather patches",
            bytemuck::cast_slice(&patch_ranges),
            storage,
        );
        let multiplier_buffer = init(
            "delta form factors",
            bytemuck::cast_slice(&multipliers),
            storage,
        );
        let params = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("gather params"),
            size: std::mem::size_of::<GatherParams>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let totals = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("gather totals"),
            size: 16,
            usage: readable,
            mapped_at_creation: false,
        });
        let totals_readback = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("gather totals readback"),
            size: 16,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });

        let size = wgpu::Extent3d {
            width: columns * 3 * res,
            height: rows * res,
            depth_or_array_layers: 1,
        };
        let texture = |label: &str, format: wgpu::TextureFormat, usage: wgpu::TextureUsages| {
            device
                .create_texture(&wgpu::TextureDescriptor {
                    label: Some(label),
                    size,
                    mip_level_count: 1,
                    sample_count: 1,
                    dimension: wgpu::TextureDimension::D2,
                    format,
                    usage,
                    view_formats: &[],
                })
                .create_view(&Default::default())
        };
        let color_view = texture(
            "gather hemicubes",
            wgpu::TextureFormat::Rgba32Float,
            wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
        );
        let depth_view = texture(
            "gather depth",
            wgpu::TextureFormat::Depth32Float,
            wgpu::TextureUsages::RENDER_ATTACHMENT,
        );

        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("gather.wgsl"),
            source: wgpu::ShaderSource::Wgsl(shaders::gather().into()),
        });
        // Bind group `k` reads `radiosity[k]` and writes the other buffer.
        let resources = |k: usize| {
            Resources::new()
                .buffer(slot::VERTICES, &vertex_buffer)
                .buffer(slot::RECEIVERS, &receiver_buffer)
                .buffer(slot::PARAMS, &params)
                .buffer(slot::RADIOSITY, &radiosity[k])
                .buffer(slot::PATCHES, &patch_buffer)
                .buffer(slot::DONORS, &donor_buffer)
                .buffer(slot::UPDATED, &radiosity[1 - k])
                .view(slot::HEMICUBES, &color_view)
                .buffer(slot::MULTIPLIERS, &multiplier_buffer)
                .buffer(slot::ELEMENTS, &element_buffer)
                .buffer(slot::CHANGE, &change)
                .buffer(slot::IRRADIANCE, &irradiance)
                .buffer(slot::TOTALS, &totals)
        };
        let bound = [resources(0), resources(1)];
        // Reversed depth (see gather.wgsl): nearer is greater.
        let hemicube_layout = RADIOSITY_HEMICUBES.layout(&device);
        let hemicube = render_pipeline(
            &device,
            &module,
            &[],
            &RADIOSITY_HEMICUBES,
            &hemicube_layout,
            wgpu::TextureFormat::Rgba32Float,
            1,
            wgpu::CompareFunction::Greater,
        );
        let hemicube_groups = [0, 1]
            .map(|k| RADIOSITY_HEMICUBES.bind(&device, &hemicube_layout, |s| bound[k].get(s)));
        let (gather, gather0) = GATHER.compute(&device, &module, &[], |s| bound[0].get(s));
        let gather1 = GATHER.bind(&device, &gather.get_bind_group_layout(0), |s| {
            bound[1].get(s)
        });
        let total_change = TOTAL_CHANGE.compute(&device, &module, &[], |s| bound[0].get(s));

        Ok(Self {
            device,
            queue,
            options,
            resolution: res,
            capacity,
            columns,
            element_count: n as u32,
            triangle_vertices,
            near: offset * 1e-2,
            emitted,
            areas,
            albedo,
            emission,
            current: 0,
            next_element: 0,
            bounces: 0,
            hemicubes: 0,
            change_fraction: 1.0,
            direct: None,
            radiosity,
            irradiance,
            params,
            totals,
            totals_readback,
            color_view,
            depth_view,
            hemicube,
            hemicube_groups,
            gather,
            gather_groups: [gather0, gather1],
            total_change,
        })
    }

    /// Replaces the radiosity the next bounce gathers from with `b` (one
    /// value per element, atlas order), e.g. a progressive solution to be
    /// refined by gathering. A running bounce starts over.
    ///
    /// # Panics
    /// If `b` does not hold one value per element.
    pub fn start_from(&mut self, b: &[Vec3]) {
        assert_eq!(
            b.len(),
            self.element_count as usize,
            "one value per element"
        );
        let values: Vec<[f32; 4]> = b
            .iter()
            .zip(&self.emission)
            .map(|(b, e)| v4(*b - *e, 0.0))
            .collect();
        if !values.is_empty() {
            self.queue.write_buffer(
                &self.radiosity[self.current],
                0,
                bytemuck::cast_slice(&values),
            );
        }
        self.next_element = 0;
    }

    /// Emitted power `Σ A_e E_e` (W, channels summed).
    pub fn emitted_power(&self) -> f64 {
        self.emitted
    }

    /// The top-face resolution in use (the option rounded up to even).
    pub fn hemicube_resolution(&self) -> u32 {
        self.resolution
    }

    /// Power changed by the last completed bounce as a fraction of the
    /// emitted power (1 before the first bounce).
    pub fn change_fraction(&self) -> f64 {
        self.change_fraction
    }

    /// Bounces completed since the solver was created.
    pub fn total_bounces(&self) -> u64 {
        self.bounces
    }

    /// Hemicubes rendered since the solver was created.
    pub fn total_hemicubes(&self) -> u64 {
        self.hemicubes
    }

    /// Runs passes until `budget` is spent (at least one pass, so that
    /// every call makes progress), stopping early once the bounce limit is
    /// reached. A bounce may end in a later call; [`GatherSolver::radiosity`]
    /// always shows the last completed one.
    pub fn step(&mut self, budget: Duration) -> Result<GatherReport, GpuError> {
        let started = Instant::now();
        let (bounces, hemicubes) = (self.bounces, self.hemicubes);
        while self.bounces < u64::from(self.options.max_bounces) {
            self.pass_once()?;
            if started.elapsed() >= budget {
                break;
            }
        }
        Ok(self.report(bounces, hemicubes))
    }

    /// Completes the running bounce (or runs a whole one).
    pub fn bounce(&mut self) -> Result<GatherReport, GpuError> {
        let (bounces, hemicubes) = (self.bounces, self.hemicubes);
        let target = self.bounces + 1;
        while self.bounces < target {
            self.pass_once()?;
        }
        Ok(self.report(bounces, hemicubes))
    }

    /// Bounces until one changes at most `threshold` of the emitted power,
    /// or [`GatherOptions::max_bounces`] bounces have run.
    pub fn solve(&mut self, threshold: f64) -> Result<GatherReport, GpuError> {
        let (bounces, hemicubes) = (self.bounces, self.hemicubes);
        while self.change_fraction > threshold && self.bounces < u64::from(self.options.max_bounces)
        {
            self.bounce()?;
        }
        Ok(self.report(bounces, hemicubes))
    }

    fn report(&self, bounces: u64, hemicubes: u64) -> GatherReport {
        GatherReport {
            bounces: self.bounces - bounces,
            hemicubes: self.hemicubes - hemicubes,
            change_fraction: self.change_fraction,
        }
    }

    /// Radiosity per element (W/m² per channel) after the last completed
    /// bounce, in atlas element order: `B`, or `B - E - D` with
    /// [`GatherOptions::indirect_only`] (zero before the first bounce).
    pub fn radiosity(&self) -> Result<Vec<Vec3>, GpuError> {
        let total = self.total_radiosity()?;
        if !self.options.indirect_only {
            return Ok(total);
        }
        Ok(match &self.direct {
            None => vec![Vec3::ZERO; total.len()],
            Some(direct) => total
                .iter()
                .zip(direct)
                .map(|(b, d)| (*b - *d).max(Vec3::ZERO))
                .collect(),
        })
    }

    /// Radiosity B per element after the last completed bounce, direct
    /// light included: the buffer's `B - E` plus `E`.
    pub fn total_radiosity(&self) -> Result<Vec<Vec3>, GpuError> {
        Ok(self
            .read_vec4(&self.radiosity[self.current])?
            .into_iter()
            .zip(&self.emission)
            .map(|(r, e)| *e + Vec3::new(r[0], r[1], r[2]))
            .collect())
    }

    /// Where the power gathered by the last completed bounce went (after
    /// [`GatherSolver::step`] stopped mid-bounce, the elements of the
    /// passes already run show the running bounce instead).
    pub fn energy_balance(&self) -> Result<GatherBalance, GpuError> {
        let h = self.read_vec4(&self.irradiance)?;
        let (received, absorbed) = received_and_absorbed(&h, &self.areas, &self.albedo);
        Ok(GatherBalance {
            emitted: self.emitted,
            received,
            absorbed,
        })
    }

    /// One pass: hemicubes for the next batch of elements and their
    /// integration; after the last batch of a bounce, the change reduction,
    /// its readback and the buffer swap.
    fn pass_once(&mut self) -> Result<(), GpuError> {
        let first = self.next_element;
        let count = self.capacity.min(self.element_count - first);
        let last = first + count >= self.element_count;
        let res = self.resolution;
        let params = GatherParams {
            first,
            count,
            resolution: res,
            columns: self.columns,
            element_count: self.element_count,
            near: self.near,
            pad: [0; 2],
        };
        self.queue
            .write_buffer(&self.params, 0, bytemuck::bytes_of(&params));

        let mut encoder = self.device.create_command_encoder(&Default::default());
        {
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("gather hemicubes"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &self.color_view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        // Pixels that see nothing gather nothing.
                        load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &self.depth_view,
                    depth_ops: Some(wgpu::Operations {
                        // Reversed depth: 0 is infinitely far.
                        load: wgpu::LoadOp::Clear(0.0),
                        store: wgpu::StoreOp::Discard,
                    }),
                    stencil_ops: None,
                }),
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_pipeline(&self.hemicube);
            pass.set_bind_group(0, &self.hemicube_groups[self.current], &[]);
            for slot in 0..count {
                let origin = ((slot % self.columns) * 3 * res, (slot / self.columns) * res);
                for face in 0..FACES {
                    let (x, y, rows) = face_viewport(origin, face, res);
                    pass.set_viewport(x as f32, y as f32, res as f32, res as f32, 0.0, 1.0);
                    pass.set_scissor_rect(x, y, res, rows);
                    let instance = slot * FACES + face;
                    pass.draw(0..self.triangle_vertices, instance..instance + 1);
                }
            }
        }
        {
            let mut pass = encoder.begin_compute_pass(&Default::default());
            pass.set_pipeline(&self.gather);
            pass.set_bind_group(0, &self.gather_groups[self.current], &[]);
            pass.dispatch_workgroups(count.max(1), 1, 1);
            if last {
                pass.set_pipeline(&self.total_change.0);
                pass.set_bind_group(0, &self.total_change.1, &[]);
                pass.dispatch_workgroups(1, 1, 1);
            }
        }
        if last {
            encoder.copy_buffer_to_buffer(&self.totals, 0, &self.totals_readback, 0, 16);
        }
        self.queue.submit([encoder.finish()]);
        self.hemicubes += u64::from(count);
        if !last {
            self.next_element = first + count;
            return Ok(());
        }
        let bytes = map_read(&self.device, &self.totals_readback)?;
        let totals: [f32; 4] = bytemuck::pod_read_unaligned(&bytes);
        self.change_fraction = if self.emitted > 0.0 {
            f64::from(totals[0].max(0.0)) / self.emitted
        } else {
            0.0
        };
        self.current = 1 - self.current;
        self.next_element = 0;
        self.bounces += 1;
        if self.options.indirect_only && self.bounces == 1 {
            // `B` now holds E plus the first bounce of E.
            self.direct = Some(self.total_radiosity()?);
        }
        Ok(())
    }

    /// Copies a vec4 buffer with one entry per element back to the CPU.
    fn read_vec4(&self, buffer: &wgpu::Buffer) -> Result<Vec<[f32; 4]>, GpuError> {
        read_vec4(&self.device, &self.queue, buffer, self.element_count)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The delta form factors of a hemicube sum to one (after
    /// normalisation), and before it the discretisation error is small:
    /// the hemicube integrates the cosine-weighted hemisphere.
    #[test]
    fn delta_form_factors_sum_to_one() {
        for res in [8u32, 32, 64] {
            let values = delta_form_factors(res);
            assert_eq!(values.len(), (3 * res * res) as usize);
            let sum: f64 = values.iter().map(|v| f64::from(*v)).sum();
            assert!((sum - 1.0).abs() < 1e-5, "res {res}: {sum}");
            assert!(values.iter().all(|v| *v > 0.0));
        }
    }

    /// Tiles of the side faces do not overlap and cover the tile.
    #[test]
    fn face_viewports_tile_three_res_by_res() {
        let res = 8;
        let mut covered = vec![0u32; (3 * res * res) as usize];
        for face in 0..FACES {
            let (x, y, rows) = face_viewport((0, 0), face, res);
            for r in y..y + rows {
                for c in x..x + res {
                    covered[(r * 3 * res + c) as usize] += 1;
                }
            }
        }
        assert!(covered.iter().all(|c| *c == 1));
    }
}
