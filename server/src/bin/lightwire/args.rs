//! Arguments several subcommands share, declared once.

use lightwire_scene::Charts;

/// `--charts`, as `bake` and the benchmarks take it.
#[derive(clap::Args)]
pub(crate) struct ChartsArg {
    /// How a mesh's triangles get charts: each its own (`triangles`),
    /// two that form a parallelogram one (`pairs`), or pairs merged
    /// into the largest parallelograms they tile (`parallelograms`); or
    /// the static meshes on lightmap UVs: their own, else generated ones
    /// (`lightmap-uvs`, the default), or always generated (`generated`,
    /// by Lightwire's own projection; `uvunwrap`, by the uvunwrap crate).
    #[arg(long, value_enum, default_value_t = Charts::default())]
    pub(crate) charts: Charts,
}

/// A number from 0 to 1; `what` names it in the error.
fn zero_to_one(text: &str, what: &str) -> Result<f32, String> {
    match text.parse::<f32>() {
        Ok(x) if (0.0..=1.0).contains(&x) => Ok(x),
        _ => Err(format!("{text:?} is not {what}: give a number from 0 to 1")),
    }
}

/// `--shared-batch-ratio`: a share of a patch's power.
pub(crate) fn shared_batch_ratio(text: &str) -> Result<f32, String> {
    zero_to_one(text, "a share of a patch's power")
}

/// `--cross-coarse-below`: a form factor.
pub(crate) fn form_factor_threshold(text: &str) -> Result<f32, String> {
    zero_to_one(text, "a form factor")
}
