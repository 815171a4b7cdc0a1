// requires: common.wgsl
// Hemicubes rasterized at shooters (thesis §4.3.2). The instance index
// selects the (shooter slot, face) pair: instance = slot * 5 + face.
//
// Vertices are stored in object space and placed by their object's pose
// here, on the GPU: `poses` holds two sets of object matrices, the current
// poses and the old ones (the scene before a move); slots at or after
// `batch.old_from_slot` use the old set (thesis §4.4.2 renders a hemicube at
// the old and at the new position of each shooter). An object whose matrix
// is zero is absent: its triangles collapse to a point and draw nothing.
//
// Three kinds of target (the vertex entry points are in the draw layouts'
// files, hemicube_faces.wgsl and hemicube_rows.wgsl):
//   vs_main/fs_main  item buffers (R32Uint): the nearest patch id.
//   vs_rad/fs_back   the element seen and its distance from the eye
//                    (Rg32Uint), for the cross projection of thesis
//                    Alg. 4.5, which reads them once redistribute.wgsl's
//                    `shade_back` has turned them into shot radiosity.
//   vs_rad/fs_element  the element seen (R32Uint), for the moving tiles'
//                    gathering (thesis Alg. 4.4-4.5), which reads what
//                    each element shows from redistribute.wgsl's shown
//                    textures itself.

// One vertex of a patch's triangles (two for a quad, one for a triangle
// patch): xyz in object space, w = bitcast
// patch id; st.xy = the patch parameters (s, t) of the corner, st.z =
// bitcast object id.
struct Vertex {
    pos: vec4<f32>,
    st: vec4<f32>,
};

@group(0) @binding(0) var<storage, read> vertices: array<Vertex>;
@group(0) @binding(1) var<uniform> shooters: array<Shooter, MAX_BATCH>;
@group(0) @binding(2) var<uniform> batch: Batch;
@group(0) @binding(3) var<storage, read> poses: array<mat4x4<f32>>;
@group(0) @binding(6) var<storage, read> patches: array<PatchRange>;

fn world_position(v: Vertex, slot: u32) -> vec3<f32> {
    let objects = arrayLength(&poses) / 2u;
    let base = select(0u, objects, slot >= batch.old_from_slot);
    let m = poses[base + bitcast<u32>(v.st.z)];
    return (m * vec4<f32>(v.pos.xyz, 1.0)).xyz;
}

// Perspective with a 90° frustum: x, y in [-w, w]; depth in [0, 1] between
// near and far.
fn project(s: Shooter, face: u32, p: vec3<f32>) -> vec4<f32> {
    let l = face_local(s, face, p - s.eye.xyz);
    let z = (l.z - batch.near) * batch.far / (batch.far - batch.near);
    return vec4<f32>(l.x, l.y, z, l.z);
}

// What a hemicube vertex carries to the rasterizer. The entry points that
// place it in the target live in the files of the two draw layouts
// (gpu/hemicube.rs `Draws`): hemicube_faces.wgsl (a viewport per face) and
// hemicube_rows.wgsl (every face in one draw, clipped by clip distances).
// Fragments read these at the same locations in both.
struct ItemVertex {
    clip: vec4<f32>,
    id: u32,
};

// Vertex `vi` of instance `ii = slot * 5 + face`, projected into its face
// (x, y in [-w, w]) with the patch id.
fn item_vertex(vi: u32, ii: u32) -> ItemVertex {
    let slot = ii / 5u;
    let v = vertices[vi];
    let clip = project(shooters[slot], ii % 5u, world_position(v, slot));
    return ItemVertex(clip, bitcast<u32>(v.pos.w));
}

struct ItemFragment {
    @location(0) @interpolate(flat) id: u32,
};

@fragment
fn fs_main(in: ItemFragment) -> @location(0) u32 {
    return in.id;
}

// `chart`: the vertex's patch's first element, chart width and height and
// triangle flag (its `PatchRange`, read once per vertex, not per fragment).
struct RadVertex {
    clip: vec4<f32>,
    chart: vec4<u32>,
    st: vec2<f32>,
    offset: vec3<f32>,
};

fn rad_vertex(vi: u32, ii: u32) -> RadVertex {
    let slot = ii / 5u;
    let s = shooters[slot];
    let v = vertices[vi];
    let p = world_position(v, slot);
    let r = patches[bitcast<u32>(v.pos.w)];
    return RadVertex(
        project(s, ii % 5u, p),
        vec4<u32>(r.first, r.w, r.h, r.triangle),
        v.st.xy,
        p - s.eye.xyz,
    );
}

struct RadFragment {
    @location(0) @interpolate(flat) chart: vec4<u32>,
    @location(2) st: vec2<f32>,
    @location(3) offset: vec3<f32>,
};

// The element each pixel sees and its distance from the eye (Rg32Uint,
// the distance bitcast; the clear's NO_PATCH and 0 where nothing is): a
// back hemicube of cross redistribution. The back pass binds `poses` with
// the moving objects' matrices zero (gpu/progressive/redistribute/cross.rs
// `back_poses`), so it sees the static surfaces behind them; what they
// show is looked up per pixel (redistribute.wgsl `shade_back`), so the
// drawing at a tile's new pose serves again at its old pose in the next
// move, when their light has changed.
@fragment
fn fs_back(in: RadFragment) -> @location(0) vec2<u32> {
    let e = element_in_chart(in.chart.x, in.chart.y, in.chart.z, in.chart.w, in.st);
    return vec2<u32>(e, bitcast<u32>(length(in.offset)));
}

// The element each pixel sees (R32Uint, the clear's NO_PATCH where
// nothing is): a moving tile's gathering hemicube. The gather reads each
// pixel's light from the shown textures (redistribute.wgsl
// `front_irradiance`), so one drawing serves the gather in the move and the
// one after it (`regather_moving`), which read different shown values.
@fragment
fn fs_element(in: RadFragment) -> @location(0) u32 {
    return element_in_chart(in.chart.x, in.chart.y, in.chart.z, in.chart.w, in.st);
}

// Clearing the slots a pass draws (gpu/hemicube.rs `encode`): a render
// pass keeps what its targets held (a clear at the pass's start would
// clear all of them, every slot the target can hold, which on a software
// rasterizer costs as much as drawing), and this triangle, drawn over the
// viewport and scissor of the slots in use, writes the far depth and
// "nothing" there first.
@vertex
fn vs_clear(@builtin(vertex_index) vi: u32) -> @builtin(position) vec4<f32> {
    let corner = vec2<f32>(f32((vi << 1u) & 2u), f32(vi & 2u));
    return vec4<f32>(corner * 2.0 - 1.0, 1.0, 1.0);
}

@fragment
fn fs_clear_items() -> @location(0) u32 {
    return NO_PATCH;
}

@fragment
fn fs_clear_back() -> @location(0) vec2<u32> {
    return vec2<u32>(NO_PATCH, 0u);
}
