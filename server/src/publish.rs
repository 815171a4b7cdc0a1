//! The one way from solver radiosity to the lightmap a client receives.
//!
//! A solver returns radiosity per element of the atlas, at the poses of
//! its state, and nothing else. What a viewer's bilinear filter reads is
//! more than that, in this order:
//!
//! 1. seams stitched: the elements of one place on several charts agree
//!    (`Atlas::stitch`, inside `Validity::fill`);
//! 2. invalid elements (inside or under geometry at the state's poses)
//!    filled from their valid neighbours on their own chart, so that a
//!    filter never blends in light that cannot be there (`Validity::fill`);
//! 3. scattered into the atlas texture, a texel shared by several
//!    elements of a mesh's own lightmap showing its owner;
//! 4. the gutters around the islands of a mesh's lightmap block filled;
//! 5. texels on either side of a seam between islands made to read alike
//!    (steps 3-5: `Atlas::to_image`).
//!
//! The live service ([`crate::service`]), `lightwire bake` ([`crate::bake`])
//! and the benchmarks ([`crate::bench`]) all publish through [`lightmap`],
//! so they cannot disagree on the order.

use glam::Vec3;
use lightwire_scene::atlas::Atlas;
use lightwire_solve::validity::Validity;

/// The lightmap image (row-major RGB, `atlas.width × atlas.height`) a
/// client receives for `radiosity` (per element of `atlas`) at a state
/// whose valid texels are `validity`. `radiosity` is left as published
/// (stitched and filled), for callers that compare it element by element.
pub fn lightmap(atlas: &Atlas, validity: &Validity, radiosity: &mut [Vec3]) -> Vec<[f32; 3]> {
    validity.fill(atlas, radiosity);
    atlas.to_image(radiosity)
}
