//! Elements and patches placed in the world at the objects' poses.
//!
//! Elements are uploaded once in their object's space ([`LocalElement`]);
//! `place_elements` (progressive.wgsl) puts them in the world at the current
//! poses after every move. The CPU keeps the same placement for what it
//! needs itself: the patches as parallelograms ([`WorldPatch`], to cut
//! shooters), element areas at the objects' scales, and the scene's extent
//! (for depth ranges and surface offsets).

use bytemuck::{Pod, Zeroable};
use glam::Vec3;

use crate::validity::Validity;
use lightwire_scene::atlas::{Atlas, ChartMap};
use lightwire_scene::{PatchShape, Pose, Scene};

use super::buffers::v4;

/// Receiving points are moved this fraction of the scene's extent off
/// edges and off their surface (like the reference solver's offset).
pub(super) const SURFACE_OFFSET: f32 = 1e-5;

/// One element in its object's space (`LocalElement` in elements.wgsl);
/// `place_elements` derives the world-space `Element` from it and the pose.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(super) struct LocalElement {
    pub(super) position: [f32; 4],
    pub(super) normal: [f32; 4],
    pub(super) lookup: [f32; 4],
    pub(super) albedo: [f32; 4],
    pub(super) nudge: [f32; 4],
}
const _: () = assert!(std::mem::size_of::<LocalElement>() == 80);

/// Size of a world-space element (`Element` in elements.wgsl: position
/// and area, normal and patch, lookup point and object, albedo).
pub(super) const ELEMENT_BYTES: u64 = 64;

/// Byte offset of `albedo.w`, the invalid flag, in a [`LocalElement`] and
/// in a world-space `Element` (both put `albedo` fourth).
pub(super) const INVALID_FLAG_OFFSET: u64 = 60;

/// `albedo.w` of an element: 1 when it is invalid (`is_invalid` in
/// elements.wgsl: it receives nothing).
pub(super) fn invalid_flag(invalid: bool) -> f32 {
    if invalid { 1.0 } else { 0.0 }
}

/// One patch's elements as the shaders find them (`PatchRange` in
/// common.wgsl): first element, element count, chart size, and whether
/// the patch is a triangle: [`TRIANGLE`] (the half `t <= s` of its chart,
/// whose texels above the diagonal stand for no surface) or
/// [`TRIANGLE_ON_LIGHTMAP`] (lit on its mesh's own lightmap UVs,
/// `atlas/uv.rs`: its hemicube vertices carry chart coordinates rather than
/// patch parameters, and its frame, which the receiving shaders cannot
/// rebuild from its corner texels, is its [`PatchFrame`]); a
/// parallelogram on its mesh's lightmap is [`QUAD_ON_LIGHTMAP`], the same
/// but whole. Kept at 20 bytes: every hemicube vertex reads its patch's.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable, Debug, PartialEq)]
pub(super) struct PatchRange {
    pub(super) first: u32,
    pub(super) count: u32,
    pub(super) w: u32,
    pub(super) h: u32,
    pub(super) triangle: u32,
}
const _: () = assert!(std::mem::size_of::<PatchRange>() == 20);

/// A patch's frame in object space, `origin`, `u`, `v` (`PatchFrame` in
/// receive.wgsl): read by the occlusion test for the triangles on their
/// mesh's own lightmap UVs only; zero for every other patch.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable, Debug, PartialEq)]
pub(super) struct PatchFrame {
    pub(super) origin: [f32; 4],
    pub(super) u: [f32; 4],
    pub(super) v: [f32; 4],
}
const _: () = assert!(std::mem::size_of::<PatchFrame>() == 48);

/// `PatchRange::triangle` of a triangle on a chart of Lightwire's own.
pub(super) const TRIANGLE: u32 = 1;
/// `PatchRange::triangle` of a triangle on its mesh's lightmap UVs.
pub(super) const TRIANGLE_ON_LIGHTMAP: u32 = 2;
/// `PatchRange::triangle` of a parallelogram on its mesh's lightmap UVs.
pub(super) const QUAD_ON_LIGHTMAP: u32 = 3;

/// A patch placed in the world, as the CPU needs it to place shooters:
/// the frame `origin + s u + t v` of its shape (a quad covers `s, t ∈
/// [0, 1]`, a triangle the half `t <= s`).
#[derive(Debug, Clone, Copy)]
pub(super) struct WorldPatch {
    pub(super) origin: Vec3,
    pub(super) u: Vec3,
    pub(super) v: Vec3,
    pub(super) normal: Vec3,
    pub(super) first: u32,
    pub(super) w: u32,
    pub(super) h: u32,
    pub(super) triangle: bool,
    /// Its chart's map from patch parameters to texel coordinates when it
    /// is lit on its mesh's own lightmap UVs (`atlas/uv.rs`).
    pub(super) lightmap: Option<ChartMap>,
}

impl WorldPatch {
    /// The point an element at patch parameters `st` receives at: its
    /// sample moved `offset` towards the patch's centroid and `offset` off
    /// the surface, as `place_elements` (progressive.wgsl) moves it.
    pub(super) fn receiving_point(&self, st: [f32; 2], offset: f32) -> Vec3 {
        let [s, t] = st;
        let sample = self.origin + self.u * s + self.v * t;
        let inward = (self.centre() - sample).normalize_or_zero();
        sample + (inward + self.normal) * offset
    }

    /// The centroid: `(1/2, 1/2)` on a quad, `(2/3, 1/3)` on a triangle.
    pub(super) fn centre(&self) -> Vec3 {
        let [s, t] = centre_param(self.triangle);
        self.origin + self.u * s + self.v * t
    }

    /// What a hemicube vertex at patch parameters `st` carries for the
    /// texel lookup (`element_at` in common.wgsl): `st` itself, or on a
    /// triangle on its mesh's lightmap its chart coordinates (an affine
    /// function of `st`, which interpolation across the triangle keeps).
    pub(super) fn vertex_st(&self, st: [f32; 2]) -> [f32; 2] {
        match self.lightmap {
            Some(map) => map.to_chart(glam::Vec2::from(st)).to_array(),
            None => st,
        }
    }

    /// The corners (four, or a triangle's three).
    pub(super) fn corners(&self) -> Vec<Vec3> {
        let (o, u, v) = (self.origin, self.u, self.v);
        if self.triangle {
            vec![o, o + u, o + u + v]
        } else {
            vec![o, o + u, o + u + v, o + v]
        }
    }
}

/// Patch parameters of the centroid of a quad or a triangle
/// (`PatchShape::centre_param`).
fn centre_param(triangle: bool) -> [f32; 2] {
    if triangle {
        [2.0 / 3.0, 1.0 / 3.0]
    } else {
        [0.5, 0.5]
    }
}

/// The scene's patches in their objects' space and where each one's
/// elements sit in the atlas: what placing them at poses needs.
#[derive(Debug, Clone)]
pub(super) struct PatchTable {
    pub(super) shapes: Vec<PatchShape>,
    /// The object of every patch.
    pub(super) objects: Vec<u32>,
    /// First element and chart size of every patch.
    layout: Vec<[u32; 3]>,
    /// One past the last element of every patch.
    ends: Vec<u32>,
    /// Chart maps of the triangles on their meshes' own lightmap UVs.
    maps: Vec<Option<ChartMap>>,
}

impl PatchTable {
    pub(super) fn new(scene: &Scene, atlas: &Atlas) -> Self {
        Self {
            shapes: scene.patches.iter().map(|p| p.shape).collect(),
            objects: scene.patches.iter().map(|p| p.object).collect(),
            layout: atlas
                .charts
                .iter()
                .enumerate()
                .map(|(p, c)| [atlas.patch_elements[p], c.w, c.h])
                .collect(),
            ends: (0..atlas.charts.len())
                .map(|p| atlas.patch_elements[p + 1])
                .collect(),
            maps: atlas.lightmap_maps.clone(),
        }
    }

    /// Chart maps of the triangles on their meshes' own lightmap UVs
    /// (`Atlas::lightmap_maps`).
    pub(super) fn maps(&self) -> &[Option<ChartMap>] {
        &self.maps
    }

    /// Every patch placed at its object's pose.
    pub(super) fn place(&self, poses: &[Pose]) -> Vec<WorldPatch> {
        place_patches(&self.shapes, &self.objects, &self.layout, &self.maps, poses)
    }

    /// First element, element count, chart size and shape of every patch
    /// (`PatchRange` in common.wgsl).
    pub(super) fn ranges(&self) -> Vec<PatchRange> {
        self.layout
            .iter()
            .zip(&self.ends)
            .zip(&self.shapes)
            .zip(&self.maps)
            .map(|(((&[first, w, h], end), shape), map)| PatchRange {
                first,
                count: end - first,
                w,
                h,
                triangle: match (shape.is_triangle(), map.is_some()) {
                    (false, false) => 0,
                    (true, false) => TRIANGLE,
                    (true, true) => TRIANGLE_ON_LIGHTMAP,
                    (false, true) => QUAD_ON_LIGHTMAP,
                },
            })
            .collect()
    }

    /// Every patch's [`PatchFrame`] (zero where the shaders do not read
    /// it), at least one.
    pub(super) fn frames(&self) -> Vec<PatchFrame> {
        let mut frames: Vec<PatchFrame> = self
            .shapes
            .iter()
            .zip(&self.maps)
            .map(|(shape, map)| match map {
                Some(_) => {
                    let (o, u, v) = shape.frame();
                    PatchFrame {
                        origin: v4(o, 1.0),
                        u: v4(u, 0.0),
                        v: v4(v, 0.0),
                    }
                }
                None => PatchFrame::zeroed(),
            })
            .collect();
        if frames.is_empty() {
            frames.push(PatchFrame::zeroed());
        }
        frames
    }
}

/// Every patch placed at its object's pose; `layout` gives each patch's
/// first element and chart size.
fn place_patches(
    shapes: &[PatchShape],
    objects: &[u32],
    layout: &[[u32; 3]],
    maps: &[Option<ChartMap>],
    poses: &[Pose],
) -> Vec<WorldPatch> {
    shapes
        .iter()
        .enumerate()
        .map(|(p, shape)| {
            let (origin, u, v) = shape.transformed(&poses[objects[p] as usize]).frame();
            let [first, w, h] = layout[p];
            WorldPatch {
                origin,
                u,
                v,
                normal: u.cross(v).normalize(),
                first,
                w,
                h,
                triangle: shape.is_triangle(),
                lightmap: maps.get(p).copied().flatten(),
            }
        })
        .collect()
}

/// The length of the diagonal of the box around `patches` (at least a
/// micrometre), the scale of depth ranges and offsets.
pub(super) fn extent(patches: &[WorldPatch]) -> f32 {
    let mut lo = Vec3::splat(f32::INFINITY);
    let mut hi = Vec3::splat(f32::NEG_INFINITY);
    for wp in patches {
        for corner in wp.corners() {
            lo = lo.min(corner);
            hi = hi.max(corner);
        }
    }
    (hi - lo).length().max(1e-6)
}

/// World areas of elements: scale-1 areas times their object's scale².
pub(super) fn world_areas(local: &[f32], objects: &[u32], poses: &[Pose]) -> Vec<f32> {
    local
        .iter()
        .zip(objects)
        .map(|(a, o)| {
            let s = poses[*o as usize].scale;
            a * s * s
        })
        .collect()
}

/// Emitted power `Σ A_e E_e` (W, channels summed) of the elements of
/// `atlas` at the world areas `areas`.
pub(super) fn emitted_power(atlas: &Atlas, areas: &[f32]) -> f64 {
    atlas
        .elements
        .iter()
        .zip(areas)
        .map(|(e, a)| f64::from(*a) * f64::from(e.emission.element_sum()))
        .sum()
}

/// The object-to-world matrix of a pose.
pub(super) fn pose_matrix(pose: &Pose) -> [[f32; 4]; 4] {
    glam::Mat4::from_scale_rotation_translation(
        Vec3::splat(pose.scale),
        pose.rotation,
        pose.translation,
    )
    .to_cols_array_2d()
}

/// The object-to-world matrix of every object at `poses`, zero for an
/// absent one (`absent[o]`; present where `absent` is shorter): the
/// hemicube shaders' `poses` for one pose set, on which an absent object's
/// triangles collapse to a point.
pub(super) fn pose_matrices(poses: &[Pose], absent: &[bool]) -> Vec<[[f32; 4]; 4]> {
    poses
        .iter()
        .enumerate()
        .map(|(o, p)| {
            if absent.get(o).copied().unwrap_or(false) {
                [[0.0; 4]; 4]
            } else {
                pose_matrix(p)
            }
        })
        .collect()
}

/// Every atlas element in its object's space, with the invalid flag of
/// `validity`; `extent` scales the distance receiving points are moved off
/// edges and surfaces.
pub(super) fn local_elements(
    shapes: &[PatchShape],
    atlas: &Atlas,
    validity: &Validity,
    extent: f32,
) -> Vec<LocalElement> {
    atlas
        .elements
        .iter()
        .enumerate()
        .map(|(i, e)| {
            let p = e.patch as usize;
            let shape = &shapes[p];
            let (origin, u, v) = shape.frame();
            let chart = atlas.charts[p];
            let normal = u.cross(v).normalize();
            let [s, t] = e.st;
            let sample = origin + u * s + v * t;
            let [cs, ct] = shape.centre_param();
            let centre = origin + u * cs + v * ct;
            // Edge samples look up visibility a quarter cell inside their
            // own patch, so the item buffer shows their patch, not the
            // neighbour sharing the edge; on a triangle that includes its
            // diagonal edge `t = s` (the neighbour across it is the other
            // half of a quad, or another triangle of a mesh).
            // (A quarter texel in patch parameters: on Lightwire's own
            // charts `0.25 / (w - 1)`, on a mesh's lightmap by its map.)
            let (qs, qt) = match atlas.lightmap_maps[p] {
                Some(map) => (
                    0.25 / map.ds.length().max(1.0),
                    0.25 / map.dt.length().max(1.0),
                ),
                None => {
                    let quarter = |cells: u32| 0.25 / (cells.max(2) - 1) as f32;
                    (quarter(chart.w), quarter(chart.h))
                }
            };
            let (ls, lt) = if shape.is_triangle() {
                let ls = s.clamp(qs + qt, 1.0 - qs);
                (ls, t.clamp(qt, (ls - qs).max(qt)))
            } else {
                (s.clamp(qs, 1.0 - qs), t.clamp(qt, 1.0 - qt))
            };
            let lookup = origin + u * ls + v * lt;
            LocalElement {
                position: v4(sample, e.area),
                normal: v4(normal, f32::from_bits(e.patch)),
                lookup: v4(lookup, f32::from_bits(e.object)),
                albedo: v4(e.albedo, invalid_flag(validity.is_invalid(i))),
                // Receiving points are moved a hair towards the patch's
                // centroid and off the surface (like the reference solver's offset).
                nudge: v4(
                    (centre - sample).normalize_or_zero(),
                    extent * SURFACE_OFFSET,
                ),
            }
        })
        .collect()
}
