// requires: common.wgsl, elements.wgsl
// What an element receives from the shooters of a batch: the batch's
// bindings (the shooters, their energy T, the batch constants, the item
// buffers and the poses they were drawn with), visibility through the item
// buffers and the form factor. Shared by the reconstruction shaders of
// progressive.wgsl and redistribute.wgsl.

@group(0) @binding(7) var<uniform> shooters: array<Shooter, MAX_BATCH>;
@group(0) @binding(8) var<storage, read_write> energy: array<vec4<f32>>;
@group(0) @binding(9) var<uniform> batch: Batch;
@group(0) @binding(10) var item: texture_2d<u32>;
// Object matrices: the current set, then the old set (see hemicube.wgsl).
@group(0) @binding(12) var<storage, read> poses: array<mat4x4<f32>>;

// A patch's frame in object space (`PatchFrame` in
// server/src/gpu/placement.rs): only a triangle on its mesh's own lightmap
// UVs has one (`TRIANGLE_ON_LIGHTMAP`).
struct PatchFrame {
    origin: vec4<f32>,
    u: vec4<f32>,
    v: vec4<f32>,
};
@group(0) @binding(34) var<storage, read> patch_frames: array<PatchFrame>;

const PI: f32 = 3.14159265358979;
// Inward offset of corner samples in cells (atlas::CORNER_OFFSET).
const CORNER_OFFSET: f32 = 0.05;

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
// occluded by it). The patch's frame is rebuilt from three corner elements
// in object space: their samples sit CORNER_OFFSET of a cell inside the
// corners (server/src/atlas.rs). A quad's are texels (0, 0), (w-1, 0) and
// (0, h-1); a triangle's chart corner (0, h-1) lies above its diagonal and
// stands for no surface, so its `v` comes from (w-1, 0) and (w-1, h-1),
// and it occludes only on its half t <= s (the texels the item buffer
// shows for it are the triangle's; its parallelogram would also shadow
// through the neighbouring triangle's side). A patch on its mesh's own
// lightmap (a triangle, or a parallelogram of them) reads its stored frame.
fn crosses(p: u32, pose_base: u32, a: vec3<f32>, b: vec3<f32>) -> bool {
    let r = patches[p];
    let first = local_elements[r.first];
    let m = poses[pose_base + bitcast<u32>(first.lookup.w)];
    var o: vec3<f32>;
    var u: vec3<f32>;
    var v: vec3<f32>;
    if (on_lightmap(r.triangle)) {
        // Its frame is stored: its corner texels are not on its corners.
        let f = patch_frames[p];
        o = (m * f.origin).xyz;
        u = (m * f.u).xyz;
        v = (m * f.v).xyz;
    } else {
        let e00 = (m * vec4<f32>(first.position.xyz, 1.0)).xyz;
        let e10 = (m * vec4<f32>(local_elements[r.first + r.w - 1u].position.xyz, 1.0)).xyz;
        let cu = (e10 - e00) / (f32(r.w - 1u) - 2.0 * CORNER_OFFSET);
        var cv: vec3<f32>;
        if (r.triangle != 0u) {
            let e11 = (m * vec4<f32>(local_elements[r.first + r.h * r.w - 1u].position.xyz, 1.0)).xyz;
            cv = (e11 - e10) / (f32(r.h - 1u) - 2.0 * CORNER_OFFSET);
        } else {
            let e01 = (m * vec4<f32>(local_elements[r.first + (r.h - 1u) * r.w].position.xyz, 1.0)).xyz;
            cv = (e01 - e00) / (f32(r.h - 1u) - 2.0 * CORNER_OFFSET);
        }
        o = e00 - (cu + cv) * CORNER_OFFSET;
        u = cu * f32(r.w - 1u);
        v = cv * f32(r.h - 1u);
    }
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
    let upper = select(1.0, su, r.triangle == ON_OWN_CHART_TRIANGLE || r.triangle == TRIANGLE_ON_LIGHTMAP);
    return su > 0.0 && su < 1.0 && sv > 0.0 && sv < upper;
}

// Running sum of Lambert's contour integral over the edges of a region
// clipped to a receiver's upper hemisphere, edge by edge as `Clip2` does:
// `exit` and `entry` are where the boundary crosses the horizon plane.
struct Contour {
    sum: f32,
    exit: vec3<f32>,
    entry: vec3<f32>,
};

fn contour_edge(acc: ptr<function, Contour>, a: vec3<f32>, b: vec3<f32>, nx: vec3<f32>) {
    let c = cross(a, b);
    let len = length(c);
    if (len > 1e-20) {
        (*acc).sum += atan2(len, dot(a, b)) * dot(nx, c) / len;
    }
}

// Edge a -> b (relative to the receiver), kept above its horizon.
fn horizon_edge(acc: ptr<function, Contour>, a: vec3<f32>, b: vec3<f32>, nx: vec3<f32>) {
    let da = dot(a, nx);
    let db = dot(b, nx);
    let ka = da >= 0.0;
    let kb = db >= 0.0;
    let m = a + (b - a) * (da / (da - db));
    if (ka || kb) {
        contour_edge(acc, select(m, a, ka), select(m, b, kb), nx);
    }
    if (ka && !kb) {
        (*acc).exit = m;
    }
    if (!ka && kb) {
        (*acc).entry = m;
    }
}

// Edge a -> b of the unit square of shooter `s`, cut by `cut` (whose exit
// and entry points are kept in `cuts`), placed relative to `x` and clipped
// to its horizon.
fn region_edge(acc: ptr<function, Contour>, cuts: ptr<function, Clip2>, s: Shooter, a: vec2<f32>, b: vec2<f32>, cut: vec3<f32>, x: vec3<f32>, nx: vec3<f32>) {
    let kept = clip_by_line(cuts, a, b, cut);
    if (kept.any) {
        let p = kept.p;
        let q = kept.q;
        horizon_edge(acc, s.corner.xyz + s.su.xyz * p.x + s.sv.xyz * p.y - x, s.corner.xyz + s.su.xyz * q.x + s.sv.xyz * q.y - x, nx);
    }
}

// Exact unoccluded form factor from the point `x` (normal `nx`) to the
// shooter's region (its parallelogram, cut by `shooter_cut` on a triangle's
// diagonal), clipped to the upper hemisphere of `x` (Lambert's contour
// integral; the limit of infinitely fine subdivision of eq. 2.2.7). Used
// only where the shooter is so close that the disk approximation would
// need more than `max_subdivision`² sub-disks, e.g. for samples on the edge
// a wall shares with the shooting floor. The region's edges are clipped
// twice (by the cut, then by the horizon), each clipping adding the edge
// along its line (`Clip2`).
fn polygon_form_factor(s: Shooter, x: vec3<f32>, nx: vec3<f32>) -> f32 {
    let given = shooter_cut(s);
    // An uncut region: a cut that keeps everything.
    let cut = select(vec3<f32>(0.0, 0.0, 1.0), given, is_cut(given));
    var acc = Contour(0.0, vec3<f32>(0.0), vec3<f32>(0.0));
    var cuts = Clip2(0.0, vec2<f32>(0.0), vec2<f32>(0.0), vec2<f32>(0.0));
    region_edge(&acc, &cuts, s, vec2<f32>(0.0, 0.0), vec2<f32>(1.0, 0.0), cut, x, nx);
    region_edge(&acc, &cuts, s, vec2<f32>(1.0, 0.0), vec2<f32>(1.0, 1.0), cut, x, nx);
    region_edge(&acc, &cuts, s, vec2<f32>(1.0, 1.0), vec2<f32>(0.0, 1.0), cut, x, nx);
    region_edge(&acc, &cuts, s, vec2<f32>(0.0, 1.0), vec2<f32>(0.0, 0.0), cut, x, nx);
    // The cut's own edge (zero length when the cut crosses nothing).
    let ce = cuts.exit;
    let cn = cuts.entry;
    horizon_edge(&acc, s.corner.xyz + s.su.xyz * ce.x + s.sv.xyz * ce.y - x, s.corner.xyz + s.su.xyz * cn.x + s.sv.xyz * cn.y - x, nx);
    // The horizon's edge.
    contour_edge(&acc, acc.exit, acc.entry, nx);
    return abs(acc.sum) / (2.0 * PI);
}

// Exact unoccluded form factor from the point `x` (normal `nx`) to the
// part of shooter `s`'s region that lies on its patch `p`, a triangle or a
// parallelogram on its mesh's own lightmap. Such a tile is its texels'
// footprint, cut by at most one of the patch's edges
// (server/src/gpu/progressive/shooters.rs); a small triangle's other edges
// may cross it too, and the region beyond them is not the patch. On a
// concave crease (the inside of a sphere) that part lies behind a near
// receiver's horizon and would take light away; on a flat one it would
// add light the patch does not have. So the unit square of the region is
// clipped by every edge of the patch (Sutherland-Hodgman, in the region's
// coordinates, from the patch's stored frame), then integrated as
// `polygon_form_factor` does. Only near receivers take this branch.
fn lightmap_form_factor(s: Shooter, p: u32, x: vec3<f32>, nx: vec3<f32>) -> f32 {
    let r = patches[p];
    let m = poses[bitcast<u32>(local_elements[r.first].lookup.w)];
    let f = patch_frames[p];
    let o = (m * f.origin).xyz;
    let u = (m * f.u).xyz;
    let v = (m * f.v).xyz;
    let n = cross(u, v);
    let nn = max(dot(n, n), 1e-30);
    let du = cross(v, n) / nn;
    let dv = cross(n, u) / nn;
    // Patch parameters of the region's corner and of its two edges.
    let c = vec2<f32>(dot(s.corner.xyz - o, du), dot(s.corner.xyz - o, dv));
    let eu = vec2<f32>(dot(s.su.xyz, du), dot(s.su.xyz, dv));
    let ev = vec2<f32>(dot(s.sv.xyz, du), dot(s.sv.xyz, dv));
    // The patch as half-planes a x + b y + c >= 0 over the region's (x, y):
    // t >= 0 and s <= 1, then t <= s (a triangle) or s >= 0 and t <= 1.
    var lines = array<vec3<f32>, 4>(
        vec3<f32>(eu.y, ev.y, c.y),
        vec3<f32>(-eu.x, -ev.x, 1.0 - c.x),
        vec3<f32>(eu.x - eu.y, ev.x - ev.y, c.x - c.y),
        vec3<f32>(0.0, 0.0, 1.0),
    );
    if (r.triangle == QUAD_ON_LIGHTMAP) {
        lines[2] = vec3<f32>(eu.x, ev.x, c.x);
        lines[3] = vec3<f32>(-eu.y, -ev.y, 1.0 - c.y);
    }
    var poly = array<vec2<f32>, 8>(
        vec2<f32>(0.0, 0.0), vec2<f32>(1.0, 0.0), vec2<f32>(1.0, 1.0), vec2<f32>(0.0, 1.0),
        vec2<f32>(0.0), vec2<f32>(0.0), vec2<f32>(0.0), vec2<f32>(0.0),
    );
    var count = 4u;
    for (var l = 0u; l < 4u; l++) {
        let line = lines[l];
        var next = array<vec2<f32>, 8>();
        var k = 0u;
        for (var i = 0u; i < count; i++) {
            let a = poly[i];
            let b = poly[(i + 1u) % count];
            let ha = dot(line.xy, a) + line.z;
            let hb = dot(line.xy, b) + line.z;
            if (ha >= 0.0 && k < 8u) {
                next[k] = a;
                k++;
            }
            if ((ha >= 0.0) != (hb >= 0.0) && k < 8u) {
                next[k] = a + (b - a) * (ha / (ha - hb));
                k++;
            }
        }
        poly = next;
        count = k;
        if (count < 3u) {
            return 0.0;
        }
    }
    var acc = Contour(0.0, vec3<f32>(0.0), vec3<f32>(0.0));
    for (var i = 0u; i < count; i++) {
        let a = poly[i];
        let b = poly[(i + 1u) % count];
        horizon_edge(&acc, s.corner.xyz + s.su.xyz * a.x + s.sv.xyz * a.y - x, s.corner.xyz + s.su.xyz * b.x + s.sv.xyz * b.y - x, nx);
    }
    contour_edge(&acc, acc.exit, acc.entry, nx);
    return abs(acc.sum) / (2.0 * PI);
}

// Disk-approximation form factor from shooter `s` to a receiving point `x`
// with normal `nx` (thesis eq. 2.2.7, in the receiver form of eq. 2.2.8
// without ρ and B^u): A_s (1/m) Σ_k cos φ_s cos φ_x / (π r_k² + A_s/m).
// The shooter is split into m = k×k sub-disks when it is large compared with
// its distance (thesis §4.3.3, adaptive form factor subdivision); beyond
// `max_subdivision` sub-disks per axis the exact limit is used instead.
// A shooter cut by a triangle's diagonal (`shooter_cut`) keeps the part of
// each sub-cell on the triangle: a sub-disk of that part's area at its
// centroid, the sub-areas summing to A_s.
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
        // A cluster of triangles (chart width 0, shooters.rs) covers only
        // part of its rectangle: the exact form factor to the rectangle,
        // scaled by the share it covers.
        var cover = 1.0;
        if (bitcast<u32>(s.su.w) == 0u) {
            cover = min(area / max(length(cross(s.su.xyz, s.sv.xyz)), 1e-30), 1.0);
        } else if (on_lightmap(patches[bitcast<u32>(s.n.w)].triangle)) {
            return lightmap_form_factor(s, bitcast<u32>(s.n.w), x, nx);
        }
        return polygon_form_factor(s, x, nx) * cover;
    }
    let k = u32(max(wanted, 1.0));
    let kf = f32(k);
    let m = f32(k * k);
    let cut = shooter_cut(s);
    let cut_shooter = is_cut(cut);
    // The share of the parallelogram on the triangle: sub-areas are A_s
    // times each cell's share of it.
    var kept = 1.0;
    if (cut_shooter) {
        kept = max(cut_cell(vec2<f32>(0.0), vec2<f32>(1.0), cut).x, 1e-12);
    }
    var sum = 0.0;
    for (var j = 0u; j < k; j++) {
        for (var i = 0u; i < k; i++) {
            var cell = vec3<f32>(1.0, (f32(i) + 0.5) / kf, (f32(j) + 0.5) / kf);
            if (cut_shooter) {
                cell = cut_cell(vec2<f32>(f32(i), f32(j)) / kf, vec2<f32>(f32(i + 1u), f32(j + 1u)) / kf, cut);
                if (cell.x <= 0.0) {
                    continue;
                }
            }
            let sub = area * cell.x / (m * kept);
            let c = s.corner.xyz + s.su.xyz * cell.y + s.sv.xyz * cell.z;
            let d = x - c;
            let r2 = dot(d, d);
            let rl = sqrt(r2);
            if (rl <= 0.0) {
                continue;
            }
            let cs = dot(s.n.xyz, d) / rl;
            let cx = -dot(nx, d) / rl;
            if (cs > 0.0 && cx > 0.0) {
                sum += sub * cs * cx / (PI * r2 + sub);
            }
        }
    }
    return sum;
}
