// Required by every other file in shaders/: the shooter record, the batch
// constants, patch ranges, the element record, object flags and the
// hemicube face projection.
// Rasterization (hemicube.wgsl) and the lookup in the reconstruction
// shaders (`visibility` in receive.wgsl) must use the very same
// projection, so it lives here once.

// One shooter: a rectangle of elements of the shooting patch (thesis §4.3.3,
// dynamic shooter subdivision). Mirrors `GpuShooter` in server/src/gpu/progressive/shooters.rs
// (sizes checked by the tests of server/src/gpu/shaders.rs).
// Most shooters a batch holds: the size of the uniform arrays that hold
// them (`MAX_BATCH` in server/src/gpu/progressive/shooters.rs). A uniform
// buffer, not a storage buffer, because every receiver reads every shooter:
// uniform reads are what GPUs cache for that, and lavapipe turns each
// storage-buffer read into a loop over the lanes.
const MAX_BATCH: u32 = 128u;

struct Shooter {
    // xyz: corner of the shooter's region (world), w: its area (m²).
    corner: vec4<f32>,
    // Edge vectors of the region (world); su.w: the bitcast chart width of
    // the shooter's patch (a batch may shoot several patches), zero for a
    // cluster of triangles, whose tile.xy is then a range of `members`
    // (progressive.wgsl).
    // sv.w: the first coefficient of the cut (see `shooter_cut`).
    su: vec4<f32>,
    sv: vec4<f32>,
    // xyz: hemicube eye (region centre lifted off the surface); w: the
    // bitcast first element of the shooter's patch.
    eye: vec4<f32>,
    // Orthonormal frame of the hemicube: two tangents and the normal;
    // n.w is the bitcast id of the shooting patch; t1.w, t2.w: the second
    // and third coefficients of the cut.
    t1: vec4<f32>,
    t2: vec4<f32>,
    n: vec4<f32>,
    // Element tile in chart texels: a0, b0, a1, b1 (half-open).
    tile: vec4<u32>,
};

// The cut of a shooter's region: the region is the parallelogram
// corner + x su + y sv, (x, y) in [0, 1]², and, when the cut's first two
// coefficients are not both zero, only its part where
// cut.x * x + cut.y * y + cut.z >= 0. A tile of a triangle's chart that
// straddles the chart's diagonal is cut by the diagonal (its triangle is
// the half t <= s, server/src/gpu/progressive/shooters.rs); every other
// shooter is uncut (all three zero).
fn shooter_cut(s: Shooter) -> vec3<f32> {
    return vec3<f32>(s.sv.w, s.t1.w, s.t2.w);
}

// Whether any shooter may be cut: false for a scene without triangle
// patches (server/src/gpu/progressive/pipelines.rs `cut_constants`), whose
// shooters never are, so that the compiler drops the cut code, which a SIMD
// rasterizer (lavapipe) would otherwise run under a mask for every lane.
override CUT_SHOOTERS: bool = true;

fn is_cut(cut: vec3<f32>) -> bool {
    return CUT_SHOOTERS && (cut.x != 0.0 || cut.y != 0.0);
}

// Running sums of a polygon clipped by a line, taken edge by edge: a convex
// polygon clipped by a line is the kept parts of its edges plus one edge
// along the line, from the point where its boundary leaves the kept side
// (`exit`) to the point where it comes back (`entry`); both stay zero when
// it does not cross. Sums over edges do not depend on their order, so no
// list of vertices is kept: a list indexed at run time lives in memory
// rather than registers, and on a SIMD rasterizer (lavapipe runs every
// branch of every invocation under a mask) it cost more than the rest of
// the receiving shader (issue 19).
struct Clip2 {
    // Twice the signed area (shoelace) and the first moment times six.
    twice: f32,
    moment: vec2<f32>,
    exit: vec2<f32>,
    entry: vec2<f32>,
};

fn shoelace_edge(acc: ptr<function, Clip2>, a: vec2<f32>, b: vec2<f32>) {
    let w = a.x * b.y - b.x * a.y;
    (*acc).twice += w;
    (*acc).moment += (a + b) * w;
}

// The part of an edge a clipping line keeps: from `p` to `q`, if `any`.
struct Kept {
    p: vec2<f32>,
    q: vec2<f32>,
    any: bool,
};

// Edge a -> b of a polygon clipped by the line of `cut` (kept where
// cut.x x + cut.y y + cut.z >= 0); where the boundary leaves or comes back
// to the kept side is noted in `acc`.
fn clip_by_line(acc: ptr<function, Clip2>, a: vec2<f32>, b: vec2<f32>, cut: vec3<f32>) -> Kept {
    let ha = dot(cut.xy, a) + cut.z;
    let hb = dot(cut.xy, b) + cut.z;
    let ka = ha >= 0.0;
    let kb = hb >= 0.0;
    // Used only where the signs differ (then ha != hb).
    let m = a + (b - a) * (ha / (ha - hb));
    if (ka && !kb) {
        (*acc).exit = m;
    }
    if (!ka && kb) {
        (*acc).entry = m;
    }
    return Kept(select(m, a, ka), select(m, b, kb), ka || kb);
}

// Edge a -> b of the polygon, kept where cut.x x + cut.y y + cut.z >= 0.
fn clip_edge_2d(acc: ptr<function, Clip2>, a: vec2<f32>, b: vec2<f32>, cut: vec3<f32>) {
    let kept = clip_by_line(acc, a, b, cut);
    if (kept.any) {
        shoelace_edge(acc, kept.p, kept.q);
    }
}

// The share of the cell [lo, hi] of the unit square that lies on the kept
// side of `cut` (one clipping step and the shoelace formula), in .x; the
// centroid of that part in .yz (the cell's centre when none is).
fn cut_cell(lo: vec2<f32>, hi: vec2<f32>, cut: vec3<f32>) -> vec3<f32> {
    var acc = Clip2(0.0, vec2<f32>(0.0), vec2<f32>(0.0), vec2<f32>(0.0));
    let c1 = vec2<f32>(hi.x, lo.y);
    let c3 = vec2<f32>(lo.x, hi.y);
    clip_edge_2d(&acc, lo, c1, cut);
    clip_edge_2d(&acc, c1, hi, cut);
    clip_edge_2d(&acc, hi, c3, cut);
    clip_edge_2d(&acc, c3, lo, cut);
    shoelace_edge(&acc, acc.exit, acc.entry);
    let full = (hi.x - lo.x) * (hi.y - lo.y);
    if (full <= 0.0 || abs(acc.twice) <= 1e-12 * full) {
        return vec3<f32>(0.0, (lo + hi) * 0.5);
    }
    return vec3<f32>(abs(acc.twice) * 0.5 / full, acc.moment / (3.0 * acc.twice));
}

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

// A patch's elements: first element, element count, chart width, chart
// height, and whether the patch is a triangle: 0 a quad, 1 a triangle (the
// half t <= s of its chart, server/src/scene/mod.rs), 2 a triangle on its
// mesh's own lightmap UVs (server/src/atlas/uv.rs), whose frame is its
// `PatchFrame` (receive.wgsl), since its corner texels do not lie on its
// corners, 3 a parallelogram on its mesh's lightmap UVs (the same, whole).
// Mirrors `PatchRange` in server/src/gpu/placement.rs.
struct PatchRange {
    first: u32,
    count: u32,
    w: u32,
    h: u32,
    triangle: u32,
};

const ON_OWN_CHART_TRIANGLE: u32 = 1u;
const TRIANGLE_ON_LIGHTMAP: u32 = 2u;
const QUAD_ON_LIGHTMAP: u32 = 3u;

// Whether a patch's `PatchRange::triangle` says it lies on its mesh's own
// lightmap UVs (its hemicube vertices carry chart coordinates).
fn on_lightmap(triangle: u32) -> bool {
    return triangle == TRIANGLE_ON_LIGHTMAP || triangle == QUAD_ON_LIGHTMAP;
}

// The element of patch `p` nearest to patch parameters `st` on its chart
// (`element_in_chart`).
fn element_at(p: PatchRange, st: vec2<f32>) -> u32 {
    return element_in_chart(p.first, p.w, p.h, p.triangle, st);
}

// The element nearest to `st` on the chart of `w` x `h` texels from element
// `first` (texel centres lie on the patch edges, thesis §4.1): the texel
// `st` rounds to. On a triangle the texels above the chart's diagonal
// (b > a) stand for no surface and hold no light (server/src/atlas.rs), so
// a fragment that interpolation put a hair above the diagonal edge reads
// the diagonal texel of its column instead (wallner §2: a triangle's texels
// are those its footprint covers). On a patch on its mesh's lightmap,
// `st` is already in chart coordinates (its hemicube vertices carry them,
// server/src/gpu/hemicube.rs `patch_vertices`), and the texel a point of
// the patch rounds to overlaps the patch.
fn element_in_chart(first: u32, w: u32, h: u32, triangle: u32, st: vec2<f32>) -> u32 {
    if (on_lightmap(triangle)) {
        let c = clamp(round(st), vec2<f32>(0.0), vec2<f32>(f32(w - 1u), f32(h - 1u)));
        return first + u32(c.y) * w + u32(c.x);
    }
    let c = clamp(st, vec2<f32>(0.0), vec2<f32>(1.0));
    let a = u32(round(c.x * f32(w - 1u)));
    var b = u32(round(c.y * f32(h - 1u)));
    if (triangle == ON_OWN_CHART_TRIANGLE) {
        b = min(b, a);
    }
    return first + b * w + a;
}

// Texels per row of the textures of what the static set shows moving
// tiles' hemicubes, one texel per element (`shade_static` in
// redistribute.wgsl, read by its hemicube passes; `SHOWN_WIDTH` in
// solve/src/gpu/progressive/redistribute/mod.rs).
const SHOWN_WIDTH: u32 = 2048u;

fn shown_texel(e: u32) -> vec2<i32> {
    return vec2<i32>(i32(e % SHOWN_WIDTH), i32(e / SHOWN_WIDTH));
}

// An empty item-buffer pixel (`fs_clear_items` in hemicube.wgsl); no patch
// selected.
const NO_PATCH: u32 = 0xffffffffu;

// Bits of `object_flags`, one word per scene object.
// MOVING: the object is in the moved set M of the running redistribution.
const OBJECT_MOVING: u32 = 1u;
// ABSENT: the object is removed from the simulation (thesis §4.5.2): it is
// not rasterized, does not receive and does not shoot.
const OBJECT_ABSENT: u32 = 2u;
// PASSIVE: the object occludes and is drawn in the hemicubes, but its
// elements neither receive nor shoot in progressive iterations: a cross
// session's moving objects, whose light comes from each move's gathers
// and shots (redistribute.wgsl), while the static set is refined around
// them (server/src/gpu/dynamic.rs).
const OBJECT_PASSIVE: u32 = 4u;


// The hemicube face of shooter `s` that world direction `d` from its eye
// falls on (0 = top, 1..4 = sides; see `face_local`).
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

// Eye-space coordinates (right, up, forward) of world direction `d` in
// `face`: `d`'s coordinates (x, y, z) in the shooter's frame (t1, t2, n),
// ordered and signed by the face's axes (right, up, forward): face 0 (top)
// (t1, t2, n), 1 (t2, n, t1), 2 (-t2, n, -t1), 3 (-t1, n, t2), 4 (t1, n,
// -t2). Selects rather than a
// matrix per face: neighbouring invocations look through different faces,
// and a SIMD rasterizer (lavapipe) runs every case of a switch for them.
fn face_local(s: Shooter, face: u32, d: vec3<f32>) -> vec3<f32> {
    let x = dot(d, s.t1.xyz);
    let y = dot(d, s.t2.xyz);
    let z = dot(d, s.n.xyz);
    let right = select(select(select(x, -x, face == 3u), -y, face == 2u), y, face == 1u);
    let up = select(z, y, face == 0u);
    let forward = select(select(select(select(-y, y, face == 3u), -x, face == 2u), x, face == 1u), z, face == 0u);
    return vec3<f32>(right, up, forward);
}

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

// `albedo.w` of an element is 1 when it is invalid (inside or under
// geometry, server/src/validity.rs): it receives nothing.
fn is_invalid(el: Element) -> bool {
    return (u32(el.albedo.w) & 1u) != 0u;
}
