//! Two triangles of a mesh that form a parallelogram share one chart.
//!
//! A mesh has a patch per triangle, and a triangle's chart is a square
//! whose half above the diagonal stands for no surface (`atlas.rs`): a
//! quad cut in two, as every exporter triangulates quads, costs two
//! square charts and twice its texels, half of them dead, and each small
//! triangle gets at least three texels whatever the density asks. Where
//! two triangles of one mesh surface (same object, material, density and
//! texture) share an edge and their four corners form a parallelogram
//! (the shared edge a diagonal of it), they become one quad patch: one
//! chart over the parallelogram, every texel on the surface, the same
//! geometry. Wallner's system packs per-triangle lightmaps into charts
//! of many triangles (§2); this is its smallest case, the quad. Then
//! [`merge_parallelograms`] joins such quads that extend each other into
//! larger parallelograms, as long as any two do: a wall tessellated into
//! a grid is one chart, as a hand-written quad is, without the texels
//! every cell's own chart repeats along its edges and without a patch
//! (and a shot, and triangles drawn into every hemicube) per cell. Charts
//! of triangles that tile no parallelogram (near-planar regions in
//! general) are not built.
//!
//! Pairs through an edge that is the longest of both triangles (a quad
//! cut along its diagonal) are taken first, so that a grid of cells
//! pairs cell by cell rather than across cells; then pairs through any
//! shared edge. A texture pairs only when its coordinates are affine
//! over the parallelogram (the fourth corner's coordinates are what the
//! other three give), since `AlbedoMap` interpolates linearly over the
//! patch. The same holds for triangles lit on their mesh's own lightmap
//! UVs (`Patch::lightmap`, `--charts lightmap-uvs`): where an island of
//! the asset's lightmap maps a flat grid of cells affinely (a wall or a
//! floor unwrapped by a planar projection, as lightmap unwrappers do), the
//! grid becomes one patch on that island, its texels the island's, shot
//! in tiles like any chart: a patch, a shot and hemicube triangles per
//! parallelogram rather than per triangle.

use std::collections::HashMap;
use std::sync::Arc;

use glam::{Vec2, Vec3};

use super::texture::AlbedoMap;
use super::{Charts, Patch, PatchLightmap, PatchShape};

/// The fourth corner lies within this fraction of the shared edge's length
/// of where the parallelogram puts it (or within the f32 rounding of the
/// corners' coordinates, about 1e-7 of their magnitude, when that is more).
const PARALLELOGRAM_TOLERANCE: f32 = 1e-5;
/// Texture coordinates agree within this (plus the same fraction of their
/// magnitude).
const UV_TOLERANCE: f32 = 1e-5;

/// Corners are the same when they lie within this fraction of the
/// meshes' extent of each other (a triangle's corners are recomputed from
/// its frame, `origin + u + v`, so shared corners differ by f32 rounding).
/// They are found through a grid of this spacing.
const CORNER_QUANTUM: f32 = 1e-5;

/// A corner's cell on the grid.
type Key = [i64; 3];

/// The corners' grid: a point's cell, and the cells a point within a
/// hundredth of a cell of it may round to (more than one only near a
/// cell's border), so that two copies of one corner always meet.
struct Grid {
    lo: Vec3,
    quantum: f32,
}

impl Grid {
    fn key(&self, p: Vec3) -> Key {
        ((p - self.lo) / self.quantum)
            .round()
            .as_i64vec3()
            .to_array()
    }

    fn keys(&self, p: Vec3) -> Vec<Key> {
        let f = (p - self.lo) / self.quantum;
        let mut keys = vec![self.key(p)];
        for axis in 0..3 {
            let x = f[axis];
            let half = x.floor() + 0.5;
            if (x - half).abs() < 0.01 {
                let other = if x < half { half.ceil() } else { half.floor() } as i64;
                let more: Vec<Key> = keys
                    .iter()
                    .map(|k| {
                        let mut k = *k;
                        k[axis] = other;
                        k
                    })
                    .collect();
                keys.extend(more);
            }
        }
        keys
    }

    fn same(&self, a: Vec3, b: Vec3) -> bool {
        (a - b).abs().max_element() <= self.quantum
    }
}

/// What two triangles must share to be one patch.
#[derive(Clone, PartialEq, Eq, Hash)]
struct Group {
    object: u32,
    material: u32,
    surface_index: usize,
    density: u32,
    texture: Option<usize>,
    lightmap: Option<u32>,
}

fn group(p: &Patch) -> Group {
    Group {
        object: p.object,
        material: p.material,
        surface_index: p.surface_index,
        density: p.texel_density.to_bits(),
        texture: p
            .albedo_map
            .as_ref()
            .map(|m| Arc::as_ptr(&m.texture) as usize),
        lightmap: p.lightmap.map(|l| l.mesh),
    }
}

/// A triangle's corners counter-clockwise from the front (`AlbedoMap::uv`
/// and `PatchLightmap::uv` are in the same order).
fn corners(p: &Patch) -> Option<[Vec3; 3]> {
    match p.shape {
        PatchShape::Triangle { origin, u, v } => Some([origin, origin + u, origin + u + v]),
        PatchShape::Quad { .. } => None,
    }
}

/// Coordinates given at patch parameters (0, 0), (1, 0) and (1, 1) (a
/// triangle's corners, three of a quad's), at `(s, t)`: affine over the
/// patch, as `AlbedoMap::uv_at` and the atlas's `ChartMap` are.
fn affine_uv([a, b, c]: [Vec2; 3], s: f32, t: f32) -> Vec2 {
    a + (b - a) * s + (c - b) * t
}

/// Both or neither of two patches' coordinates `a` and `b` (textures or
/// lightmap UVs) and, when both, the joined patch's from `join_uv` (`None`
/// when they do not join).
fn both<T, U>(
    a: Option<T>,
    b: Option<T>,
    join_uv: impl FnOnce(T, T) -> Option<U>,
) -> Option<Option<U>> {
    match (a, b) {
        (None, None) => Some(None),
        (Some(a), Some(b)) => join_uv(a, b).map(Some),
        _ => None,
    }
}

/// The texture and lightmap coordinates of the patch that joins `a` and
/// `b`, each from `join_uv` of theirs (both or neither must have one, a
/// texture the same one); `None` when they do not join.
fn joined_maps(
    a: &Patch,
    b: &Patch,
    join_uv: impl Fn([Vec2; 3], [Vec2; 3]) -> Option<[Vec2; 3]>,
) -> Option<(Option<AlbedoMap>, Option<PatchLightmap>)> {
    let albedo_map = both(a.albedo_map.as_ref(), b.albedo_map.as_ref(), |ma, mb| {
        Arc::ptr_eq(&ma.texture, &mb.texture)
            .then(|| join_uv(ma.uv, mb.uv))
            .flatten()
            .map(|uv| AlbedoMap {
                texture: Arc::clone(&ma.texture),
                uv,
            })
    })?;
    let lightmap = both(a.lightmap, b.lightmap, |la, lb| {
        join_uv(la.uv, lb.uv).map(|uv| PatchLightmap { uv, ..la })
    })?;
    Some((albedo_map, lightmap))
}

/// The quad's coordinates when triangles with coordinates `uva` and `uvb`
/// join through `a`'s edge `ka` (`b`'s `kb`) into the quad with corners
/// x, d0, y of `join`: only when they agree on the shared edge and are
/// affine over the quad.
fn join_uvs(uva: [Vec2; 3], uvb: [Vec2; 3], ka: usize, kb: usize) -> Option<[Vec2; 3]> {
    let (t0, t1, tx) = (uva[ka], uva[(ka + 1) % 3], uva[(ka + 2) % 3]);
    let (s1, s0, ty) = (uvb[kb], uvb[(kb + 1) % 3], uvb[(kb + 2) % 3]);
    (close_uv(t0, s0) && close_uv(t1, s1) && close_uv(tx + ty, t0 + t1)).then_some([tx, t0, ty])
}

fn close_uv(a: Vec2, b: Vec2) -> bool {
    (a - b).length() <= UV_TOLERANCE * (1.0 + a.length().max(b.length()))
}

/// The quad of triangles `a` and `b` if they share their edge `ka` of `a`
/// (corners `ka`, `ka + 1`) as a diagonal of a parallelogram with
/// consistent texture coordinates.
fn join(a: &Patch, ka: usize, b: &Patch, grid: &Grid) -> Option<Patch> {
    let ca = corners(a)?;
    let cb = corners(b)?;
    let (d0, d1, x) = (ca[ka], ca[(ka + 1) % 3], ca[(ka + 2) % 3]);
    // `b` runs the shared edge the other way: d1, d0, then its third corner.
    let kb = (0..3).find(|&k| grid.same(cb[k], d1) && grid.same(cb[(k + 1) % 3], d0))?;
    let y = cb[(kb + 2) % 3];
    // Within the tolerance, or the rounding of the sums at the corners'
    // magnitude (a small cell far from the origin).
    let magnitude = [x, y, d0, d1]
        .iter()
        .map(|p| p.abs().max_element())
        .fold(0.0f32, f32::max);
    let tolerance =
        (PARALLELOGRAM_TOLERANCE * (d1 - d0).length()).max(8.0 * f32::EPSILON * magnitude);
    if (x + y - d0 - d1).length() > tolerance {
        return None;
    }
    // The quad's frame below: corners x, d0, y (s, t = 0,0 / 1,0 / 1,1).
    let (albedo_map, lightmap) = joined_maps(a, b, |ua, ub| join_uvs(ua, ub, ka, kb))?;
    let suffix = b.name.rsplit('/').next().unwrap_or(&b.name);
    Some(Patch {
        name: format!("{}+{suffix}", a.name),
        // Corners x, d0, y, d1 counter-clockwise: `a` is (x, d0, d1), `b`
        // is (d0, y, d1), and u × v faces as both do.
        shape: PatchShape::Quad {
            origin: x,
            u: d0 - x,
            v: y - d0,
        },
        albedo_map,
        lightmap,
        ..a.clone()
    })
}

/// Joins pairs of triangles of `patches` that form a parallelogram into one
/// quad patch each (see the module documentation); quads, lone triangles
/// and the order of what remains are kept (a quad takes its first
/// triangle's place).
pub fn pair_triangles(patches: Vec<Patch>) -> Vec<Patch> {
    let (lo, hi) = patches
        .iter()
        .filter_map(corners)
        .flatten()
        .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), c| {
            (lo.min(c), hi.max(c))
        });
    let quantum = ((hi - lo).max_element() * CORNER_QUANTUM).max(f32::MIN_POSITIVE);
    let grid = Grid { lo, quantum };
    // Directed edges of every triangle: (group, from, to) -> (patch, edge).
    let mut edges: HashMap<(Group, Key, Key), Vec<(usize, usize)>> = HashMap::new();
    for (i, p) in patches.iter().enumerate() {
        if let Some(c) = corners(p) {
            let g = group(p);
            for k in 0..3 {
                edges
                    .entry((g.clone(), grid.key(c[k]), grid.key(c[(k + 1) % 3])))
                    .or_default()
                    .push((i, k));
            }
        }
    }
    let longest = |p: &Patch, k: usize| -> bool {
        let Some(c) = corners(p) else {
            return false;
        };
        let len = |k: usize| (c[(k + 1) % 3] - c[k]).length_squared();
        (0..3).all(|j| len(k) >= len(j))
    };
    let mut partner: Vec<Option<Patch>> = vec![None; patches.len()];
    let mut used = vec![false; patches.len()];
    for diagonal_only in [true, false] {
        for (i, a) in patches.iter().enumerate() {
            let Some(c) = corners(a) else {
                continue;
            };
            if used[i] {
                continue;
            }
            let g = group(a);
            let found = (0..3).find_map(|ka| {
                if diagonal_only && !longest(a, ka) {
                    return None;
                }
                // `b` runs the edge the other way; its copies of the two
                // corners may round to neighbouring cells.
                let (from, to) = (grid.keys(c[(ka + 1) % 3]), grid.keys(c[ka]));
                from.iter()
                    .flat_map(|f| to.iter().map(move |t| (*f, *t)))
                    .filter_map(|(f, t)| edges.get(&(g.clone(), f, t)))
                    .flatten()
                    .find_map(|&(j, kb)| {
                        if j == i || used[j] || (diagonal_only && !longest(&patches[j], kb)) {
                            return None;
                        }
                        join(a, ka, &patches[j], &grid).map(|q| (j, q))
                    })
            });
            if let Some((j, quad)) = found {
                used[i] = true;
                used[j] = true;
                partner[i] = Some(quad);
            }
        }
    }
    patches
        .into_iter()
        .zip(used)
        .zip(partner)
        .filter_map(|((p, used), quad)| match (used, quad) {
            (false, _) => Some(p),
            (true, Some(q)) => Some(q),
            (true, None) => None,
        })
        .collect()
}

/// A quad's corners counter-clockwise from the front: `origin`,
/// `origin + u`, `origin + u + v`, `origin + v`, at patch parameters
/// (0, 0), (1, 0), (1, 1), (0, 1).
const QUAD_ST: [(f32, f32); 4] = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)];

fn mergeable(p: &Patch) -> Option<[Vec3; 4]> {
    match p.shape {
        PatchShape::Quad { origin, u, v } if p.mesh => {
            Some([origin, origin + u, origin + u + v, origin + v])
        }
        _ => None,
    }
}

/// The parallelogram of mesh quads `a` and `b` if `b` holds `a`'s edge `ka`
/// (corners `ka`, `ka + 1`) as a whole edge and the two extend each other
/// across it (their sides through the edge's ends are collinear), with
/// texture coordinates affine over the union. It keeps `a`'s name.
fn extend(a: &Patch, ka: usize, b: &Patch, grid: &Grid) -> Option<Patch> {
    let ca = mergeable(a)?;
    let cb = mergeable(b)?;
    let (p, q) = (ca[ka], ca[(ka + 1) % 4]);
    // `b` runs the edge the other way: q, p, then p + w_b, q + w_b.
    let kb = (0..4).find(|&k| grid.same(cb[k], q) && grid.same(cb[(k + 1) % 4], p))?;
    let w_a = ca[(ka + 3) % 4] - p;
    let w_b = cb[(kb + 2) % 4] - p;
    if w_a.dot(w_b) >= 0.0 {
        return None;
    }
    // `w_b` on the line of `w_a` (then `b` lies in `a`'s plane, beyond the
    // edge), within the tolerance of `join` at the sides' scale.
    let magnitude = ca
        .iter()
        .chain(&cb)
        .map(|c| c.abs().max_element())
        .fold(0.0f32, f32::max);
    let tolerance = (PARALLELOGRAM_TOLERANCE * w_b.length()).max(8.0 * f32::EPSILON * magnitude);
    let along = w_a.normalize_or_zero();
    if (w_b - along * w_b.dot(along)).length() > tolerance {
        return None;
    }
    // Agree on the edge, and change across it at one rate.
    let c = w_b.length() / w_a.length();
    let (albedo_map, lightmap) = joined_maps(a, b, |ua, ub| extend_uvs(ua, ub, ka, kb, c))?;
    // Cells: `a`'s and `b`'s along the edge must match in number (then in
    // size) and be as deep across it for the union to be a grid of equal
    // cells; otherwise the union counts as one cell.
    let (a_edge, a_across) = (a.cells[ka % 2], a.cells[1 - ka % 2]);
    let (b_edge, b_across) = (b.cells[kb % 2], b.cells[1 - kb % 2]);
    let (depth_a, depth_b) = (
        w_a.length() / a_across.max(1) as f32,
        w_b.length() / b_across.max(1) as f32,
    );
    let uniform = a_edge == b_edge && (depth_a - depth_b).abs() <= 1e-4 * depth_a.max(depth_b);
    let cells = if uniform {
        [a_edge, a_across.saturating_add(b_across)]
    } else {
        [1, 1]
    };
    Some(Patch {
        cells,
        // Corners p + w_b, q + w_b, q + w_a, p + w_a counter-clockwise, as
        // `a`'s p, q, q + w_a, p + w_a are.
        shape: PatchShape::Quad {
            origin: p + w_b,
            u: q - p,
            v: w_a - w_b,
        },
        albedo_map,
        lightmap,
        ..a.clone()
    })
}

/// The union's coordinates when quad `b` extends quad `a` across `a`'s
/// edge `ka` (`b`'s `kb`), `b` being `c` times as deep across it (the
/// union's corners as `extend` orders them): only when they agree on the
/// edge and change across it at one rate.
fn extend_uvs(uv_a: [Vec2; 3], uv_b: [Vec2; 3], ka: usize, kb: usize, c: f32) -> Option<[Vec2; 3]> {
    let at = |uv: [Vec2; 3], k: usize| {
        let (s, t) = QUAD_ST[k % 4];
        affine_uv(uv, s, t)
    };
    let across_a = at(uv_a, ka + 3) - at(uv_a, ka);
    let across_b = at(uv_b, kb + 2) - at(uv_b, kb + 1);
    (close_uv(at(uv_a, ka), at(uv_b, kb + 1))
        && close_uv(at(uv_a, ka + 1), at(uv_b, kb))
        && close_uv(across_b + at(uv_a, ka), at(uv_a, ka) - across_a * c))
    .then(|| [at(uv_b, kb + 2), at(uv_b, kb + 3), at(uv_a, ka + 2)])
}

/// Joins mesh quads (pairs from [`pair_triangles`]) of one surface that
/// extend each other across a whole shared edge into one parallelogram, as
/// long as any two do: a grid of cells on a wall becomes one chart, as a
/// hand-written quad is. A quad grows across the edges parallel to the one
/// it last grew across first (a row of cells becomes a strip, then strips
/// of equal length join), so that a grid ends as one parallelogram in any
/// order. The merged patch is named after its first triangle and how many
/// it holds (`node/mesh/0/6:24`) and takes the place of the earlier of each
/// two it joins; other patches are kept as they are.
pub fn merge_parallelograms(patches: Vec<Patch>) -> Vec<Patch> {
    let (lo, hi) = patches
        .iter()
        .filter_map(mergeable)
        .flatten()
        .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), c| {
            (lo.min(c), hi.max(c))
        });
    if lo.x > hi.x {
        return patches;
    }
    let quantum = ((hi - lo).max_element() * CORNER_QUANTUM).max(f32::MIN_POSITIVE);
    let grid = Grid { lo, quantum };
    type EdgeKey = (Group, Key, Key);
    let edge_keys = |p: &Patch| -> Vec<EdgeKey> {
        let Some(c) = mergeable(p) else {
            return Vec::new();
        };
        let g = group(p);
        (0..4)
            .map(|k| (g.clone(), grid.key(c[k]), grid.key(c[(k + 1) % 4])))
            .collect()
    };
    let mut edges: HashMap<EdgeKey, Vec<usize>> = HashMap::new();
    for (i, p) in patches.iter().enumerate() {
        for key in edge_keys(p) {
            edges.entry(key).or_default().push(i);
        }
    }
    let mut live: Vec<Option<Patch>> = patches.into_iter().map(Some).collect();
    let unlink = |edges: &mut HashMap<EdgeKey, Vec<usize>>, p: &Patch, i: usize| {
        for key in edge_keys(p) {
            if let Some(v) = edges.get_mut(&key) {
                v.retain(|&j| j != i);
            }
        }
    };
    // Triangles per live patch (a mesh quad is a pair, `pair_triangles`).
    let mut counts = vec![2usize; live.len()];
    // The first quad that extends `live[cur]`, and their union. Edges 0
    // and 2 first: after a merge they are the ones parallel to the edge just
    // crossed (the merged frame's `u` runs along it).
    let find = |live: &[Option<Patch>], edges: &HashMap<EdgeKey, Vec<usize>>, cur: usize| {
        let a = live[cur].as_ref()?;
        let c = mergeable(a)?;
        let g = group(a);
        [0, 2, 1, 3].into_iter().find_map(|ka| {
            let (from, to) = (grid.keys(c[(ka + 1) % 4]), grid.keys(c[ka]));
            from.iter()
                .flat_map(|f| to.iter().map(move |t| (*f, *t)))
                .filter_map(|(f, t)| edges.get(&(g.clone(), f, t)))
                .flatten()
                .find_map(|&j| {
                    let b = live[j].as_ref()?;
                    (j != cur).then(|| extend(a, ka, b, &grid).map(|m| (j, m)))?
                })
        })
    };
    for i in 0..live.len() {
        let mut cur = i;
        while let Some((j, mut merged)) = find(&live, &edges, cur) {
            let (Some(a), Some(b)) = (live[cur].take(), live[j].take()) else {
                break;
            };
            unlink(&mut edges, &a, cur);
            unlink(&mut edges, &b, j);
            let at = cur.min(j);
            counts[at] = counts[cur] + counts[j];
            let first = if at == cur { &a } else { &b };
            let (dir, last) = first.name.rsplit_once('/').unwrap_or(("", &first.name));
            let head = last.split(['+', ':']).next().unwrap_or(last);
            merged.name = if dir.is_empty() {
                format!("{head}:{}", counts[at])
            } else {
                format!("{dir}/{head}:{}", counts[at])
            };
            for key in edge_keys(&merged) {
                edges.entry(key).or_default().push(at);
            }
            live[at] = Some(merged);
            cur = at;
        }
    }
    live.into_iter().flatten().collect()
}

/// The patches of a scene with its meshes' triangles given charts as
/// `charts` asks.
pub fn charts(mut patches: Vec<Patch>, charts: Charts) -> Vec<Patch> {
    // Only the static world is lit on its meshes' own lightmaps: a moving
    // object's cross tiles follow the rows of Lightwire's own charts.
    // Triangles on their lightmap pair and merge where their UVs are affine
    // over the union (`join_uvs`, `extend_uvs`).
    for p in &mut patches {
        if !matches!(
            charts,
            Charts::LightmapUvs | Charts::Generated | Charts::Uvunwrap
        ) || p.object != super::STATIC_OBJECT
        {
            p.lightmap = None;
        }
    }
    match charts {
        Charts::Triangles => patches,
        Charts::Pairs => pair_triangles(patches),
        Charts::Parallelograms | Charts::LightmapUvs | Charts::Generated | Charts::Uvunwrap => {
            merge_parallelograms(pair_triangles(patches))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::texture::{Filter, Texture, Wrap};

    fn triangle(name: &str, a: Vec3, b: Vec3, c: Vec3) -> Patch {
        Patch {
            name: name.to_string(),
            surface_index: 0,
            object: 0,
            material: 0,
            texel_density: 4.0,
            shape: PatchShape::triangle(a, b, c),
            albedo_map: None,
            mesh: true,
            cells: [1, 1],
            lightmap: None,
        }
    }

    /// An `n` x `n` grid of unit cells on the floor, each cut along the
    /// diagonal from its (0, 0) corner, facing up.
    fn grid(n: usize) -> Vec<Patch> {
        let p = |i: usize, j: usize| Vec3::new(i as f32, 0.0, -(j as f32));
        let mut out = Vec::new();
        for j in 0..n {
            for i in 0..n {
                let k = out.len();
                out.push(triangle(
                    &format!("m/{k}"),
                    p(i, j),
                    p(i + 1, j),
                    p(i + 1, j + 1),
                ));
                out.push(triangle(
                    &format!("m/{}", k + 1),
                    p(i, j),
                    p(i + 1, j + 1),
                    p(i, j + 1),
                ));
            }
        }
        out
    }

    /// A 2 x 2 black-and-white checker, repeating, sampled nearest.
    fn checker() -> Arc<Texture> {
        Arc::new(
            Texture::from_linear(
                "checker",
                2,
                2,
                vec![Vec3::ZERO, Vec3::ONE, Vec3::ONE, Vec3::ZERO],
                [Wrap::Repeat; 2],
                Filter::Nearest,
            )
            .expect("a valid 2 x 2 texture"),
        )
    }

    fn area(patches: &[Patch]) -> f32 {
        patches.iter().map(|p| p.shape.area()).sum()
    }

    #[test]
    fn a_grid_of_cells_pairs_cell_by_cell_into_unit_squares_facing_as_before() {
        let triangles = grid(3);
        let paired = pair_triangles(triangles.clone());
        assert_eq!(paired.len(), 9);
        assert!((area(&paired) - area(&triangles)).abs() < 1e-5);
        for q in &paired {
            let PatchShape::Quad { u, v, .. } = q.shape else {
                panic!("{} is not a quad", q.name);
            };
            // Each cell alone: unit edges along the grid, facing up.
            assert!((u.length() - 1.0).abs() < 1e-6 && (v.length() - 1.0).abs() < 1e-6);
            assert!(u.dot(v).abs() < 1e-6, "{}: not a cell", q.name);
            assert!(q.shape.normal().dot(Vec3::Y) > 0.999, "{}", q.name);
        }
        assert_eq!(paired[0].name, "m/0+1");
        // The quad covers both triangles' points.
        let q = &paired[0];
        let (o, u, v) = q.shape.frame();
        for t in &triangles[..2] {
            let c = t.shape.centre();
            let d = c - o;
            let (s, w) = (d.dot(u) / u.length_squared(), d.dot(v) / v.length_squared());
            assert!(q.shape.contains(s, w), "{} centre off the quad", t.name);
        }
    }

    /// A slanted parallelogram off the grid: the corners the two triangles
    /// recompute from their frames differ in the last bits, and still meet.
    #[test]
    fn a_slanted_parallelogram_pairs_despite_rounding() {
        let p = [
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(2.1, 0.2, 0.0),
            Vec3::new(2.1, 0.3, -1.3),
            Vec3::new(0.0, 0.1, -1.3),
        ];
        let halves = vec![
            triangle("f/0", p[0], p[1], p[2]),
            triangle("f/1", p[0], p[2], p[3]),
        ];
        let paired = pair_triangles(halves.clone());
        assert_eq!(paired.len(), 1);
        assert!((area(&paired) - area(&halves)).abs() < 1e-5);
        let corners = paired[0].shape.corners();
        for c in p {
            assert!(
                corners.iter().any(|q| (*q - c).length() < 1e-5),
                "corner {c} lost"
            );
        }
    }

    #[test]
    fn triangles_that_are_no_parallelogram_or_differ_stay_triangles() {
        // A kite: shares an edge, but the corners are no parallelogram.
        let a = Vec3::ZERO;
        let b = Vec3::new(1.0, 0.0, 0.0);
        let c = Vec3::new(0.0, 0.0, -1.0);
        let kite = vec![
            triangle("k/0", a, b, c),
            triangle("k/1", b, Vec3::new(2.0, 0.0, -2.0), c),
        ];
        assert_eq!(pair_triangles(kite.clone()), kite);
        // A parallelogram, but of two materials, or folded (not coplanar).
        let mut two = grid(1);
        two[1].material = 1;
        assert_eq!(pair_triangles(two.clone()), two);
        let mut folded = grid(1);
        folded[1] = triangle(
            "m/1",
            Vec3::ZERO,
            Vec3::new(1.0, 0.0, -1.0),
            Vec3::new(0.0, 0.3, -1.0),
        );
        assert_eq!(pair_triangles(folded).len(), 2);
        // Opposite windings (one faces down) never pair.
        let mut flipped = grid(1);
        let (o, u, v) = flipped[1].shape.frame();
        flipped[1] = triangle("m/1", o + u + v, o + u, o);
        assert_eq!(pair_triangles(flipped).len(), 2);
    }

    #[test]
    fn a_texture_pairs_only_when_affine_and_then_reads_the_same_everywhere() {
        let texture = checker();
        // Texture coordinates = 0.3 * (x, -z) at every corner: affine.
        let mut cells = grid(2);
        for p in &mut cells {
            let (o, u, v) = p.shape.frame();
            let at = |q: Vec3| Vec2::new(q.x, -q.z) * 0.3;
            p.albedo_map = Some(AlbedoMap {
                texture: Arc::clone(&texture),
                uv: [at(o), at(o + u), at(o + u + v)],
            });
        }
        let paired = pair_triangles(cells.clone());
        assert_eq!(paired.len(), 4);
        for (q, t) in paired.iter().zip(cells.chunks(2)) {
            let map = q.albedo_map.as_ref().expect("keeps its texture");
            let (o, u, v) = q.shape.frame();
            for tri in t {
                let (to, tu, tv) = tri.shape.frame();
                let p = to + tu * 0.6 + tv * 0.3;
                let d = p - o;
                let (s, w) = (d.dot(u) / u.length_squared(), d.dot(v) / v.length_squared());
                let want = tri.albedo_map.as_ref().expect("textured").uv_at(0.6, 0.3);
                assert!((map.uv_at(s, w) - want).length() < 1e-5, "{}", q.name);
            }
        }
        // One corner's coordinates moved: the map is no longer affine over
        // that cell, whose triangles stay apart.
        let mut bent = cells;
        if let Some(m) = bent[1].albedo_map.as_mut() {
            m.uv[2] += Vec2::new(0.2, 0.0);
        }
        assert_eq!(pair_triangles(bent).len(), 5);
    }

    /// Patch parameters of `p` on the quad `q` (in its plane).
    fn st(q: &Patch, p: Vec3) -> (f32, f32) {
        let (o, u, v) = q.shape.frame();
        let n = u.cross(v);
        // Solve p - o = s u + t v in the plane.
        let d = p - o;
        let s = d.cross(v).dot(n) / n.length_squared();
        let t = u.cross(d).dot(n) / n.length_squared();
        (s, t)
    }

    fn covered_once(charts: &[Patch], triangles: &[Patch]) {
        for t in triangles {
            let c = t.shape.centre();
            let on: Vec<&str> = charts
                .iter()
                .filter(|q| {
                    let (s, w) = st(q, c);
                    (q.shape.centre() - c).dot(q.shape.normal()).abs() < 1e-4
                        && q.shape.contains(s, w)
                })
                .map(|q| q.name.as_str())
                .collect();
            assert_eq!(on.len(), 1, "{} lies on {on:?}", t.name);
        }
    }

    #[test]
    fn a_grid_of_cells_merges_into_one_parallelogram_facing_as_before() {
        let triangles = grid(4);
        let charts = super::charts(triangles.clone(), Charts::Parallelograms);
        assert_eq!(
            charts.len(),
            1,
            "{:?}",
            charts.iter().map(|q| &q.name).collect::<Vec<_>>()
        );
        let q = &charts[0];
        assert_eq!(q.name, "m/0:32");
        assert!(q.mesh);
        assert!((q.shape.area() - 16.0).abs() < 1e-4);
        assert!(q.shape.normal().dot(Vec3::Y) > 0.999);
        let (_, u, v) = q.shape.frame();
        assert!((u.length() - 4.0).abs() < 1e-5 && (v.length() - 4.0).abs() < 1e-5);
        covered_once(&charts, &triangles);
        // `Charts::Pairs` stops at the cells, `Charts::Triangles` before.
        assert_eq!(super::charts(triangles.clone(), Charts::Pairs).len(), 16);
        assert_eq!(
            super::charts(triangles.clone(), Charts::Triangles),
            triangles
        );
    }

    /// `triangles` (of `grid`) on a lightmap whose UVs are `uv_of` their
    /// corners' positions.
    fn on_lightmap(triangles: &[Patch], uv_of: impl Fn(Vec3) -> Vec2) -> Vec<Patch> {
        triangles
            .iter()
            .map(|t| {
                let c = corners(t).expect("a triangle");
                Patch {
                    lightmap: Some(PatchLightmap {
                        mesh: 0,
                        uv: c.map(&uv_of),
                    }),
                    ..t.clone()
                }
            })
            .collect()
    }

    /// Where a merged patch on the lightmap puts world point `x` of it.
    fn lightmap_uv_at(q: &Patch, x: Vec3) -> Vec2 {
        let (s, t) = st(q, x);
        affine_uv(q.lightmap.expect("on the lightmap").uv, s, t)
    }

    #[test]
    fn triangles_on_their_lightmap_merge_only_where_their_uvs_are_affine() {
        let triangles = grid(4);
        // A planar projection, as an unwrapper gives a flat island.
        let planar = |p: Vec3| Vec2::new(0.1 + 0.2 * p.x, 0.9 + 0.15 * p.z);
        let flat = on_lightmap(&triangles, planar);
        let charts = super::charts(flat.clone(), Charts::LightmapUvs);
        assert_eq!(charts.len(), 1, "one island, one parallelogram");
        let q = &charts[0];
        assert!(!q.shape.is_triangle());
        for t in &flat {
            for c in corners(t).expect("a triangle") {
                assert!((lightmap_uv_at(q, c) - planar(c)).length() < 1e-5);
            }
        }
        // Not on the lightmap under the other modes.
        let own = super::charts(flat.clone(), Charts::Parallelograms);
        assert!(own.iter().all(|p| p.lightmap.is_none()));
        // The grid's middle corner moved in the lightmap (two islands'
        // worth of distortion): the UVs are not affine over the cells around
        // it, which stay apart; whatever merges keeps every corner's UV.
        let middle = Vec3::new(2.0, 0.0, -2.0);
        let bent_uv = |p: Vec3| {
            planar(p)
                + if (p - middle).length() < 1e-6 {
                    Vec2::new(0.03, 0.0)
                } else {
                    Vec2::ZERO
                }
        };
        let bent = on_lightmap(&triangles, bent_uv);
        let charts = super::charts(bent.clone(), Charts::LightmapUvs);
        assert!(charts.len() > 4, "{} patches", charts.len());
        assert!(charts.iter().any(|p| p.shape.is_triangle()));
        covered_once(&charts, &bent);
        for q in &charts {
            for t in bent.iter().filter(|t| {
                let (s, w) = st(q, t.shape.centre());
                q.shape.contains(s, w)
            }) {
                for c in corners(t).expect("a triangle") {
                    assert!(
                        (lightmap_uv_at(q, c) - bent_uv(c)).length() < 1e-5,
                        "{} reads {} at {c}, the mesh says {}",
                        q.name,
                        lightmap_uv_at(q, c),
                        bent_uv(c)
                    );
                }
            }
        }
        // Another mesh's lightmap: no merge across.
        let mut two = flat;
        for t in &mut two[16..] {
            t.lightmap = t.lightmap.map(|l| PatchLightmap { mesh: 1, ..l });
        }
        assert_eq!(super::charts(two, Charts::LightmapUvs).len(), 2);
    }

    #[test]
    fn an_l_shape_merges_into_parallelograms_that_cover_each_triangle_once() {
        // A 3 x 3 grid without its last cell: no single parallelogram.
        let mut triangles = grid(3);
        triangles.truncate(16);
        let charts = super::charts(triangles.clone(), Charts::Parallelograms);
        assert!((2..=3).contains(&charts.len()), "{} charts", charts.len());
        assert!((area(&charts) - 8.0).abs() < 1e-4);
        covered_once(&charts, &triangles);
    }

    #[test]
    fn quads_that_do_not_extend_each_other_stay_apart() {
        let cells = pair_triangles(grid(2));
        assert_eq!(cells.len(), 4);
        // Another material on one cell: the other three make an L, which
        // merges into two.
        let mut two = cells.clone();
        two[3].material = 1;
        let merged = merge_parallelograms(two);
        assert_eq!(merged.len(), 3);
        assert!(
            merged
                .iter()
                .any(|q| q.material == 1 && q.name == cells[3].name)
        );
        // A cell folded up along its shared edges: not in the plane.
        let mut folded = cells.clone();
        let (o, u, v) = folded[1].shape.frame();
        folded[1].shape = PatchShape::Quad {
            origin: o,
            u: u + Vec3::Y * 0.5,
            v,
        };
        let merged = merge_parallelograms(folded.clone());
        assert!(merged.iter().any(|q| q.name == folded[1].name));
        // A half-width cell beside a whole one shares part of an edge only.
        let half = vec![
            cells[0].clone(),
            Patch {
                name: "m/x".into(),
                shape: PatchShape::Quad {
                    origin: Vec3::new(1.0, 0.0, 0.0),
                    u: Vec3::new(1.0, 0.0, 0.0),
                    v: Vec3::new(0.0, 0.0, -0.5),
                },
                ..cells[0].clone()
            },
        ];
        assert_eq!(merge_parallelograms(half).len(), 2);
        // Hand-written quads (not of a mesh) never merge.
        let mut hand = cells;
        for q in &mut hand {
            q.mesh = false;
        }
        assert_eq!(merge_parallelograms(hand.clone()), hand);
    }

    #[test]
    fn a_texture_merges_only_when_affine_and_then_reads_the_same_everywhere() {
        let texture = checker();
        let at = |q: Vec3| Vec2::new(q.x, -q.z) * 0.3 + Vec2::new(0.1, 0.2);
        let mut cells = grid(3);
        for p in &mut cells {
            let (o, u, v) = p.shape.frame();
            p.albedo_map = Some(AlbedoMap {
                texture: Arc::clone(&texture),
                uv: [at(o), at(o + u), at(o + u + v)],
            });
        }
        let charts = super::charts(cells.clone(), Charts::Parallelograms);
        assert_eq!(charts.len(), 1);
        let q = &charts[0];
        let map = q.albedo_map.as_ref().expect("keeps its texture");
        for tri in &cells {
            let (to, tu, tv) = tri.shape.frame();
            let p = to + tu * 0.6 + tv * 0.3;
            let (s, w) = st(q, p);
            let want = tri.albedo_map.as_ref().expect("textured").uv_at(0.6, 0.3);
            assert!((map.uv_at(s, w) - want).length() < 1e-5, "{}", tri.name);
        }
        // The coordinates scaled on one cell (still affine on it, as a pair
        // needs): it stays apart; the rest merge around it.
        let mut bent = cells;
        for tri in &mut bent[8..10] {
            if let Some(m) = tri.albedo_map.as_mut() {
                m.uv = m.uv.map(|c| c * 2.0);
            }
        }
        let merged = super::charts(bent.clone(), Charts::Parallelograms);
        assert!(merged.len() >= 3, "{} charts", merged.len());
        assert!(merged.iter().any(|q| q.name == "m/8+9"));
        covered_once(&merged, &bent);
    }

    mod random {
        use super::*;
        use proptest::prelude::*;

        /// A grid of `n` x `m` cells of `sx` x `sz` metres, far from the
        /// origin, each cut along a random diagonal, some left out, some
        /// of another material, the triangles in a random order.
        fn floor(n: u32, m: u32, (sx, sz): (f32, f32), seed: u64) -> Vec<Patch> {
            let mut rng = fastrand::Rng::with_seed(seed);
            let at = |i: u32, j: u32| Vec3::new(30.0 + i as f32 * sx, 2.0, -(j as f32) * sz);
            let mut out = Vec::new();
            for j in 0..m {
                for i in 0..n {
                    if rng.f32() < 0.15 {
                        continue;
                    }
                    let material = u32::from(rng.f32() < 0.2);
                    let c = [at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)];
                    let k = if rng.bool() { 0 } else { 1 };
                    for t in [[c[k], c[k + 1], c[k + 2]], [c[k], c[k + 2], c[(k + 3) % 4]]] {
                        let name = format!("m/{}", out.len());
                        out.push(Patch {
                            material,
                            ..triangle(&name, t[0], t[1], t[2])
                        });
                    }
                }
            }
            rng.shuffle(&mut out);
            out
        }

        proptest! {
            #![proptest_config(ProptestConfig::with_cases(64))]
            /// Whatever the grid's holes, materials and order: every
            /// triangle lies on exactly one chart of its material, the
            /// charts cover the same area, hold every triangle once, and a
            /// chart of equal cells is as large as its cells.
            #[test]
            fn merged_charts_cover_every_triangle_once(
                n in 1u32..7, m in 1u32..7, sx in 0.05f32..2.0, sz in 0.05f32..2.0, seed in any::<u64>()
            ) {
                let triangles = floor(n, m, (sx, sz), seed);
                let charts = super::super::charts(triangles.clone(), Charts::Parallelograms);
                let total: f32 = area(&triangles);
                prop_assert!((area(&charts) - total).abs() <= 1e-4 * total.max(1e-3));
                for t in &triangles {
                    let c = t.shape.centre();
                    let on: Vec<&Patch> = charts
                        .iter()
                        .filter(|q| {
                            let (s, w) = st(q, c);
                            q.shape.contains(s, w)
                        })
                        .collect();
                    prop_assert_eq!(on.len(), 1, "{} on {} charts", t.name, on.len());
                    prop_assert_eq!(on[0].material, t.material);
                }
                let held: usize = charts
                    .iter()
                    .map(|q| match (q.shape.is_triangle(), q.name.rsplit_once(':')) {
                        (true, _) => 1,
                        (false, Some((_, k))) => k.parse().unwrap_or(0),
                        (false, None) => 2,
                    })
                    .sum();
                prop_assert_eq!(held, triangles.len());
                for q in &charts {
                    let cells = (q.cells[0] * q.cells[1]) as f32;
                    prop_assert!((q.shape.area() - cells * sx * sz).abs() <= 1e-3 * q.shape.area());
                }
            }
        }
    }
}
