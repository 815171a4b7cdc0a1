//! The tone curve: linear HDR radiosity to 8-bit sRGB, for viewing.
//!
//! Every picture Lightwire shows goes through this one curve: the PNGs of
//! `lightwire bake` and `GET /api/scenes/{id}/lightmap.png` (server
//! `bake.rs`), the client's `view` renderer (`client/src/render/tonemap.rs`
//! re-exports this module; its fragment shader `view.wgsl` is the GPU
//! twin) and the dashboard (`server/dashboard/src/tone.js` is the
//! JavaScript twin; its WebGL shader in `view3d.js` the GPU one). The
//! shared vectors in `protocol/tests/vectors/tone.json` pin it: the Rust
//! test `protocol/tests/tone.rs` and the dashboard's
//! `server/dashboard/test/tone.test.mjs` both check them.
//!
//! # The curve
//!
//! 1. **White point** `w` ([`white_point`]): the 95th percentile of the
//!    luminance `L = 0.2126 R + 0.7152 G + 0.0722 B` (Rec. 709 weights,
//!    computed in `f32`) of the *covered* texels, those with `L > 0`;
//!    uncovered (zero) texels do not drag it down. Sorted ascending, it is
//!    the value at index `n * 95 / 100` (integer division) of the `n`
//!    covered luminances; 1 when no texel has light; never below `1e-12`.
//! 2. **Exposure** `k = 1 / w` ([`exposure_for`], [`auto_exposure`]), so a
//!    lightmap's bright-but-typical surfaces land in the same place whatever
//!    the scene's units. A viewer may scale it (`view --exposure`, the
//!    dashboard's slider in stops); the curve below takes `k` as given.
//! 3. **Curve**, per channel: `y = 1 - exp(-max(B, 0) * k)`. It never
//!    clips: the white point maps to `1 - 1/e` (about 0.632, sRGB 0.8165,
//!    8-bit 208) and brighter values approach 1. Negative and NaN radiosity
//!    count as 0.
//! 4. **Encoding**: the sRGB transfer function ([`srgb_encode`],
//!    IEC 61966-2-1) of `y` clamped to [0, 1], then
//!    `round(clamp(s, 0, 1) * 255)`, halves away from zero.
//!
//! This is the curve `lightwire bake` has always used, and the client's
//! renderer already used it; it was chosen over the dashboard's because
//! `bake`'s PNGs (and the client frames compared with them) then stay
//! bit-identical and the rule needs nothing but the texels. The dashboard
//! used to approximate it (a white point from a log2 histogram in 1/8-stop
//! bins that left out emitting surfaces, and a 4096-entry sRGB table
//! indexed by truncation); it now computes this one exactly.
//!
//! What that costs: emitters count. When lights cover more than 5% of the
//! covered texels the white point is a light's luminance and the rest of
//! the picture is dark (of the chart texels, lights are 0.9% in
//! cornell-blocks, 2.0% in indirect-light, 3.6% in cornell-small and
//! cornell-large, but 5.6% in cornell-low, 50% in plates, 100% in
//! furnace); the dashboard's slider and `view --exposure` compensate.
//! Leaving emitters out would need every tone mapper to know the scene's
//! materials and would change `bake`'s PNGs and the client's frames.
//!
//! Twins in other languages compute in double precision where this code
//! uses `f32`; the results differ only when a value lies within about
//! `1e-5` of an 8-bit rounding boundary, and the shared vectors stay clear
//! of those. A GPU computes `exp` and `pow` to a few ulps, so a shader's
//! 8-bit output may be one step off at such boundaries.

/// The percentile of covered texels' luminance that becomes the white point.
pub const WHITE_PERCENTILE: usize = 95;

/// The smallest white point (so the exposure stays finite).
pub const MIN_WHITE: f32 = 1e-12;

/// Rec. 709 luminance of linear RGB, in `f32` in this order of operations
/// (the twins emulate it exactly).
pub fn luminance(rgb: [f32; 3]) -> f32 {
    0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2]
}

/// The white point of a lightmap or image: the [`WHITE_PERCENTILE`]th
/// percentile of covered texels' [`luminance`]; 1 for one without light.
pub fn white_point(texels: &[[f32; 3]]) -> f32 {
    let mut lum: Vec<f32> = texels
        .iter()
        .map(|p| luminance(*p))
        .filter(|l| *l > 0.0)
        .collect();
    lum.sort_by(f32::total_cmp);
    lum.get(lum.len() * WHITE_PERCENTILE / 100)
        .copied()
        .unwrap_or(1.0)
        .max(MIN_WHITE)
}

/// The exposure that puts `white` at the curve's white point: `1 / white`.
pub fn exposure_for(white: f32) -> f32 {
    1.0 / white.max(MIN_WHITE)
}

/// The exposure `lightwire bake` uses for these texels.
pub fn auto_exposure(texels: &[[f32; 3]]) -> f32 {
    exposure_for(white_point(texels))
}

/// The sRGB transfer function (IEC 61966-2-1) of a value in [0, 1].
pub fn srgb_encode(y: f32) -> f32 {
    if y <= 0.003_130_8 {
        12.92 * y
    } else {
        1.055 * y.powf(1.0 / 2.4) - 0.055
    }
}

/// One channel of radiosity to its 8-bit sRGB value at `exposure`.
pub fn encode_channel(b: f32, exposure: f32) -> u8 {
    let y = 1.0 - (-b.max(0.0) * exposure).exp();
    (srgb_encode(y.clamp(0.0, 1.0)).clamp(0.0, 1.0) * 255.0).round() as u8
}

/// One radiosity value to 8-bit sRGB at `exposure`.
pub fn tone_map(rgb: [f32; 3], exposure: f32) -> [u8; 3] {
    rgb.map(|b| encode_channel(b, exposure))
}

/// A row-major image to packed 8-bit RGB, exposed for white point `white`.
pub fn tone_map_image(pixels: &[[f32; 3]], white: f32) -> Vec<u8> {
    let exposure = exposure_for(white);
    pixels.iter().flat_map(|p| tone_map(*p, exposure)).collect()
}
