//! RGB9E5 against its definition (EXT_texture_shared_exponent).

use lightwire_protocol::lightmap::{RGB9E5_MAX, rgb9e5_decode, rgb9e5_encode};
use proptest::prelude::*;

/// The tight error bound. Rounding to the shared exponent's step loses at
/// most half a step; the step is at most 2^-9 of the largest channel, except
/// when the largest channel rounds up to 2^9 and the exponent is bumped, in
/// which case the largest channel is at least 511.5 steps of the old size:
/// the bound is max / 511.5 (2^-9 would be exceeded by 0.1 %, see
/// `bumped_exponent_is_the_worst_case`). Below 2^-15 the exponent is clamped
/// and the error is at most half the smallest step, 2^-25.
fn bound(maxc: f32) -> f64 {
    (f64::from(maxc) / 511.5).max((2.0f64).powi(-25))
}

#[test]
fn known_encodings() {
    assert_eq!(rgb9e5_encode([0.0, 0.0, 0.0]), 0);
    assert_eq!(rgb9e5_encode([1.0, 0.5, 0.25]), 0x8101_0100);
    assert_eq!(rgb9e5_encode([65408.0, 0.0, 0.0]), 0xF800_01FF);
    // Smallest nonzero: mantissa 1 at exponent 0 = 2^-24.
    assert_eq!(rgb9e5_encode([2f32.powi(-24), 0.0, 0.0]), 1);
    assert_eq!(rgb9e5_decode(1), [2f32.powi(-24), 0.0, 0.0]);
}

#[test]
fn clamps_negative_nan_and_too_large() {
    assert_eq!(rgb9e5_encode([-1.0, f32::NAN, -0.0]), 0);
    assert_eq!(rgb9e5_encode([f32::NEG_INFINITY, 0.0, 0.0]), 0);
    let max = rgb9e5_decode(rgb9e5_encode([1e9, f32::INFINITY, 65409.0]));
    assert_eq!(max, [RGB9E5_MAX; 3]);
}

#[test]
fn bumped_exponent_is_the_worst_case() {
    // max = 1.999 rounds up to 512 * 2^-8, so the step becomes 2^-7; a
    // channel of 2^-8 sits exactly half a step off.
    let rgb = [1.999, 2f32.powi(-8), 0.0];
    let d = rgb9e5_decode(rgb9e5_encode(rgb));
    let err = f64::from((d[1] - rgb[1]).abs());
    assert!(err > f64::from(rgb[0]) * 2f64.powi(-9));
    assert!(err <= bound(rgb[0]));
}

proptest! {
    /// Every value RGB9E5 can represent survives encode(decode(bits))
    /// exactly (bit patterns may differ: small mantissas have several
    /// spellings, and the encoder picks the canonical one).
    #[test]
    fn representable_values_are_exact(bits in any::<u32>()) {
        let rgb = rgb9e5_decode(bits);
        prop_assert_eq!(rgb9e5_decode(rgb9e5_encode(rgb)), rgb);
        // and the encoder is idempotent on its own output
        let canon = rgb9e5_encode(rgb);
        prop_assert_eq!(rgb9e5_encode(rgb9e5_decode(canon)), canon);
    }

    #[test]
    fn relative_error_is_bounded_by_the_max_channel(
        e in -30i32..16, m in proptest::array::uniform3(0.0f32..2.0)
    ) {
        let rgb = m.map(|v| (v * 2f32.powi(e)).min(RGB9E5_MAX));
        let d = rgb9e5_decode(rgb9e5_encode(rgb));
        let maxc = rgb[0].max(rgb[1]).max(rgb[2]);
        for i in 0..3 {
            let err = f64::from((d[i] - rgb[i]).abs());
            prop_assert!(err <= bound(maxc), "channel {i}: {rgb:?} -> {d:?}, err {err}");
            if maxc >= 2f32.powi(-15) {
                // the usual statement, with the bumped-exponent slack
                prop_assert!(err <= f64::from(maxc) * 2f64.powi(-9) * (512.0 / 511.5));
            }
        }
    }

    #[test]
    fn arbitrary_floats_never_panic_and_stay_in_range(rgb in any::<[f32; 3]>()) {
        let d = rgb9e5_decode(rgb9e5_encode(rgb));
        prop_assert!(d.iter().all(|v| v.is_finite() && *v >= 0.0 && *v <= RGB9E5_MAX));
    }
}
