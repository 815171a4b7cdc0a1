//! The one tone curve (`lightwire_protocol::tone`) against the shared
//! vectors in `tests/vectors/tone.json`, which the dashboard's
//! `server/dashboard/test/tone.test.mjs` checks its JavaScript twin with.

use std::path::PathBuf;

use lightwire_protocol::tone::{
    auto_exposure, exposure_for, srgb_encode, tone_map, tone_map_image, white_point,
};
use serde_json::Value;

fn vectors() -> Value {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/vectors/tone.json");
    let text = std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("reading {}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("parsing {}: {e}", path.display()))
}

/// The cases of the vectors' list `key`, at least `at_least` of them.
fn cases(key: &str, at_least: usize) -> Vec<Value> {
    let Value::Array(cases) = vectors()[key].take() else {
        panic!("{key} is not an array");
    };
    assert!(cases.len() >= at_least, "{key}: {} cases", cases.len());
    cases
}

/// A JSON number as the f32 it stands for (parsed, then rounded to f32:
/// what the JavaScript test does with `Math.fround`).
fn f32_of(v: &Value) -> f32 {
    v.as_f64().unwrap_or_else(|| panic!("{v} is not a number")) as f32
}

fn rgb_of(v: &Value) -> [f32; 3] {
    let a = v.as_array().unwrap_or_else(|| panic!("{v} is not a texel"));
    assert_eq!(a.len(), 3, "{v} is not a texel");
    [f32_of(&a[0]), f32_of(&a[1]), f32_of(&a[2])]
}

fn texels_of(v: &Value) -> Vec<[f32; 3]> {
    v.as_array()
        .unwrap_or_else(|| panic!("{v} is not a list of texels"))
        .iter()
        .map(rgb_of)
        .collect()
}

fn bytes_of(v: &Value) -> Vec<u8> {
    v.as_array()
        .unwrap_or_else(|| panic!("{v} is not a list of bytes"))
        .iter()
        .map(|b| {
            b.as_u64()
                .and_then(|b| u8::try_from(b).ok())
                .unwrap_or_else(|| panic!("{b} is not a byte"))
        })
        .collect()
}

/// The curve in f64, before rounding to a byte: the vectors' outputs must
/// lie clear of a rounding boundary, or an f64 twin could round the other
/// way.
fn unrounded(b: f32, exposure: f32) -> f64 {
    let y = 1.0 - (-f64::from(b.max(0.0)) * f64::from(exposure)).exp();
    let y = y.clamp(0.0, 1.0);
    let s = if y <= 0.003_130_8 {
        12.92 * y
    } else {
        1.055 * y.powf(1.0 / 2.4) - 0.055
    };
    s.clamp(0.0, 1.0) * 255.0
}

fn assert_clear_of_boundaries(b: f32, exposure: f32, what: &str) {
    let u = unrounded(b, exposure);
    if u > 0.0 && u < 255.0 {
        let margin = (u - u.floor() - 0.5).abs();
        assert!(
            margin >= 0.02,
            "{what}: {b} at exposure {exposure} is {u} / 255, too close to a rounding boundary for a shared vector"
        );
    }
}

#[test]
fn white_points_match_the_shared_vectors() {
    for case in cases("white_points", 10) {
        let name = case["name"].as_str().unwrap_or("?");
        let texels = texels_of(&case["texels"]);
        let want = f32_of(&case["white"]);
        assert_eq!(white_point(&texels), want, "{name}");
        assert_eq!(auto_exposure(&texels), 1.0 / want, "{name}: exposure");
    }
}

#[test]
fn pixels_match_the_shared_vectors() {
    for case in cases("pixels", 30) {
        let rgb = rgb_of(&case["rgb"]);
        let exposure = f32_of(&case["exposure"]);
        let want = bytes_of(&case["bytes"]);
        assert_eq!(tone_map(rgb, exposure).to_vec(), want, "{case}");
        for b in rgb {
            assert_clear_of_boundaries(b, exposure, &case.to_string());
        }
    }
}

#[test]
fn images_match_the_shared_vectors() {
    for case in cases("images", 1) {
        let name = case["name"].as_str().unwrap_or("?");
        let texels = texels_of(&case["texels"]);
        let width = case["width"].as_u64().unwrap_or(0) as usize;
        let height = case["height"].as_u64().unwrap_or(0) as usize;
        assert_eq!(texels.len(), width * height, "{name}: size");
        let white = white_point(&texels);
        assert_eq!(white, f32_of(&case["white"]), "{name}: white point");
        assert_eq!(
            tone_map_image(&texels, white),
            bytes_of(&case["bytes"]),
            "{name}: bytes"
        );
        for b in texels.iter().flatten() {
            assert_clear_of_boundaries(*b, exposure_for(white), name);
        }
    }
}

#[test]
fn srgb_encode_is_the_iec_transfer_function() {
    assert_eq!(srgb_encode(0.0), 0.0);
    assert!((srgb_encode(1.0) - 1.0).abs() < 1e-6);
    assert!((srgb_encode(0.003_130_8) - 0.040_45).abs() < 1e-5);
    // Continuous at the knee.
    assert!((srgb_encode(0.003_130_9) - srgb_encode(0.003_130_8)).abs() < 1e-5);
}

// The two tests below were the client's (`client/src/render/tonemap.rs`)
// before the curve moved here; their assertions are unchanged.

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

#[test]
fn negative_and_nan_radiosity_count_as_zero() {
    assert_eq!(tone_map([-1.0, f32::NAN, -0.0], 1.0), [0, 0, 0]);
    assert_eq!(tone_map([f32::INFINITY; 3], 1.0), [255; 3]);
}
