//! Lightmap UVs generated for a mesh that brings none (issue 18, item 2).
//!
//! Wallner §2 packs a lightmap per triangle into the atlas; lightmap bakers
//! instead cut a mesh into charts that each unfold onto the plane with
//! little distortion, so that a texel straddling two triangles of one chart
//! is one element and the light runs across their edge without a seam.
//! This module builds such charts in three steps:
//!
//! 1. **Segment by normal.** Triangles are welded into a graph through
//!    shared edges (corners equal to [`WELD`] of the mesh's extent; an edge
//!    of more than two triangles joins none). From the largest unassigned
//!    triangle, a chart grows across edges to every triangle whose normal is
//!    within [`MAX_ANGLE_DEG`] of the seed's, as long as its projection onto
//!    the seed's plane overlaps none of the chart's (a surface that curls
//!    back over itself starts a new chart). A flat region is one chart; a
//!    sphere a few dozen.
//! 2. **Project.** Each chart is projected orthographically onto its seed's
//!    plane (affine on every triangle, so triangles that form a parallelogram
//!    in space form one in UV and merge there, `pairs.rs`; a triangle within
//!    the angle keeps at least `cos` of its area) and turned so that its
//!    smallest enclosing rectangle is axis-aligned (an edge of that rectangle
//!    lies on an edge of the convex hull).
//! 3. **Pack.** The rectangles, in texels at the mesh's density, go onto
//!    shelves (tallest first) of the width that makes the square block
//!    smallest, [`GAP`] texels apart and [`BORDER`] texels from the block's
//!    edge, so that an island's texels, the gutter publication fills around
//!    it and the bilinear reads of its surface never touch another's
//!    (`atlas/uv.rs`, `Atlas::to_image`). `uv::block_side` then sizes the
//!    block from the same density, never smaller than the packing assumed
//!    (projection only shrinks UV area), so the gaps hold.

use std::collections::HashMap;

use glam::{DVec2, Vec2, Vec3};

/// Charts take triangles whose normals are within this angle of their
/// seed's (degrees): a triangle at the limit is stretched by at most
/// `1 / cos` (15%) across the chart's plane.
pub const MAX_ANGLE_DEG: f32 = 30.0;
/// Texels between two charts' rectangles: each island's own texels reach
/// at most one texel beyond it, and its gutter one more.
pub const GAP: f32 = 3.0;
/// Texels between a chart and the block's edge (the atlas adds a ring of
/// its own, `atlas::BLOCK_RING`).
pub const BORDER: f32 = 2.0;
/// Corners closer than this fraction of the mesh's extent are one vertex.
pub const WELD: f32 = 1e-5;
/// The largest block generated (texels); larger meshes are scaled down to
/// it (fewer texels per metre than their density asks).
pub const MAX_SIDE: f32 = crate::uv::MAX_SIDE as f32;

/// A mesh's generated lightmap UVs.
#[derive(Debug, Clone)]
pub struct Unwrap {
    /// Per triangle, its corners' UVs in [0, 1]², in the triangle's corner
    /// order.
    pub uvs: Vec<[Vec2; 3]>,
    /// Per triangle, the chart it lies on.
    pub chart: Vec<u32>,
    /// Number of charts.
    pub charts: usize,
    /// Per chart, the normal of the plane it is projected onto (its first
    /// triangle's).
    pub axes: Vec<Vec3>,
    /// The side of the square block the packing assumed (texels).
    pub side: f32,
}

mod lscm;

pub use lscm::{MAX_CHART_ANGLE, PADDING};

/// Which unwrapper generates a mesh's lightmap UVs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Unwrapper {
    /// This module's own projected charts ([`project`]): the default, as
    /// accurate at a player's eye on the real levels as the crate's and
    /// with a smaller atlas (BENCHMARKS.md §9).
    #[default]
    Projected,
    /// The `uvunwrap` crate (`unwrap/lscm.rs`): segmentation, conformal
    /// flattening, packing by shape; fewer charts and elements, most on
    /// curved surfaces.
    Uvunwrap,
}

/// Generates lightmap UVs for `triangles` (each triangle's front is the
/// side its corners run counter-clockwise around) at `density` texels per
/// metre, with `unwrapper`.
pub fn unwrap(triangles: &[[Vec3; 3]], density: f32, unwrapper: Unwrapper) -> Unwrap {
    unwrap_graded(triangles, density, unwrapper, (&[], &[]))
}

/// [`unwrap`] with a refinement level per triangle (`near_lights.rs`;
/// empty: none) and a material per triangle (empty: one): under the
/// projection, a chart takes triangles of one level and one material only
/// and is laid out at `2^level × density`. The `uvunwrap` crate's charts
/// ignore both.
///
/// A texel holds radiosity, the light that leaves the surface with its
/// albedo in it (PROTOCOL.md), so it can stand for one material only: a
/// dark sticky note (albedo 0.1) set into a white frame of the same
/// plane, one chart, read the frame's light, eight times its own (the
/// garage's worst point at the eye, BENCHMARKS.md §1).
pub fn unwrap_graded(
    triangles: &[[Vec3; 3]],
    density: f32,
    unwrapper: Unwrapper,
    (levels, materials): (&[u8], &[u32]),
) -> Unwrap {
    match unwrapper {
        Unwrapper::Uvunwrap => lscm::unwrap(triangles, density),
        Unwrapper::Projected => project_graded(triangles, density, (levels, materials)),
    }
}

/// Generates lightmap UVs for `triangles` (any corner order; each
/// triangle's front is the side its corners run counter-clockwise around)
/// at `density` texels per metre by projecting near-planar charts (the
/// module's three steps).
pub fn project(triangles: &[[Vec3; 3]], density: f32) -> Unwrap {
    project_graded(triangles, density, (&[], &[]))
}

/// [`project`] with a refinement level and a material per triangle
/// ([`unwrap_graded`]).
pub fn project_graded(
    triangles: &[[Vec3; 3]],
    density: f32,
    (levels, materials): (&[u8], &[u32]),
) -> Unwrap {
    let n = triangles.len();
    let level = |t: usize| levels.get(t).copied().unwrap_or(0);
    let material = |t: usize| materials.get(t).copied().unwrap_or(0);
    let normals: Vec<Vec3> = triangles
        .iter()
        .map(|[a, b, c]| (*b - *a).cross(*c - *a).normalize_or_zero())
        .collect();
    let areas: Vec<f32> = triangles
        .iter()
        .map(|[a, b, c]| 0.5 * (*b - *a).cross(*c - *a).length())
        .collect();
    let neighbours = neighbours(triangles);

    // 1. Segment: seeds by decreasing area.
    let mut order: Vec<u32> = (0..n as u32).collect();
    order.sort_by(|&a, &b| areas[b as usize].total_cmp(&areas[a as usize]));
    let cos_max = MAX_ANGLE_DEG.to_radians().cos();
    let mut chart = vec![u32::MAX; n];
    let mut tried = vec![u32::MAX; n];
    let mut charts: Vec<Chart> = Vec::new();
    let mut axes = Vec::new();
    let mut queue = Vec::new();
    for &seed in &order {
        if chart[seed as usize] != u32::MAX {
            continue;
        }
        let id = charts.len() as u32;
        let normal = normals[seed as usize];
        // `tangent × bitangent = normal`: a triangle counter-clockwise
        // around the normal stays counter-clockwise in the plane.
        let tangent = normal.any_orthonormal_vector();
        let bitangent = normal.cross(tangent);
        let project = |p: Vec3| DVec2::new(p.dot(tangent).into(), p.dot(bitangent).into());
        let flat = |t: u32| triangles[t as usize].map(project);
        let seed_flat = flat(seed);
        let cell = seed_flat
            .iter()
            .zip(seed_flat.iter().cycle().skip(1))
            .map(|(a, b)| a.distance(*b))
            .fold(0.0, f64::max)
            .max(1e-9);
        let mut grid = Grid {
            cell,
            cells: HashMap::new(),
            flat: Vec::new(),
        };
        let mut members = Vec::new();
        queue.clear();
        queue.push(seed);
        tried[seed as usize] = id;
        while let Some(t) = queue.pop() {
            let p = flat(t);
            if grid.overlaps(&p) {
                continue;
            }
            grid.insert(p);
            chart[t as usize] = id;
            members.push(t);
            for &m in &neighbours[t as usize] {
                let m = m as usize;
                if chart[m] == u32::MAX
                    && tried[m] != id
                    && level(m) == level(seed as usize)
                    && material(m) == material(seed as usize)
                    && normals[m].dot(normal) >= cos_max
                    && !normals[m].is_nan()
                {
                    tried[m] = id;
                    queue.push(m as u32);
                }
            }
        }
        let density = density * f32::from(1u8 << level(seed as usize).min(7));
        charts.push(Chart::new(members, grid.flat, density));
        axes.push(normal);
    }

    // 3. Pack: scaled down until the block fits `MAX_SIDE`.
    let mut scale = 1.0f32;
    let (mut places, mut side) = pack(&charts, scale);
    for _ in 0..64 {
        if side <= MAX_SIDE {
            break;
        }
        scale *= ((MAX_SIDE - 2.0 * BORDER) / (side - 2.0 * BORDER)).min(0.98);
        (places, side) = pack(&charts, scale);
    }
    let mut uvs = vec![[Vec2::ZERO; 3]; n];
    for (c, place) in charts.iter().zip(&places) {
        for (k, &t) in c.members.iter().enumerate() {
            uvs[t as usize] = c.texels[k].map(|p| (place + p * scale) / side);
        }
    }
    Unwrap {
        uvs,
        chart,
        charts: charts.len(),
        axes,
        side,
    }
}

/// Per welded edge (its two vertex ids, smaller first), the triangles that
/// have it.
type EdgeTriangles = HashMap<(u32, u32), Vec<u32>>;

/// The edges of a triangle soup after welding its corners (equal to
/// [`WELD`] of the extent): per welded edge (its two vertex ids, smaller
/// first), the triangles that have it, and per triangle its corners' ids.
fn welded_edges(triangles: &[[Vec3; 3]]) -> (EdgeTriangles, Vec<[u32; 3]>) {
    let (corners, _) = weld(triangles);
    let mut edges: HashMap<(u32, u32), Vec<u32>> = HashMap::new();
    for (t, v) in corners.iter().enumerate() {
        for k in 0..3 {
            let (a, b) = (v[k], v[(k + 1) % 3]);
            if a != b {
                edges
                    .entry((a.min(b), a.max(b)))
                    .or_default()
                    .push(t as u32);
            }
        }
    }
    (edges, corners)
}

/// A triangle soup's corners welded (equal to [`WELD`] of its extent): per
/// triangle its corners' vertex ids, and per id the first corner's
/// position.
fn weld(triangles: &[[Vec3; 3]]) -> (Vec<[u32; 3]>, Vec<Vec3>) {
    let (mut lo, mut hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
    for t in triangles {
        for p in t {
            lo = lo.min(*p);
            hi = hi.max(*p);
        }
    }
    let step = ((hi - lo).max_element() * WELD).max(f32::MIN_POSITIVE);
    let mut ids: HashMap<[i64; 3], u32> = HashMap::new();
    let mut id = |p: Vec3| {
        let k = ((p - lo) / step).round();
        let key = [k.x as i64, k.y as i64, k.z as i64];
        let next = ids.len() as u32;
        *ids.entry(key).or_insert(next)
    };
    let corners: Vec<[u32; 3]> = triangles.iter().map(|tri| tri.map(&mut id)).collect();
    let mut positions = vec![Vec3::ZERO; ids.len()];
    let mut seen = vec![false; ids.len()];
    for (tri, v) in triangles.iter().zip(&corners) {
        for (p, &k) in tri.iter().zip(v) {
            if !seen[k as usize] {
                seen[k as usize] = true;
                positions[k as usize] = *p;
            }
        }
    }
    (corners, positions)
}

/// Each triangle's neighbours across its edges (corners welded to [`WELD`]
/// of the extent; an edge shared by more than two triangles joins none).
fn neighbours(triangles: &[[Vec3; 3]]) -> Vec<Vec<u32>> {
    let (edges, _) = welded_edges(triangles);
    let mut out = vec![Vec::new(); triangles.len()];
    for list in edges.values() {
        if let [a, b] = list[..]
            && a != b
        {
            out[a as usize].push(b);
            out[b as usize].push(a);
        }
    }
    // The map's order is not stable from run to run; the charts grown from
    // these lists must be.
    for list in &mut out {
        list.sort_unstable();
    }
    out
}

/// Two corners' vertex normals within this cosine (about 1.1°) are the
/// same normal: the asset shades the surface smoothly across their edge.
pub const SMOOTH_NORMAL_COS: f32 = 0.9998;
/// Across an edge whose faces meet at more than this angle (degrees) the
/// light is not made continuous, whatever the vertex normals say: a
/// smoothed hard corner (a box exported with averaged normals) keeps its
/// crease.
pub const SMOOTH_MAX_DEG: f32 = 60.0;

/// The edges where a mesh's own vertex normals say its surface is smooth:
/// welded edges of exactly two triangles whose normals agree at both of
/// the edge's ends (within [`SMOOTH_NORMAL_COS`]) and whose faces meet
/// within [`SMOOTH_MAX_DEG`]. `normals` holds, per triangle, its corners'
/// vertex normals in its corner order, or `None` where the asset gave none
/// (glTF then asks for flat shading: no smooth edges). Coplanar
/// neighbours count too (their seams are stitched anyway). Each edge is
/// returned once, as its two end points.
pub fn smooth_edges(triangles: &[[Vec3; 3]], normals: &[Option<[Vec3; 3]>]) -> Vec<[Vec3; 2]> {
    let (edges, corners) = welded_edges(triangles);
    let face = |t: usize| {
        let [a, b, c] = triangles[t];
        (b - a).cross(c - a).normalize_or_zero()
    };
    // Vertex normal of triangle `t` at welded vertex `v`.
    let at = |t: usize, v: u32| -> Option<Vec3> {
        let k = corners[t].iter().position(|&c| c == v)?;
        Some(normals.get(t).copied().flatten()?[k].normalize_or_zero())
    };
    let max_cos = SMOOTH_MAX_DEG.to_radians().cos();
    let mut out: Vec<(u64, [Vec3; 2])> = edges
        .iter()
        .filter_map(|(&(a, b), list)| {
            let [s, t] = list[..] else { return None };
            let (s, t) = (s as usize, t as usize);
            if s == t || face(s).dot(face(t)) < max_cos {
                return None;
            }
            for v in [a, b] {
                if at(s, v)?.dot(at(t, v)?) < SMOOTH_NORMAL_COS {
                    return None;
                }
            }
            let k = corners[s].iter().position(|&c| c == a)?;
            let l = corners[s].iter().position(|&c| c == b)?;
            Some((
                (s as u64 * 3 + k as u64) * 3 + l as u64,
                [triangles[s][k], triangles[s][l]],
            ))
        })
        .collect();
    // In triangle order (the map's order is not stable).
    out.sort_unstable_by_key(|&(key, _)| key);
    out.into_iter().map(|(_, e)| e).collect()
}

/// A chart's triangles projected so far, on a uniform grid of their
/// bounding boxes (cells the seed's longest edge wide).
struct Grid {
    cell: f64,
    cells: HashMap<(i64, i64), Vec<u32>>,
    flat: Vec<[DVec2; 3]>,
}

impl Grid {
    fn range(&self, p: &[DVec2; 3]) -> (i64, i64, i64, i64) {
        let lo = p[0].min(p[1]).min(p[2]) / self.cell;
        let hi = p[0].max(p[1]).max(p[2]) / self.cell;
        (
            lo.x.floor() as i64,
            lo.y.floor() as i64,
            hi.x.floor() as i64,
            hi.y.floor() as i64,
        )
    }

    /// Whether `p` covers part of a triangle already in the chart (more
    /// than a millionth of the smaller's area: shared edges and corners do
    /// not count).
    fn overlaps(&self, p: &[DVec2; 3]) -> bool {
        let area = super::gltf::signed_area(p).abs();
        let (x0, y0, x1, y1) = self.range(p);
        // A triangle far larger than the cells (a big one beside small
        // ones) is tested against every member instead.
        if (x1 - x0 + 1) * (y1 - y0 + 1) > 4 * self.flat.len().max(1) as i64 {
            return self.flat.iter().any(|q| Self::meet(p, area, q));
        }
        for y in y0..=y1 {
            for x in x0..=x1 {
                if let Some(list) = self.cells.get(&(x, y))
                    && list
                        .iter()
                        .any(|&k| Self::meet(p, area, &self.flat[k as usize]))
                {
                    return true;
                }
            }
        }
        false
    }

    fn meet(p: &[DVec2; 3], area: f64, q: &[DVec2; 3]) -> bool {
        let smaller = area.min(super::gltf::signed_area(q).abs());
        super::gltf::intersection_area(p, q) > 1e-6 * smaller
    }

    fn insert(&mut self, p: [DVec2; 3]) {
        let k = self.flat.len() as u32;
        let (x0, y0, x1, y1) = self.range(&p);
        if (x1 - x0 + 1) * (y1 - y0 + 1) <= 1 << 16 {
            for y in y0..=y1 {
                for x in x0..=x1 {
                    self.cells.entry((x, y)).or_default().push(k);
                }
            }
        }
        self.flat.push(p);
    }
}

/// One chart: its triangles and their corners in texels, turned to its
/// smallest enclosing rectangle, which starts at the origin.
struct Chart {
    members: Vec<u32>,
    texels: Vec<[Vec2; 3]>,
    size: Vec2,
}

impl Chart {
    fn new(members: Vec<u32>, flat: Vec<[DVec2; 3]>, density: f32) -> Chart {
        let points: Vec<DVec2> = flat.iter().flatten().copied().collect();
        let axis = smallest_rectangle_axis(&points);
        let turn = |p: DVec2| DVec2::new(p.dot(axis), axis.perp_dot(p));
        // `turn` is a rotation (determinant +1), so triangles keep their
        // orientation.
        let mut texels: Vec<[Vec2; 3]> = flat
            .iter()
            .map(|t| t.map(|p| (turn(p) * f64::from(density)).as_vec2()))
            .collect();
        let (mut lo, mut hi) = (Vec2::INFINITY, Vec2::NEG_INFINITY);
        for p in texels.iter().flatten() {
            lo = lo.min(*p);
            hi = hi.max(*p);
        }
        for t in &mut texels {
            for p in t {
                *p -= lo;
            }
        }
        Chart {
            members,
            texels,
            size: hi - lo,
        }
    }
}

/// The unit direction along which the smallest-area rectangle around
/// `points` lies: one of its sides is collinear with an edge of their
/// convex hull, so each hull edge's direction is tried.
fn smallest_rectangle_axis(points: &[DVec2]) -> DVec2 {
    let hull = convex_hull(points);
    if hull.len() < 3 {
        return DVec2::X;
    }
    // At most 256 directions on a hull of many edges (a disk's).
    let stride = hull.len().div_ceil(256);
    let mut best = (f64::INFINITY, DVec2::X);
    for k in (0..hull.len()).step_by(stride) {
        let axis = (hull[(k + 1) % hull.len()] - hull[k]).normalize_or_zero();
        if axis == DVec2::ZERO {
            continue;
        }
        let (mut lo, mut hi) = (DVec2::INFINITY, DVec2::NEG_INFINITY);
        for p in &hull {
            let q = DVec2::new(p.dot(axis), axis.perp_dot(*p));
            lo = lo.min(q);
            hi = hi.max(q);
        }
        let area = (hi - lo).x * (hi - lo).y;
        if area < best.0 - 1e-12 * area.abs() {
            best = (area, axis);
        }
    }
    best.1
}

/// Andrew's monotone chain: the hull counter-clockwise, without
/// collinear points.
fn convex_hull(points: &[DVec2]) -> Vec<DVec2> {
    let mut p = points.to_vec();
    p.sort_by(|a, b| a.x.total_cmp(&b.x).then(a.y.total_cmp(&b.y)));
    p.dedup();
    if p.len() < 3 {
        return p;
    }
    // The lower chain left to right, then the upper right to left.
    let mut hull: Vec<DVec2> = Vec::with_capacity(2 * p.len());
    for chain in [p.clone(), p.iter().rev().copied().collect()] {
        let start = hull.len();
        for q in chain {
            while hull.len() >= start + 2 {
                let (a, b) = (hull[hull.len() - 2], hull[hull.len() - 1]);
                if (b - a).perp_dot(q - a) > 0.0 {
                    break;
                }
                hull.pop();
            }
            hull.push(q);
        }
        hull.pop();
    }
    hull
}

/// Shelf packing of the charts' rectangles (times `scale`), tallest first,
/// at the shelf width that gives the smallest square: each chart's corner
/// in texels, and the square's side.
fn pack(charts: &[Chart], scale: f32) -> (Vec<Vec2>, f32) {
    let sizes: Vec<Vec2> = charts.iter().map(|c| c.size * scale).collect();
    let mut order: Vec<usize> = (0..sizes.len()).collect();
    order.sort_by(|&a, &b| sizes[b].y.total_cmp(&sizes[a].y));
    let area: f32 = sizes.iter().map(|s| (s.x + GAP) * (s.y + GAP)).sum();
    let widest = sizes.iter().map(|s| s.x).fold(0.0, f32::max);
    let shelves = |width: f32| {
        let mut places = vec![Vec2::ZERO; sizes.len()];
        let (mut x, mut y, mut row, mut right) = (0.0f32, 0.0f32, 0.0f32, 0.0f32);
        for &k in &order {
            let s = sizes[k];
            if x > 0.0 && x + s.x > width {
                y += row + GAP;
                (x, row) = (0.0, 0.0);
            }
            places[k] = Vec2::new(x, y) + Vec2::splat(BORDER);
            right = right.max(x + s.x);
            x += s.x + GAP;
            row = row.max(s.y);
        }
        let side = right.max(y + row) + 2.0 * BORDER;
        (places, side)
    };
    let mut best: Option<(Vec<Vec2>, f32)> = None;
    for step in 0..12 {
        let width = (area.sqrt() * (1.0 + 0.1 * step as f32)).max(widest);
        let (places, side) = shelves(width);
        if best.as_ref().is_none_or(|b| side < b.1) {
            best = Some((places, side));
        }
    }
    best.unwrap_or_else(|| (Vec::new(), 2.0 * BORDER))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An `n` x `n` grid of unit cells, each cut into two triangles.
    fn grid(n: usize) -> Vec<[Vec3; 3]> {
        let p = |i: usize, j: usize| Vec3::new(i as f32, 0.0, -(j as f32));
        let mut out = Vec::new();
        for j in 0..n {
            for i in 0..n {
                out.push([p(i, j), p(i + 1, j), p(i + 1, j + 1)]);
                out.push([p(i, j), p(i + 1, j + 1), p(i, j + 1)]);
            }
        }
        out
    }

    #[test]
    fn a_chart_never_joins_two_materials() {
        let tris = grid(4);
        // The first two rows one material, the last two another.
        let materials: Vec<u32> = (0..tris.len()).map(|t| u32::from(t >= 16)).collect();
        let u = project_graded(&tris, 8.0, (&[], &materials));
        assert_eq!(u.charts, 2);
        for (t, &m) in materials.iter().enumerate() {
            assert_eq!(u.chart[t] == u.chart[0], m == materials[0], "triangle {t}");
        }
        // One material: one chart, as without materials.
        assert_eq!(project_graded(&tris, 8.0, (&[], &[7; 32])).charts, 1);
    }

    #[test]
    fn a_flat_grid_is_one_chart_and_its_uvs_are_affine() {
        let tris = grid(6);
        let u = project(&tris, 4.0);
        assert_eq!(u.charts, 1);
        // An affine map sends the cell corners to a square grid: every
        // cell's two triangles have equal UV area, in texels 4² each.
        for (t, uv) in tris.iter().zip(&u.uvs) {
            let area = crate::uv::uv_area(uv) * u.side * u.side;
            assert!((area - 8.0).abs() < 1e-2, "{t:?}: {area}");
        }
        // 6 m at 4 texels/m plus the borders.
        assert!((u.side - (24.0 + 2.0 * BORDER)).abs() < 1e-3, "{}", u.side);
    }

    /// A closed UV sphere seen from outside (`segments` around, `rings`
    /// from pole to pole), radius 1.
    fn sphere(segments: usize, rings: usize) -> Vec<[Vec3; 3]> {
        let at = |i: usize, j: usize| {
            let theta = std::f32::consts::PI * j as f32 / rings as f32;
            let phi = std::f32::consts::TAU * (i % segments) as f32 / segments as f32;
            Vec3::new(
                theta.sin() * phi.cos(),
                theta.cos(),
                -theta.sin() * phi.sin(),
            )
        };
        let mut out = Vec::new();
        for j in 0..rings {
            for i in 0..segments {
                let (a, b, c, d) = (at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1));
                if j > 0 {
                    out.push([a, d, b]);
                }
                if j + 1 < rings {
                    out.push([b, d, c]);
                }
            }
        }
        out
    }

    /// What both unwrappers must give: UVs in [0, 1], each triangle the
    /// same orientation in UV as in space (seen from its front), no two
    /// triangles overlapping (the check `TEXCOORD_1` gets), and every
    /// triangle's normal within `cos_max` of its chart's axis.
    fn check_charts(tris: &[[Vec3; 3]], u: &Unwrap, cos_max: f32) {
        assert_eq!(u.uvs.len(), tris.len());
        for uv in &u.uvs {
            for p in uv {
                assert!(
                    (0.0..=1.0).contains(&p.x) && (0.0..=1.0).contains(&p.y),
                    "{uv:?}"
                );
            }
            assert!(crate::uv::uv_area(uv) > 0.0, "{uv:?} is turned over");
        }
        let overlaps = crate::gltf::find_uv_overlaps(&u.uvs, 4).expect("checkable");
        assert!(overlaps.is_empty(), "{overlaps:?}");
        assert_eq!(u.axes.len(), u.charts);
        for (t, &c) in tris.iter().zip(&u.chart) {
            let n = (t[1] - t[0]).cross(t[2] - t[0]).normalize();
            assert!(n.dot(u.axes[c as usize]) >= cos_max, "{t:?} on chart {c}");
        }
    }

    /// What every unwrap must give: UVs in [0, 1], each triangle the same
    /// orientation in UV as in space (seen from its front), no two
    /// triangles overlapping (the check `TEXCOORD_1` gets), every
    /// triangle's normal within the angle of its chart's first, and
    /// different charts at least [`GAP`] texels apart at the side
    /// `uv::block_side` will give the block.
    fn check(tris: &[[Vec3; 3]], u: &Unwrap, density: f32) {
        check_charts(tris, u, MAX_ANGLE_DEG.to_radians().cos() - 1e-5);
        // Gaps between charts, in texels of the block the atlas will give.
        let area: f32 = tris
            .iter()
            .map(|[a, b, c]| 0.5 * (*b - *a).cross(*c - *a).length())
            .sum();
        let uv_area: f32 = u.uvs.iter().map(crate::uv::uv_area).sum();
        let side = density * (area / uv_area).sqrt();
        assert!(
            side >= u.side - 1e-3,
            "block {side} smaller than packed {}",
            u.side
        );
        let mut boxes: HashMap<u32, (Vec2, Vec2)> = HashMap::new();
        for (uv, &c) in u.uvs.iter().zip(&u.chart) {
            let b = boxes
                .entry(c)
                .or_insert((Vec2::INFINITY, Vec2::NEG_INFINITY));
            for p in uv {
                b.0 = b.0.min(*p * side);
                b.1 = b.1.max(*p * side);
            }
        }
        let boxes: Vec<(Vec2, Vec2)> = boxes.into_values().collect();
        assert_eq!(boxes.len(), u.charts);
        for (i, a) in boxes.iter().enumerate() {
            assert!(
                a.0.min_element() >= BORDER - 1e-3 && a.1.max_element() <= side - BORDER + 1e-3
            );
            for b in &boxes[i + 1..] {
                let apart = (b.0 - a.1).max(a.0 - b.1).max_element();
                assert!(
                    apart >= GAP - 1e-3,
                    "charts {a:?} and {b:?} are {apart} texels apart"
                );
            }
        }
    }

    #[test]
    fn a_box_is_six_charts() {
        let tris = cube();
        let u = project(&tris, 8.0);
        assert_eq!(u.charts, 6);
        check(&tris, &u, 8.0);
    }

    #[test]
    fn a_sphere_is_cut_into_near_planar_charts_that_do_not_overlap() {
        let tris = sphere(32, 16);
        let u = project(&tris, 20.0);
        check(&tris, &u, 20.0);
        // Far fewer charts than triangles (each a patch of its own on
        // Lightwire's charts), more than the six of a cube.
        assert!(
            u.charts > 6 && u.charts * 10 < tris.len(),
            "{} charts",
            u.charts
        );
    }

    /// A ramp that winds twice around a column: every turn projects onto
    /// the ones above it, so charts must stop where the projection would
    /// overlap, even though the normal allows more.
    #[test]
    fn a_surface_that_curls_over_itself_is_cut_where_its_projection_would_overlap() {
        let mut tris = Vec::new();
        let steps = 96;
        let at = |k: usize, r: f32| {
            let a = std::f32::consts::TAU * k as f32 / 48.0;
            Vec3::new(r * a.cos(), 0.01 * k as f32, -r * a.sin())
        };
        for k in 0..steps {
            let (a, b, c, d) = (at(k, 1.0), at(k, 2.0), at(k + 1, 2.0), at(k + 1, 1.0));
            tris.push([a, b, c]);
            tris.push([a, c, d]);
        }
        let u = project(&tris, 10.0);
        check(&tris, &u, 10.0);
        // Nearly flat (the ramp rises 1 cm per 7.5°, its normal within 5°
        // of vertical): the normal alone would make it one chart.
        assert!(u.charts >= 2, "{} charts", u.charts);
    }

    #[test]
    fn a_mesh_too_large_for_the_largest_block_is_scaled_down_to_it() {
        let tris = grid(8);
        // 8 m at 1,000 texels/m would be 8,000 texels.
        let u = project(&tris, 1000.0);
        assert!(u.side <= MAX_SIDE && u.side > MAX_SIDE * 0.9, "{}", u.side);
        assert_eq!(u.charts, 1);
    }

    /// Vertex normals per corner: the sphere's radial ones (smooth), or
    /// each triangle's own face normal (flat).
    fn normals_of(tris: &[[Vec3; 3]], smooth: bool) -> Vec<Option<[Vec3; 3]>> {
        tris.iter()
            .map(|t| {
                let face = (t[1] - t[0]).cross(t[2] - t[0]).normalize();
                Some(t.map(|p| if smooth { p.normalize() } else { face }))
            })
            .collect()
    }

    #[test]
    fn smooth_edges_are_where_vertex_normals_agree_and_faces_meet_gently() {
        let (segments, rings) = (12, 6);
        let tris = sphere(segments, rings);
        // Every edge of a closed mesh joins two triangles: edges = 3/2 of
        // the triangles, all of them smooth on radial normals.
        let all = smooth_edges(&tris, &normals_of(&tris, true));
        assert_eq!(all.len(), tris.len() * 3 / 2);
        for [a, b] in &all {
            assert!((a.length() - 1.0).abs() < 1e-5 && (b.length() - 1.0).abs() < 1e-5);
        }
        // Flat normals: only the diagonals inside the quads between two
        // rings (their two triangles are coplanar); none: no smooth edge.
        assert_eq!(
            smooth_edges(&tris, &normals_of(&tris, false)).len(),
            segments * (rings - 2)
        );
        assert!(smooth_edges(&tris, &vec![None; tris.len()]).is_empty());
        // One triangle without normals: only its own edges drop out.
        let mut some = normals_of(&tris, true);
        some[7] = None;
        assert_eq!(smooth_edges(&tris, &some).len(), all.len() - 3);
        // A box whose corners carry averaged normals (every corner the same
        // normal for all its faces) still meets at 90°: no smooth edge.
        let cube = cube();
        let averaged: Vec<Option<[Vec3; 3]>> = cube
            .iter()
            .map(|t| Some(t.map(|p| (p - Vec3::splat(0.5)).normalize())))
            .collect();
        let kept = smooth_edges(&cube, &averaged);
        // Only the faces' own diagonals (coplanar) are smooth.
        assert_eq!(kept.len(), 6, "{kept:?}");
        for [a, b] in kept {
            let d = (b - a).abs();
            assert!(d.min_element() < 1e-6 && (d.max_element() - 1.0).abs() < 1e-6);
            assert_eq!(
                d.cmpgt(Vec3::splat(0.5)).bitmask().count_ones(),
                2,
                "a diagonal"
            );
        }
    }

    /// A unit cube's twelve triangles, counter-clockwise from outside.
    fn cube() -> Vec<[Vec3; 3]> {
        let c = |x: f32, y: f32, z: f32| Vec3::new(x, y, z);
        let quad = |a: Vec3, b: Vec3, d: Vec3, e: Vec3| [[a, b, d], [a, d, e]];
        [
            quad(c(0., 0., 1.), c(1., 0., 1.), c(1., 1., 1.), c(0., 1., 1.)),
            quad(c(1., 0., 0.), c(0., 0., 0.), c(0., 1., 0.), c(1., 1., 0.)),
            quad(c(1., 0., 1.), c(1., 0., 0.), c(1., 1., 0.), c(1., 1., 1.)),
            quad(c(0., 0., 0.), c(0., 0., 1.), c(0., 1., 1.), c(0., 1., 0.)),
            quad(c(0., 1., 1.), c(1., 1., 1.), c(1., 1., 0.), c(0., 1., 0.)),
            quad(c(0., 0., 0.), c(1., 0., 0.), c(1., 0., 1.), c(0., 0., 1.)),
        ]
        .into_iter()
        .flatten()
        .collect()
    }

    /// What the crate's unwrap must give the atlas: UVs in [0, 1], each
    /// triangle the same orientation in UV as in space, no overlaps, every
    /// triangle near the chart angle of its chart's mean normal, a block
    /// `uv::block_side` will not make smaller than the packing, and the
    /// texels two charts overlap at least 3 apart (each island's own
    /// texels, then one ring of gutter each) on that block. Charts packed
    /// by shape nest, so the gap is checked texel by texel, not on boxes.
    fn check_uvunwrap(tris: &[[Vec3; 3]], u: &Unwrap, density: f32) {
        // The crate bounds the angle on crease-preserving smoothed normals
        // against its own running average: on face normals against the
        // area-weighted mean a sphere's charts reach 44° at 30°.
        check_charts(tris, u, (1.5 * MAX_CHART_ANGLE).to_radians().cos());
        let area: f32 = tris
            .iter()
            .map(|[a, b, c]| 0.5 * (*b - *a).cross(*c - *a).length())
            .sum();
        let uv_area: f32 = u.uvs.iter().map(crate::uv::uv_area).sum();
        let side = density * (area / uv_area).sqrt();
        assert!(side >= u.side - 1e-2, "block {side} < packed {}", u.side);
        // Per texel, the chart whose triangles overlap it.
        let mut owner: HashMap<(i32, i32), u32> = HashMap::new();
        for (uv, &c) in u.uvs.iter().zip(&u.chart) {
            let q = uv.map(|p| p * side);
            let lo = q[0].min(q[1]).min(q[2]).floor();
            let hi = q[0].max(q[1]).max(q[2]).ceil();
            for j in lo.y as i32..hi.y as i32 {
                for i in lo.x as i32..hi.x as i32 {
                    if crate::atlas::uv::covered(&q, i as u32, j as u32).0 > 0.0 {
                        owner.insert((i, j), c);
                    }
                }
            }
        }
        for (&(i, j), &c) in &owner {
            for dj in -2..=2 {
                for di in -2..=2 {
                    if let Some(&d) = owner.get(&(i + di, j + dj)) {
                        assert_eq!(d, c, "texel ({i}, {j}) of chart {c} is near chart {d}");
                    }
                }
            }
        }
    }

    #[test]
    fn uvunwrap_keeps_a_flat_grid_one_chart_at_the_density_asked() {
        let tris = grid(6);
        let u = unwrap(&tris, 4.0, Unwrapper::Uvunwrap);
        check_uvunwrap(&tris, &u, 4.0);
        assert_eq!(u.charts, 1);
        for (t, uv) in tris.iter().zip(&u.uvs) {
            let area = crate::uv::uv_area(uv) * u.side * u.side;
            assert!((area - 8.0).abs() < 0.05, "{t:?}: {area}");
        }
    }

    #[test]
    fn uvunwrap_cuts_a_cube_at_its_edges() {
        let tris = cube();
        let u = unwrap(&tris, 8.0, Unwrapper::Uvunwrap);
        check_uvunwrap(&tris, &u, 8.0);
        assert_eq!(u.charts, 6);
    }

    /// Where a conformal map pays: a sphere unfolds into fewer charts than
    /// the projection's, none overlapping or closer than the gap.
    #[test]
    fn uvunwrap_unfolds_a_sphere_into_fewer_charts_than_the_projection() {
        let tris = sphere(32, 16);
        let u = unwrap(&tris, 20.0, Unwrapper::Uvunwrap);
        check_uvunwrap(&tris, &u, 20.0);
        let projected = project(&tris, 20.0);
        assert!(
            u.charts >= 2 && u.charts < projected.charts,
            "{} charts, {} projected",
            u.charts,
            projected.charts
        );
    }

    #[test]
    fn uvunwrap_scales_a_mesh_too_large_for_the_largest_block_down_to_it() {
        let tris = grid(8);
        let u = unwrap(&tris, 1000.0, Unwrapper::Uvunwrap);
        assert!(u.side <= MAX_SIDE && u.side > MAX_SIDE * 0.9, "{}", u.side);
        assert_eq!(u.charts, 1);
    }
}
