//! The shapes a scene file's surface may take, checked and expanded into
//! patch shapes: a quad (one patch), a box (six) or a mesh (one per
//! triangle, with its lightmap UVs when it gives them).

use glam::{Vec2, Vec3};

use super::{Checker, TriangleUvs};
use crate::PatchShape;
use crate::file::{BoxJson, Facing, MeshJson, QuadJson, SurfaceJson};

/// A surface's patch shapes, each with its patch's name, from the one
/// shape it gives, and a mesh's lightmap UVs. Reports a surface that
/// gives no shape or more than one.
pub(super) fn surface_shapes(
    c: &mut Checker,
    loc: &str,
    s: &SurfaceJson,
) -> (Vec<(String, PatchShape)>, Option<TriangleUvs>) {
    let given = [
        s.quad.is_some().then_some("quad"),
        s.box_.is_some().then_some("box"),
        s.mesh.is_some().then_some("mesh"),
    ];
    let given: Vec<&str> = given.into_iter().flatten().collect();
    match (&s.quad, &s.box_, &s.mesh) {
        _ if given.len() > 1 => {
            c.report(
                loc,
                format!(
                    "has {}{}; give exactly one shape",
                    if given.len() == 2 { "both " } else { "" },
                    given
                        .iter()
                        .map(|g| format!("\"{g}\""))
                        .collect::<Vec<_>>()
                        .join(" and ")
                ),
            );
            (Vec::new(), None)
        }
        (Some(q), _, _) => (
            quad(c, loc, q)
                .map(|q| vec![(s.name.clone(), q)])
                .unwrap_or_default(),
            None,
        ),
        (_, Some(b), _) => (boxed(c, loc, &s.name, b), None),
        (_, _, Some(m)) => mesh(c, loc, &s.name, m),
        (None, None, None) => {
            c.report(loc, "has no shape; give \"quad\", \"box\" or \"mesh\"");
            (Vec::new(), None)
        }
    }
}

/// Relative tolerance for planarity and parallelogram checks.
const SHAPE_TOLERANCE: f32 = 1e-4;

fn quad(c: &mut Checker, loc: &str, q: &QuadJson) -> Option<PatchShape> {
    let (origin, u, v) = match (&q.origin, &q.u, &q.v, &q.corners) {
        (Some(o), Some(u), Some(v), None) => {
            let o = c.vec3(loc, "quad.origin", o);
            let u = c.vec3(loc, "quad.u", u);
            let v = c.vec3(loc, "quad.v", v);
            (o?, u?, v?)
        }
        (None, None, None, Some(corners)) => {
            let mut p = [Vec3::ZERO; 4];
            let mut ok = true;
            for (k, corner) in corners.iter().enumerate() {
                match c.vec3(loc, &format!("quad.corners[{k}]"), corner) {
                    Some(x) => p[k] = x,
                    None => ok = false,
                }
            }
            if !ok {
                return None;
            }
            let (u, v) = (p[1] - p[0], p[3] - p[0]);
            let n = u.cross(v);
            let scale = u.length().max(v.length());
            if n.length() > 0.0 {
                let deviation = p[2] - (p[0] + u + v);
                let off_plane = deviation.dot(n.normalize()).abs();
                if off_plane > SHAPE_TOLERANCE * scale {
                    c.report(loc, format!("quad is not planar: corners[2] lies {off_plane} m off the plane of the other three corners"));
                    return None;
                }
                if deviation.length() > SHAPE_TOLERANCE * scale {
                    c.report(
                        loc,
                        format!(
                            "quad is not a parallelogram: corners[2] is {} m away from corners[1] + corners[3] - corners[0]",
                            deviation.length()
                        ),
                    );
                    return None;
                }
            }
            (p[0], u, v)
        }
        _ => {
            c.report(
                loc,
                "quad needs either \"origin\", \"u\" and \"v\", or \"corners\" (four points)",
            );
            return None;
        }
    };
    let area = u.cross(v).length();
    let scale = u.length_squared().max(v.length_squared());
    if !(area > 1e-10 && area > 1e-6 * scale) {
        c.report(
            loc,
            format!("quad has zero area (|u × v| = {area}): its edges are degenerate or parallel"),
        );
        return None;
    }
    Some(PatchShape::Quad { origin, u, v })
}

fn boxed(c: &mut Checker, loc: &str, name: &str, b: &BoxJson) -> Vec<(String, PatchShape)> {
    let center = c.vec3(loc, "box.center", &b.center);
    let size = c.vec3(loc, "box.size", &b.size);
    let rotation = c.rotation(loc, "box.rotation", &b.rotation);
    let (Some(center), Some(size), Some(rotation)) = (center, size, rotation) else {
        return Vec::new();
    };
    for (k, s) in size.to_array().iter().enumerate() {
        if *s <= 0.0 {
            c.report(loc, format!("box.size[{k}] = {s} must be greater than 0"));
            return Vec::new();
        }
    }
    let ex = rotation * Vec3::X * size.x;
    let ey = rotation * Vec3::Y * size.y;
    let ez = rotation * Vec3::Z * size.z;
    let min = center - 0.5 * (ex + ey + ez);
    // (suffix, origin, u, v) with u × v pointing out of the box.
    let faces = [
        ("+x", min + ex, ey, ez),
        ("-x", min, ez, ey),
        ("+y", min + ey, ez, ex),
        ("-y", min, ex, ez),
        ("+z", min + ez, ex, ey),
        ("-z", min, ey, ex),
    ];
    faces
        .into_iter()
        .map(|(suffix, origin, u, v)| {
            let (u, v) = match b.facing {
                Facing::Out => (u, v),
                Facing::In => (v, u),
            };
            (
                format!("{name}/{suffix}"),
                PatchShape::Quad { origin, u, v },
            )
        })
        .collect()
}

/// Triangles listed per mesh before the rest are only counted.
const MAX_LISTED_TRIANGLES: usize = 8;

/// A mesh's triangles, each a patch named `name/k` (k the triangle's index
/// in the mesh). Reports out-of-range indices, an index count that is not a
/// multiple of three, non-finite positions and degenerate triangles (twice
/// the area at most [`crate::gltf::DEGENERATE_RATIO`] times the longest edge
/// squared: the corners lie on a line to within f32 precision, the glTF
/// importer's rule).
///
/// With `lightmap_uvs` (one per position, as glTF's `TEXCOORD_1`), also
/// each triangle's UVs in its patch's corner order; reports UVs outside
/// [0, 1], triangles of zero UV area and overlapping ones, as the glTF
/// importer does.
fn mesh(
    c: &mut Checker,
    loc: &str,
    name: &str,
    m: &MeshJson,
) -> (Vec<(String, PatchShape)>, Option<TriangleUvs>) {
    let (shapes, kept) = mesh_shapes(c, loc, name, m);
    let Some(uvs) = &m.lightmap_uvs else {
        return (shapes, None);
    };
    if uvs.len() != m.positions.len() {
        c.report(
            loc,
            format!(
                "mesh.lightmap_uvs has {} entries for {} positions: give one [u, v] per position",
                uvs.len(),
                m.positions.len()
            ),
        );
        return (shapes, None);
    }
    let (lo, hi) = (
        -crate::gltf::UV_RANGE_SLACK,
        1.0 + crate::gltf::UV_RANGE_SLACK,
    );
    let outside: Vec<usize> = (0..uvs.len())
        .filter(|&k| !uvs[k].iter().all(|x| (lo..=hi).contains(x)))
        .collect();
    for &k in outside.iter().take(MAX_LISTED_TRIANGLES) {
        c.report(
            loc,
            format!(
                "mesh.lightmap_uvs[{k}] is {:?}: lightmap UVs must lie in [0, 1]",
                uvs[k]
            ),
        );
    }
    if shapes.is_empty() || !outside.is_empty() {
        return (shapes, None);
    }
    let sequential: Vec<u32> = (0..m.positions.len() as u32).collect();
    let indices = m.indices.as_deref().unwrap_or(&sequential);
    let positions: Vec<Vec3> = m
        .positions
        .iter()
        .map(|p| glam::DVec3::from_array(*p).as_vec3())
        .collect();
    // The kept triangles' UVs; `kept[i]` is the i-th one's number.
    let tris: Vec<[Vec2; 3]> = kept
        .iter()
        .map(|&k| {
            let t = &indices[3 * k..3 * k + 3];
            let [a, b, d] = [0, 1, 2].map(|j| positions[t[j] as usize]);
            let order = PatchShape::triangle_order(a, b, d);
            order.map(|j| Vec2::from_array(uvs[t[j] as usize]))
        })
        .collect();
    let zero: Vec<usize> = (0..tris.len())
        .filter(|&k| crate::uv::uv_area(&tris[k]).abs() * 2.0 <= 1e-12)
        .collect();
    for &k in zero.iter().take(MAX_LISTED_TRIANGLES) {
        c.report(
            loc,
            format!(
                "mesh triangle {} has zero area in mesh.lightmap_uvs ({:?}): it would get no lightmap texels",
                kept[k], tris[k]
            ),
        );
    }
    match crate::gltf::find_uv_overlaps(&tris, MAX_LISTED_TRIANGLES) {
        Ok(overlaps) => {
            for o in &overlaps {
                c.report(
                    loc,
                    format!(
                        "mesh triangle {} overlaps triangle {} in mesh.lightmap_uvs by {:.3e} (UV units², {:.1}% of the smaller): lightmap UVs must not overlap",
                        kept[o.a],
                        kept[o.b],
                        o.area,
                        100.0 * o.fraction
                    ),
                );
            }
            if !overlaps.is_empty() {
                return (shapes, None);
            }
        }
        Err(work) => {
            c.report(
                loc,
                format!(
                    "mesh.lightmap_uvs of its {} triangles cannot be checked for overlaps: the layout needs {work} grid entries or candidate pairs, over the limit",
                    tris.len()
                ),
            );
            return (shapes, None);
        }
    }
    if !zero.is_empty() || tris.len() != shapes.len() {
        return (shapes, None);
    }
    (shapes, Some(tris))
}

/// A mesh's triangles as patch shapes, and the number of each in the mesh:
/// degenerate triangles are dropped with a warning. Empty when positions or
/// indices are invalid (reported).
fn mesh_shapes(
    c: &mut Checker,
    loc: &str,
    name: &str,
    m: &MeshJson,
) -> (Vec<(String, PatchShape)>, Vec<usize>) {
    let mut positions = Vec::with_capacity(m.positions.len());
    let mut ok = true;
    for (k, p) in m.positions.iter().enumerate() {
        match c.vec3(loc, &format!("mesh.positions[{k}]"), p) {
            Some(x) => positions.push(x),
            None => ok = false,
        }
    }
    let sequential: Vec<u32>;
    let indices: &[u32] = match &m.indices {
        Some(indices) => indices,
        None => {
            sequential = (0..m.positions.len() as u32).collect();
            &sequential
        }
    };
    let what = if m.indices.is_some() {
        "mesh.indices"
    } else {
        "mesh.positions (no indices)"
    };
    if indices.is_empty() {
        c.report(loc, format!("{what} holds no triangle"));
        return (Vec::new(), Vec::new());
    }
    if !indices.len().is_multiple_of(3) {
        c.report(
            loc,
            format!(
                "{what} has {} entries, not a multiple of 3 (three per triangle)",
                indices.len()
            ),
        );
        ok = false;
    }
    if let Some((k, i)) = indices
        .iter()
        .enumerate()
        .find(|(_, i)| **i as usize >= m.positions.len())
    {
        c.report(
            loc,
            format!(
                "mesh.indices[{k}] = {i} is out of range: there are {} positions",
                m.positions.len()
            ),
        );
        ok = false;
    }
    if !ok {
        return (Vec::new(), Vec::new());
    }
    let mut degenerate = Vec::new();
    let mut shapes = Vec::with_capacity(indices.len() / 3);
    let mut kept = Vec::with_capacity(indices.len() / 3);
    for (k, t) in indices.chunks_exact(3).enumerate() {
        let [a, b, d] = [0, 1, 2].map(|j| positions[t[j] as usize]);
        if crate::gltf::is_degenerate(a, b, d) {
            degenerate.push(k);
            continue;
        }
        shapes.push((format!("{name}/{k}"), PatchShape::triangle(a, b, d)));
        kept.push(k);
    }
    if !degenerate.is_empty() {
        let listed: Vec<String> = degenerate
            .iter()
            .take(MAX_LISTED_TRIANGLES)
            .map(|k| format!("#{k} (indices {:?})", &indices[3 * k..3 * k + 3]))
            .collect();
        let more = degenerate.len().saturating_sub(MAX_LISTED_TRIANGLES);
        c.warn(
            loc,
            format!(
                "dropped {} of {} mesh triangles that no lightmap can hold: zero-area or sliver (corners on a line): {}{}",
                degenerate.len(),
                indices.len() / 3,
                listed.join(", "),
                if more > 0 {
                    format!(" and {more} more")
                } else {
                    String::new()
                }
            ),
        );
    }
    if shapes.is_empty() {
        c.report(loc, "mesh has no triangle of non-zero area");
    }
    (shapes, kept)
}
