//! Semantic checks that turn a [`SceneFile`] into a [`Scene`].
//!
//! Every check records a [`SceneIssue`] naming the entry (kind, index and
//! name) and the problem, and validation carries on, so that one run reports
//! all problems of a file instead of the first.
//!
//! The shapes a surface may take (quad, box, mesh) are checked in
//! `validate/shape.rs`; glTF imports join the scene in `validate/import.rs`.

use std::collections::HashMap;
use std::path::Path;

use glam::{Quat, Vec2, Vec3};

use super::file::{
    MaterialJson, ObjectJson, PoseJson, SceneFile, SolverJson, SurfaceJson, Vec3Json,
};
use super::gltf::ImportOptions;
use super::{
    Charts, LoadOptions, Material, Object, Patch, PatchLightmap, PatchShape, Pose, Scene,
    SceneIssue, SolverHints, UvMesh, light::Light,
};

mod import;
pub(crate) mod lights;
mod shape;

/// Largest atlas edge a scene may ask for.
pub const MAX_ATLAS_LIMIT: u32 = 16384;
/// Smallest atlas edge a scene may ask for.
pub const MIN_ATLAS_LIMIT: u32 = 16;
/// Name reserved for the static world.
pub const STATIC_NAME: &str = "static";

#[derive(Default)]
struct Checker {
    issues: Vec<SceneIssue>,
    /// What was dropped or changed and loading went on past.
    warnings: Vec<SceneIssue>,
}

impl Checker {
    fn report(&mut self, location: &str, problem: impl Into<String>) {
        self.issues.push(SceneIssue {
            location: location.to_string(),
            problem: problem.into(),
        });
    }

    fn warn(&mut self, location: &str, problem: impl Into<String>) {
        self.warnings.push(SceneIssue {
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
    let mut c = Checker::default();
    let (texel_density, max_atlas_size) = check_settings(&mut c, &raw, options);
    let solver = solver_hints(&mut c, &raw.solver, options.density_scale);
    let mut materials = check_materials(&mut c, &raw.materials);
    let mut objects = check_objects(&mut c, &raw.objects);
    let mut lights = lights::check_lights(&mut c, &raw.lights, &objects);
    let detail = check_light_detail(&mut c, &raw);
    let (mut patches, mut uv_meshes) =
        check_surfaces(&mut c, &raw, options, texel_density, (&lights, detail));

    // glTF imports: their materials, dynamic nodes and lights join the
    // scene's.
    let into = Parts {
        materials: &mut materials,
        objects: &mut objects,
        patches: &mut patches,
        uv_meshes: &mut uv_meshes,
        lights: &mut lights,
    };
    import::check_imports(&mut c, &raw, options, base, texel_density, detail, into);

    let sky = lights::check_sky(&mut c, raw.sky.as_ref(), &lights);
    let lit =
        lights.iter().any(|l| l.intensity.max_element() > 0.0) || sky.is_some_and(|s| s.is_lit());
    check_lit(&mut c, &raw, &patches, &materials, lit);
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
        lights,
        sky,
        warnings: c.warnings,
    })
}

/// Checks the scene's name, the load options' density scale and the
/// lightmap settings. Returns the scene's texel density (`None` when it is
/// not valid) and the largest atlas edge it asks for.
fn check_settings(c: &mut Checker, raw: &SceneFile, options: LoadOptions) -> (Option<f32>, u32) {
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
    (texel_density, max_atlas_size)
}

/// Checks the materials: unique names, albedo in [0, 1), emission not
/// negative. Returns them in file order (a value that is not valid as 0).
fn check_materials(c: &mut Checker, raw: &[MaterialJson]) -> Vec<Material> {
    c.unique("material", raw.iter().map(|m| m.name.as_str()));
    let mut materials = Vec::with_capacity(raw.len());
    for (i, m) in raw.iter().enumerate() {
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
    materials
}

/// Checks the dynamic objects: unique names, not the static world's, and
/// valid poses. Returns the scene's objects.
fn check_objects(c: &mut Checker, raw: &[ObjectJson]) -> Vec<Object> {
    // Objects: the static world first, then the dynamic ones in file order.
    c.unique("object", raw.iter().map(|o| o.name.as_str()));
    let mut objects = vec![Object {
        name: STATIC_NAME.to_string(),
        dynamic: false,
        initial_pose: Pose::IDENTITY,
    }];
    for (i, o) in raw.iter().enumerate() {
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
    objects
}

/// Checks every surface and expands it into patches: a quad into one, a
/// box into six, a mesh into one per triangle. Returns the patches and
/// the lightmap UV meshes of the mesh surfaces lit on lightmap UVs.
fn check_surfaces(
    c: &mut Checker,
    raw: &SceneFile,
    options: LoadOptions,
    texel_density: Option<f32>,
    near: (&[Light], f32),
) -> (Vec<Patch>, Vec<UvMesh>) {
    c.unique("surface", raw.surfaces.iter().map(|s| s.name.as_str()));
    let mut patches = Vec::new();
    let mut uv_meshes = Vec::new();
    for (i, s) in raw.surfaces.iter().enumerate() {
        let loc = format!("surface #{i} \"{}\"", s.name);
        let (material, object) = surface_refs(c, &loc, raw, s);
        let density = match s.texel_density {
            Some(d) => c.density(&loc, "texel_density", d, options.density_scale),
            None => texel_density,
        };
        // A mesh's lightmap UVs per triangle, in its patches' corner order.
        let (shapes, lightmap_uvs) = shape::surface_shapes(c, &loc, s);
        if let (Some(material), Some(object), Some(density)) = (material, object, density) {
            let surface = Surface {
                index: i,
                name: &s.name,
                from_mesh: s.mesh.is_some(),
                material: material as u32,
                object,
                density,
            };
            add_surface(
                &surface,
                shapes,
                lightmap_uvs,
                options.charts,
                near,
                &mut patches,
                &mut uv_meshes,
            );
        }
    }
    (patches, uv_meshes)
}

/// Looks up a surface's material and object by name, and reports the
/// unknown ones. A surface that names no object is static (object 0).
fn surface_refs(
    c: &mut Checker,
    loc: &str,
    raw: &SceneFile,
    s: &SurfaceJson,
) -> (Option<usize>, Option<u32>) {
    let material = raw.materials.iter().position(|m| m.name == s.material);
    if material.is_none() {
        c.report(loc, format!("unknown material \"{}\"", s.material));
    }
    let object = match &s.object {
        None => Some(0u32),
        Some(name) => match raw.objects.iter().position(|o| &o.name == name) {
            Some(k) => Some(k as u32 + 1),
            None => {
                c.report(loc, format!("unknown object \"{name}\" (dynamic objects are declared under \"objects\"; omit \"object\" for static surfaces)"));
                None
            }
        },
    };
    (material, object)
}

/// A mesh's lightmap UVs per triangle, in its patches' corner order.
type TriangleUvs = Vec<[Vec2; 3]>;

/// A valid surface of the file: what all its patches share.
struct Surface<'a> {
    /// Its index in the file's `surfaces`.
    index: usize,
    name: &'a str,
    /// Whether it is a mesh.
    from_mesh: bool,
    material: u32,
    object: u32,
    /// Texels per metre.
    density: f32,
}

/// Adds a valid surface's patches to `patches`. A mesh lit on lightmap
/// UVs (its own, or generated here when [`generates_uvs`] says so) also
/// gets a [`UvMesh`] in `uv_meshes`, and each of its patches its UVs.
fn add_surface(
    s: &Surface,
    shapes: Vec<(String, PatchShape)>,
    mut lightmap_uvs: Option<TriangleUvs>,
    charts: Charts,
    (lights, detail): (&[Light], f32),
    patches: &mut Vec<Patch>,
    uv_meshes: &mut Vec<UvMesh>,
) {
    let generate = s.from_mesh
        && !shapes.is_empty()
        && generates_uvs(charts, s.object, lightmap_uvs.is_some());
    let triangles = || -> Vec<[Vec3; 3]> {
        shapes
            .iter()
            .map(|(_, shape)| {
                let (o, u, v) = shape.frame();
                [o, o + u, o + u + v]
            })
            .collect()
    };
    let (mut generated_charts, mut packed_side) = (0, 0.0);
    if generate {
        // In the patches' corner order, as given ones are.
        let triangles = triangles();
        // (The `uvunwrap` crate's charts take no levels: none are cast.)
        let detail = if charts.unwrapper() == super::unwrap::Unwrapper::Projected {
            detail
        } else {
            0.0
        };
        let levels =
            super::near_lights::budgeted_levels(&triangles, s.density, (lights, &[]), detail)
                .levels;
        let unwrap =
            super::unwrap::unwrap_graded(&triangles, s.density, charts.unwrapper(), (&levels, &[]));
        generated_charts = unwrap.charts;
        packed_side = refined_side(&unwrap, &levels);
        lightmap_uvs = Some(unwrap.uvs);
    }
    let uv_mesh = lightmap_uvs.as_ref().map(|uvs| {
        uv_meshes.push(UvMesh {
            name: s.name.to_string(),
            object: s.object,
            surface_index: s.index,
            triangles: triangles(),
            uvs: uvs.clone(),
            generated: generate,
            charts: generated_charts,
            smooth_edges: Vec::new(),
            packed_side,
        });
        (uv_meshes.len() - 1) as u32
    });
    for (k, (name, shape)) in shapes.into_iter().enumerate() {
        let lightmap = uv_mesh
            .zip(lightmap_uvs.as_ref().and_then(|u| u.get(k)))
            .map(|(mesh, &uv)| PatchLightmap { mesh, uv });
        patches.push(Patch {
            name,
            surface_index: s.index,
            object: s.object,
            material: s.material,
            texel_density: s.density,
            shape,
            albedo_map: None,
            mesh: s.from_mesh,
            cells: [1, 1],
            lightmap,
        });
    }
}

/// Reports a scene without surfaces or imports, and, when nothing else is
/// wrong, one that no patch lights.
fn check_lit(
    c: &mut Checker,
    raw: &SceneFile,
    patches: &[Patch],
    materials: &[Material],
    lit_by_lights: bool,
) {
    if raw.surfaces.is_empty() && raw.imports.is_empty() {
        c.report("scene", "has no surfaces");
    } else if c.issues.is_empty()
        && !patches
            .iter()
            .any(|p| materials[p.material as usize].is_emitter())
        && !lit_by_lights
    {
        c.report(
            "scene",
            "has no light: give a surface a material with emission > 0, add a point, spot or directional light (\"lights\") or a sky (\"sky\"), or everything will be black",
        );
    }
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

/// What an import adds to.
struct Parts<'a> {
    materials: &'a mut Vec<Material>,
    objects: &'a mut Vec<Object>,
    patches: &'a mut Vec<Patch>,
    uv_meshes: &'a mut Vec<UvMesh>,
    lights: &'a mut Vec<crate::Light>,
}

/// Whether a mesh surface of `object` gets generated lightmap UVs
/// (`scene/unwrap.rs`) under `charts`: a static one without its own under
/// `lightmap-uvs`, every static one under `generated`.
fn generates_uvs(charts: Charts, object: u32, has_own: bool) -> bool {
    object == super::STATIC_OBJECT
        && match charts {
            Charts::LightmapUvs => !has_own,
            Charts::Generated | Charts::Uvunwrap => true,
            Charts::Triangles | Charts::Pairs | Charts::Parallelograms => false,
        }
}

/// The side generated UVs were packed for when some triangle was refined
/// near a light, else 0 (the block then sized from the density alone, as
/// before refinement existed: `uv::block_side`).
pub(super) fn refined_side(unwrap: &super::unwrap::Unwrap, levels: &[u8]) -> f32 {
    if levels.iter().any(|&l| l > 0) {
        unwrap.side
    } else {
        0.0
    }
}

/// The scene file's `lightmap.light_detail` (texels across the distance to
/// a point or spot light, `near_lights.rs`); 0 (none) after reporting a
/// value that is not valid.
fn check_light_detail(c: &mut Checker, raw: &SceneFile) -> f32 {
    let Some(d) = c.finite("lightmap", "light_detail", raw.lightmap.light_detail) else {
        return 0.0;
    };
    if !(0.0..=MAX_LIGHT_DETAIL).contains(&d) {
        c.report(
            "lightmap",
            format!("light_detail = {d} must be between 0 (off) and {MAX_LIGHT_DETAIL} texels"),
        );
        return 0.0;
    }
    d
}

/// The largest `lightmap.light_detail` accepted.
const MAX_LIGHT_DETAIL: f32 = 64.0;

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
    let mut c = Checker::default();
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
        lights: Vec::new(),
        sky: None,
        warnings: Vec::new(),
    };
    let mut into = Parts {
        materials: &mut scene.materials,
        objects: &mut scene.objects,
        patches: &mut scene.patches,
        uv_meshes: &mut scene.uv_meshes,
        lights: &mut scene.lights,
    };
    import::merge_import(
        &mut c,
        &loc,
        &imported,
        &mut into,
        (density, crate::near_lights::DEFAULT_DETAIL),
        0,
        options.charts,
    );
    // A sky Lightwire's export kept in the asset's extras.
    scene.sky = imported
        .sky
        .filter(|s| s.is_lit())
        .map(|s| s.with_ground(s.ground_albedo, &scene.lights));
    if scene.patches.is_empty() {
        c.report(&loc, "has no triangles");
    } else if !scene
        .patches
        .iter()
        .any(|p| scene.materials[p.material as usize].is_emitter())
        && !scene.lights.iter().any(|l| l.intensity.max_element() > 0.0)
        && scene.sky.is_none()
    {
        c.report(
            &loc,
            "has no light: no material has an emissiveFactor > 0 and no node a KHR_lights_punctual light, so everything would be black",
        );
    }
    if !c.issues.is_empty() {
        return Err(c.issues);
    }
    scene.patches = super::pairs::charts(std::mem::take(&mut scene.patches), options.charts);
    scene.warnings = c.warnings;
    Ok(scene)
}
