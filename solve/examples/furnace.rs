//! A furnace for a closed level: where the progressive solver loses light.
//!
//! ```text
//! cargo run --release -p lightwire-solve --example furnace -- \
//!     scenes/levels/garage.json [--albedo 0.5] [--tolerance 1e-3] \
//!     [--density-scale S] [--resolution PIXELS] [--worst N] [--no-clusters]
//! ```
//!
//! Every material is replaced by one that emits `E = 1` W/m² and reflects
//! `ρ` (grey). In a closed room every point then sees surfaces of radiosity
//! `B` in every direction, so `B = E + ρ B` and the exact solution is
//! `B = E / (1 − ρ)` everywhere, whatever the geometry. A solver that
//! loses a share `x` of what each bounce carries reads
//! `E / (1 − ρ (1 − x))` instead: at ρ = 0.5, 10% lost per bounce reads
//! 0.909 of the truth. So the ratio `B / (E / (1 − ρ))` over the valid
//! texels measures the transport's loss (or gain) without any reference
//! solution, and per surface it says where.
//!
//! A level that is not closed lets light escape for real: the example casts
//! rays from every valid texel and prints the share of its hemisphere that
//! sees nothing ("open"); only texels with little of it are judged.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use glam::Vec3;
use lightwire_scene::atlas::Atlas;
use lightwire_scene::{LoadOptions, Scene};
use lightwire_solve::gpu;
use lightwire_solve::raycast::{CosineGrid, Raycaster};
use lightwire_solve::validity::Validity;

/// Rays per side of each texel's cosine grid for its open share (64 rays).
const OPEN_GRID: usize = 8;
/// Texels more open than this are not judged.
const OPEN_LIMIT: f64 = 0.02;

fn main() -> Result<()> {
    let mut scene_path = None;
    let mut albedo = 0.5f32;
    let mut tolerance = 1e-3f64;
    let mut density = 1.0f32;
    let mut worst = 20usize;
    let mut options = gpu::ProgressiveOptions::default();
    let mut args = std::env::args().skip(1);
    let number = |flag: &str, v: Option<String>| -> Result<f64> {
        let v = v.with_context(|| format!("{flag} needs a number"))?;
        v.parse::<f64>().with_context(|| format!("{flag} {v}"))
    };
    while let Some(arg) = args.next() {
        match arg.as_str() {
            "--albedo" => albedo = number("--albedo", args.next())? as f32,
            "--tolerance" => tolerance = number("--tolerance", args.next())?,
            "--density-scale" => density = number("--density-scale", args.next())? as f32,
            "--resolution" => {
                options.hemicube_resolution = number("--resolution", args.next())? as u32
            }
            "--worst" => worst = number("--worst", args.next())? as usize,
            "--no-clusters" => options.cluster_triangles = false,
            flag if flag.starts_with("--") => bail!("unknown option {flag}"),
            path => scene_path = Some(PathBuf::from(path)),
        }
    }
    if !(0.0..1.0).contains(&albedo) {
        bail!("--albedo {albedo}: must be in [0, 1)");
    }
    let path = scene_path.context(
        "usage: furnace SCENE [--albedo A] [--tolerance T] [--density-scale S] [--resolution PIXELS] [--worst N] [--no-clusters]",
    )?;
    let mut scene = Scene::load_with(&path, LoadOptions::scaled(density))
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    for m in &mut scene.materials {
        m.albedo = Vec3::splat(albedo);
        m.emission = Vec3::ONE;
    }
    let atlas = Atlas::build(&scene).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    let poses = scene.initial_poses();
    let validity = Validity::compute(&scene, &atlas, &poses);
    let exact = 1.0 / (1.0 - f64::from(albedo));

    // The open share of each valid texel's hemisphere.
    let caster = Raycaster::new(&scene, &poses);
    let reach = caster.extent() * 4.0;
    let grid = CosineGrid::new(OPEN_GRID);
    let open: Vec<f64> = atlas
        .elements
        .iter()
        .enumerate()
        .map(|(i, e)| {
            if validity.is_invalid(i) || !e.covers_surface() {
                return 1.0;
            }
            let pose = &poses[e.object as usize];
            let n = pose.transform_normal(e.normal).as_dvec3().normalize();
            let x = pose.transform_point(e.position).as_dvec3() + n * 1e-4;
            let escaped = grid
                .around(n)
                .filter(|&d| caster.closest_hit(x, d, reach).is_none())
                .count();
            escaped as f64 / grid.len() as f64
        })
        .collect();

    let device = gpu::Device::new(None)?;
    let mut solver = gpu::ProgressiveSolver::new(&device, &scene, &atlas, &poses, options)?;
    let started = std::time::Instant::now();
    solver.solve(tolerance)?;
    let seconds = started.elapsed().as_secs_f64();
    let b = solver.radiosity()?;
    let balance = solver.energy_balance()?;

    let mean = |v: Vec3| f64::from(v.x + v.y + v.z) / 3.0;
    let (mut judged, mut area_all, mut area_invalid) = (Vec::new(), 0.0, 0.0);
    // What a texel receives against what its closed surroundings send:
    // H / B_exact with H = (B − E) / ρ. With the surroundings exact it is
    // one bounce's delivery; at a small ρ (0.05) they nearly are.
    let mut delivered = Vec::new();
    for (i, e) in atlas.elements.iter().enumerate() {
        let a = f64::from(e.area);
        if !e.covers_surface() {
            continue;
        }
        area_all += a;
        if validity.is_invalid(i) {
            area_invalid += a;
        } else if open[i] <= OPEN_LIMIT {
            judged.push((mean(b[i]) / exact, a, i));
            if albedo > 0.0 {
                delivered.push(((mean(b[i]) - 1.0) / (f64::from(albedo) * exact), a, i));
            }
        }
    }
    let judged_area: f64 = judged.iter().map(|j| j.1).sum();
    let weighted_mean = judged.iter().map(|j| j.0 * j.1).sum::<f64>() / judged_area.max(1e-30);
    judged.sort_by(|x, y| x.0.total_cmp(&y.0));
    delivered.sort_by(|x, y| x.0.total_cmp(&y.0));
    let quantile_of = |judged: &[(f64, f64, usize)], q: f64| {
        let mut acc = 0.0;
        for j in judged {
            acc += j.1;
            if acc >= q * judged_area {
                return j.0;
            }
        }
        judged.last().map_or(f64::NAN, |j| j.0)
    };
    println!(
        "{}: {} elements, {} invalid ({:.1}% of the surface area); ρ = {albedo}, exact B = {exact:.4}",
        scene.name,
        atlas.elements.len(),
        validity.count(),
        100.0 * area_invalid / area_all.max(1e-30)
    );
    println!(
        "progressive: {seconds:.1} s, {} shots to {tolerance:e}; energy shot {:.2} W, received {:.2} W ({:.4})",
        solver.total_shots(),
        balance.shot,
        balance.received,
        balance.received / balance.shot.max(1e-30)
    );
    let open_area: f64 = atlas
        .elements
        .iter()
        .enumerate()
        .filter(|(i, e)| e.covers_surface() && !validity.is_invalid(*i) && open[*i] > OPEN_LIMIT)
        .map(|(_, e)| f64::from(e.area))
        .sum();
    println!(
        "judged: {} texels, {:.1}% of the valid area ({:.1}% more than {:.0}% open)",
        judged.len(),
        100.0 * judged_area / (area_all - area_invalid).max(1e-30),
        100.0 * open_area / (area_all - area_invalid).max(1e-30),
        100.0 * OPEN_LIMIT
    );
    let quantile = |q: f64| quantile_of(&judged, q);
    println!(
        "B / exact, area-weighted: mean {weighted_mean:.4}, p1 {:.4}, p5 {:.4}, p25 {:.4}, median {:.4}, p75 {:.4}, p95 {:.4}, p99 {:.4}",
        quantile(0.01),
        quantile(0.05),
        quantile(0.25),
        quantile(0.5),
        quantile(0.75),
        quantile(0.95),
        quantile(0.99)
    );
    if !delivered.is_empty() {
        let q = |p: f64| quantile_of(&delivered, p);
        let mean = delivered.iter().map(|j| j.0 * j.1).sum::<f64>() / judged_area.max(1e-30);
        println!(
            "received / sent by the surroundings, (B − E) / (ρ B_exact): mean {mean:.4}, p1 {:.4}, p5 {:.4}, p25 {:.4}, median {:.4}, p75 {:.4}, p95 {:.4}, p99 {:.4}",
            q(0.01),
            q(0.05),
            q(0.25),
            q(0.5),
            q(0.75),
            q(0.95),
            q(0.99)
        );
        let dark: Vec<_> = delivered.iter().filter(|j| j.0 < 0.25).collect();
        let dark_area: f64 = dark.iter().map(|j| j.1).sum();
        println!(
            "{} texels ({:.2}% of the judged area) receive less than a quarter; a spread of them:",
            dark.len(),
            100.0 * dark_area / judged_area.max(1e-30)
        );
        for j in dark
            .iter()
            .step_by((dark.len() / worst.max(1)).max(1))
            .take(worst)
        {
            let e = &atlas.elements[j.2];
            println!(
                "  {:.4} at {:.3} {:.3} {:.3} facing {:.2} {:.2} {:.2}, {}",
                j.0,
                e.position.x,
                e.position.y,
                e.position.z,
                e.normal.x,
                e.normal.y,
                e.normal.z,
                scene.patches[e.patch as usize].name
            );
        }
    }
    // Per surface: the area-weighted mean ratio, worst first by lost power.
    let mut per_patch = vec![(0.0f64, 0.0f64, 0usize); scene.patches.len()];
    for &(r, a, i) in &judged {
        let p = &mut per_patch[atlas.elements[i].patch as usize];
        p.0 += r * a;
        p.1 += a;
        p.2 += 1;
    }
    let mut order: Vec<usize> = (0..per_patch.len())
        .filter(|&p| per_patch[p].1 > 0.0)
        .collect();
    order.sort_by(|&x, &y| {
        let lost = |p: usize| per_patch[p].1 - per_patch[p].0;
        lost(y).total_cmp(&lost(x))
    });
    println!("surface | texels | area m² | B / exact | lost share of all judged power");
    let judged_power = weighted_mean * judged_area;
    for &p in order.iter().take(worst) {
        let (ra, a, n) = per_patch[p];
        let centre = atlas
            .elements_of(p as u32)
            .map(|i| atlas.elements[i].position)
            .fold(Vec3::ZERO, |s, x| s + x)
            / atlas.elements_of(p as u32).len().max(1) as f32;
        println!(
            "{:<24} | {n:5} | {a:7.3} | {:.4} | {:.4} at {:.2} {:.2} {:.2}",
            scene.patches[p].name,
            ra / a,
            (a - ra) / judged_power.max(1e-30),
            centre.x,
            centre.y,
            centre.z
        );
    }
    Ok(())
}
