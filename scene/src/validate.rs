//! Semantic checks that turn a [`SceneFile`] into a [`Scene`].
//!
//! Every check records a [`SceneIssue`] naming the entry (kind, index and
//! name) and the problem, and validation carries on, so that one run reports
//! all problems of a file instead of the first.

use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;

use glam::{Quat, Vec2, Vec3};

use super::file::{
    BoxJson, Facing, ImportJson, MeshJson, PoseJson, QuadJson, SceneFile, SolverJson, Vec3Json,
};
use super::gltf::{ImportOptions, ImportedScene};
use super::texture::AlbedoMap;
use super::{
    Charts, LoadOptions, Material, Object, Patch, PatchLightmap, PatchShape, Pose, Scene,
    SceneIssue, SolverHints, UvMesh,
};

/// Largest atlas edge a scene may ask for.
pub const MAX_ATLAS_LIMIT: u32 = 16384;
/// Smallest atlas edge a scene may ask for.
pub const MIN_ATLAS_LIMIT: u32 = 16;
/// Name reserved for the static world.
pub const STATIC_NAME: &str = "static";

struct Checker {
    issues: Vec<SceneIssue>,
}

impl Checker {
    fn report(&mut self, location: &str, problem: impl Into<String>) {
        self.issues.push(SceneIssue {
            location: location.to_string(),
            problem: problem.into(),
        });
    }

    /// Converts to f32, reporting NaN, infinities and values that overflow
    /// single precision.
    fn finite(&mut self, location: &str, what: &str, x: f64) -> Option<f32> {
        let y = x as f32;
        if x.is_finite() && y.is_finite() {
            Some(y)
        } else {
            self.report(
                location,
                format!("{what} = {x:e} is not a finite number (single precision holds magnitudes up to 3.4e38)"),
            );
            None
        }
    }

    fn vec3(&mut self, location: &str, what: &str, v: &Vec3Json) -> Option<Vec3> {
        let x = self.finite(location, &format!("{what}[0]"), v[0]);
        let y = self.finite(location, &format!("{what}[1]"), v[1]);
        let z = self.finite(location, &format!("{what}[2]"), v[2]);
        Some(Vec3::new(x?, y?, z?))
    }

    /// A rotation must be a unit quaternion (within 1e-3; it is then
    /// renormalised).
    fn rotation(&mut self, location: &str, what: &str, q: &[f64; 4]) -> Option<Quat> {
        let mut c = [0.0f32; 4];
        let mut ok = true;
        for (i, x) in q.iter().enumerate() {
            match self.finite(location, &format!("{what}[{i}]"), *x) {
                Some(v) => c[i] = v,
                None => ok = false,
            }
        }
        if !ok {
            return None;
        }
        let quat = Quat::from_xyzw(c[0], c[1], c[2], c[3]);
        let len = quat.length();
        if (len - 1.0).abs() > 1e-3 {
            self.report(
                location,
                format!(
                    "{what} has length {len}; a rotation must be a unit quaternion [x, y, z, w]"
                ),
            );
            return None;
        }
        Some(quat.normalize())
    }

    fn pose(&mut self, location: &str, pose: &PoseJson) -> Option<Pose> {
        let translation = self.vec3(location, "pose.translation", &pose.translation);
        let rotation = self.rotation(location, "pose.rotation", &pose.rotation);
        let scale = self.finite(location, "pose.scale", pose.scale);
        if let Some(s) = scale {
            if s <= 0.0 {
                self.report(location, format!("pose.scale = {s} must be greater than 0"));
                return None;
            }
        }
        Some(Pose {
            translation: translation?,
            rotation: rotation?,
            scale: scale?,
        })
    }

    fn density(&mut self, location: &str, what: &str, d: f64, scale: f32) -> Option<f32> {
        let d = self.finite(location, what, d)?;
        if d <= 0.0 {
            self.report(
                location,
                format!("{what} = {d} must be greater than 0 texels per metre"),
            );
            return None;
        }
        Some(d * scale)
    }

    fn unique<'a>(&mut self, kind: &str, names: impl Iterator<Item = &'a str>) {
        let mut seen: HashMap<&str, usize> = HashMap::new();
        for (i, name) in names.enumerate() {
            if name.trim().is_empty() {
                self.report(&format!("{kind} #{i}"), "name is empty");
            } else if let Some(first) = seen.get(name) {
                self.report(
                    &format!("{kind} #{i} \"{name}\""),
                    format!("duplicate name: {kind} #{first} is also called \"{name}\""),
                );
            } else {
                seen.insert(name, i);
            }
        }
    }
}

/// Validates a parsed scene file; `base` is the directory its `imports`
/// are relative to (the working directory when `None`). Returns every
/// problem found.
pub fn validate(
    raw: SceneFile,
    options: LoadOptions,
    base: Option<&Path>,
) -> Result<Scene, Vec<SceneIssue>> {
    let mut c = Checker { issues: Vec::new() };

    if raw.name.trim().is_empty() {
        c.report("scene", "name is empty");
    }
    if !(options.density_scale.is_finite() && options.density_scale > 0.0) {
        c.report(
            "load options",
            format!("density scale {} must be > 0", options.density_scale),
        );
    }
    let texel_density = c.density(
        "lightmap",
        "texel_density",
        raw.lightmap.texel_density,
        options.density_scale,
    );
    let max_atlas_size = raw.lightmap.max_atlas_size;
    if !(MIN_ATLAS_LIMIT..=MAX_ATLAS_LIMIT).contains(&max_atlas_size) {
        c.report(
            "lightmap",
            format!("max_atlas_size = {max_atlas_size} must be between {MIN_ATLAS_LIMIT} and {MAX_ATLAS_LIMIT}"),
        );
    }

    let solver = solver_hints(&mut c, &raw.solver, options.density_scale);

    // Materials.
    c.unique("material", raw.materials.iter().map(|m| m.name.as_str()));
    let mut materials = Vec::with_capacity(raw.materials.len());
    for (i, m) in raw.materials.iter().enumerate() {
        let loc = format!("material #{i} \"{}\"", m.name);
        let albedo = c.vec3(&loc, "albedo", &m.albedo);
        let emission = c.vec3(&loc, "emission", &m.emission);
        if let Some(a) = albedo {
            for (k, x) in a.to_array().iter().enumerate() {
                if !(0.0..1.0).contains(x) {
                    c.report(&loc, format!("albedo[{k}] = {x} is outside [0, 1): a surface cannot reflect all the light it receives"));
                }
            }
        }
        if let Some(e) = emission {
            for (k, x) in e.to_array().iter().enumerate() {
                if *x < 0.0 {
                    c.report(
                        &loc,
                        format!("emission[{k}] = {x} is negative; emission must be >= 0"),
                    );
                }
            }
        }
        materials.push(Material {
            name: m.name.clone(),
            albedo: albedo.unwrap_or(Vec3::ZERO),
            emission: emission.unwrap_or(Vec3::ZERO),
        });
    }

    // Objects: the static world first, then the dynamic ones in file order.
    c.unique("object", raw.objects.iter().map(|o| o.name.as_str()));
    let mut objects = vec![Object {
        name: STATIC_NAME.to_string(),
        dynamic: false,
        initial_pose: Pose::IDENTITY,
    }];
    for (i, o) in raw.objects.iter().enumerate() {
        let loc = format!("object #{i} \"{}\"", o.name);
        if o.name == STATIC_NAME {
            c.report(
                &loc,
                format!("the name \"{STATIC_NAME}\" is reserved for the static world"),
            );
        }
        let pose = c.pose(&loc, &o.pose).unwrap_or_default();
        objects.push(Object {
            name: o.name.clone(),
            dynamic: true,
            initial_pose: pose,
        });
    }

    // Surfaces.
    c.unique("surface", raw.surfaces.iter().map(|s| s.name.as_str()));
    let mut patches = Vec::new();
    let mut uv_meshes = Vec::new();
    for (i, s) in raw.surfaces.iter().enumerate() {
        let loc = format!("surface #{i} \"{}\"", s.name);
        let material = raw.materials.iter().position(|m| m.name == s.material);
        if material.is_none() {
            c.report(&loc, format!("unknown material \"{}\"", s.material));
        }
        let object = match &s.object {
            None => Some(0u32),
            Some(name) => match raw.objects.iter().position(|o| &o.name == name) {
                Some(k) => Some(k as u32 + 1),
                None => {
                    c.report(&loc, format!("unknown object \"{name}\" (dynamic objects are declared under \"objects\"; omit \"object\" for static surfaces)"));
                    None
                }
            },
        };
        let density = match s.texel_density {
            Some(d) => c.density(&loc, "texel_density", d, options.density_scale),
            None => texel_density,
        };
        let given = [
            s.quad.is_some().then_some("quad"),
            s.box_.is_some().then_some("box"),
            s.mesh.is_some().then_some("mesh"),
        ];
        let given: Vec<&str> = given.into_iter().flatten().collect();
        // A mesh's lightmap UVs per triangle, in its patches' corner order.
        let mut lightmap_uvs: Option<TriangleUvs> = None;
        let shapes: Vec<(String, PatchShape)> = match (&s.quad, &s.box_, &s.mesh) {
            _ if given.len() > 1 => {
                c.report(
                    &loc,
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
                Vec::new()
            }
            (Some(q), _, _) => quad(&mut c, &loc, q)
                .map(|q| vec![(s.name.clone(), q)])
                .unwrap_or_default(),
            (_, Some(b), _) => boxed(&mut c, &loc, &s.name, b),
            (_, _, Some(m)) => {
                let (shapes, uvs) = mesh(&mut c, &loc, &s.name, m);
                lightmap_uvs = uvs;
                shapes
            }
            (None, None, None) => {
                c.report(&loc, "has no shape; give \"quad\", \"box\" or \"mesh\"");
                Vec::new()
            }
        };
        let from_mesh = s.mesh.is_some();
        if let (Some(material), Some(object), Some(density)) = (material, object, density) {
            let generate = from_mesh
                && !shapes.is_empty()
                && generates_uvs(options.charts, object, lightmap_uvs.is_some());
            let triangles = || -> Vec<[Vec3; 3]> {
                shapes
                    .iter()
                    .map(|(_, shape)| {
                        let (o, u, v) = shape.frame();
                        [o, o + u, o + u + v]
                    })
                    .collect()
            };
            if generate {
                // In the patches' corner order, as given ones are.
                lightmap_uvs = Some(super::unwrap::unwrap(&triangles(), density).uvs);
            }
            let uv_mesh = lightmap_uvs.as_ref().map(|uvs| {
                uv_meshes.push(UvMesh {
                    name: s.name.clone(),
                    object,
                    surface_index: i,
                    triangles: triangles(),
                    uvs: uvs.clone(),
                    generated: generate,
                    smooth_edges: Vec::new(),
                });
                (uv_meshes.len() - 1) as u32
            });
            for (k, (name, shape)) in shapes.into_iter().enumerate() {
                let lightmap = uv_mesh
                    .zip(lightmap_uvs.as_ref().and_then(|u| u.get(k)))
                    .map(|(mesh, &uv)| PatchLightmap { mesh, uv });
                patches.push(Patch {
                    name,
                    surface_index: i,
                    object,
                    material: material as u32,
                    texel_density: density,
                    shape,
                    albedo_map: None,
                    mesh: from_mesh,
                    cells: [1, 1],
                    lightmap,
                });
            }
        }
    }

    // glTF imports: their materials and dynamic nodes join the scene's.
    for (i, import) in raw.imports.iter().enumerate() {
        let loc = format!("import #{i} \"{}\"", import.file);
        let density = match import.texel_density {
            Some(d) => c.density(&loc, "texel_density", d, options.density_scale),
            None => texel_density,
        };
        let emission_scale = c.finite(&loc, "emission_scale", import.emission_scale);
        if let Some(e) = emission_scale {
            if e < 0.0 {
                c.report(&loc, format!("emission_scale = {e} must be >= 0"));
            }
        }
        let (Some(density), Some(emission_scale)) = (density, emission_scale) else {
            continue;
        };
        let path = match base {
            Some(base) => base.join(&import.file),
            None => Path::new(&import.file).to_path_buf(),
        };
        let imported = match super::gltf::import(&path, &import_options(import, emission_scale)) {
            Ok(imported) => imported,
            Err(e) => {
                c.report(&loc, e.to_string());
                continue;
            }
        };
        let into = Parts {
            materials: &mut materials,
            objects: &mut objects,
            patches: &mut patches,
            uv_meshes: &mut uv_meshes,
        };
        merge_import(
            &mut c,
            &loc,
            &imported,
            into,
            density,
            raw.surfaces.len() + i,
            options.charts,
        );
    }

    if raw.surfaces.is_empty() && raw.imports.is_empty() {
        c.report("scene", "has no surfaces");
    } else if c.issues.is_empty()
        && !patches
            .iter()
            .any(|p| materials[p.material as usize].is_emitter())
    {
        c.report(
            "scene",
            "has no emitter: no surface uses a material with emission > 0, so everything would be black",
        );
    }

    if !c.issues.is_empty() {
        return Err(c.issues);
    }
    patches = super::pairs::charts(patches, options.charts);
    Ok(Scene {
        name: raw.name,
        description: raw.description,
        texel_density: texel_density.unwrap_or(1.0),
        max_atlas_size,
        materials,
        objects,
        patches,
        uv_meshes,
        solver,
    })
}

/// The file's `"solver"` settings, checked; dropped (the defaults) at any
/// density but the file's own, for which they were measured.
fn solver_hints(c: &mut Checker, raw: &SolverJson, density_scale: f32) -> SolverHints {
    let mut hints = SolverHints::default();
    if let Some(g) = raw.cross_grid {
        if (1..=SolverHints::MAX_CROSS_GRID).contains(&g) {
            hints.cross_grid = Some(g);
        } else {
            c.report(
                "solver",
                format!(
                    "cross_grid = {g} must be between 1 and {}",
                    SolverHints::MAX_CROSS_GRID
                ),
            );
        }
    }
    if let Some(r) = raw.back_resolution {
        if (SolverHints::MIN_BACK_RESOLUTION..=SolverHints::MAX_BACK_RESOLUTION).contains(&r) {
            hints.back_resolution = Some(r);
        } else {
            c.report(
                "solver",
                format!(
                    "back_resolution = {r} must be between {} and {}",
                    SolverHints::MIN_BACK_RESOLUTION,
                    SolverHints::MAX_BACK_RESOLUTION
                ),
            );
        }
    }
    if let Some(t) = raw.cross_coarse_below {
        if (0.0..=1.0).contains(&t) {
            hints.cross_coarse_below = Some(t as f32);
        } else {
            c.report(
                "solver",
                format!("cross_coarse_below = {t} must be between 0 and 1"),
            );
        }
    }
    if density_scale == 1.0 {
        hints
    } else {
        SolverHints::default()
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

/// A mesh's lightmap UVs per triangle, in its patches' corner order.
type TriangleUvs = Vec<[Vec2; 3]>;

/// Triangles listed per mesh before the rest are only counted.
const MAX_LISTED_TRIANGLES: usize = 8;

/// A mesh's triangles, each a patch named `name/k` (k the triangle's index
/// in the mesh). Reports out-of-range indices, an index count that is not a
/// multiple of three, non-finite positions and degenerate triangles (twice
/// the area at most [`super::gltf::DEGENERATE_RATIO`] times the longest edge
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
    let shapes = mesh_shapes(c, loc, name, m);
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
        -super::gltf::UV_RANGE_SLACK,
        1.0 + super::gltf::UV_RANGE_SLACK,
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
    let tris: Vec<[Vec2; 3]> = indices
        .chunks_exact(3)
        .map(|t| {
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
                "mesh triangle {k} has zero area in mesh.lightmap_uvs ({:?}): it would get no lightmap texels",
                tris[k]
            ),
        );
    }
    match super::gltf::find_uv_overlaps(&tris, MAX_LISTED_TRIANGLES) {
        Ok(overlaps) => {
            for o in &overlaps {
                c.report(
                    loc,
                    format!(
                        "mesh triangle {} overlaps triangle {} in mesh.lightmap_uvs by {:.3e} (UV units², {:.1}% of the smaller): lightmap UVs must not overlap",
                        o.a,
                        o.b,
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

fn mesh_shapes(c: &mut Checker, loc: &str, name: &str, m: &MeshJson) -> Vec<(String, PatchShape)> {
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
        return Vec::new();
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
        return Vec::new();
    }
    let mut degenerate = Vec::new();
    let mut shapes = Vec::with_capacity(indices.len() / 3);
    for (k, t) in indices.chunks_exact(3).enumerate() {
        let [a, b, d] = [0, 1, 2].map(|j| positions[t[j] as usize]);
        let twice_area = (b - a).cross(d - a).length();
        let longest = (b - a)
            .length_squared()
            .max((d - b).length_squared())
            .max((a - d).length_squared());
        // Positions are finite here, so the comparison is never with NaN.
        if twice_area <= super::gltf::DEGENERATE_RATIO * longest || longest == 0.0 {
            degenerate.push(k);
            continue;
        }
        shapes.push((format!("{name}/{k}"), PatchShape::triangle(a, b, d)));
    }
    if !degenerate.is_empty() {
        let listed: Vec<String> = degenerate
            .iter()
            .take(MAX_LISTED_TRIANGLES)
            .map(|k| format!("#{k} (indices {:?})", &indices[3 * k..3 * k + 3]))
            .collect();
        let more = degenerate.len().saturating_sub(MAX_LISTED_TRIANGLES);
        c.report(
            loc,
            format!(
                "mesh has {} degenerate triangle(s), whose corners lie on a line: {}{}",
                degenerate.len(),
                listed.join(", "),
                if more > 0 {
                    format!(" and {more} more")
                } else {
                    String::new()
                }
            ),
        );
        return Vec::new();
    }
    shapes
}

fn import_options(import: &ImportJson, emission_scale: f32) -> ImportOptions {
    ImportOptions {
        nodes: import.nodes.clone(),
        dynamic_nodes: import.dynamic_nodes.clone(),
        emission_scale,
    }
}

/// What an import adds to.
struct Parts<'a> {
    materials: &'a mut Vec<Material>,
    objects: &'a mut Vec<Object>,
    patches: &'a mut Vec<Patch>,
    uv_meshes: &'a mut Vec<UvMesh>,
}

/// Adds an imported glTF to the scene being built: its materials (a name
/// already taken must have the same albedo and emission, and is then
/// shared), its dynamic objects (names must be new), and every triangle as a
/// patch named `<node>/<mesh>/<primitive>/<k>` (names, or `node#i`,
/// `mesh#j`, when the glTF has none). `surface_index` is what atlas errors
/// name the import by. The importer has already refused degenerate
/// triangles, NaNs and bad accessors, naming file, node, mesh and primitive.
fn merge_import(
    c: &mut Checker,
    loc: &str,
    imported: &ImportedScene,
    into: Parts<'_>,
    density: f32,
    surface_index: usize,
    charts: Charts,
) {
    let mut material_ids = Vec::with_capacity(imported.materials.len());
    for m in &imported.materials {
        let id = match into.materials.iter().position(|x| x.name == m.name) {
            Some(k) => {
                let x = &into.materials[k];
                if x.albedo != m.albedo || x.emission != m.emission {
                    c.report(
                        loc,
                        format!(
                            "material \"{}\" is also defined elsewhere with other values (albedo {:?} vs {:?}, emission {:?} vs {:?}); rename one",
                            m.name, m.albedo, x.albedo, m.emission, x.emission
                        ),
                    );
                }
                k
            }
            None => {
                into.materials.push(Material {
                    name: m.name.clone(),
                    albedo: m.albedo,
                    emission: m.emission,
                });
                into.materials.len() - 1
            }
        };
        material_ids.push(id as u32);
    }
    let mut object_ids = Vec::with_capacity(imported.objects.len());
    for (k, o) in imported.objects.iter().enumerate() {
        if k == 0 {
            object_ids.push(super::STATIC_OBJECT);
            continue;
        }
        if into.objects.iter().any(|x| x.name == o.name) {
            c.report(
                loc,
                format!(
                    "dynamic node \"{}\" has the name of an object that already exists; object names must be unique",
                    o.name
                ),
            );
        }
        into.objects.push(Object {
            name: o.name.clone(),
            dynamic: true,
            initial_pose: o.pose,
        });
        object_ids.push((into.objects.len() - 1) as u32);
    }
    let mut uv_mesh_of: HashMap<(usize, usize), usize> = HashMap::new();
    // Per own-UV mesh, its triangles' vertex normals (for its smooth edges).
    let mut own_normals: std::collections::BTreeMap<usize, Vec<Option<[Vec3; 3]>>> =
        std::collections::BTreeMap::new();
    let generated = generate_import_uvs(
        imported,
        &object_ids,
        charts,
        density,
        surface_index,
        into.uv_meshes,
    );
    for (n, inst) in imported.instances.iter().enumerate() {
        let (node, mesh) = names(inst);
        let (Some(&material), Some(&object)) = (
            material_ids.get(inst.material as usize),
            object_ids.get(inst.object as usize),
        ) else {
            c.report(
                loc,
                format!("node \"{node}\" mesh \"{mesh}\": material or object index out of range"),
            );
            continue;
        };
        // The importer has checked that a textured primitive has the
        // coordinates its texture reads.
        let texture = imported
            .materials
            .get(inst.material as usize)
            .and_then(|m| {
                let set = m.base_color_texture.as_ref()?.tex_coord;
                Some((m.texture.clone()?, inst.uvs(set)?))
            });
        // The primitives of one node's mesh share its lightmap space.
        let uv_mesh = inst.lightmap_uvs.as_ref().map(|_| {
            *uv_mesh_of.entry((inst.node, inst.mesh)).or_insert_with(|| {
                into.uv_meshes.push(UvMesh {
                    name: format!("{node}/{mesh}"),
                    object,
                    surface_index,
                    triangles: Vec::new(),
                    uvs: Vec::new(),
                    generated: false,
                    smooth_edges: Vec::new(),
                });
                into.uv_meshes.len() - 1
            })
        });
        for (k, tri) in inst.indices.iter().enumerate() {
            let [a, b, d] = tri.map(|i| inst.positions.get(i as usize).copied());
            let (Some(a), Some(b), Some(d)) = (a, b, d) else {
                c.report(
                    loc,
                    format!("node \"{node}\" mesh \"{mesh}\" primitive {}: triangle {k} indexes past its positions", inst.primitive),
                );
                break;
            };
            // The base colour texture's coordinates at the patch's corners,
            // in the order `PatchShape::triangle` puts the vertices.
            let order = PatchShape::triangle_order(a, b, d);
            let albedo_map = texture.as_ref().and_then(|(texture, uvs)| {
                let uv = order.map(|j| uvs.get(tri[j] as usize).copied());
                Some(AlbedoMap {
                    texture: Arc::clone(texture),
                    uv: [uv[0]?, uv[1]?, uv[2]?],
                })
            });
            // Its lightmap UVs, generated or its own, in the same order.
            let lightmap = match &generated[n] {
                Some((m, uvs)) => uvs.get(k).map(|uv| PatchLightmap {
                    mesh: *m as u32,
                    uv: order.map(|j| uv[j]),
                }),
                None => uv_mesh
                    .zip(inst.lightmap_uvs.as_ref())
                    .and_then(|(m, uvs)| {
                        let uv = order.map(|j| uvs.get(tri[j] as usize).copied());
                        Some(PatchLightmap {
                            mesh: m as u32,
                            uv: [uv[0]?, uv[1]?, uv[2]?],
                        })
                    }),
            };
            into.patches.push(Patch {
                name: format!("{node}/{mesh}/{}/{k}", inst.primitive),
                surface_index,
                object,
                material,
                texel_density: density,
                shape: PatchShape::triangle(a, b, d),
                albedo_map,
                mesh: true,
                cells: [1, 1],
                lightmap,
            });
        }
        // The primitives of one node's mesh share its lightmap space.
        if let (Some(uvs), Some(k)) = (&inst.lightmap_uvs, uv_mesh) {
            let m = &mut into.uv_meshes[k];
            let normals = own_normals.entry(k).or_default();
            for tri in &inst.indices {
                let corner = |j: usize| {
                    let i = tri[j] as usize;
                    Some((*inst.positions.get(i)?, *uvs.get(i)?))
                };
                if let (Some(a), Some(b), Some(d)) = (corner(0), corner(1), corner(2)) {
                    m.triangles.push([a.0, b.0, d.0]);
                    m.uvs.push([a.1, b.1, d.1]);
                    normals.push(corner_normals(inst, tri));
                }
            }
        }
    }
    for (k, normals) in own_normals {
        let m = &mut into.uv_meshes[k];
        m.smooth_edges = super::unwrap::smooth_edges(&m.triangles, &normals);
    }
}

/// Triangle `tri`'s vertex normals of `inst`, corner by corner, if it has
/// them.
fn corner_normals(inst: &super::gltf::MeshInstance, tri: &[u32; 3]) -> Option<[Vec3; 3]> {
    let n = inst.normals.as_ref()?;
    let [a, b, c] = tri.map(|i| n.get(i as usize).copied());
    Some([a?, b?, c?])
}

/// An instance's node and mesh names, or `node#i`, `mesh#j` when the glTF
/// has none.
fn names(inst: &super::gltf::MeshInstance) -> (String, String) {
    let node = inst
        .node_name
        .clone()
        .unwrap_or_else(|| format!("node#{}", inst.node));
    let mesh = inst
        .mesh_name
        .clone()
        .unwrap_or_else(|| format!("mesh#{}", inst.mesh));
    (node, mesh)
}

/// Whether a mesh surface of `object` gets generated lightmap UVs
/// (`scene/unwrap.rs`) under `charts`: a static one without its own under
/// `lightmap-uvs`, every static one under `generated`.
fn generates_uvs(charts: Charts, object: u32, has_own: bool) -> bool {
    object == super::STATIC_OBJECT
        && match charts {
            Charts::LightmapUvs => !has_own,
            Charts::Generated => true,
            Charts::Triangles | Charts::Pairs | Charts::Parallelograms => false,
        }
}

/// Generated lightmap UVs for the static meshes of an import that
/// [`generates_uvs`] picks: one [`UvMesh`] per node's mesh (its primitives
/// share it), pushed onto `uv_meshes`; per instance, that mesh's index and
/// the instance's triangles' UVs in their index order.
fn generate_import_uvs(
    imported: &ImportedScene,
    object_ids: &[u32],
    charts: Charts,
    density: f32,
    surface_index: usize,
    uv_meshes: &mut Vec<UvMesh>,
) -> Vec<Option<(usize, Vec<[Vec2; 3]>)>> {
    let mut out = vec![None; imported.instances.len()];
    // Instances by node and mesh, in order.
    let mut groups: Vec<((usize, usize), Vec<usize>)> = Vec::new();
    for (n, inst) in imported.instances.iter().enumerate() {
        let object = object_ids.get(inst.object as usize).copied();
        if !object.is_some_and(|o| generates_uvs(charts, o, inst.lightmap_uvs.is_some())) {
            continue;
        }
        match groups
            .iter_mut()
            .find(|(key, _)| *key == (inst.node, inst.mesh))
        {
            Some((_, members)) => members.push(n),
            None => groups.push(((inst.node, inst.mesh), vec![n])),
        }
    }
    for (_, members) in groups {
        let mut triangles = Vec::new();
        let mut normals = Vec::new();
        let mut ranges = Vec::with_capacity(members.len());
        for &n in &members {
            let inst = &imported.instances[n];
            let start = triangles.len();
            // The importer has checked every index against its positions.
            for tri in &inst.indices {
                let [a, b, d] = tri.map(|i| inst.positions.get(i as usize).copied());
                if let (Some(a), Some(b), Some(d)) = (a, b, d) {
                    triangles.push([a, b, d]);
                    normals.push(corner_normals(inst, tri));
                }
            }
            ranges.push(start..triangles.len());
        }
        let first = &imported.instances[members[0]];
        let unwrap = super::unwrap::unwrap(&triangles, density);
        let m = uv_meshes.len();
        for (&n, range) in members.iter().zip(ranges) {
            out[n] = Some((m, unwrap.uvs[range].to_vec()));
        }
        uv_meshes.push(UvMesh {
            name: {
                let (node, mesh) = names(first);
                format!("{node}/{mesh}")
            },
            object: object_ids.get(first.object as usize).copied().unwrap_or(0),
            surface_index,
            smooth_edges: super::unwrap::smooth_edges(&triangles, &normals),
            triangles,
            uvs: unwrap.uvs,
            generated: true,
        });
    }
    out
}

/// Texels on the surface a glTF opened on its own gets by default
/// ([`scene_from_gltf`]): enough to show soft shadows on a room, few enough
/// to solve in seconds on a software GPU.
pub const GLTF_DEFAULT_TEXELS: f32 = 16384.0;

/// A scene made of one glTF file (`lightwire bake --scene level.glb`):
/// named after the file, texel density `sqrt(GLTF_DEFAULT_TEXELS / area)`
/// (clamped to 1-256 texels/m, times `options.density_scale`), atlas up to
/// 4096 texels, dynamic nodes as marked in their `extras`.
pub fn scene_from_gltf(path: &Path, options: LoadOptions) -> Result<Scene, Vec<SceneIssue>> {
    let loc = path.display().to_string();
    let imported = super::gltf::import(path, &ImportOptions::default()).map_err(|e| {
        vec![SceneIssue {
            location: loc.clone(),
            problem: e.to_string(),
        }]
    })?;
    let area: f32 = imported
        .instances
        .iter()
        .flat_map(|i| {
            i.indices.iter().map(|t| {
                let [a, b, d] = t.map(|k| i.positions.get(k as usize).copied().unwrap_or_default());
                0.5 * (b - a).cross(d - a).length()
            })
        })
        .sum();
    let mut c = Checker { issues: Vec::new() };
    if !(options.density_scale.is_finite() && options.density_scale > 0.0) {
        c.report(
            "load options",
            format!("density scale {} must be > 0", options.density_scale),
        );
        return Err(c.issues);
    }
    let density = (GLTF_DEFAULT_TEXELS / area.max(1e-6))
        .sqrt()
        .clamp(1.0, 256.0)
        * options.density_scale;
    let mut scene = Scene {
        name: path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "scene".to_string()),
        description: format!("imported from {loc}"),
        texel_density: density,
        max_atlas_size: 4096,
        materials: Vec::new(),
        objects: vec![Object {
            name: STATIC_NAME.to_string(),
            dynamic: false,
            initial_pose: Pose::IDENTITY,
        }],
        patches: Vec::new(),
        uv_meshes: Vec::new(),
        solver: SolverHints::default(),
    };
    let into = Parts {
        materials: &mut scene.materials,
        objects: &mut scene.objects,
        patches: &mut scene.patches,
        uv_meshes: &mut scene.uv_meshes,
    };
    merge_import(&mut c, &loc, &imported, into, density, 0, options.charts);
    if scene.patches.is_empty() {
        c.report(&loc, "has no triangles");
    } else if !scene
        .patches
        .iter()
        .any(|p| scene.materials[p.material as usize].is_emitter())
    {
        c.report(
            &loc,
            "has no emitter: no material has an emissiveFactor > 0, so everything would be black",
        );
    }
    if !c.issues.is_empty() {
        return Err(c.issues);
    }
    scene.patches = super::pairs::charts(std::mem::take(&mut scene.patches), options.charts);
    Ok(scene)
}
