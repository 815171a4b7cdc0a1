//! Does the light come back (issue 57)? A session is driven through the
//! jumps of a transform script and back to the start pose, settles, and is
//! compared texel by texel with a fresh session at the start pose.
//!
//! ```text
//! cargo run --release -p lightwire-solve --example round_trip -- \
//!     scenes/cornell-low.json [--density-scale S] [--methods cross,incremental,full] \
//!     [--corrections N] [--script scenes/scripts/teleport-stress.json] \
//!     [--hold settled|published|corrected] [--jumps N] [--surfaces N] [--trace]
//! ```
//!
//! `--jumps N` plays only the first N jumps (an incremental session
//! recomputes from scratch every 10th move, `DynamicOptions::
//! reanchor_every`: with 19 jumps the return is such a move). `--trace`
//! compares the state after every jump with a fresh session at its pose.
//!
//! `--hold` says how long each jump is held before the next pose arrives:
//! until the move's first complete state (`published`, a driver faster
//! than the solver), until its refinement is done (`settled`, the
//! default) or until its gathered corrections have run too
//! (`corrected`). The return to the start pose always settles fully.
//!
//! Prints per method the agreement with the fresh session
//! (`metrics::agreement`: share of lit texels more than 1%, 2%, 5% off,
//! p99, worst, total light), the time from the return to its first state,
//! to its refined state and to its corrected state, the correction
//! residuals, and the `--surfaces` patches whose total light differs most
//! (area-weighted, channels summed; valid texels at the start poses).

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use glam::Vec3;
use lightwire_protocol::script::Script;
use lightwire_scene::atlas::Atlas;
use lightwire_scene::{LoadOptions, Pose, Scene};
use lightwire_solve::accuracy::agreement;
use lightwire_solve::gpu::{self, DynamicOptions, DynamicSolver, Redistribution};
use lightwire_solve::validity::Validity;

#[derive(Clone, Copy, PartialEq)]
enum Hold {
    Published,
    Settled,
    Corrected,
}

fn main() -> Result<()> {
    let mut scene_path = None;
    let mut density = 1.0f32;
    let mut methods = vec![
        Redistribution::Cross,
        Redistribution::Incremental,
        Redistribution::Full,
    ];
    let mut corrections = DynamicOptions::default().corrections;
    let mut script_path = PathBuf::from("scenes/scripts/teleport-stress.json");
    let mut hold = Hold::Settled;
    let mut surfaces = 5usize;
    let mut trace = false;
    let mut count = usize::MAX;
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        let mut value = |name: &str| args.next().with_context(|| format!("{name} needs a value"));
        match arg.as_str() {
            "--density-scale" => {
                let v = value("--density-scale")?;
                density = v.parse().with_context(|| format!("--density-scale {v}"))?;
            }
            "--methods" => {
                let v = value("--methods")?;
                methods = v
                    .split(',')
                    .map(|m| m.parse().map_err(|e| anyhow::anyhow!("--methods {m}: {e}")))
                    .collect::<Result<_>>()?;
            }
            "--corrections" => {
                let v = value("--corrections")?;
                corrections = v.parse().with_context(|| format!("--corrections {v}"))?;
            }
            "--script" => script_path = PathBuf::from(value("--script")?),
            "--hold" => {
                hold = match value("--hold")?.as_str() {
                    "published" => Hold::Published,
                    "settled" => Hold::Settled,
                    "corrected" => Hold::Corrected,
                    other => bail!("--hold {other}: expected published, settled or corrected"),
                }
            }
            "--trace" => trace = true,
            "--jumps" => {
                let v = value("--jumps")?;
                count = v.parse().with_context(|| format!("--jumps {v}"))?;
            }
            "--surfaces" => {
                let v = value("--surfaces")?;
                surfaces = v.parse().with_context(|| format!("--surfaces {v}"))?;
            }
            other if other.starts_with("--") => bail!("unknown option {other}"),
            other => scene_path = Some(PathBuf::from(other)),
        }
    }
    let scene_path = scene_path.context("usage: round_trip SCENE [options]")?;
    let scene = Scene::load_with(&scene_path, LoadOptions::scaled(density))
        .with_context(|| format!("loading {}", scene_path.display()))?;
    let atlas = Atlas::build(&scene).map_err(|e| anyhow::anyhow!("{e}"))?;
    let script = Script::load(&script_path)?;
    let object = match &script.object {
        Some(name) => scene
            .object_by_name(name)
            .with_context(|| format!("the scene has no object {name}"))?
            as usize,
        None => bail!("{} names no object", script_path.display()),
    };
    let start = scene.initial_poses();
    // The script may end where it starts; the return is made below.
    let jumps: Vec<Vec<Pose>> = script.keys()[1..]
        .iter()
        .map(|k| {
            let mut poses = scene.initial_poses();
            poses[object] = Pose::from(k);
            poses
        })
        .filter(|poses| *poses != start)
        .take(count)
        .collect();
    let device = gpu::Device::new(None)?;
    eprintln!(
        "{}: {} elements on {}; {} jumps of {}, corrections {corrections}",
        scene.name,
        atlas.elements.len(),
        device.describe(),
        jumps.len(),
        script_path.display()
    );
    let keep = Validity::compute(&scene, &atlas, &start);
    println!(
        "| method | lit texels | > 1% off | > 2% | > 5% | p99 | worst | total light | ms to first state | to refined | to corrected | residuals |"
    );
    println!("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |");
    for method in methods {
        let options = DynamicOptions {
            method,
            corrections,
            ..DynamicOptions::default()
        };
        let mut fresh = DynamicSolver::new(&device, &scene, &atlas, &start, 0u64, options)?;
        run(&mut fresh, Hold::Corrected)?;
        let expected = published(&fresh, &atlas)?;
        drop(fresh);

        let mut d = DynamicSolver::new(&device, &scene, &atlas, &start, 0u64, options)?;
        run(&mut d, Hold::Corrected)?;
        for (k, poses) in jumps.iter().enumerate() {
            d.set_poses(poses, k as u64 + 1);
            run(&mut d, hold)?;
            if trace {
                // Against a fresh session at this pose, held as long.
                let mut f = DynamicSolver::new(&device, &scene, &atlas, poses, 0u64, options)?;
                run(&mut f, Hold::Corrected)?;
                let valid = Validity::compute(&scene, &atlas, poses);
                let (got, want) = (published(&d, &atlas)?, published(&f, &atlas)?);
                if let Some(a) = agreement(&atlas, &got, &want, valid.keep()) {
                    eprintln!("  jump {}: {a}", k + 1);
                }
            }
        }
        d.set_poses(&start, jumps.len() as u64 + 1);
        let times = run(&mut d, Hold::Corrected)?;
        let got = published(&d, &atlas)?;
        let a = agreement(&atlas, &got, &expected, keep.keep())
            .context("the fresh state has no lit texel")?;
        let ms =
            |d: Option<Duration>| d.map_or("-".into(), |d| format!("{:.0}", d.as_secs_f64() * 1e3));
        println!(
            "| {method} | {} | {:.1}% | {:.1}% | {:.1}% | {:.2}% | {:.2}% | {:+.2}% | {} | {} | {} | {:?} |",
            a.elements,
            a.over_1 * 100.0,
            a.over_2 * 100.0,
            a.over_5 * 100.0,
            a.p99 * 100.0,
            a.worst * 100.0,
            a.total * 100.0,
            ms(times.first),
            ms(times.settled),
            ms(times.corrected),
            d.correction_residuals()
                .iter()
                .map(|r| format!("{r:.1e}"))
                .collect::<Vec<_>>()
        );
        // The patches whose light differs most.
        let mut by_patch: Vec<(f64, f64)> = vec![(0.0, 0.0); scene.patches.len()];
        for (i, e) in atlas.elements.iter().enumerate() {
            if keep.is_invalid(i) || !e.covers_surface() || e.emission.max_element() > 0.0 {
                continue;
            }
            let p = &mut by_patch[e.patch as usize];
            p.0 += f64::from(e.area) * f64::from(got[i].element_sum());
            p.1 += f64::from(e.area) * f64::from(expected[i].element_sum());
        }
        let mut ratios: Vec<(usize, f64)> = by_patch
            .iter()
            .enumerate()
            .filter(|(_, (_, f))| *f > 0.0)
            .map(|(p, (g, f))| (p, g / f - 1.0))
            .collect();
        ratios.sort_by(|a, b| b.1.abs().total_cmp(&a.1.abs()));
        for (p, r) in ratios.iter().take(surfaces) {
            eprintln!("  {method}: {} {:+.2}%", scene.patches[*p].name, r * 100.0);
        }
    }
    Ok(())
}

/// When the states of one pose came.
struct Times {
    first: Option<Duration>,
    settled: Option<Duration>,
    corrected: Option<Duration>,
}

/// Steps `d` until `hold` is reached.
fn run(d: &mut DynamicSolver<u64>, hold: Hold) -> Result<Times> {
    let started = Instant::now();
    let mut times = Times {
        first: None,
        settled: None,
        corrected: None,
    };
    loop {
        if times.settled.is_none() && d.is_settled() {
            times.settled = Some(started.elapsed());
        }
        if d.is_idle() {
            times.corrected = Some(started.elapsed());
        }
        let done = match hold {
            Hold::Published => times.first.is_some(),
            Hold::Settled => times.settled.is_some(),
            Hold::Corrected => times.corrected.is_some(),
        };
        if done {
            return Ok(times);
        }
        if d.step(Duration::from_millis(20))?.completed && times.first.is_none() {
            times.first = Some(started.elapsed());
        }
    }
}

/// The state as published: clamped at zero, invalid texels filled.
fn published(d: &DynamicSolver<u64>, atlas: &Atlas) -> Result<Vec<Vec3>> {
    let mut b = d.radiosity()?;
    d.progressive().validity().fill(atlas, &mut b);
    Ok(b)
}
