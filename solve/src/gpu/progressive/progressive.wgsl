// requires: common.wgsl, elements.wgsl, receive.wgsl
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

// The bindings of progressive refinement alone (the shared ones are in
// elements.wgsl and receive.wgsl).
@group(0) @binding(3) var<storage, read_write> irradiance: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> patch_power: array<f32>;
@group(0) @binding(6) var<storage, read_write> selection: Selection;
@group(0) @binding(14) var<storage, read_write> placed: array<Element>;
// Patch ids of the triangle clusters (server/src/gpu/progressive/clusters.rs):
// a cluster shooter (chart width 0) shoots the patches members[tile.x..tile.y].
@group(0) @binding(27) var<storage, read> members: array<u32>;

// patch id, its unshot power, total unshot power, unused.
struct Selection {
    patch_id: u32,
    power: f32,
    total: f32,
    _pad: f32,
};

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

// One workgroup per shooter: B_s^u = Σ A_e B_e^u / A_s over the shooter's
// tile of elements (or its cluster's triangles), stored in the intermediate buffer T (`energy`), and the
// tile's unshot radiosity cleared (thesis Alg. 4.2 lines 6-7, 23-29).
@compute @workgroup_size(64)
fn shooter_energy(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) lid: u32) {
    let s = shooters[wid.x];
    let first_element = bitcast<u32>(s.eye.w);
    let chart_w = bitcast<u32>(s.su.w);
    let tw = s.tile.z - s.tile.x;
    let count = tw * (s.tile.w - s.tile.y);
    var acc = vec3<f32>(0.0);
    if (chart_w == 0u) {
        // A cluster of whole triangles: every element of each member.
        for (var m = s.tile.x + lid; m < s.tile.y; m += WG) {
            let p = patches[members[m]];
            for (var k = 0u; k < p.count; k++) {
                let idx = p.first + k;
                acc += unshot[idx].rgb * elements[idx].position.w;
                unshot[idx] = vec4<f32>(0.0);
            }
        }
    } else {
        for (var k = lid; k < count; k += WG) {
            let a = s.tile.x + k % tw;
            let b = s.tile.y + k / tw;
            let idx = first_element + b * chart_w + a;
            acc += unshot[idx].rgb * elements[idx].position.w;
            unshot[idx] = vec4<f32>(0.0);
        }
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

// One thread per element: gather ΔB = ρ B_s^u A_s F from every shooter of
// the batch whose item buffer shows this element's patch (thesis Alg. 4.2
// lines 30-39); add it to B and B^u; keep the irradiance H for the energy
// bookkeeping. A batch may shoot several patches (shoot.rs); an element
// takes nothing from its own patch's shooters.
@compute @workgroup_size(64)
fn reconstruct(@builtin(global_invocation_id) gid: vec3<u32>) {
    let e = gid.x;
    if (e >= batch.element_count) {
        return;
    }
    let el = elements[e];
    let id = bitcast<u32>(el.normal.w);
    // An element inside or under geometry (albedo.w,
    // server/src/validity.rs) receives nothing, nor does one of a passive
    // object (common.wgsl).
    if (absent(el) || passive(el) || is_invalid(el)) {
        return;
    }
    let x = el.position.xyz;
    let nx = el.normal.xyz;
    var h = vec3<f32>(0.0);
    for (var k = 0u; k < batch.shooters; k++) {
        let s = shooters[k];
        // In front of the shooter's plane (a planar patch does not see
        // itself), and some of the shooter above the element's horizon.
        if (bitcast<u32>(s.n.w) == id || dot(x - s.corner.xyz, s.n.xyz) <= 0.0) {
            continue;
        }
        let v = visibility(k, s, el.lookup.xyz - s.eye.xyz, x, id);
        if (v <= 0.0) {
            continue;
        }
        h += energy[k].rgb * (v * form_factor(s, x, nx));
    }
    // Negative light is received like positive (thesis §2.2.5: a
    // correction of shot radiosity propagates as negative light in the
    // progressive iterations that follow). Receiving only where h > 0 kept
    // the positive part of a batch and dropped the negative part, so every
    // incremental move (§4.4), whose refinement shoots the negative light
    // it leaves in C, created energy: a null move on indirect-light gained
    // 3% of the room's power, five 2° moves 20% NRMSE.
    if (any(h != vec3<f32>(0.0))) {
        let db = vec4<f32>(el.albedo.rgb * h, 0.0);
        radiosity[e] += db;
        unshot[e] += db;
        irradiance[e] += vec4<f32>(h, 0.0);
    }
}

// One workgroup per patch: Σ A_e (|B^u_r| + |B^u_g| + |B^u_b|), the unshot
// power. Redistribution leaves negative unshot radiosity (thesis §2.2.5),
// which must be shot like positive, so magnitudes are summed. A dispatch
// holds at most 65,535 workgroups per dimension and a mesh may have more
// patches (one per triangle), so workgroup `w` takes patches w, w + N,
// w + 2N, ... for N dispatched workgroups.
@compute @workgroup_size(64)
fn patch_power_main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let n = arrayLength(&patch_power);
    for (var q = wid.x; q < n; q += groups.x) {
        let p = patches[q];
        var acc = 0.0;
        for (var k = lid; k < p.count; k += WG) {
            let idx = p.first + k;
            let el = elements[idx];
            if (!absent(el) && !passive(el)) {
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
            patch_power[q] = partial[0].x;
        }
        // `partial` is reused by the next patch.
        workgroupBarrier();
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
