// requires: common.wgsl, hemicube.wgsl
enable clip_distances;
// The hemicube rasterizer drawn in one instanced draw per pass
// (gpu/hemicube.rs `Draws::One`): the viewport is the whole target, ROWS
// slots high and five faces wide, and instance `slot * 5 + face` moves its
// face's clip space into that face's cell; four clip distances (the face's
// x = ±w and y = ±w planes, linear in clip space, so clipping against them
// is exact) cut each triangle to its cell, as the per-face viewport and
// scissor do in hemicube_faces.wgsl. One draw instead of 5 per slot: a
// draw has a fixed cost on every GPU, and on a software rasterizer it is
// most of a small scene's hemicube time. Needs Features::CLIP_DISTANCES.

// Slots the target holds: the viewport's height in face cells.
override ROWS: f32 = 1.0;

// Clip position `c` of face `ii % 5` of slot `ii / 5` (its own x, y in
// [-w, w]) in the whole target: x' / w = (2 face + 1 + x / w) / 5 - 1, and
// as the framebuffer's rows run down while NDC's y runs up,
// y' / w = 1 - (2 slot + 1 - y / w) / ROWS.
fn in_target(c: vec4<f32>, ii: u32) -> vec4<f32> {
    let face = f32(ii % 5u);
    let slot = f32(ii / 5u);
    let x = (c.x + (2.0 * face - 4.0) * c.w) / 5.0;
    let y = (c.y + (ROWS - 2.0 * slot - 1.0) * c.w) / ROWS;
    return vec4<f32>(x, y, c.z, c.w);
}

// Non-negative inside the part of face `ii % 5`'s cell that a hemicube
// uses: w - x, w + x, w - y, and w + y on the top face, y on a side face,
// whose lower half lies below the horizon (as the per-face scissor in
// gpu/hemicube.rs).
fn face_bounds(c: vec4<f32>, ii: u32) -> array<f32, 4> {
    let bottom = select(c.y, c.w + c.y, ii % 5u == 0u);
    return array<f32, 4>(c.w - c.x, c.w + c.x, c.w - c.y, bottom);
}

struct ItemOut {
    @builtin(position) clip: vec4<f32>,
    @builtin(clip_distances) bounds: array<f32, 4>,
    @location(0) @interpolate(flat) id: u32,
};

@vertex
fn vs_main(@builtin(vertex_index) vi: u32, @builtin(instance_index) ii: u32) -> ItemOut {
    let v = item_vertex(vi, ii);
    return ItemOut(in_target(v.clip, ii), face_bounds(v.clip, ii), v.id);
}

struct RadOut {
    @builtin(position) clip: vec4<f32>,
    @builtin(clip_distances) bounds: array<f32, 4>,
    @location(0) @interpolate(flat) chart: vec4<u32>,
    @location(2) st: vec2<f32>,
    @location(3) offset: vec3<f32>,
};

@vertex
fn vs_rad(@builtin(vertex_index) vi: u32, @builtin(instance_index) ii: u32) -> RadOut {
    let v = rad_vertex(vi, ii);
    return RadOut(in_target(v.clip, ii), face_bounds(v.clip, ii), v.chart, v.st, v.offset);
}
