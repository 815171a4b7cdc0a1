// Progressive refinement radiosity as gathering (thesis Alg. 4.2, gems §39.2).
// Entry points, in the order one batch runs them:
//   shooter_energy  GENERATESHOOTINGPATCHES: unshot power of each shooter's
//                   elements into `energy`, then clear them (thesis §4.3.3).
//   (hemicube.wgsl rasterizes the item buffers here.)
//   reconstruct     RECONSTRUCTIONSHADER: every element gathers from every
//                   shooter of the batch.
//   patch_power     per-patch unshot power, a reduction (gems §39.2.3).
//   select_shooter  FINDSHOOTINGQUAD: the patch with the most unshot power,
//                   and the total, into `selection` (read back by the CPU).

// One element (lightmap texel), written only by `place_elements`; its size
// is `ELEMENT_BYTES` in server/src/gpu/placement.rs.
struct Element {
    // xyz: world sample position, nudged a hair towards the patch centre
    // and off the surface (so that a sample on an edge is in front of the
    // neighbouring wall it touches), w: area (m²).
    position: vec4<f32>,
    // xyz: unit normal, w: bitcast patch id.
    normal: vec4<f32>,
    // xyz: point used for the visibility lookup (edge samples nudged into
    // their own patch), w: bitcast object id.
    lookup: vec4<f32>,
    // rgb: albedo, w: 1 if invalid (see `is_invalid`).
    albedo: vec4<f32>,
};


// patch id, its unshot power, total unshot power, unused.
struct Selection {
    patch_id: u32,
    power: f32,
    total: f32,
    _pad: f32,
};

@group(0) @binding(0) var<storage, read> elements: array<Element>;
@group(0) @binding(1) var<storage, read_write> radiosity: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> unshot: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> irradiance: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> patches: array<PatchRange>;
@group(0) @binding(5) var<storage, read_write> patch_power: array<f32>;
@group(0) @binding(6) var<storage, read_write> selection: Selection;
@group(0) @binding(7) var<storage, read> shooters: array<Shooter>;
@group(0) @binding(8) var<storage, read_write> energy: array<vec4<f32>>;
@group(0) @binding(9) var<uniform> batch: Batch;
@group(0) @binding(10) var item: texture_2d<u32>;
@group(0) @binding(11) var<storage, read> object_flags: array<u32>;
// Object matrices: the current set, then the old set (see hemicube.wgsl).
@group(0) @binding(12) var<storage, read> poses: array<mat4x4<f32>>;
@group(0) @binding(13) var<storage, read> local_elements: array<LocalElement>;
@group(0) @binding(14) var<storage, read_write> placed: array<Element>;

// An element in its object's space, as uploaded once; `place_elements`
// puts it in the world at the current poses.
struct LocalElement {
    // xyz: sample point (object space), w: area at scale 1.
    position: vec4<f32>,
    // xyz: unit normal (object space), w: bitcast patch id.
    normal: vec4<f32>,
    // xyz: visibility lookup point (object space), w: bitcast object id.
    lookup: vec4<f32>,
    // rgb: albedo, w: the invalid flag, as in `Element`.
    albedo: vec4<f32>,
    // xyz: unit direction from the sample towards the patch centre (or
    // zero), w: the world-space distance samples are moved off edges and
    // off their surface.
    nudge: vec4<f32>,
};

const WG: u32 = 64u;
const PI: f32 = 3.14159265358979;
const NO_PATCH: u32 = 0xffffffffu;
// Inward offset of corner samples in cells (atlas::CORNER_OFFSET).
const CORNER_OFFSET: f32 = 0.05;

var<workgroup> partial: array<vec3<f32>, 64>;
var<workgroup> partial_power: array<f32, 256>;
var<workgroup> partial_id: array<u32, 256>;
var<workgroup> partial_total: array<f32, 256>;

// Elements of every object placed at its current pose: dynamic objects
// are transformed here, on the GPU, after each move.
@compute @workgroup_size(64)
fn place_elements(@builtin(global_invocation_id) gid: vec3<u32>) {
    let e = gid.x;
    if (e >= arrayLength(&local_elements)) {
        return;
    }
    let l = local_elements[e];
    let m = poses[bitcast<u32>(l.lookup.w)];
    let scale2 = dot(m[0].xyz, m[0].xyz);
    let n = normalize((m * vec4<f32>(l.normal.xyz, 0.0)).xyz);
    let inward = (m * vec4<f32>(l.nudge.xyz, 0.0)).xyz;
    let len = length(inward);
    let dir = select(vec3<f32>(0.0), inward / len, len > 0.0);
    let sample = (m * vec4<f32>(l.position.xyz, 1.0)).xyz;
    var out: Element;
    out.position = vec4<f32>(sample + (dir + n) * l.nudge.w, l.position.w * scale2);
    out.normal = vec4<f32>(n, l.normal.w);
    out.lookup = vec4<f32>((m * vec4<f32>(l.lookup.xyz, 1.0)).xyz, l.lookup.w);
    out.albedo = l.albedo;
    placed[e] = out;
}

// Whether element `el` belongs to an object removed from the simulation.
fn absent(el: Element) -> bool {
    return (object_flags[bitcast<u32>(el.lookup.w)] & OBJECT_ABSENT) != 0u;
}

// One workgroup per shooter: B_s^u = Σ A_e B_e^u / A_s over the shooter's
// tile of elements, stored in the intermediate buffer T (`energy`), and the
// tile's unshot radiosity cleared (thesis Alg. 4.2 lines 6-7, 23-29).
@compute @workgroup_size(64)
fn shooter_energy(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) lid: u32) {
    let s = shooters[wid.x];
    let tw = s.tile.z - s.tile.x;
    let count = tw * (s.tile.w - s.tile.y);
    var acc = vec3<f32>(0.0);
    for (var k = lid; k < count; k += WG) {
        let a = s.tile.x + k % tw;
        let b = s.tile.y + k / tw;
        let idx = batch.first_element + b * batch.chart_w + a;
        acc += unshot[idx].rgb * elements[idx].position.w;
        unshot[idx] = vec4<f32>(0.0);
    }
    partial[lid] = acc;
    workgroupBarrier();
    for (var stride = WG / 2u; stride > 0u; stride = stride / 2u) {
        if (lid < stride) {
            partial[lid] += partial[lid + stride];
        }
        workgroupBarrier();
    }
    if (lid == 0u) {
        energy[wid.x] = vec4<f32>(partial[0] / max(s.corner.w, 1e-30), 0.0);
    }
}

// Whether the shooter in item-buffer slot `slot` sees the receiving point
// `x` (on patch `id`), looking along `d` (eye to the point's lookup
// position): 1 or 0.
//
// The pixel the direction falls in shows the point's own patch, nothing, or
// another patch. Surface-level ids alone (thesis §4.3.2) cannot tell a
// block in front of a floor point from the wall that rises behind it, and
// at grazing angles one pixel covers several texels, so another patch in
// the pixel only occludes if, placed as the buffer drew it, it really
// crosses the segment from the eye to `x` (`crosses`). The rule it replaces
// ("any of the four nearest pixels shows my patch", thesis §5, "general
// observations") moved every shadow edge a whole pixel into the shadow: on
// cornell-blocks the direct light on the floor read 10% too bright at
// resolution 64, the blocks' shadows half gone. A weighted share of the
// four pixels (percentage-closer filtering) measured as accurate but cost
// four texture loads per receiver and shooter, twice the reconstruction
// time on lavapipe.
fn visibility(slot: u32, s: Shooter, d: vec3<f32>, x: vec3<f32>, id: u32) -> f32 {
    let face = face_of(s, d);
    let l = face_local(s, face, d);
    if (l.z <= 0.0) {
        return 0.0;
    }
    let res = f32(batch.resolution);
    let ndc = l.xy / l.z;
    let p = vec2<f32>((ndc.x * 0.5 + 0.5) * res, (0.5 - ndc.y * 0.5) * res);
    let last = i32(batch.resolution) - 1;
    let q = clamp(vec2<i32>(floor(p)), vec2<i32>(0), vec2<i32>(last));
    let origin = vec2<i32>(i32(face * batch.resolution), i32(slot * batch.resolution));
    let shown = textureLoad(item, origin + q, 0).r;
    // The shooter's own (planar) patch occludes nothing in front of it.
    if (shown == id || shown == NO_PATCH || shown == bitcast<u32>(s.n.w)) {
        return 1.0;
    }
    // Another patch: it occludes only if, placed as the buffer drew it
    // (redistribution draws old-pose buffers too), it really lies across
    // the segment from the eye to `x`.
    let pose_base = select(0u, arrayLength(&poses) / 2u, slot >= batch.old_from_slot);
    return select(1.0, 0.0, crosses(shown, pose_base, s.eye.xyz, x));
}

// Whether patch `p`, placed by the pose set starting at `pose_base` in
// `poses`, crosses the open segment from `a` to `b` (short of `b` by a
// hair, so that a receiver on the patch's plane or on its edge is not
// occluded by it). The patch's parallelogram is rebuilt from its three
// corner elements in object space: their samples sit CORNER_OFFSET of a
// cell inside the corners (server/src/atlas.rs).
fn crosses(p: u32, pose_base: u32, a: vec3<f32>, b: vec3<f32>) -> bool {
    let r = patches[p];
    let first = local_elements[r.first];
    let m = poses[pose_base + bitcast<u32>(first.lookup.w)];
    let e00 = (m * vec4<f32>(first.position.xyz, 1.0)).xyz;
    let e10 = (m * vec4<f32>(local_elements[r.first + r.w - 1u].position.xyz, 1.0)).xyz;
    let e01 = (m * vec4<f32>(local_elements[r.first + (r.h - 1u) * r.w].position.xyz, 1.0)).xyz;
    let cu = (e10 - e00) / (f32(r.w - 1u) - 2.0 * CORNER_OFFSET);
    let cv = (e01 - e00) / (f32(r.h - 1u) - 2.0 * CORNER_OFFSET);
    let o = e00 - (cu + cv) * CORNER_OFFSET;
    let u = cu * f32(r.w - 1u);
    let v = cv * f32(r.h - 1u);
    let n = cross(u, v);
    let denom = dot(b - a, n);
    if (abs(denom) < 1e-30) {
        return false;
    }
    let t = dot(o - a, n) / denom;
    if (t <= 0.0 || t >= 1.0 - 1e-4) {
        return false;
    }
    let q = a + (b - a) * t - o;
    let nn = dot(n, n);
    let su = dot(q, cross(v, n)) / nn;
    let sv = dot(q, cross(n, u)) / nn;
    return su > 0.0 && su < 1.0 && sv > 0.0 && sv < 1.0;
}

// `albedo.w` of an element is 1 when it is invalid (inside or under
// geometry, server/src/validity.rs): it receives nothing.
fn is_invalid(el: Element) -> bool {
    return (u32(el.albedo.w) & 1u) != 0u;
}


// Exact unoccluded form factor from the point `x` (normal `nx`) to the
// shooter's parallelogram, clipped to the upper hemisphere of `x`
// (Lambert's contour integral; the limit of infinitely fine subdivision of
// eq. 2.2.7). Used only where the shooter is so close that the disk
// approximation would need more than `max_subdivision`² sub-disks, e.g. for
// samples on the edge a wall shares with the shooting floor.
fn polygon_form_factor(s: Shooter, x: vec3<f32>, nx: vec3<f32>) -> f32 {
    var p = array<vec3<f32>, 4>(
        s.corner.xyz - x,
        s.corner.xyz + s.su.xyz - x,
        s.corner.xyz + s.su.xyz + s.sv.xyz - x,
        s.corner.xyz + s.sv.xyz - x,
    );
    var q: array<vec3<f32>, 8>;
    var count = 0u;
    for (var i = 0u; i < 4u; i++) {
        let a = p[i];
        let b = p[(i + 1u) % 4u];
        let da = dot(a, nx);
        let db = dot(b, nx);
        if (da >= 0.0) {
            q[count] = a;
            count++;
        }
        if ((da >= 0.0) != (db >= 0.0)) {
            q[count] = a + (b - a) * (da / (da - db));
            count++;
        }
    }
    if (count < 3u) {
        return 0.0;
    }
    var sum = 0.0;
    for (var e = 0u; e < count; e++) {
        let a = q[e];
        let b = q[(e + 1u) % count];
        let c = cross(a, b);
        let len = length(c);
        if (len <= 1e-20) {
            continue;
        }
        sum += atan2(len, dot(a, b)) * dot(nx, c) / len;
    }
    return abs(sum) / (2.0 * PI);
}

// Disk-approximation form factor from shooter `s` to a receiving point `x`
// with normal `nx` (thesis eq. 2.2.7, in the receiver form of eq. 2.2.8
// without ρ and B^u): A_s (1/m) Σ_k cos φ_s cos φ_x / (π r_k² + A_s/m).
// The shooter is split into m = k×k sub-disks when it is large compared with
// its distance (thesis §4.3.3, adaptive form factor subdivision); beyond
// `max_subdivision` sub-disks per axis the exact limit is used instead.
fn form_factor(s: Shooter, x: vec3<f32>, nx: vec3<f32>) -> f32 {
    let area = s.corner.w;
    // Distance to the nearest point of the shooter, not to its centre: a
    // receiver next to the shooter's edge needs the fine subdivision even
    // when the shooter as a whole is far away.
    let rel = x - s.corner.xyz;
    let st = clamp(
        vec2<f32>(dot(rel, s.su.xyz) / dot(s.su.xyz, s.su.xyz), dot(rel, s.sv.xyz) / dot(s.sv.xyz, s.sv.xyz)),
        vec2<f32>(0.0),
        vec2<f32>(1.0),
    );
    let r = max(length(rel - s.su.xyz * st.x - s.sv.xyz * st.y), 1e-12);
    let wanted = ceil(batch.subdivision * sqrt(area) / r);
    if (wanted > f32(batch.max_subdivision)) {
        return polygon_form_factor(s, x, nx);
    }
    let k = u32(max(wanted, 1.0));
    let m = f32(k * k);
    let sub = area / m;
    var sum = 0.0;
    for (var j = 0u; j < k; j++) {
        for (var i = 0u; i < k; i++) {
            let c = s.corner.xyz + s.su.xyz * ((f32(i) + 0.5) / f32(k))
                + s.sv.xyz * ((f32(j) + 0.5) / f32(k));
            let d = x - c;
            let r2 = dot(d, d);
            let rl = sqrt(r2);
            if (rl <= 0.0) {
                continue;
            }
            let cs = dot(s.n.xyz, d) / rl;
            let cx = -dot(nx, d) / rl;
            if (cs > 0.0 && cx > 0.0) {
                sum += cs * cx / (PI * r2 + sub);
            }
        }
    }
    return sub * sum;
}

// One thread per element: gather ΔB = ρ B_s^u A_s F from every shooter of
// the batch whose item buffer shows this element's patch (thesis Alg. 4.2
// lines 30-39); add it to B and B^u; keep the irradiance H for the energy
// bookkeeping.
@compute @workgroup_size(64)
fn reconstruct(@builtin(global_invocation_id) gid: vec3<u32>) {
    let e = gid.x;
    if (e >= batch.element_count) {
        return;
    }
    let el = elements[e];
    let id = bitcast<u32>(el.normal.w);
    // A planar patch does not see itself; an element inside or under
    // geometry (albedo.w, server/src/validity.rs) receives nothing.
    if (id == batch.patch_id || absent(el) || is_invalid(el)) {
        return;
    }
    let x = el.position.xyz;
    let nx = el.normal.xyz;
    var h = vec3<f32>(0.0);
    for (var k = 0u; k < batch.shooters; k++) {
        let s = shooters[k];
        // In front of the shooter's plane, and some of the shooter above
        // the element's horizon.
        if (dot(x - s.corner.xyz, s.n.xyz) <= 0.0) {
            continue;
        }
        let v = visibility(k, s, el.lookup.xyz - s.eye.xyz, x, id);
        if (v <= 0.0) {
            continue;
        }
        h += energy[k].rgb * (v * form_factor(s, x, nx));
    }
    if (any(h > vec3<f32>(0.0))) {
        let db = vec4<f32>(el.albedo.rgb * h, 0.0);
        radiosity[e] += db;
        unshot[e] += db;
        irradiance[e] += vec4<f32>(h, 0.0);
    }
}

// One workgroup per patch: Σ A_e (|B^u_r| + |B^u_g| + |B^u_b|), the unshot
// power. Redistribution leaves negative unshot radiosity (thesis §2.2.5),
// which must be shot like positive, so magnitudes are summed.
@compute @workgroup_size(64)
fn patch_power_main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) lid: u32) {
    let p = patches[wid.x];
    var acc = 0.0;
    for (var k = lid; k < p.count; k += WG) {
        let idx = p.first + k;
        let el = elements[idx];
        if (!absent(el)) {
            let u = abs(unshot[idx].rgb);
            acc += (u.r + u.g + u.b) * el.position.w;
        }
    }
    partial[lid] = vec3<f32>(acc, 0.0, 0.0);
    workgroupBarrier();
    for (var stride = WG / 2u; stride > 0u; stride = stride / 2u) {
        if (lid < stride) {
            partial[lid] += partial[lid + stride];
        }
        workgroupBarrier();
    }
    if (lid == 0u) {
        patch_power[wid.x] = partial[0].x;
    }
}

// One workgroup: arg-max and sum over the patch powers (gems §39.2.3; the
// thesis uses a depth test for the same reduction).
@compute @workgroup_size(256)
fn select_shooter(@builtin(local_invocation_index) lid: u32) {
    let n = arrayLength(&patch_power);
    var best = -1.0;
    var best_id = NO_PATCH;
    var total = 0.0;
    for (var p = lid; p < n; p += 256u) {
        let w = patch_power[p];
        total += w;
        if (w > best) {
            best = w;
            best_id = p;
        }
    }
    partial_power[lid] = best;
    partial_id[lid] = best_id;
    partial_total[lid] = total;
    workgroupBarrier();
    for (var stride = 128u; stride > 0u; stride = stride / 2u) {
        if (lid < stride) {
            let o = lid + stride;
            let better = partial_power[o] > partial_power[lid]
                || (partial_power[o] == partial_power[lid] && partial_id[o] < partial_id[lid]);
            if (better) {
                partial_power[lid] = partial_power[o];
                partial_id[lid] = partial_id[o];
            }
            partial_total[lid] += partial_total[o];
        }
        workgroupBarrier();
    }
    if (lid == 0u) {
        selection.patch_id = partial_id[0];
        selection.power = max(partial_power[0], 0.0);
        selection.total = partial_total[0];
        selection._pad = 0.0;
    }
}
