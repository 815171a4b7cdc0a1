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
use super::clusters::{Piece, Unit};
use super::shooters::{GpuShooter, contact_limit};
use crate::gpu::buffers::{WORKGROUP, encode_compute, map_read};
use crate::gpu::device::GpuError;
use crate::gpu::hemicube;

/// Most shooters a patch may be cut into (contact splits included) to join
/// a batch it is not the first of. Sharing pays where a batch's fixed cost
/// outweighs its shooters', which is so for the small patches a mesh has
/// many of (a triangle's chart of 2 x 2 texels is at most four tiles); a
/// large patch shot early alongside another, before it has received that
/// one's light, is shot again later with a coarser grid, which made the
/// quad scenes' progressive solution 0.1-0.5 points less accurate at the
/// same unshot power (BENCHMARKS.md, "shared batches").
const SHARED_TILES: usize = 4;

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
                depth: &self.buffers.depth_view,
                resolution: self.options.hemicube_resolution.max(1),
            },
            slots,
            self.triangle_vertices,
            self.draws,
        );
    }

    /// One SHOOTINGITERATION (thesis Alg. 4.2): the selected patch, and
    /// the next ones by unshot power in the slots it leaves free
    /// ([`Self::shared_patches`]). Returns false when there was nothing to
    /// shoot.
    pub(super) fn batch_once(&mut self) -> Result<bool, GpuError> {
        if !self.clusters.is_empty() {
            return self.shoot_clusters();
        }
        let patches = self.shared_patches();
        self.shoot_patches(&patches)
    }

    /// One batch where the scene's triangles form regions (`clusters.rs`):
    /// the unit (a region, or a patch in none) with the most unshot power,
    /// then, as [`Self::shared_patches`] does for patches, the next units
    /// holding at least `shared_batch_ratio` of its power that take at
    /// most [`SHARED_TILES`] shooters. A region is cut into as many pieces
    /// as its power asks for ([`Tiling::wanted`], the count a quad of that
    /// power is tiled into); a piece of one triangle is tiled as the
    /// triangle alone would be, with what room is left.
    fn shoot_clusters(&mut self) -> Result<bool, GpuError> {
        let mut units = self.clusters.units(&self.powers);
        let order = |a: &(Unit, f32), b: &(Unit, f32)| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0));
        let Some(best) = units.iter().copied().max_by(|a, b| order(b, a)) else {
            return Ok(false);
        };
        if best.1 <= 0.0 {
            return Ok(false);
        }
        let ratio = self.options.shared_batch_ratio;
        let floor = if ratio > 0.0 && ratio <= 1.0 {
            best.1 * ratio
        } else {
            f32::INFINITY
        };
        units.retain(|u| u.0 != best.0 && u.1 >= floor && u.1 > 0.0);
        let room = self.batch_capacity as usize;
        if units.len() > room {
            units.select_nth_unstable_by(room, order);
            units.truncate(room);
        }
        units.sort_by(order);
        units.insert(0, best);

        let tiling = self.tiling();
        let capacity = self.batch_capacity as usize;
        let mut shooters: Vec<GpuShooter> = Vec::with_capacity(capacity);
        let mut shot_power = 0.0;
        let mut first_patch = None;
        for (unit, power) in units {
            let room = capacity - shooters.len();
            if room == 0 {
                break;
            }
            let first = shooters.is_empty();
            let most = if first { room } else { SHARED_TILES.min(room) };
            let pieces = match unit {
                Unit::Patch(id) => vec![Piece::Patch(id, power)],
                Unit::Region(r) => {
                    let wanted = tiling.wanted(f64::from(power), self.batch_capacity) as usize;
                    if wanted > most {
                        continue;
                    }
                    self.clusters.cut(r, wanted, &self.powers)
                }
            };
            let mut spare = most.saturating_sub(pieces.len());
            let mut taken = Vec::new();
            for piece in &pieces {
                match *piece {
                    Piece::Patch(id, w) => {
                        let Some(patch) = self.patches.get(id as usize) else {
                            continue;
                        };
                        // Tiled as it would be alone, its contact splits
                        // included, within the room left.
                        let mut grid = tiling.grid(patch, f64::from(w), self.batch_capacity);
                        let limit = |grid| {
                            if self.options.split_contacts {
                                contact_limit(grid, self.batch_capacity)
                            } else {
                                (grid.0 * grid.1) as usize
                            }
                        };
                        if limit(grid) > spare + 1 {
                            grid = (1, 1);
                        }
                        let limit = limit(grid).min(spare + 1);
                        spare -= limit - 1;
                        taken.extend(tiling.fitted_shooters(id, patch, &self.areas, grid, limit));
                        first_patch.get_or_insert(id);
                    }
                    Piece::Members { start, end, .. } => {
                        let members = self.clusters.members(start, end);
                        taken.push(tiling.cluster_shooter(
                            members,
                            [start, end],
                            &self.patches,
                            &self.areas,
                        ));
                        first_patch.get_or_insert(members[0]);
                    }
                }
            }
            if taken.len() > most {
                continue;
            }
            shooters.extend(taken);
            shot_power += f64::from(power);
        }
        if shooters.is_empty() {
            return Ok(false);
        }
        self.submit_batch(&shooters, first_patch.unwrap_or(0), shot_power)?;
        Ok(true)
    }

    /// The selected patch and its power, then, when batches are shared
    /// ([`super::ProgressiveOptions::shared_batch_ratio`]), every other
    /// patch holding at least that share of its unshot power, the most
    /// powerful first (the lower id on a tie), at most a batch's capacity
    /// of them.
    pub(super) fn shared_patches(&self) -> Vec<(u32, f32)> {
        let sel = self.selection;
        let mut picked = vec![(sel.patch_id, sel.power)];
        let ratio = self.options.shared_batch_ratio;
        if !(ratio > 0.0 && ratio <= 1.0) || sel.power <= 0.0 {
            return picked;
        }
        let floor = sel.power * ratio;
        let mut others: Vec<(u32, f32)> = (0..self.powers.len() as u32)
            .map(|p| (p, self.powers[p as usize]))
            .filter(|&(p, w)| p != sel.patch_id && w >= floor && w > 0.0)
            .collect();
        let order = |a: &(u32, f32), b: &(u32, f32)| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0));
        let room = self.batch_capacity as usize;
        if others.len() > room {
            others.select_nth_unstable_by(room, order);
            others.truncate(room);
        }
        others.sort_by(order);
        picked.extend(others);
        picked
    }

    /// One batch shooting `patches` (id, unshot power), each tiled as it
    /// would be alone in a batch; a further one joins only if it takes at
    /// most [`SHARED_TILES`] shooters and they fit in the slots left.
    /// Returns false when the first has nothing to shoot.
    pub(super) fn shoot_patches(&mut self, patches: &[(u32, f32)]) -> Result<bool, GpuError> {
        let Some(&(first, first_power)) = patches.first() else {
            return Ok(false);
        };
        if first as usize >= self.patches.len() || first_power <= 0.0 {
            return Ok(false);
        }
        let tiling = self.tiling();
        let capacity = self.batch_capacity as usize;
        let mut shooters = Vec::with_capacity(capacity);
        let mut shot_power = 0.0;
        for &(id, power) in patches {
            let room = capacity - shooters.len();
            let Some(patch) = self.patches.get(id as usize) else {
                continue;
            };
            if room == 0 {
                break;
            }
            let grid = tiling.grid(patch, f64::from(power), self.batch_capacity);
            // Each patch is tiled as it would be alone in its batch, its
            // contact splits included: one that might not fit waits.
            let limit = if self.options.split_contacts {
                contact_limit(grid, self.batch_capacity)
            } else {
                (grid.0 * grid.1) as usize
            };
            let first = shooters.is_empty();
            if limit > room || (!first && limit > SHARED_TILES) {
                continue;
            }
            shooters.extend(tiling.fitted_shooters(id, patch, &self.areas, grid, limit));
            shot_power += f64::from(power);
        }
        self.submit_batch(&shooters, first, shot_power)?;
        Ok(true)
    }

    /// Shoots `shooters` in one batch (`first`: the patch whose chart the
    /// batch constants name) and selects anew.
    fn submit_batch(
        &mut self,
        shooters: &[GpuShooter],
        first: u32,
        shot_power: f64,
    ) -> Result<(), GpuError> {
        let count = shooters.len() as u32;
        let uniform = self.batch_uniform(first, count, u32::MAX, 0);
        self.queue
            .write_buffer(&self.buffers.shooters, 0, bytemuck::cast_slice(shooters));
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
        self.refresh_selection()?;
        self.shots += u64::from(count);
        self.batches += 1;
        self.shot_power += shot_power;
        Ok(())
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
        let selection = std::mem::size_of::<Selection>() as u64;
        encoder.copy_buffer_to_buffer(
            &self.buffers.selection,
            0,
            &self.buffers.selection_readback,
            0,
            selection,
        );
        if self.reads_powers() {
            encoder.copy_buffer_to_buffer(
                &self.buffers.patch_power,
                0,
                &self.buffers.selection_readback,
                selection,
                4 * self.patches.len() as u64,
            );
        }
    }

    /// Whether the CPU needs every patch's unshot power: when a batch may
    /// shoot more than one patch, or regions of triangles are chosen by
    /// the sum of theirs.
    fn reads_powers(&self) -> bool {
        let ratio = self.options.shared_batch_ratio;
        (ratio > 0.0 && ratio <= 1.0 && self.patches.len() > 1) || !self.clusters.is_empty()
    }

    /// Reads what [`Self::encode_selection`] copied: the selection, and
    /// the patches' powers when batches are shared.
    pub(super) fn refresh_selection(&mut self) -> Result<(), GpuError> {
        let bytes = map_read(&self.device, &self.buffers.selection_readback)?;
        let selection = std::mem::size_of::<Selection>();
        self.selection = bytemuck::pod_read_unaligned(&bytes[..selection]);
        if self.reads_powers() {
            let powers = &bytes[selection..selection + 4 * self.patches.len()];
            self.powers.clear();
            self.powers.extend(
                powers
                    .chunks_exact(4)
                    .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])),
            );
        }
        Ok(())
    }
}
