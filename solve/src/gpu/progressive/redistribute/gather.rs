//! The light M's texels gather: their direct light, per texel on the CPU
//! as each move starts; the tiles' second gather from the static set once
//! a cross move's batches have run, read between tile centres by the
//! smoothing; and the end of a move.

use super::plan::front_shooters;
use super::resources::DynamicPasses;
use super::{CrossTile, HEMICUBES_ONLY, Move, Redistribution};
use crate::direct::element_direct_light;
use crate::gpu::GpuError;
use crate::gpu::buffers::{WORKGROUP, encode_compute};
use crate::gpu::hemicube;
use crate::gpu::profile::Stage;
use crate::gpu::progressive::ProgressiveSolver;

/// Samples per emitting patch of the moving elements' direct light,
/// `DIRECT_GRID`² (as `progressive/regather.rs`: a shadow ray each, the unoccluded form
/// factor exact whatever the count).
const DIRECT_GRID: usize = 8;

impl ProgressiveSolver {
    /// Ends a move whose batches have all run: M's direct light if no job
    /// wrote it; for cross, the smoothing, the regathering of the static
    /// texels near the move and of the tiles, and the smoothing again;
    /// then M is no longer marked and the next shooter is selected, so
    /// that progressive refinement can continue.
    pub(super) fn end_move(&mut self, mv: &mut Move) -> Result<(), GpuError> {
        if std::mem::take(&mut mv.direct_due) {
            // A move without jobs (nothing of M faces anything).
            self.write_moving_direct(&mv.moving);
        }
        // The shadows M casts from the lights and the sky, before the
        // static texels near it gather again (`lights.rs`).
        self.relight(mv)?;
        let mut encoder = self.device.create_command_encoder(&Default::default());
        if mv.method == Redistribution::Cross && !mv.is_empty_move() {
            // While M is still marked: the tiles' gathered light, read
            // between tile centres, becomes the texels' radiosity. (An
            // empty move, e.g. the removal of no moving objects in a
            // static scene, gathered nothing and may come before any
            // pass was built.)
            self.profile.open(&mut encoder);
            self.encode_smoothing(&mut encoder);
            self.queue.submit([encoder.finish()]);
            encoder = self.device.create_command_encoder(&Default::default());
            // What the static texels near the move now reflect is
            // unshot (before the next shooter is chosen); then the
            // tiles gather again from the static set as it now is,
            // those texels included, and their texels show that.
            let contacts = self.regather(&mv.moving, true)?;
            self.regather_tiles(mv, &mut encoder);
            if let Some(contacts) = contacts {
                // The texels at a contact gather on the CPU while the
                // tiles gather again on the GPU; only the smoothing
                // reads what they gather.
                self.submit_queued(&mut encoder);
                self.gather_contacts(&contacts);
                self.profile.open(&mut encoder);
            }
            self.encode_smoothing(&mut encoder);
            self.queue.submit([encoder.finish()]);
            encoder = self.device.create_command_encoder(&Default::default());
        } else if mv.method == Redistribution::Cross {
            // Without contacts to gather.
            self.regather(&mv.moving, false)?;
        } else {
            // Incremental reshooting reaches them (tests/dynamic.rs).
            self.regather.clear();
        }
        self.write_flags(&[]);
        self.profile.open(&mut encoder);
        self.encode_selection(&mut encoder);
        self.profile.mark(&mut encoder, Stage::Selection);
        self.queue.submit([encoder.finish()]);
        self.profile.sync();
        let readback = self.profile.start();
        self.refresh_selection()?;
        self.profile.stop(readback, Stage::SelectionReadback);
        Ok(())
    }

    /// Whether object `o` is flagged in `moving` and present now.
    fn is_present_moving(&self, moving: &[bool], o: usize) -> bool {
        moving.get(o).copied().unwrap_or(false) && !self.absent[o]
    }

    /// The elements that take part in a move's light of their own: valid,
    /// surface-covering elements of the objects flagged in `moving` that
    /// are present now (their direct light, `write_moving_direct`; their
    /// contacts, `progressive/regather.rs`).
    pub(in crate::gpu::progressive) fn present_moving_elements(
        &self,
        moving: &[bool],
    ) -> Vec<usize> {
        (0..self.element_count as usize)
            .filter(|&i| {
                self.is_present_moving(moving, self.element_objects[i] as usize)
                    && !self.validity.is_invalid(i)
                    && self.atlas.elements[i].covers_surface()
            })
            .collect()
    }

    /// The direct light of every valid element of the objects flagged in
    /// `moving` that are present at the current poses, per element on the
    /// CPU ([`element_direct_light`]), into `moving_direct` (zero for the
    /// rest of their patches). Cross redistribution's tiles gather only
    /// reflected light and add this per texel: a tile's hemicube gave all
    /// its texels the direct light of its centre, and a face under a lamp
    /// read flat where the light falls off towards its edges (the top of
    /// cornell-large's box 4.65-4.9 everywhere against 4.1-5.0).
    pub(super) fn write_moving_direct(&self, moving: &[bool]) {
        let elements = self.present_moving_elements(moving);
        if elements.is_empty() {
            return;
        }
        let light = element_direct_light(
            &self.scene,
            &self.atlas,
            (&self.poses, &self.absent),
            &elements,
            DIRECT_GRID,
        );
        let mut values = vec![[0.0f32; 4]; self.element_count as usize];
        for (&i, h) in elements.iter().zip(light) {
            values[i] = [h.x, h.y, h.z, 0.0];
        }
        let d = self.dynamic.as_ref().expect("built in begin_move");
        for (patch, p) in self.patches.iter().enumerate() {
            if !self.is_present_moving(moving, self.table.objects[patch] as usize) {
                continue;
            }
            let range = p.first as usize..(p.first + p.w * p.h) as usize;
            self.queue.write_buffer(
                &d.moving_direct,
                p.first as u64 * 16,
                bytemuck::cast_slice(&values[range]),
            );
        }
    }

    /// Encodes `smooth_moving` (profiled as smoothing).
    fn encode_smoothing(&self, encoder: &mut wgpu::CommandEncoder) {
        let d = self.dynamic.as_ref().expect("built in begin_move");
        encode_compute(encoder, &d.smooth, self.element_count.div_ceil(WORKGROUP));
        self.profile.mark(encoder, Stage::Smoothing);
    }

    /// Encodes the regathering of a cross move's tiles at their new
    /// positions (`regather_moving` in redistribute.wgsl): front hemicubes
    /// of the static set's total radiosity, as many tiles per pass as the
    /// batch holds. Tiles of objects that are absent now (a removal) have
    /// nothing to gather. Profiled as front hemicubes and tile gather.
    fn regather_tiles(&mut self, mv: &Move, encoder: &mut wgpu::CommandEncoder) {
        let tiles: Vec<CrossTile> = mv
            .tiles
            .iter()
            .filter(|t| !self.absent[self.table.objects[t.patch as usize] as usize])
            .copied()
            .collect();
        let tiling = self.tiling();
        let capacity = self.batch_capacity.max(1) as usize;
        let d = self.dynamic.as_ref().expect("built in begin_move");
        self.profile.open(encoder);
        // Whether a chunk has drawn over the job's hemicubes.
        let mut drawn = false;
        for (c, chunk) in tiles.chunks(capacity).enumerate() {
            let list = front_shooters(&tiling, chunk, &self.patches, &self.areas);
            let n = list.len() as u32;
            let uniform = self.batch_uniform(chunk[0].patch, n, u32::MAX, HEMICUBES_ONLY);
            // Each chunk's shooters and uniform must be in place when its
            // passes run: submit what came before first.
            self.submit_queued(encoder);
            self.upload(&list, uniform);
            if c == 0 {
                // The radiosity does not change between the chunks.
                encode_compute(
                    encoder,
                    &d.shade_total,
                    self.element_count.div_ceil(WORKGROUP),
                );
            }
            // The move's job drew these tiles' hemicubes already (what
            // they see is read per pixel, from the shown texture
            // `shade_total` just wrote).
            if drawn || d.front_ids_of != chunk {
                drawn = true;
                self.encode_gathering_hemicubes(encoder, d, n);
                self.profile.mark(encoder, Stage::FrontHemicubes);
            }
            encode_compute(encoder, &d.regather, n);
            self.profile.mark(encoder, Stage::TileGather);
        }
    }

    /// The moving tiles' gathering hemicubes (element ids, `ELEMENT_IDS`)
    /// for the first `slots` shooters uploaded.
    pub(super) fn encode_gathering_hemicubes(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        d: &DynamicPasses,
        slots: u32,
    ) {
        hemicube::encode(
            encoder,
            (&d.rad_front.0, &d.rad_front.1),
            &hemicube::Target {
                view: &d.front_view,
                depth: &self.buffers.depth_view,
                resolution: self.gather_resolution(),
            },
            slots,
            self.triangle_vertices,
            self.draws,
        );
    }
}
