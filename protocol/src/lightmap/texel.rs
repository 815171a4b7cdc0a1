//! Quantizing one texel into its wire bytes and back, per [`PixelFormat`].

use half::f16;

use super::rgb9e5::{RGB9E5_MAX, rgb9e5_decode, rgb9e5_encode};
use crate::PixelFormat;

/// Encodes linear RGB as one texel, written little-endian into `out`
/// (exactly `format.bytes_per_texel()` bytes).
///
/// - `Rgb9e5`: [`rgb9e5_encode`], 4 bytes.
/// - `Rgba16f`: R, G, B as IEEE binary16 (round to nearest even; negative and
///   NaN become 0, above 65504 becomes 65504), then A = 1.0 (`0x3C00`),
///   each `u16` little-endian: 8 bytes.
pub fn quantize_into(format: PixelFormat, rgb: [f32; 3], out: &mut [u8]) {
    match format {
        PixelFormat::Rgb9e5 => out[..4].copy_from_slice(&rgb9e5_encode(rgb).to_le_bytes()),
        PixelFormat::Rgba16f => {
            for (i, v) in rgb.into_iter().enumerate() {
                // `NaN > 0.0` is false, so NaN -> 0 (`clamp` would keep NaN).
                let v = if v > 0.0 {
                    v.min(f32::from(f16::MAX))
                } else {
                    0.0
                };
                let h = f16::from_f32(v);
                out[2 * i..2 * i + 2].copy_from_slice(&h.to_bits().to_le_bytes());
            }
            out[6..8].copy_from_slice(&f16::ONE.to_bits().to_le_bytes());
        }
    }
}

/// Decodes one texel's wire bytes to linear RGB (alpha is ignored).
pub fn dequantize(format: PixelFormat, bytes: &[u8]) -> [f32; 3] {
    match format {
        PixelFormat::Rgb9e5 => {
            rgb9e5_decode(u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]))
        }
        PixelFormat::Rgba16f => [0, 1, 2]
            .map(|i| f16::from_bits(u16::from_le_bytes([bytes[2 * i], bytes[2 * i + 1]])).to_f32()),
    }
}

/// The largest finite channel value a format can hold.
pub const fn max_value(format: PixelFormat) -> f32 {
    match format {
        PixelFormat::Rgb9e5 => RGB9E5_MAX,
        PixelFormat::Rgba16f => 65504.0,
    }
}
