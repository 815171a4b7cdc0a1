// The `view` renderer: quads in object space, placed by one model matrix per
// object, lit by the lightmap with bilinear filtering and tone-mapped with
// the one tone curve of `lightwire bake` (`protocol/src/tone.rs`, re-exported
// as client/src/render/tonemap.rs, is the CPU twin; `fs_main` computes the
// same formula).

struct Frame {
    // World to clip (reversed-Z, infinite far plane).
    view_proj: mat4x4<f32>,
    // Radiosity is multiplied by this before the tone curve.
    exposure: f32,
}

@group(0) @binding(0) var<uniform> frame: Frame;
// One model matrix per object of the scene, indexed by the vertex's object.
@group(0) @binding(1) var<storage, read> models: array<mat4x4<f32>>;
// Linear radiosity (RGB9E5 or RGBA16F as received; both filterable).
@group(0) @binding(2) var lightmap: texture_2d<f32>;
// Bilinear, clamp to edge, no mipmaps (mip levels would blend charts).
@group(0) @binding(3) var lightmap_sampler: sampler;

struct VertexIn {
    @location(0) position: vec3<f32>,
    @location(1) uv: vec2<f32>,
    @location(2) object: u32,
}

struct VertexOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) uv: vec2<f32>,
}

@vertex
fn vs_main(v: VertexIn) -> VertexOut {
    var out: VertexOut;
    out.clip = frame.view_proj * (models[v.object] * vec4<f32>(v.position, 1.0));
    out.uv = v.uv;
    return out;
}

// The sRGB transfer function (IEC 61966-2-1).
fn srgb(c: vec3<f32>) -> vec3<f32> {
    return select(1.055 * pow(c, vec3<f32>(1.0 / 2.4)) - 0.055, 12.92 * c, c <= vec3<f32>(0.0031308));
}

@fragment
fn fs_main(in: VertexOut) -> @location(0) vec4<f32> {
    let b = max(textureSampleLevel(lightmap, lightmap_sampler, in.uv, 0.0).rgb, vec3<f32>(0.0));
    let y = 1.0 - exp(-b * frame.exposure);
    return vec4<f32>(srgb(clamp(y, vec3<f32>(0.0), vec3<f32>(1.0))), 1.0);
}
