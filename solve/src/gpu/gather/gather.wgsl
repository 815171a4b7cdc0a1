// requires: common.wgsl
// Gather radiosity (thesis §4.2, Alg. 4.1), with common.wgsl (for
// `Shooter`, `PatchRange` and the hemicube face frames of `face_local`).
// One pass of a bounce gathers for a batch of elements; its entry points run
// in this order:
//   vs_gather/fs_gather  "Render all B_j to a hemicube placed on patch i":
//                        the current radiosity of every surface, rasterized
//                        into one large target holding a tile per element
//                        (the top face and the upper halves of the four side
//                        faces; the CPU sets a viewport per face).
//   gather_main          "Multiply the hemicube with the precomputed delta
//                        form factors, integrate it, store the result in
//                        B_i": one workgroup per element, a parallel
//                        reduction (thesis §4.2, "Integration").
//   total_change         after the last pass of a bounce: the power the
//                        bounce changed, Σ A_i |ΔB_i|, for the convergence
//                        test.
// Bounces are Jacobi sweeps: every pass of a bounce reads `radiosity` (the
// previous bounce) and writes `updated`; the CPU swaps the two afterwards.
// Both hold the reflected radiosity R = B - E, not B: that is what the
// hemicubes show, so a fragment reads one value and no emission; the CPU
// adds E back where it reads B (gather/mod.rs).

// One patch corner in world space. Mirrors `GatherVertex` in
// solve/src/gpu/gather/resources.rs.
struct GatherVertex {
    // xyz: world position, w: bitcast patch id.
    pos: vec4<f32>,
    // xyz: the patch's unit normal (the side its radiosity leaves from).
    normal: vec4<f32>,
    // xy: patch parameters (s, t) of the corner.
    st: vec4<f32>,
};

// Constants of one pass. Mirrors `GatherParams` in gather/resources.rs.
struct GatherParams {
    // First element of the pass; the pass gathers for `count` elements.
    first: u32,
    count: u32,
    // Top-face resolution in pixels (even); a tile is 3 res x res pixels.
    resolution: u32,
    // Tiles per row of the target.
    columns: u32,
    element_count: u32,
    // Near plane distance (reversed depth: depth = near / distance).
    near: f32,
    pad0: u32,
    pad1: u32,
};

// What an element adds to what it gathers. Mirrors `GatherElement`.
struct GatherElement {
    // rgb: self-emitted radiosity E, w: world area (m²).
    emission: vec4<f32>,
    // rgb: albedo ρ.
    albedo: vec4<f32>,
    // rgb: irradiance D from the emission of the emitters, integrated on
    // the CPU by next-event estimation (server/src/direct.rs).
    direct: vec4<f32>,
};

@group(0) @binding(0) var<storage, read> vertices: array<GatherVertex>;
// The receiving frame of every element, as a `Shooter` record: eye = the
// receiving point, t1/t2/n = the hemicube frame (other fields unused).
@group(0) @binding(1) var<storage, read> receivers: array<Shooter>;
@group(0) @binding(2) var<uniform> params: GatherParams;
// R = B - E of the previous bounce (read) and of this one (written).
@group(0) @binding(3) var<storage, read> radiosity: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> patches: array<PatchRange>;
@group(0) @binding(5) var<storage, read_write> updated: array<vec4<f32>>;
@group(0) @binding(6) var hemicubes: texture_2d<f32>;
// Delta form factors of one tile, row-major over its 3 res x res pixels.
@group(0) @binding(7) var<storage, read> multipliers: array<f32>;
@group(0) @binding(8) var<storage, read> elements: array<GatherElement>;
// Per element: A_i Σ_channels |B_i(new) - B_i(old)|, which is
// A_i Σ_channels |R_i(new) - R_i(old)| (E_i does not change).
@group(0) @binding(9) var<storage, read_write> change: array<f32>;
// Per element: the gathered irradiance H_i = D_i + Σ ΔF_p R_p (for
// bookkeeping).
@group(0) @binding(10) var<storage, read_write> irradiance: array<vec4<f32>>;
// x: Σ change over all elements.
@group(0) @binding(11) var<storage, read_write> totals: vec4<f32>;
// Per element: whose light it shows, itself or, for an invalid texel
// (under or inside geometry), its nearest valid neighbour
// (server/src/validity.rs, `Validity::donors`): the part of its region
// beside the geometry is lit, the rest hidden by the geometry itself.
@group(0) @binding(12) var<storage, read> donors: array<u32>;

struct HemicubeOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) @interpolate(flat) patch_id: u32,
    // 1 if the eye is on the side of the surface its light leaves from.
    @location(1) @interpolate(flat) front: u32,
    @location(2) st: vec2<f32>,
};

// Instance = slot * 5 + face (the element `params.first + slot`; face 0 is
// the top, 1..4 the sides, as in `face_local`). A 90° frustum per face with
// *reversed* depth: clip z = near, w = distance, so depth = near / distance
// (1 at the near plane, towards 0 far away; compared with Greater). The eye
// sits 1e-5 of the scene's extent from a neighbouring wall, so the near
// plane must be closer still, and with ordinary depth (1 - near/distance)
// Depth32Float would have no precision left to order the light and the
// ceiling 1 cm above it; reversed depth keeps float precision relative.
@vertex
fn vs_gather(@builtin(vertex_index) vi: u32, @builtin(instance_index) ii: u32) -> HemicubeOut {
    let r = receivers[params.first + ii / 5u];
    let v = vertices[vi];
    let l = face_local(r, ii % 5u, v.pos.xyz - r.eye.xyz);
    var out: HemicubeOut;
    out.clip = vec4<f32>(l.x, l.y, params.near, l.z);
    out.patch_id = bitcast<u32>(v.pos.w);
    out.front = select(0u, 1u, dot(r.eye.xyz - v.pos.xyz, v.normal.xyz) > 0.0);
    out.st = v.st.xy;
    return out;
}

// The radiosity a pixel shows: the reflected part R = B - E (what the
// radiosity buffers hold) of the element of the seen patch nearest to the
// fragment on the patch's chart (`element_at` in common.wgsl, the same
// lookup as `fs_element` in hemicube.wgsl; never a texel above a triangle's
// diagonal). The emission
// reaches receivers through `GatherElement::direct` instead: a few pixels
// of a small light alias.
// The back of a surface occludes but leaves no light (radiosity leaves a
// patch on its normal's side only).
@fragment
fn fs_gather(in: HemicubeOut) -> @location(0) vec4<f32> {
    if (in.front == 0u) {
        return vec4<f32>(0.0, 0.0, 0.0, 1.0);
    }
    let k = donors[element_at(patches[in.patch_id], in.st)];
    return vec4<f32>(radiosity[k].rgb, 1.0);
}

const GATHER_WG: u32 = 64u;
var<workgroup> tile_sums: array<vec3<f32>, 64>;
var<workgroup> change_sums: array<f32, 256>;

// One workgroup per element of the pass: H = D + Σ_p ΔF_p R_p over the
// tile's pixels (thesis Alg. 4.1 lines 4-5, the emitters' share D
// integrated apart), then R_i = ρ_i H, which is B_i = E_i + ρ_i H
// (eq. 2.2.4) without the E_i the CPU adds back.
@compute @workgroup_size(64)
fn gather_main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) lid: u32) {
    let slot = wid.x;
    let res = params.resolution;
    let tile_w = 3u * res;
    let origin = vec2<u32>((slot % params.columns) * tile_w, (slot / params.columns) * res);
    let pixels = tile_w * res;
    var acc = vec3<f32>(0.0);
    for (var k = lid; k < pixels; k += GATHER_WG) {
        let q = origin + vec2<u32>(k % tile_w, k / tile_w);
        acc += textureLoad(hemicubes, vec2<i32>(q), 0).rgb * multipliers[k];
    }
    tile_sums[lid] = acc;
    workgroupBarrier();
    for (var stride = GATHER_WG / 2u; stride > 0u; stride = stride / 2u) {
        if (lid < stride) {
            tile_sums[lid] += tile_sums[lid + stride];
        }
        workgroupBarrier();
    }
    let e = params.first + slot;
    if (lid == 0u && slot < params.count) {
        let el = elements[e];
        let h = el.direct.rgb + tile_sums[0];
        let r = el.albedo.rgb * h;
        let d = abs(r - radiosity[e].rgb);
        updated[e] = vec4<f32>(r, 0.0);
        irradiance[e] = vec4<f32>(h, 0.0);
        change[e] = el.emission.w * (d.r + d.g + d.b);
    }
}

// One workgroup: Σ_i change_i, the power a bounce added (or removed).
@compute @workgroup_size(256)
fn total_change(@builtin(local_invocation_index) lid: u32) {
    var acc = 0.0;
    for (var e = lid; e < params.element_count; e += 256u) {
        acc += change[e];
    }
    change_sums[lid] = acc;
    workgroupBarrier();
    for (var stride = 128u; stride > 0u; stride = stride / 2u) {
        if (lid < stride) {
            change_sums[lid] += change_sums[lid + stride];
        }
        workgroupBarrier();
    }
    if (lid == 0u) {
        totals = vec4<f32>(change_sums[0], 0.0, 0.0, 0.0);
    }
}
