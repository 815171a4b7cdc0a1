//! Linear HDR radiosity to 8-bit sRGB: the one tone curve of
//! [`lightwire_protocol::tone`] (white point, exposure, curve, sRGB), the
//! same as `lightwire bake`'s PNGs and the dashboard's. This module
//! re-exports it under the renderer's names.
//!
//! The fragment shader (`view.wgsl`) is its GPU twin: the same formula per
//! pixel, `srgb(clamp(1 - exp(-max(B, 0) * exposure), 0, 1))`, written to an
//! 8-bit target. [`tone_map`] is its CPU twin, for tests and tools; a GPU's
//! `exp` and `pow` are accurate to a few ulps, so a pixel may differ by one
//! step where a value lies on an 8-bit rounding boundary.

pub use lightwire_protocol::tone::{auto_exposure, srgb_encode, tone_map, white_point};
