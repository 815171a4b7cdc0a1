// One bounce of instant radiosity with imperfect shadow maps (vpl.rs):
// virtual point lights (ism §4.1) on the surfaces whose light changed, their
// visibility from low-resolution paraboloid depth maps splatted from a
// subset of the scene's points and filled by pull-push (ism §4.11).

// Side of one imperfect shadow map, in texels (`ISM_SIDE` in vpl.rs).
const SIDE: u32 = 32u;
// Texels of one map.
const MAP: u32 = 1024u;
// Texels of one map's pull-push pyramid: 32² + 16² + 8² + 4² + 2² + 1.
const PYRAMID: u32 = 1365u;
const PI: f32 = 3.14159265;
// Depth of a direction no point reached (nothing occludes there).
const FAR: f32 = 3.0e38;

struct BounceParams {
    vpls: u32,
    // Points splatted into each map.
    points: u32,
    receivers: u32,
    // Receivers between two consecutive points of one map.
    stride: u32,
    // Relative depth tolerance of the visibility test.
    bias: f32,
    // Workgroups along x of the splat dispatch (its grid is 2D).
    row: u32,
    _pad0: u32,
    _pad1: u32,
}

// An element as the bounce sees it: where it receives (w: 1 when it
// receives, 0 for an invalid or empty texel), its normal, its albedo.
struct BounceReceiver {
    position: vec4<f32>,
    normal: vec4<f32>,
    albedo: vec4<f32>,
}

// A virtual point light: where (w: the area it stands for, m²), its
// normal, and the power it sends (W per channel, signed: a light that went
// away sends negative power).
struct GpuVpl {
    position: vec4<f32>,
    normal: vec4<f32>,
    power: vec4<f32>,
}

@group(0) @binding(0) var<uniform> params: BounceParams;
@group(0) @binding(1) var<storage, read> receivers: array<BounceReceiver>;
@group(0) @binding(2) var<storage, read> vpls: array<GpuVpl>;
// Splatted depths: the bitwise complement of the nearest distance's bits,
// so that 0 (a cleared buffer) is empty and atomicMax keeps the nearest.
@group(0) @binding(3) var<storage, read_write> splats: array<atomic<u32>>;
// Depths after pull-push, one map per light.
@group(0) @binding(4) var<storage, read_write> depths: array<f32>;
// Reflected first bounce per receiver (W/m² per channel).
@group(0) @binding(5) var<storage, read_write> bounce: array<vec4<f32>>;

// An orthonormal frame about unit `n` (Duff et al. 2017, branchless).
fn frame(n: vec3<f32>) -> mat2x3<f32> {
    let s = select(-1.0, 1.0, n.z >= 0.0);
    let a = -1.0 / (s + n.z);
    let b = n.x * n.y * a;
    return mat2x3<f32>(
        vec3<f32>(1.0 + s * n.x * n.x * a, s * b, -s * n.x),
        vec3<f32>(b, s + n.y * n.y * a, -n.y),
    );
}

// The texel of light `v`'s paraboloid map that unit direction `d` (in the
// world, on the light's side of its surface) falls in.
fn texel_of(v: GpuVpl, d: vec3<f32>) -> u32 {
    let n = v.normal.xyz;
    let t = frame(n);
    let z = max(dot(d, n), 0.0);
    let uv = vec2<f32>(dot(d, t[0]), dot(d, t[1])) / (1.0 + z);
    let cell = clamp(vec2<i32>(floor((uv * 0.5 + 0.5) * f32(SIDE))), vec2<i32>(0), vec2<i32>(i32(SIDE) - 1));
    return u32(cell.y) * SIDE + u32(cell.x);
}

// Splat: point `k` of light `v`'s subset (every `stride`-th receiver from
// an offset of the light's own, so that the maps see different subsets
// that together cover the scene, ism §4.11) into the light's map.
@compute @workgroup_size(64)
fn splat(@builtin(global_invocation_id) id: vec3<u32>) {
    let flat = id.y * params.row * 64u + id.x;
    let v = flat / max(params.points, 1u);
    let k = flat % max(params.points, 1u);
    if v >= params.vpls {
        return;
    }
    let j = k * params.stride + (v * 7919u) % params.stride;
    if j >= params.receivers {
        return;
    }
    let p = receivers[j];
    if p.position.w == 0.0 {
        return;
    }
    let light = vpls[v];
    let d = p.position.xyz - light.position.xyz;
    let dist = length(d);
    if dist <= 0.0 {
        return;
    }
    let dir = d / dist;
    if dot(dir, light.normal.xyz) <= 1e-3 {
        return;
    }
    atomicMax(&splats[v * MAP + texel_of(light, dir)], ~bitcast<u32>(dist));
}

var<workgroup> level_depth: array<f32, PYRAMID>;
var<workgroup> level_weight: array<f32, PYRAMID>;

// Offset of pyramid level `l` (side SIDE >> l).
fn level_start(l: u32) -> u32 {
    var start = 0u;
    for (var k = 0u; k < l; k++) {
        let s = SIDE >> k;
        start += s * s;
    }
    return start;
}

// Pull-push (ism §4.11, after Marroquim et al. 2007): one workgroup per
// map. Pull averages each 2 x 2 block's filled texels into the next
// coarser level, with a weight saturating at one; push fills each empty
// or partly filled texel from its parent, coarse to fine. A map no point
// reached stays at FAR (nothing occludes).
@compute @workgroup_size(64)
fn pull_push(@builtin(workgroup_id) group: vec3<u32>, @builtin(local_invocation_index) lane: u32) {
    let v = group.x + group.y * 65535u;
    if v >= params.vpls {
        return;
    }
    for (var t = lane; t < MAP; t += 64u) {
        let bits = atomicLoad(&splats[v * MAP + t]);
        let filled = bits != 0u;
        level_depth[t] = select(0.0, bitcast<f32>(~bits), filled);
        level_weight[t] = select(0.0, 1.0, filled);
    }
    workgroupBarrier();
    for (var l = 1u; l <= 5u; l++) {
        let side = SIDE >> l;
        let fine = level_start(l - 1u);
        let coarse = level_start(l);
        for (var t = lane; t < side * side; t += 64u) {
            let x = t % side;
            let y = t / side;
            var sum = 0.0;
            var weight = 0.0;
            for (var c = 0u; c < 4u; c++) {
                let f = fine + (2u * y + c / 2u) * (2u * side) + 2u * x + c % 2u;
                sum += level_depth[f] * level_weight[f];
                weight += level_weight[f];
            }
            level_depth[coarse + t] = select(0.0, sum / weight, weight > 0.0);
            level_weight[coarse + t] = min(weight, 1.0);
        }
        workgroupBarrier();
    }
    for (var l = 5u; l >= 1u; l--) {
        let side = SIDE >> (l - 1u);
        let fine = level_start(l - 1u);
        let coarse = level_start(l);
        for (var t = lane; t < side * side; t += 64u) {
            let x = t % side;
            let y = t / side;
            let parent = coarse + (y / 2u) * (side / 2u) + x / 2u;
            let w = level_weight[fine + t];
            if w < 1.0 && level_weight[parent] > 0.0 {
                level_depth[fine + t] = w * level_depth[fine + t] + (1.0 - w) * level_depth[parent];
                level_weight[fine + t] = 1.0;
            }
        }
        workgroupBarrier();
    }
    for (var t = lane; t < MAP; t += 64u) {
        depths[v * MAP + t] = select(FAR, level_depth[t], level_weight[t] > 0.0);
    }
}

// Gather: every receiver sums what each light sends it, `Φ cos θ_v cos θ_r
// / (π r² + A)` (the disc approximation of the form factor, thesis eq.
// 2.2.7-2.2.8, which bounds a light's reach near its own surface), where
// the light's map says it is seen, and reflects it.
@compute @workgroup_size(64)
fn gather(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = id.x;
    if i >= params.receivers {
        return;
    }
    let r = receivers[i];
    if r.position.w == 0.0 {
        bounce[i] = vec4<f32>(0.0);
        return;
    }
    var e = vec3<f32>(0.0);
    for (var v = 0u; v < params.vpls; v++) {
        let light = vpls[v];
        let d = r.position.xyz - light.position.xyz;
        let r2 = dot(d, d);
        if r2 <= 0.0 {
            continue;
        }
        let dist = sqrt(r2);
        let dir = d / dist;
        let cos_v = dot(dir, light.normal.xyz);
        let cos_r = -dot(dir, r.normal.xyz);
        if cos_v <= 0.0 || cos_r <= 0.0 {
            continue;
        }
        let depth = depths[v * MAP + texel_of(light, dir)];
        if dist > depth * (1.0 + params.bias) {
            continue;
        }
        e += light.power.xyz * (cos_v * cos_r / (PI * r2 + light.position.w));
    }
    bounce[i] = vec4<f32>(r.albedo.xyz * e, 0.0);
}
