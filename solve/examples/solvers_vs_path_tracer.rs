//! Every solver against the path tracer, the independent oracle: NRMSE
//! and p95 (the project's metric: visible, non-emitting elements) of the
//! reference, the progressive solver without and with its gathered
//! corrections, and the gather solver, each against a path-traced
//! lightmap of the same atlas.
//!
//! ```text
//! cargo run --release -p lightwire-solve --example solvers_vs_path_tracer -- \
//!     [SCENE [DENSITY_SCALE [SPP]]]
//! ```
//!
//! Defaults: `scenes/cornell-large.json`, 0.35, 16384 paths per element.
//! With `ROWS=PATCH` in the environment it also prints every solver's
//! value at the elements of patch `PATCH` with `0.2 <= s <= 0.8` and
//! `t <= 0.3` (a box side's two bottom rows).

use lightwire_scene::atlas::Atlas;
use lightwire_scene::{LoadOptions, Scene};
use lightwire_solve::accuracy;
use lightwire_solve::solver::{self, SolverKind, SolverSettings};
use lightwire_solve::validity::Validity;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let path = args
        .get(1)
        .cloned()
        .unwrap_or_else(|| "scenes/cornell-large.json".into());
    let density_scale: f32 = args.get(2).map_or(Ok(0.35), |s| s.parse())?;
    let spp: u32 = args.get(3).map_or(Ok(16_384), |s| s.parse())?;
    let scene = Scene::load_with(
        std::path::Path::new(&path),
        LoadOptions::scaled(density_scale),
    )?;
    let atlas = Atlas::build(&scene).map_err(|e| format!("{path}: {e}"))?;
    let poses = scene.initial_poses();
    let runs = [
        (SolverKind::Pathtrace, 0, "pathtrace"),
        (SolverKind::Reference, 0, "reference"),
        (SolverKind::Progressive, 0, "progressive"),
        (
            SolverKind::Progressive,
            solver::DEFAULT_CORRECTIONS,
            "progressive+corrections",
        ),
        (SolverKind::Gather, 0, "gather"),
    ];
    let mut out = Vec::new();
    for (kind, corrections, name) in runs {
        let settings = SolverSettings {
            spp: Some(spp),
            corrections: Some(corrections),
            ..SolverSettings::default()
        };
        let mut s = solver::build(kind, &scene, &atlas, &poses, &settings, &solver::Silent)?;
        s.solve(1e-4)?;
        out.push((name, s.radiosity()?));
    }
    let validity = Validity::compute(&scene, &atlas, &poses);
    println!("{path} x{density_scale}, {spp} paths per element");
    for (name, b) in &out[1..] {
        let m = accuracy::accuracy_where(&atlas, b, &out[0].1, validity.keep())
            .ok_or("no lit, visible, non-emitting elements")?;
        println!("{name} vs pathtrace: {m}");
    }
    if let Ok(patch) = std::env::var("ROWS") {
        for (i, e) in atlas.elements.iter().enumerate() {
            if scene.patches[e.patch as usize].name != patch
                || !(0.2..=0.8).contains(&e.st[0])
                || e.st[1] > 0.3
            {
                continue;
            }
            print!("{patch} st=({:.3}, {:.3})", e.st[0], e.st[1]);
            for (name, b) in &out {
                print!("  {name} {:.3}", b[i].element_sum());
            }
            println!();
        }
    }
    Ok(())
}
