//! Where a GPU solver deviates from the reference, surface by surface.
//!
//! ```text
//! cargo run --release -p lightwire-solve --example accuracy_by_surface -- \
//!     scenes/cornell-blocks.json [--density-scale 0.5] [--direct] [--gather] \
//!     [--max-shooters N] [--resolution PIXELS] [--close] [--dump SURFACE]...
//!     [--correct N] [--polish N] [--gather-resolution PIXELS]
//! ```
//!
//! `--correct N` runs N gathered corrections after the progressive solve
//! (`gpu::Correction`, as `lightwire bake` does) and prints the accuracy
//! after each; `--polish N` instead runs N plain gather sweeps started from
//! the progressive solution (the final gather that was tried first).
//!
//! `--close` adds a white front wall (cornell-blocks' open side, z = 5.592)
//! so that no light escapes: a shot should then deliver all of its power,
//! and `energy:` shows how much each shot loses.
//!
//! Solves the scene with the reference solver and with the progressive (or,
//! with `--gather`, the gather) GPU solver, then prints the metric of
//! `metrics::accuracy` over the visible elements (those not inside or under
//! geometry), the energy balance, and per surface the ratio of the
//! area-weighted mean radiosity per channel and the surface's own NRMSE and
//! p95. A channel-dependent ratio points at bounces (the channel with the
//! highest albedo gathers the most of them); a surface far off while its
//! neighbours are right points at visibility.
//!
//! `--direct` compares the first shot only: the progressive solver stops
//! after its first batch (the brightest emitter's shot), the gather solver
//! after its first bounce, and the reference does no Jacobi sweep, so all
//! hold emission plus direct light. The
//! numbers of docs/benchmarks-history.md's "Where the GPU solvers deviate" come from
//! here.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use glam::DVec3;
use lightwire_scene::atlas::Atlas;
use lightwire_scene::{LoadOptions, Scene};
use lightwire_solve::accuracy::accuracy_where;
use lightwire_solve::gpu;
use lightwire_solve::reference::{ReferenceSolver, Silent, SolveOptions};
use lightwire_solve::validity::Validity;

fn main() -> Result<()> {
    let mut scene_path = None;
    let (mut density, mut direct, mut gather, mut close) = (1.0f32, false, false, false);
    let mut gpu_options = gpu::ProgressiveOptions::default();
    let mut dump: Vec<String> = Vec::new();
    let mut polish = 0u32;
    let mut correct = 0u32;
    let mut gather_options = gpu::GatherOptions::default();
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        match arg.as_str() {
            "--density-scale" => {
                let v = args.next().context("--density-scale needs a number")?;
                density = v.parse().with_context(|| format!("--density-scale {v}"))?;
            }
            "--direct" => direct = true,
            "--close" => close = true,
            "--max-shooters" => {
                let v = args.next().context("--max-shooters needs a number")?;
                gpu_options.max_shooters =
                    v.parse().with_context(|| format!("--max-shooters {v}"))?;
            }
            "--resolution" => {
                let v = args.next().context("--resolution needs a number")?;
                gpu_options.hemicube_resolution =
                    v.parse().with_context(|| format!("--resolution {v}"))?;
            }
            "--dump" => dump.push(args.next().context("--dump needs a surface name")?),
            "--gather" => gather = true,
            "--gather-resolution" => {
                let v = args.next().context("--gather-resolution needs a number")?;
                gather_options.hemicube_resolution = v
                    .parse()
                    .with_context(|| format!("--gather-resolution {v}"))?;
            }
            "--correct" => {
                let v = args.next().context("--correct needs a number")?;
                correct = v.parse().with_context(|| format!("--correct {v}"))?;
            }
            "--polish" => {
                let v = args.next().context("--polish needs a number")?;
                polish = v.parse().with_context(|| format!("--polish {v}"))?;
            }
            flag if flag.starts_with("--") => bail!("unknown option {flag}"),
            path => scene_path = Some(PathBuf::from(path)),
        }
    }
    let path = scene_path.context(
        "usage: accuracy_by_surface SCENE.json [--density-scale S] [--direct] [--gather] [--max-shooters N] [--resolution PIXELS] [--close] [--dump SURFACE]... [--correct N] [--polish N] [--gather-resolution PIXELS]",
    )?;
    let options = LoadOptions::scaled(density);
    let scene = if close {
        let text = std::fs::read_to_string(&path).with_context(|| path.display().to_string())?;
        let mut json: serde_json::Value = serde_json::from_str(&text)?;
        json["surfaces"]
            .as_array_mut()
            .context("the scene has no surfaces array")?
            .push(serde_json::json!({
                "name": "front",
                "material": "white",
                "quad": { "origin": [0, 0, 5.592], "u": [0, 5.488, 0], "v": [5.56, 0, 0] }
            }));
        Scene::parse_with(&json.to_string(), &path.display().to_string(), options)?
    } else {
        Scene::load_with(&path, options)?
    };
    let atlas = Atlas::build(&scene).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    let poses = scene.initial_poses();
    let validity = Validity::compute(&scene, &atlas, &poses);
    eprintln!(
        "{}: {} elements, {} invalid",
        scene.name,
        atlas.elements.len(),
        validity.count()
    );

    let reference = ReferenceSolver::new(&scene, &atlas, &poses, &Silent)?;
    let options = SolveOptions {
        tolerance: 1e-6,
        max_iterations: if direct {
            0
        } else {
            SolveOptions::default().max_iterations
        },
    };
    let expected = reference.solve(options, &Silent).radiosity;

    let device = gpu::Device::new(None)?;
    let values = if gather {
        let setup = std::time::Instant::now();
        let mut solver = gpu::GatherSolver::new(&device, &scene, &atlas, &poses, gather_options)?;
        let setup = setup.elapsed().as_secs_f64();
        let started = std::time::Instant::now();
        if direct {
            solver.bounce()?;
        } else {
            solver.solve(1e-4)?;
        }
        println!(
            "gather: setup {setup:.3} s (direct light by rays included), solve {:.3} s",
            started.elapsed().as_secs_f64()
        );
        solver.radiosity()?
    } else {
        let mut solver = gpu::ProgressiveSolver::new(&device, &scene, &atlas, &poses, gpu_options)?;
        let started = std::time::Instant::now();
        if direct {
            solver.step(std::time::Duration::ZERO)?;
        } else {
            solver.solve(1e-4)?;
        }
        println!(
            "progressive: {:.3} s, {} shots",
            started.elapsed().as_secs_f64(),
            solver.total_shots()
        );
        let balance = solver.energy_balance()?;
        println!(
            "energy: shot {:.3} W, received {:.3} W ({:.4} of shot)",
            balance.shot,
            balance.received,
            balance.received / balance.shot
        );
        let mut b = solver.radiosity()?;
        if correct > 0 {
            let keep = validity.keep();
            let started = std::time::Instant::now();
            let mut correction =
                gpu::Correction::new(&device, &scene, &atlas, &poses, gather_options)?;
            for k in 1..=correct {
                let report = correction.round(&mut solver, 1e-4)?;
                b = solver.radiosity()?;
                if let Some(a) = accuracy_where(&atlas, &b, &expected, &keep) {
                    println!(
                        "correction {k}: {:.3} s, {} shots, residual {:.2e}, {a}",
                        started.elapsed().as_secs_f64(),
                        report.shots,
                        report.residual_fraction
                    );
                }
            }
        }
        if polish > 0 {
            let keep = validity.keep();
            let started = std::time::Instant::now();
            let mut g = gpu::GatherSolver::new(&device, &scene, &atlas, &poses, gather_options)?;
            g.start_from(&b);
            for k in 1..=polish {
                g.bounce()?;
                let v = g.radiosity()?;
                if let Some(a) = accuracy_where(&atlas, &v, &expected, &keep) {
                    println!("polish {k}: {:.3} s, {a}", started.elapsed().as_secs_f64());
                }
            }
            g.radiosity()?
        } else {
            b
        }
    };

    let overall = accuracy_where(&atlas, &values, &expected, validity.keep())
        .context("nothing lit to compare")?;
    println!("overall: {overall}");
    println!("surface | mean reference (r, g, b) | ratio (r, g, b) | surface accuracy");
    for (p, patch) in scene.patches.iter().enumerate() {
        let range = atlas.elements_of(p as u32);
        let (mut got, mut want) = (DVec3::ZERO, DVec3::ZERO);
        let mut area = 0.0;
        for i in range.clone().filter(|&i| !validity.is_invalid(i)) {
            let a = f64::from(atlas.elements[i].area);
            got += values[i].as_dvec3() * a;
            want += expected[i].as_dvec3() * a;
            area += a;
        }
        let mean = want / area.max(1e-30);
        let ratio = got / want;
        let own = accuracy_where(&atlas, &values, &expected, |i| {
            range.contains(&i) && !validity.is_invalid(i)
        });
        println!(
            "{:<20} | {:.3} {:.3} {:.3} | {:.4} {:.4} {:.4} | {}",
            patch.name,
            mean.x,
            mean.y,
            mean.z,
            ratio.x,
            ratio.y,
            ratio.z,
            own.map_or_else(|| "-".to_string(), |a| a.to_string())
        );
    }
    for name in &dump {
        let Some(p) = scene.patches.iter().position(|p| &p.name == name) else {
            bail!("no surface {name:?}");
        };
        let chart = atlas.charts[p];
        println!(
            "{name}: luminance, reference | GPU / reference per texel (rows t, columns s; * invalid)"
        );
        let lum = |v: glam::Vec3| 0.2126 * v.x + 0.7152 * v.y + 0.0722 * v.z;
        let mut grid = vec![usize::MAX; (chart.w * chart.h) as usize];
        for i in atlas.elements_of(p as u32) {
            let [x, y] = atlas.elements[i].texel;
            grid[((y - chart.y) * chart.w + (x - chart.x)) as usize] = i;
        }
        for row in 0..chart.h {
            let mut line_ref = String::new();
            let mut line_ratio = String::new();
            for col in 0..chart.w {
                let i = grid[(row * chart.w + col) as usize];
                line_ref += &format!("{:6.3} ", lum(expected[i]));
                let mark = if validity.is_invalid(i) { '*' } else { ' ' };
                line_ratio += &format!("{:5.3}{mark}", lum(values[i]) / lum(expected[i]).max(1e-9));
            }
            println!("{line_ref}| {line_ratio}");
        }
    }
    Ok(())
}
