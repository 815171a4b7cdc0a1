//! The Khronos glTF validator (npm `gltf-validator`, pinned in
//! `scene/tests/gltf-validator` and installed there by `make
//! gltf-validator-deps`, which `make test` runs), for the tests of
//! Lightwire's own `.glb` files: the committed meshes and what `bake` and
//! `serve` export.

use std::path::Path;

/// Runs the validator on `files`; returns whether it accepted them all
/// and its report (stdout, then stderr), which says ` errors 0 ` once per
/// file it found valid.
pub fn khronos_validate(files: &[&Path]) -> (bool, String) {
    let dir = crate::repo().join("scene/tests/gltf-validator");
    assert!(
        dir.join("node_modules/gltf-validator").is_dir(),
        "{} has no node_modules/gltf-validator: run `make gltf-validator-deps` (make test does)",
        dir.display()
    );
    let out = std::process::Command::new("node")
        .arg(dir.join("validate.mjs"))
        .args(files)
        .output()
        .expect("run node (install nodejs; make test does)");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    (out.status.success(), text)
}
