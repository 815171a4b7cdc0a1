//! One SHOOTINGITERATION (thesis Alg. 4.2) and the selection of the next
//! shooting patch by a reduction on the GPU (gems §39.2.3).
//!
//! A batch writes its shooters and constants, then encodes, in one
//! submission: `shooter_energy` (what each shooter shoots, its tile's
//! unshot radiosity cleared), the item buffers, `reconstruct` (every
//! element gathers from every shooter), and the selection (`patch_power_main`
//! and `select_shooter`), whose 16-byte answer is the only readback: the
//! next batch's patch and the convergence measure.

use bytemuck::{Pod, Zeroable};

use super::ProgressiveSolver;
use super::shooters::contact_limit;
use crate::gpu::buffers::{WORKGROUP, encode_compute, map_read};
use crate::gpu::device::GpuError;
use crate::gpu::hemicube;

/// Per-batch constants (`Batch` in common.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(in crate::gpu) struct BatchUniform {
    pub(super) patch_id: u32,
    pub(super) shooters: u32,
    pub(super) resolution: u32,
    pub(super) first_element: u32,
    pub(super) chart_w: u32,
    pub(super) element_count: u32,
    pub(super) near: f32,
    pub(super) far: f32,
    pub(super) subdivision: f32,
    pub(super) max_subdivision: u32,
    pub(super) old_from_slot: u32,
    pub(super) mode: u32,
}
const _: () = assert!(std::mem::size_of::<BatchUniform>() == 48);

/// The reduction's answer (`Selection` in progressive.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable, Debug)]
pub(in crate::gpu) struct Selection {
    pub(super) patch_id: u32,
    pub(super) power: f32,
    pub(super) total: f32,
    pub(super) _pad: f32,
}
const _: () = assert!(std::mem::size_of::<Selection>() == 16);

impl ProgressiveSolver {
    /// The batch constants for `count` shooters of `patch_id`.
    pub(super) fn batch_uniform(
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

    /// Item buffers for slots `0..slots` (cleared to "no patch").
    pub(super) fn encode_item_buffers(&self, encoder: &mut wgpu::CommandEncoder, slots: u32) {
        let item = &self.pipelines.item_buffers;
        hemicube::encode(
            encoder,
            (&item.0, &item.1),
            &hemicube::Target {
                view: &self.buffers.item_view,
                resolve: None,
                depth: &self.buffers.depth_view,
                resolution: self.options.hemicube_resolution.max(1),
            },
            slots,
            self.triangle_vertices,
            self.draws,
        );
    }

    /// One SHOOTINGITERATION (thesis Alg. 4.2). Returns false when there
    /// was nothing to shoot.
    pub(super) fn batch_once(&mut self) -> Result<bool, GpuError> {
        let sel = self.selection;
        if sel.patch_id as usize >= self.patches.len() || sel.power <= 0.0 {
            return Ok(false);
        }
        let patch = self.patches[sel.patch_id as usize];
        let tiling = self.tiling();
        let grid = tiling.grid(&patch, f64::from(sel.power), self.batch_capacity);
        let limit = if self.options.split_contacts {
            contact_limit(grid, self.batch_capacity)
        } else {
            (grid.0 * grid.1) as usize
        };
        let shooters = tiling.shooters(sel.patch_id, &patch, &self.areas, grid, limit);
        let count = shooters.len() as u32;
        let uniform = self.batch_uniform(sel.patch_id, count, u32::MAX, 0);
        self.queue
            .write_buffer(&self.buffers.shooters, 0, bytemuck::cast_slice(&shooters));
        self.queue
            .write_buffer(&self.buffers.batch, 0, bytemuck::bytes_of(&uniform));

        let mut encoder = self.device.create_command_encoder(&Default::default());
        encode_compute(&mut encoder, &self.pipelines.shooter_energy, count);
        self.encode_item_buffers(&mut encoder, count);
        encode_compute(
            &mut encoder,
            &self.pipelines.reconstruct,
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
    pub(super) fn encode_selection(&self, encoder: &mut wgpu::CommandEncoder) {
        {
            let p = &self.pipelines;
            let mut pass = encoder.begin_compute_pass(&Default::default());
            pass.set_pipeline(&p.patch_power.0);
            pass.set_bind_group(0, &p.patch_power.1, &[]);
            // At most the dispatch limit; `patch_power_main` takes the
            // rest in turns.
            let groups = (self.patches.len() as u32).clamp(1, self.max_workgroups);
            pass.dispatch_workgroups(groups, 1, 1);
            pass.set_pipeline(&p.select.0);
            pass.set_bind_group(0, &p.select.1, &[]);
            pass.dispatch_workgroups(1, 1, 1);
        }
        encoder.copy_buffer_to_buffer(
            &self.buffers.selection,
            0,
            &self.buffers.selection_readback,
            0,
            std::mem::size_of::<Selection>() as u64,
        );
    }

    pub(super) fn read_selection(&self) -> Result<Selection, GpuError> {
        let bytes = map_read(&self.device, &self.buffers.selection_readback)?;
        Ok(bytemuck::pod_read_unaligned(&bytes))
    }
}
