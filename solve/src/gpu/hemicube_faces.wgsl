// requires: common.wgsl, hemicube.wgsl
// The hemicube rasterizer drawn one face at a time (gpu/hemicube.rs
// `Draws::PerFace`): each draw has its face's viewport and scissor, so a
// vertex leaves in the face's own clip space and the rasterizer clips it
// to the face. Works on every device.

struct ItemOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) @interpolate(flat) id: u32,
};

@vertex
fn vs_main(@builtin(vertex_index) vi: u32, @builtin(instance_index) ii: u32) -> ItemOut {
    let v = item_vertex(vi, ii);
    return ItemOut(v.clip, v.id);
}

struct RadOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) @interpolate(flat) chart: vec4<u32>,
    @location(2) st: vec2<f32>,
    @location(3) offset: vec3<f32>,
};

@vertex
fn vs_rad(@builtin(vertex_index) vi: u32, @builtin(instance_index) ii: u32) -> RadOut {
    let v = rad_vertex(vi, ii);
    return RadOut(v.clip, v.chart, v.st, v.offset);
}
