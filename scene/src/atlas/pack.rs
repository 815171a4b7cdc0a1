//! Packing the atlas (see the `atlas.rs` module documentation): the size
//! of every patch's chart and mesh's lightmap block, and the shelves they
//! are placed on in the narrowest atlas that holds them.

use super::{BLOCK_RING, HEIGHT_ALIGN, MIN_WIDTH, PADDING};
use crate::{Patch, PatchShape, Scene};

/// Texels along an edge of `length` metres at `density` texels per metre.
fn texels_along(length: f32, density: f32) -> u32 {
    let cells = (length * density).ceil().max(1.0);
    // Saturating conversion: absurd densities become an overflow error later.
    (cells.min(1.0e9) as u32).saturating_add(1)
}

/// Chart dimensions for one patch: a quad's edges each at the density; a
/// triangle's chart is square (its third edge runs along the chart's
/// diagonal, whose texel centres must lie on it), as many texels per side as
/// the longer of `u` and `v` needs at the density. `u` and `v` meet at the
/// triangle's largest angle (`PatchShape::triangle`), so the third edge is
/// sampled at most twice as coarsely (at most sqrt(2) times unless that
/// angle is obtuse), as a quad's cell diagonal is; a quad cut in two
/// (`Scene::triangulated`) keeps the quad's grid.
///
/// A quad merged from `n` equal cells along an edge (`Patch::cells`) gets
/// `n` times the spacings one cell's chart would have, plus one: its edge
/// texels fall where the cells' would, also where it meets a smaller merged
/// chart of the same tessellation. Not when a cell is shorter than a texel
/// spacing at the density: a whole spacing per cell would then hold more
/// texels than the density asks for (up to one per cell of a fine mesh), so
/// such a chart is sampled at the density like any quad, and where it meets
/// another along part of an edge their texels are not stitched.
fn chart_size(patch: &Patch) -> (u32, u32) {
    let along = |length: f32, cells: u32| {
        let cell = length / cells.max(1) as f32;
        if cells <= 1 || cell * patch.texel_density < 1.0 {
            return texels_along(length, patch.texel_density);
        }
        let spacings = texels_along(cell, patch.texel_density) - 1;
        cells.saturating_mul(spacings).saturating_add(1)
    };
    match patch.shape {
        PatchShape::Quad { u, v, .. } => (
            along(u.length(), patch.cells[0]),
            along(v.length(), patch.cells[1]),
        ),
        PatchShape::Triangle { u, v, .. } => {
            let n = texels_along(u.length().max(v.length()), patch.texel_density);
            (n, n)
        }
    }
}

/// Shelf-packs charts of the given sizes into an atlas `width` wide; returns
/// positions and the packed height.
fn shelf_pack(sizes: &[(u32, u32)], width: u32) -> Option<(Vec<(u32, u32)>, u32)> {
    let mut order: Vec<usize> = (0..sizes.len()).collect();
    order.sort_by(|&a, &b| {
        sizes[b]
            .1
            .cmp(&sizes[a].1)
            .then(sizes[b].0.cmp(&sizes[a].0))
            .then(a.cmp(&b))
    });
    let mut pos = vec![(0, 0); sizes.len()];
    let (mut x, mut y, mut shelf) = (0u32, 0u32, 0u32);
    for i in order {
        let (w, h) = sizes[i];
        if w > width {
            return None;
        }
        if x + w > width {
            y = y.checked_add(shelf + PADDING)?;
            x = 0;
            shelf = 0;
        }
        pos[i] = (x, y);
        x += w + PADDING;
        shelf = shelf.max(h);
    }
    Some((pos, y.checked_add(shelf)?))
}

/// The sizes of the items to pack: every patch's chart, then every mesh's
/// lightmap block with its ring. Also, per mesh, whether its triangles
/// use its block.
pub(super) fn item_sizes(scene: &Scene) -> (Vec<(u32, u32)>, Vec<bool>) {
    // Packed items: every patch on a chart of its own (a triangle on its
    // mesh's lightmap takes none: a 0 x 0 item, placed with its block
    // below), then the blocks of the meshes whose triangles use them.
    let mut sizes: Vec<(u32, u32)> = scene
        .patches
        .iter()
        .map(|p| {
            if p.lightmap.is_some() {
                (0, 0)
            } else {
                chart_size(p)
            }
        })
        .collect();
    let used: Vec<bool> = (0..scene.uv_meshes.len())
        .map(|m| {
            scene
                .patches
                .iter()
                .any(|p| p.lightmap.is_some_and(|l| l.mesh as usize == m))
        })
        .collect();
    let sides: Vec<u32> = scene
        .uv_meshes
        .iter()
        .zip(&used)
        .map(|(mesh, &used)| {
            if used {
                super::uv::block_side(scene, mesh)
            } else {
                0
            }
        })
        .collect();
    // A block is packed with a ring of [`BLOCK_RING`] texels around it,
    // which publication fills as its gutter: an island that reaches its
    // lightmap's border is read bilinearly there from its own light, never
    // from the chart packed next to it.
    sizes.extend(sides.iter().map(|&n| {
        if n > 0 {
            (n + 2 * BLOCK_RING, n + 2 * BLOCK_RING)
        } else {
            (0, 0)
        }
    }));
    (sizes, used)
}

/// Where [`narrowest`] places the items to pack.
pub(super) struct Packing {
    pub(super) width: u32,
    /// The packed height, rounded up to [`HEIGHT_ALIGN`].
    pub(super) height: u32,
    /// Each item's left column and top row.
    pub(super) positions: Vec<(u32, u32)>,
}

/// The narrowest atlas whose shelves hold items of `sizes`: the smallest
/// power of two wide (from [`MIN_WIDTH`], at most `max`) in which they are
/// no taller than wide, or, `max` wide, no taller than `max`; none when
/// they do not fit in `max` × `max`.
pub(super) fn narrowest(sizes: &[(u32, u32)], max: u32) -> Option<Packing> {
    let mut width = MIN_WIDTH.min(max);
    loop {
        if let Some((pos, height)) = shelf_pack(sizes, width) {
            let aligned = height.div_ceil(HEIGHT_ALIGN) * HEIGHT_ALIGN;
            if aligned <= width || (width >= max && aligned <= max) {
                return Some(Packing {
                    width,
                    height: aligned,
                    positions: pos,
                });
            }
        }
        if width >= max {
            return None;
        }
        width = (width * 2).min(max);
    }
}
