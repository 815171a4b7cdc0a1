//! GPU progressive refinement radiosity (thesis Alg. 4.2, gems §39.2).
//!
//! One *batch* is one SHOOTINGITERATION of the thesis: the patch with the
//! most unshot power (found by the previous batch's reduction) is split into
//! shooters, every shooter gets a hemicube item buffer, and every element
//! gathers from all shooters at once. Slots the patch leaves free go to
//! small patches next in power (`shoot.rs`), so that a mesh of many small
//! triangles does not pay a batch per triangle. See the module doc of [`crate::gpu`]
//! for the data flow.
//!
//! The solver in parts, one concept per file:
//!
//! - this file: the solver's state and its public interface;
//! - `options.rs`: its tuning;
//! - `resources.rs`: the buffers and targets it keeps, and the slot each is
//!   bound at;
//! - `pipelines.rs`: the compute passes and their bindings by name;
//! - `shooters.rs`: cutting the shooting patch into shooters (§4.3.3);
//! - `shoot.rs`: one batch and the selection of the next patch;
//! - `redistribute/`: following moves (incremental and cross
//!   redistribution, thesis §4.4-4.5), with `redistribute.wgsl`;
//! - `regather.rs`: the texels next to a moved object gather again.

use std::time::{Duration, Instant};

use bytemuck::Zeroable;
use glam::Vec3;

use super::buffers::{WORKGROUP, non_empty, read_vec4, received_and_absorbed, v4};
use super::device::{Device, GpuError};
use super::hemicube::{Draws, FACES, patch_vertices};
use super::placement::{
    self, ELEMENT_BYTES, INVALID_FLAG_OFFSET, LocalElement, PatchTable, WorldPatch, invalid_flag,
    pose_matrices, world_areas,
};
use super::profile::Profiler;
use crate::direct::StaticHits;
use crate::validity::Validity;
use lightwire_scene::atlas::Atlas;
use lightwire_scene::{Pose, Scene};

mod clusters;
mod options;
mod pipelines;
mod redistribute;
mod regather;
mod resources;
mod shoot;
mod shooters;
mod slot;

pub use options::ProgressiveOptions;
#[cfg(test)]
pub(in crate::gpu) use pipelines::{PROGRESSIVE_PASSES, REDISTRIBUTION_PASSES};
pub use redistribute::{Move, Redistribution};
pub(in crate::gpu) use shoot::{BatchUniform, Selection};
pub(in crate::gpu) use shooters::{GpuShooter, MAX_BATCH};

use clusters::Clusters;
use pipelines::Pipelines;
use resources::{Buffers, Upload};
use shooters::Tiling;

/// How far around a moved object, in texels, validity is re-tested and
/// static texels gather again when a cross move completes
/// ([`ProgressiveSolver::update_validity`], `regather.rs`).
const REGATHER_TEXELS: f32 = 2.0;

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
    /// `Σ A_e E_e`, and the power the lights and the sky deliver onto the
    /// elements (`Σ A_e D_e`, their direct light).
    pub emitted: f64,
    /// The lights' and the sky's part of `emitted`.
    pub lights: f64,
    /// Power taken out of the unshot buffers by shots so far.
    pub shot: f64,
    /// Power that arrived at elements: `Σ A_e H_e`.
    pub received: f64,
    /// Power absorbed by elements: `Σ A_e (1 - ρ_e) H_e`.
    pub absorbed: f64,
    /// Power still waiting to be shot.
    pub unshot: f64,
}

/// Progressive refinement radiosity on the GPU: elements, B, B^u and the
/// per-patch unshot power live in GPU buffers for the solver's lifetime;
/// the CPU only places shooters and reads one 16-byte selection per batch
/// (and the patches' powers, when batches are shared).
///
/// Objects can move ([`ProgressiveSolver::begin_move`]): elements are kept
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
    /// How hemicube passes are drawn: every target holds `batch_capacity`
    /// slots.
    draws: Draws,
    /// Workgroups one dispatch may have per dimension (the adapter's limit).
    max_workgroups: u32,
    /// Patches in object space, their objects and their elements.
    table: PatchTable,
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
    /// The regathering rays' hits on the static world, kept between moves
    /// (regather.rs).
    static_hits: StaticHits,
    /// The scene and atlas, to re-test validity after a move.
    scene: Scene,
    atlas: Atlas,
    /// Objects removed from the simulation (thesis §4.5.2).
    absent: Vec<bool>,
    /// Objects that occlude but neither receive nor shoot in progressive
    /// iterations ([`ProgressiveSolver::set_passive`]).
    passive: Vec<bool>,
    /// Dynamic objects whose surface is closed and faces out
    /// ([`Scene::closed_objects`]): cross redistribution gives their tiles
    /// no back hemicubes. Static objects never move, so they are not
    /// tested (a static mesh of 100k triangles would hash 300k edges).
    closed: Vec<bool>,
    /// Element areas at scale 1 and their objects, for shooter areas.
    local_areas: Vec<f32>,
    element_objects: Vec<u32>,
    /// World areas of the elements at the current poses.
    areas: Vec<f32>,
    albedo: Vec<Vec3>,
    element_count: u32,
    emitted: f64,
    /// `Σ A D` and `Σ A (1 − ρ) D` of the lights' direct light
    /// (`lights::delivered_power`).
    delivered: (f64, f64),
    near: f32,
    far: f32,
    /// How far receiving points are moved off their surface and towards
    /// their patch's centre (`placement::local_elements`).
    surface_offset: f32,
    /// Regions of near-coplanar triangles shot together (empty without
    /// [`ProgressiveOptions::cluster_triangles`] or triangles).
    clusters: Clusters,
    /// Latest selection read back: what the next batch shoots.
    selection: Selection,
    /// Every patch's unshot power, read back with the selection when
    /// batches are shared ([`ProgressiveOptions::shared_batch_ratio`]).
    powers: Vec<f32>,
    shots: u64,
    batches: u64,
    shot_power: f64,
    /// `E + D` per element when publishing indirect light only.
    direct: Option<Vec<Vec3>>,

    buffers: Buffers,
    pipelines: Pipelines,
    /// Vertices of the patches' triangles to draw per hemicube face.
    triangle_vertices: u32,
    /// Redistribution passes and targets, built on first use.
    dynamic: Option<redistribute::DynamicPasses>,
    /// Cross jobs that copied their old-pose item buffers, and their
    /// old-pose back hemicubes, from the last move instead of drawing them
    /// (`ProgressiveOptions::keep_old_pose_hemicubes`).
    kept_item_jobs: u64,
    kept_back_jobs: u64,
    /// Whether the scene has triangle patches, whose shooters may be cut
    /// (`pipelines::cut_constants`).
    triangles: bool,
    /// Where redistribution's time goes (disabled unless profiling).
    profile: Profiler,
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
        let res = options.hemicube_resolution.max(1);
        let batch_capacity = batch_capacity(&gpu.limits, &options, atlas.elements.len())?;
        let n = atlas.elements.len();
        let absent: Vec<bool> = (0..poses.len())
            .map(|o| absent.get(o).copied().unwrap_or(false))
            .collect();

        let table = PatchTable::new(scene, atlas);
        let patches = table.place(poses);
        // Scene extent at the given poses, for depth ranges and offsets.
        let extent = placement::extent(&patches);
        let (vertices, triangle_vertices) =
            patch_vertices(&table.shapes, &table.objects, table.maps());

        let validity = Validity::compute(scene, atlas, poses);
        let locals = non_empty(placement::local_elements(
            &table.shapes,
            atlas,
            &validity,
            extent,
        ));
        let local_areas: Vec<f32> = atlas.elements.iter().map(|e| e.area).collect();
        let element_objects: Vec<u32> = atlas.elements.iter().map(|e| e.object).collect();
        let albedo: Vec<Vec3> = atlas.elements.iter().map(|e| e.albedo).collect();
        let emission = non_empty(atlas.elements.iter().map(|e| v4(e.emission, 0.0)).collect());
        let areas = world_areas(&local_areas, &element_objects, poses);
        // The lights' and the sky's direct light, reflected (issue 59):
        // unshot light the elements start with besides their emission. It
        // is reflected light, so the emission buffer (what redistribution
        // resets a moved texel to and leaves out of what tiles gather)
        // keeps only the materials' emission.
        let lit = crate::lights::element_irradiance(
            scene,
            atlas,
            (poses, &absent),
            &(0..n).collect::<Vec<_>>(),
        );
        let emitted = placement::emitted_power(atlas, &areas)
            + crate::lights::reflected_power(atlas, &lit, &areas);
        let delivered = crate::lights::delivered_power(atlas, &lit, &areas);
        let source: Vec<[f32; 4]> = emission
            .iter()
            .enumerate()
            .map(|(i, e)| {
                let own = match (atlas.elements.get(i), lit.get(i)) {
                    (Some(el), Some(d)) => el.albedo * *d,
                    _ => Vec3::ZERO,
                };
                [e[0] + own.x, e[1] + own.y, e[2] + own.z, e[3]]
            })
            .collect();
        let clusters = clusters(scene, &patches, &table, &options);
        let buffers = Buffers::new(
            &device,
            &Upload {
                members: clusters.order(),
                locals: &locals,
                emission: &emission,
                start: &start_radiosity(atlas, &source, &absent, &validity),
                patch_ranges: &table.ranges(),
                patch_frames: &table.frames(),
                vertices: &vertices,
                objects: poses.len(),
                capacity: batch_capacity,
                resolution: res,
            },
        );
        let draws = Draws::choose(&device, batch_capacity, options.one_draw_hemicubes);
        let triangles = scene.patches.iter().any(|p| p.shape.is_triangle());
        let pipelines = Pipelines::new(&device, &buffers, draws, triangles);

        let mut solver = Self {
            device,
            queue,
            options,
            batch_capacity,
            draws,
            max_workgroups: options
                .max_power_workgroups
                .min(gpu.limits.max_compute_workgroups_per_dimension)
                .max(1),
            table,
            patches,
            poses: poses.to_vec(),
            validity,
            regather: Vec::new(),
            static_hits: regather::static_hits(),
            closed: (0..scene.objects.len() as u32)
                .map(|o| scene.objects[o as usize].dynamic && scene.is_closed(o))
                .collect(),
            scene: scene.clone(),
            atlas: atlas.clone(),
            passive: vec![false; absent.len()],
            absent,
            local_areas,
            element_objects,
            areas,
            albedo,
            element_count: n as u32,
            emitted,
            delivered,
            near: extent * 1e-4,
            far: extent * 4.0,
            surface_offset: extent * placement::SURFACE_OFFSET,
            clusters,
            selection: Selection::zeroed(),
            powers: Vec::new(),
            shots: 0,
            batches: 0,
            shot_power: 0.0,
            direct: None,
            buffers,
            pipelines,
            triangle_vertices,
            dynamic: None,
            kept_item_jobs: 0,
            kept_back_jobs: 0,
            triangles,
            profile: Profiler::disabled(),
        };
        solver.start(scene, poses)?;
        Ok(solver)
    }

    /// Places the elements at the solver's poses, finds the first shooting
    /// patch, and with [`ProgressiveOptions::indirect_only`] shoots the
    /// direct light.
    fn start(&mut self, scene: &Scene, poses: &[Pose]) -> Result<(), GpuError> {
        let current = self.poses.clone();
        self.write_poses(&current, &current, &[]);
        self.write_flags(&[]);
        let mut encoder = self.device.create_command_encoder(&Default::default());
        self.encode_place(&mut encoder);
        self.encode_selection(&mut encoder);
        self.queue.submit([encoder.finish()]);
        self.refresh_selection()?;
        if self.options.indirect_only {
            self.shoot_direct(scene, poses)?;
        }
        Ok(())
    }

    /// Writes both pose sets and the object flags: `current` (zero for
    /// absent objects), `old` (zero for objects absent before), and which
    /// objects are `moving`.
    fn write_poses(&self, current: &[Pose], old: &[Pose], old_absent: &[bool]) {
        let objects = current.len().max(1);
        let mut matrices = pose_matrices(current, &self.absent);
        matrices.resize(objects, [[0.0; 4]; 4]);
        matrices.extend(pose_matrices(old, old_absent));
        matrices.resize(objects * 2, [[0.0; 4]; 4]);
        self.queue
            .write_buffer(&self.buffers.poses, 0, bytemuck::cast_slice(&matrices));
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
                if self.passive.get(o).copied().unwrap_or(false) {
                    f |= 4;
                }
                f
            })
            .collect();
        self.queue
            .write_buffer(&self.buffers.flags, 0, bytemuck::cast_slice(&flags));
    }

    /// Makes the objects flagged in `passive` occlude without taking part
    /// in progressive iterations: their elements neither receive nor shoot,
    /// and their unshot radiosity is not counted (`OBJECT_PASSIVE`,
    /// common.wgsl). Cross redistribution lights its moving objects by
    /// each move's gathers and shoots their light in the move; refinement
    /// between moves then shoots the static set's unshot light (what the
    /// last move deposited: the objects' reflection and shadows) with the
    /// objects in place as occluders (`DynamicSolver`). Call between moves.
    pub fn set_passive(&mut self, passive: &[bool]) -> Result<(), GpuError> {
        self.passive = (0..self.absent.len())
            .map(|o| passive.get(o).copied().unwrap_or(false))
            .collect();
        self.write_flags(&[]);
        self.reselect()
    }

    /// Selects the next shooter anew from the current unshot radiosity.
    fn reselect(&mut self) -> Result<(), GpuError> {
        let mut encoder = self.device.create_command_encoder(&Default::default());
        self.encode_selection(&mut encoder);
        self.queue.submit([encoder.finish()]);
        self.refresh_selection()?;
        Ok(())
    }

    /// Places every element at the current poses (`place_elements`).
    fn encode_place(&self, encoder: &mut wgpu::CommandEncoder) {
        let mut pass = encoder.begin_compute_pass(&Default::default());
        pass.set_pipeline(&self.pipelines.place.0);
        pass.set_bind_group(0, &self.pipelines.place.1, &[]);
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

    /// Times redistribution's stages into `profile` (`gpu::profile`).
    pub fn set_profiler(&mut self, profile: Profiler) {
        self.profile = profile;
    }

    /// Whether each hemicube pass is one draw (the device has clip
    /// distances and [`ProgressiveOptions::one_draw_hemicubes`] is on) or a
    /// draw per face.
    pub fn hemicubes_in_one_draw(&self) -> bool {
        matches!(self.draws, Draws::One { .. })
    }

    /// Cross jobs since the solver was created whose old-pose item buffers
    /// were the last move's, copied instead of drawn
    /// ([`ProgressiveOptions::keep_old_pose_hemicubes`]).
    pub fn kept_item_jobs(&self) -> u64 {
        self.kept_item_jobs
    }

    /// Cross jobs since the solver was created whose old-pose back
    /// hemicubes were the last move's, copied instead of drawn.
    pub fn kept_back_jobs(&self) -> u64 {
        self.kept_back_jobs
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

    /// The scene, atlas, poses and absent objects the solver lights, for
    /// gathers on the CPU (`gpu::Correction`'s ray-cast sweep).
    pub(crate) fn world(&self) -> (&Scene, &Atlas, &[Pose], &[bool]) {
        (&self.scene, &self.atlas, &self.poses, &self.absent)
    }

    /// Re-tests validity near the objects flagged in `moving` after the
    /// poses changed from `old` to the current ones, and uploads the
    /// elements whose state changed.
    pub(super) fn update_validity(&mut self, old: &[Pose], moving: &[bool]) -> Vec<usize> {
        let objects: Vec<u32> = (0..moving.len() as u32)
            .filter(|&o| moving[o as usize])
            .collect();
        let mut flipped = Vec::new();
        if objects.is_empty() {
            return flipped;
        }
        let before = self.validity.clone();
        // Two texels' reach (the coarsest texel spacing of the scene):
        // validity changes within one, and the texels next to those are
        // the ones a moved object's shadow and reflected light change
        // most, which cross redistribution's first-order projection gets
        // least right (`regather.rs`; cornell-large x0.35 after the test
        // move, static texels 2.03% off a from-scratch solve with one
        // texel, 1.80% with two, 1.77% with three, 2.24% when all gather:
        // a 256-ray gather is itself about 2% noisy).
        let margin = REGATHER_TEXELS
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
                flipped.push(i);
                let flag = invalid_flag(now).to_le_bytes();
                self.queue.write_buffer(
                    &self.buffers.local_elements,
                    i as u64 * std::mem::size_of::<LocalElement>() as u64 + INVALID_FLAG_OFFSET,
                    &flag,
                );
                self.queue.write_buffer(
                    &self.buffers.elements,
                    i as u64 * ELEMENT_BYTES + INVALID_FLAG_OFFSET,
                    &flag,
                );
            }
        }
        flipped
    }

    /// Shoots every emitting patch once, in patch order, and remembers what
    /// that delivered (plus the emission itself) as the direct part.
    fn shoot_direct(&mut self, scene: &Scene, poses: &[Pose]) -> Result<(), GpuError> {
        for (p, patch) in scene.patches.iter().enumerate() {
            let material = &scene.materials[patch.material as usize];
            let scale = poses[patch.object as usize].scale;
            let power = material.emission.element_sum() * patch.shape.area() * scale * scale;
            if power <= 0.0 {
                continue;
            }
            self.shoot_patches(&[(p as u32, power)])?;
        }
        // `B` now holds E plus the first bounce of E.
        self.direct = Some(self.total_radiosity()?);
        Ok(())
    }

    /// Adds `delta` (one value per element, atlas order) to every valid
    /// element's radiosity and unshot radiosity, and selects the next
    /// shooter anew: refinement then carries the change to the rest of the
    /// scene. Negative values are shot like positive ones (thesis §2.2.5).
    ///
    /// # Panics
    /// If `delta` does not hold one value per element.
    pub fn add_unshot(&mut self, delta: &[Vec3]) -> Result<(), GpuError> {
        assert_eq!(
            delta.len(),
            self.element_count as usize,
            "one value per element"
        );
        let mut b = self.read_vec4(&self.buffers.radiosity)?;
        let mut u = self.read_vec4(&self.buffers.unshot)?;
        for (i, d) in delta.iter().enumerate() {
            if self.validity.is_invalid(i) {
                continue;
            }
            for c in 0..3 {
                b[i][c] += d[c];
                u[i][c] += d[c];
            }
        }
        if !b.is_empty() {
            self.queue
                .write_buffer(&self.buffers.radiosity, 0, bytemuck::cast_slice(&b));
            self.queue
                .write_buffer(&self.buffers.unshot, 0, bytemuck::cast_slice(&u));
        }
        self.reselect()
    }

    /// Adds `delta` (one value per element, atlas order) to the radiosity
    /// the valid elements of the objects flagged in `shown_only` show,
    /// without changing what they shot or will shoot: the addition is kept
    /// apart like the smoothing of a cross move (`smooth_moving`), so the
    /// next move takes back exactly what their tiles shot. For the passive
    /// moving objects of a cross session, whose light is each move's
    /// business: a gathered correction brings what they show to the
    /// gather's accuracy (`gpu::Correction`). Elements of other objects are
    /// left as they are; without a cross move so far (nothing kept apart
    /// yet) nothing changes.
    ///
    /// # Panics
    /// If `delta` does not hold one value per element.
    pub fn add_shown(&mut self, delta: &[Vec3], shown_only: &[bool]) -> Result<(), GpuError> {
        assert_eq!(
            delta.len(),
            self.element_count as usize,
            "one value per element"
        );
        let Some(smoothed) = self.dynamic.as_ref().map(|d| d.smoothed.clone()) else {
            return Ok(());
        };
        let which = |i: usize| {
            !self.validity.is_invalid(i)
                && shown_only
                    .get(self.element_objects[i] as usize)
                    .copied()
                    .unwrap_or(false)
        };
        if !(0..delta.len()).any(|i| which(i) && delta[i] != Vec3::ZERO) {
            return Ok(());
        }
        let mut b = self.read_vec4(&self.buffers.radiosity)?;
        let mut s = self.read_vec4(&smoothed)?;
        for (i, d) in delta.iter().enumerate() {
            if !which(i) {
                continue;
            }
            for c in 0..3 {
                b[i][c] += d[c];
                s[i][c] += d[c];
            }
        }
        self.queue
            .write_buffer(&self.buffers.radiosity, 0, bytemuck::cast_slice(&b));
        self.queue
            .write_buffer(&smoothed, 0, bytemuck::cast_slice(&s));
        Ok(())
    }

    /// Takes `b` (one value per element, atlas order) as the light of
    /// every valid element of the present objects, with nothing left
    /// unshot: as if refinement had converged to it, each patch having
    /// shot all it shows. For a session that starts from a solution
    /// computed otherwise (`gpu::DynamicSolver` on a level starts from the
    /// ray solver's, `crate::rays`); what moves take back later is this
    /// light, as for any converged state (thesis §4.4, §4.5).
    ///
    /// # Panics
    /// If `b` does not hold one value per element.
    pub fn adopt(&mut self, b: &[Vec3]) -> Result<(), GpuError> {
        assert_eq!(
            b.len(),
            self.element_count as usize,
            "one value per element"
        );
        let mut radiosity = self.read_vec4(&self.buffers.radiosity)?;
        let mut unshot = self.read_vec4(&self.buffers.unshot)?;
        for (i, v) in b.iter().enumerate() {
            let object = self.element_objects[i] as usize;
            if self.validity.is_invalid(i) || self.absent.get(object).copied().unwrap_or(false) {
                continue;
            }
            radiosity[i] = [v.x, v.y, v.z, radiosity[i][3]];
            unshot[i] = [0.0, 0.0, 0.0, unshot[i][3]];
        }
        if !radiosity.is_empty() {
            self.queue
                .write_buffer(&self.buffers.radiosity, 0, bytemuck::cast_slice(&radiosity));
            self.queue
                .write_buffer(&self.buffers.unshot, 0, bytemuck::cast_slice(&unshot));
        }
        self.reselect()
    }

    /// Radiosity B per element (W/m² per channel), direct light included.
    pub fn total_radiosity(&self) -> Result<Vec<Vec3>, GpuError> {
        Ok(self
            .read_vec4(&self.buffers.radiosity)?
            .into_iter()
            .map(|v| Vec3::new(v[0], v[1], v[2]))
            .collect())
    }

    /// Where the power went so far (reads the irradiance back).
    pub fn energy_balance(&self) -> Result<EnergyBalance, GpuError> {
        let h = self.read_vec4(&self.buffers.irradiance)?;
        let (received, absorbed) = received_and_absorbed(&h, &self.areas, &self.albedo);
        // The lights' direct light enters as unshot reflected light: what
        // the elements absorbed of it at once was never received.
        let (onto, taken) = self.delivered;
        Ok(EnergyBalance {
            emitted: self.emitted + taken,
            lights: onto,
            shot: self.shot_power,
            received,
            absorbed: absorbed + taken,
            unshot: f64::from(self.selection.total.max(0.0)),
        })
    }

    /// What cutting a patch into shooters needs of the solver.
    fn tiling(&self) -> Tiling<'_> {
        Tiling {
            emitted: self.emitted,
            validity: &self.validity,
            atlas: &self.atlas,
            lift: self.near * 2.0,
        }
    }

    /// Copies a vec4 buffer with one entry per element back to the CPU.
    fn read_vec4(&self, buffer: &wgpu::Buffer) -> Result<Vec<[f32; 4]>, GpuError> {
        read_vec4(&self.device, &self.queue, buffer, self.element_count)
    }
}

/// Shooters per batch the item-buffer target holds with `options` on an
/// adapter of `limits`, once the hemicubes and `n` elements are known to
/// fit those limits at all.
fn batch_capacity(
    limits: &wgpu::Limits,
    options: &ProgressiveOptions,
    n: usize,
) -> Result<u32, GpuError> {
    let res = options.hemicube_resolution.max(1);
    if FACES * res > limits.max_texture_dimension_2d {
        return Err(GpuError::TooLarge(format!(
            "a hemicube resolution of {res} needs a {} pixel wide item buffer; the adapter allows {}",
            FACES * res,
            limits.max_texture_dimension_2d
        )));
    }
    // Redistribution batches render two hemicubes per shooter, so the
    // capacity is even; at most the shaders' uniform array of shooters.
    let batch_capacity = (options
        .max_shooters
        .clamp(2, MAX_BATCH)
        .min(limits.max_texture_dimension_2d / res)
        / 2)
        * 2;
    let element_bytes = n as u64 * std::mem::size_of::<LocalElement>() as u64;
    // Cross redistribution's shown textures hold a texel per element,
    // SHOWN_WIDTH a row.
    let shown_rows = n.div_ceil(redistribute::SHOWN_WIDTH as usize);
    if element_bytes > limits.max_storage_buffer_binding_size
        || n > (limits.max_compute_workgroups_per_dimension as usize) * WORKGROUP as usize
        || shown_rows > limits.max_texture_dimension_2d as usize
    {
        return Err(GpuError::TooLarge(format!(
            "{n} elements do not fit the adapter's storage buffer, dispatch or texture limits"
        )));
    }
    Ok(batch_capacity)
}

/// `B` and `B^u` of every element at the start: its `source`, the
/// emission plus the lights' direct light reflected (padded as the
/// buffers are). Absent objects start dark: they neither hold nor
/// shoot light; so do invalid elements (under or inside geometry at the
/// start poses, [`Validity`]): what an emitter emits inside a wall or under
/// a block reaches no one in the room, and shot from the tile it shares
/// with valid elements it would (a closed level whose every surface emits,
/// `examples/furnace.rs` on the garage, read 27% too bright at its 99th
/// percentile with it).
fn start_radiosity(
    atlas: &Atlas,
    source: &[[f32; 4]],
    absent: &[bool],
    validity: &Validity,
) -> Vec<[f32; 4]> {
    source
        .iter()
        .enumerate()
        .map(|(i, e)| {
            let object = atlas.elements.get(i).map_or(0, |e| e.object as usize);
            if absent.get(object).copied().unwrap_or(false) || validity.is_invalid(i) {
                [0.0; 4]
            } else {
                *e
            }
        })
        .collect()
}

/// The triangle clusters of the patches placed as `patches`, with
/// [`ProgressiveOptions::cluster_triangles`] (else none).
fn clusters(
    scene: &Scene,
    patches: &[WorldPatch],
    table: &PatchTable,
    options: &ProgressiveOptions,
) -> Clusters {
    if options.cluster_triangles {
        let materials: Vec<u32> = scene.patches.iter().map(|p| p.material).collect();
        let mesh: Vec<bool> = scene.patches.iter().map(|p| p.mesh).collect();
        Clusters::build(patches, &table.objects, &materials, &mesh)
    } else {
        Clusters::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every surface of cornell-blocks emitting: the floor's elements under
    /// the blocks start dark (they would shoot from under them), every
    /// other element at its emission, and an absent object's all dark.
    #[test]
    fn elements_under_geometry_start_dark() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../scenes/cornell-blocks.json");
        let mut scene = Scene::load(std::path::Path::new(path)).expect("cornell-blocks loads");
        for m in &mut scene.materials {
            m.emission = Vec3::ONE;
        }
        let atlas = Atlas::build(&scene).expect("fits");
        let poses = scene.initial_poses();
        let validity = Validity::compute(&scene, &atlas, &poses);
        let emission: Vec<[f32; 4]> = atlas.elements.iter().map(|e| v4(e.emission, 0.0)).collect();
        let start = start_radiosity(&atlas, &emission, &[false], &validity);
        let mut dark = 0;
        for (i, e) in atlas.elements.iter().enumerate() {
            if validity.is_invalid(i) {
                assert_eq!(start[i], [0.0; 4], "element {i} is under geometry");
                dark += 1;
            } else {
                assert_eq!(start[i], v4(e.emission, 0.0), "element {i} is in the room");
            }
        }
        assert!(dark > 0, "the blocks stand on the floor");
        let absent = start_radiosity(&atlas, &emission, &[true], &validity);
        assert!(
            absent.iter().all(|b| *b == [0.0; 4]),
            "an absent object is dark"
        );
    }
}
