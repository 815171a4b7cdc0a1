// Required by every other file in shaders/: the shooter record, the batch
// constants, patch ranges, object flags and the hemicube face projection.
// Rasterization (hemicube.wgsl) and the lookup in the reconstruction
// shaders (`visibility` in receive.wgsl) must use the very same
// projection, so it lives here once.

// One shooter: a rectangle of elements of the shooting patch (thesis §4.3.3,
// dynamic shooter subdivision). Mirrors `GpuShooter` in server/src/gpu/progressive/shooters.rs
// (sizes checked by the tests of server/src/gpu/shaders.rs).
struct Shooter {
    // xyz: corner of the shooter's region (world), w: its area (m²).
    corner: vec4<f32>,
    // Edge vectors of the region (world); su.w: cross redistribution's
    // gather_moving takes the bitcast chart width of the shooter's patch.
    su: vec4<f32>,
    sv: vec4<f32>,
    // xyz: hemicube eye (region centre lifted off the surface); w: for
    // gather_moving, the bitcast first element of the shooter's patch.
    eye: vec4<f32>,
    // Orthonormal frame of the hemicube: two tangents and the normal;
    // n.w is the bitcast id of the shooting patch.
    t1: vec4<f32>,
    t2: vec4<f32>,
    n: vec4<f32>,
    // Element tile in chart texels: a0, b0, a1, b1 (half-open).
    tile: vec4<u32>,
};

// Per-batch constants. Mirrors `BatchUniform` in server/src/gpu/progressive/shoot.rs.
struct Batch {
    patch_id: u32,
    shooters: u32,
    resolution: u32,
    first_element: u32,
    chart_w: u32,
    element_count: u32,
    near: f32,
    far: f32,
    // Form-factor subdivision: sub-disks per axis = ceil(subdivision * sqrt(A_s) / r).
    subdivision: f32,
    max_subdivision: u32,
    // Item-buffer slots at or after this one were rendered with the old
    // poses (the scene before a move); earlier slots with the current ones.
    // Progressive batches set it past the last slot.
    old_from_slot: u32,
    // What a redistribution batch does (KIND_* and flags in
    // redistribute.wgsl); 0 in progressive batches.
    mode: u32,
};

// A patch's elements: first element, element count, chart width, chart height.
struct PatchRange {
    first: u32,
    count: u32,
    w: u32,
    h: u32,
};

// Bits of `object_flags`, one word per scene object.
// MOVING: the object is in the moved set M of the running redistribution.
const OBJECT_MOVING: u32 = 1u;
// ABSENT: the object is removed from the simulation (thesis §4.5.2): it is
// not rasterized, does not receive and does not shoot.
const OBJECT_ABSENT: u32 = 2u;


// Right, up and forward axes of hemicube face `face` (0 = top, along the
// normal; 1..4 = the four sides).
fn face_axes(s: Shooter, face: u32) -> mat3x3<f32> {
    let t1 = s.t1.xyz;
    let t2 = s.t2.xyz;
    let n = s.n.xyz;
    switch face {
        case 0u: { return mat3x3<f32>(t1, t2, n); }
        case 1u: { return mat3x3<f32>(t2, n, t1); }
        case 2u: { return mat3x3<f32>(-t2, n, -t1); }
        case 3u: { return mat3x3<f32>(-t1, n, t2); }
        default: { return mat3x3<f32>(t1, n, -t2); }
    }
}

// The hemicube face of shooter `s` that world direction `d` from its eye
// falls on (0 = top, 1..4 = sides; see `face_axes`).
fn face_of(s: Shooter, d: vec3<f32>) -> u32 {
    let x = dot(d, s.t1.xyz);
    let y = dot(d, s.t2.xyz);
    let z = dot(d, s.n.xyz);
    if (z >= max(abs(x), abs(y))) {
        return 0u;
    }
    if (abs(x) >= abs(y)) {
        return select(2u, 1u, x > 0.0);
    }
    return select(4u, 3u, y > 0.0);
}

// Eye-space coordinates (right, up, forward) of world direction `d` in `face`.
fn face_local(s: Shooter, face: u32, d: vec3<f32>) -> vec3<f32> {
    let m = face_axes(s, face);
    return vec3<f32>(dot(d, m[0]), dot(d, m[1]), dot(d, m[2]));
}
