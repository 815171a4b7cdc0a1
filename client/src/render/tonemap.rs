//! Linear HDR radiosity to 8-bit sRGB: the curve of `lightwire bake`'s
//! PNGs (server `bake.rs`, `white_point` and `tone_map_with`) and of the
//! dashboard, reimplemented here because the client may not depend on the
//! server. The fragment shader (`view.wgsl`) applies the same curve per
//! pixel; [`tone_map`] is its CPU twin, for tests and tools.
//!
//! `y = 1 - exp(-B * exposure)` per channel, then the sRGB transfer
//! function. The automatic exposure is `1 / white point`, the white point
//! being the 95th percentile of the luminance of covered texels (texels
//! with any light), so that a lightmap's bright-but-typical surfaces land
//! near `1 - 1/e` (about 0.63, sRGB 0.82, 8-bit 208) whatever the scene's units.

/// The 95th percentile of covered texels' luminance (Rec. 709 weights);
/// 1 for a lightmap without light. Same as the server's `bake::white_point`.
pub fn white_point(texels: &[[f32; 3]]) -> f32 {
    let mut lum: Vec<f32> = texels
        .iter()
        .map(|p| 0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2])
        .filter(|l| *l > 0.0)
        .collect();
    lum.sort_by(f32::total_cmp);
    lum.get(lum.len() * 95 / 100)
        .copied()
        .unwrap_or(1.0)
        .max(1e-12)
}

/// The exposure `lightwire bake` would use for this lightmap.
pub fn auto_exposure(texels: &[[f32; 3]]) -> f32 {
    1.0 / white_point(texels)
}

/// The sRGB transfer function (IEC 61966-2-1) of a value in [0, 1].
pub fn srgb_encode(y: f32) -> f32 {
    if y <= 0.003_130_8 {
        12.92 * y
    } else {
        1.055 * y.powf(1.0 / 2.4) - 0.055
    }
}

/// One radiosity value to 8-bit sRGB, as the renderer's fragment shader
/// does (negative values count as 0).
pub fn tone_map(rgb: [f32; 3], exposure: f32) -> [u8; 3] {
    rgb.map(|b| {
        let y = 1.0 - (-b.max(0.0) * exposure).exp();
        (srgb_encode(y.clamp(0.0, 1.0)).clamp(0.0, 1.0) * 255.0).round() as u8
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_white_point_is_the_95th_percentile_of_covered_texels() {
        // 100 covered texels of luminance 1..=100 and many uncovered ones:
        // uncovered (zero) texels do not drag the white point down.
        let mut texels: Vec<[f32; 3]> = (1..=100).map(|i| [i as f32; 3]).collect();
        texels.extend(std::iter::repeat_n([0.0; 3], 1000));
        assert!((white_point(&texels) - 96.0).abs() < 1e-3);
        assert_eq!(white_point(&[[0.0; 3]; 4]), 1.0, "no light: exposure 1");
    }

    #[test]
    fn the_curve_matches_bakes_png_encoding() {
        // At the white point: 1 - 1/e = 0.632 -> sRGB 0.8165 -> 208.
        assert_eq!(tone_map([1.0, 0.0, -1.0], 1.0), [208, 0, 0]);
        // Saturates towards white, never above.
        assert_eq!(tone_map([1e6; 3], 1.0), [255; 3]);
        // The linear segment of sRGB near black.
        assert_eq!(tone_map([1e-4, 0.0, 0.0], 1.0), [0, 0, 0]);
    }
}
