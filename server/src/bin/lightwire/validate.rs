//! `lightwire validate`: load scene files and say what is wrong with them.

use std::path::PathBuf;

use anyhow::Result;
use lightwire_scene::atlas::Atlas;
use lightwire_scene::load::load_scene;
use lightwire_scene::{LoadOptions, Scene};

/// `lightwire validate`'s arguments.
#[derive(clap::Args)]
pub(crate) struct ValidateArgs {
    /// Scene files.
    #[arg(required = true)]
    scenes: Vec<PathBuf>,
    /// Multiply every texel density by this factor.
    #[arg(long, default_value_t = 1.0)]
    density_scale: f32,
}

impl ValidateArgs {
    pub(crate) fn run(self) -> Result<()> {
        validate_command(&self.scenes, self.density_scale)
    }
}

pub(crate) fn load(path: &std::path::Path, density_scale: f32) -> Result<(Scene, Atlas)> {
    Ok(load_scene(path, LoadOptions::scaled(density_scale))?)
}

fn validate_command(paths: &[PathBuf], density_scale: f32) -> Result<()> {
    let mut failed = 0;
    for path in paths {
        match load(path, density_scale) {
            Ok((scene, atlas)) => {
                for w in &scene.warnings {
                    println!("warning: {w}");
                }
                let dynamic = atlas.dynamic_element_count(&scene);
                println!(
                    "{}: ok: scene \"{}\", {} surfaces, {} objects, atlas {}x{}, {} static + {} dynamic elements",
                    path.display(),
                    scene.name,
                    scene.patches.len(),
                    scene.objects.len(),
                    atlas.width,
                    atlas.height,
                    atlas.elements.len() - dynamic,
                    dynamic
                );
            }
            Err(e) => {
                eprintln!("error: {e:#}");
                failed += 1;
            }
        }
    }
    if failed > 0 {
        anyhow::bail!("{failed} of {} scene files are invalid", paths.len());
    }
    Ok(())
}
