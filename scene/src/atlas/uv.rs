//! Triangles lit on their mesh's own lightmap UVs (`TEXCOORD_1`,
//! `Charts::LightmapUvs`; wallner §2 solves on per-triangle lightmaps packed
//! into an atlas, here the packing is the asset's).
//!
//! A mesh's lightmap `[0, 1]²` is one square block of the atlas, `side`
//! texels a side ([`block_side`]: the density of its patches over its
//! surface). A triangle's chart is the rectangle of the block's texels whose
//! footprint overlaps its UV triangle (at least 2 x 2), and each of those
//! texels is an element of the triangle: its area is the part of the
//! footprint the triangle covers (zero for a texel of the rectangle it
//! misses, which validity marks invalid and dilation fills), its sample
//! point the point of the triangle nearest to the texel's centre (the centre
//! itself when it lies on the triangle). Texels of the block that no chart
//! holds take the mean of their neighbours that one does when the lightmap
//! is published ([`super::Atlas::to_image`]), so that bilinear filtering at
//! an island's border reads its light, not black; so do those of a ring of
//! [`super::BLOCK_RING`] texels packed around the block, so that an island
//! reaching the lightmap's border never reads the chart packed beside it. A texel that two triangles both cover is an
//! element of each, sampled on its own triangle; they form a group that is
//! stitched (set to its mean) on publication as a seam's texels are, and
//! the texel shows that mean ([`super::Atlas::to_image`] writes the one
//! element that owns it, the one covering most of it).
//!
//! Where the UVs are affine over a flat grid of triangles (an island
//! unwrapped by a planar projection), the grid is one parallelogram patch
//! (`scene/pairs.rs`) and everything above holds for it as for a triangle:
//! its chart is the rectangle its UV parallelogram overlaps, its elements
//! the texels of that rectangle, each covering the part of its footprint
//! inside the parallelogram.
//!
//! Patch parameters `(s, t)` map to a chart's texel coordinates (centres at
//! integers) by an affine [`ChartMap`]; on Lightwire's own charts that is
//! `(s (w - 1), t (h - 1))`.

use glam::{DVec2, Vec2, Vec3};

use crate::uv::{MAX_SIDE, uv_area};
use crate::{Scene, UvMesh};

/// Affine map from patch parameters `(s, t)` to a chart's texel
/// coordinates, texel `(a, b)`'s centre at `(a, b)`: `origin + s ds + t dt`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ChartMap {
    pub origin: Vec2,
    pub ds: Vec2,
    pub dt: Vec2,
}

impl ChartMap {
    /// Lightwire's own chart of `w x h` texels: `s = a / (w - 1)`.
    pub fn native(w: u32, h: u32) -> Self {
        Self {
            origin: Vec2::ZERO,
            ds: Vec2::new(w.saturating_sub(1) as f32, 0.0),
            dt: Vec2::new(0.0, h.saturating_sub(1) as f32),
        }
    }

    /// Texel coordinates of the point at patch parameters `st`.
    pub fn to_chart(&self, st: Vec2) -> Vec2 {
        self.origin + self.ds * st.x + self.dt * st.y
    }

    /// Patch parameters of texel coordinates `xy` (the inverse map), or
    /// `None` for a degenerate map.
    pub fn to_param(&self, xy: Vec2) -> Option<Vec2> {
        let det = f64::from(self.ds.perp_dot(self.dt));
        if det.abs() <= 1e-12 {
            return None;
        }
        let d = (xy - self.origin).as_dvec2();
        let (ds, dt) = (self.ds.as_dvec2(), self.dt.as_dvec2());
        Some(DVec2::new(d.perp_dot(dt) / det, ds.perp_dot(d) / det).as_vec2())
    }
}

/// The side of the square lightmap block that gives `mesh` about the texel
/// density of its patches: `density × sqrt(surface area / UV area)`, or the
/// side its generated UVs were packed for if larger (charts refined near a
/// light, `near_lights.rs`), rounded
/// up to a multiple of 4, between 16 and [`MAX_SIDE`]. `lightwire bake`'s
/// resampled lightmaps (`crate::uvmap`) take the same size.
pub fn block_side(scene: &Scene, mesh: &UvMesh) -> u32 {
    let area: f32 = mesh
        .triangles
        .iter()
        .map(|[a, b, c]| 0.5 * (*b - *a).cross(*c - *a).length())
        .sum();
    let uv_area: f32 = mesh.uvs.iter().map(|t| uv_area(t).abs()).sum();
    let density = scene
        .patches
        .iter()
        .find(|p| p.object == mesh.object && p.surface_index == mesh.surface_index)
        .map_or(scene.texel_density, |p| p.texel_density);
    let side = (density * (area / uv_area.max(1e-12)).sqrt()).max(mesh.packed_side.ceil());
    let side = if side.is_finite() {
        side.ceil() as u32
    } else {
        MAX_SIDE
    };
    side.div_ceil(4).saturating_mul(4).clamp(16, MAX_SIDE)
}

/// Signed area of a polygon (positive counter-clockwise).
pub fn polygon_area(q: &[Vec2]) -> f32 {
    let mut twice = 0.0;
    for k in 0..q.len() {
        twice += q[k].perp_dot(q[(k + 1) % q.len()]);
    }
    0.5 * twice
}

/// The corners of a patch on its mesh's lightmap in its chart's texel
/// coordinates: a triangle's three (patch parameters (0, 0), (1, 0),
/// (1, 1)), or a parallelogram's four (and (0, 1)), in patch order.
pub fn chart_corners(map: &ChartMap, triangle: bool) -> Vec<Vec2> {
    let params: &[Vec2] = if triangle {
        &[Vec2::ZERO, Vec2::X, Vec2::ONE]
    } else {
        &[Vec2::ZERO, Vec2::X, Vec2::ONE, Vec2::Y]
    };
    params.iter().map(|&st| map.to_chart(st)).collect()
}

/// The chart of a convex polygon (a triangle, a parallelogram) whose
/// corners lie at `q` (texel coordinates of its block, texel `(i, j)`
/// covering `[i, i + 1] x [j, j + 1]`): the first texel and the size of the
/// rectangle of texels its footprint overlaps, inside the block's `side` x
/// `side`, at least 2 x 2 (grown inside the block where it is narrower).
pub fn polygon_chart(q: &[Vec2], side: u32) -> ([u32; 2], [u32; 2]) {
    let last = side.saturating_sub(1) as f32;
    let axis = |k: usize| {
        let lo = q.iter().map(|p| p[k]).fold(f32::INFINITY, f32::min);
        let hi = q.iter().map(|p| p[k]).fold(f32::NEG_INFINITY, f32::max);
        let first = lo.floor().clamp(0.0, last) as u32;
        let end = (hi.ceil() - 1.0).clamp(0.0, last) as u32;
        let end = end.max(first + 1).min(side.saturating_sub(1));
        let first = first.min(end.saturating_sub(1));
        (first, end - first + 1)
    };
    let (x, w) = axis(0);
    let (y, h) = axis(1);
    ([x, y], [w, h])
}

/// The part of texel `(i, j)`'s footprint that the convex polygon `q`
/// (texel coordinates, either winding) covers: its area in texels² and its
/// corners (empty when it covers none).
pub fn covered(q: &[Vec2], i: u32, j: u32) -> (f64, Vec<DVec2>) {
    let (x0, y0) = (f64::from(i), f64::from(j));
    let mut poly: Vec<DVec2> = q.iter().map(|p| p.as_dvec2()).collect();
    if polygon_area(q) < 0.0 {
        poly.reverse();
    }
    // Sutherland–Hodgman against the footprint's four sides: keep
    // `sign * (p[axis] - bound) >= 0`.
    for (axis, bound, sign) in [
        (0, x0, 1.0),
        (0, x0 + 1.0, -1.0),
        (1, y0, 1.0),
        (1, y0 + 1.0, -1.0),
    ] {
        if poly.is_empty() {
            break;
        }
        let inside = |p: DVec2| sign * (p[axis] - bound) >= 0.0;
        let mut out = Vec::with_capacity(poly.len() + 2);
        for k in 0..poly.len() {
            let (p, r) = (poly[k], poly[(k + 1) % poly.len()]);
            if inside(p) {
                out.push(p);
            }
            if inside(p) != inside(r) {
                let f = (bound - p[axis]) / (r[axis] - p[axis]);
                out.push(p + (r - p) * f);
            }
        }
        poly = out;
    }
    let mut twice = 0.0;
    for k in 0..poly.len() {
        twice += poly[k].perp_dot(poly[(k + 1) % poly.len()]);
    }
    let area = 0.5 * twice.abs();
    if poly.len() < 3 || area <= 1e-12 {
        return (0.0, Vec::new());
    }
    (area, poly)
}

/// Barycentric coordinates of `p` in the triangle `q` (2D), and of the
/// triangle's nearest point to `p` with the distance to it.
pub fn nearest(q: &[Vec2; 3], p: Vec2) -> (Vec3, f32) {
    let area = (q[1] - q[0]).perp_dot(q[2] - q[0]);
    let b1 = (p - q[0]).perp_dot(q[2] - q[0]) / area;
    let b2 = (q[1] - q[0]).perp_dot(p - q[0]) / area;
    let b = Vec3::new(1.0 - b1 - b2, b1, b2);
    if b.min_element() >= 0.0 {
        return (b, 0.0);
    }
    // Outside: the nearest point lies on an edge.
    let mut best = (Vec3::ZERO, f32::INFINITY);
    for (i, j) in [(0, 1), (1, 2), (2, 0)] {
        let e = q[j] - q[i];
        let s = ((p - q[i]).dot(e) / e.length_squared().max(1e-30)).clamp(0.0, 1.0);
        let d = (q[i] + e * s).distance(p);
        if d < best.1 {
            let mut b = Vec3::ZERO;
            b[i] = 1.0 - s;
            b[j] = s;
            best = (b, d);
        }
    }
    best
}

/// The point of triangle `q` nearest to `p` (`p` itself when inside).
pub fn nearest_on_triangle(q: &[Vec2; 3], p: Vec2) -> Vec2 {
    nearest_on_polygon(q, p)
}

/// The point of the convex polygon `q` (three or more corners) nearest to
/// `p` (`p` itself when inside): the nearest over the triangles of its fan
/// from `q[0]`.
pub fn nearest_on_polygon(q: &[Vec2], p: Vec2) -> Vec2 {
    let mut best = (p, f32::INFINITY);
    for k in 1..q.len().saturating_sub(1) {
        let t = [q[0], q[k], q[k + 1]];
        let (b, d) = nearest(&t, p);
        if d == 0.0 {
            return p;
        }
        if d < best.1 {
            best = (t[0] * b.x + t[1] * b.y + t[2] * b.z, d);
        }
    }
    best.0
}

/// `p` moved [`super::CORNER_OFFSET`] of a texel towards the centroid of
/// the convex polygon `q` when it lies on one of its corners (at most half
/// way there), else `p`: as on Lightwire's charts, no element samples the
/// corner itself, where the fan of a mesh vertex's triangles meets, every
/// one of them at distance zero.
pub fn inward_of_corners(q: &[Vec2], p: Vec2) -> Vec2 {
    let Some(corner) = q.iter().find(|c| c.distance(p) < 1e-4) else {
        return p;
    };
    let centroid = q.iter().copied().sum::<Vec2>() / q.len().max(1) as f32;
    let to = centroid - *corner;
    *corner + to.normalize_or_zero() * super::CORNER_OFFSET.min(0.5 * to.length())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chart_maps_invert() {
        let map = ChartMap {
            origin: Vec2::new(1.5, -0.5),
            ds: Vec2::new(3.0, 1.0),
            dt: Vec2::new(-0.5, 2.0),
        };
        for st in [Vec2::ZERO, Vec2::new(1.0, 0.0), Vec2::new(0.3, 0.7)] {
            let back = map.to_param(map.to_chart(st)).expect("invertible");
            assert!((back - st).length() < 1e-5, "{st} -> {back}");
        }
        let native = ChartMap::native(5, 3);
        assert_eq!(native.to_chart(Vec2::new(1.0, 1.0)), Vec2::new(4.0, 2.0));
    }

    #[test]
    fn covered_parts_of_texels_sum_to_the_triangle() {
        let q = [
            Vec2::new(0.3, 0.2),
            Vec2::new(5.7, 1.1),
            Vec2::new(2.2, 4.9),
        ];
        let ([x, y], [w, h]) = polygon_chart(&q, 16);
        let mut sum = 0.0;
        for j in y..y + h {
            for i in x..x + w {
                sum += covered(&q, i, j).0;
            }
        }
        assert!((sum - f64::from(uv_area(&q))).abs() < 1e-5, "{sum}");
        // The texels it overlaps: columns 0 to 5, rows 0 to 4.
        assert_eq!([x, y], [0, 0]);
        assert_eq!([w, h], [6, 5]);
        assert!(covered(&q, 5, 1).0 > 0.0 && covered(&q, 2, 4).0 > 0.0);
        // One within a single texel still gets 2 x 2.
        let tiny = [
            Vec2::new(3.2, 7.1),
            Vec2::new(3.8, 7.2),
            Vec2::new(3.5, 7.9),
        ];
        assert_eq!(polygon_chart(&tiny, 16), ([3, 7], [2, 2]));
        assert_eq!(
            polygon_chart(&tiny.map(|p| p + Vec2::new(12.0, 8.0)), 16),
            ([14, 14], [2, 2])
        );
        // Clockwise the same.
        let r = [q[0], q[2], q[1]];
        assert!((covered(&r, 2, 2).0 - covered(&q, 2, 2).0).abs() < 1e-12);
        assert!(
            (covered(&q, 2, 2).0 - 1.0).abs() < 1e-12,
            "an inner texel is whole"
        );
    }

    #[test]
    fn covered_parts_of_texels_sum_to_a_parallelogram() {
        // A skewed parallelogram, clockwise, as a chart map gives one.
        let map = ChartMap {
            origin: Vec2::new(2.3, 0.7),
            ds: Vec2::new(6.2, 1.1),
            dt: Vec2::new(-1.4, 4.3),
        };
        let q: Vec<Vec2> = chart_corners(&map, false).into_iter().rev().collect();
        assert_eq!(q.len(), 4);
        let area = polygon_area(&q).abs();
        assert!((area - map.ds.perp_dot(map.dt).abs()).abs() < 1e-4);
        let ([x, y], [w, h]) = polygon_chart(&q, 32);
        let mut sum = 0.0;
        for j in y..y + h {
            for i in x..x + w {
                sum += covered(&q, i, j).0;
            }
        }
        assert!((sum - f64::from(area)).abs() < 1e-4, "{sum} vs {area}");
        // Its fourth corner (patch parameters (0, 1)) widens the chart
        // beyond the triangle's.
        let triangle = chart_corners(&map, true);
        assert_eq!(triangle.len(), 3);
        let (_, [tw, _]) = polygon_chart(&triangle, 32);
        assert!(w > tw, "{w} vs {tw}");
        // The nearest point of a point outside lies on its boundary, inside
        // it is the point itself.
        let inside = map.to_chart(Vec2::new(0.2, 0.9));
        assert_eq!(nearest_on_polygon(&q, inside), inside);
        let beyond = map.to_chart(Vec2::new(-0.1, 0.9));
        let on = nearest_on_polygon(&q, beyond);
        let st = map.to_param(on).expect("invertible");
        assert!(st.x.abs() < 1e-4 && (0.0..=1.0).contains(&st.y), "{st}");
    }

    #[test]
    fn nearest_points_lie_on_the_triangle() {
        let q = [
            Vec2::new(0.0, 0.0),
            Vec2::new(4.0, 0.0),
            Vec2::new(0.0, 4.0),
        ];
        assert_eq!(
            nearest_on_triangle(&q, Vec2::new(1.0, 1.0)),
            Vec2::new(1.0, 1.0)
        );
        assert_eq!(
            nearest_on_triangle(&q, Vec2::new(1.0, -2.0)),
            Vec2::new(1.0, 0.0)
        );
        assert_eq!(
            nearest_on_triangle(&q, Vec2::new(3.0, 3.0)),
            Vec2::new(2.0, 2.0)
        );
        assert_eq!(nearest_on_triangle(&q, Vec2::new(-1.0, -1.0)), Vec2::ZERO);
    }
}
