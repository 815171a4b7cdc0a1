//! Planning a move: the jobs of each method, the shooter grids of
//! incremental redistribution, the tiles of cross redistribution, and
//! which faces of M face nothing.

use super::{CrossTile, Job, Move};
use crate::gpu::GpuError;
use crate::gpu::placement::WorldPatch;
use crate::gpu::progressive::shooters::Tiling;
use crate::gpu::progressive::{GpuShooter, ProgressiveSolver};

impl ProgressiveSolver {
    /// Total power per patch at the current placement (one readback of the
    /// radiosity), which sizes incremental redistribution's shooter grids.
    pub(super) fn patch_power(&self) -> Result<Vec<f64>, GpuError> {
        let mut patch_power = vec![0.0f64; self.patches.len()];
        let radiosity = self.total_radiosity()?;
        for (e, b) in radiosity.iter().enumerate() {
            let p = self.element_patch(e);
            patch_power[p] += f64::from(self.areas[e]) * f64::from(b.abs().element_sum());
        }
        Ok(patch_power)
    }

    /// Incremental: every patch of M present before the move shoots its
    /// negated old shot radiosity, then every patch of C that holds light
    /// shoots, the brightest first. Patches are cut into as many shooters
    /// as a progressive batch gives them (a static patch's hemicubes, two
    /// per shooter, then take more than one batch when they do not fit).
    pub(super) fn plan_incremental(&self, mv: &mut Move, patch_power: &[f64]) {
        let full = self.batch_capacity;
        let in_m = |p: usize| mv.moving[self.table.objects[p] as usize];
        for (p, power) in patch_power.iter().enumerate() {
            if in_m(p) && !mv.old_absent[self.table.objects[p] as usize] {
                mv.jobs.push_back(Job::Negative {
                    patch: p as u32,
                    shooters: self.grid_count(p, *power, full),
                });
            }
        }
        let mut statics: Vec<usize> = (0..self.patches.len())
            .filter(|&p| !in_m(p) && patch_power[p] > 0.0)
            .collect();
        statics.sort_by(|a, b| patch_power[*b].total_cmp(&patch_power[*a]));
        for p in statics {
            mv.jobs.push_back(Job::Static {
                patch: p as u32,
                shooters: self.grid_count(p, patch_power[p], full),
                from: 0,
            });
        }
    }

    /// Cross: the tiles of every patch of M (`cut_tiles`), and jobs of as
    /// many tiles of one object as a batch holds, two or four hemicubes
    /// per tile (`cross_slots`).
    pub(super) fn plan_cross(&self, mv: &mut Move) {
        let old_patches = self.table.place(&mv.old_poses);
        for p in 0..self.patches.len() {
            if !mv.moving[self.table.objects[p] as usize]
                || self.faces_nothing_anywhere(mv, p, &old_patches)
            {
                continue;
            }
            self.cut_tiles(p, &mut mv.tiles);
        }
        // A job's tiles belong to one object: presence (whether the
        // old and the new position exist) is a per-batch flag.
        let object = |t: &CrossTile| self.table.objects[t.patch as usize];
        mv.tiles.sort_by_key(|t| object(t));
        let mut first = 0;
        while (first as usize) < mv.tiles.len() {
            let o = object(&mv.tiles[first as usize]);
            let per_job = (self.batch_capacity / self.cross_slots(o as usize)).max(1);
            let count = mv.tiles[first as usize..]
                .iter()
                .take(per_job as usize)
                .take_while(|t| object(t) == o)
                .count() as u32;
            mv.jobs.push_back(Job::Cross { first, count });
            first += count;
        }
    }

    /// Whether patch `p` of M is a closed object's face with no receiver
    /// in front of it wherever it is (a box's bottom on the floor), before
    /// the move (the patches placed as `old_patches`) and after it: it
    /// gathers, shoots and shadows nothing, and gets no tiles.
    fn faces_nothing_anywhere(&self, mv: &Move, p: usize, old_patches: &[WorldPatch]) -> bool {
        let object = self.table.objects[p] as usize;
        self.cross_slots(object) == 2
            && (mv.old_absent[object] || self.faces_nothing(p, old_patches, &mv.old_absent))
            && (self.absent[object] || self.faces_nothing(p, &self.patches, &self.absent))
    }

    /// Cuts patch `p` into tiles of at most `cross_tile` texels a side and
    /// appends those that stand for some surface to `tiles`.
    fn cut_tiles(&self, p: usize, tiles: &mut Vec<CrossTile>) {
        let side = self.options.cross_tile.max(1);
        let tiling = self.tiling();
        let wp = self.patches[p];
        // At least 2 x 2 tiles where the chart allows: one tile
        // per face is too coarse a shadow caster and receiver.
        let along = |n: u32| n.div_ceil(side).max(n.min(2));
        let (gx, gy) = (along(wp.w), along(wp.h));
        for j in 0..gy {
            for i in 0..gx {
                let texels = [
                    i * wp.w / gx,
                    j * wp.h / gy,
                    (i + 1) * wp.w / gx,
                    (j + 1) * wp.h / gy,
                ];
                // A tile wholly above a triangle's diagonal
                // stands for no surface: it neither gathers
                // nor shoots (`smooth_moving` reads only the
                // tiles that gathered).
                if tiling.covers_surface(&wp, &texels) {
                    tiles.push(CrossTile {
                        patch: p as u32,
                        texels,
                    });
                }
            }
        }
    }

    /// Whether no element receives in front of patch `p`'s plane with the
    /// patches placed as `placed` and the objects flagged in `absent` left
    /// out: `reconstruct_dyn`'s test of a receiver against a front slot
    /// (`dot(x - corner, n) > 0`, `x` the receiving point, nudged off its
    /// surface and towards its patch's centre as `place_elements` does)
    /// then fails for every receiver, the patch's front hemicubes see
    /// nothing, and its texels gather no light, direct or reflected. A
    /// box resting on the floor: the floor's receiving points lie a hair
    /// above its bottom's plane, the walls' above it. Patches wholly
    /// behind the plane are passed over by their corners; those within a
    /// hair of it by their elements.
    fn faces_nothing(&self, p: usize, placed: &[WorldPatch], absent: &[bool]) -> bool {
        let (o, n) = (placed[p].origin, placed[p].normal);
        let hair = 2.0 * self.surface_offset;
        placed.iter().enumerate().all(|(q, wp)| {
            if q == p || absent[self.table.objects[q] as usize] {
                return true;
            }
            let reach = wp
                .corners()
                .iter()
                .map(|c| (*c - o).dot(n))
                .fold(f32::NEG_INFINITY, f32::max);
            if reach > hair {
                return false;
            }
            reach < -hair
                || (wp.first..wp.first + wp.w * wp.h).all(|i| {
                    let e = &self.atlas.elements[i as usize];
                    !e.covers_surface()
                        || (wp.receiving_point(e.st, self.surface_offset) - o).dot(n) <= 0.0
                })
        })
    }

    /// Hemicube slots per tile of object `o` in a cross batch: front and
    /// back at the new and the old position, or the fronts only for a
    /// closed object (see `cross.rs`).
    pub(super) fn cross_slots(&self, o: usize) -> u32 {
        if self.closed.get(o).copied().unwrap_or(false) {
            2
        } else {
            4
        }
    }

    /// Number of shooters for a patch holding `power`, at most `capacity`.
    fn grid_count(&self, patch: usize, power: f64, capacity: u32) -> u32 {
        let (gx, gy) = self.tiling().grid(&self.patches[patch], power, capacity);
        gx * gy
    }

    fn element_patch(&self, element: usize) -> usize {
        // Patches own contiguous element ranges in order.
        self.patches
            .partition_point(|p| p.first as usize <= element)
            .saturating_sub(1)
    }
}

/// One shooter per cross tile at the placement `placed` (areas `areas`);
/// `gather_moving` and `regather_moving` walk the tile's texels by the
/// first element and chart width every shooter carries (`Tiling::shooter`).
pub(super) fn front_shooters(
    tiling: &Tiling<'_>,
    tiles: &[CrossTile],
    placed: &[WorldPatch],
    areas: &[f32],
) -> Vec<GpuShooter> {
    tiles
        .iter()
        .map(|t| tiling.shooter(t.patch, &placed[t.patch as usize], areas, t.texels))
        .collect()
}
