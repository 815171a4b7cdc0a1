//! A scene loaded for solving: [`lightwire_scene::load::load_scene`], then
//! the samples the static world encloses moved into the open part of their
//! texels ([`crate::validity::relocate`]). Every command that solves
//! (`bake`, `serve`, the benches) loads through here, so they all light
//! the same samples.

use std::path::Path;

use lightwire_scene::atlas::Atlas;
use lightwire_scene::{LoadOptions, Scene, SceneError};

/// Reads, validates and lays out the scene at `path` and relocates its
/// enclosed samples.
pub fn load_scene(path: &Path, options: LoadOptions) -> Result<(Scene, Atlas), SceneError> {
    let (scene, mut atlas) = lightwire_scene::load::load_scene(path, options)?;
    let moved = crate::validity::relocate(&scene, &mut atlas);
    if moved > 0 {
        tracing::info!(
            "{}: {moved} texel samples inside geometry moved to the open part of their texel",
            path.display()
        );
    }
    Ok((scene, atlas))
}
