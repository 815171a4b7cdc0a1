//! Test content: triangle-mesh scenes generated here, never downloaded
//! (issue 18, item 7). `cargo run -p lightwire-scene --example make_meshes`
//! writes them to `scenes/meshes/`; a test regenerates them and compares the
//! bytes, so the committed files always match this code.
//!
//! Every mesh gets its own lightmap space: `TEXCOORD_1` charts laid out in
//! [0, 1]² without overlaps (except the furnace sphere, which has none on
//! purpose, for chart generation).

use glam::{Quat, Vec2, Vec3};

use super::write::{GlbImage, GlbMaterial, GlbMesh, GlbNode, GlbPrimitive, GlbScene, WriteError};

/// Makes one scene.
pub type Generator = fn() -> GlbScene;

/// File name and generator of every committed mesh scene.
pub const FILES: [(&str, Generator); 4] = [
    ("cornell-large.glb", cornell_large),
    ("cornell-dynamic.glb", cornell_dynamic),
    ("furnace-sphere.glb", furnace_sphere),
    ("atrium.glb", atrium),
];

/// All files as (name, bytes).
pub fn generate_all() -> Result<Vec<(&'static str, Vec<u8>)>, WriteError> {
    FILES
        .iter()
        .map(|(name, make)| Ok((*name, make().to_glb()?)))
        .collect()
}

fn material(name: &str, albedo: [f32; 3], emission: [f32; 3]) -> GlbMaterial {
    GlbMaterial {
        name: name.to_string(),
        base_color: Vec3::from(albedo),
        emission: Vec3::from(emission),
        base_color_texture: None,
    }
}

/// A chart rectangle in lightmap UV space: [u0, u1] × [v0, v1].
#[derive(Clone, Copy)]
struct Chart {
    u0: f32,
    v0: f32,
    u1: f32,
    v1: f32,
}

impl Chart {
    const FULL: Chart = Chart {
        u0: 0.0,
        v0: 0.0,
        u1: 1.0,
        v1: 1.0,
    };

    fn at(&self, s: f32, t: f32) -> Vec2 {
        Vec2::new(
            self.u0 + s * (self.u1 - self.u0),
            self.v0 + t * (self.v1 - self.v0),
        )
    }

    /// Cell (i, j) of an `nx × ny` grid of charts over [0, 1]², shrunk by
    /// `pad` on every side.
    fn cell(i: usize, j: usize, nx: usize, ny: usize, pad: f32) -> Chart {
        Chart {
            u0: i as f32 / nx as f32 + pad,
            v0: j as f32 / ny as f32 + pad,
            u1: (i + 1) as f32 / nx as f32 - pad,
            v1: (j + 1) as f32 / ny as f32 - pad,
        }
    }
}

/// Appends a parallelogram `origin + s·u + t·v`, s, t ∈ [0, 1], split into
/// `nu × nv` cells of two triangles each, facing `u × v`; TEXCOORD_1 maps it
/// onto `chart`, TEXCOORD_0 is `uv0_scale × (s·|u|, t·|v|)` (metres).
#[allow(clippy::too_many_arguments)] // a private generator helper; every call names its cells
fn grid(
    p: &mut GlbPrimitive,
    origin: Vec3,
    u: Vec3,
    v: Vec3,
    nu: usize,
    nv: usize,
    chart: Chart,
    uv0_scale: f32,
) {
    let normal = u.cross(v).normalize();
    let base = p.positions.len() as u32;
    for j in 0..=nv {
        for i in 0..=nu {
            let (s, t) = (i as f32 / nu as f32, j as f32 / nv as f32);
            p.positions.push(origin + u * s + v * t);
            if let Some(n) = &mut p.normals {
                n.push(normal);
            }
            if let Some(uv) = &mut p.uv0 {
                uv.push(Vec2::new(s * u.length(), t * v.length()) * uv0_scale);
            }
            if let Some(uv) = &mut p.uv1 {
                uv.push(chart.at(s, t));
            }
        }
    }
    let row = nu as u32 + 1;
    for j in 0..nv as u32 {
        for i in 0..nu as u32 {
            let a = base + j * row + i;
            let (b, c, d) = (a + 1, a + row + 1, a + row);
            p.indices.push([a, b, c]);
            p.indices.push([a, c, d]);
        }
    }
}

fn primitive(material: usize, uv0: bool, uv1: bool) -> GlbPrimitive {
    GlbPrimitive {
        positions: Vec::new(),
        normals: Some(Vec::new()),
        uv0: uv0.then(Vec::new),
        uv1: uv1.then(Vec::new),
        indices: Vec::new(),
        material: Some(material),
    }
}

/// One quad as a mesh of `k` x `k` cells of two triangles, TEXCOORD_1 over
/// all of [0, 1]².
fn quad_mesh(
    name: &str,
    material: usize,
    (origin, u, v): ([f32; 3], [f32; 3], [f32; 3]),
    k: usize,
) -> GlbMesh {
    let mut p = primitive(material, true, true);
    grid(
        &mut p,
        origin.into(),
        u.into(),
        v.into(),
        k,
        k,
        Chart::FULL,
        1.0,
    );
    GlbMesh {
        name: name.to_string(),
        primitives: vec![p],
    }
}

/// An axis-aligned box centred at the origin, faces outward, each face `k`
/// x `k` cells of two triangles; the six faces' charts are a 3 × 2 grid
/// with 1/64 padding.
fn box_mesh(name: &str, material: usize, size: Vec3, k: usize) -> GlbMesh {
    let h = size * 0.5;
    // (origin, u, v) with u × v outward, as scene/validate.rs expands boxes.
    let faces = [
        (
            Vec3::new(h.x, -h.y, h.z),
            Vec3::new(0.0, 0.0, -size.z),
            Vec3::new(0.0, size.y, 0.0),
        ),
        (
            Vec3::new(-h.x, -h.y, -h.z),
            Vec3::new(0.0, 0.0, size.z),
            Vec3::new(0.0, size.y, 0.0),
        ),
        (
            Vec3::new(-h.x, h.y, h.z),
            Vec3::new(size.x, 0.0, 0.0),
            Vec3::new(0.0, 0.0, -size.z),
        ),
        (
            Vec3::new(-h.x, -h.y, -h.z),
            Vec3::new(size.x, 0.0, 0.0),
            Vec3::new(0.0, 0.0, size.z),
        ),
        (
            Vec3::new(-h.x, -h.y, h.z),
            Vec3::new(size.x, 0.0, 0.0),
            Vec3::new(0.0, size.y, 0.0),
        ),
        (
            Vec3::new(h.x, -h.y, -h.z),
            Vec3::new(-size.x, 0.0, 0.0),
            Vec3::new(0.0, size.y, 0.0),
        ),
    ];
    let cells = k;
    let mut p = primitive(material, true, true);
    for (k, (o, u, v)) in faces.into_iter().enumerate() {
        grid(
            &mut p,
            o,
            u,
            v,
            cells,
            cells,
            Chart::cell(k % 3, k / 3, 3, 2, 1.0 / 64.0),
            1.0,
        );
    }
    GlbMesh {
        name: name.to_string(),
        primitives: vec![p],
    }
}

/// `scenes/cornell-large.json` with every quad as two triangles: the same
/// materials, dimensions and light; the box is a static mesh at the JSON
/// scene's initial pose. 24 triangles.
pub fn cornell_large() -> GlbScene {
    cornell(false)
}

/// As [`cornell_large`], but the box is a dynamic object (node `box`, marked
/// in its extras) turned 20° about y. 24 triangles.
pub fn cornell_dynamic() -> GlbScene {
    cornell(true)
}

/// [`cornell_large`] with every quad (walls, light, box faces) cut into a
/// `k` x `k` grid of cells, two triangles each: `24 k²` triangles, for
/// benchmarks at a chosen triangle count (`lightwire bench meshes`).
pub fn cornell_tessellated(k: usize) -> GlbScene {
    cornell_with(false, k.max(1))
}

fn cornell(dynamic: bool) -> GlbScene {
    cornell_with(dynamic, 1)
}

fn cornell_with(dynamic: bool, k: usize) -> GlbScene {
    let materials = vec![
        material("white", [0.73, 0.73, 0.73], [0.0; 3]),
        material("red", [0.63, 0.065, 0.05], [0.0; 3]),
        material("green", [0.14, 0.45, 0.09], [0.0; 3]),
        material("light", [0.78, 0.78, 0.78], [16.0, 16.0, 16.0]),
    ];
    // Surfaces exactly as in scenes/cornell-large.json.
    let meshes = vec![
        quad_mesh(
            "floor",
            0,
            ([0.0, 0.0, 0.0], [0.0, 0.0, 5.592], [5.56, 0.0, 0.0]),
            k,
        ),
        quad_mesh(
            "ceiling",
            0,
            ([0.0, 5.488, 0.0], [5.56, 0.0, 0.0], [0.0, 0.0, 5.592]),
            k,
        ),
        quad_mesh(
            "back",
            0,
            ([0.0, 0.0, 0.0], [5.56, 0.0, 0.0], [0.0, 5.488, 0.0]),
            k,
        ),
        quad_mesh(
            "left",
            1,
            ([0.0, 0.0, 0.0], [0.0, 5.488, 0.0], [0.0, 0.0, 5.592]),
            k,
        ),
        quad_mesh(
            "right",
            2,
            ([5.56, 0.0, 0.0], [0.0, 0.0, 5.592], [0.0, 5.488, 0.0]),
            k,
        ),
        quad_mesh(
            "light",
            3,
            ([1.53, 5.478, 1.546], [2.5, 0.0, 0.0], [0.0, 0.0, 2.5]),
            k,
        ),
        box_mesh("box", 0, Vec3::new(1.6, 1.7, 1.6), k),
    ];
    let mut nodes: Vec<GlbNode> = meshes
        .iter()
        .enumerate()
        .map(|(i, m)| GlbNode::new(m.name.clone(), Some(i)))
        .collect();
    let b = &mut nodes[6];
    b.translation = Vec3::new(2.78, 0.85, 2.796);
    if dynamic {
        b.rotation = Quat::from_rotation_y(20f32.to_radians());
        b.extras = Some(serde_json::json!({ "lightwire": { "dynamic": true } }));
    }
    GlbScene {
        materials,
        images: Vec::new(),
        meshes,
        roots: (0..nodes.len()).collect(),
        nodes,
    }
}

/// Segments of the furnace sphere around the equator and from pole to pole.
pub const SPHERE_SEGMENTS: (usize, usize) = (32, 16);

/// A closed UV sphere (radius 0.5 m, centre at the origin) seen from inside:
/// triangles face the centre. Material as `scenes/furnace.json` (albedo 0.5,
/// emission 1 W/m²), so converged radiosity is E/(1−ρ) = 2 W/m² everywhere.
/// Vertices are shared across the seam and at the poles (watertight), and
/// there is no TEXCOORD_1: charts must be generated.
/// 2·32 + 2·32·14 = 960 triangles.
pub fn furnace_sphere() -> GlbScene {
    let (nu, nv) = SPHERE_SEGMENTS;
    let r = 0.5f32;
    let mut positions = vec![Vec3::new(0.0, r, 0.0)];
    for j in 1..nv {
        let theta = std::f32::consts::PI * j as f32 / nv as f32;
        for i in 0..nu {
            let phi = std::f32::consts::TAU * i as f32 / nu as f32;
            positions.push(
                Vec3::new(
                    theta.sin() * phi.cos(),
                    theta.cos(),
                    theta.sin() * phi.sin(),
                ) * r,
            );
        }
    }
    positions.push(Vec3::new(0.0, -r, 0.0));
    let south = positions.len() as u32 - 1;
    let ring = |j: usize, i: usize| (1 + (j - 1) * nu + i % nu) as u32;
    let mut indices = Vec::new();
    // Outward-facing winding would be (a, b, c) counter-clockwise seen from
    // outside; each triangle below is listed clockwise from outside, so it
    // faces the centre.
    for i in 0..nu {
        indices.push([0, ring(1, i), ring(1, i + 1)]);
        indices.push([south, ring(nv - 1, i + 1), ring(nv - 1, i)]);
    }
    for j in 1..nv - 1 {
        for i in 0..nu {
            let (a, b) = (ring(j, i), ring(j, i + 1));
            let (c, d) = (ring(j + 1, i + 1), ring(j + 1, i));
            indices.push([a, d, c]);
            indices.push([a, c, b]);
        }
    }
    let normals = positions.iter().map(|p| -p.normalize()).collect();
    GlbScene {
        materials: vec![material("grey-emitter", [0.5, 0.5, 0.5], [1.0, 1.0, 1.0])],
        images: Vec::new(),
        meshes: vec![GlbMesh {
            name: "sphere".to_string(),
            primitives: vec![GlbPrimitive {
                positions,
                normals: Some(normals),
                uv0: None,
                uv1: None,
                indices,
                material: Some(0),
            }],
        }],
        nodes: vec![GlbNode::new("sphere", Some(0))],
        roots: vec![0],
    }
}

/// An 8 × 8 checker of two greys as a PNG (the atrium floor's texture).
fn checker_png() -> Vec<u8> {
    let mut pixels = Vec::with_capacity(8 * 8 * 3);
    for y in 0..8 {
        for x in 0..8 {
            let v = if (x + y) % 2 == 0 { 230 } else { 90 };
            pixels.extend_from_slice(&[v, v, v]);
        }
    }
    let mut png = Vec::new();
    let encoder = image::codecs::png::PngEncoder::new(&mut png);
    // Writing 192 bytes of RGB8 into memory cannot fail.
    if let Err(e) =
        image::ImageEncoder::write_image(encoder, &pixels, 8, 8, image::ExtendedColorType::Rgb8)
    {
        tracing::error!("checker PNG: {e}");
    }
    png
}

/// Atrium dimensions: a 20 × 20 m hall, 9 m high, centred on the origin.
const HALL: f32 = 20.0;
const HEIGHT: f32 = 9.0;
/// Columns: radius, height, sides, rings.
const COLUMN: (f32, f32, usize, usize) = (0.4, 6.0, 12, 4);
/// Column x positions; two rows at z = ±4 m.
const COLUMN_X: [f32; 4] = [-6.0, -2.0, 2.0, 6.0];
const COLUMN_Z: [f32; 2] = [-4.0, 4.0];

/// An atrium of a few thousand triangles: floor (checker texture on
/// TEXCOORD_0, 2 m squares), four walls, a ceiling with an emissive 4 × 4 m
/// panel just below it, eight columns (one mesh, instanced by eight nodes)
/// and six semicircular arches between them (one mesh, six nodes).
pub fn atrium() -> GlbScene {
    let materials = vec![
        GlbMaterial {
            base_color_texture: Some(0),
            ..material("floor", [0.8, 0.8, 0.8], [0.0; 3])
        },
        material("stone", [0.7, 0.68, 0.62], [0.0; 3]),
        material("ceiling", [0.75, 0.75, 0.75], [0.0; 3]),
        material("panel", [0.78, 0.78, 0.78], [20.0, 19.0, 17.0]),
    ];
    let mut meshes = Vec::new();
    let mut nodes = Vec::new();
    for mesh in hall() {
        nodes.push(GlbNode::new(mesh.name.clone(), Some(meshes.len())));
        meshes.push(mesh);
    }

    // Column mesh (local: base at the origin), instanced.
    let column_mesh = meshes.len();
    meshes.push(column());
    for (row, z) in COLUMN_Z.iter().enumerate() {
        for (k, x) in COLUMN_X.iter().enumerate() {
            let mut n = GlbNode::new(format!("column-{row}-{k}"), Some(column_mesh));
            n.translation = Vec3::new(*x, 0.0, *z);
            nodes.push(n);
        }
    }
    // Arch mesh (local: springs at x = ±2, y = 0), instanced between
    // neighbouring columns.
    let arch_mesh = meshes.len();
    meshes.push(arch());
    for (row, z) in COLUMN_Z.iter().enumerate() {
        for k in 0..COLUMN_X.len() - 1 {
            let mut n = GlbNode::new(format!("arch-{row}-{k}"), Some(arch_mesh));
            n.translation = Vec3::new(0.5 * (COLUMN_X[k] + COLUMN_X[k + 1]), COLUMN.1, *z);
            nodes.push(n);
        }
    }
    GlbScene {
        materials,
        images: vec![GlbImage {
            name: "checker".into(),
            png: checker_png(),
        }],
        meshes,
        roots: (0..nodes.len()).collect(),
        nodes,
    }
}

/// The atrium's hall, a mesh per surface: floor, ceiling, the four walls
/// and the light panel.
fn hall() -> Vec<GlbMesh> {
    let mut meshes = vec![hall_floor(), hall_ceiling()];
    meshes.extend(hall_walls());
    meshes.push(hall_panel());
    meshes
}

/// The hall's floor.
fn hall_floor() -> GlbMesh {
    let h = HALL / 2.0;
    // Floor: 20 × 20 cells, faces up; texture repeats every 2 m (8 texels).
    let mut floor = primitive(0, true, true);
    grid(
        &mut floor,
        Vec3::new(-h, 0.0, -h),
        Vec3::new(0.0, 0.0, HALL),
        Vec3::new(HALL, 0.0, 0.0),
        20,
        20,
        Chart::FULL,
        0.5,
    );
    GlbMesh {
        name: "floor".into(),
        primitives: vec![floor],
    }
}

/// The hall's ceiling.
fn hall_ceiling() -> GlbMesh {
    let h = HALL / 2.0;
    // Ceiling faces down.
    let mut ceiling = primitive(2, true, true);
    grid(
        &mut ceiling,
        Vec3::new(-h, HEIGHT, -h),
        Vec3::new(HALL, 0.0, 0.0),
        Vec3::new(0.0, 0.0, HALL),
        10,
        10,
        Chart::FULL,
        1.0,
    );
    GlbMesh {
        name: "ceiling".into(),
        primitives: vec![ceiling],
    }
}

/// The hall's four walls: north, east, south, west.
fn hall_walls() -> Vec<GlbMesh> {
    let h = HALL / 2.0;
    // Walls face into the hall.
    let up = Vec3::new(0.0, HEIGHT, 0.0);
    let walls = [
        (
            "wall-north",
            Vec3::new(-h, 0.0, -h),
            Vec3::new(HALL, 0.0, 0.0),
        ),
        (
            "wall-east",
            Vec3::new(h, 0.0, -h),
            Vec3::new(0.0, 0.0, HALL),
        ),
        (
            "wall-south",
            Vec3::new(h, 0.0, h),
            Vec3::new(-HALL, 0.0, 0.0),
        ),
        (
            "wall-west",
            Vec3::new(-h, 0.0, h),
            Vec3::new(0.0, 0.0, -HALL),
        ),
    ];
    walls
        .into_iter()
        .map(|(name, origin, u)| {
            let mut p = primitive(1, true, true);
            grid(&mut p, origin, u, up, 10, 4, Chart::FULL, 1.0);
            GlbMesh {
                name: name.into(),
                primitives: vec![p],
            }
        })
        .collect()
}

/// The hall's light panel.
fn hall_panel() -> GlbMesh {
    // Light panel, 5 cm below the ceiling, facing down.
    let mut panel = primitive(3, true, true);
    grid(
        &mut panel,
        Vec3::new(-2.0, HEIGHT - 0.05, -2.0),
        Vec3::new(4.0, 0.0, 0.0),
        Vec3::new(0.0, 0.0, 4.0),
        4,
        4,
        Chart::FULL,
        1.0,
    );
    GlbMesh {
        name: "panel".into(),
        primitives: vec![panel],
    }
}

/// A column: a `sides`-gon prism, `rings` rows high, with a top cap (the
/// floor closes the bottom); TEXCOORD_1 unrolls the side onto the lower
/// three quarters of [0, 1]² (one duplicated seam of vertices) and puts the
/// cap in the top quarter.
fn column() -> GlbMesh {
    let (r, height, sides, rings) = COLUMN;
    let mut p = primitive(1, false, true);
    let pad = 1.0 / 64.0;
    let chart = Chart {
        u0: pad,
        v0: pad,
        u1: 1.0 - pad,
        v1: 0.75 - pad,
    };
    for j in 0..=rings {
        for i in 0..=sides {
            let phi = std::f32::consts::TAU * i as f32 / sides as f32;
            let dir = Vec3::new(phi.cos(), 0.0, -phi.sin());
            p.positions
                .push(dir * r + Vec3::Y * (height * j as f32 / rings as f32));
            if let Some(n) = &mut p.normals {
                n.push(dir);
            }
            if let Some(uv) = &mut p.uv1 {
                uv.push(chart.at(i as f32 / sides as f32, j as f32 / rings as f32));
            }
        }
    }
    let row = sides as u32 + 1;
    for j in 0..rings as u32 {
        for i in 0..sides as u32 {
            let a = j * row + i;
            // Counter-clockwise seen from outside (normal `dir`).
            p.indices.push([a, a + 1, a + row + 1]);
            p.indices.push([a, a + row + 1, a + row]);
        }
    }
    // Top cap: a fan around the centre, facing up.
    let centre = p.positions.len() as u32;
    let cap = |phi: f32| Vec2::new(0.5 + 0.1 * phi.cos(), 0.875 + 0.1 * phi.sin());
    p.positions.push(Vec3::Y * height);
    if let Some(n) = &mut p.normals {
        n.push(Vec3::Y);
    }
    if let Some(uv) = &mut p.uv1 {
        uv.push(Vec2::new(0.5, 0.875));
    }
    for i in 0..sides {
        let phi = std::f32::consts::TAU * i as f32 / sides as f32;
        p.positions
            .push(Vec3::new(phi.cos() * r, height, -phi.sin() * r));
        if let Some(n) = &mut p.normals {
            n.push(Vec3::Y);
        }
        if let Some(uv) = &mut p.uv1 {
            uv.push(cap(phi));
        }
    }
    for i in 0..sides as u32 {
        // Rim points go counter-clockwise seen from above (φ increases
        // towards −z), so (centre, i, i + 1) faces up.
        p.indices
            .push([centre, centre + 1 + i, centre + 1 + (i + 1) % sides as u32]);
    }
    // glTF requires TEXCOORD_0 wherever TEXCOORD_1 is (attribute sets are
    // contiguous); the lightmap layout serves.
    p.uv0 = p.uv1.clone();
    GlbMesh {
        name: "column".into(),
        primitives: vec![p],
    }
}

/// Segments of an arch from one springing to the other.
const ARCH_SEGMENTS: usize = 16;

/// A semicircular arch in the xy plane, 0.8 m deep (z from −0.4 to 0.4),
/// intrados radius 1.6, extrados 2.0, springing at y = 0 (so the feet of two
/// neighbouring arches each cover half of a column top and touch at its
/// centre): the soffit (facing the centre), the back of the arch (facing
/// out), the two faces (±z) and the two feet (facing down). TEXCOORD_1: one
/// chart row per part.
fn arch() -> GlbMesh {
    let (ri, ro, d) = (1.6f32, 2.0f32, 0.4f32);
    let n = ARCH_SEGMENTS;
    let mut p = primitive(1, false, true);
    let pad = 1.0 / 128.0;
    let point = |r: f32, k: usize, z: f32| {
        let a = std::f32::consts::PI * k as f32 / n as f32;
        Vec3::new(r * a.cos(), r * a.sin(), z)
    };
    // Adds a strip of quads (k, k+1) with corners from `corner(k, side)`,
    // side 0/1 across the strip, facing `normal(k)`.
    let strip = |p: &mut GlbPrimitive,
                 chart: Chart,
                 corner: &dyn Fn(usize, usize) -> Vec3,
                 normal: &dyn Fn(usize) -> Vec3| {
        let base = p.positions.len() as u32;
        for k in 0..=n {
            for side in 0..2 {
                p.positions.push(corner(k, side));
                if let Some(ns) = &mut p.normals {
                    ns.push(normal(k));
                }
                if let Some(uv) = &mut p.uv1 {
                    uv.push(chart.at(k as f32 / n as f32, side as f32));
                }
            }
        }
        for k in 0..n as u32 {
            let (a, b) = (base + 2 * k, base + 2 * k + 1);
            let (c, e) = (a + 2, b + 2);
            // Quad a (k, 0), c (k+1, 0), e (k+1, 1), b (k, 1).
            p.indices.push([a, c, e]);
            p.indices.push([a, e, b]);
        }
    };
    let radial = |k: usize| {
        let a = std::f32::consts::PI * k as f32 / n as f32;
        Vec3::new(a.cos(), a.sin(), 0.0)
    };
    let row = |j: usize| Chart::cell(0, j, 1, 5, pad);
    // Soffit: faces the centre (−radial). Going k→k+1 along the arc and
    // side 0→1 from z = −d to z = +d, (arc tangent) × (+z) = +radial, so
    // swap the sides: side 0 at +d.
    strip(
        &mut p,
        row(0),
        &|k, s| point(ri, k, if s == 0 { d } else { -d }),
        &|k| -radial(k),
    );
    // Extrados: faces outward.
    strip(
        &mut p,
        row(1),
        &|k, s| point(ro, k, if s == 0 { -d } else { d }),
        &radial,
    );
    // Front (+z): side 0 outer, side 1 inner: tangent × (inner − outer) = +z.
    strip(
        &mut p,
        row(2),
        &|k, s| point(if s == 0 { ro } else { ri }, k, d),
        &|_| Vec3::Z,
    );
    // Back (−z).
    strip(
        &mut p,
        row(3),
        &|k, s| point(if s == 0 { ri } else { ro }, k, -d),
        &|_| Vec3::NEG_Z,
    );
    // Feet, facing down: the rectangles ±[ri, ro] × [−d, d] at y = 0.
    for (f, sign) in [(0usize, 1.0f32), (1, -1.0)] {
        let chart = Chart::cell(f, 4, 2, 5, pad);
        let base = p.positions.len() as u32;
        let corners = [
            Vec3::new(sign * ri, 0.0, -d),
            Vec3::new(sign * ro, 0.0, -d),
            Vec3::new(sign * ro, 0.0, d),
            Vec3::new(sign * ri, 0.0, d),
        ];
        let uvs = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)];
        for (c, (s, t)) in corners.iter().zip(uvs) {
            p.positions.push(*c);
            if let Some(ns) = &mut p.normals {
                ns.push(Vec3::NEG_Y);
            }
            if let Some(uv) = &mut p.uv1 {
                uv.push(chart.at(s, t));
            }
        }
        // (1,0,0) × (0,0,1) = (0,−1,0): counter-clockwise seen from below
        // for sign = +1; mirrored for sign = −1.
        if sign > 0.0 {
            p.indices.push([base, base + 1, base + 2]);
            p.indices.push([base, base + 2, base + 3]);
        } else {
            p.indices.push([base, base + 2, base + 1]);
            p.indices.push([base, base + 3, base + 2]);
        }
    }
    p.uv0 = p.uv1.clone();
    GlbMesh {
        name: "arch".into(),
        primitives: vec![p],
    }
}

/// Triangle counts of the generated scenes, as instanced (for tests and the
/// README).
pub fn expected_triangles(name: &str) -> Option<usize> {
    let (su, sv) = SPHERE_SEGMENTS;
    let column = 2 * COLUMN.2 * COLUMN.3 + COLUMN.2;
    let arch = 4 * 2 * ARCH_SEGMENTS + 4;
    match name {
        "cornell-large.glb" | "cornell-dynamic.glb" => Some(6 * 2 + 12),
        "furnace-sphere.glb" => Some(2 * su + 2 * su * (sv - 2)),
        "atrium.glb" => {
            Some(2 * 20 * 20 + 2 * 10 * 10 + 4 * 2 * 10 * 4 + 2 * 4 * 4 + 8 * column + 6 * arch)
        }
        _ => None,
    }
}
