//! Seams between the islands of a mesh's own lightmap (issue 18, item 3).
//!
//! Where two patches meet along an edge and face the same way, a client
//! reading the lightmap bilinearly on either side of the edge must read the
//! same light, or it sees a line. On Lightwire's own charts the edge's
//! texels sit on the edge itself (thesis §4.1) and those of the two charts
//! are stitched as [`super::Atlas::seams`] groups. On a mesh's own lightmap
//! UVs (`atlas/uv.rs`) texels straddle the edges, and an edge that is a
//! seam of the asset's unwrap (its two sides lie in different places of the
//! lightmap, or in different meshes' lightmaps) is read from two unrelated
//! rows of texels plus the gutter around each island. No texel lies on the
//! seam, so no group of texels can be set equal.
//!
//! Instead, as lightmap bakers do, the published image is adjusted by least
//! squares: points along every such edge, [`SAMPLES_PER_TEXEL`] per texel
//! of the side that samples it, each give the equation "bilinear read on
//! side A = bilinear read on side B" over the (at most eight) texels the two
//! reads weigh. The texels those equations touch take the values that
//! minimize the equations' squared residuals plus, for each texel, `keep ×
//! (value − solved value)²`: texels that hold an element keep their light
//! with [`KEEP_HELD`], gutter texels (filled from their island's border)
//! are nearly free ([`KEEP_GUTTER`]), and no texel goes below zero. The
//! normal equations are symmetric positive definite and are solved per
//! channel by conjugate gradients (preconditioned by their diagonal),
//! starting from the last publication's adjustment, with the texels the
//! solution would pull below zero pinned there (an active set, kept from
//! one publication to the next), on every publication
//! ([`super::Atlas::to_image`]); no other texel changes.
//!
//! A pair of patches is a seam when both belong to one object, reflect
//! alike (`Scene::reflects_alike`: radiosity jumps where the albedo does), they face
//! the same way within 1° ([`super::SEAM_COS`]) or meet where the asset's
//! vertex normals say the surface is smooth (`UvMesh::smooth_edges`: a
//! faceted column or sphere, whose facets' flat light differs but which an
//! engine shades as one curved surface; a crease the asset keeps sharp is
//! left alone, its light differs for real), at least one lies on its
//! mesh's lightmap, and a point of their shared edge falls on different
//! places of the atlas on the two sides (more than [`SAME_PLACE`] texels
//! apart: otherwise it is an edge inside an island, whose texels are shared
//! and already bilinearly continuous).

use std::collections::HashMap;

use glam::{Vec2, Vec3};
use rayon::prelude::*;

use super::{Chart, ChartMap, NO_ELEMENT, SEAM_COS};
use crate::Scene;

/// Points per texel of the sampling side along a seam. Bilinear reads are
/// linear only within a texel cell and the two sides' cells do not line
/// up; at 2 the reads between the points drifted 5% apart on the atrium's
/// generated charts (`atrium_lightmap_island_seams_agree_within_two_percent`).
pub const SAMPLES_PER_TEXEL: f32 = 4.0;
/// How strongly a texel that holds an element keeps its solved value,
/// against a seam equation's weight of 1: a lone equation between two
/// such texels keeps `KEEP_HELD / (KEEP_HELD + 2)` of their difference
/// (0.5%: across a crease an asset shades smoothly the two sides may
/// differ by 100%, a lit facet beside an unlit one).
pub const KEEP_HELD: f64 = 0.01;
/// How strongly a gutter texel (no element) keeps its filled value.
pub const KEEP_GUTTER: f64 = 1e-3;
/// The two sides' points of a shared edge closer than this (texels) are
/// one place: the edge lies inside an island.
pub const SAME_PLACE: f32 = 1e-2;
/// Rounds of pinning texels the solution pulls below zero, and releasing
/// pinned ones it would raise, per call ([`IslandSeams::apply`]).
const PIN_ROUNDS: usize = 4;
/// The keep weight that holds a pinned texel at zero.
const KEEP_PINNED: f64 = 100.0;
/// Conjugate-gradient iterations at most, per channel.
const MAX_ITERATIONS: usize = 100;
/// Conjugate gradients stop when the residual's squared norm falls below
/// this fraction of the right-hand side's (a relative residual of 1e-4:
/// seams are compared at 1-2%).
const STOP: f64 = 1e-8;
/// Bilinear weights below this are left out.
const MIN_WEIGHT: f32 = 1e-4;

/// The seam equations of an atlas and the texels they touch.
#[derive(Debug, Clone, Default)]
pub struct IslandSeams {
    /// Row-major image index of every texel an equation reads.
    texels: Vec<u32>,
    /// Its `keep` weight.
    keep: Vec<f64>,
    /// Bilinear weights, as (index into `texels`, weight), of every
    /// equation's side A then side B.
    entries: Vec<(u32, f32)>,
    /// Per equation: where side A's entries start, where side B's start,
    /// where they end.
    rows: Vec<[u32; 3]>,
    /// Per channel, the change the last [`IslandSeams::apply`] made to each
    /// texel: the next one starts from it (a publication's image differs
    /// little from the last one's, so conjugate gradients start near the
    /// answer). Shared by clones of the atlas, which solve the same system.
    last: std::sync::Arc<std::sync::Mutex<Vec<LastSolve>>>,
}

/// One channel's solution of the last [`IslandSeams::apply`]: the change
/// it made to each texel, and which texels it pinned at zero.
#[derive(Debug, Clone, Default)]
struct LastSolve {
    change: Vec<f64>,
    pinned: Vec<bool>,
}

/// What finding seams needs of an atlas being built.
pub(super) struct Charts<'a> {
    pub(super) charts: &'a [Chart],
    pub(super) maps: &'a [Option<ChartMap>],
    pub(super) texel_element: &'a [u32],
    pub(super) width: u32,
    pub(super) height: u32,
}

impl Charts<'_> {
    /// Atlas pixel coordinates (texel `(x, y)`'s centre at `(x, y)`) of
    /// patch parameters `st` of patch `p`.
    fn pixel(&self, p: usize, st: Vec2) -> Vec2 {
        let c = self.charts[p];
        let map = self.maps[p].unwrap_or_else(|| ChartMap::native(c.w, c.h));
        Vec2::new(c.x as f32, c.y as f32) + map.to_chart(st)
    }

    /// The (at most four) texels a bilinear read at pixel coordinates `q`
    /// weighs, with their weights.
    fn bilinear(&self, q: Vec2) -> Vec<(u32, f32)> {
        let (w, h) = (self.width, self.height);
        if w < 2 || h < 2 {
            return Vec::new();
        }
        let x = q.x.clamp(0.0, (w - 1) as f32);
        let y = q.y.clamp(0.0, (h - 1) as f32);
        let (x0, y0) = ((x.floor() as u32).min(w - 2), (y.floor() as u32).min(h - 2));
        let (fx, fy) = (x - x0 as f32, y - y0 as f32);
        [
            (x0, y0, (1.0 - fx) * (1.0 - fy)),
            (x0 + 1, y0, fx * (1.0 - fy)),
            (x0, y0 + 1, (1.0 - fx) * fy),
            (x0 + 1, y0 + 1, fx * fy),
        ]
        .into_iter()
        .filter(|&(_, _, wt)| wt >= MIN_WEIGHT)
        .map(|(x, y, wt)| (y * w + x, wt))
        .collect()
    }
}

/// Patch parameters of a patch's corners: a quad's four, a triangle's three.
fn corner_params(triangle: bool) -> &'static [Vec2] {
    if triangle {
        &[Vec2::ZERO, Vec2::X, Vec2::ONE]
    } else {
        &[Vec2::ZERO, Vec2::X, Vec2::ONE, Vec2::Y]
    }
}

/// Edges by object and grid cell.
type Grid = HashMap<(u32, [i32; 3]), Vec<u32>>;

/// The 27 cells around and including a cell, as offsets.
fn neighbourhood() -> impl Iterator<Item = (i32, i32, i32)> {
    (-1..=1).flat_map(|dx| (-1..=1).flat_map(move |dy| (-1..=1).map(move |dz| (dx, dy, dz))))
}

/// One edge of a patch (or, for a smooth edge, of an object: `patch` holds
/// the object), in object space and in patch parameters.
#[derive(Clone, Copy)]
struct Edge {
    patch: u32,
    a: Vec3,
    b: Vec3,
    st_a: Vec2,
    st_b: Vec2,
}

impl Edge {
    /// Where `x` lies along the edge (0 at `a`, 1 at `b`) if it lies on it
    /// within `tolerance`.
    fn locate(&self, x: Vec3, tolerance: f32) -> Option<f32> {
        let d = self.b - self.a;
        let len2 = d.length_squared();
        if len2 <= 0.0 {
            return None;
        }
        let f = (x - self.a).dot(d) / len2;
        if !(-1e-4..=1.0 + 1e-4).contains(&f) {
            return None;
        }
        ((self.a + d * f - x).length() <= tolerance).then_some(f.clamp(0.0, 1.0))
    }
}

/// The edges of every patch, in patch order, each patch's from corner to
/// corner around it.
fn patch_edges(scene: &Scene) -> Vec<Edge> {
    scene
        .patches
        .iter()
        .enumerate()
        .flat_map(|(p, patch)| {
            let (o, u, v) = patch.shape.frame();
            let params = corner_params(patch.shape.is_triangle());
            (0..params.len()).map(move |k| {
                let (sa, sb) = (params[k], params[(k + 1) % params.len()]);
                Edge {
                    patch: p as u32,
                    a: o + u * sa.x + v * sa.y,
                    b: o + u * sb.x + v * sb.y,
                    st_a: sa,
                    st_b: sb,
                }
            })
        })
        .collect()
}

/// The cells of the grids edges are looked up on, and how close a point
/// must be to an edge to lie on it.
struct Space {
    /// The corner of the edges' bounding box.
    lo: Vec3,
    /// A cell's side.
    cell: f32,
    tolerance: f32,
}

impl Space {
    /// Cells about the median edge's length over the bounding box of
    /// `edges`, and a tolerance of 1e-5 of its extent.
    fn around(edges: &[Edge]) -> Space {
        // A grid of cells about the median edge's length; an edge is
        // entered in the cells of points half a cell apart along it, so a
        // point on it lies in one of those cells or next to one.
        let mut lengths: Vec<f32> = edges.iter().map(|e| (e.b - e.a).length()).collect();
        lengths.sort_by(f32::total_cmp);
        let (lo, hi) = edges.iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), e| (lo.min(e.a).min(e.b), hi.max(e.a).max(e.b)),
        );
        let extent = (hi - lo).max_element().max(1e-6);
        let cell = lengths[lengths.len() / 2].max(extent * 1e-4);
        let tolerance = extent * 1e-5;
        Space {
            lo,
            cell,
            tolerance,
        }
    }

    /// The cell `x` lies in.
    fn key(&self, x: Vec3) -> [i32; 3] {
        ((x - self.lo) / self.cell).floor().as_ivec3().to_array()
    }

    /// Enters edge `i` of `object` in `grid`, in the cells of points half a
    /// cell apart along it.
    fn enter(&self, grid: &mut Grid, object: u32, e: &Edge, i: u32) {
        let steps = (((e.b - e.a).length() / (0.5 * self.cell)).ceil() as usize).max(1);
        for k in 0..=steps {
            let list = grid
                .entry((object, self.key(e.a.lerp(e.b, k as f32 / steps as f32))))
                .or_default();
            if list.last() != Some(&i) {
                list.push(i);
            }
        }
    }
}

/// Edges where an asset's vertex normals say its surface is smooth
/// (`UvMesh::smooth_edges`), on a grid of their own.
struct SmoothEdges {
    edges: Vec<Edge>,
    grid: Grid,
}

impl SmoothEdges {
    /// The smooth edges of every mesh of `scene`, entered on cells of
    /// `space`.
    fn new(scene: &Scene, space: &Space) -> SmoothEdges {
        let edges: Vec<Edge> = scene
            .uv_meshes
            .iter()
            .flat_map(|m| {
                m.smooth_edges.iter().map(|&[a, b]| Edge {
                    patch: m.object,
                    a,
                    b,
                    st_a: Vec2::ZERO,
                    st_b: Vec2::ZERO,
                })
            })
            .collect();
        let mut grid = Grid::new();
        for (i, e) in edges.iter().enumerate() {
            space.enter(&mut grid, e.patch, e, i as u32);
        }
        SmoothEdges { edges, grid }
    }

    /// Whether `x` lies on a smooth edge of `object`.
    fn at(&self, space: &Space, object: u32, x: Vec3) -> bool {
        let [cx, cy, cz] = space.key(x);
        neighbourhood().any(|(dx, dy, dz)| {
            self.grid
                .get(&(object, [cx + dx, cy + dy, cz + dz]))
                .is_some_and(|list| {
                    list.iter()
                        .any(|&i| self.edges[i as usize].locate(x, space.tolerance).is_some())
                })
        })
    }
}

/// The seam equations found so far.
struct Equations<'a> {
    seams: IslandSeams,
    /// Where each texel an equation reads is in `seams.texels`.
    slot: HashMap<u32, u32>,
    /// The atlas's element per texel, which says whether a texel is gutter.
    texel_element: &'a [u32],
}

impl Equations<'_> {
    /// The index of `texel` in `seams.texels`, added with its keep weight
    /// the first time.
    fn index(&mut self, texel: u32) -> u32 {
        *self.slot.entry(texel).or_insert_with(|| {
            self.seams.texels.push(texel);
            self.seams.keep.push(
                if self.texel_element.get(texel as usize) == Some(&NO_ELEMENT) {
                    KEEP_GUTTER
                } else {
                    KEEP_HELD
                },
            );
            (self.seams.texels.len() - 1) as u32
        })
    }

    /// Adds the equation "bilinear read at `here` = bilinear read at
    /// `there`" (atlas pixel coordinates).
    fn push(&mut self, charts: &Charts, here: Vec2, there: Vec2) {
        let start = self.seams.entries.len() as u32;
        for (t, w) in charts.bilinear(here) {
            let i = self.index(t);
            self.seams.entries.push((i, w));
        }
        let mid = self.seams.entries.len() as u32;
        for (t, w) in charts.bilinear(there) {
            let i = self.index(t);
            self.seams.entries.push((i, w));
        }
        self.seams
            .rows
            .push([start, mid, self.seams.entries.len() as u32]);
    }
}

/// What finding the seams along an edge looks up.
struct Finder<'a> {
    scene: &'a Scene,
    charts: &'a Charts<'a>,
    /// Every patch's edges ([`patch_edges`]).
    edges: &'a [Edge],
    /// `edges` by object and cell.
    grid: &'a Grid,
    space: &'a Space,
    smooth: SmoothEdges,
    /// The cosine of the largest angle between the faces of a smooth edge.
    smooth_cos: f32,
}

impl Finder<'_> {
    /// Adds the equations at the sample points along edge `e` of a patch on
    /// its mesh's lightmap, [`SAMPLES_PER_TEXEL`] per texel.
    fn along(&self, equations: &mut Equations, e: &Edge) {
        let p = e.patch as usize;
        let normal = self.scene.patches[p].shape.normal();
        let (pa, pb) = (self.charts.pixel(p, e.st_a), self.charts.pixel(p, e.st_b));
        let n = (((pb - pa).length() * SAMPLES_PER_TEXEL).ceil() as usize).max(1);
        for k in 0..n {
            let f = (k as f32 + 0.5) / n as f32;
            let x = e.a.lerp(e.b, f);
            let here = pa.lerp(pb, f);
            self.point(equations, p, normal, x, here);
        }
    }

    /// Adds an equation at the point `x` of an edge of patch `p` (facing
    /// `normal`), at `here` in the atlas, for every other patch of its
    /// object that has an edge through `x`, is a seam with it (see the
    /// module documentation) and shows `x` at another place of the atlas.
    fn point(&self, equations: &mut Equations, p: usize, normal: Vec3, x: Vec3, here: Vec2) {
        let patch = &self.scene.patches[p];
        let [cx, cy, cz] = self.space.key(x);
        let mut seen: Vec<u32> = Vec::new();
        // Whether `x` is on a smooth edge: asked at most once per point.
        let mut smooth_here: Option<bool> = None;
        for (dx, dy, dz) in neighbourhood() {
            let Some(list) = self.grid.get(&(patch.object, [cx + dx, cy + dy, cz + dz])) else {
                continue;
            };
            for &j in list {
                let other = &self.edges[j as usize];
                let q = other.patch as usize;
                if q == p || seen.contains(&other.patch) || !self.scene.reflects_alike(p, q) {
                    continue;
                }
                // Facing the same way, or meeting at a crease the
                // asset shades smoothly.
                let cos = self.scene.patches[q].shape.normal().dot(normal);
                if cos < SEAM_COS
                    && (cos < self.smooth_cos
                        || !*smooth_here
                            .get_or_insert_with(|| self.smooth.at(self.space, patch.object, x)))
                {
                    continue;
                }
                let Some(g) = other.locate(x, self.space.tolerance) else {
                    continue;
                };
                seen.push(other.patch);
                let there = self.charts.pixel(q, other.st_a.lerp(other.st_b, g));
                if (there - here).length() <= SAME_PLACE {
                    continue;
                }
                equations.push(self.charts, here, there);
            }
        }
    }
}

/// The dot product of two vectors.
fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>()
}

impl IslandSeams {
    /// The seam equations of `scene`'s patches on `charts` (see the module
    /// documentation); none when no patch lies on its mesh's lightmap.
    pub(super) fn find(scene: &Scene, charts: &Charts) -> IslandSeams {
        let on_uvs = |p: usize| charts.maps.get(p).is_some_and(|m| m.is_some());
        if !(0..scene.patches.len()).any(on_uvs) {
            return IslandSeams::default();
        }
        let edges = patch_edges(scene);
        let space = Space::around(&edges);
        let mut grid = Grid::new();
        for (i, e) in edges.iter().enumerate() {
            space.enter(
                &mut grid,
                scene.patches[e.patch as usize].object,
                e,
                i as u32,
            );
        }
        let finder = Finder {
            scene,
            charts,
            edges: &edges,
            grid: &grid,
            space: &space,
            smooth: SmoothEdges::new(scene, &space),
            smooth_cos: crate::unwrap::SMOOTH_MAX_DEG.to_radians().cos(),
        };

        let mut equations = Equations {
            seams: IslandSeams::default(),
            slot: HashMap::new(),
            texel_element: charts.texel_element,
        };
        for e in &edges {
            if on_uvs(e.patch as usize) {
                finder.along(&mut equations, e);
            }
        }
        equations.seams
    }

    /// How many seam equations (points along seams, once per side that
    /// samples them).
    pub fn len(&self) -> usize {
        self.rows.len()
    }

    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }

    /// The texels (row-major image indices) the equations read: the only
    /// ones [`IslandSeams::apply`] changes.
    pub fn texels(&self) -> &[u32] {
        &self.texels
    }

    /// The two sides' bilinear reads of `image` at every seam point.
    pub fn reads(&self, image: &[[f32; 3]]) -> Vec<(Vec3, Vec3)> {
        let side = |range: std::ops::Range<u32>| {
            self.entries[range.start as usize..range.end as usize]
                .iter()
                .map(|&(i, w)| Vec3::from_array(image[self.texels[i as usize] as usize]) * w)
                .sum::<Vec3>()
        };
        self.rows
            .iter()
            .map(|&[a, b, end]| (side(a..b), side(b..end)))
            .collect()
    }

    /// Adjusts the texels the seams read so that both sides of every seam
    /// read alike (least squares, see the module documentation), with no
    /// texel below zero: light is never negative, and a gutter the solution
    /// pulls below zero to carry a steep step (a crease between a lit and
    /// an unlit facet) would be shown clamped, the step back. Such texels
    /// are pinned at zero and the rest solved again (an active set: a
    /// pinned texel the solution would raise is released), for at most
    /// [`PIN_ROUNDS`] rounds; the pins carry over to the next call, as the
    /// solution does.
    pub fn apply(&self, image: &mut [[f32; 3]]) {
        if self.rows.is_empty() || self.texels.iter().any(|&t| t as usize >= image.len()) {
            return;
        }
        let n = self.texels.len();
        // The diagonal of AᵀA; with the keep weights, the preconditioner
        // (they span five orders of magnitude with pinned texels).
        let seam_diagonal = self.seam_diagonal();
        // The three channels are independent systems.
        let last = self.last.lock().map(|l| l.clone()).unwrap_or_default();
        let solved: Vec<(Vec<f64>, LastSolve)> = [0usize, 1, 2]
            .par_iter()
            .map(|&channel| {
                let previous = last.get(channel).filter(|l| l.change.len() == n);
                self.solve_channel(image, channel, previous, &seam_diagonal)
            })
            .collect();
        let (solved, lasts): (Vec<Vec<f64>>, Vec<LastSolve>) = solved.into_iter().unzip();
        if let Ok(mut last) = self.last.lock() {
            *last = lasts;
        }
        // A pinned texel is held near zero, not at it.
        for (channel, x) in solved.iter().enumerate() {
            for (&t, v) in self.texels.iter().zip(x) {
                image[t as usize][channel] = v.max(0.0) as f32;
            }
        }
    }

    /// y = (AᵀA + K) x for the keep weights `keep` (none: AᵀA x).
    fn multiply(&self, keep: Option<&[f64]>, x: &[f64], y: &mut [f64]) {
        match keep {
            Some(keep) => {
                for (yi, (xi, k)) in y.iter_mut().zip(x.iter().zip(keep)) {
                    *yi = k * xi;
                }
            }
            None => y.fill(0.0),
        }
        for &[a, b, end] in &self.rows {
            let (a, b, end) = (a as usize, b as usize, end as usize);
            let mut r = 0.0;
            for &(i, w) in &self.entries[a..b] {
                r += f64::from(w) * x[i as usize];
            }
            for &(i, w) in &self.entries[b..end] {
                r -= f64::from(w) * x[i as usize];
            }
            for &(i, w) in &self.entries[a..b] {
                y[i as usize] += f64::from(w) * r;
            }
            for &(i, w) in &self.entries[b..end] {
                y[i as usize] -= f64::from(w) * r;
            }
        }
    }

    /// The diagonal of AᵀA, A the seam equations.
    fn seam_diagonal(&self) -> Vec<f64> {
        let mut seam_diagonal = vec![0.0; self.texels.len()];
        for &[a, _, end] in &self.rows {
            for &(i, w) in &self.entries[a as usize..end as usize] {
                seam_diagonal[i as usize] += f64::from(w) * f64::from(w);
            }
        }
        seam_diagonal
    }

    /// Conjugate gradients on (AᵀA + K) x = K target, from `x`, for the keep
    /// weights `keep`, preconditioned by the diagonal (`seam_diagonal`, the
    /// diagonal of AᵀA, plus `keep`).
    fn solve(&self, seam_diagonal: &[f64], keep: &[f64], target: &[f64], x: &mut [f64]) {
        let n = self.texels.len();
        let diagonal: Vec<f64> = seam_diagonal.iter().zip(keep).map(|(d, k)| d + k).collect();
        let rhs: Vec<f64> = target.iter().zip(keep).map(|(t, k)| t * k).collect();
        let mut ax = vec![0.0; n];
        self.multiply(Some(keep), x, &mut ax);
        let mut r: Vec<f64> = rhs.iter().zip(&ax).map(|(b, a)| b - a).collect();
        let precondition =
            |r: &[f64]| -> Vec<f64> { r.iter().zip(&diagonal).map(|(r, d)| r / d).collect() };
        let mut z = precondition(&r);
        let mut d = z.clone();
        let mut rz = dot(&r, &z);
        let stop = STOP * dot(&rhs, &rhs).max(1e-30);
        let mut ad = vec![0.0; n];
        for _ in 0..MAX_ITERATIONS {
            if dot(&r, &r) <= stop {
                break;
            }
            self.multiply(Some(keep), &d, &mut ad);
            let dad = dot(&d, &ad);
            if dad <= 0.0 {
                break;
            }
            let alpha = rz / dad;
            for ((xi, ri), (di, adi)) in x.iter_mut().zip(&mut r).zip(d.iter().zip(&ad)) {
                *xi += alpha * di;
                *ri -= alpha * adi;
            }
            z = precondition(&r);
            let next = dot(&r, &z);
            let beta = next / rz;
            rz = next;
            for (di, zi) in d.iter_mut().zip(&z) {
                *di = zi + beta * *di;
            }
        }
    }

    /// One channel of the adjusted texels, from their values in `image`:
    /// solved from the last call's solution on (`previous`: its change and
    /// pins), then again while [`IslandSeams::repin`] changes the pins, for
    /// at most [`PIN_ROUNDS`] rounds. Returns the texels' values and what
    /// the next call starts from.
    fn solve_channel(
        &self,
        image: &[[f32; 3]],
        channel: usize,
        previous: Option<&LastSolve>,
        seam_diagonal: &[f64],
    ) -> (Vec<f64>, LastSolve) {
        let n = self.texels.len();
        let x0: Vec<f64> = self
            .texels
            .iter()
            .map(|&t| f64::from(image[t as usize][channel]))
            .collect();
        let mut x: Vec<f64> = match previous {
            Some(l) => x0.iter().zip(&l.change).map(|(x, c)| x + c).collect(),
            None => x0.clone(),
        };
        let mut pinned = previous.map_or_else(|| vec![false; n], |l| l.pinned.clone());
        let mut rounds = 0;
        loop {
            let keep: Vec<f64> = (0..n)
                .map(|i| if pinned[i] { KEEP_PINNED } else { self.keep[i] })
                .collect();
            let target: Vec<f64> = (0..n)
                .map(|i| if pinned[i] { 0.0 } else { x0[i] })
                .collect();
            self.solve(seam_diagonal, &keep, &target, &mut x);
            if rounds == PIN_ROUNDS {
                break;
            }
            rounds += 1;
            if !self.repin(&x0, &mut x, &mut pinned) {
                break;
            }
        }
        let change = x.iter().zip(&x0).map(|(x, x0)| x - x0).collect();
        (x, LastSolve { change, pinned })
    }

    /// Releases the pinned texels that the solution `x` (from the texels'
    /// values `x0`) would raise, and pins at zero the free ones it pulls
    /// below zero. Returns whether any texel changed.
    fn repin(&self, x0: &[f64], x: &mut [f64], pinned: &mut [bool]) -> bool {
        let n = self.texels.len();
        // The objective's gradient at the pinned texels:
        // negative where raising one would lower it.
        let mut gradient = vec![0.0; n];
        self.multiply(None, x, &mut gradient);
        let mut changed = false;
        for i in 0..n {
            if pinned[i] {
                let g = gradient[i] + self.keep[i] * (x[i] - x0[i]);
                if g < 0.0 {
                    pinned[i] = false;
                    changed = true;
                }
            } else if x[i] < 0.0 {
                pinned[i] = true;
                x[i] = 0.0;
                changed = true;
            }
        }
        changed
    }
}
