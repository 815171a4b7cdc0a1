//! A scene and its lightmap atlas, loaded together: what every command and
//! the service start from.
//!
//! [`crate`] parses and validates a scene file on its own terms
//! (shapes, materials, objects); whether its lightmap fits the atlas size
//! it asks for is the atlas's question ([`Atlas::build`] plans and packs
//! the charts once). [`load_scene`] asks both and reports either answer as
//! a [`SceneError`] naming the file, so `scene` and `atlas` do not depend
//! on each other.

use std::path::Path;

use crate::atlas::Atlas;
use crate::{LoadOptions, Scene, SceneError};

/// Reads, parses and validates the scene file at `path` and builds its
/// atlas. An atlas that does not fit is an invalid scene, reported like
/// any other problem of the file.
pub fn load_scene(path: &Path, options: LoadOptions) -> Result<(Scene, Atlas), SceneError> {
    let scene = Scene::load_with(path, options)?;
    with_atlas(scene, &path.display().to_string())
}

/// [`load_scene`] for scene JSON in memory; `origin` names it in errors.
pub fn parse_scene(
    text: &str,
    origin: &str,
    options: LoadOptions,
) -> Result<(Scene, Atlas), SceneError> {
    let scene = Scene::parse_with(text, origin, options)?;
    with_atlas(scene, origin)
}

fn with_atlas(scene: Scene, origin: &str) -> Result<(Scene, Atlas), SceneError> {
    match Atlas::build(&scene) {
        Ok(atlas) => Ok((scene, atlas)),
        Err(issue) => Err(SceneError::Invalid {
            origin: origin.to_string(),
            issues: vec![issue],
        }),
    }
}
