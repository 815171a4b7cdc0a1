//! Exact overlap test of lightmap-UV triangles with a uniform grid.
//!
//! A lightmap texel belongs to one surface point (Wallner §2: per-triangle
//! lightmaps packed into an atlas; Coombe and Harris §39.2: texels are the
//! elements), so two triangles of one lightmap must not share UV area. The
//! test clips one triangle by the other (Sutherland–Hodgman; both convex) and
//! measures the intersection's area in f64, so shared edges and vertices
//! (area 0) never count. Candidate pairs come from a uniform grid of about
//! one cell per triangle over the triangles' bounding box; a pair is tested only in the cell that
//! holds the lower-left corner of the intersection of the two bounding boxes,
//! so each pair is tested once without a set of visited pairs.

use glam::{DVec2, Vec2};

use super::{OVERLAP_AREA, OVERLAP_RELATIVE};

/// Two triangles whose UV areas intersect.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UvOverlap {
    /// Indices into the slice given to [`find_uv_overlaps`], `a < b`.
    pub a: usize,
    pub b: usize,
    /// Intersection area in UV units².
    pub area: f64,
    /// `area` over the smaller triangle's area.
    pub fraction: f64,
}

fn cross(a: DVec2, b: DVec2) -> f64 {
    a.x * b.y - a.y * b.x
}

pub(crate) fn signed_area(p: &[DVec2]) -> f64 {
    let mut s = 0.0;
    for i in 0..p.len() {
        s += cross(p[i], p[(i + 1) % p.len()]);
    }
    0.5 * s
}

/// Area of the intersection of two counter-clockwise triangles.
pub(crate) fn intersection_area(a: &[DVec2; 3], b: &[DVec2; 3]) -> f64 {
    let mut poly: Vec<DVec2> = a.to_vec();
    for i in 0..3 {
        let (e0, e1) = (b[i], b[(i + 1) % 3]);
        let inside = |p: DVec2| cross(e1 - e0, p - e0) >= 0.0;
        let input = std::mem::take(&mut poly);
        for j in 0..input.len() {
            let cur = input[j];
            let prev = input[(j + input.len() - 1) % input.len()];
            let (ci, pi) = (inside(cur), inside(prev));
            if ci != pi {
                // Intersection of segment prev→cur with the edge line.
                let d = cur - prev;
                let denom = cross(e1 - e0, d);
                if denom != 0.0 {
                    let t = cross(e1 - e0, e0 - prev) / denom;
                    poly.push(prev + d * t);
                }
            }
            if ci {
                poly.push(cur);
            }
        }
        if poly.len() < 3 {
            return 0.0;
        }
    }
    signed_area(&poly).abs()
}

/// Grid entries (triangle × cell) allowed before the check gives up.
pub const MAX_CELL_ENTRIES: usize = 1 << 24;
/// Candidate pairs allowed before the check gives up.
pub const MAX_PAIRS: u64 = 1 << 27;

/// Pairs of triangles that overlap by more than the tolerance of
/// [`OVERLAP_AREA`] / [`OVERLAP_RELATIVE`]; stops after `limit` pairs.
/// Triangles with zero UV area are skipped (reported separately).
///
/// The grid spans the bounding box of the triangles with about one cell per
/// triangle, so a mesh that uses a corner of [0, 1]² is as fast as one that
/// fills it. The work is bounded, since the input is a file: when the
/// triangles' bounding boxes cover more than [`MAX_CELL_ENTRIES`] grid cells
/// in total, or more than [`MAX_PAIRS`] candidate pairs share cells (very
/// long thin UV triangles, or many piled into one place), it returns
/// `Err(work)` with the amount of work it would have needed so far.
pub fn find_uv_overlaps(tris: &[[Vec2; 3]], limit: usize) -> Result<Vec<UvOverlap>, u64> {
    let n = tris.len();
    // Counter-clockwise f64 copies, their areas and bounding boxes.
    let mut ccw: Vec<[DVec2; 3]> = Vec::with_capacity(n);
    let mut area = Vec::with_capacity(n);
    let mut bbox = Vec::with_capacity(n);
    let mut valid = Vec::with_capacity(n);
    let (mut all_lo, mut all_hi) = (DVec2::INFINITY, DVec2::NEG_INFINITY);
    for t in tris {
        let mut p = t.map(|v| v.as_dvec2());
        let a = signed_area(&p);
        if a < 0.0 {
            p.swap(1, 2);
        }
        let lo = p[0].min(p[1]).min(p[2]);
        let hi = p[0].max(p[1]).max(p[2]);
        let ok = a.abs() > 0.0 && lo.is_finite() && hi.is_finite();
        if ok {
            all_lo = all_lo.min(lo);
            all_hi = all_hi.max(hi);
        }
        valid.push(ok);
        area.push(a.abs());
        bbox.push((lo, hi));
        ccw.push(p);
    }
    let count = valid.iter().filter(|&&v| v).count();
    if count < 2 {
        return Ok(Vec::new());
    }
    // About one cell per triangle, shaped like the bounding box.
    let size = (all_hi - all_lo).max(DVec2::splat(1e-12));
    let gx = ((count as f64 * size.x / size.y).sqrt().ceil() as usize).clamp(1, 4096);
    let gy = (count.div_ceil(gx)).clamp(1, 4096);
    let cell_x =
        |x: f64| (((x - all_lo.x) / size.x * gx as f64).floor().max(0.0) as usize).min(gx - 1);
    let cell_y =
        |y: f64| (((y - all_lo.y) / size.y * gy as f64).floor().max(0.0) as usize).min(gy - 1);
    let mut entries: u64 = 0;
    for (i, (lo, hi)) in bbox.iter().enumerate() {
        if valid[i] {
            entries +=
                ((cell_x(hi.x) - cell_x(lo.x) + 1) * (cell_y(hi.y) - cell_y(lo.y) + 1)) as u64;
        }
    }
    if entries > MAX_CELL_ENTRIES as u64 {
        return Err(entries);
    }
    let mut cells: Vec<Vec<u32>> = vec![Vec::new(); gx * gy];
    for (i, (lo, hi)) in bbox.iter().enumerate() {
        if !valid[i] {
            continue;
        }
        for cy in cell_y(lo.y)..=cell_y(hi.y) {
            for cx in cell_x(lo.x)..=cell_x(hi.x) {
                cells[cy * gx + cx].push(i as u32);
            }
        }
    }
    let pairs: u64 = cells
        .iter()
        .map(|c| (c.len() as u64) * (c.len() as u64).saturating_sub(1) / 2)
        .sum();
    if pairs > MAX_PAIRS {
        return Err(pairs);
    }
    let mut found = Vec::new();
    for cy in 0..gy {
        for cx in 0..gx {
            let list = &cells[cy * gx + cx];
            for (k, &i) in list.iter().enumerate() {
                for &j in &list[k + 1..] {
                    let (i, j) = (i.min(j) as usize, i.max(j) as usize);
                    let (lo_i, hi_i) = bbox[i];
                    let (lo_j, hi_j) = bbox[j];
                    let lo = lo_i.max(lo_j);
                    let hi = hi_i.min(hi_j);
                    if lo.x > hi.x || lo.y > hi.y {
                        continue;
                    }
                    // Test each pair once: in the cell of the lower-left
                    // corner of the intersection of the bounding boxes.
                    if cell_x(lo.x) != cx || cell_y(lo.y) != cy {
                        continue;
                    }
                    let smaller = area[i].min(area[j]);
                    let tolerance = OVERLAP_AREA.min(OVERLAP_RELATIVE * smaller);
                    let overlap = intersection_area(&ccw[i], &ccw[j]);
                    if overlap > tolerance {
                        found.push(UvOverlap {
                            a: i,
                            b: j,
                            area: overlap,
                            fraction: overlap / smaller,
                        });
                        if found.len() >= limit {
                            return Ok(found);
                        }
                    }
                }
            }
        }
    }
    Ok(found)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(x: f32, y: f32) -> Vec2 {
        Vec2::new(x, y)
    }

    #[test]
    fn shared_edge_is_not_an_overlap_but_a_shift_is() {
        let a = [v(0.1, 0.1), v(0.5, 0.1), v(0.5, 0.5)];
        let b = [v(0.1, 0.1), v(0.5, 0.5), v(0.1, 0.5)];
        assert!(find_uv_overlaps(&[a, b], 10).expect("bounded").is_empty());
        // Move b across the shared diagonal by 0.01: a sliver overlaps.
        let c = b.map(|p| p + v(0.01, -0.01));
        let o = find_uv_overlaps(&[a, c], 10).expect("bounded");
        assert_eq!(o.len(), 1);
        assert_eq!((o[0].a, o[0].b), (0, 1));
        assert!(o[0].area > 1e-4, "{o:?}");
    }

    #[test]
    fn intersection_area_is_exact_for_nested_and_crossing_triangles() {
        let big = [
            DVec2::new(0.0, 0.0),
            DVec2::new(1.0, 0.0),
            DVec2::new(0.0, 1.0),
        ];
        let small = [
            DVec2::new(0.1, 0.1),
            DVec2::new(0.3, 0.1),
            DVec2::new(0.1, 0.3),
        ];
        assert!((intersection_area(&big, &small) - 0.02).abs() < 1e-12);
        assert!((intersection_area(&small, &big) - 0.02).abs() < 1e-12);
        // The mirror of `big` about x + y = 1 meets it only on the diagonal.
        let mirror = [
            DVec2::new(1.0, 1.0),
            DVec2::new(0.0, 1.0),
            DVec2::new(1.0, 0.0),
        ];
        assert!(intersection_area(&big, &mirror).abs() < 1e-12);
        // A square [0.25, 0.75]² split by its diagonal vs `big`: half of the
        // lower-left triangle of the square lies below x + y = 1.
        let lower = [
            DVec2::new(0.25, 0.25),
            DVec2::new(0.75, 0.25),
            DVec2::new(0.25, 0.75),
        ];
        assert!((intersection_area(&big, &lower) - 0.125).abs() < 1e-12);
    }

    #[test]
    fn a_grid_of_many_triangles_has_no_overlaps_and_a_duplicate_is_found() {
        // 200 × 200 squares, two triangles each: 80 000 triangles sharing
        // edges and vertices everywhere.
        let n = 200;
        let mut tris = Vec::new();
        for y in 0..n {
            for x in 0..n {
                let s = 1.0 / n as f32;
                let (x0, y0) = (x as f32 * s, y as f32 * s);
                tris.push([v(x0, y0), v(x0 + s, y0), v(x0 + s, y0 + s)]);
                tris.push([v(x0, y0), v(x0 + s, y0 + s), v(x0, y0 + s)]);
            }
        }
        assert!(find_uv_overlaps(&tris, 10).expect("bounded").is_empty());
        let dup = tris[12345];
        tris.push(dup);
        let o = find_uv_overlaps(&tris, 10).expect("bounded");
        assert_eq!(o.len(), 1, "{o:?}");
        assert_eq!((o[0].a, o[0].b), (12345, tris.len() - 1));
        assert!((o[0].fraction - 1.0).abs() < 1e-6);
    }

    #[test]
    fn a_mesh_in_a_corner_of_the_square_is_gridded_over_its_own_bounds() {
        // 20 000 triangles inside [0, 0.001]²: on a grid over [0, 1]² they
        // would all share one cell (2·10⁸ candidate pairs, over the limit).
        let n = 100;
        let s = 0.001 / n as f32;
        let mut tris = Vec::new();
        for y in 0..n {
            for x in 0..n {
                let (x0, y0) = (x as f32 * s, y as f32 * s);
                tris.push([v(x0, y0), v(x0 + s, y0), v(x0 + s, y0 + s)]);
                tris.push([v(x0, y0), v(x0 + s, y0 + s), v(x0, y0 + s)]);
            }
        }
        assert_eq!(find_uv_overlaps(&tris, 10), Ok(Vec::new()));
    }

    #[test]
    fn work_is_bounded_for_piles_of_triangles() {
        // 20 000 copies of one triangle: every pair overlaps; stops at the
        // limit instead of listing 2·10⁸ pairs.
        let t = [v(0.1, 0.1), v(0.9, 0.1), v(0.1, 0.9)];
        let pile = vec![t; 20_000];
        match find_uv_overlaps(&pile, 5) {
            Ok(found) => assert_eq!(found.len(), 5),
            Err(work) => assert!(work > MAX_PAIRS.min(MAX_CELL_ENTRIES as u64), "{work}"),
        }
        // 20 000 thin slivers spanning the square side by side (valid, but
        // each one's bounding box covers the whole grid): refused as too
        // much work, not tried.
        let n = 20_000;
        let slivers: Vec<[Vec2; 3]> = (0..n)
            .map(|i| {
                let x0 = i as f32 / n as f32;
                let x1 = (i + 1) as f32 / n as f32;
                [v(x0, 0.0), v(1.0 - x0, 1.0), v(x1, 0.0)]
            })
            .collect();
        assert!(find_uv_overlaps(&slivers, 5).is_err());
    }
}
