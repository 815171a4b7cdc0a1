//! The lightmap atlas: lightmap texels are the radiosity elements.
//!
//! Every patch of a [`Scene`] gets a chart: a `w × h` rectangle of texels in
//! one atlas texture. Texel centres are placed so that the outermost row and
//! column of a chart lie *on* the patch's edges (thesis §4.1, "cross-texture
//! radiosity interpolation"): texel `(a, b)` of a chart sits at patch
//! parameters `s = a / (w - 1)`, `t = b / (h - 1)`. Two adjacent coplanar
//! patches therefore own samples at the very same world positions along their
//! shared edge, compute the same radiosity there, and bilinear filtering
//! interpolates across the seam without either chart reading the other.
//!
//! Because boundary samples sit on the edge, each texel stands for the part
//! of the patch nearest to it: interior texels cover a full cell
//! `|u|/(w-1) × |v|/(h-1)`, edge texels half a cell and corner texels a
//! quarter, so the element areas of a patch sum to exactly its area.
//! Corner samples are moved inward by [`CORNER_OFFSET`] of a cell along both
//! axes, so that a corner sample is never on two edges at once (where the
//! surface it belongs to is ambiguous to a rasterised item buffer).
//!
//! Packing (`atlas/pack.rs`): charts are sorted by height (then width) and
//! placed on shelves, left to right, with [`PADDING`] empty texels between
//! charts and shelves. The atlas width is the smallest power of two (at
//! least 64) for which the packing is no taller than it is wide; the height
//! is rounded up to a multiple of [`HEIGHT_ALIGN`]. Texels that belong to no
//! chart are "not covered" and carry no element.

use glam::{Vec2, Vec3};

use crate::{Patch, Scene, SceneIssue};

mod pack;
pub mod stitch;
pub mod uv;
pub use stitch::IslandSeams;
pub use uv::ChartMap;

/// Empty texels between neighbouring charts (a gutter for filtering).
pub const PADDING: u32 = 1;
/// Texels around a mesh's lightmap block that belong to it (filled as its
/// gutter on publication, [`Atlas::to_image`]), besides [`PADDING`].
pub const BLOCK_RING: u32 = 1;
/// Atlas height is rounded up to a multiple of this (the tile size used by
/// the lightmap codec).
pub const HEIGHT_ALIGN: u32 = 8;
/// Inward offset of corner samples, as a fraction of the texel spacing.
pub const CORNER_OFFSET: f32 = 0.05;
/// Marker in [`Atlas::texel_element`] for a texel that belongs to no chart.
pub const NO_ELEMENT: u32 = u32::MAX;
/// Smallest atlas width tried.
const MIN_WIDTH: u32 = 64;

/// Where a patch lives in the atlas.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct Chart {
    /// Left column of the chart in the atlas.
    pub x: u32,
    /// Top row of the chart in the atlas.
    pub y: u32,
    /// Texels along the patch's `u` edge (>= 2).
    pub w: u32,
    /// Texels along the patch's `v` edge (>= 2).
    pub h: u32,
}

/// One radiosity element: a texel of a chart.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Element {
    /// Patch (surface) id, an index into [`Scene::patches`].
    pub patch: u32,
    /// Object id, an index into [`Scene::objects`].
    pub object: u32,
    /// Atlas column and row.
    pub texel: [u32; 2],
    /// Patch parameters `(s, t)` of the sample, in [0, 1]².
    pub st: [f32; 2],
    /// Sample position in object-local space.
    pub position: Vec3,
    /// Unit normal in object-local space.
    pub normal: Vec3,
    /// Area this element stands for, in object-local units (m²); 0 for a
    /// texel of a triangle's chart that lies wholly above the diagonal
    /// ([`Element::covers_surface`]).
    pub area: f32,
    /// The bounds of the region it stands for, in patch parameters:
    /// `[s0, t0, s1, t1]`; on a triangle, only its part with `t <= s`.
    pub region: [f32; 4],
    /// Diffuse reflectance per channel (from the material).
    pub albedo: Vec3,
    /// Self-emitted radiant exitance per channel (from the material).
    pub emission: Vec3,
}

impl Element {
    /// Whether the texel stands for any surface: false only for the texels
    /// of a triangle's chart above its diagonal, which are invalid
    /// everywhere (`validity.rs`) and filled by dilation.
    pub fn covers_surface(&self) -> bool {
        self.area > 0.0
    }
}

/// The packed atlas and its elements.
#[derive(Debug, Clone)]
pub struct Atlas {
    pub width: u32,
    pub height: u32,
    /// One chart per patch, indexed like [`Scene::patches`].
    pub charts: Vec<Chart>,
    /// Elements, grouped by patch in patch order, row-major within a chart.
    pub elements: Vec<Element>,
    /// First element of each patch; `patch_elements[p]..patch_elements[p+1]`.
    pub patch_elements: Vec<u32>,
    /// Element index per texel (row-major, `width * height`), or
    /// [`NO_ELEMENT`].
    pub texel_element: Vec<u32>,
    /// Groups of elements of different charts that stand for the same point
    /// of a surface (a seam's texels, [`Atlas::stitch`]), or for one texel
    /// of a mesh's own lightmap that several of its triangles cover
    /// (`atlas/uv.rs`).
    pub seams: Vec<Vec<u32>>,
    /// Per patch, the map from its parameters to its chart's texels when
    /// it is lit on its mesh's own lightmap UVs (a triangle, or a
    /// parallelogram of triangles, `atlas/uv.rs`); `None` on Lightwire's
    /// own charts ([`ChartMap::native`]).
    pub lightmap_maps: Vec<Option<ChartMap>>,
    /// Per patch, whether it is a triangle (else a parallelogram).
    pub triangles: Vec<bool>,
    /// Per entry of [`Scene::uv_meshes`], its lightmap's block in the atlas
    /// when its triangles are lit on it (a square chart of `w = h` texels).
    pub blocks: Vec<Option<Chart>>,
    /// The seams between islands of the meshes' own lightmaps (and between
    /// those and Lightwire's charts), which [`Atlas::to_image`] makes read
    /// alike on both sides (`atlas/stitch.rs`).
    pub island_seams: IslandSeams,
}

/// Chart sizes and positions without elements: enough to know whether a
/// scene fits.
#[derive(Debug, Clone)]
pub struct Layout {
    pub width: u32,
    pub height: u32,
    pub charts: Vec<Chart>,
    /// As [`Atlas::lightmap_maps`].
    pub lightmap_maps: Vec<Option<ChartMap>>,
    /// As [`Atlas::blocks`].
    pub blocks: Vec<Option<Chart>>,
}

/// Two patches meet smoothly (their seam's texels are stitched) when their
/// normals are this close: the cosine of 1°.
pub const SEAM_COS: f32 = 0.999_847_7;
/// Seam texels coincide when their grid points are this close (metres, in
/// object space), and are looked up on a grid of this spacing.
const SEAM_TOLERANCE: f32 = 1e-4;

/// The seams of an atlas (issue 18, item 3): every chart is a patch of its
/// own, so two patches that share an edge each have a row of texels on it
/// (and a corner texel at each shared vertex), at the same grid points
/// where their charts have as many texels along the edge (`atlas.rs`
/// places edge samples on the edge). Each computes its own element
/// average over its own side, so in a gradient the two disagree, and a
/// client sees the seam. Texels of one object whose grid points (corner
/// samples taken at the corner itself, not moved inward) coincide on
/// patches that face the same way within 1° and reflect alike
/// ([`Scene::reflects_alike`]) are one group; creases, where flat patches
/// meet at an angle, and edges where the material changes are not seams:
/// their light differs for real. Returns only groups of two or more.
fn find_seams(scene: &Scene, charts: &[Chart], elements: &[Element]) -> Vec<Vec<u32>> {
    use std::collections::HashMap;
    let mut at: HashMap<(u32, [i64; 3]), Vec<u32>> = HashMap::new();
    let mut first = 0usize;
    for (patch, chart) in scene.patches.iter().zip(charts) {
        let (origin, u, v) = patch.shape.frame();
        let count = (chart.w * chart.h) as usize;
        if patch.lightmap.is_some() {
            // Its texels are not on its edges (`atlas/uv.rs`).
            first += count;
            continue;
        }
        for (k, e) in elements[first..first + count].iter().enumerate() {
            let (a, b) = ((k as u32) % chart.w, (k as u32) / chart.w);
            let on_edge = a == 0
                || b == 0
                || a == chart.w - 1
                || b == chart.h - 1
                || (patch.shape.is_triangle() && a == b);
            if !on_edge || !e.covers_surface() {
                continue;
            }
            let point = origin
                + u * (a as f32 / (chart.w - 1) as f32)
                + v * (b as f32 / (chart.h - 1) as f32);
            let key = (point / SEAM_TOLERANCE).round();
            let key = [key.x as i64, key.y as i64, key.z as i64];
            at.entry((e.object, key))
                .or_default()
                .push((first + k) as u32);
        }
        first += count;
    }
    let mut seams = Vec::new();
    for (_, members) in at {
        if members.len() < 2 {
            continue;
        }
        // Members that face the same way, grouped greedily; a texel never
        // meets another of its own chart at one point.
        let mut groups: Vec<Vec<u32>> = Vec::new();
        for i in members {
            let n = elements[i as usize].normal;
            let p = elements[i as usize].patch as usize;
            match groups.iter_mut().find(|g| {
                let first = &elements[g[0] as usize];
                first.normal.dot(n) >= SEAM_COS && scene.reflects_alike(first.patch as usize, p)
            }) {
                Some(g) => g.push(i),
                None => groups.push(vec![i]),
            }
        }
        seams.extend(groups.into_iter().filter(|g| {
            g.len() >= 2 && {
                let p = elements[g[0] as usize].patch;
                g.iter().any(|&i| elements[i as usize].patch != p)
            }
        }));
    }
    seams
}

/// Groups of the elements that share a texel of a mesh's own lightmap and
/// cover part of it (`atlas/uv.rs`), two or more each.
fn shared_texels(maps: &[Option<ChartMap>], elements: &[Element]) -> Vec<Vec<u32>> {
    use std::collections::HashMap;
    let mut at: HashMap<[u32; 2], Vec<u32>> = HashMap::new();
    for (i, e) in elements.iter().enumerate() {
        if e.covers_surface() && maps.get(e.patch as usize).is_some_and(|m| m.is_some()) {
            at.entry(e.texel).or_default().push(i as u32);
        }
    }
    at.into_values().filter(|g| g.len() >= 2).collect()
}

fn elements_area(elements: &[Element], i: u32) -> f32 {
    elements.get(i as usize).map_or(0.0, |e| e.area)
}

/// The elements of a patch lit on its mesh's own lightmap (a triangle or
/// a parallelogram of them): every texel of its chart, row-major, as
/// `atlas/uv.rs` says.
fn uv_elements(
    patch: &Patch,
    p: u32,
    material: &crate::Material,
    chart: &Chart,
    map: &ChartMap,
) -> Vec<Element> {
    let (origin, u, v) = patch.shape.frame();
    let normal = patch.shape.normal();
    // The patch's corners in chart coordinates, and world area per
    // texel² of the chart.
    let q = uv::chart_corners(map, patch.shape.is_triangle());
    let texels = f64::from(uv::polygon_area(&q).abs());
    let scale = if texels > 0.0 {
        f64::from(patch.shape.area()) / texels
    } else {
        0.0
    };
    // Chart coordinates put texel (a, b)'s footprint at [a - 0.5, a + 0.5]:
    // shift by half a texel for `uv::covered`, whose texel (i, j) covers
    // [i, i + 1].
    let shifted: Vec<Vec2> = q.iter().map(|&c| c + Vec2::splat(0.5)).collect();
    let centre = Vec2::from(patch.shape.centre_param());
    let param = |xy: Vec2| map.to_param(xy).unwrap_or(centre);
    let mut out = Vec::with_capacity((chart.w * chart.h) as usize);
    for b in 0..chart.h {
        for a in 0..chart.w {
            let centre = Vec2::new(a as f32, b as f32);
            let (covered, poly) = uv::covered(&shifted, a, b);
            let st = param(uv::inward_of_corners(
                &q,
                uv::nearest_on_polygon(&q, centre),
            ));
            // The bounds of the covered part in patch parameters (the
            // texel's sample alone when it covers none).
            let mut region = [st.x, st.y, st.x, st.y];
            for c in &poly {
                let at = param(c.as_vec2() - Vec2::splat(0.5));
                region = [
                    region[0].min(at.x),
                    region[1].min(at.y),
                    region[2].max(at.x),
                    region[3].max(at.y),
                ];
            }
            let area = (covered * scale) as f32;
            out.push(Element {
                patch: p,
                object: patch.object,
                texel: [chart.x + a, chart.y + b],
                st: st.to_array(),
                position: origin + u * st.x + v * st.y,
                normal,
                area,
                region,
                albedo: patch.region_albedo(material, region, st.to_array()),
                emission: material.emission,
            });
        }
    }
    out
}

/// Plans the atlas for a scene, or explains why it does not fit.
pub fn plan(scene: &Scene) -> Result<Layout, SceneIssue> {
    let (sizes, used) = pack::item_sizes(scene);
    let max = scene.max_atlas_size;
    check_item_sizes(scene, &sizes, max)?;
    let Some(packing) = pack::narrowest(&sizes, max) else {
        let texels: u64 = sizes
            .iter()
            .map(|&(w, h)| u64::from(w + PADDING) * u64::from(h + PADDING))
            .sum();
        return Err(SceneIssue {
            location: "lightmap".to_string(),
            problem: format!(
                "atlas overflow: {} surfaces need about {texels} texels, which do not fit in {max} x {max} (lightmap.max_atlas_size); lower texel_density or raise max_atlas_size",
                scene.patches.len()
            ),
        });
    };
    let mut charts: Vec<Chart> = sizes
        .iter()
        .zip(packing.positions)
        .map(|(&(w, h), (x, y))| Chart { x, y, w, h })
        .collect();
    let blocks: Vec<Option<Chart>> = charts
        .split_off(scene.patches.len())
        .into_iter()
        .zip(&used)
        .map(|(b, &used)| {
            used.then(|| Chart {
                x: b.x + BLOCK_RING,
                y: b.y + BLOCK_RING,
                w: b.w - 2 * BLOCK_RING,
                h: b.h - 2 * BLOCK_RING,
            })
        })
        .collect();
    let lightmap_maps = place_on_blocks(scene, &blocks, &mut charts);
    Ok(Layout {
        width: packing.width,
        height: packing.height.max(HEIGHT_ALIGN),
        charts,
        lightmap_maps,
        blocks,
    })
}

/// Reports the first packed item (`sizes`: the patches' charts, then the
/// meshes' lightmap blocks) wider or taller than `max`, the largest atlas
/// edge.
fn check_item_sizes(scene: &Scene, sizes: &[(u32, u32)], max: u32) -> Result<(), SceneIssue> {
    if let Some((i, (w, h))) = sizes
        .iter()
        .enumerate()
        .find(|(_, (w, h))| *w > max || *h > max)
    {
        let location = match scene.patches.get(i) {
            Some(p) => format!("surface #{} \"{}\"", p.surface_index, p.name),
            None => format!(
                "mesh \"{}\"'s lightmap",
                scene.uv_meshes[i - scene.patches.len()].name
            ),
        };
        return Err(SceneIssue {
            location,
            problem: format!(
                "atlas overflow: this surface alone needs {w} x {h} texels but lightmap.max_atlas_size is {max}; lower its texel_density"
            ),
        });
    }
    Ok(())
}

/// Places the chart of every patch lit on its mesh's lightmap in that
/// mesh's block (`blocks`): the texels its lightmap UVs cover. Returns,
/// per patch, the map from its parameters to its chart (`None` for a
/// patch on a chart of its own).
fn place_on_blocks(
    scene: &Scene,
    blocks: &[Option<Chart>],
    charts: &mut [Chart],
) -> Vec<Option<ChartMap>> {
    let mut lightmap_maps = vec![None; scene.patches.len()];
    for (p, patch) in scene.patches.iter().enumerate() {
        let Some(l) = patch.lightmap else { continue };
        let Some(block) = blocks.get(l.mesh as usize).copied().flatten() else {
            continue;
        };
        let q = l.uv.map(|c| c * block.w as f32);
        // A parallelogram's fourth corner is affine.
        let mut corners = q.to_vec();
        if !patch.shape.is_triangle() {
            corners.push(q[0] + q[2] - q[1]);
        }
        let ([x, y], [w, h]) = uv::polygon_chart(&corners, block.w);
        charts[p] = Chart {
            x: block.x + x,
            y: block.y + y,
            w,
            h,
        };
        let centre = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
        lightmap_maps[p] = Some(ChartMap {
            origin: q[0] - centre,
            ds: q[1] - q[0],
            dt: q[2] - q[1],
        });
    }
    lightmap_maps
}

/// Parameter of sample `a` of `n` along an edge, with the corner offset
/// applied when `corner` is set.
fn sample_param(a: u32, n: u32, corner: bool) -> f32 {
    let cells = (n - 1) as f32;
    let mut s = a as f32 / cells;
    if corner {
        let inward = CORNER_OFFSET / cells;
        s = if a == 0 { s + inward } else { s - inward };
    }
    s
}

/// The part of the parameter box `[s0, s1] x [t0, t1]` on the triangle's
/// side of the chart's diagonal (`t <= s`), as a fraction of the box.
fn triangle_share([s0, t0, s1, t1]: [f32; 4]) -> f32 {
    let (s0, t0, s1, t1) = (f64::from(s0), f64::from(t0), f64::from(s1), f64::from(t1));
    let box_area = (s1 - s0) * (t1 - t0);
    if box_area <= 0.0 {
        return 0.0;
    }
    let clipped = clip_below_diagonal(&[(s0, t0), (s1, t0), (s1, t1), (s0, t1)]);
    let mut twice = 0.0;
    for i in 0..clipped.len() {
        let (p, q) = (clipped[i], clipped[(i + 1) % clipped.len()]);
        twice += p.0 * q.1 - q.0 * p.1;
    }
    ((twice.abs() * 0.5) / box_area).clamp(0.0, 1.0) as f32
}

/// Sutherland–Hodgman clip of the parameter polygon `square` (four
/// corners in order) by the half-plane `t <= s` of a triangle's chart, with
/// repeated corners (where a corner lies on the diagonal) dropped: at most
/// five corners. The atlas's element areas and the reference solver's
/// element regions both come from it.
pub fn clip_below_diagonal(square: &[(f64, f64); 4]) -> Vec<(f64, f64)> {
    fn same(p: (f64, f64), q: (f64, f64)) -> bool {
        (q.0 - p.0).abs() <= 1e-12 && (q.1 - p.1).abs() <= 1e-12
    }
    let inside = |p: (f64, f64)| p.1 <= p.0;
    let mut out: Vec<(f64, f64)> = Vec::with_capacity(8);
    let mut push = |p: (f64, f64)| {
        if !out.last().is_some_and(|&q| same(p, q)) {
            out.push(p);
        }
    };
    for i in 0..4 {
        let (p, q) = (square[i], square[(i + 1) % 4]);
        if inside(p) {
            push(p);
        }
        if inside(p) != inside(q) {
            // Where t - s changes sign along p -> q.
            let (dp, dq) = (p.1 - p.0, q.1 - q.0);
            let f = dp / (dp - dq);
            push((p.0 + (q.0 - p.0) * f, p.1 + (q.1 - p.1) * f));
        }
    }
    while out.len() > 1 && same(out[0], out[out.len() - 1]) {
        out.pop();
    }
    // A convex box cut by one line keeps at most five corners.
    out.truncate(5);
    out
}

/// The span of patch parameter an element covers along one axis.
fn region_1d(a: u32, n: u32) -> (f32, f32) {
    let cells = (n - 1) as f32;
    let lo = ((a as f32 - 0.5) / cells).max(0.0);
    let hi = ((a as f32 + 0.5) / cells).min(1.0);
    (lo, hi)
}

impl Atlas {
    /// Charts and packs every patch of the scene and creates its elements.
    pub fn build(scene: &Scene) -> Result<Atlas, SceneIssue> {
        let layout = plan(scene)?;
        let (width, height) = (layout.width, layout.height);
        let mut texel_element = vec![NO_ELEMENT; (width as usize) * (height as usize)];
        let mut elements = Vec::new();
        let mut patch_elements = Vec::with_capacity(scene.patches.len() + 1);
        for (p, (patch, chart)) in scene.patches.iter().zip(&layout.charts).enumerate() {
            patch_elements.push(elements.len() as u32);
            let material = &scene.materials[patch.material as usize];
            if let Some(map) = layout.lightmap_maps[p] {
                for e in uv_elements(patch, p as u32, material, chart, &map) {
                    let texel = (e.texel[1] * width + e.texel[0]) as usize;
                    let owner = texel_element[texel];
                    // The texel shows the element that covers most of it.
                    if owner == NO_ELEMENT || elements_area(&elements, owner) < e.area {
                        texel_element[texel] = elements.len() as u32;
                    }
                    elements.push(e);
                }
                continue;
            }
            let (origin, u, v) = patch.shape.frame();
            let triangle = patch.shape.is_triangle();
            let normal = patch.shape.normal();
            // The area of the (s, t) unit square: the quad's, twice the
            // triangle's.
            let square_area = u.cross(v).length();
            for b in 0..chart.h {
                for a in 0..chart.w {
                    let on_u_edge = a == 0 || a == chart.w - 1;
                    let on_v_edge = b == 0 || b == chart.h - 1;
                    let corner = on_u_edge && on_v_edge;
                    let (mut s, mut t) = (
                        sample_param(a, chart.w, corner),
                        sample_param(b, chart.h, corner),
                    );
                    let (s0, s1) = region_1d(a, chart.w);
                    let (t0, t1) = region_1d(b, chart.h);
                    let region = [s0, t0, s1, t1];
                    let mut area = square_area * (s1 - s0) * (t1 - t0);
                    if triangle {
                        if b > a {
                            // Above the diagonal: no surface. The texel
                            // keeps an element of area 0 (charts stay full
                            // grids, which the GPU's element indexing
                            // needs), sampled at the nearest point of the
                            // diagonal edge; validity marks it invalid and
                            // dilation fills it.
                            let m = (s + t) * 0.5;
                            (s, t) = (m, m);
                            area = 0.0;
                        } else {
                            area *= triangle_share(region);
                        }
                    }
                    let texel = [chart.x + a, chart.y + b];
                    texel_element[(texel[1] * width + texel[0]) as usize] = elements.len() as u32;
                    elements.push(Element {
                        patch: p as u32,
                        object: patch.object,
                        texel,
                        st: [s, t],
                        position: origin + u * s + v * t,
                        normal,
                        area,
                        region,
                        albedo: patch.region_albedo(material, region, [s, t]),
                        emission: material.emission,
                    });
                }
            }
        }
        patch_elements.push(elements.len() as u32);
        let mut seams = find_seams(scene, &layout.charts, &elements);
        seams.extend(shared_texels(&layout.lightmap_maps, &elements));
        seams.sort_unstable();
        let island_seams = IslandSeams::find(
            scene,
            &stitch::Charts {
                charts: &layout.charts,
                maps: &layout.lightmap_maps,
                texel_element: &texel_element,
                width,
                height,
            },
        );
        Ok(Atlas {
            width,
            height,
            charts: layout.charts,
            elements,
            patch_elements,
            texel_element,
            seams,
            lightmap_maps: layout.lightmap_maps,
            triangles: scene
                .patches
                .iter()
                .map(|p| p.shape.is_triangle())
                .collect(),
            blocks: layout.blocks,
            island_seams,
        })
    }

    /// The map from `patch`'s parameters to its chart's texel coordinates.
    pub fn chart_map(&self, patch: u32) -> ChartMap {
        match self.lightmap_maps.get(patch as usize).copied().flatten() {
            Some(map) => map,
            None => {
                let c = self.charts[patch as usize];
                ChartMap::native(c.w, c.h)
            }
        }
    }

    /// The part of element `e`'s texel footprint its patch covers, in patch
    /// parameters, when the element is of a patch lit on its mesh's own
    /// lightmap UVs (`atlas/uv.rs`; empty when it covers none).
    pub fn lightmap_region(&self, e: usize) -> Option<Vec<Vec2>> {
        let el = self.elements.get(e)?;
        let map = self
            .lightmap_maps
            .get(el.patch as usize)
            .copied()
            .flatten()?;
        let chart = self.charts[el.patch as usize];
        let triangle = self
            .triangles
            .get(el.patch as usize)
            .copied()
            .unwrap_or(true);
        let q: Vec<Vec2> = uv::chart_corners(&map, triangle)
            .into_iter()
            .map(|c| c + Vec2::splat(0.5))
            .collect();
        let (_, polygon) = uv::covered(&q, el.texel[0] - chart.x, el.texel[1] - chart.y);
        Some(
            polygon
                .into_iter()
                .filter_map(|c| map.to_param(c.as_vec2() - Vec2::splat(0.5)))
                .collect(),
        )
    }

    /// Whether `patch` is lit on its mesh's own lightmap UVs (a triangle or
    /// a parallelogram of them).
    pub fn on_lightmap_uvs(&self, patch: u32) -> bool {
        self.lightmap_maps
            .get(patch as usize)
            .is_some_and(|m| m.is_some())
    }

    /// The element of `patch` whose texel holds the point at patch
    /// parameters `st` (clamped onto its chart; on a triangle of
    /// Lightwire's own charts, a point beyond the diagonal reads the
    /// diagonal's texel, whose `b <= a` stands for surface).
    pub fn element_of(&self, patch: u32, triangle: bool, st: Vec2) -> Option<usize> {
        let chart = *self.charts.get(patch as usize)?;
        let xy = self.chart_map(patch).to_chart(st);
        let a = xy.x.round().clamp(0.0, (chart.w - 1) as f32) as u32;
        let mut b = xy.y.round().clamp(0.0, (chart.h - 1) as f32) as u32;
        if triangle && !self.on_lightmap_uvs(patch) {
            b = b.min(a);
        }
        Some(self.patch_elements[patch as usize] as usize + (b * chart.w + a) as usize)
    }

    /// Makes the texels of every seam agree: each group of
    /// [`Atlas::seams`] takes the mean of its members that `keep` accepts
    /// (the valid ones), and those members are set to it; groups without
    /// such a member are left alone.
    pub fn stitch(&self, values: &mut [Vec3], keep: impl Fn(usize) -> bool) {
        for group in &self.seams {
            let (mut sum, mut n) = (Vec3::ZERO, 0u32);
            for &i in group {
                if let Some(v) = values.get(i as usize).filter(|_| keep(i as usize)) {
                    sum += *v;
                    n += 1;
                }
            }
            if n < 2 {
                continue;
            }
            let mean = sum / n as f32;
            for &i in group {
                if let Some(v) = values.get_mut(i as usize).filter(|_| keep(i as usize)) {
                    *v = mean;
                }
            }
        }
    }

    /// The element at atlas texel `(x, y)`, if the texel is covered.
    pub fn element_at(&self, x: u32, y: u32) -> Option<u32> {
        if x >= self.width || y >= self.height {
            return None;
        }
        match self.texel_element[(y * self.width + x) as usize] {
            NO_ELEMENT => None,
            e => Some(e),
        }
    }

    /// The patch (surface) that owns atlas texel `(x, y)`, if any.
    pub fn patch_at(&self, x: u32, y: u32) -> Option<u32> {
        self.element_at(x, y)
            .map(|e| self.elements[e as usize].patch)
    }

    /// The elements of one patch.
    pub fn elements_of(&self, patch: u32) -> std::ops::Range<usize> {
        self.patch_elements[patch as usize] as usize
            ..self.patch_elements[patch as usize + 1] as usize
    }

    /// Number of elements on dynamic objects.
    pub fn dynamic_element_count(&self, scene: &Scene) -> usize {
        self.elements
            .iter()
            .filter(|e| scene.objects[e.object as usize].dynamic)
            .count()
    }

    /// The lightmap as a client samples it: `values` (one per element, with
    /// invalid texels already filled, see `Validity::dilate`) read
    /// bilinearly at patch parameters `(s, t)` of `patch`, clamped to its
    /// chart (texel centres sit at `s = a / (w - 1)`).
    pub fn sample(&self, values: &[Vec3], patch: u32, st: [f32; 2]) -> Vec3 {
        self.sample_weights(patch, st)
            .iter()
            .map(|&(i, w)| values[i] * w)
            .sum()
    }

    /// The four elements [`Atlas::sample`] blends at patch parameters
    /// `(s, t)` of `patch` and their bilinear weights (summing to 1), for
    /// whoever keeps a lookup to apply it to many radiosities (the ray
    /// solver's kept rays, `lightwire_solve::rays`). The chart must be at
    /// least 2 x 2.
    pub fn sample_weights(&self, patch: u32, [s, t]: [f32; 2]) -> [(usize, f32); 4] {
        let chart = self.charts[patch as usize];
        let first = self.patch_elements[patch as usize] as usize;
        let xy = self.chart_map(patch).to_chart(Vec2::new(s, t));
        let axis = |x: f32, n: u32| -> (u32, f32) {
            let x = x.clamp(0.0, (n - 1) as f32);
            let x0 = (x.floor() as u32).min(n - 2);
            (x0, x - x0 as f32)
        };
        let ((a, fa), (b, fb)) = (axis(xy.x, chart.w), axis(xy.y, chart.h));
        // Elements are row-major within their chart.
        let at = |a: u32, b: u32| first + (b * chart.w + a) as usize;
        [
            (at(a, b), (1.0 - fa) * (1.0 - fb)),
            (at(a + 1, b), fa * (1.0 - fb)),
            (at(a, b + 1), (1.0 - fa) * fb),
            (at(a + 1, b + 1), fa * fb),
        ]
    }

    /// Scatters one value per element into a row-major RGB image of the
    /// atlas; uncovered texels are zero, but for the gutters of the meshes'
    /// own lightmap blocks ([`Atlas::fill_block_gutters`]), and the texels
    /// around the seams between their islands are adjusted so that both
    /// sides read alike ([`IslandSeams::apply`]).
    pub fn to_image(&self, values: &[Vec3]) -> Vec<[f32; 3]> {
        let mut image = vec![[0.0; 3]; (self.width as usize) * (self.height as usize)];
        for (i, (e, value)) in self.elements.iter().zip(values).enumerate() {
            let texel = (e.texel[1] * self.width + e.texel[0]) as usize;
            // A texel of a mesh's own lightmap may hold several elements
            // (`atlas/uv.rs`): it shows its owner.
            if self.texel_element[texel] == i as u32 {
                image[texel] = value.to_array();
            }
        }
        self.fill_block_gutters(&mut image);
        self.island_seams.apply(&mut image);
        image
    }

    /// In every mesh's lightmap block (`atlas/uv.rs`) and the ring of
    /// [`BLOCK_RING`] texels around it, the texels no chart holds but next
    /// to one that does take the mean of those neighbours (8-connected):
    /// the gutter bilinear filtering reads at an island's border.
    fn fill_block_gutters(&self, image: &mut [[f32; 3]]) {
        let w = self.width as i64;
        let ring = i64::from(BLOCK_RING);
        for block in self.blocks.iter().flatten() {
            let (x0, y0) = (i64::from(block.x) - ring, i64::from(block.y) - ring);
            let (x1, y1) = (
                (x0 + i64::from(block.w) + 2 * ring).min(w),
                (y0 + i64::from(block.h) + 2 * ring).min(i64::from(self.height)),
            );
            let (x0, y0) = (x0.max(0), y0.max(0));
            for y in y0..y1 {
                for x in x0..x1 {
                    if self.texel_element[(y * w + x) as usize] != NO_ELEMENT {
                        continue;
                    }
                    let (mut sum, mut n) = (Vec3::ZERO, 0.0f32);
                    for (dx, dy) in (-1..=1).flat_map(|dy| (-1..=1).map(move |dx| (dx, dy))) {
                        let (nx, ny) = (x + dx, y + dy);
                        if nx < x0 || ny < y0 || nx >= x1 || ny >= y1 {
                            continue;
                        }
                        let t = (ny * w + nx) as usize;
                        if self.texel_element[t] != NO_ELEMENT {
                            sum += Vec3::from_array(image[t]);
                            n += 1.0;
                        }
                    }
                    if n > 0.0 {
                        image[(y * w + x) as usize] = (sum / n).to_array();
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene(text: &str) -> Scene {
        Scene::parse(text, "test").unwrap_or_else(|e| panic!("{e}"))
    }

    const TWO_BOXES: &str = r#"{
        "name": "t",
        "lightmap": { "texel_density": 7.3 },
        "materials": [ { "name": "m", "albedo": [0.5, 0.5, 0.5], "emission": [1, 1, 1] } ],
        "objects": [ { "name": "o", "pose": { "translation": [3, 0, 0] } } ],
        "surfaces": [
            { "name": "room", "material": "m", "box": { "center": [0, 0, 0], "size": [2.1, 1.3, 0.7], "facing": "in" } },
            { "name": "cube", "material": "m", "object": "o", "texel_density": 4, "box": { "center": [0, 0, 0], "size": [0.5, 0.5, 0.5] } }
        ]
    }"#;

    /// A slanted quad cut into two triangles along its diagonal (indices
    /// 0 1 2 and 0 2 3), and a lone obtuse triangle, at a density that is
    /// not a divisor of any edge.
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

    /// Two coplanar 1 m quads that share the edge `x = 1`, the second of
    /// material `second`.
    fn side_by_side(second: &str) -> Scene {
        scene(&format!(
            r#"{{
            "name": "t",
            "lightmap": {{ "texel_density": 4 }},
            "materials": [
                {{ "name": "white", "albedo": [0.8, 0.8, 0.8] }},
                {{ "name": "white too", "albedo": [0.8, 0.8, 0.8] }},
                {{ "name": "dark", "albedo": [0.1, 0.1, 0.1] }},
                {{ "name": "lamp", "albedo": [0, 0, 0], "emission": [5, 5, 5] }}
            ],
            "surfaces": [
                {{ "name": "a", "material": "white", "quad": {{ "origin": [0, 0, 0], "u": [1, 0, 0], "v": [0, 0, -1] }} }},
                {{ "name": "b", "material": "{second}", "quad": {{ "origin": [1, 0, 0], "u": [1, 0, 0], "v": [0, 0, -1] }} }},
                {{ "name": "lamp", "material": "lamp", "quad": {{ "origin": [0.8, 1, -0.2], "u": [0, 0, -0.4], "v": [0.4, 0, 0] }} }}
            ]
        }}"#
        ))
    }

    #[test]
    fn seams_join_patches_that_reflect_alike_and_never_across_an_albedo_step() {
        for (second, joined) in [("white", true), ("white too", true), ("dark", false)] {
            let scene = side_by_side(second);
            assert_eq!(scene.reflects_alike(0, 1), joined, "{second}");
            let atlas = Atlas::build(&scene).unwrap_or_else(|e| panic!("{e}"));
            let across = atlas
                .seams
                .iter()
                .filter(|g| {
                    g.iter().any(|&i| atlas.elements[i as usize].patch == 0)
                        && g.iter().any(|&i| atlas.elements[i as usize].patch == 1)
                })
                .count();
            if joined {
                // The shared edge's texels, one per grid point (4 per metre).
                assert_eq!(across, 5, "{second}: the edge's texels are stitched");
            } else {
                assert_eq!(across, 0, "{second}: no seam where the albedo steps");
            }
        }
    }

    #[test]
    fn element_areas_of_a_patch_sum_to_its_area() {
        for text in [TWO_BOXES, TRIANGLES] {
            check_areas(&scene(text));
        }
    }

    #[test]
    fn triangle_charts_hold_the_triangle_below_the_diagonal() {
        // Unpaired: the floor's two triangles form a parallelogram, which
        // would otherwise be one quad patch (`scene/pairs.rs`).
        let options = crate::LoadOptions::unpaired(1.0);
        let scene = Scene::parse_with(TRIANGLES, "test", options).unwrap_or_else(|e| panic!("{e}"));
        let atlas = Atlas::build(&scene).expect("fits");
        assert_eq!(scene.patches.len(), 3);
        for (p, patch) in scene.patches.iter().enumerate() {
            assert!(patch.shape.is_triangle());
            let chart = atlas.charts[p];
            assert_eq!(chart.w, chart.h, "triangle charts are square");
            // The two edges along the chart's axes at the density, the third
            // (the diagonal) at most twice as coarse.
            let (origin, u, v) = patch.shape.frame();
            let cells = (chart.w - 1) as f32;
            assert!(cells >= u.length().max(v.length()) * patch.texel_density - 1e-3);
            assert!((u + v).length() / cells <= 2.0 / patch.texel_density);
            // The largest angle is between the axes: the diagonal is the
            // longest edge.
            assert!((u + v).length() >= u.length().max(v.length()) - 1e-6);
            let mut covering = 0;
            for e in atlas.elements_of(p as u32).map(|e| &atlas.elements[e]) {
                let (a, b) = (e.texel[0] - chart.x, e.texel[1] - chart.y);
                let [s, t] = e.st;
                assert!(
                    patch.shape.contains(s, t),
                    "sample ({s}, {t}) off the triangle"
                );
                assert!((e.position - (origin + u * s + v * t)).length() < 1e-5);
                if b > a {
                    assert!(
                        !e.covers_surface(),
                        "texel ({a}, {b}) above the diagonal has area"
                    );
                } else {
                    covering += 1;
                    assert!(
                        e.covers_surface(),
                        "texel ({a}, {b}) on the triangle has no area"
                    );
                }
                if a == b {
                    assert!(
                        (s - t).abs() < 1e-6,
                        "diagonal texel ({a}, {b}) off the diagonal edge: {s}, {t}"
                    );
                }
            }
            assert_eq!(covering, chart.w * (chart.w + 1) / 2);
        }
    }

    fn check_areas(scene: &Scene) {
        let atlas = Atlas::build(scene).expect("fits");
        for (p, patch) in scene.patches.iter().enumerate() {
            let sum: f32 = atlas
                .elements_of(p as u32)
                .map(|e| atlas.elements[e].area)
                .sum();
            let area = patch.shape.area();
            assert!(
                (sum - area).abs() < 1e-4 * area,
                "{}: {sum} vs {area}",
                patch.name
            );
        }
    }

    #[test]
    fn boundary_samples_lie_on_patch_edges_and_corners_are_nudged_inward() {
        let scene = scene(TWO_BOXES);
        let atlas = Atlas::build(&scene).expect("fits");
        for e in &atlas.elements {
            let chart = atlas.charts[e.patch as usize];
            let (a, b) = (e.texel[0] - chart.x, e.texel[1] - chart.y);
            let edge_a = a == 0 || a == chart.w - 1;
            let edge_b = b == 0 || b == chart.h - 1;
            let [s, t] = e.st;
            if edge_a && edge_b {
                assert!(
                    s > 0.0 && s < 1.0 && t > 0.0 && t < 1.0,
                    "corner {:?} not inside: {s}, {t}",
                    e.texel
                );
                let cell = 1.0 / (chart.w - 1) as f32;
                assert!(
                    s.min(1.0 - s) <= CORNER_OFFSET * cell * 1.001,
                    "corner moved too far"
                );
            } else if edge_a {
                assert!(s == 0.0 || s == 1.0, "edge sample off the edge: {s}");
            } else if edge_b {
                assert!(t == 0.0 || t == 1.0, "edge sample off the edge: {t}");
            }
        }
    }

    #[test]
    fn texel_and_element_lookups_agree_both_ways() {
        let scene = scene(TWO_BOXES);
        let atlas = Atlas::build(&scene).expect("fits");
        for (i, e) in atlas.elements.iter().enumerate() {
            assert_eq!(atlas.element_at(e.texel[0], e.texel[1]), Some(i as u32));
            assert_eq!(atlas.patch_at(e.texel[0], e.texel[1]), Some(e.patch));
        }
        let covered = atlas
            .texel_element
            .iter()
            .filter(|&&e| e != NO_ELEMENT)
            .count();
        assert_eq!(
            covered,
            atlas.elements.len(),
            "every covered texel has exactly one element"
        );
        assert_eq!(atlas.element_at(atlas.width, 0), None);
    }

    #[test]
    fn charts_stay_inside_the_atlas_and_keep_their_padding() {
        let scene = scene(TWO_BOXES);
        let atlas = Atlas::build(&scene).expect("fits");
        for (i, a) in atlas.charts.iter().enumerate() {
            assert!(a.x + a.w <= atlas.width && a.y + a.h <= atlas.height);
            for b in &atlas.charts[..i] {
                let apart = a.x + a.w + PADDING <= b.x
                    || b.x + b.w + PADDING <= a.x
                    || a.y + a.h + PADDING <= b.y
                    || b.y + b.h + PADDING <= a.y;
                assert!(apart, "charts {a:?} and {b:?} overlap or touch");
            }
        }
        assert_eq!(atlas.height % HEIGHT_ALIGN, 0);
    }

    #[test]
    fn chart_size_follows_density_with_samples_on_both_ends() {
        // 2.1 m at 7.3 texels/m: ceil(15.33) = 16 cells, 17 samples.
        let scene = scene(TWO_BOXES);
        let atlas = Atlas::build(&scene).expect("fits");
        let x_face = scene
            .patches
            .iter()
            .position(|p| p.name == "room/+y")
            .expect("box face");
        let chart = atlas.charts[x_face];
        assert_eq!(
            (chart.w.max(chart.h), chart.w.min(chart.h)),
            (17, 7),
            "{chart:?}"
        );
        // The dynamic cube uses its own density: 0.5 m at 4/m = 2 cells.
        let cube = scene
            .patches
            .iter()
            .position(|p| p.name == "cube/+z")
            .expect("cube face");
        assert_eq!((atlas.charts[cube].w, atlas.charts[cube].h), (3, 3));
    }

    #[test]
    fn a_scene_too_large_for_its_atlas_names_the_problem() {
        let text = TWO_BOXES.replace(
            "\"texel_density\": 7.3 }",
            "\"texel_density\": 7.3, \"max_atlas_size\": 16 }",
        );
        let err = crate::load::parse_scene(&text, "test", Default::default())
            .expect_err("must overflow")
            .to_string();
        assert!(
            err.contains("atlas overflow") && err.contains("surface #0 \"room/"),
            "{err}"
        );
    }

    /// A floor of `n` x `n` square cells of side `c` cut along a diagonal
    /// (without cell `skip`), at 6.7 texels per metre.
    /// On Lightwire's own charts (`--charts parallelograms`): by default a
    /// mesh without lightmap UVs would get generated ones.
    fn mesh_floor(c: f32, n: u32, skip: Option<(u32, u32)>) -> Scene {
        let (mut positions, mut indices) = (Vec::new(), Vec::new());
        for j in 0..n {
            for i in 0..n {
                if Some((i, j)) == skip {
                    continue;
                }
                let k = positions.len() as u32;
                let (x, z) = (i as f32 * c, -(j as f32) * c);
                for (dx, dz) in [(0.0, 0.0), (c, 0.0), (c, -c), (0.0, -c)] {
                    positions.push(format!("[{}, 0, {}]", x + dx, z + dz));
                }
                indices.extend([k, k + 1, k + 2, k, k + 2, k + 3]);
            }
        }
        let text = format!(
            r#"{{
            "name": "t",
            "lightmap": {{ "texel_density": 6.7 }},
            "materials": [ {{ "name": "m", "albedo": [0.5, 0.5, 0.5], "emission": [1, 1, 1] }} ],
            "surfaces": [ {{ "name": "floor", "material": "m", "mesh": {{
                "positions": [{}], "indices": {indices:?} }} }} ]
        }}"#,
            positions.join(", ")
        );
        let options = crate::LoadOptions {
            density_scale: 1.0,
            charts: crate::Charts::Parallelograms,
        };
        Scene::parse_with(&text, "test", options).unwrap_or_else(|e| panic!("{e}"))
    }

    /// Cells shorter than a texel spacing: the merged chart is sampled at
    /// the density, as a hand-written quad of its size (4 texels along
    /// 0.4 m at 6.7 per metre), not a whole spacing per cell (5).
    #[test]
    fn a_merged_chart_of_cells_finer_than_a_texel_keeps_the_density() {
        let scene = mesh_floor(0.1, 4, None);
        assert_eq!(scene.patches.len(), 1);
        assert_eq!(scene.patches[0].cells, [4, 4]);
        let layout = plan(&scene).unwrap_or_else(|e| panic!("{e}"));
        let chart = layout.charts[0];
        assert_eq!((chart.w, chart.h), (4, 4));
    }

    /// An L-shaped floor of 0.37 m cells (a 3 x 3 grid without a corner
    /// cell), at a density that puts no whole number of texels in a cell:
    /// its triangles merge into parallelograms that meet along part of an
    /// edge (`scene/pairs.rs`), and every edge texel of one that lies on
    /// the other's edge is a seam texel shared with it, as the cells' own
    /// charts would have been.
    #[test]
    fn merged_charts_meeting_at_a_t_junction_share_their_edge_texels() {
        let scene = mesh_floor(0.37, 3, Some((2, 2)));
        assert!(
            (2..=3).contains(&scene.patches.len()),
            "{:?}",
            scene.patches.iter().map(|p| &p.name).collect::<Vec<_>>()
        );
        let cells: u32 = scene.patches.iter().map(|p| p.cells[0] * p.cells[1]).sum();
        assert_eq!(cells, 8, "every cell in a grid of equal cells");
        let atlas = Atlas::build(&scene).unwrap_or_else(|e| panic!("{e}"));
        let seam: std::collections::HashSet<u32> = atlas.seams.iter().flatten().copied().collect();
        let on_edge_of = |q: &Patch, x: Vec3| {
            let k = q.shape.corners();
            (0..k.len()).any(|i| {
                let (a, d) = (k[i], k[(i + 1) % k.len()] - k[i]);
                let t = ((x - a).dot(d) / d.length_squared()).clamp(0.0, 1.0);
                (a + d * t - x).length() < 1e-5
            })
        };
        let mut checked = 0;
        for (i, e) in atlas.elements.iter().enumerate() {
            let p = &scene.patches[e.patch as usize];
            let chart = atlas.charts[e.patch as usize];
            let [a, b] = [e.texel[0] - chart.x, e.texel[1] - chart.y];
            let (o, u, v) = p.shape.frame();
            let x =
                o + u * (a as f32 / (chart.w - 1) as f32) + v * (b as f32 / (chart.h - 1) as f32);
            let shared = scene
                .patches
                .iter()
                .enumerate()
                .any(|(k, q)| k != e.patch as usize && on_edge_of(q, x));
            if shared {
                checked += 1;
                assert!(
                    seam.contains(&(i as u32)),
                    "{} texel {a},{b} at {x} is on another chart's edge but no seam texel",
                    p.name
                );
            }
        }
        // The shared boundary is at least two cells long: eight spacings
        // or more at 2.48 texels per cell.
        assert!(checked >= 2 * 6, "{checked} texels on shared edges");
    }

    /// One mesh with lightmap UVs: a floor of two triangles whose UVs are
    /// affine over it (one parallelogram on the lightmap, `pairs.rs`) in
    /// the left half of its lightmap, and a wall of two whose UVs are not
    /// (a trapezoid: two triangles sharing their diagonal's texels) in the
    /// right, one corner on the lightmap's border; and a quad without.
    const LIGHTMAP_UVS: &str = r#"{
        "name": "t",
        "lightmap": { "texel_density": 9.3 },
        "materials": [ { "name": "m", "albedo": [0.5, 0.5, 0.5], "emission": [1, 1, 1] } ],
        "surfaces": [
            { "name": "room", "material": "m", "mesh": {
                "positions": [[0, 0, 0], [2.1, 0, 0], [2.1, 0, -1.3], [0, 0, -1.3],
                              [0, 0, -1.3], [2.1, 0, -1.3], [2.1, 1.7, -1.3], [0, 1.7, -1.3]],
                "indices": [0, 1, 2, 0, 2, 3, 4, 5, 6, 4, 6, 7],
                "lightmap_uvs": [[0.03, 0.9], [0.47, 0.9], [0.47, 0.1], [0.03, 0.1],
                                 [0.55, 0.9], [1.0, 0.9], [0.9, 0.2], [0.62, 0.2]] } },
            { "name": "wall", "material": "m", "quad": {
                "origin": [0, 0, 0], "u": [0, 0, -1.3], "v": [0, 1, 0] } }
        ]
    }"#;

    fn lightmap_uv_scene(charts: crate::Charts) -> Scene {
        let options = crate::LoadOptions {
            density_scale: 1.0,
            charts,
        };
        Scene::parse_with(LIGHTMAP_UVS, "test", options).unwrap_or_else(|e| panic!("{e}"))
    }

    #[test]
    fn triangles_on_their_lightmap_uvs_cover_their_texels() {
        use crate::Charts;
        // Other modes light the mesh on Lightwire's charts: the floor's and
        // the wall's two triangles become one quad each.
        let own = lightmap_uv_scene(Charts::Parallelograms);
        assert_eq!(own.patches.len(), 3);
        assert!(own.patches.iter().all(|p| p.lightmap.is_none()));
        assert_eq!(own.uv_meshes.len(), 1);

        // On the lightmap the floor is one parallelogram, the wall's UVs
        // (a trapezoid) keep its triangles apart.
        let scene = lightmap_uv_scene(Charts::LightmapUvs);
        assert_eq!(scene.patches.len(), 4, "the floor, two triangles, the quad");
        let on_uvs: Vec<bool> = scene
            .patches
            .iter()
            .filter(|p| p.lightmap.is_some())
            .map(|p| p.shape.is_triangle())
            .collect();
        assert_eq!(on_uvs, [false, true, true]);
        check_areas(&scene);
        let atlas = Atlas::build(&scene).expect("fits");
        let block = atlas.blocks[0].expect("the mesh has a block");
        let side = crate::atlas::uv::block_side(&scene, &scene.uv_meshes[0]);
        assert_eq!((block.w, block.h), (side, side));
        for (p, patch) in scene.patches.iter().enumerate() {
            let chart = atlas.charts[p];
            let Some(l) = patch.lightmap else {
                assert!(!atlas.on_lightmap_uvs(p as u32));
                // Lightwire's own chart stays clear of the block.
                assert!(
                    chart.x >= block.x + block.w + PADDING
                        || chart.x + chart.w + PADDING <= block.x
                        || chart.y >= block.y + block.h + PADDING
                        || chart.y + chart.h + PADDING <= block.y
                );
                continue;
            };
            check_chart_in_block(&scene, &atlas, p, l, block);
            check_elements_on_uvs(&scene, &atlas, p);
        }
        // The wall's diagonal texels are shared by its two triangles.
        let shared = atlas
            .seams
            .iter()
            .filter(|g| {
                g.iter().any(|&i| {
                    atlas.elements[i as usize].patch != atlas.elements[g[0] as usize].patch
                })
            })
            .count();
        assert!(
            shared >= 10,
            "{shared} shared texels along the wall's diagonal"
        );
        // The image shows each texel's owner.
        let values: Vec<Vec3> = (0..atlas.elements.len())
            .map(|i| Vec3::splat(i as f32))
            .collect();
        let image = atlas.to_image(&values);
        for (t, &owner) in atlas.texel_element.iter().enumerate() {
            if owner != NO_ELEMENT {
                assert_eq!(image[t][0], owner as f32);
            }
        }
        check_block_gutters(&atlas, &image, block);
    }

    /// Checks that patch `p`, lit on its mesh's lightmap at `l`, has its
    /// chart inside the mesh's `block`, and its corners at their UVs.
    fn check_chart_in_block(
        scene: &Scene,
        atlas: &Atlas,
        p: usize,
        l: crate::PatchLightmap,
        block: Chart,
    ) {
        let side = block.w;
        let patch = &scene.patches[p];
        let chart = atlas.charts[p];
        assert!(atlas.on_lightmap_uvs(p as u32));
        assert!(chart.x >= block.x && chart.x + chart.w <= block.x + block.w);
        assert!(chart.y >= block.y && chart.y + chart.h <= block.y + block.h);
        // The chart map puts the patch's corners at their UVs (a
        // parallelogram's fourth where the mesh has it).
        let triangle = patch.shape.is_triangle();
        let map = atlas.chart_map(p as u32);
        let corner = |st: Vec2| {
            map.to_chart(st) + Vec2::new(chart.x as f32 + 0.5, chart.y as f32 + 0.5)
                - Vec2::new(block.x as f32, block.y as f32)
        };
        for (st, uv) in [Vec2::ZERO, Vec2::X, Vec2::ONE].into_iter().zip(l.uv) {
            assert!((corner(st) - uv * side as f32).length() < 1e-3);
        }
        if !triangle {
            let fourth = corner(Vec2::Y);
            assert!(
                scene.uv_meshes[0].uvs[..2]
                    .iter()
                    .flatten()
                    .any(|uv| (fourth - *uv * side as f32).length() < 1e-3),
                "the floor's fourth corner at {fourth} is one of its UVs"
            );
        }
    }

    /// Checks the elements of patch `p`, lit on its mesh's lightmap: their
    /// samples lie on the patch, a texel's owner covers most of it, texels
    /// several triangles cover are one seam group, and a point inside the
    /// patch reads an element whose texel holds it.
    fn check_elements_on_uvs(scene: &Scene, atlas: &Atlas, p: usize) {
        let patch = &scene.patches[p];
        let chart = atlas.charts[p];
        let triangle = patch.shape.is_triangle();
        let map = atlas.chart_map(p as u32);
        let (origin, u, v) = patch.shape.frame();
        for i in atlas.elements_of(p as u32) {
            let e = &atlas.elements[i];
            let [s, t] = e.st;
            let top = if triangle { s } else { 1.0 };
            assert!(
                (-1e-5..=1.0 + 1e-5).contains(&s) && (-1e-5..=top + 1e-5).contains(&t),
                "{}: sample ({s}, {t}) off the patch",
                patch.name
            );
            assert!((e.position - (origin + u * s + v * t)).length() < 1e-5);
            // A texel the triangle covers has an owner that covers at
            // least as much of it, and shares a seam group with the
            // other triangles covering it.
            if e.covers_surface() {
                let owner = atlas.element_at(e.texel[0], e.texel[1]).expect("owned");
                assert!(atlas.elements[owner as usize].area >= e.area);
                let sharing = atlas
                    .elements
                    .iter()
                    .filter(|o| o.texel == e.texel && o.covers_surface())
                    .count();
                if sharing > 1 {
                    assert!(
                        atlas
                            .seams
                            .iter()
                            .any(|g| g.contains(&(i as u32)) && g.len() == sharing),
                        "a shared texel is one seam group"
                    );
                }
            }
        }
        // A point inside the patch reads an element of it whose texel
        // holds the point and covers surface.
        for (s, t) in [(0.5, 0.25), (0.9, 0.1), (0.7, 0.6), (0.34, 0.3)] {
            let i = atlas
                .element_of(p as u32, triangle, Vec2::new(s, t))
                .expect("inside");
            let e = &atlas.elements[i];
            assert_eq!(e.patch, p as u32);
            assert!(e.covers_surface(), "{}: ({s}, {t})", patch.name);
            let xy = map.to_chart(Vec2::new(s, t));
            let texel = Vec2::new((e.texel[0] - chart.x) as f32, (e.texel[1] - chart.y) as f32);
            assert!((xy - texel).abs().max_element() <= 0.5 + 1e-4);
        }
    }

    /// Checks the gutter texels of the published `image` in and around a
    /// mesh's `block`.
    fn check_block_gutters(atlas: &Atlas, image: &[[f32; 3]], block: Chart) {
        // Texels of the block and of the ring around it beside an island
        // take their held neighbours' mean; those farther out stay black.
        // The wall's corner at u = 1 reaches the block's border: the ring
        // beyond it is its gutter.
        let (mut gutter, mut empty, mut ring) = (0, 0, 0);
        let (lo, hi) = (block.x - BLOCK_RING, block.x + block.w + BLOCK_RING);
        let (top, bottom) = (block.y - BLOCK_RING, block.y + block.h + BLOCK_RING);
        for y in top..bottom {
            for x in lo..hi {
                let t = (y * atlas.width + x) as usize;
                if atlas.texel_element[t] != NO_ELEMENT {
                    continue;
                }
                let held: Vec<f32> = (-1i64..=1)
                    .flat_map(|dy| (-1i64..=1).map(move |dx| (dx, dy)))
                    .filter_map(|(dx, dy)| {
                        let (nx, ny) = (i64::from(x) + dx, i64::from(y) + dy);
                        let inside = nx >= i64::from(lo)
                            && ny >= i64::from(top)
                            && nx < i64::from(hi)
                            && ny < i64::from(bottom);
                        let o = atlas.element_at(nx as u32, ny as u32).filter(|_| inside)?;
                        Some(o as f32)
                    })
                    .collect();
                if held.is_empty() {
                    assert_eq!(image[t], [0.0; 3]);
                    empty += 1;
                } else {
                    let mean = held.iter().sum::<f32>() / held.len() as f32;
                    assert!((image[t][0] - mean).abs() <= 1e-3 * mean.max(1.0));
                    gutter += 1;
                    let in_block = x >= block.x
                        && y >= block.y
                        && x < block.x + block.w
                        && y < block.y + block.h;
                    ring += usize::from(!in_block);
                }
            }
        }
        assert!(
            gutter > 20 && empty > 20 && ring > 0,
            "{gutter} gutter texels ({ring} in the ring), {empty} empty"
        );
    }
}
