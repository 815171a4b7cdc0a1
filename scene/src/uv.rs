//! Lightmap-UV geometry that the scene's own UVs (validation, generated
//! UVs in [`unwrap`](crate::unwrap)) and the atlas's UV blocks
//! ([`atlas::uv`](crate::atlas::uv)) share. A leaf: it imports nothing of
//! the crate, so neither side has to import the other.

use glam::Vec2;

/// The side of a mesh's lightmap block is at most this many texels.
pub const MAX_SIDE: u32 = 4096;

/// Signed area of a UV triangle (positive counter-clockwise).
pub fn uv_area([a, b, c]: &[Vec2; 3]) -> f32 {
    0.5 * (*b - *a).perp_dot(*c - *a)
}
