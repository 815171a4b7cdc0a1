//! `scenes/scene.schema.json` lets editors validate scene files. It must
//! agree with the loader: every shipped scene passes it, and the fixtures
//! whose problem is a matter of shape (not of geometry or cross-references)
//! fail it.

use std::path::PathBuf;

fn scenes_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../scenes")
}

fn read_json(path: &PathBuf) -> serde_json::Value {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn validator() -> jsonschema::Validator {
    jsonschema::validator_for(&read_json(&scenes_dir().join("scene.schema.json")))
        .expect("the schema is a valid JSON Schema")
}

#[test]
fn every_shipped_scene_satisfies_the_schema() {
    let validator = validator();
    let mut checked = 0;
    for entry in std::fs::read_dir(scenes_dir()).expect("scenes/") {
        let path = entry.expect("entry").path();
        let name = path.to_string_lossy().into_owned();
        if !name.ends_with(".json") || name.ends_with(".schema.json") {
            continue;
        }
        let scene = read_json(&path);
        let errors: Vec<String> = validator
            .iter_errors(&scene)
            .map(|e| e.to_string())
            .collect();
        assert!(errors.is_empty(), "{name}: {errors:?}");
        checked += 1;
    }
    assert!(checked >= 6);
}

#[test]
fn fixtures_with_shape_errors_fail_the_schema() {
    let validator = validator();
    for name in [
        "albedo-out-of-range.json",
        "negative-emission.json",
        "unknown-field.json",
        "missing-field.json",
        "both-shapes.json",
        "no-shape.json",
        "bad-scale.json",
        "bad-texel-density.json",
        "bad-max-atlas-size.json",
        "bad-solver-settings.json",
        "non-finite-number.json",
        "mesh-non-finite.json",
    ] {
        let fixture = read_json(&scenes_dir().join("fixtures/bad").join(name));
        assert!(
            !validator.is_valid(&fixture),
            "{name} should fail the schema"
        );
    }
}

/// A scene file's `"solver"` settings reach the solver's options at the
/// file's own density, not at another (they were measured at that one),
/// and settings the command line states win over them.
#[test]
fn scene_solver_settings_apply_at_the_files_density_and_yield_to_the_command_line() {
    use lightwire_server::gpu::ProgressiveOptions;
    use lightwire_server::scene::{LoadOptions, Scene, SolverHints};

    let path = scenes_dir().join("cornell-low.json");
    let stated = read_json(&path)["solver"].clone();
    let defaults = ProgressiveOptions::default();
    let back = stated["back_resolution"]
        .as_u64()
        .expect("cornell-low states back_resolution") as u32;
    assert_ne!(
        back, defaults.back_resolution,
        "the test needs a setting that differs from the default"
    );
    let grid = stated["cross_grid"]
        .as_u64()
        .map_or(defaults.cross_grid, |g| g as u32);

    let scene = Scene::load(&path).expect("cornell-low loads");
    let options = defaults.with_hints(&scene.solver);
    assert_eq!((options.cross_grid, options.back_resolution), (grid, back));
    // Everything else keeps the defaults.
    assert_eq!(options.cross_tile, defaults.cross_tile);
    assert_eq!(options.hemicube_resolution, defaults.hemicube_resolution);

    let halved = Scene::load_with(&path, LoadOptions::scaled(0.5)).expect("loads at half density");
    assert!(halved.solver.is_empty(), "{}", halved.solver);

    let cli = SolverHints {
        cross_grid: Some(grid + 1),
        back_resolution: Some(back + 8),
    };
    let options = defaults.with_hints(&cli.or(scene.solver));
    assert_eq!(
        (options.cross_grid, options.back_resolution),
        (grid + 1, back + 8)
    );
    let cli = SolverHints {
        cross_grid: Some(grid + 1),
        back_resolution: None,
    };
    let options = defaults.with_hints(&cli.or(scene.solver));
    assert_eq!(
        (options.cross_grid, options.back_resolution),
        (grid + 1, back)
    );
}
