//! The real third-party levels in `$LEVELS` (default `../shared/levels`
//! beside the repository; see its README): they load as their authors
//! exported them, and the scene files of `scenes/levels/` that light them
//! load too. The levels are never copied into the repository, so these
//! tests run only in `make test-levels` (the `levels` feature), which
//! fails when the folder is missing.

use std::path::{Path, PathBuf};

use lightwire_scene::gltf::{ImportOptions, import};
use lightwire_scene::load::load_scene;
use lightwire_scene::{Charts, LoadOptions, SceneIssue};
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

/// Issue 59: the level files lit by the lights a level brings load with
/// them and nothing emits: `zdm2-sky` under a sun with a disc and a sky,
/// `pandora-lamps` under 30 spots and 26 point lights, its crate a
/// dynamic object.
#[test]
fn the_levels_under_lights_load_with_them_and_no_emitter() {
    use lightwire_scene::LightKind;
    let dir = temp_dir("lit-levels");
    for (name, spots, points, suns, sky) in [
        ("zdm2-sky", 0, 0, 1, true),
        ("pandora-lamps", 30, 26, 0, false),
    ] {
        let path = level_scene(name, &dir);
        let (scene, atlas) =
            load_scene(&path, LoadOptions::default()).unwrap_or_else(|e| panic!("{name}: {e}"));
        let count = |f: fn(&LightKind) -> bool| scene.lights.iter().filter(|l| f(&l.kind)).count();
        assert_eq!(
            count(|k| matches!(k, LightKind::Spot { .. })),
            spots,
            "{name}: spots"
        );
        assert_eq!(
            count(|k| matches!(k, LightKind::Point)),
            points,
            "{name}: point lights"
        );
        assert_eq!(
            count(
                |k| matches!(k, LightKind::Directional { angular_radius, .. } if *angular_radius > 0.0)
            ),
            suns,
            "{name}: suns with a disc"
        );
        assert_eq!(scene.sky.is_some(), sky, "{name}: sky");
        assert!(
            !scene
                .patches
                .iter()
                .any(|p| scene.materials[p.material as usize].is_emitter()),
            "{name}: lit by its lights alone"
        );
        assert!(
            atlas.elements.len() > 200_000,
            "{name}: {} elements",
            atlas.elements.len()
        );
    }
}

/// Issue 58, item 2: the `uvunwrap` crate's charts (`--charts uvunwrap`)
/// on every level: it loads, its generated UVs overlap nowhere, it cuts
/// fewer charts than Lightwire's projection, and it unwraps the same way
/// twice (no thread-count or hash-order dependence).
#[test]
fn every_level_unwraps_with_the_uvunwrap_crate_into_fewer_charts() {
    let dir = temp_dir("levels-uvunwrap");
    for name in ["garage", "pandora", "zdm2"] {
        let path = level_scene(name, &dir);
        let load = |charts| {
            load_scene(
                &path,
                LoadOptions {
                    charts,
                    ..LoadOptions::default()
                },
            )
            .unwrap_or_else(|e| panic!("{name}: {e}"))
        };
        let charts = |scene: &lightwire_scene::Scene| -> usize {
            scene
                .uv_meshes
                .iter()
                .filter(|m| m.generated)
                .map(|m| m.charts)
                .sum()
        };
        let (projected, _) = load(Charts::Generated);
        let (scene, atlas) = load(Charts::Uvunwrap);
        let (_, again) = load(Charts::Uvunwrap);
        assert!(
            charts(&scene) > 0 && charts(&scene) < charts(&projected),
            "{name}: {} charts, {} projected",
            charts(&scene),
            charts(&projected)
        );
        for mesh in scene.uv_meshes.iter().filter(|m| m.generated) {
            let overlaps = lightwire_scene::gltf::find_uv_overlaps(&mesh.uvs, 4)
                .unwrap_or_else(|e| panic!("{name}: {e}"));
            assert!(overlaps.is_empty(), "{name} {}: {overlaps:?}", mesh.name);
        }
        assert_eq!(
            (atlas.width, atlas.height),
            (again.width, again.height),
            "{name}"
        );
        assert!(
            atlas.elements == again.elements,
            "{name}: the same elements in the same places"
        );
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

/// The three.js example (`server/tests/threejs.rs` runs it on a repository
/// scene) on the garage: `lightwire serve --dev` on the level, and
/// `server/dashboard/e2e/threejs.e2e.mjs` in headless Chromium checks that
/// three.js draws the level lit by the stream (not black, not the
/// placeholder), that moving the crate changes the picture, and that no
/// console error happens. Screenshots in `target/threejs-artifacts/`.
#[test]
fn three_js_draws_the_garage_lit_by_the_stream() {
    use lightwire_testkit::http::blocking;
    use std::process::{Command, Stdio};
    use std::time::{Duration, Instant};

    // The first state of the level comes after about 15 s in a release
    // build (BENCHMARKS.md §9); a generous bound for slower hosts.
    const READY: Duration = Duration::from_secs(900);
    const E2E: Duration = Duration::from_secs(600);
    let path = level_scene("garage", &temp_dir("levels-threejs"));
    let server = lightwire_testkit::lightwire!().serve_dev_on(&path, &[]);
    let started = Instant::now();
    while blocking::get_with(&server.addr, "/readyz", &[]).map(|r| r.status) != Some(200) {
        assert!(
            started.elapsed() < READY,
            "the garage is not ready after {READY:?}"
        );
        std::thread::sleep(Duration::from_millis(500));
    }
    eprintln!("garage ready after {:.0?}", started.elapsed());
    let dashboard = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("dashboard");
    let chromium = std::env::var("CHROMIUM").unwrap_or_else(|_| "/usr/bin/chromium".into());
    assert!(
        Path::new(&chromium).exists() && dashboard.join("node_modules/playwright-core").is_dir(),
        "needs Chromium at {chromium} and `npm ci` in {} (make test does both)",
        dashboard.display()
    );
    let artifacts = lightwire_testkit::lightwire!()
        .target_dir()
        .join("threejs-artifacts");
    let started = Instant::now();
    // The crate, 1 m towards the lit +x wall and turned by 30°: still on
    // the open floor.
    let mut node = Command::new("node")
        .current_dir(&dashboard)
        .arg("e2e/threejs.e2e.mjs")
        .arg("--url")
        .arg(server.url("/examples/threejs/?scene=garage"))
        .args(["--name", "garage", "--move", "1,0,0,30", "--timeout", "300"])
        .arg("--artifacts")
        .arg(&artifacts)
        .arg("--chromium")
        .arg(&chromium)
        .stdout(Stdio::inherit())
        .stderr(Stdio::inherit())
        .spawn()
        .unwrap_or_else(|e| panic!("cannot run node (install nodejs): {e}"));
    let status = loop {
        if let Some(status) = node.try_wait().expect("wait for node") {
            break status;
        }
        if started.elapsed() > E2E {
            let _ = node.kill();
            let _ = node.wait();
            panic!("the browser test did not finish within {E2E:?}");
        }
        std::thread::sleep(Duration::from_millis(200));
    };
    assert!(
        status.success(),
        "the three.js example failed on the garage ({status}); see its output above and the screenshots in {}",
        artifacts.display()
    );
    for shot in ["placeholder", "lit", "moved"] {
        let shot = artifacts.join(format!("garage-{shot}.png"));
        let size = std::fs::metadata(&shot).map(|m| m.len()).unwrap_or(0);
        assert!(
            size > 1_000,
            "screenshot {} is missing or empty",
            shot.display()
        );
    }
}

/// Where a player looks, the garage's progressive bake (to 1e-2 unshot, as
/// BENCHMARKS.md §9 bakes it, with its two gathered corrections, swept by
/// rays on a level) reads close to the path tracer: `lightwire bench eye`
/// at 2,000 seeded points in view, 8,192 paths each. With every sample
/// where the nearest point of its patch fell (`validity::relocate` not
/// run), the lamp's frame read black beside the emitting panel: NRMSE
/// 53.2%, median 4.7%, p95 16.4%, 14% of points more than 10% off; with
/// samples moved out of geometry 9.0%, 3.0%, 13.8% and 8%. The bounds hold
/// that, and the issue's p95 of 15% (not yet its 5% NRMSE).
#[test]
fn the_garage_bake_reads_close_to_the_path_tracer_where_a_player_looks() {
    garage_bake_where_a_player_looks("progressive", "1e-2");
}

/// The same for the ray solver (`--solver rays`, to 1e-3 of the emitted
/// power still to come), which bakes the garage in about a tenth of the
/// progressive bake's time (BENCHMARKS.md §9): it converges the ray-cast
/// gather the progressive bake's corrections only step towards, and reads
/// at least as close (NRMSE 9.0%, median 3.0%, p95 13.3%, 8% of points
/// more than 10% off, with samples moved out of geometry; 53.2%, 4.2%,
/// 15.6% and 12% without).
#[test]
fn the_garage_ray_bake_reads_close_to_the_path_tracer_where_a_player_looks() {
    garage_bake_where_a_player_looks("rays", "1e-3");
}

/// Runs `lightwire ARGS`, asserts that it succeeded, and returns its
/// standard output.
fn run_lightwire(args: &[&str]) -> String {
    let output = lightwire_testkit::lightwire!()
        .command()
        .args(args)
        .output()
        .expect("runs");
    let stdout = String::from_utf8_lossy(&output.stdout).into_owned();
    assert!(
        output.status.success(),
        "{args:?}: {stdout}{}",
        String::from_utf8_lossy(&output.stderr)
    );
    stdout
}

/// Bakes the garage with `solver` to `tolerance`, runs `bench eye` on the
/// lightmap and asserts the bounds above.
fn garage_bake_where_a_player_looks(solver: &str, tolerance: &str) {
    let dir = temp_dir(&format!("levels-eye-{solver}"));
    let scene = level_scene("garage", &dir);
    let out = dir.join("bake");
    let scene = scene.to_str().expect("utf-8");
    run_lightwire(&[
        "bake",
        "--scene",
        scene,
        "--solver",
        solver,
        "--tolerance",
        tolerance,
        "--out",
        out.to_str().expect("utf-8"),
    ]);
    let lightmap = out.join("lightmap.exr");
    eye_within_bounds(scene, &lightmap, solver);
}

/// Runs `bench eye` on `lightmap` of `scene` (2,000 seeded points in view,
/// 8,192 paths each: at 400 the NRMSE of one lightmap read 11% or 29% with
/// the points drawn, BENCHMARKS.md §9) and asserts the bounds above;
/// `what` names the lightmap in messages.
fn eye_within_bounds(scene: &str, lightmap: &Path, what: &str) {
    let report = run_lightwire(&[
        "bench",
        "eye",
        "--scene",
        scene,
        "--lightmap",
        lightmap.to_str().expect("utf-8"),
        "--points",
        "2000",
        "--spp",
        "8192",
    ]);
    // "  NRMSE 11.7%  median 4.9%  p95 16.8%  >10% off: 14%  >25% off: 3%"
    let figure = |name: &str| -> f64 {
        let line = report
            .lines()
            .find(|l| l.trim_start().starts_with("NRMSE"))
            .unwrap_or_else(|| panic!("no NRMSE line in {report}"));
        let at = line
            .find(name)
            .unwrap_or_else(|| panic!("no {name} in {line}"));
        line[at + name.len()..]
            .trim_start()
            .split('%')
            .next()
            .and_then(|v| v.trim().parse().ok())
            .unwrap_or_else(|| panic!("no number after {name} in {line}"))
    };
    let (nrmse, median, p95, off10) = (
        figure("NRMSE"),
        figure("median"),
        figure("p95"),
        figure(">10% off:"),
    );
    eprintln!(
        "garage, {what}, where a player looks: NRMSE {nrmse}%, median {median}%, \
         p95 {p95}%, >10% off {off10}%"
    );
    assert!(
        median <= 4.5,
        "median point {median}% off (at most 4.5%): {report}"
    );
    assert!(p95 <= 15.0, "p95 {p95}% (at most 15%): {report}");
    assert!(
        off10 <= 12.0,
        "{off10}% of points more than 10% off (at most 12%): {report}"
    );
    assert!(nrmse <= 12.0, "NRMSE {nrmse}% (at most 12%): {report}");
}

/// The lightmap the live service publishes for the garage, once the
/// session is idle (`lightwire_solver_idle` 1: its static set lit by the
/// ray solver, the crate inserted by cross redistribution, the gathered
/// corrections run), reads as close to the path tracer where a player
/// looks as the bakes above, by the same bounds: what a viewer of the
/// level gets, not only `bake`. It came idle after 35-38 s in a release
/// build (BENCHMARKS.md §9) and read 53.2%, 4.3% median, 15.7% p95 before
/// samples were moved out of geometry.
#[test]
fn the_served_garage_once_idle_reads_close_to_the_path_tracer_where_a_player_looks() {
    use lightwire_testkit::http::blocking;
    use std::time::{Duration, Instant};

    const IDLE: Duration = Duration::from_secs(900);
    let dir = temp_dir("levels-served-eye");
    let path = level_scene("garage", &dir);
    let server = lightwire_testkit::lightwire!().serve_dev_on(&path, &[]);
    let started = Instant::now();
    let idle = |metrics: &str| {
        metrics
            .lines()
            .any(|l| l.trim() == "lightwire_solver_idle{scene=\"garage\"} 1")
    };
    loop {
        let metrics = blocking::get_with(&server.addr, "/metrics", &[]).map(|r| r.text());
        if metrics.as_deref().is_some_and(idle) {
            break;
        }
        assert!(
            started.elapsed() < IDLE,
            "the served garage is not idle after {IDLE:?}"
        );
        std::thread::sleep(Duration::from_millis(200));
    }
    eprintln!("served garage idle after {:.0?}", started.elapsed());
    // Texels the stream's encoder held back within its error budget are
    // published once the session holds still (`settle_ms`, 500 ms).
    std::thread::sleep(Duration::from_millis(1500));
    let response = blocking::get(&server.addr, "/api/scenes/garage/lightmap.exr", None);
    assert_eq!(response.status, 200, "{}", response.text());
    let lightmap = dir.join("served.exr");
    std::fs::write(&lightmap, &response.body).expect("write the lightmap");
    eye_within_bounds(path.to_str().expect("utf-8"), &lightmap, "served once idle");
}
