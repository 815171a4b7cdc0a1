//! The batches of incremental radiosity with reshooting (thesis §4.4,
//! Alg. 4.3): a patch of M shoots its negated old shot radiosity from its
//! old position ([`Job::Negative`]), a patch of C shoots with a hemicube
//! at the old and at the new poses ([`Job::Static`]).

use std::time::Instant;

use super::{Job, KIND_NEGATIVE, KIND_STATIC};
use crate::gpu::buffers::{WORKGROUP, encode_compute};
use crate::gpu::placement::WorldPatch;
use crate::gpu::profile::Stage;
use crate::gpu::progressive::ProgressiveSolver;
use crate::gpu::progressive::shooters::contact_limit;

impl ProgressiveSolver {
    /// Encodes a [`Job::Negative`] batch into `encoder`: `patch`, placed at
    /// its old pose as `wp` with the element areas `old_areas` of that
    /// pose, shoots its negated old shot radiosity from about `shooters`
    /// shooters. `setup` is when the job's setup started (profiling).
    pub(super) fn run_negative(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        setup: Option<Instant>,
        (patch, shooters): (u32, u32),
        (wp, old_areas): (&WorldPatch, &[f32]),
    ) {
        let grid = self.shooter_grid_for_count(wp, shooters);
        let list = self
            .tiling()
            .shooters(patch, wp, old_areas, grid, self.job_split_limit(grid));
        let n = list.len() as u32;
        self.upload(&list, self.batch_uniform(patch, n, 0, KIND_NEGATIVE));
        self.encode_incremental_batch(encoder, setup, n, n);
    }

    /// Encodes a [`Job::Static`] batch into `encoder`: of the about
    /// `shooters` shooters of static `patch`, those from `from` on that
    /// fit half the batch shoot, each with a hemicube at the new and at
    /// the old poses. Returns the job of the shooters left, if any.
    pub(super) fn run_static(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        setup: Option<Instant>,
        (patch, shooters, from): (u32, u32, u32),
    ) -> Option<Job> {
        let wp = self.patches[patch as usize];
        let grid = self.shooter_grid_for_count(&wp, shooters);
        let all = self
            .tiling()
            .shooters(patch, &wp, &self.areas, grid, self.job_split_limit(grid));
        let half = (self.batch_capacity / 2) as usize;
        let from = (from as usize).min(all.len());
        let to = (from + half).min(all.len());
        let rest = (to < all.len()).then_some(Job::Static {
            patch,
            shooters,
            from: to as u32,
        });
        let mut list = all[from..to].to_vec();
        let n = list.len() as u32;
        list.extend_from_within(..);
        self.upload(&list, self.batch_uniform(patch, n, n, KIND_STATIC));
        self.encode_incremental_batch(encoder, setup, n, 2 * n);
        rest
    }

    /// The passes of an incremental batch of `shooters` shooters whose
    /// hemicubes take `slots` slots: their energy, their item buffers, and
    /// every element's reconstruction (`reconstruct_dyn`).
    fn encode_incremental_batch(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        setup: Option<Instant>,
        shooters: u32,
        slots: u32,
    ) {
        let d = self.dynamic.as_ref().expect("built in begin_move");
        self.profile.stop(setup, Stage::JobSetup);
        self.profile.open(encoder);
        encode_compute(encoder, &d.energy, shooters);
        self.profile.mark(encoder, Stage::ShooterEnergy);
        self.encode_item_buffers(encoder, slots);
        self.profile.mark(encoder, Stage::ItemBuffers);
        encode_compute(
            encoder,
            &d.reconstruct,
            self.element_count.div_ceil(WORKGROUP),
        );
        self.profile.mark(encoder, Stage::Reconstruct);
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
}
