//! `lightwire validate`: load scene files and say what is wrong with them.

use std::path::PathBuf;

use anyhow::Result;
use lightwire_scene::LoadOptions;
use lightwire_scene::load::load_scene;

/// `lightwire validate`'s arguments.
#[derive(clap::Args)]
pub(crate) struct ValidateArgs {
    /// Scene files.
    #[arg(required = true)]
    scenes: Vec<PathBuf>,
    /// Multiply every texel density by this factor.
    #[arg(long, default_value_t = 1.0)]
    density_scale: f32,
    #[command(flatten)]
    charts: crate::args::ChartsArg,
}

impl ValidateArgs {
    pub(crate) fn run(self) -> Result<()> {
        let options = LoadOptions {
            density_scale: self.density_scale,
            charts: self.charts.charts,
        };
        validate_command(&self.scenes, options)
    }
}

fn validate_command(paths: &[PathBuf], options: LoadOptions) -> Result<()> {
    let mut failed = 0;
    for path in paths {
        match load_scene(path, options) {
            Ok((scene, atlas)) => {
                for w in &scene.warnings {
                    println!("warning: {w}");
                }
                let dynamic = atlas.dynamic_element_count(&scene);
                let generated: Vec<_> = scene.uv_meshes.iter().filter(|m| m.generated).collect();
                let charts = if generated.is_empty() {
                    String::new()
                } else {
                    format!(
                        ", {} generated charts on {} meshes",
                        generated.iter().map(|m| m.charts).sum::<usize>(),
                        generated.len()
                    )
                };
                println!(
                    "{}: ok: scene \"{}\", {} surfaces, {} objects, atlas {}x{} ({:.0}% of its texels elements), {} static + {} dynamic elements{charts}",
                    path.display(),
                    scene.name,
                    scene.patches.len(),
                    scene.objects.len(),
                    atlas.width,
                    atlas.height,
                    100.0 * atlas.elements.len() as f64
                        / (f64::from(atlas.width) * f64::from(atlas.height)).max(1.0),
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
