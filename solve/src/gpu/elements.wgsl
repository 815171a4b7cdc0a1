// requires: common.wgsl
// The elements (lightmap texels) as the compute passes of progressive.wgsl
// and redistribute.wgsl see them: their records, their radiosity and the
// buffers that describe patches and objects. Shared by those two files.

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

@group(0) @binding(0) var<storage, read> elements: array<Element>;
@group(0) @binding(1) var<storage, read_write> radiosity: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> unshot: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> patches: array<PatchRange>;
@group(0) @binding(11) var<storage, read> object_flags: array<u32>;
@group(0) @binding(13) var<storage, read> local_elements: array<LocalElement>;

// Threads per workgroup of the compute passes over elements.
const WG: u32 = 64u;

// Whether element `el` belongs to an object removed from the simulation.
fn absent(el: Element) -> bool {
    return (object_flags[bitcast<u32>(el.lookup.w)] & OBJECT_ABSENT) != 0u;
}

// Whether element `el` belongs to an object that occludes but neither
// receives nor shoots in progressive iterations (common.wgsl).
fn passive(el: Element) -> bool {
    return (object_flags[bitcast<u32>(el.lookup.w)] & OBJECT_PASSIVE) != 0u;
}
