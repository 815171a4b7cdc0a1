//! Lightmap UVs from the `uvunwrap` crate (issue 58, item 2): charts grown
//! by normal deviation from the largest planar regions, flattened by planar
//! projection or least-squares conformal maps with as-rigid-as-possible
//! smoothing where they curve, and packed by shape at a fixed texel density,
//! as xatlas does for Unity and Godot. The projection of the parent module
//! cuts a chart where its projection would overlap and packs rectangles;
//! this one unfolds a curved surface conformally and nests small charts
//! into the gaps of large ones, so a level gets fewer charts and elements
//! (BENCHMARKS.md §9 measures both).

use glam::{Vec2, Vec3};

use super::{BORDER, MAX_SIDE, Unwrap, weld};

/// Empty texels around each chart: charts at least twice this apart and
/// this far from the block's edge, as the projection's [`super::GAP`] and
/// [`BORDER`] (each island's texels reach one texel beyond it, its gutter
/// one more).
pub const PADDING: u32 = 2;

/// The crate's limit on a chart's normal deviation (degrees) from its
/// average normal: the projection's [`super::MAX_ANGLE_DEG`], not the
/// crate's default 70°. Light across a crease is not continuous, and a
/// chart that folds round one blends both sides in a texel: on the garage
/// at 45° the lamp's frame read 17.7% NRMSE where a player looks, 12.4% at
/// 30° (one run of `lightwire bench eye`, 2,000 points).
pub const MAX_CHART_ANGLE: f32 = 30.0;

/// Generates lightmap UVs for `triangles` (each triangle's front is the side
/// its corners run counter-clockwise around) at `density` texels per metre,
/// with `uvunwrap`. Corners equal to [`super::WELD`] of the extent are one
/// vertex, so charts run across every manifold edge whose faces are within
/// the angle. Triangles the crate cannot chart (thinner than f32 UVs
/// resolve) collapse onto a corner of a charted neighbour: they get no
/// texels of their own, as degenerate triangles get none. Falls back to the
/// projection when the crate refuses the mesh (the error is logged).
pub fn unwrap(triangles: &[[Vec3; 3]], density: f32) -> Unwrap {
    let (corners, positions) = weld(triangles);
    let positions: Vec<[f32; 3]> = positions.iter().map(|p| p.to_array()).collect();
    let indices: Vec<u32> = corners.iter().flatten().copied().collect();
    let run = |density: f32, page_size: Option<u32>| {
        let options = uvunwrap::Options {
            max_chart_angle: MAX_CHART_ANGLE,
            density: uvunwrap::Density::Fixed {
                texels_per_unit: density,
                page_size,
            },
            padding: PADDING,
            ..uvunwrap::Options::default()
        };
        uvunwrap::generate(&[uvunwrap::MeshInput::new(&positions, &indices)], &options)
    };
    let mut density = density;
    for _ in 0..8 {
        let mut atlas = match run(density, None) {
            Ok(atlas) => atlas,
            Err(e) => {
                tracing::warn!(
                    "uvunwrap could not unwrap a mesh of {} triangles ({e}); its charts are projected instead",
                    triangles.len()
                );
                return super::project(triangles, density);
            }
        };
        // The block is square and the crate's growing page is not: packed
        // again onto square pages a little larger than the page's area,
        // taken where everything fits one (`SQUARE_TRIES`).
        let area = f64::from(atlas.width) * f64::from(atlas.height);
        for grow in SQUARE_TRIES {
            let size = ((area.sqrt() * grow) as u32).div_ceil(4) * 4;
            if size >= atlas.width.max(atlas.height) {
                break;
            }
            if let Ok(square) = run(density, Some(size))
                && square.page_count == 1
            {
                atlas = square;
                break;
            }
        }
        // The block: the page's longer side, plus the ring the projection
        // leaves (`BORDER` beyond the crate's padding).
        let page = atlas.width.max(atlas.height) as f32;
        let side = page + 2.0 * (BORDER - PADDING as f32).max(0.0);
        if side > MAX_SIDE {
            density *= (MAX_SIDE / side).min(0.98);
            continue;
        }
        return from_atlas(&atlas, triangles, side, page);
    }
    super::project(triangles, density)
}

/// Square pages tried, as multiples of the side of a square of the growing
/// page's area, smallest first.
const SQUARE_TRIES: [f64; 2] = [1.04, 1.12];

/// Turns the crate's single page (`page` texels, `[0, 1]` on its sides) into
/// an [`Unwrap`] on a square block of `side` texels, centred.
fn from_atlas(atlas: &uvunwrap::Atlas, triangles: &[[Vec3; 3]], side: f32, page: f32) -> Unwrap {
    let n = triangles.len();
    let Some(out) = atlas.meshes.first() else {
        return Unwrap {
            uvs: vec![[Vec2::ZERO; 3]; n],
            chart: vec![u32::MAX; n],
            charts: 0,
            axes: Vec::new(),
            side,
        };
    };
    let offset = Vec2::splat(0.5 * (side - page));
    let (w, h) = (atlas.width as f32, atlas.height as f32);
    let mut uvs = Vec::with_capacity(n);
    let mut chart = Vec::with_capacity(n);
    let mut charts = 0u32;
    for tri in out.indices.chunks_exact(3) {
        let v = [0, 1, 2].map(|k| out.vertices.get(tri[k] as usize));
        let uv = v.map(|v| {
            v.map_or(Vec2::ZERO, |v| {
                (Vec2::new(v.uv[0] * w, v.uv[1] * h) + offset) / side
            })
        });
        let c = v.iter().flatten().find_map(|v| v.chart).unwrap_or(u32::MAX);
        if c != u32::MAX {
            charts = charts.max(c + 1);
        }
        uvs.push(uv);
        chart.push(c);
    }
    uvs.resize(n, [Vec2::ZERO; 3]);
    chart.resize(n, u32::MAX);
    // Each chart's area-weighted mean normal.
    let mut axes = vec![Vec3::ZERO; charts as usize];
    for (&c, [a, b, d]) in chart.iter().zip(triangles) {
        if let Some(axis) = axes.get_mut(c as usize) {
            *axis += 0.5 * (*b - *a).cross(*d - *a);
        }
    }
    Unwrap {
        uvs,
        chart,
        charts: charts as usize,
        axes: axes.into_iter().map(Vec3::normalize_or_zero).collect(),
        side,
    }
}
