//! The real third-party levels in `$LEVELS` (default `../shared/levels`
//! beside the repository; see its README): they load as their authors
//! exported them, and the scene files of `scenes/levels/` that light them
//! load too. The levels are never copied into the repository, so these
//! tests run only in `make test-levels` (the `levels` feature), which
//! fails when the folder is missing.

use std::path::{Path, PathBuf};

use lightwire_scene::gltf::{ImportOptions, import};
use lightwire_scene::load::load_scene;
use lightwire_scene::{LoadOptions, SceneIssue};
use lightwire_testkit::repo;

/// The levels folder: `$LEVELS`, else `../shared/levels` beside the
/// repository.
fn levels() -> PathBuf {
    let dir = std::env::var_os("LEVELS")
        .map(PathBuf::from)
        .unwrap_or_else(|| repo().join("../shared/levels"));
    assert!(
        dir.join("README.md").is_file(),
        "no levels at {} (set LEVELS to the folder that holds garage/, pandora/ and zdm2/)",
        dir.display()
    );
    dir
}

/// The path a scene file of `scenes/levels/` imports its level from, as
/// written there (relative to the scene file, for the usual layout).
const WRITTEN: &str = "../../../shared/levels/";

/// `scenes/levels/<name>.json`, its import pointed at [`levels`], written
/// into `dir`.
fn level_scene(name: &str, dir: &Path) -> PathBuf {
    let path = repo().join(format!("scenes/levels/{name}.json"));
    let text = std::fs::read_to_string(&path).expect("scene file");
    assert!(
        text.contains(WRITTEN),
        "{}: imports from {WRITTEN}",
        path.display()
    );
    let at = levels().display().to_string().replace('\\', "/");
    let out = dir.join(format!("{name}.json"));
    std::fs::write(&out, text.replace(WRITTEN, &format!("{at}/"))).expect("write");
    out
}

/// A fresh folder of this test process under the system's temporary one.
fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("lightwire-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temporary folder");
    dir
}

fn dropped<'a>(warnings: &'a [SceneIssue], kind: &str) -> Option<&'a SceneIssue> {
    warnings
        .iter()
        .find(|w| w.problem.starts_with("dropped") && w.problem.contains(kind))
}

/// The count a "dropped N ..." warning states.
fn count(w: &SceneIssue) -> usize {
    w.problem
        .split_whitespace()
        .nth(1)
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no count in {w}"))
}

#[test]
fn every_level_imports_as_shipped_and_says_what_it_dropped() {
    // (file, triangles in the file, zero-area triangles its SOURCE.md counts)
    for (file, triangles, zero_area) in [
        ("garage/garage.gltf", 11_358, 5),
        ("zdm2/zdm2.glb", 58_772, 1_134),
        ("pandora/pandora.gltf", 60_694, 0),
    ] {
        let path = levels().join(file);
        let imported = import(&path, &ImportOptions::default())
            .unwrap_or_else(|e| panic!("{file} refused: {e}"));
        let kept = imported.triangle_count();
        let degenerate = dropped(&imported.warnings, "zero-area").map_or(0, count);
        let duplicate = dropped(&imported.warnings, "duplicate").map_or(0, count);
        assert_eq!(
            kept + degenerate + duplicate,
            triangles,
            "{file}: every triangle is kept or counted as dropped: {:#?}",
            imported.warnings
        );
        // Every zero-area triangle is dropped; slivers (corners on a line to
        // within 1e-6 of the longest edge) may add a few.
        assert!(
            degenerate >= zero_area && degenerate <= zero_area + triangles / 500,
            "{file}: {degenerate} dropped as zero-area or sliver, {zero_area} have zero area"
        );
        if zero_area == 0 {
            assert!(
                dropped(&imported.warnings, "zero-area").is_none(),
                "{file}: {:#?}",
                imported.warnings
            );
        }
    }
}

#[test]
fn lightwire_validate_loads_the_garage_and_reports_the_dropped_triangles() {
    let path = levels().join("garage/garage.gltf");
    let out = lightwire_testkit::lightwire!()
        .command()
        .args(["validate", path.to_str().expect("utf-8")])
        .output()
        .expect("runs");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.contains("warning:") && stdout.contains("dropped 5 zero-area"),
        "{stdout}"
    );
    assert!(stdout.contains(": ok: scene \"garage\""), "{stdout}");
}

#[test]
fn the_level_scene_files_load_lit_with_a_dynamic_object() {
    let dir = temp_dir("levels");
    // (scene, the fewest static elements it must have)
    for (name, min_elements) in [("garage", 60_000), ("pandora", 200_000), ("zdm2", 200_000)] {
        let path = level_scene(name, &dir);
        let (scene, atlas) =
            load_scene(&path, LoadOptions::default()).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert!(
            scene
                .patches
                .iter()
                .any(|p| scene.materials[p.material as usize].is_emitter()),
            "{name} is lit"
        );
        assert!(
            scene.objects.iter().any(|o| o.dynamic),
            "{name} has an object a driver can move"
        );
        let dynamic = atlas.dynamic_element_count(&scene);
        let elements = atlas.elements.len() - dynamic;
        assert!(
            elements >= min_elements,
            "{name}: {elements} static elements, fewer than {min_elements}"
        );
        assert!(dynamic > 0, "{name}: the dynamic object has texels");
    }
}

#[test]
fn a_level_scene_loads_to_the_same_atlas_every_time() {
    // Charts grown from hash-map order once made the element count differ
    // from run to run (and so every lightmap); two loads must agree.
    let dir = temp_dir("levels-again");
    let path = level_scene("garage", &dir);
    let load = || load_scene(&path, LoadOptions::default()).expect("loads");
    let (_, a) = load();
    let (_, b) = load();
    assert_eq!((a.width, a.height), (b.width, b.height));
    assert_eq!(a.elements.len(), b.elements.len());
    assert!(
        a.elements.iter().zip(&b.elements).all(|(x, y)| x == y),
        "the same elements in the same places"
    );
}
