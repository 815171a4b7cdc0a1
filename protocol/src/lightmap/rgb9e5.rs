//! RGB9E5: three 9-bit mantissas sharing one 5-bit exponent, 4 bytes per
//! texel. The algorithm is the one of OpenGL's EXT_texture_shared_exponent
//! (§"Shared exponent texture format", the `float3_to_rgb9e5` reference
//! code), which is also Vulkan's `E5B9G9R9_UFLOAT_PACK32` and wgpu's
//! `Rgb9e5Ufloat`, so a client can upload tiles to a GPU texture unchanged.
//!
//! Bit layout of the `u32` (sent little-endian):
//!
//! ```text
//!  31    27 26       18 17        9 8         0
//! [ exp:5  ][  blue:9  ][ green:9  ][  red:9   ]
//! ```
//!
//! A channel decodes to `mantissa * 2^(exp - 15 - 9)`.

/// Mantissa bits per channel.
const N: i32 = 9;
/// Exponent bias.
const B: i32 = 15;
/// The largest value a channel can hold: `(2^9 - 1) / 2^9 * 2^(31 - 15)`.
pub const RGB9E5_MAX: f32 = 65408.0;

/// Encodes linear RGB. Negative values and NaN become 0, values above
/// [`RGB9E5_MAX`] (including +inf) become [`RGB9E5_MAX`]. Rounds each channel
/// to the nearest representable value at the shared exponent (ties away
/// from zero), exactly as the reference code does.
pub fn rgb9e5_encode(rgb: [f32; 3]) -> u32 {
    // Not `clamp`: it passes NaN through. `NaN > 0.0` is false, so NaN -> 0.
    let c = rgb.map(|v| f64::from(if v > 0.0 { v.min(RGB9E5_MAX) } else { 0.0 }));
    let maxc = c[0].max(c[1]).max(c[2]);

    // floor(log2(maxc)), clamped below at -B-1; exact from the exponent bits
    // (every value below 2^-16 clamps anyway, so subnormals need no care).
    let floor_log2 = if maxc < f64::from(f32::MIN_POSITIVE) {
        -B - 1
    } else {
        (((maxc as f32).to_bits() >> 23) as i32 - 127).max(-B - 1)
    };
    let mut exp = floor_log2 + 1 + B;
    // Dividing by a power of two and adding 0.5 are exact in f64.
    let maxs = (maxc / exp2(exp - B - N) + 0.5).floor();
    if maxs == f64::from(1 << N) {
        exp += 1;
    }
    let scale = exp2(exp - B - N);
    let m = c.map(|v| (v / scale + 0.5).floor() as u32);
    debug_assert!(m.iter().all(|&v| v < (1 << N)) && (0..32).contains(&exp));
    ((exp as u32) << 27) | (m[2] << 18) | (m[1] << 9) | m[0]
}

/// Decodes RGB9E5 to linear RGB. Every `u32` is valid.
pub fn rgb9e5_decode(v: u32) -> [f32; 3] {
    let exp = (v >> 27) as i32;
    let scale = exp2(exp - B - N);
    [v & 0x1ff, (v >> 9) & 0x1ff, (v >> 18) & 0x1ff].map(|m| (f64::from(m) * scale) as f32)
}

/// 2^e for the small integer exponents used here (-25..=7), exactly.
fn exp2(e: i32) -> f64 {
    f64::from_bits(((e + 1023) as u64) << 52)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reference_values() {
        assert_eq!(rgb9e5_encode([0.0; 3]), 0);
        // 1.0 = 256 * 2^(16 - 24): exponent 16, mantissa 256.
        assert_eq!(rgb9e5_encode([1.0, 0.0, 0.0]), (16 << 27) | 256);
        assert_eq!(rgb9e5_decode((16 << 27) | 256), [1.0, 0.0, 0.0]);
        assert_eq!(
            rgb9e5_decode(rgb9e5_encode([RGB9E5_MAX; 3])),
            [RGB9E5_MAX; 3]
        );
        assert_eq!(
            rgb9e5_decode(rgb9e5_encode([f32::INFINITY, -1.0, f32::NAN])),
            [RGB9E5_MAX, 0.0, 0.0]
        );
    }
}
