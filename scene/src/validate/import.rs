//! glTF imports: the materials, dynamic nodes and triangles of an imported
//! file join the scene's.

use std::collections::{BTreeMap, HashMap};
use std::path::Path;
use std::sync::Arc;

use glam::{Vec2, Vec3};

use super::{Checker, Parts, generates_uvs};
use crate::file::{ImportJson, SceneFile};
use crate::gltf::{ImportOptions, ImportedScene, MaterialOverride, MeshInstance};
use crate::light::Light;
use crate::texture::{AlbedoMap, Texture};
use crate::{Charts, LoadOptions, Material, Object, Patch, PatchLightmap, PatchShape, UvMesh};

/// Reads every glTF file the scene file imports, relative to `base` (the
/// working directory when `None`), and adds it to the scene being built.
/// An import whose settings or file are not valid is reported and left out.
pub(super) fn check_imports(
    c: &mut Checker,
    raw: &SceneFile,
    options: LoadOptions,
    base: Option<&Path>,
    texel_density: Option<f32>,
    detail: f32,
    mut into: Parts<'_>,
) {
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
        let light_scale = c.finite(&loc, "light_scale", import.light_scale);
        if let Some(l) = light_scale
            && l < 0.0
        {
            c.report(&loc, format!("light_scale = {l} must be >= 0"));
        }
        let (Some(density), Some(emission_scale), Some(light_scale)) =
            (density, emission_scale, light_scale)
        else {
            continue;
        };
        let path = match base {
            Some(base) => base.join(&import.file),
            None => Path::new(&import.file).to_path_buf(),
        };
        let mut import_opts = import_options(import, emission_scale, light_scale);
        import_opts.materials = material_overrides(c, &loc, import);
        let imported = match crate::gltf::import(&path, &import_opts) {
            Ok(imported) => imported,
            Err(e) => {
                c.report(&loc, e.to_string());
                continue;
            }
        };
        unknown_materials(c, &loc, import, &imported);
        merge_import(
            c,
            &loc,
            &imported,
            &mut into,
            (density, detail),
            raw.surfaces.len() + i,
            options.charts,
        );
    }
}

/// Checks an import's `materials` overrides (by name, `"*"` for every
/// material not named) and returns them for the importer. Reports values a
/// material may not have; a name the file lacks is reported after the
/// import ([`unknown_materials`]).
fn material_overrides(
    c: &mut Checker,
    loc: &str,
    import: &ImportJson,
) -> BTreeMap<String, MaterialOverride> {
    let mut out = BTreeMap::new();
    for (name, o) in &import.materials {
        let at = format!("{loc}: materials.\"{name}\"");
        let albedo = o.albedo.as_ref().and_then(|a| c.vec3(&at, "albedo", a));
        let emission = o.emission.as_ref().and_then(|e| c.vec3(&at, "emission", e));
        if let Some(a) = albedo {
            if !(a.cmpge(Vec3::ZERO).all() && a.cmplt(Vec3::ONE).all()) {
                c.report(&at, format!("albedo {a:?} must lie in [0, 1) per channel"));
            }
        }
        if let Some(e) = emission {
            if e.min_element() < 0.0 {
                c.report(&at, format!("emission {e:?} must be >= 0 per channel"));
            }
        }
        out.insert(name.clone(), MaterialOverride { albedo, emission });
    }
    out
}

/// Reports override names (other than `"*"`) no imported material has.
fn unknown_materials(c: &mut Checker, loc: &str, import: &ImportJson, imported: &ImportedScene) {
    for name in import.materials.keys() {
        if name != "*" && !imported.materials.iter().any(|m| &m.name == name) {
            let known: Vec<&str> = imported
                .materials
                .iter()
                .map(|m| m.name.as_str())
                .take(12)
                .collect();
            c.report(
                loc,
                format!(
                    "materials.\"{name}\": the file has no material of that name (it has {}{})",
                    known.join(", "),
                    if imported.materials.len() > known.len() {
                        ", ..."
                    } else {
                        ""
                    }
                ),
            );
        }
    }
}

fn import_options(import: &ImportJson, emission_scale: f32, light_scale: f32) -> ImportOptions {
    ImportOptions {
        nodes: import.nodes.clone(),
        dynamic_nodes: import.dynamic_nodes.clone(),
        emission_scale,
        materials: BTreeMap::new(),
        light_scale,
    }
}

/// Adds an imported glTF to the scene being built: its materials (a name
/// already taken must have the same albedo and emission, and is then
/// shared), its dynamic objects (names must be new), and every triangle as a
/// patch named `<node>/<mesh>/<primitive>/<k>` (names, or `node#i`,
/// `mesh#j`, when the glTF has none). `surface_index` is what atlas errors
/// name the import by. The importer has already refused NaNs and bad
/// accessors, naming file, node, mesh and primitive, and dropped zero-area
/// and duplicate triangles (its warnings join the scene's).
pub(super) fn merge_import(
    c: &mut Checker,
    loc: &str,
    imported: &ImportedScene,
    into: &mut Parts<'_>,
    (density, detail): (f32, f32),
    surface_index: usize,
    charts: Charts,
) {
    for w in &imported.warnings {
        c.warn(&format!("{loc}: {}", w.location), w.problem.clone());
    }
    let material_ids = merge_materials(c, loc, imported, into.materials);
    let object_ids = merge_objects(c, loc, imported, into.objects);
    // A light under a dynamic node rides with that node's object.
    into.lights.extend(imported.lights.iter().map(|l| {
        crate::Light {
            object: object_ids
                .get(l.object as usize)
                .copied()
                .unwrap_or(crate::STATIC_OBJECT),
            ..l.clone()
        }
    }));
    let mut uv_mesh_of: HashMap<(usize, usize), usize> = HashMap::new();
    // Per own-UV mesh, its triangles' vertex normals (for its smooth edges).
    let mut own_normals: BTreeMap<usize, Vec<Option<[Vec3; 3]>>> = BTreeMap::new();
    let generated = generate_import_uvs(
        (c, loc),
        imported,
        &object_ids,
        charts,
        (density, detail, into.lights),
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
                    charts: 0,
                    smooth_edges: Vec::new(),
                    packed_side: 0.0,
                });
                into.uv_meshes.len() - 1
            })
        });
        let instance = Instance {
            inst,
            node: &node,
            mesh: &mesh,
            surface_index,
            object,
            material,
            density,
            texture: base_color(imported, inst),
            generated: generated[n].as_ref(),
            uv_mesh,
        };
        add_instance_patches(c, loc, &instance, into.patches);
        // The primitives of one node's mesh share its lightmap space.
        if let (Some(uvs), Some(k)) = (&inst.lightmap_uvs, uv_mesh) {
            add_own_uv_triangles(
                &mut into.uv_meshes[k],
                own_normals.entry(k).or_default(),
                inst,
                uvs,
            );
        }
    }
    for (k, normals) in own_normals {
        let m = &mut into.uv_meshes[k];
        m.smooth_edges = crate::unwrap::smooth_edges(&m.triangles, &normals);
    }
}

/// Adds an import's materials to the scene's. A name already taken must
/// have the same albedo and emission, and the material is then shared.
/// Returns each imported material's index in the scene.
fn merge_materials(
    c: &mut Checker,
    loc: &str,
    imported: &ImportedScene,
    materials: &mut Vec<Material>,
) -> Vec<u32> {
    let mut material_ids = Vec::with_capacity(imported.materials.len());
    for m in &imported.materials {
        let id = match materials.iter().position(|x| x.name == m.name) {
            Some(k) => {
                let x = &materials[k];
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
                materials.push(Material {
                    name: m.name.clone(),
                    albedo: m.albedo,
                    emission: m.emission,
                });
                materials.len() - 1
            }
        };
        material_ids.push(id as u32);
    }
    material_ids
}

/// Adds an import's dynamic objects to the scene's; their names must be
/// new. Returns each imported object's index in the scene (its static
/// world is the scene's).
fn merge_objects(
    c: &mut Checker,
    loc: &str,
    imported: &ImportedScene,
    objects: &mut Vec<Object>,
) -> Vec<u32> {
    let mut object_ids = Vec::with_capacity(imported.objects.len());
    for (k, o) in imported.objects.iter().enumerate() {
        if k == 0 {
            object_ids.push(crate::STATIC_OBJECT);
            continue;
        }
        if objects.iter().any(|x| x.name == o.name) {
            c.report(
                loc,
                format!(
                    "dynamic node \"{}\" has the name of an object that already exists; object names must be unique",
                    o.name
                ),
            );
        }
        objects.push(Object {
            name: o.name.clone(),
            dynamic: true,
            initial_pose: o.pose,
        });
        object_ids.push((objects.len() - 1) as u32);
    }
    object_ids
}

/// One imported instance on its way into the scene: what all its
/// triangles' patches share.
struct Instance<'a> {
    inst: &'a MeshInstance,
    node: &'a str,
    mesh: &'a str,
    surface_index: usize,
    object: u32,
    material: u32,
    density: f32,
    /// Its base colour texture and the coordinates that texture reads.
    texture: Option<(Arc<Texture>, &'a [Vec2])>,
    /// Its generated lightmap UVs: the [`UvMesh`] and, per triangle in
    /// index order, the UVs ([`generate_import_uvs`]).
    generated: Option<&'a (usize, Vec<[Vec2; 3]>)>,
    /// The [`UvMesh`] of its own lightmap UVs.
    uv_mesh: Option<usize>,
}

/// An instance's base colour texture and the coordinates it reads, when
/// its material has one.
fn base_color<'a>(
    imported: &ImportedScene,
    inst: &'a MeshInstance,
) -> Option<(Arc<Texture>, &'a [Vec2])> {
    // The importer has checked that a textured primitive has the
    // coordinates its texture reads.
    imported
        .materials
        .get(inst.material as usize)
        .and_then(|m| {
            let set = m.base_color_texture.as_ref()?.tex_coord;
            Some((m.texture.clone()?, inst.uvs(set)?))
        })
}

/// Adds a patch per triangle of an instance to `patches`, with the base
/// colour texture's coordinates and the lightmap UVs at its corners.
/// Reports a triangle that indexes past the positions, and stops there.
fn add_instance_patches(c: &mut Checker, loc: &str, at: &Instance, patches: &mut Vec<Patch>) {
    let (inst, node, mesh) = (at.inst, at.node, at.mesh);
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
        let albedo_map = at.texture.as_ref().and_then(|(texture, uvs)| {
            let uv = order.map(|j| uvs.get(tri[j] as usize).copied());
            Some(AlbedoMap {
                texture: Arc::clone(texture),
                uv: [uv[0]?, uv[1]?, uv[2]?],
            })
        });
        // Its lightmap UVs, generated or its own, in the same order.
        let lightmap = match at.generated {
            Some((m, uvs)) => uvs.get(k).map(|uv| PatchLightmap {
                mesh: *m as u32,
                uv: order.map(|j| uv[j]),
            }),
            None => at
                .uv_mesh
                .zip(inst.lightmap_uvs.as_ref())
                .and_then(|(m, uvs)| {
                    let uv = order.map(|j| uvs.get(tri[j] as usize).copied());
                    Some(PatchLightmap {
                        mesh: m as u32,
                        uv: [uv[0]?, uv[1]?, uv[2]?],
                    })
                }),
        };
        patches.push(Patch {
            name: format!(
                "{node}/{mesh}/{}/{}",
                inst.primitive,
                inst.triangle_numbers.get(k).copied().unwrap_or(k as u32)
            ),
            surface_index: at.surface_index,
            object: at.object,
            material: at.material,
            texel_density: at.density,
            shape: PatchShape::triangle(a, b, d),
            albedo_map,
            mesh: true,
            cells: [1, 1],
            lightmap,
        });
    }
}

/// Appends an instance's triangles, with their lightmap UVs `uvs`, to the
/// [`UvMesh`] `m` of its own UVs, and their vertex normals to `normals`.
fn add_own_uv_triangles(
    m: &mut UvMesh,
    normals: &mut Vec<Option<[Vec3; 3]>>,
    inst: &MeshInstance,
    uvs: &[Vec2],
) {
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

/// Triangle `tri`'s vertex normals of `inst`, corner by corner, if it has
/// them.
fn corner_normals(inst: &MeshInstance, tri: &[u32; 3]) -> Option<[Vec3; 3]> {
    let n = inst.normals.as_ref()?;
    let [a, b, c] = tri.map(|i| n.get(i as usize).copied());
    Some([a?, b?, c?])
}

/// An instance's node and mesh names, or `node#i`, `mesh#j` when the glTF
/// has none.
fn names(inst: &MeshInstance) -> (String, String) {
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

/// Generated lightmap UVs for the static meshes of an import that
/// [`generates_uvs`] picks: one [`UvMesh`] per node's mesh (its primitives
/// share it), pushed onto `uv_meshes`; per instance, that mesh's index and
/// the instance's triangles' UVs in their index order.
fn generate_import_uvs(
    (c, loc): (&mut Checker, &str),
    imported: &ImportedScene,
    object_ids: &[u32],
    charts: Charts,
    (density, detail, lights): (f32, f32, &[Light]),
    surface_index: usize,
    uv_meshes: &mut Vec<UvMesh>,
) -> Vec<Option<(usize, Vec<[Vec2; 3]>)>> {
    let mut out = vec![None; imported.instances.len()];
    // The import's emitting triangles (static ones in world space): near
    // them texels are refined as near a point light (`near_lights.rs`).
    let emitters: Vec<[Vec3; 3]> = imported
        .instances
        .iter()
        .filter(|inst| {
            object_ids.get(inst.object as usize) == Some(&super::super::STATIC_OBJECT)
                && imported
                    .materials
                    .get(inst.material as usize)
                    .is_some_and(|m| m.emission.max_element() > 0.0)
        })
        .flat_map(|inst| {
            inst.indices.iter().filter_map(|tri| {
                let [a, b, d] = tri.map(|i| inst.positions.get(i as usize).copied());
                Some([a?, b?, d?])
            })
        })
        .collect();
    // Per material, the first material that reflects as it does (the same
    // albedo and emission, neither textured): charts keep them apart only
    // where the light leaving them differs (`Scene::reflects_alike`).
    let alike: Vec<u32> = (0..imported.materials.len())
        .map(|m| {
            let a = &imported.materials[m];
            imported.materials[..m]
                .iter()
                .position(|b| {
                    a.texture.is_none()
                        && b.texture.is_none()
                        && a.albedo == b.albedo
                        && a.emission == b.emission
                })
                .unwrap_or(m) as u32
        })
        .collect();
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
        let mut materials = Vec::new();
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
                    materials.push(
                        alike
                            .get(inst.material as usize)
                            .copied()
                            .unwrap_or(inst.material),
                    );
                }
            }
            ranges.push(start..triangles.len());
        }
        let first = &imported.instances[members[0]];
        // Static triangles are in world space, as the lights are; the
        // mesh's emitting triangles count as lights.
        // (The `uvunwrap` crate's charts take no levels: none are cast.)
        let detail = if charts.unwrapper() == crate::unwrap::Unwrapper::Projected {
            detail
        } else {
            0.0
        };
        let refined =
            crate::near_lights::budgeted_levels(&triangles, density, (lights, &emitters), detail);
        if refined.detail < detail || refined.shadow_level < crate::near_lights::SHADOW_LEVEL {
            let (node, mesh) = names(first);
            c.warn(
                loc,
                format!(
                    "mesh \"{node}/{mesh}\": texels near its lights and sun shadow edges would add more than {:.0}% texels; light_detail lowered to {:.2}, shadow edges at {}x the density",
                    100.0 * crate::near_lights::MAX_EXTRA,
                    refined.detail,
                    1u32 << refined.shadow_level
                ),
            );
        }
        let levels = refined.levels;
        // A chart holds one material: a texel's radiosity has its albedo in it.
        let unwrap = crate::unwrap::unwrap_graded(
            &triangles,
            density,
            charts.unwrapper(),
            (&levels, &materials),
        );
        let packed_side = super::refined_side(&unwrap, &levels);
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
            smooth_edges: crate::unwrap::smooth_edges(&triangles, &normals),
            triangles,
            uvs: unwrap.uvs,
            generated: true,
            charts: unwrap.charts,
            packed_side,
        });
    }
    out
}
