//! The batches of cross redistribution radiosity (thesis §3.3, §4.5,
//! Alg. 4.4-4.5): a job's tiles get their hemicubes at the old and the new
//! pose, gather from the static set, and shoot through the cross
//! projection ([`Job::Cross`](super::Job::Cross)).

use std::time::Instant;

use glam::Vec3;

use super::plan::front_shooters;
use super::resources::encode_kept_rows;
use super::{CrossTile, HAS_NEW, HAS_OLD, HEMICUBES_ONLY, KEPT_MARKS, KIND_CROSS, Move, ONE_SIDED};
use crate::gpu::buffers::{WORKGROUP, encode_compute, encode_compute_grid, v4};
use crate::gpu::hemicube::{self, FACES};
use crate::gpu::placement::{WorldPatch, pose_matrices};
use crate::gpu::profile::Stage;
use crate::gpu::progressive::{GpuShooter, ProgressiveSolver};
use lightwire_scene::Pose;

/// The hemicube slots of one cross job and how its batch reads them.
struct CrossBatch<'a> {
    /// The job's tiles, all on one object.
    tiles: &'a [CrossTile],
    /// Tiles in the job.
    count: u32,
    /// Whether the object is present after the move.
    has_new: bool,
    /// Every slot's shooter, the new pose's slots first and the old pose's
    /// from `old_from` on.
    list: Vec<GpuShooter>,
    old_from: u32,
    /// The back hemicubes' shooters, slot by slot.
    through: Vec<GpuShooter>,
    /// The batch's `Batch.mode`.
    mode: u32,
}

/// What a cross job wrote before its passes, that they and the next move
/// read.
struct CrossUpload {
    /// Every object's matrix at the new pose (zero: absent), as the item
    /// buffers see it.
    new_poses: Vec<[[f32; 4]; 4]>,
    /// The back hemicubes' `poses`: the new pose set, then the old one,
    /// the moving objects' matrices zero.
    back_poses: Vec<[[f32; 4]; 4]>,
    /// Whether the old pose's item buffers are the last move's (`Kept`).
    items_kept: bool,
    /// Top-face resolution of the back hemicubes.
    back_res: u32,
}

impl ProgressiveSolver {
    /// Encodes a [`Job::Cross`](super::Job::Cross) batch into `encoder`:
    /// `tiles` of `mv` (of one object) shoot, the old placement and areas
    /// being `old`. With `direct_due`, computes and writes M's direct
    /// light (`write_moving_direct`) before the first pass that reads it.
    /// `setup` is when the job's setup started (profiling).
    pub(super) fn run_cross(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        setup: Option<Instant>,
        mv: &Move,
        tiles: &[CrossTile],
        old: (&[WorldPatch], &[f32]),
        direct_due: bool,
    ) {
        let mut batch = self.cross_batch(mv, tiles, old);
        let keep = self.options.keep_old_pose_hemicubes;
        let up = self.upload_cross(mv, &mut batch, keep);
        self.profile.stop(setup, Stage::JobSetup);
        self.profile.open(encoder);
        let back_kept = self.encode_cross_hemicubes(encoder, &batch, &up, keep);
        self.encode_cross_projection(encoder, mv, &batch, &up, direct_due);
        self.kept_item_jobs += u64::from(up.items_kept);
        self.kept_back_jobs += u64::from(back_kept);
        self.keep_cross_rows(&batch, up, keep);
    }

    /// The slots of a cross batch of `tiles` of `mv`, at the new placement
    /// and at the old one, `old`.
    fn cross_batch<'a>(
        &self,
        mv: &Move,
        tiles: &'a [CrossTile],
        (old_patches, old_areas): (&[WorldPatch], &[f32]),
    ) -> CrossBatch<'a> {
        // All tiles of a job are on one object (see begin_move).
        let object = self.table.objects[tiles[0].patch as usize] as usize;
        let count = tiles.len() as u32;
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
        // goes to zero when the move completes
        // (`progressive/regather.rs`).
        // Its slots are [new front, old front] (ONE_SIDED).
        let slots = self.cross_slots(object);
        let one_sided = slots == 2;
        let mut list = Vec::with_capacity((slots * count) as usize);
        let tiling = self.tiling();
        for (placed, areas) in [
            (&self.patches[..], &self.areas[..]),
            (old_patches, old_areas),
        ] {
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
        CrossBatch {
            tiles,
            count,
            has_new,
            list,
            old_from,
            through,
            mode,
        }
    }

    /// Writes the batch's shooters and uniforms, and the back hemicubes'
    /// shooters, uniform and poses. With `keep`, the old pose's item
    /// buffers are the last move's when they were drawn from the same
    /// shooters and poses (the batch's mode then says so).
    fn upload_cross(&self, mv: &Move, batch: &mut CrossBatch<'_>, keep: bool) -> CrossUpload {
        // The old pose's item buffers and back hemicubes are the last
        // move's new ones when nothing else changed (`Kept`), and so
        // is which of their slots reach each element.
        let new_poses = pose_matrices(&self.poses, &self.absent);
        let old_poses = pose_matrices(&mv.old_poses, &mv.old_absent);
        let d = self.dynamic.as_ref().expect("built in begin_move");
        let items_kept = keep
            && d.kept
                .holds(&batch.list[batch.old_from as usize..], &old_poses);
        if items_kept {
            batch.mode |= KEPT_MARKS;
        }
        let (patch, count, old_from) = (batch.tiles[0].patch, batch.count, batch.old_from);
        self.upload(
            &batch.list,
            self.batch_uniform(patch, count, old_from, batch.mode),
        );
        let mut back_uniform = self.batch_uniform(patch, count, old_from, HEMICUBES_ONLY);
        back_uniform.resolution = self.options.back_resolution.max(1);
        self.queue
            .write_buffer(&d.back_shooters, 0, bytemuck::cast_slice(&batch.through));
        self.queue
            .write_buffer(&d.back_batch, 0, bytemuck::bytes_of(&back_uniform));
        let back_poses = self.back_pose_matrices(mv);
        self.queue
            .write_buffer(&d.back_poses, 0, bytemuck::cast_slice(&back_poses));
        CrossUpload {
            new_poses,
            back_poses,
            items_kept,
            back_res: back_uniform.resolution,
        }
    }

    /// Both pose sets as the back hemicubes see them: every object's
    /// matrix at the new pose, then at the old one, zero for the objects
    /// absent then and for those of M.
    fn back_pose_matrices(&self, mv: &Move) -> Vec<[[f32; 4]; 4]> {
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
        back_poses
    }

    /// Encodes the batch's hemicubes: the item buffers (the old pose's
    /// copied when kept), the shown textures, the tiles' gathering
    /// hemicubes at the new pose, and the back hemicubes (the old pose's
    /// copied when the last move's match). Returns whether the back
    /// hemicubes of the old pose were kept ones.
    fn encode_cross_hemicubes(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        batch: &CrossBatch<'_>,
        up: &CrossUpload,
        keep: bool,
    ) -> bool {
        let d = self.dynamic.as_ref().expect("built in begin_move");
        let (old_from, total) = (batch.old_from, batch.list.len() as u32);
        let res = self.options.hemicube_resolution.max(1);
        encode_kept_rows(
            encoder,
            keep,
            (&d.kept, up.items_kept),
            (&self.buffers.item_view, old_from, total, res),
            |encoder, slots| self.encode_item_buffers(encoder, slots),
        );
        self.profile.mark(encoder, Stage::ItemBuffers);
        // Counted with the front hemicubes (or the back ones).
        encode_compute(
            encoder,
            &d.shade_static,
            self.element_count.div_ceil(WORKGROUP),
        );
        if batch.has_new {
            self.encode_gathering_hemicubes(encoder, d, batch.count);
            self.profile.mark(encoder, Stage::FrontHemicubes);
        }
        let back_res = up.back_res;
        let objects = self.poses.len().max(1);
        let (_, old_back) = up.back_poses.split_at(objects);
        let back_kept = keep
            && d.kept_back
                .holds(&batch.through[old_from as usize..], old_back);
        encode_kept_rows(
            encoder,
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
        self.profile.mark(encoder, Stage::BackHemicubes);
        back_kept
    }

    /// Encodes what the batch does with its hemicubes: the tiles gather
    /// (after M's direct light is written, with `direct_due`), and every
    /// element receives through the cross projection (`reconstruct_dyn`).
    fn encode_cross_projection(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        mv: &Move,
        batch: &CrossBatch<'_>,
        up: &CrossUpload,
        direct_due: bool,
    ) {
        if direct_due {
            // The tiles' gather reads M's direct light: computed
            // on the CPU while the GPU draws the hemicubes queued
            // so far (which do not read it).
            self.submit_queued(encoder);
            let direct = self.profile.start();
            self.write_moving_direct(&mv.moving);
            self.profile.stop(direct, Stage::DirectLight);
            self.profile.open(encoder);
        }
        let d = self.dynamic.as_ref().expect("built in begin_move");
        encode_compute(encoder, &d.gather, batch.count);
        self.profile.mark(encoder, Stage::TileGather);
        // Every slot shaded with the light of now, kept or drawn
        // (counted with the projection: on lavapipe a timestamp
        // right after a pass that writes a storage texture is
        // taken only once the next pass has run).
        let (back_res, total) = (up.back_res, batch.list.len() as u32);
        encode_compute_grid(
            encoder,
            &d.shade_back,
            (
                (FACES * back_res).div_ceil(8),
                (total * back_res).div_ceil(8),
            ),
        );
        encode_compute(
            encoder,
            &d.reconstruct,
            self.element_count.div_ceil(WORKGROUP),
        );
        self.profile.mark(encoder, Stage::CrossProjection);
    }

    /// With `keep`, remembers what the batch's new-pose item buffers and
    /// back hemicubes were drawn from, for the next move (`Kept`); and
    /// which tiles' gathering hemicubes were drawn, for the gather after
    /// the move.
    fn keep_cross_rows(&mut self, batch: &CrossBatch<'_>, up: CrossUpload, keep: bool) {
        let objects = self.poses.len().max(1);
        let (new_back, _) = up.back_poses.split_at(objects);
        let old_from = batch.old_from as usize;
        let d = self.dynamic.as_mut().expect("built in begin_move");
        if keep {
            d.kept.shooters = batch.list[..old_from].to_vec();
            d.kept.poses = up.new_poses;
            d.kept_back.shooters = batch.through[..old_from].to_vec();
            d.kept_back.poses = new_back.to_vec();
        }
        d.front_ids_of.clear();
        if batch.has_new {
            d.front_ids_of.extend_from_slice(batch.tiles);
        }
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
}
