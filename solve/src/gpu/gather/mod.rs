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
//!
//! The solver in parts:
//!
//! - this file: the options, the solver's state, its public interface and
//!   its passes;
//! - `resources.rs`: the records shared with `gather.wgsl`, what they
//!   start with, and the buffers, targets and pipelines;
//! - `tile.rs`: one element's hemicube tile (the target's layout, the face
//!   viewports, the delta form factors).

use std::time::{Duration, Instant};

use glam::Vec3;

use super::buffers::{map_read, non_empty, read_vec4, received_and_absorbed, v4};
use super::device::{Device, GpuError};
use super::hemicube::FACES;
use super::placement::{self, PatchTable, SURFACE_OFFSET, world_areas};
use crate::validity::Validity;
use lightwire_scene::atlas::Atlas;
use lightwire_scene::{Pose, Scene};

mod resources;
mod tile;

#[cfg(test)]
pub(super) use resources::{ALL_PASSES, GatherVertex};
use resources::{
    GatherBuffers, GatherPipelines, Upload, gather_elements, receivers, targets, world_triangles,
};
pub(super) use resources::{GatherElement, GatherParams};
use tile::{TileLayout, delta_form_factors, face_viewport};

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
    /// `Σ A_i E_i`, and the power the lights and the sky deliver onto the
    /// elements (`Σ A_i D_i`, their direct light).
    pub emitted: f64,
    /// The lights' and the sky's part of `emitted`.
    pub lights: f64,
    /// Power that arrived at elements: `Σ A_i H_i`.
    pub received: f64,
    /// Power absorbed by elements: `Σ A_i (1 - ρ_i) H_i`. At convergence
    /// `emitted - absorbed` is the power that escaped the scene.
    pub absorbed: f64,
}

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
    /// `Σ A D` and `Σ A (1 − ρ) D` of the lights' direct light
    /// (`lights::delivered_power`).
    delivered: (f64, f64),
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
        let TileLayout {
            res,
            capacity,
            columns,
            rows,
        } = TileLayout::new(limits, options.hemicube_resolution, options.batch_elements)?;

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

        let receivers = receivers(&patches, atlas, offset);
        let local_areas: Vec<f32> = atlas.elements.iter().map(|e| e.area).collect();
        let objects: Vec<u32> = atlas.elements.iter().map(|e| e.object).collect();
        let areas = world_areas(&local_areas, &objects, poses);
        let albedo: Vec<Vec3> = atlas.elements.iter().map(|e| e.albedo).collect();
        let emission: Vec<Vec3> = atlas.elements.iter().map(|e| e.emission).collect();
        // The lights' and the sky's direct light, with the emitters' in
        // `D` (issue 59).
        let lit = crate::lights::element_irradiance(
            scene,
            atlas,
            (poses, &[]),
            &(0..n).collect::<Vec<_>>(),
        );
        let emitted = placement::emitted_power(atlas, &areas)
            + crate::lights::reflected_power(atlas, &lit, &areas);
        let delivered = crate::lights::delivered_power(atlas, &lit, &areas);
        let elements = gather_elements((scene, atlas, poses), &receivers, &areas, &lit);
        let vertices = world_triangles(&patches);
        let triangle_vertices = vertices.len() as u32;

        // Buffers may not be empty.
        let buffers = GatherBuffers::new(
            &device,
            &Upload {
                // `B = E` is `R = 0`.
                start: &vec![[0.0f32; 4]; n.max(1)],
                vertices: &non_empty(vertices),
                receivers: &non_empty(receivers),
                elements: &non_empty(elements),
                donors: &non_empty(Validity::compute(scene, atlas, poses).donors(atlas)),
                patch_ranges: &non_empty(table.ranges()),
                multipliers: &delta_form_factors(res),
            },
        );
        let (color_view, depth_view) = targets(&device, (columns * 3 * res, rows * res));
        let pipelines = GatherPipelines::new(&device, &buffers, &color_view);
        let GatherBuffers {
            radiosity,
            irradiance,
            params,
            totals,
            totals_readback,
            ..
        } = buffers;

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
            delivered,
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
            hemicube: pipelines.hemicube,
            hemicube_groups: pipelines.hemicube_groups,
            gather: pipelines.gather,
            gather_groups: pipelines.gather_groups,
            total_change: pipelines.total_change,
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
        // `H` holds the lights' direct light (`GatherElement::direct`):
        // the emitted power counts all of it, not only what is reflected.
        let (onto, taken) = self.delivered;
        Ok(GatherBalance {
            emitted: self.emitted + taken,
            lights: onto,
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
            let color = wgpu::Operations {
                // Pixels that see nothing gather nothing.
                load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                store: wgpu::StoreOp::Store,
            };
            let mut pass = lightwire_adapter::begin_render_pass(
                &mut encoder,
                "gather hemicubes",
                (&self.color_view, None, color),
                (&self.depth_view, lightwire_adapter::REVERSED_DEPTH),
            );
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
