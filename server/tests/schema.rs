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
    // The level scenes (scenes/levels/) too: their levels are outside the
    // repository, but the files themselves are ours.
    let entries = std::fs::read_dir(scenes_dir())
        .expect("scenes/")
        .chain(std::fs::read_dir(scenes_dir().join("levels")).expect("scenes/levels/"));
    for entry in entries {
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
    assert!(checked >= 9);
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
        "bad-light-detail.json",
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

/// A scene file's `"solver"` settings satisfy the schema, reach the
/// solver's options at the file's own density, not at another (they were
/// measured at that one), and settings the command line states win over
/// them. (Written here on a copy of cornell-low, whose own file states
/// only `cross_coarse_below`.)
#[test]
fn scene_solver_settings_apply_at_the_files_density_and_yield_to_the_command_line() {
    use lightwire_scene::{LoadOptions, Scene, SolverHints};
    use lightwire_solve::gpu::ProgressiveOptions;

    let defaults = ProgressiveOptions::default();
    let (grid, back, coarse) = (
        defaults.cross_grid + 1,
        defaults.back_resolution / 2,
        defaults.cross_coarse_below * 4.0,
    );
    let mut file = read_json(&scenes_dir().join("cornell-low.json"));
    file["solver"] = serde_json::json!({
        "cross_grid": grid,
        "back_resolution": back,
        "cross_coarse_below": coarse,
    });
    file.as_object_mut().expect("an object").remove("$schema");
    let errors: Vec<String> = validator()
        .iter_errors(&file)
        .map(|e| e.to_string())
        .collect();
    assert!(errors.is_empty(), "{errors:?}");
    let path = std::env::temp_dir().join(format!(
        "lightwire-solver-settings-{}.json",
        std::process::id()
    ));
    std::fs::write(&path, file.to_string()).expect("writes the scene");
    let scene = Scene::load(&path);
    let halved = Scene::load_with(&path, LoadOptions::scaled(0.5));
    std::fs::remove_file(&path).ok();
    let scene = scene.expect("the scene loads");
    let options = defaults.with_hints(&scene.solver);
    assert_eq!(
        (
            options.cross_grid,
            options.back_resolution,
            options.cross_coarse_below
        ),
        (grid, back, coarse)
    );
    // Everything else keeps the defaults.
    assert_eq!(options.cross_tile, defaults.cross_tile);
    assert_eq!(options.hemicube_resolution, defaults.hemicube_resolution);

    let halved = halved.expect("loads at half density");
    assert!(halved.solver.is_empty(), "{}", halved.solver);

    let cli = SolverHints {
        cross_grid: Some(grid + 1),
        back_resolution: None,
        cross_coarse_below: Some(0.0),
    };
    let options = defaults.with_hints(&cli.or(scene.solver));
    assert_eq!(
        (
            options.cross_grid,
            options.back_resolution,
            options.cross_coarse_below
        ),
        (grid + 1, back, 0.0)
    );
}
