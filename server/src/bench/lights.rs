//! `lightwire bench lights` (issue 60, item 6): what following a light
//! that changes costs, and how right each published state is.
//!
//! Per scene, the first light goes through five changes, one after the
//! other, each from a state that holds still and is corrected (as a
//! session that nobody disturbs is): switched off, switched on again,
//! dimmed to half, recoloured (its channels times (1, 0.6, 0.3)), and
//! moved (a point or spot light 0.5 m along +x, a directional light turned
//! 5° about the vertical). A session of the service's options
//! ([`DynamicOptions::default`], cross redistribution) takes each change
//! with [`DynamicSolver::set_lights`] and steps in 10 ms slices, as the
//! tick loop does; the clock runs from handing it the lights to
//!
//! - the **first state** it completes (what viewers see first),
//! - the **settled** state (refined to the last publication level,
//!   [`DynamicSolver::is_settled`]),
//! - **idle** ([`DynamicSolver::is_idle`]): the gathered corrections
//!   done and, with a basis, the basis built again where the change left
//!   it (a move).
//!
//! Each scene runs twice, side by side: with the service's basis of each
//! light's light (`gpu::basis`: a switch, dim or recolour is one
//! composition, a move is shot) and with shooting alone
//! (`light_basis` 0: every change is its signed direct light shot as
//! unshot radiosity, `ProgressiveSolver::set_light`).
//!
//! Each is compared with the CPU reference solver lit by the new light
//! (NRMSE and p95 relative error over the visible non-emitting elements);
//! a state with no light at all is reported by its brightest texel over
//! the brightest before the change. What a change claims to beat is
//! starting over: the time a fresh session of the same options takes to
//! its first and its corrected state is measured on the same scene in the
//! same run. A shot change (a move, or any change without the basis) is
//! first published as the state so far plus one bounce of the change by
//! virtual point lights and imperfect shadow maps (`gpu::vpl`, ism §4.1,
//! §4.11); a third run per scene keeps the basis but turns that first
//! answer off, to show what it buys.
//!
//! [`sweep`] then varies the first answer's virtual lights and shadow-map
//! points on the move (the ism seed's Fig. 9.8 and 9.9 as a table): per
//! setting, the first state's NRMSE against the reference and the time of
//! each stage (its Table 9.4's columns VPLS, ISM and II, as far as a
//! lightmap has them).

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use glam::{Quat, Vec3};
use serde::Serialize;

use lightwire_scene::atlas::Atlas;
use lightwire_scene::{Charts, Light, LightKind, LoadOptions, Scene};
use lightwire_solve::accuracy::accuracy_where;
use lightwire_solve::gpu::{BounceOptions, Device, DynamicOptions, DynamicSolver};
use lightwire_solve::load::load_scene;
use lightwire_solve::reference::{MAX_ELEMENTS, ReferenceSolver, Silent, SolveOptions};
use lightwire_solve::validity::Validity;

/// How the benchmark runs.
#[derive(Debug, Clone)]
pub struct Settings {
    pub density_scale: f32,
    pub charts: Charts,
    /// [`DynamicOptions::light_basis`] of the session (0: every change
    /// is shot).
    pub light_basis: usize,
    /// [`DynamicOptions::first_bounce`] of the session.
    pub first_bounce: Option<BounceOptions>,
    /// Where [`sweep`] writes its atlas PNGs (none: no images).
    pub images: Option<PathBuf>,
}

/// One change of the light and what following it took.
#[derive(Debug, Clone, Serialize)]
pub struct Change {
    /// `off`, `on`, `dim`, `recolour` or `move`.
    pub change: &'static str,
    /// Milliseconds from `set_lights` to the first completed state, the
    /// settled one and the corrected one.
    pub ms_first: f64,
    pub ms_settled: f64,
    pub ms_corrected: f64,
    /// NRMSE (fraction) of those states against the reference lit by the
    /// new light; `None` for a state with no light.
    pub nrmse_first: Option<f64>,
    pub nrmse_settled: Option<f64>,
    pub nrmse_corrected: Option<f64>,
    /// p95 relative error of the corrected state.
    pub p95_corrected: Option<f64>,
    /// The brightest texel of the corrected state over the brightest
    /// before the change (what a switch-off leaves).
    pub brightest_ratio: f64,
}

/// One scene's result.
#[derive(Debug, Clone, Serialize)]
pub struct LightsResult {
    pub scene: String,
    pub elements: usize,
    /// How the session followed the changes: `basis` (each light's light
    /// kept apart, `gpu::basis`; a move is shot) or `shooting` (every
    /// change shot as signed unshot light).
    pub method: &'static str,
    /// Whether a shot change was first published as one bounce of
    /// virtual point lights (`gpu::vpl`).
    pub first_answer: bool,
    /// Bytes of the basis once built (0 without one).
    pub basis_bytes: usize,
    /// The light changed, and its kind.
    pub light: String,
    pub kind: &'static str,
    /// A fresh session of the same options: ms to its first and its
    /// corrected state, and the corrected state's NRMSE.
    pub fresh_ms_first: f64,
    pub fresh_ms_corrected: f64,
    pub fresh_nrmse: f64,
    pub changes: Vec<Change>,
}

type Session = DynamicSolver<u32>;

const SLICE: Duration = Duration::from_millis(10);

/// The scene file at `path` at the settings' density and charts.
fn load(path: &Path, settings: &Settings) -> Result<(Scene, Atlas)> {
    Ok(load_scene(
        path,
        LoadOptions {
            density_scale: settings.density_scale,
            charts: settings.charts,
        },
    )?)
}

/// Runs the benchmark on the scene file at `path`.
pub fn run(gpu: &Device, path: &Path, settings: &Settings) -> Result<LightsResult> {
    let (scene, atlas) = load(path, settings)?;
    let Some(first) = scene.lights.first().cloned() else {
        bail!(
            "{} has no point, spot or directional light to change (add one under \"lights\")",
            path.display()
        );
    };
    if atlas.elements.len() > MAX_ELEMENTS {
        bail!(
            "{} has {} elements; the reference this benchmark compares with takes at most {MAX_ELEMENTS} (use --density-scale)",
            path.display(),
            atlas.elements.len()
        );
    }
    let poses = scene.initial_poses();
    let validity = Validity::compute(&scene, &atlas, &poses);
    let reference = |lights: &[Light]| -> Result<Vec<Vec3>> {
        let mut lit = scene.clone();
        lit.lights = lights.to_vec();
        Ok(ReferenceSolver::new(&lit, &atlas, &poses, &Silent)?
            .solve(SolveOptions::default(), &Silent)
            .radiosity)
    };
    let nrmse = |values: &[Vec3], expected: &[Vec3]| {
        accuracy_where(&atlas, values, expected, validity.keep()).map(|a| (a.nrmse, a.p95_rel))
    };

    eprintln!("{}: a fresh session", scene.name);
    let options = DynamicOptions {
        light_basis: settings.light_basis,
        first_bounce: settings.first_bounce,
        ..DynamicOptions::default()
    };
    let started = Instant::now();
    let mut fresh = Session::new(gpu, &scene, &atlas, &poses, 0, options)?;
    let mut fresh_ms_first = None;
    while !fresh.is_idle() {
        let step = fresh.step(SLICE)?;
        if step.completed && fresh_ms_first.is_none() {
            fresh_ms_first = Some(ms(started));
        }
    }
    let fresh_ms_corrected = ms(started);
    let start_reference = reference(&scene.lights)?;
    let fresh_nrmse =
        nrmse(&published(&fresh, &atlas)?, &start_reference).map_or(f64::NAN, |a| a.0);

    let basis_bytes = fresh.basis().map_or(0, |b| b.bytes());
    let mut session = fresh;
    let mut lights = scene.lights.clone();
    let mut changes = Vec::new();
    let mut tag = 0;
    for change in ["off", "on", "dim", "recolour", "move"] {
        let mut light = lights[0].clone();
        match change {
            "off" => light.intensity = Vec3::ZERO,
            "on" => light.intensity = first.intensity,
            "dim" => light.intensity *= 0.5,
            "recolour" => light.intensity *= Vec3::new(1.0, 0.6, 0.3),
            _ => moved(&mut light),
        }
        lights[0] = light;
        let expected = reference(&lights)?;
        let before = brightest(&published(&session, &atlas)?);
        eprintln!("{}: {change}", scene.name);
        tag += 1;
        let started = Instant::now();
        session.set_lights(&lights, tag);
        let mut first_state = None;
        let mut settled = None;
        while !session.is_idle() {
            let step = session.step(SLICE)?;
            if step.completed && first_state.is_none() && session.reflected() == &tag {
                first_state = Some((ms(started), published(&session, &atlas)?));
            }
            if settled.is_none() && session.is_settled() && session.reflected() == &tag {
                settled = Some((ms(started), published(&session, &atlas)?));
            }
        }
        let ms_corrected = ms(started);
        let corrected = published(&session, &atlas)?;
        let (ms_first, first_b) = first_state.context("no state completed after the change")?;
        let (ms_settled, settled_b) = settled.unwrap_or((ms_corrected, corrected.clone()));
        let c = nrmse(&corrected, &expected);
        changes.push(Change {
            change,
            ms_first,
            ms_settled,
            ms_corrected,
            nrmse_first: nrmse(&first_b, &expected).map(|a| a.0),
            nrmse_settled: nrmse(&settled_b, &expected).map(|a| a.0),
            nrmse_corrected: c.map(|a| a.0),
            p95_corrected: c.map(|a| a.1),
            brightest_ratio: if before > 0.0 {
                f64::from(brightest(&corrected) / before)
            } else {
                f64::NAN
            },
        });
    }
    Ok(LightsResult {
        scene: scene.name.clone(),
        elements: atlas.elements.len(),
        method: if basis_bytes > 0 { "basis" } else { "shooting" },
        first_answer: settings.first_bounce.is_some(),
        basis_bytes,
        light: first.name.clone(),
        kind: match first.kind {
            LightKind::Point => "point",
            LightKind::Spot { .. } => "spot",
            LightKind::Directional { .. } => "directional",
        },
        fresh_ms_first: fresh_ms_first.unwrap_or(fresh_ms_corrected),
        fresh_ms_corrected,
        fresh_nrmse,
        changes,
    })
}

/// The benchmark's move of `light`: a point or spot light 0.5 m along
/// +x, a directional light turned 5° about the vertical.
fn moved(light: &mut Light) {
    match &mut light.kind {
        LightKind::Directional { direction, .. } => {
            *direction = Quat::from_rotation_y(5f32.to_radians()) * *direction;
        }
        _ => light.position += Vec3::X * 0.5,
    }
}

/// The sweep's move of `light`, one that changes most of a room's light:
/// a point or spot light 1.5 m along -x, 1 m down and 0.5 m along +z, a
/// directional light turned 30° about the vertical.
fn far(light: &mut Light) {
    match &mut light.kind {
        LightKind::Directional { direction, .. } => {
            *direction = Quat::from_rotation_y(30f32.to_radians()) * *direction;
        }
        _ => light.position += Vec3::new(-1.5, -1.0, 0.5),
    }
}

/// The session's state as published: clamped, invalid texels filled.
fn published(session: &Session, atlas: &Atlas) -> Result<Vec<Vec3>> {
    let mut b = session.radiosity()?;
    session.progressive().validity().fill(atlas, &mut b);
    Ok(b)
}

fn brightest(b: &[Vec3]) -> f32 {
    b.iter().map(|c| c.max_element()).fold(0.0, f32::max)
}

fn ms(since: Instant) -> f64 {
    since.elapsed().as_secs_f64() * 1e3
}

/// `x` as a percentage with two decimals, or `dark` for no light.
fn pct(x: Option<f64>) -> String {
    x.map_or_else(|| "dark".into(), |x| format!("{:.2}%", x * 100.0))
}

/// Prints one scene's result as Markdown tables.
pub fn print(r: &LightsResult) {
    let basis = if r.basis_bytes > 0 {
        format!("basis of {:.1} KB", r.basis_bytes as f64 / 1024.0)
    } else {
        "no basis".into()
    };
    println!(
        "\n{} ({} elements), light \"{}\" ({}), {} ({basis}), {}: a fresh session's first state {:.0} ms, idle {:.0} ms, NRMSE {:.2}%",
        r.scene,
        r.elements,
        r.light,
        r.kind,
        r.method,
        if r.first_answer {
            "first answer by virtual lights"
        } else {
            "no first answer"
        },
        r.fresh_ms_first,
        r.fresh_ms_corrected,
        r.fresh_nrmse * 100.0
    );
    println!(
        "| change | ms to first state | NRMSE | ms settled | NRMSE | ms to idle | NRMSE | p95 rel | brightest / before |"
    );
    println!("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |");
    for c in &r.changes {
        println!(
            "| {} | {:.0} | {} | {:.0} | {} | {:.0} | {} | {} | {} |",
            c.change,
            c.ms_first,
            pct(c.nrmse_first),
            c.ms_settled,
            pct(c.nrmse_settled),
            c.ms_corrected,
            pct(c.nrmse_corrected),
            pct(c.p95_corrected),
            if c.brightest_ratio.is_nan() {
                "from dark".to_string()
            } else {
                format!("{:.3}", c.brightest_ratio)
            }
        );
    }
}

/// The default scenes: those of `scenes/` lit by a point light or a sun.
pub fn default_scenes(scenes: &Path) -> Vec<PathBuf> {
    ["cornell-point.json", "window-sun.json"]
        .iter()
        .map(|f| scenes.join(f))
        .collect()
}

/// One setting of the first answer on the sweep's move.
#[derive(Debug, Clone, Serialize)]
pub struct SweepRow {
    pub scene: String,
    /// Bounces gathered, and whether the rest was added as a series.
    pub bounces: u32,
    pub tail: bool,
    /// Virtual point lights asked for per bounce, and placed in all.
    pub vpls: u32,
    pub vpls_placed: usize,
    /// Points splatted into each light's shadow map.
    pub points: u32,
    /// Milliseconds from `set_lights` to the first state.
    pub ms_first: f64,
    /// The first bounce's stages (ms): placing the lights and uploading,
    /// the shadow maps (splat and pull-push), the gather and read-back.
    pub ms_vpls: f64,
    pub ms_maps: f64,
    pub ms_gather: f64,
    /// The first state against the reference lit by the moved light.
    pub nrmse_first: f64,
    pub p95_first: f64,
    /// The first state's light over the reference's, less one
    /// (area-weighted over the visible non-emitting texels): below zero
    /// where bounces are missing.
    pub bias_first: f64,
}

/// A larger move than the changes' ([`far`]) and back, once per setting
/// of `bounces`, on one session without the basis (every setting starts
/// from the same corrected state at the first light): the first state's
/// error and the time of each stage.
pub fn sweep(
    gpu: &Device,
    path: &Path,
    settings: &Settings,
    bounces: &[BounceOptions],
) -> Result<Vec<SweepRow>> {
    let (scene, atlas) = load(path, settings)?;
    if scene.lights.is_empty() || atlas.elements.len() > MAX_ELEMENTS {
        bail!(
            "{}: the sweep needs a light and at most {MAX_ELEMENTS} elements",
            path.display()
        );
    }
    let poses = scene.initial_poses();
    let validity = Validity::compute(&scene, &atlas, &poses);
    let start = scene.lights.clone();
    let mut there = start.clone();
    far(&mut there[0]);
    let mut lit = scene.clone();
    lit.lights = there.clone();
    let expected = ReferenceSolver::new(&lit, &atlas, &poses, &Silent)?
        .solve(SolveOptions::default(), &Silent)
        .radiosity;
    let options = DynamicOptions {
        light_basis: 0,
        ..DynamicOptions::default()
    };
    let mut session = Session::new(gpu, &scene, &atlas, &poses, 0, options)?;
    while !session.is_idle() {
        session.step(SLICE)?;
    }
    let mut rows = Vec::new();
    let mut tag = 0;
    for bounce in bounces {
        eprintln!(
            "{}: first answer with {} virtual lights, {} points each",
            scene.name, bounce.vpls, bounce.points
        );
        session.set_first_bounce(Some(*bounce));
        tag += 1;
        let started = Instant::now();
        session.set_lights(&there, tag);
        let first = loop {
            let step = session.step(SLICE)?;
            if step.completed && session.reflected() == &tag {
                break (ms(started), published(&session, &atlas)?);
            }
        };
        let times = session.bounce_report().unwrap_or_default();
        if let Some(dir) = &settings.images {
            let name = format!(
                "{}-b{}{}-v{}-p{}",
                scene.name,
                bounce.bounces,
                if bounce.tail { "t" } else { "" },
                bounce.vpls,
                bounce.points
            );
            write_images(dir, &atlas, (&scene.name, &name), &first.1, &expected)?;
        }
        let a = accuracy_where(&atlas, &first.1, &expected, validity.keep())
            .context("no visible texel to compare")?;
        rows.push(SweepRow {
            scene: scene.name.clone(),
            bounces: bounce.bounces,
            tail: bounce.tail,
            vpls: bounce.vpls,
            vpls_placed: times.placed,
            points: bounce.points,
            ms_first: first.0,
            ms_vpls: times.vpls.as_secs_f64() * 1e3,
            ms_maps: times.maps.as_secs_f64() * 1e3,
            ms_gather: times.gather.as_secs_f64() * 1e3,
            nrmse_first: a.nrmse,
            p95_first: a.p95_rel,
            bias_first: bias(&atlas, &validity, &first.1, &expected),
        });
        // Back to the start, corrected, for the next setting.
        while !session.is_idle() {
            session.step(SLICE)?;
        }
        tag += 1;
        session.set_lights(&start, tag);
        while !session.is_idle() {
            session.step(SLICE)?;
        }
    }
    Ok(rows)
}

/// `values`' light over `expected`'s, less one: area-weighted sums over
/// the valid non-emitting texels, channels summed.
fn bias(atlas: &Atlas, validity: &Validity, values: &[Vec3], expected: &[Vec3]) -> f64 {
    let (mut got, mut want) = (0.0f64, 0.0f64);
    for (i, e) in atlas.elements.iter().enumerate() {
        if validity.is_invalid(i) || !e.covers_surface() || e.emission != Vec3::ZERO {
            continue;
        }
        got += f64::from(e.area * values[i].element_sum());
        want += f64::from(e.area * expected[i].element_sum());
    }
    if want > 0.0 {
        got / want - 1.0
    } else {
        f64::NAN
    }
}

/// `NAME.png` (the state) and `NAME-diff5.png` (five times its difference
/// from `expected`) in `dir`, at the white point of `expected`; and
/// `SCENE-reference.png` once.
fn write_images(
    dir: &Path,
    atlas: &Atlas,
    (scene, name): (&str, &str),
    values: &[Vec3],
    expected: &[Vec3],
) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let reference = atlas.to_image(expected);
    let white = crate::bake::white_point(&reference);
    let (w, h) = (atlas.width, atlas.height);
    let path = dir.join(format!("{scene}-reference.png"));
    if !path.exists() {
        crate::bake::write_png_with(&path, w, h, &reference, white)?;
    }
    crate::bake::write_png_with(
        &dir.join(format!("{name}.png")),
        w,
        h,
        &atlas.to_image(values),
        white,
    )?;
    let diff: Vec<Vec3> = values
        .iter()
        .zip(expected)
        .map(|(a, b)| (*a - *b).abs() * 5.0)
        .collect();
    crate::bake::write_png_with(
        &dir.join(format!("{name}-diff5.png")),
        w,
        h,
        &atlas.to_image(&diff),
        white,
    )
}

/// The settings [`sweep`] tries by default: no bounce; one to three
/// bounces with and without the tail; virtual lights from 16 to 1,024 at
/// the service's points; points per map from 128 to 8,192 at its lights.
pub fn sweep_settings() -> Vec<BounceOptions> {
    let base = BounceOptions::default();
    let mut list = vec![BounceOptions { bounces: 0, ..base }];
    for (bounces, tail) in [(1, false), (1, true), (2, false), (3, true)] {
        list.push(BounceOptions {
            bounces,
            tail,
            ..base
        });
    }
    for vpls in [16, 64, 256, 1024] {
        list.push(BounceOptions { vpls, ..base });
    }
    for points in [128, 512, 8192] {
        list.push(BounceOptions { points, ..base });
    }
    list
}

/// Prints a sweep as a Markdown table.
pub fn print_sweep(rows: &[SweepRow]) {
    let Some(first) = rows.first() else {
        return;
    };
    println!(
        "\n{}: the far move's first answer by virtual point lights and imperfect shadow maps",
        first.scene
    );
    println!(
        "| bounces | virtual lights (placed) | points per map | NRMSE | p95 rel | light / reference | ms to first state | lights ms | maps ms | gather ms |"
    );
    println!("| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |");
    for r in rows {
        println!(
            "| {}{} | {} ({}) | {} | {:.2}% | {:.2}% | {:+.1}% | {:.0} | {:.1} | {:.1} | {:.1} |",
            r.bounces,
            if r.tail && r.bounces > 0 {
                " + tail"
            } else {
                ""
            },
            r.vpls,
            r.vpls_placed,
            r.points,
            r.nrmse_first * 100.0,
            r.p95_first * 100.0,
            r.bias_first * 100.0,
            r.ms_first,
            r.ms_vpls,
            r.ms_maps,
            r.ms_gather
        );
    }
}
