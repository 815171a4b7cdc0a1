//! GENERATESHOOTINGPATCHES (thesis Alg. 4.2, §4.3.3): the patch that
//! shoots next is cut into tiles of its chart's texels, each tile one
//! shooter with its own hemicube.
//!
//! The grid grows with the patch's share of the unshot power; tiles at
//! contacts are split further; each tile's hemicube eye sits over the part
//! of it that is in the room.
//!
//! A triangle's chart is square and its triangle the half `t <= s`
//! (wallner §2 packs per-triangle lightmaps the same way): tiles wholly
//! above the diagonal stand for no surface and do not shoot, and a tile the
//! diagonal crosses is *cut* by it (`Shooter` in common.wgsl), so that its
//! form factors integrate over the part of its rectangle on the triangle.

use bytemuck::{Pod, Zeroable};
use glam::{Vec2, Vec3};

use crate::gpu::buffers::v4;
use crate::gpu::placement::WorldPatch;
use crate::validity::Validity;
use lightwire_scene::atlas::{Atlas, ChartMap};

/// One shooter (`Shooter` in common.wgsl): the region `corner + x su +
/// y sv`, `(x, y) ∈ [0, 1]²`, cut to its part where `cut · (x, y, 1) >= 0`
/// when the cut (`sv[3]`, `t1[3]`, `t2[3]`) is not zero in its first two
/// coefficients.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(in crate::gpu) struct GpuShooter {
    pub(in crate::gpu) corner: [f32; 4],
    pub(in crate::gpu) su: [f32; 4],
    pub(in crate::gpu) sv: [f32; 4],
    pub(in crate::gpu) eye: [f32; 4],
    pub(in crate::gpu) t1: [f32; 4],
    pub(in crate::gpu) t2: [f32; 4],
    pub(in crate::gpu) n: [f32; 4],
    pub(in crate::gpu) tile: [u32; 4],
}
const _: () = assert!(std::mem::size_of::<GpuShooter>() == 128);

/// Most shooters a batch holds (`MAX_BATCH` in common.wgsl, which must
/// match): the shooters are a uniform buffer (`var<uniform>`, a fixed-size
/// array), read by every receiver for every shooter. 128 of 128 bytes is
/// 16 KiB, the smallest uniform binding any adapter allows.
pub(in crate::gpu) const MAX_BATCH: u32 = 128;

/// Size of a buffer holding a batch's shooters as the shaders' uniform
/// array (`array<Shooter, MAX_BATCH>`) wants it: always the whole array.
pub(in crate::gpu) fn uniform_bytes() -> u64 {
    u64::from(MAX_BATCH) * std::mem::size_of::<GpuShooter>() as u64
}

impl GpuShooter {
    /// The coefficients `(a, b, c)` of the cut: the region keeps the points
    /// `x, y` with `a x + b y + c >= 0` (all zero: uncut).
    pub(in crate::gpu) fn cut(&self) -> [f32; 3] {
        [self.sv[3], self.t1[3], self.t2[3]]
    }

    /// The centroid of the region (of its part on the triangle when cut).
    pub(in crate::gpu) fn centre(&self) -> Vec3 {
        let corner = Vec3::from_slice(&self.corner[..3]);
        let su = Vec3::from_slice(&self.su[..3]);
        let sv = Vec3::from_slice(&self.sv[..3]);
        let (_, [x, y]) = cut_cell(self.cut(), [0.0, 0.0], [1.0, 1.0]);
        corner + su * x + sv * y
    }
}

/// The share of the cell `[lo, hi]` of the unit square on the kept side of
/// `cut` (uncut: all of it) and the centroid of that part (the cell's
/// centre when nothing is kept): `cut_cell` in common.wgsl.
pub(in crate::gpu) fn cut_cell(cut: [f32; 3], lo: [f32; 2], hi: [f32; 2]) -> (f32, [f32; 2]) {
    let middle = [(lo[0] + hi[0]) * 0.5, (lo[1] + hi[1]) * 0.5];
    let [a, b, c] = cut.map(f64::from);
    if a == 0.0 && b == 0.0 {
        return (1.0, middle);
    }
    let corners = [
        [lo[0], lo[1]],
        [hi[0], lo[1]],
        [hi[0], hi[1]],
        [lo[0], hi[1]],
    ]
    .map(|p| p.map(f64::from));
    let h = |p: [f64; 2]| a * p[0] + b * p[1] + c;
    let mut kept: Vec<[f64; 2]> = Vec::with_capacity(5);
    for i in 0..4 {
        let (p, q) = (corners[i], corners[(i + 1) % 4]);
        if h(p) >= 0.0 {
            kept.push(p);
        }
        if (h(p) >= 0.0) != (h(q) >= 0.0) {
            let f = h(p) / (h(p) - h(q));
            kept.push([p[0] + (q[0] - p[0]) * f, p[1] + (q[1] - p[1]) * f]);
        }
    }
    let full = f64::from(hi[0] - lo[0]) * f64::from(hi[1] - lo[1]);
    let (mut twice, mut cx, mut cy) = (0.0, 0.0, 0.0);
    for i in 0..kept.len() {
        let (p, q) = (kept[i], kept[(i + 1) % kept.len()]);
        let w = p[0] * q[1] - q[0] * p[1];
        twice += w;
        cx += (p[0] + q[0]) * w;
        cy += (p[1] + q[1]) * w;
    }
    if kept.len() < 3 || full <= 0.0 || twice.abs() <= 1e-12 * full {
        return (0.0, middle);
    }
    (
        (twice.abs() * 0.5 / full) as f32,
        [(cx / (3.0 * twice)) as f32, (cy / (3.0 * twice)) as f32],
    )
}

/// What cutting a patch into shooters needs to know of the solver.
pub(super) struct Tiling<'a> {
    /// Emitted power, the scale of a patch's share.
    pub(super) emitted: f64,
    pub(super) validity: &'a Validity,
    pub(super) atlas: &'a Atlas,
    /// Hemicube eyes are lifted this far off their patch.
    pub(super) lift: f32,
}

impl Tiling<'_> {
    /// Number of shooters for a patch holding `power` (thesis §4.3.3: the
    /// more it shoots, the finer it is split), as a grid over its chart of
    /// at most `capacity` shooters.
    pub(super) fn grid(&self, patch: &WorldPatch, power: f64, capacity: u32) -> (u32, u32) {
        let wanted = self.wanted(power, capacity);
        let aspect = (patch.u.length() / patch.v.length().max(1e-12)) as f64;
        let gx = ((f64::from(wanted) * aspect).sqrt().round() as u32).clamp(1, patch.w);
        let gy = (wanted / gx).clamp(1, patch.h);
        (gx, gy)
    }

    /// How many shooters `power` asks for, at most `capacity`: the
    /// capacity times the square root of its share of the emitted power.
    pub(super) fn wanted(&self, power: f64, capacity: u32) -> u32 {
        let share = if self.emitted > 0.0 {
            (power / self.emitted).clamp(0.0, 1.0)
        } else {
            1.0
        };
        ((f64::from(capacity) * share.sqrt()).ceil() as u32).clamp(1, capacity)
    }

    /// Patch `patch_id`, placed as `patch` (at the current or the old pose,
    /// with world element areas `areas`), split into a `gx` x `gy` grid of
    /// shooters.
    ///
    /// Tiles that straddle a contact are then split further, up to `limit`
    /// tiles in all (see [`Self::split_contacts`]).
    pub(super) fn shooters(
        &self,
        patch_id: u32,
        patch: &WorldPatch,
        areas: &[f32],
        grid: (u32, u32),
        limit: usize,
    ) -> Vec<GpuShooter> {
        self.tiles(patch, grid, limit)
            .into_iter()
            .map(|t| self.shooter(patch_id, patch, areas, t))
            .collect()
    }

    /// As [`Self::shooters`], with each tile that holds both valid and
    /// invalid elements shooting from the rectangle of its valid ones
    /// ([`Self::fitted`]). Progressive refinement's own shots use this;
    /// redistribution's batches average over whole tiles in their shaders
    /// and keep [`Self::shooters`].
    pub(super) fn fitted_shooters(
        &self,
        patch_id: u32,
        patch: &WorldPatch,
        areas: &[f32],
        grid: (u32, u32),
        limit: usize,
    ) -> Vec<GpuShooter> {
        self.tiles(patch, grid, limit)
            .into_iter()
            .map(|t| self.fitted(patch_id, patch, areas, t))
            .collect()
    }

    /// The tiles of [`Self::shooters`]: a `gx` x `gy` grid over the chart,
    /// the tiles at a triangle's diagonal and at contacts split further
    /// within `limit`, those that cover no surface dropped.
    fn tiles(&self, patch: &WorldPatch, (gx, gy): (u32, u32), limit: usize) -> Vec<[u32; 4]> {
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
        tiles.retain(|t| self.covers_surface(patch, t));
        self.split_diagonal(patch, &mut tiles, limit);
        self.split_contacts(patch, &mut tiles, limit);
        tiles.retain(|t| self.covers_surface(patch, t));
        tiles
    }

    /// The shooter of tile `tile`, its region and area those of the
    /// smallest tile holding all of its valid elements when it also holds
    /// invalid ones (a floor tile reaching under a block, a wall tile
    /// reaching into the wall that crosses it): the shader still collects
    /// and clears the unshot radiosity of the whole tile (`tile`), so the
    /// power shot is the same, but it leaves from where the surface is in
    /// the room. Shot from the whole rectangle, the part under the block
    /// sent its share of the tile's average towards the block's sides, from
    /// behind them, where it reached nothing. With this and the texels
    /// under geometry dark (`start_radiosity`), the garage's median point
    /// where a player looks went from 8.9% to 7.2% off the path tracer
    /// (BENCHMARKS.md §9; the dark texels alone: 11.7%).
    pub(super) fn fitted(
        &self,
        patch_id: u32,
        patch: &WorldPatch,
        areas: &[f32],
        tile: [u32; 4],
    ) -> GpuShooter {
        let [a0, b0, a1, b1] = tile;
        let (mut fit, mut invalid) = ([a1, b1, a0, b0], false);
        for b in b0..b1 {
            for a in a0..a1 {
                let e = (patch.first + b * patch.w + a) as usize;
                if !self.atlas.elements[e].covers_surface() {
                    continue;
                }
                if self.validity.is_invalid(e) {
                    invalid = true;
                } else {
                    fit = [
                        fit[0].min(a),
                        fit[1].min(b),
                        fit[2].max(a + 1),
                        fit[3].max(b + 1),
                    ];
                }
            }
        }
        if !invalid || fit[2] <= fit[0] || fit == tile {
            return self.shooter(patch_id, patch, areas, tile);
        }
        GpuShooter {
            tile,
            ..self.shooter(patch_id, patch, areas, fit)
        }
    }

    /// On a triangle, halves the tiles the diagonal crosses, the largest
    /// first, along the longer side, dropping halves wholly above it, until
    /// every such tile is a single diagonal texel or there are `limit`
    /// tiles. This is the diagonal's edge strip: like the strips along the
    /// chart's sides (see [`Self::shooters`]), the texels along an edge
    /// shoot their own radiosity from a region beside it, which receivers
    /// just across the edge (on a mesh, every edge may be a crease) take
    /// most of their light from.
    fn split_diagonal(&self, patch: &WorldPatch, tiles: &mut Vec<[u32; 4]>, limit: usize) {
        if !patch.triangle && patch.lightmap.is_none() {
            return;
        }
        // On its own chart, a texel of the tile lies above the diagonal
        // (b > a); on a mesh's own lightmap, an edge of the triangle (or of
        // the parallelogram) crosses the tile (`atlas/uv.rs`).
        let crossed = |t: &[u32; 4]| match patch.lightmap {
            Some(map) => !lightmap_edges(&map, patch.triangle, *t).is_empty(),
            None => t[3] - 1 > t[0],
        };
        while tiles.len() < limit {
            let Some(k) = largest(tiles, crossed) else {
                break;
            };
            let halves = halves(tiles[k]);
            tiles.swap_remove(k);
            tiles.extend(halves.into_iter().filter(|t| self.covers_surface(patch, t)));
        }
    }

    /// Whether any texel of the tile stands for surface: false only for a
    /// tile of a triangle's chart wholly above its diagonal, which holds no
    /// power and would only take a hemicube.
    pub(super) fn covers_surface(&self, patch: &WorldPatch, tile: &[u32; 4]) -> bool {
        let [a0, b0, a1, b1] = *tile;
        (b0..b1).any(|b| {
            (a0..a1).any(|a| {
                self.atlas.elements[(patch.first + b * patch.w + a) as usize].covers_surface()
            })
        })
    }

    /// Halves tiles that hold both valid and invalid elements (a floor
    /// tile reaching under a block, a ceiling tile reaching over a lamp
    /// hung below it), the largest first, along its longer side, until none
    /// is left or there are `limit` tiles (thesis §4.3.3 splits shooters by
    /// power only). The texels above a triangle's diagonal are invalid but
    /// stand for no surface, not for a contact: they count as neither (the
    /// cut keeps such a tile's form factors on the triangle), or every tile
    /// along the diagonal would take the split's budget.
    ///
    /// Such a tile shoots the average of its elements from one hemicube:
    /// whatever the block hides from that eye is lost for the whole tile,
    /// although the tile's elements beside the block see it, and its
    /// rectangle includes the part under the block that holds no light
    /// (progressive refinement's own shots now shoot from the rectangle of
    /// the valid elements instead, [`Self::fitted`]; the figures below are
    /// from before that). Measured on cornell-blocks x0.5 closed by a front wall (release,
    /// `examples/accuracy_by_surface`): a shot delivered 98.3% of its power
    /// with the power-only split, 99.3% with at most twice the tiles split
    /// here, 99.7% with every patch shot from 128 tiles (ten times the
    /// time). NRMSE against the reference at x0.5 with at most 1, 1.5, 2
    /// and 3 times the tiles: cornell-blocks 5.22%, 3.85%, 3.70%, 3.54%;
    /// cornell-large 3.32%, 1.83%, 1.75%, 1.73%; cornell-low 3.44%,
    /// 2.20%, 2.18%, 2.17%; hence [`contact_limit`]'s 1.5.
    fn split_contacts(&self, patch: &WorldPatch, tiles: &mut Vec<[u32; 4]>, limit: usize) {
        let mixed = |t: &[u32; 4]| {
            let (mut valid, mut invalid) = (false, false);
            for b in t[1]..t[3] {
                for a in t[0]..t[2] {
                    let e = (patch.first + b * patch.w + a) as usize;
                    if !self.atlas.elements[e].covers_surface() {
                        continue;
                    }
                    if self.validity.is_invalid(e) {
                        invalid = true;
                    } else {
                        valid = true;
                    }
                }
            }
            valid && invalid
        };
        while tiles.len() < limit {
            let Some(k) = largest(tiles, mixed) else {
                break;
            };
            let [first, second] = halves(tiles[k]);
            tiles[k] = first;
            tiles.push(second);
        }
    }

    /// The shooter covering chart texels `[a0, a1) x [b0, b1)` of a patch.
    pub(super) fn shooter(
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
        let (corner, su, sv, cut) = match patch.lightmap {
            Some(map) => {
                // The tile's texels' footprints, a parallelogram in patch
                // parameters, cut by the patch edge that crosses it
                // (`lightmap_edges`).
                let (c, ex, ey) = lightmap_tile(&map, [a0, b0, a1, b1]);
                let at = |p: Vec2| patch.u * p.x + patch.v * p.y;
                let cut = lightmap_edges(&map, patch.triangle, [a0, b0, a1, b1])
                    .into_iter()
                    .min_by(|a, b| {
                        let kept = |c: &[f32; 3]| cut_cell(*c, [0.0, 0.0], [1.0, 1.0]).0;
                        kept(a).total_cmp(&kept(b))
                    })
                    .unwrap_or([0.0; 3]);
                (patch.origin + at(c), at(ex), at(ey), cut)
            }
            None => {
                let (s0, s1) = (param(a0, patch.w), param(a1, patch.w));
                let (u0, u1) = (param(b0, patch.h), param(b1, patch.h));
                // On a triangle, a tile the diagonal crosses keeps its part
                // with t <= s: at (x, y) of the tile, s = s0 + x (s1 - s0)
                // and t = u0 + y (u1 - u0). Tiles wholly below it are uncut.
                let cut = if patch.triangle && u1 > s0 {
                    [s1 - s0, -(u1 - u0), s0 - u0]
                } else {
                    [0.0; 3]
                };
                (
                    patch.origin + patch.u * s0 + patch.v * u0,
                    patch.u * (s1 - s0),
                    patch.v * (u1 - u0),
                    cut,
                )
            }
        };
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
            // lost, so it looks from the valid element of its patch
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
        let eye = base + normal * self.lift;
        GpuShooter {
            corner: v4(corner, area),
            // The tile's elements: the shader finds them by its patch's
            // first element and chart width (a batch may shoot several
            // patches).
            su: v4(su, f32::from_bits(patch.w)),
            sv: v4(sv, cut[0]),
            eye: v4(eye, f32::from_bits(patch.first)),
            t1: v4(t1, cut[1]),
            t2: v4(t2, cut[2]),
            n: v4(normal, f32::from_bits(patch_id)),
            tile: [a0, b0, a1, b1],
        }
    }
}

impl Tiling<'_> {
    /// One shooter for the triangles `members` (a piece of a region of
    /// near-coplanar triangles, `clusters.rs`), which sit at `range` of
    /// the GPU's member list. Its region is the rectangle around their
    /// corners in the plane of their area-weighted normal through their
    /// centroid, its area theirs (the form factors' sub-disks spread the
    /// area over the rectangle, exact for a piece of a planar grid, and
    /// the disk approximation of eq. 2.2.7 where the piece is far); its
    /// eye sits over the centroid of their valid elements. A zero chart
    /// width marks it for `shooter_energy`, which then collects and
    /// clears the members' elements.
    pub(super) fn cluster_shooter(
        &self,
        members: &[u32],
        range: [u32; 2],
        patches: &[WorldPatch],
        areas: &[f32],
    ) -> GpuShooter {
        let (mut area, mut centroid, mut normal) = (0.0f32, Vec3::ZERO, Vec3::ZERO);
        let (mut valid_area, mut valid_centroid) = (0.0f32, Vec3::ZERO);
        for &m in members {
            let patch = &patches[m as usize];
            let mut patch_area = 0.0;
            for e in patch.first..patch.first + patch.w * patch.h {
                let e = e as usize;
                let [es, et] = self.atlas.elements[e].st;
                let at = patch.origin + patch.u * es + patch.v * et;
                patch_area += areas[e];
                centroid += at * areas[e];
                if !self.validity.is_invalid(e) {
                    valid_area += areas[e];
                    valid_centroid += at * areas[e];
                }
            }
            area += patch_area;
            normal += patch.normal * patch_area;
        }
        let first = &patches[members[0] as usize];
        let normal = normal.try_normalize().unwrap_or(first.normal);
        let centroid = if area > 0.0 {
            centroid / area
        } else {
            first.centre()
        };
        let base = if valid_area > 0.0 {
            valid_centroid / valid_area
        } else {
            centroid
        };
        // The rectangle's axes along the first triangle's edge that gives
        // the smallest rectangle (a piece of a grid: along the grid).
        let bounds = |t1: Vec3| {
            let t2 = normal.cross(t1);
            let (mut lo, mut hi) = ([f32::INFINITY; 2], [f32::NEG_INFINITY; 2]);
            for &m in members {
                for c in patches[m as usize].corners() {
                    let d = c - centroid;
                    for (k, t) in [t1, t2].into_iter().enumerate() {
                        lo[k] = lo[k].min(d.dot(t));
                        hi[k] = hi[k].max(d.dot(t));
                    }
                }
            }
            (t1, t2, lo, hi)
        };
        let (t1, t2, lo, hi) = [first.u, first.v, first.u + first.v]
            .into_iter()
            .filter_map(|e| (e - normal * e.dot(normal)).try_normalize())
            .map(bounds)
            .min_by(|a, b| {
                let size = |(_, _, lo, hi): &(Vec3, Vec3, [f32; 2], [f32; 2])| {
                    (hi[0] - lo[0]) * (hi[1] - lo[1])
                };
                size(a).total_cmp(&size(b))
            })
            .unwrap_or_else(|| bounds(normal.any_orthonormal_vector()));
        let corner = centroid + t1 * lo[0] + t2 * lo[1];
        let eye = base + normal * self.lift;
        GpuShooter {
            corner: v4(corner, area),
            su: v4(t1 * (hi[0] - lo[0]), f32::from_bits(0)),
            sv: v4(t2 * (hi[1] - lo[1]), 0.0),
            eye: v4(eye, f32::from_bits(0)),
            t1: v4(t1, 0.0),
            t2: v4(t2, 0.0),
            n: v4(normal, f32::from_bits(members[0])),
            tile: [range[0], range[1], 0, 0],
        }
    }
}

/// Most tiles a grid of `gx` x `gy` shooters may become once the tiles at
/// contacts are split ([`Tiling::split_contacts`]): one and a half times
/// the grid, within `capacity`.
/// A tile `[a0, b0, a1, b1)` of a chart on a mesh's own lightmap
/// (`atlas/uv.rs`): its texels' footprints `[a0 - 1/2, a1 - 1/2] x [b0 -
/// 1/2, b1 - 1/2]` in chart coordinates as a parallelogram in patch
/// parameters, `corner + x ex + y ey` for `x, y` in `[0, 1]`.
fn lightmap_tile(map: &ChartMap, [a0, b0, a1, b1]: [u32; 4]) -> (Vec2, Vec2, Vec2) {
    let param = |a: u32, b: u32| {
        map.to_param(Vec2::new(a as f32 - 0.5, b as f32 - 0.5))
            .unwrap_or(Vec2::ZERO)
    };
    let c = param(a0, b0);
    (c, param(a1, b0) - c, param(a0, b1) - c)
}

/// The edges of the triangle (the half `t <= s` of its frame, `s <= 1`,
/// `t >= 0`) or of the parallelogram (`0 <= s, t <= 1`) that cross tile
/// `tile` of a chart on a mesh's own lightmap, each as the cut `(a, b, c)`
/// in the tile's coordinates that keeps the patch's side (`a x + b y + c >=
/// 0`). A shooter takes one cut (`Shooter` in common.wgsl): tiles an edge
/// crosses are split first, down to single texels as far as the shooter
/// count allows, and a tile that two edges cross (at a corner of the patch)
/// keeps the cut that leaves the least of it: its region then reaches a
/// little beyond the patch (its power is its elements', exact either way).
fn lightmap_edges(map: &ChartMap, triangle: bool, tile: [u32; 4]) -> Vec<[f32; 3]> {
    let (c, ex, ey) = lightmap_tile(map, tile);
    // h(s, t) = α s + β t + γ >= 0 on the patch.
    const TRIANGLE: [[f32; 3]; 3] = [[1.0, -1.0, 0.0], [-1.0, 0.0, 1.0], [0.0, 1.0, 0.0]];
    const QUAD: [[f32; 3]; 4] = [
        [1.0, 0.0, 0.0],
        [-1.0, 0.0, 1.0],
        [0.0, 1.0, 0.0],
        [0.0, -1.0, 1.0],
    ];
    let edges: &[[f32; 3]] = if triangle { &TRIANGLE } else { &QUAD };
    edges
        .iter()
        .copied()
        .map(|[al, be, ga]| {
            [
                al * ex.x + be * ex.y,
                al * ey.x + be * ey.y,
                al * c.x + be * c.y + ga,
            ]
        })
        .filter(|&[a, b, k]| {
            let h = [k, a + k, a + b + k, b + k];
            let (lo, hi) = h
                .iter()
                .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &v| {
                    (lo.min(v), hi.max(v))
                });
            lo < 0.0 && hi > 0.0 && (a != 0.0 || b != 0.0)
        })
        .collect()
}

pub(super) fn contact_limit((gx, gy): (u32, u32), capacity: u32) -> usize {
    ((3 * gx * gy).div_ceil(2)).min(capacity) as usize
}

/// The tile of `tiles` to split next: the largest of more than one texel
/// for which `wanted`, the first of the largest.
fn largest(tiles: &[[u32; 4]], wanted: impl Fn(&[u32; 4]) -> bool) -> Option<usize> {
    let size = |t: &[u32; 4]| (t[2] - t[0]) * (t[3] - t[1]);
    (0..tiles.len())
        .filter(|&k| size(&tiles[k]) > 1 && wanted(&tiles[k]))
        .max_by_key(|&k| (size(&tiles[k]), std::cmp::Reverse(k)))
}

/// Tile `[a0, b0, a1, b1]` halved along its longer side (along `a` when
/// the sides are equal), the half nearer the origin first.
fn halves([a0, b0, a1, b1]: [u32; 4]) -> [[u32; 4]; 2] {
    if a1 - a0 >= b1 - b0 {
        let m = (a0 + a1) / 2;
        [[a0, b0, m, b1], [m, b0, a1, b1]]
    } else {
        let m = (b0 + b1) / 2;
        [[a0, b0, a1, m], [a0, m, a1, b1]]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpu::placement::PatchTable;
    use lightwire_scene::Scene;

    /// A slanted quad cut into two triangles and a lone obtuse one, at a
    /// density that divides no edge.
    const TRIANGLES: &str = r#"{
        "name": "t",
        "lightmap": { "texel_density": 6.7 },
        "materials": [ { "name": "m", "albedo": [0.5, 0.5, 0.5], "emission": [1, 1, 1] } ],
        "surfaces": [
            { "name": "floor", "material": "m", "mesh": {
                "positions": [[0, 0, 0], [2.1, 0.2, 0], [2.1, 0.3, -1.3], [0, 0.1, -1.3]],
                "indices": [0, 1, 2, 0, 2, 3] } },
            { "name": "sliver", "material": "m", "mesh": {
                "positions": [[0, 1, 0], [1.7, 1.1, 0.2], [0.4, 1.05, 0.1]] } }
        ]
    }"#;

    /// On triangles, the shooters cover the triangle and nothing else: no
    /// tile lies wholly above the diagonal, each shooter's region (cut by
    /// the diagonal where it crosses the tile) has the area of its
    /// elements, and the regions add up to the triangle.
    /// A scene's atlas, all of it valid, its patches at their initial
    /// poses and its element areas.
    fn placed(scene: &Scene) -> (Atlas, Validity, Vec<WorldPatch>, Vec<f32>) {
        let atlas = Atlas::build(scene).expect("fits");
        let validity = Validity::all_valid(&atlas);
        let patches = PatchTable::new(scene, &atlas).place(&scene.initial_poses());
        let areas = atlas.elements.iter().map(|e| e.area).collect();
        (atlas, validity, patches, areas)
    }

    fn tiling<'a>(atlas: &'a Atlas, validity: &'a Validity) -> Tiling<'a> {
        Tiling {
            emitted: 1.0,
            validity,
            atlas,
            lift: 1e-4,
        }
    }

    /// A floor tile that reaches under a block shoots from the rectangle
    /// of its valid texels: the same tiles as [`Tiling::shooters`] (the
    /// shader collects each whole tile's power), every valid sample of a
    /// mixed tile inside its region, its area that region's elements', and
    /// tiles that hold only valid texels unchanged.
    #[test]
    fn mixed_tiles_shoot_from_their_valid_texels() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../scenes/cornell-blocks.json");
        let scene = Scene::load(std::path::Path::new(path)).expect("cornell-blocks loads");
        let atlas = Atlas::build(&scene).expect("fits");
        let validity = Validity::compute(&scene, &atlas, &scene.initial_poses());
        let patches = PatchTable::new(&scene, &atlas).place(&scene.initial_poses());
        let areas: Vec<f32> = atlas.elements.iter().map(|e| e.area).collect();
        let tiling = tiling(&atlas, &validity);
        let floor = scene
            .patches
            .iter()
            .position(|p| p.name == "floor")
            .expect("a floor");
        let wp = &patches[floor];
        let (mut mixed, mut shrunk) = (0, 0);
        for grid in [(3, 3), (6, 6), (10, 10)] {
            let plain = tiling.shooters(floor as u32, wp, &areas, grid, 200);
            let fitted = tiling.fitted_shooters(floor as u32, wp, &areas, grid, 200);
            assert_eq!(plain.len(), fitted.len());
            for (p, f) in plain.iter().zip(&fitted) {
                assert_eq!(
                    p.tile, f.tile,
                    "{grid:?}: the same tiles, in the same order"
                );
                let [a0, b0, a1, b1] = f.tile;
                let elements = (b0..b1)
                    .flat_map(|b| (a0..a1).map(move |a| (wp.first + b * wp.w + a) as usize));
                let (valid, invalid): (Vec<usize>, Vec<usize>) =
                    elements.partition(|&e| !validity.is_invalid(e));
                if valid.is_empty() || invalid.is_empty() {
                    assert_eq!(
                        bytemuck::bytes_of(p),
                        bytemuck::bytes_of(f),
                        "{grid:?}: unmixed"
                    );
                    continue;
                }
                mixed += 1;
                let corner = Vec3::from_slice(&f.corner[..3]);
                let su = Vec3::from_slice(&f.su[..3]);
                let sv = Vec3::from_slice(&f.sv[..3]);
                assert!(
                    f.corner[3] <= p.corner[3] * (1.0 + 1e-6),
                    "{grid:?}: no larger"
                );
                assert!(
                    (su.cross(sv).length() - f.corner[3]).abs() <= 1e-3 * p.corner[3],
                    "{grid:?}: tile {:?}: region {} against its elements' area {}",
                    f.tile,
                    su.cross(sv).length(),
                    f.corner[3]
                );
                shrunk += usize::from(f.corner[3] < 0.99 * p.corner[3]);
                for e in valid {
                    let [es, et] = atlas.elements[e].st;
                    let d = wp.origin + wp.u * es + wp.v * et - corner;
                    let (x, y) = (
                        d.dot(su) / su.length_squared(),
                        d.dot(sv) / sv.length_squared(),
                    );
                    assert!(
                        (-1e-4..=1.0 + 1e-4).contains(&x) && (-1e-4..=1.0 + 1e-4).contains(&y),
                        "{grid:?}: tile {:?}: valid element {e} at ({x}, {y}) of the region",
                        f.tile
                    );
                }
            }
        }
        assert!(mixed > 0, "the blocks' footprints cross some floor tiles");
        assert!(
            shrunk > 0,
            "some mixed tile shoots from less than its rectangle"
        );
    }

    #[test]
    fn triangle_shooters_cover_exactly_the_triangle() {
        // Unpaired: the floor's two triangles would otherwise be one quad.
        let options = lightwire_scene::LoadOptions::unpaired(1.0);
        let scene = Scene::parse_with(TRIANGLES, "inline", options).expect("valid");
        let (atlas, validity, patches, areas) = placed(&scene);
        let tiling = tiling(&atlas, &validity);
        for (p, wp) in patches.iter().enumerate() {
            assert!(wp.triangle);
            let area = scene.patches[p].shape.area();
            for grid in [(1, 1), (3, 2), (4, 4), (5, 7)] {
                let shooters = tiling.shooters(p as u32, wp, &areas, grid, 64);
                let mut total = 0.0;
                let mut cut = 0;
                for s in &shooters {
                    let su = Vec3::from_slice(&s.su[..3]);
                    let sv = Vec3::from_slice(&s.sv[..3]);
                    let (share, _) = cut_cell(s.cut(), [0.0, 0.0], [1.0, 1.0]);
                    let region = su.cross(sv).length() * share;
                    assert!(s.corner[3] > 0.0, "{grid:?}: tile {:?} has no area", s.tile);
                    assert!(
                        (region - s.corner[3]).abs() <= 1e-4 * area,
                        "{grid:?}: tile {:?}: region {region}, elements {}",
                        s.tile,
                        s.corner[3]
                    );
                    total += region;
                    cut += usize::from(share < 1.0);
                }
                assert!(
                    (total - area).abs() <= 1e-4 * area,
                    "patch {p} {grid:?}: regions {total}, triangle {area}"
                );
                assert!(cut > 0, "some tile straddles the diagonal");
            }
        }
    }

    /// Patches on a mesh's own lightmap UVs: a parallelogram (the floor,
    /// whose UVs are affine over its two triangles) and two triangles.
    /// Every tile holds the power of the elements it covers, which sum to
    /// the patch's area; an edge that crosses a tile cuts it, so that its
    /// region is the part of its texels' footprint on the patch (a tile at
    /// a corner, where two edges cross it, keeps one cut and reaches a
    /// little beyond).
    #[test]
    fn shooters_on_a_meshs_lightmap_cover_their_patch() {
        const MESH: &str = r#"{
            "name": "t",
            "lightmap": { "texel_density": 9.3 },
            "materials": [ { "name": "m", "albedo": [0.5, 0.5, 0.5], "emission": [1, 1, 1] } ],
            "surfaces": [ { "name": "room", "material": "m", "mesh": {
                "positions": [[0, 0, 0], [2.1, 0, 0], [2.1, 0, -1.3], [0, 0, -1.3],
                              [0, 0, -1.3], [2.1, 0, -1.3], [2.1, 1.7, -1.3], [0, 1.7, -1.3]],
                "indices": [0, 1, 2, 0, 2, 3, 4, 5, 6, 4, 6, 7],
                "lightmap_uvs": [[0.03, 0.9], [0.41, 0.95], [0.47, 0.1], [0.09, 0.05],
                                 [0.55, 0.9], [0.97, 0.9], [0.9, 0.2], [0.62, 0.2]] } } ]
        }"#;
        let options = lightwire_scene::LoadOptions {
            density_scale: 1.0,
            charts: lightwire_scene::Charts::LightmapUvs,
        };
        let scene = Scene::parse_with(MESH, "inline", options).expect("valid");
        assert_eq!(scene.patches.len(), 3, "the floor and two triangles");
        let (atlas, validity, patches, areas) = placed(&scene);
        let tiling = tiling(&atlas, &validity);
        let mut quads = 0;
        for (p, wp) in patches.iter().enumerate() {
            assert!(wp.lightmap.is_some());
            quads += usize::from(!wp.triangle);
            let area = scene.patches[p].shape.area();
            for grid in [(1, 1), (3, 2), (4, 4), (6, 5)] {
                let shooters = tiling.shooters(p as u32, wp, &areas, grid, 256);
                let (mut power, mut region, mut cut) = (0.0, 0.0, 0);
                for s in &shooters {
                    let su = Vec3::from_slice(&s.su[..3]);
                    let sv = Vec3::from_slice(&s.sv[..3]);
                    let (share, _) = cut_cell(s.cut(), [0.0, 0.0], [1.0, 1.0]);
                    power += s.corner[3];
                    region += su.cross(sv).length() * share;
                    cut += usize::from(share < 1.0);
                    assert!(s.corner[3] > 0.0, "{grid:?}: tile {:?} has no area", s.tile);
                }
                assert!(
                    (power - area).abs() <= 1e-4 * area,
                    "patch {p} {grid:?}: elements {power}, patch {area}"
                );
                // The corners' overreach: under a few texels' worth.
                let texel = area / atlas.elements_of(p as u32).len() as f32;
                assert!(
                    region >= area * (1.0 - 1e-4) && region <= area + 8.0 * texel,
                    "patch {p} {grid:?}: regions {region}, patch {area}"
                );
                assert!(cut > 0, "the patch's edges cut tiles");
            }
        }
        assert_eq!(quads, 1);
    }

    /// The cut keeps the triangle's side and puts the centroid there: a
    /// unit square cut by its diagonal keeps half, centroid (2/3, 1/3).
    #[test]
    fn cut_cell_keeps_the_lower_half_of_a_diagonal_square() {
        let (share, [x, y]) = cut_cell([1.0, -1.0, 0.0], [0.0, 0.0], [1.0, 1.0]);
        assert!((share - 0.5).abs() < 1e-6, "{share}");
        assert!((x - 2.0 / 3.0).abs() < 1e-6 && (y - 1.0 / 3.0).abs() < 1e-6);
        assert_eq!(cut_cell([0.0; 3], [0.0, 0.0], [1.0, 1.0]).0, 1.0);
        assert_eq!(cut_cell([1.0, -1.0, -2.0], [0.0, 0.0], [1.0, 1.0]).0, 0.0);
    }
}
