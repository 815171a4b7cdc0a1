// Hemicube item buffers (thesis §4.3.2): every patch rasterized as its id
// into one face viewport of one shooter. The instance index selects the
// (shooter slot, face) pair: instance = slot * 5 + face. Depth testing keeps
// the nearest surface; the colour target (R32Uint) keeps its patch id.

// Triangle corners, 3 per triangle: xyz world position, w = bitcast patch id.
@group(0) @binding(0) var<storage, read> triangles: array<vec4<f32>>;
@group(0) @binding(1) var<storage, read> shooters: array<Shooter>;
@group(0) @binding(2) var<uniform> batch: Batch;

struct VertexOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) @interpolate(flat) id: u32,
};

@vertex
fn vs_main(@builtin(vertex_index) vi: u32, @builtin(instance_index) ii: u32) -> VertexOut {
    let s = shooters[ii / 5u];
    let face = ii % 5u;
    let v = triangles[vi];
    let l = face_local(s, face, v.xyz - s.eye.xyz);
    // Perspective with a 90° frustum: x, y in [-w, w]; depth in [0, 1]
    // between near and far.
    let z = (l.z - batch.near) * batch.far / (batch.far - batch.near);
    var out: VertexOut;
    out.clip = vec4<f32>(l.x, l.y, z, l.z);
    out.id = bitcast<u32>(v.w);
    return out;
}

@fragment
fn fs_main(in: VertexOut) -> @location(0) u32 {
    return in.id;
}
