//! The solved light in an asset's own lightmap UVs (`TEXCOORD_1`).
//!
//! Lightwire lights charts of its own: a patch per triangle, per pair of
//! triangles forming a parallelogram, or per grid of those (`atlas.rs`,
//! `scene/pairs.rs`), each a rectangle of texels in one atlas. A game
//! that brought a glTF mesh with `TEXCOORD_1` expects its lightmap in
//! that layout instead, one image per mesh instance (glTF, Bevy's
//! `Lightmap`, three.js `lightMap`). [`resample`] writes one: every pixel
//! of the mesh's lightmap whose centre lies on one of its UV triangles
//! takes the solved light at the surface point that centre stands for,
//! read from the atlas bilinearly between texel centres exactly as a
//! client reads the atlas through the charts' corner UVs
//! (`SurfaceInfo::corner_uvs`). Pixels within [`PADDING`] pixels of a triangle
//! take the light at its nearest point, so that a bilinear (or
//! mip-mapped, a level or two) read near a chart's border never blends in
//! the empty space around it; the rest stay black.
//!
//! On Lightwire's own charts this is a resampling of the atlas's light,
//! not a solve on the asset's texels: where the asset's texels are finer
//! than the atlas's, they interpolate it. With `--charts lightmap-uvs` the
//! mesh is solved on its own UVs (`atlas/uv.rs`, wallner §2), its block in
//! the atlas the same size as this lightmap, and the resampling reads each
//! pixel from the texel it stands for.

use std::collections::HashMap;

use glam::{Vec2, Vec3};

use crate::atlas::Atlas;
use crate::atlas::uv::nearest;
use crate::{Patch, Scene, UvMesh};

/// Pixels around every UV triangle that take the light of its nearest
/// point (the asset's own padding between charts may be smaller; a pixel
/// goes to the nearest triangle).
pub const PADDING: f32 = 2.0;

/// A mesh's lightmap in its own UVs: linear radiosity (W/m²), row-major
/// from the image's first row, which is UV v = 0 (glTF's convention).
#[derive(Debug, Clone)]
pub struct UvLightmap {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<[f32; 3]>,
    /// Pixels whose centre lies on a triangle.
    pub covered: usize,
    /// Pixels filled from a nearby triangle's nearest point (padding).
    pub padded: usize,
    /// Triangles whose patch was not found (none in a scene loaded by
    /// Lightwire; reported rather than guessed).
    pub unplaced: usize,
}

/// The side of a square lightmap for `mesh` that gives its surface about
/// the texel density of its patches (`atlas::uv::block_side`, the side of
/// its block when it is lit on its own UVs).
pub fn default_size(scene: &Scene, mesh: &UvMesh) -> u32 {
    crate::atlas::uv::block_side(scene, mesh)
}

/// Patches by object, surface and a coarse grid of object space, to find
/// the patch a triangle became. Each (object, surface) group has its own
/// cell size, twice the square root of its patches' mean area, so a large
/// quad elsewhere in the scene does not pile a fine mesh into one cell.
pub struct Locator<'a> {
    patches: &'a [Patch],
    cell: HashMap<(u32, usize), f32>,
    cells: HashMap<(u32, usize, [i64; 3]), Vec<usize>>,
    /// Patches spanning more than [`Locator::MAX_CELLS`] cells, per object
    /// and surface: tried for every point.
    large: HashMap<(u32, usize), Vec<usize>>,
}

impl<'a> Locator<'a> {
    const MAX_CELLS: i64 = 64;

    /// The index of `patches` (a scene's).
    pub fn new(patches: &'a [Patch]) -> Self {
        let mut area: HashMap<(u32, usize), (f32, usize)> = HashMap::new();
        for p in patches {
            let e = area.entry((p.object, p.surface_index)).or_default();
            e.0 += p.shape.area();
            e.1 += 1;
        }
        let cell = area
            .into_iter()
            .map(|(g, (a, n))| (g, (2.0 * (a / n.max(1) as f32).sqrt()).max(1e-6)))
            .collect();
        let mut locator = Locator {
            patches,
            cell,
            cells: HashMap::new(),
            large: HashMap::new(),
        };
        for (k, p) in patches.iter().enumerate() {
            let group = (p.object, p.surface_index);
            let corners = p.shape.corners();
            let lo = corners
                .iter()
                .fold(Vec3::splat(f32::INFINITY), |m, c| m.min(*c));
            let hi = corners
                .iter()
                .fold(Vec3::splat(f32::NEG_INFINITY), |m, c| m.max(*c));
            let (a, b) = (locator.key(group, lo), locator.key(group, hi));
            let span: i64 = (0..3).map(|i| (b[i] - a[i] + 1).max(1)).product();
            if span > Self::MAX_CELLS {
                locator.large.entry(group).or_default().push(k);
                continue;
            }
            for x in a[0]..=b[0] {
                for y in a[1]..=b[1] {
                    for z in a[2]..=b[2] {
                        locator
                            .cells
                            .entry((group.0, group.1, [x, y, z]))
                            .or_default()
                            .push(k);
                    }
                }
            }
        }
        locator
    }

    fn key(&self, group: (u32, usize), p: Vec3) -> [i64; 3] {
        let cell = self.cell.get(&group).copied().unwrap_or(1.0);
        (p / cell).floor().as_i64vec3().to_array()
    }

    /// The patch of `object` and `surface` that holds the triangle `t`
    /// (facing as it does, its centroid on the patch), and the patch
    /// parameters of its corners.
    fn place(&self, object: u32, surface: usize, t: &[Vec3; 3]) -> Option<(usize, [Vec2; 3])> {
        let group = (object, surface);
        let centroid = (t[0] + t[1] + t[2]) / 3.0;
        let normal = (t[1] - t[0]).cross(t[2] - t[0]).normalize_or_zero();
        let size = (t[1] - t[0])
            .length()
            .max((t[2] - t[0]).length())
            .max(1e-12);
        // Off the plane by more than f32 rounding of the coordinates allows
        // (corners far from the origin), or by more than a thousandth of the
        // triangle, is another surface.
        let slack = (1e-3 * size).max(8.0 * f32::EPSILON * centroid.abs().max_element());
        let none = Vec::new();
        let near = self
            .cells
            .get(&(object, surface, self.key(group, centroid)))
            .unwrap_or(&none);
        let large = self.large.get(&group).unwrap_or(&none);
        let mut best: Option<(f32, usize)> = None;
        for &k in near.iter().chain(large) {
            let shape = &self.patches[k].shape;
            if shape.normal().dot(normal) < 0.999 {
                continue;
            }
            let (o, _, _) = shape.frame();
            let off_plane = (centroid - o).dot(shape.normal()).abs();
            let st = parameters(&self.patches[k], centroid);
            let outside = outside(&self.patches[k], st);
            if off_plane > slack || outside > 1e-3 {
                continue;
            }
            let miss = (off_plane / slack).max(outside);
            if best.is_none_or(|(m, _)| miss < m) {
                best = Some((miss, k));
            }
        }
        let (_, k) = best?;
        Some((k, t.map(|c| parameters(&self.patches[k], c))))
    }
}

/// Patch parameters `(s, t)` of `p` (on or near its plane): `p = origin +
/// s u + t v` in the least-squares sense.
fn parameters(patch: &Patch, p: Vec3) -> Vec2 {
    let (o, u, v) = patch.shape.frame();
    let d = p - o;
    let (uu, uv, vv) = (u.dot(u), u.dot(v), v.dot(v));
    let det = uu * vv - uv * uv;
    let (du, dv) = (d.dot(u), d.dot(v));
    Vec2::new((vv * du - uv * dv) / det, (uu * dv - uv * du) / det)
}

/// How far `(s, t)` lies outside the patch, in parameter units (0 on it).
fn outside(patch: &Patch, st: Vec2) -> f32 {
    let square = (-st.x).max(st.x - 1.0).max(-st.y).max(st.y - 1.0).max(0.0);
    if patch.shape.is_triangle() {
        square.max(st.y - st.x)
    } else {
        square
    }
}

/// The atlas's light at atlas pixel coordinates `q` (texel `(i, j)`'s
/// centre at `(i + 0.5, j + 0.5)`), bilinear between texel centres.
fn bilinear(image: &[[f32; 3]], width: u32, height: u32, q: Vec2) -> [f32; 3] {
    let f = q - Vec2::splat(0.5);
    let x0 = f.x.floor();
    let y0 = f.y.floor();
    let (fx, fy) = (f.x - x0, f.y - y0);
    let at = |x: f32, y: f32| {
        let x = (x.max(0.0) as u32).min(width - 1);
        let y = (y.max(0.0) as u32).min(height - 1);
        Vec3::from(image[(y * width + x) as usize])
    };
    let top = at(x0, y0) * (1.0 - fx) + at(x0 + 1.0, y0) * fx;
    let bottom = at(x0, y0 + 1.0) * (1.0 - fx) + at(x0 + 1.0, y0 + 1.0) * fx;
    (top * (1.0 - fy) + bottom * fy).to_array()
}

/// Every [`Scene::uv_meshes`] entry's lightmap from the atlas light
/// `image` (linear, one pixel per atlas texel, invalid texels already
/// filled, as `bake::write_outputs` makes it), `size × size` pixels each
/// ([`default_size`] when `None`). Holds them all at once: for many large
/// meshes, [`resample`] one at a time with one [`Locator`].
pub fn resample_all(
    scene: &Scene,
    atlas: &Atlas,
    image: &[[f32; 3]],
    size: Option<u32>,
) -> Vec<UvLightmap> {
    let locator = Locator::new(&scene.patches);
    scene
        .uv_meshes
        .iter()
        .map(|mesh| {
            let side = size.unwrap_or_else(|| default_size(scene, mesh));
            resample(&locator, atlas, image, mesh, side)
        })
        .collect()
}

/// `mesh`'s lightmap of `size × size` pixels from the atlas light `image`
/// ([`resample_all`]), its triangles found through `locator` (the
/// scene's).
pub fn resample(
    locator: &Locator<'_>,
    atlas: &Atlas,
    image: &[[f32; 3]],
    mesh: &UvMesh,
    size: u32,
) -> UvLightmap {
    let (w, h) = (size.max(1), size.max(1));
    let mut pixels = vec![[0.0f32; 3]; (w as usize) * (h as usize)];
    // Distance (pixels) to the triangle each pixel took its light from.
    let mut taken = vec![f32::INFINITY; pixels.len()];
    let mut unplaced = 0;
    let scale = Vec2::new(w as f32, h as f32);
    for (tri, uv) in mesh.triangles.iter().zip(&mesh.uvs) {
        let Some((k, st)) = locator.place(mesh.object, mesh.surface_index, tri) else {
            unplaced += 1;
            continue;
        };
        let chart = &atlas.charts[k];
        // Atlas pixel coordinates of the corners (`SurfaceInfo::corner_uvs`: the
        // chart's corner texels' centres are the patch's corners; on a
        // mesh's own lightmap, its chart map, `atlas/uv.rs`).
        let map = atlas.chart_map(k as u32);
        let base = Vec2::new(chart.x as f32 + 0.5, chart.y as f32 + 0.5);
        let at = st.map(|p| base + map.to_chart(p));
        let q = uv.map(|c| c * scale);
        let lo = q[0].min(q[1]).min(q[2]) - Vec2::splat(PADDING);
        let hi = q[0].max(q[1]).max(q[2]) + Vec2::splat(PADDING);
        let (x0, y0) = (lo.x.floor().max(0.0) as u32, lo.y.floor().max(0.0) as u32);
        let (x1, y1) = (
            (hi.x.ceil().max(0.0) as u32).min(w),
            (hi.y.ceil().max(0.0) as u32).min(h),
        );
        for y in y0..y1 {
            for x in x0..x1 {
                let i = (y * w + x) as usize;
                let (b, d) = nearest(&q, Vec2::new(x as f32 + 0.5, y as f32 + 0.5));
                if d > PADDING || d >= taken[i] {
                    continue;
                }
                taken[i] = d;
                let a = at[0] * b.x + at[1] * b.y + at[2] * b.z;
                pixels[i] = bilinear(image, atlas.width, atlas.height, a);
            }
        }
    }
    let covered = taken.iter().filter(|d| **d == 0.0).count();
    let padded = taken.iter().filter(|d| d.is_finite()).count() - covered;
    UvLightmap {
        width: w,
        height: h,
        pixels,
        covered,
        padded,
        unplaced,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_is_the_point_itself_inside_and_on_an_edge_outside() {
        let q = [
            Vec2::new(0.0, 0.0),
            Vec2::new(4.0, 0.0),
            Vec2::new(0.0, 4.0),
        ];
        let (b, d) = nearest(&q, Vec2::new(1.0, 1.0));
        assert_eq!(d, 0.0);
        let p = q[0] * b.x + q[1] * b.y + q[2] * b.z;
        assert!(p.distance(Vec2::new(1.0, 1.0)) < 1e-6, "{p}");
        // Below the edge from q0 to q1: its nearest point is straight up.
        let (b, d) = nearest(&q, Vec2::new(2.0, -1.5));
        assert!((d - 1.5).abs() < 1e-6, "{d}");
        let p = q[0] * b.x + q[1] * b.y + q[2] * b.z;
        assert!(p.distance(Vec2::new(2.0, 0.0)) < 1e-6, "{p}");
        // Beyond the hypotenuse.
        let (_, d) = nearest(&q, Vec2::new(3.0, 3.0));
        assert!((d - 2.0f32.sqrt()).abs() < 1e-5, "{d}");
    }

    #[test]
    fn bilinear_reads_texel_centres_exactly_and_halfway_between() {
        let image = [[0.0, 0.0, 0.0], [2.0, 4.0, 6.0]];
        assert_eq!(bilinear(&image, 2, 1, Vec2::new(0.5, 0.5)), [0.0; 3]);
        assert_eq!(bilinear(&image, 2, 1, Vec2::new(1.5, 0.5)), [2.0, 4.0, 6.0]);
        assert_eq!(bilinear(&image, 2, 1, Vec2::new(1.0, 0.5)), [1.0, 2.0, 3.0]);
        // Clamped at the border.
        assert_eq!(bilinear(&image, 2, 1, Vec2::new(9.0, 0.0)), [2.0, 4.0, 6.0]);
    }
}
