//! Point, spot and directional lights and a sky (issue 59) in the solvers
//! that light them: the CPU reference, the ray solver and the path tracer,
//! against closed forms on a plate (a point light's `I cos θ / r²`, a
//! spot's cone, a hard shadow, the sun's `E cos θ` on a tilted plate, an
//! open sky's `π L` and a sky half hidden by a long wall) and against each
//! other in a Cornell box lit by a point light; the GPU solvers against
//! the reference on a scene of each kind of light.

mod common;

use glam::{DVec3, Vec3};
use lightwire_scene::Scene;
use lightwire_scene::atlas::Atlas;
use lightwire_solve::accuracy;
use lightwire_solve::pathtrace::{self, PathTracer, Silent};
use lightwire_solve::rays::{self, RaySolver};
use lightwire_solve::reference::{self, ReferenceSolver, SolveOptions};
use lightwire_solve::solver::{self, SolverKind, SolverSettings};

/// Albedo of the plate.
const RHO: f64 = 0.5;
/// Where the light hangs over the 4 x 4 m plate (y up).
const LIGHT: DVec3 = DVec3::new(2.0, 1.0, 2.0);
/// Its intensity, W/sr.
const INTENSITY: f64 = 3.0;

/// A 4 x 4 m plate facing up, lit by `light` (a JSON light without name
/// and position), with a 1 x 1 m blocker 0.5 m up under the light when
/// `blocker` (facing up: its underside, a back face, reflects nothing).
fn plate(light: &str, blocker: bool) -> (Scene, Atlas) {
    let block = if blocker {
        r#", { "name": "blocker", "material": "m",
               "quad": { "origin": [1.5, 0.5, 1.5], "u": [0, 0, 1], "v": [1, 0, 0] } }"#
    } else {
        ""
    };
    common::parse(&format!(
        r#"{{ "name": "plate", "lightmap": {{ "texel_density": 4 }},
            "materials": [{{ "name": "m", "albedo": [{RHO}, {RHO}, {RHO}] }}],
            "surfaces": [{{ "name": "floor", "material": "m",
                "quad": {{ "origin": [0, 0, 0], "u": [0, 0, 4], "v": [4, 0, 0] }} }}{block}],
            "lights": [{{ "name": "l", "position": [{}, {}, {}], "intensity": {INTENSITY}, {light} }}] }}"#,
        LIGHT.x, LIGHT.y, LIGHT.z
    ))
}

/// The three solvers' radiosity per element (the path tracer at 4 paths:
/// on a plate lit directly its estimate is exact).
fn solve_all(scene: &Scene, atlas: &Atlas) -> [(&'static str, Vec<Vec3>); 3] {
    solve_all_at(scene, atlas, 4)
}

/// [`solve_all`] with the path tracer at `spp` paths per element.
fn solve_all_at(scene: &Scene, atlas: &Atlas, spp: u32) -> [(&'static str, Vec<Vec3>); 3] {
    let poses = scene.initial_poses();
    let reference = ReferenceSolver::new(scene, atlas, &poses, &reference::Silent)
        .expect("small scene")
        .solve(SolveOptions::default(), &reference::Silent)
        .radiosity;
    let mut rays = RaySolver::new(
        scene,
        atlas,
        &poses,
        (rays::SIDE, lightwire_solve::direct::GRID),
        &|_, _| {},
    );
    rays.solve(atlas, 1e-6, None, &|_, _| {});
    let traced = PathTracer::new(scene, &poses)
        .estimate_elements(atlas, spp, &Silent)
        .iter()
        .map(|e| e.mean)
        .collect();
    [
        ("reference", reference),
        ("rays", rays.radiosity().to_vec()),
        ("path tracer", traced),
    ]
}

/// Every floor element against `expected(p)` (its sample position `p`),
/// relative to 1e-4 of the largest value; `skip(p)` leaves some out.
fn assert_plate(
    scene: &Scene,
    atlas: &Atlas,
    expected: impl Fn(DVec3) -> f64,
    skip: impl Fn(DVec3) -> bool,
) {
    let floor = 0;
    let max = atlas
        .elements_of(floor)
        .map(|i| expected(atlas.elements[i].position.as_dvec3()))
        .fold(0.0, f64::max);
    assert!(max > 0.0);
    for (name, b) in solve_all(scene, atlas) {
        let mut checked = 0;
        for i in atlas.elements_of(floor) {
            let p = atlas.elements[i].position.as_dvec3();
            if skip(p) {
                continue;
            }
            let want = expected(p);
            let got = f64::from(b[i].x);
            assert!(
                (got - want).abs() <= 1e-4 * max + 1e-3 * want,
                "{name}: element {i} at {p}: {got} where the closed form gives {want}"
            );
            checked += 1;
        }
        assert!(checked > 100, "{name}: {checked} elements checked");
    }
}

/// `ρ I cos θ / r²` at `p` on the floor (normal +y), times `falloff` of the
/// angle from straight down.
fn lit(p: DVec3, falloff: impl Fn(f64) -> f64) -> f64 {
    let d = LIGHT - p;
    let r = d.length();
    let cos = d.y / r;
    RHO * INTENSITY * falloff(cos.acos()) * cos / (r * r)
}

#[test]
fn a_point_light_gives_a_plate_i_cos_theta_over_r_squared() {
    let (scene, atlas) = plate(r#""type": "point""#, false);
    assert_plate(&scene, &atlas, |p| lit(p, |_| 1.0), |_| false);
}

/// glTF's spot falloff, written out here: the square of the cosine's
/// linear ramp from the outer cone (0) to the inner (1).
#[test]
fn a_spot_light_lights_its_cone_with_gltfs_falloff() {
    let (inner, outer) = (20f64.to_radians(), 40f64.to_radians());
    let (scene, atlas) = plate(
        r#""type": "spot", "direction": [0, -1, 0], "inner_cone_deg": 20, "outer_cone_deg": 40"#,
        false,
    );
    let falloff = |angle: f64| {
        let t = ((angle.cos() - outer.cos()) / (inner.cos() - outer.cos())).clamp(0.0, 1.0);
        t * t
    };
    assert_plate(&scene, &atlas, |p| lit(p, falloff), |_| false);
    // The cone ends on the plate: some elements are dark, some full.
    let dark = atlas
        .elements_of(0)
        .filter(|&i| {
            falloff(
                (LIGHT - atlas.elements[i].position.as_dvec3())
                    .normalize()
                    .y
                    .acos(),
            ) == 0.0
        })
        .count();
    assert!(dark > 50, "{dark} elements outside the cone");
}

/// The blocker's shadow on the floor is the square it projects from the
/// light: x and z from 1 to 3 m. Inside it (10 cm in from the edge) no
/// light; outside (10 cm out) the open plate's; the edge itself is left
/// out (the sample points sit off the surface by a hair).
#[test]
fn a_point_light_casts_a_hard_shadow() {
    let (scene, atlas) = plate(r#""type": "point""#, true);
    let inside =
        |p: DVec3, m: f64| (1.0 + m..=3.0 - m).contains(&p.x) && (1.0 + m..=3.0 - m).contains(&p.z);
    assert_plate(
        &scene,
        &atlas,
        |p| if inside(p, 0.0) { 0.0 } else { lit(p, |_| 1.0) },
        |p| inside(p, -0.1) && !inside(p, 0.1),
    );
}

/// The path tracer's estimate of what each texel of `atlas` holds: its
/// light at its sample, or its area average where a light's shadow edge
/// crosses it (`lights::texel_irradiance`). Which texels those are, the
/// test finds by its own shadow rays from a 9 x 9 grid over each texel,
/// its sides and corners included
/// (towards each point or spot light, and towards each sun's centre); the
/// path tracer then estimates each texel's value the way it is held, at
/// the sample or over the texel. Returns the estimates and how many
/// texels straddle an edge.
fn held_by_path_tracer(
    scene: &Scene,
    atlas: &Atlas,
    spp: u32,
) -> (Vec<pathtrace::Estimate>, usize) {
    use lightwire_scene::LightKind;
    let poses = scene.initial_poses();
    let tracer = PathTracer::new(scene, &poses);
    let at_samples = tracer.estimate_elements(atlas, spp, &Silent);
    let caster = lightwire_solve::raycast::Raycaster::new(scene, &poses);
    let sees = |p: DVec3, n: DVec3| -> Vec<bool> {
        scene
            .lights
            .iter()
            .map(|light| {
                let (d, max) = match light.kind {
                    LightKind::Directional { direction, .. } => {
                        (-direction.as_dvec3(), f64::INFINITY)
                    }
                    _ => {
                        let d = light.position.as_dvec3() - p;
                        (d.normalize(), d.length())
                    }
                };
                n.dot(d) > 0.0 && !caster.occluded(p, d, max)
            })
            .collect()
    };
    let straddles = |i: usize| {
        let e = &atlas.elements[i];
        if !e.covers_surface() {
            return false;
        }
        let wp = &caster.patches()[e.patch as usize];
        let [s0, t0, s1, t1] = e.region.map(f64::from);
        let mut first: Option<Vec<bool>> = None;
        // 9 x 9 points from edge to edge (just inside): a grid of cell
        // centres misses an edge that cuts off a sliver along the texel's
        // side, which the solvers' corner probes catch (window-sun's patch
        // edge 2 cm inside a 28 cm texel read 6.7% apart for that)
        let at = |k: usize| (k as f64 / 8.0).clamp(1e-4, 1.0 - 1e-4);
        for a in 0..9 {
            for b in 0..9 {
                let (s, t) = (s0 + (s1 - s0) * at(a), t0 + (t1 - t0) * at(b));
                let seen = sees(wp.at(s, t) + wp.normal * 1e-4, wp.normal);
                match &first {
                    None => first = Some(seen),
                    Some(f) if *f != seen => return true,
                    Some(_) => {}
                }
            }
        }
        false
    };
    let held: Vec<bool> = (0..atlas.elements.len()).map(straddles).collect();
    let estimates = (0..atlas.elements.len())
        .map(|i| {
            if held[i] {
                tracer.estimate_texel(atlas, i, spp)
            } else {
                at_samples[i]
            }
        })
        .collect();
    (estimates, held.iter().filter(|h| **h).count())
}

/// Interreflection under the other kinds of light: the reference and the
/// path tracer (4,096 paths, 16,384 in window-sun; what each texel holds:
/// [`held_by_path_tracer`])
/// within 1% plus the path tracer's noise over the non-emitting elements on a Cornell box lit by a spot (cornell-point's bulb made a spot
/// pointing down, cones 25°/40°), `window-sun` (a sun through a window and
/// a dim sky) and `courtyard` (a sun and a sky, no roof).
#[test]
fn reference_and_path_tracer_agree_under_a_spot_a_sun_and_a_sky() {
    let spot = std::fs::read_to_string(common::scene_path("cornell-point.json"))
        .expect("cornell-point.json")
        .replace(
            r#""type": "point", "position": [2.78, 4.488, 2.796], "intensity": 8"#,
            r#""type": "spot", "position": [2.78, 4.488, 2.796], "direction": [0, -1, 0], "intensity": 12, "inner_cone_deg": 25, "outer_cone_deg": 40"#,
        );
    assert!(spot.contains("\"spot\""), "the bulb became a spot");
    // (name, scene, paths: the sun patch lights window-sun's room through
    // a few bright texels, which paths find by chance)
    let scenes = [
        ("cornell-spot", common::parse_scaled(&spot, 0.5), 4096),
        ("window-sun", common::load("window-sun.json", 0.7), 16384),
        ("courtyard", common::load("courtyard.json", 0.7), 4096),
    ];
    for (name, (scene, atlas), spp) in scenes {
        reference_within_one_percent_of_the_path_tracer(name, &scene, &atlas, spp);
    }
}

/// Solves `scene` with the reference and asserts it within 1% plus the
/// path tracer's noise of what the path tracer says each texel holds
/// ([`held_by_path_tracer`] at `spp` paths) over the non-emitting
/// elements, and that noise under 1.5% (else there is nothing to judge).
/// Returns the path tracer's values, how many texels straddle a shadow
/// edge, and the reference's radiosity.
fn reference_within_one_percent_of_the_path_tracer(
    name: &str,
    scene: &Scene,
    atlas: &Atlas,
    spp: u32,
) -> (Vec<Vec3>, usize, Vec<Vec3>) {
    let poses = scene.initial_poses();
    let solution = ReferenceSolver::new(scene, atlas, &poses, &reference::Silent)
        .expect("small scene")
        .solve(SolveOptions::default(), &reference::Silent);
    let (estimates, straddling) = held_by_path_tracer(scene, atlas, spp);
    let values: Vec<Vec3> = estimates.iter().map(|e| e.mean).collect();
    let noise = pathtrace::noise_summary(atlas, &estimates);
    let accuracy = accuracy::accuracy(atlas, &values, &solution.radiosity).expect("lit");
    let report = format!(
        "{} elements ({straddling} straddling a shadow edge), path tracer at {spp} spp (noise NRMSE {:.2}%) vs reference: {accuracy}",
        atlas.elements.len(),
        noise.noise_nrmse * 100.0
    );
    eprintln!("{name}: {report}");
    assert!(
        accuracy.nrmse <= 0.01 + noise.noise_nrmse,
        "{name}: {report}"
    );
    assert!(
        noise.noise_nrmse < 0.015,
        "{name}: too noisy to judge: {report}"
    );
    (values, straddling, solution.radiosity)
}

/// Interreflection: the reference and the path tracer (its own next-event
/// estimation to the light, no code shared) agree on a Cornell box lit by
/// a point light within 1% plus the path tracer's noise, over the
/// non-emitting elements (all of them here).
#[test]
fn reference_and_path_tracer_agree_in_a_cornell_box_lit_by_a_point_light() {
    let (scene, atlas) = common::load("cornell-point.json", 0.5);
    let poses = scene.initial_poses();
    let (values, straddling, reference) =
        reference_within_one_percent_of_the_path_tracer("cornell-point", &scene, &atlas, 4096);
    assert!(straddling >= 20, "{straddling} straddling texels");
    // The ray solver's kept rays (256 per texel) against the reference:
    // 0.96% when written, 1.44% since each texel shifts its rays.
    let mut rays = RaySolver::new(
        &scene,
        &atlas,
        &poses,
        (rays::SIDE, lightwire_solve::direct::GRID),
        &|_, _| {},
    );
    rays.solve(&atlas, 1e-5, None, &|_, _| {});
    let by_rays = accuracy::accuracy(&atlas, rays.radiosity(), &reference).expect("lit");
    eprintln!("cornell-point: ray solver vs reference: {by_rays}");
    assert!(by_rays.nrmse <= 0.015, "ray solver vs reference: {by_rays}");
    // The box casts a hard shadow on the floor: the comparison includes
    // texels the light does not reach directly.
    let floor: Vec<f32> = atlas.elements_of(0).map(|i| values[i].x).collect();
    let (lo, hi) = floor.iter().fold((f32::INFINITY, 0.0f32), |(lo, hi), v| {
        (lo.min(*v), hi.max(*v))
    });
    assert!(lo < 0.2 * hi, "floor from {lo} to {hi}: no shadow");
}

/// A plate of `RHO` (4 x 4 m from the origin, facing `+y` before it is
/// tilted by `tilt_deg` about `z`), beside `extra` surfaces (JSON items
/// with a leading comma) of a black material `black`, under `lights` and
/// `sky` (JSON members with a leading comma).
fn open_plate(tilt_deg: f64, extra: &str, lit: &str) -> (Scene, Atlas) {
    let a = tilt_deg.to_radians();
    common::parse(&format!(
        r#"{{ "name": "open", "lightmap": {{ "texel_density": 4 }},
            "materials": [{{ "name": "m", "albedo": [{RHO}, {RHO}, {RHO}] }},
                          {{ "name": "black", "albedo": [0, 0, 0] }}],
            "surfaces": [{{ "name": "floor", "material": "m",
                "quad": {{ "origin": [0, 0, 0], "u": [0, 0, 4], "v": [{}, {}, 0] }} }}{extra}]{lit} }}"#,
        4.0 * a.cos(),
        4.0 * a.sin()
    ))
}

/// The sun (1,000 W/m², 0.53° across) straight down on a plate tilted by
/// 30°: `ρ E cos 30°` everywhere (nothing shadows it).
#[test]
fn the_sun_gives_a_tilted_plate_e_cos_theta() {
    let (scene, atlas) = open_plate(
        30.0,
        "",
        r#", "lights": [{ "name": "sun", "type": "directional", "direction": [0, -1, 0],
                           "intensity": 1000, "angular_diameter_deg": 0.53 }]"#,
    );
    let want = RHO * 1000.0 * 30f64.to_radians().cos();
    assert_plate(&scene, &atlas, |_| want, |_| false);
}

/// An open uniform sky of radiance `L`: `ρ π L` on a plate that sees
/// nothing else.
#[test]
fn an_open_uniform_sky_gives_a_plate_pi_l() {
    let (scene, atlas) = open_plate(0.0, "", r#", "sky": { "zenith": [2, 2, 2] }"#);
    assert_plate(
        &scene,
        &atlas,
        |_| RHO * std::f64::consts::PI * 2.0,
        |_| false,
    );
}

/// A plate facing down, 1 m over nothing, under a gradient sky (zenith 3,
/// horizon 1) and a sun of 800 W/m² at 53° elevation, over a ground of
/// albedo 0.25: it sees only the ground, whose radiance is `0.25 (π (1/3 +
/// 2) + 800 × 0.8) / π`, and reads `ρ π` that.
#[test]
fn a_ground_below_the_horizon_lights_what_faces_down() {
    let (scene, atlas) = open_plate(
        180.0,
        "",
        r#", "lights": [{ "name": "sun", "type": "directional", "direction": [0.6, -0.8, 0],
                           "intensity": 800 }],
             "sky": { "zenith": [3, 3, 3], "horizon": [1, 1, 1], "ground_albedo": [0.25, 0.25, 0.25] }"#,
    );
    let pi = std::f64::consts::PI;
    let ground = 0.25 * (pi * (1.0 / 3.0 + 2.0) + 800.0 * 0.8) / pi;
    assert_plate(&scene, &atlas, |_| RHO * pi * ground, |_| false);
}

/// A black wall 2 m high along `z` at `x = 4.5`, facing the plate (a
/// texel that sees the backs of surfaces counts as inside geometry), 400 m
/// long (infinite from
/// the plate's middle), hides from a floor point at distance `d` the view
/// factor `½ (1 − d / √(d² + h²))` of its sky (an infinitely long strip
/// perpendicular to the point's plane; Howell's catalogue): the plate reads
/// `ρ π L (1 − F)`. Over the plate (NRMSE): the reference (1,024
/// stratified rays per element) within 1% of it (0.20% when written), the
/// ray solver (256, each element its own shift of the grid) within 1.5%
/// (1.08%), the path tracer at 4,096 paths within 2% (0.59%; each path
/// sees the sky or not).
#[test]
fn a_long_wall_hides_the_share_of_the_sky_its_view_factor_says() {
    let (scene, atlas) = open_plate(
        0.0,
        r#", { "name": "wall", "material": "black",
               "quad": { "origin": [4.5, 0, -200], "u": [0, 0, 400], "v": [0, 2, 0] } }"#,
        r#", "sky": { "zenith": [1, 1, 1] }"#,
    );
    let want = |p: DVec3| {
        let (d, h) = (4.5 - p.x, 2.0);
        RHO * std::f64::consts::PI * (1.0 - 0.5 * (1.0 - d / (d * d + h * h).sqrt()))
    };
    let floor: Vec<usize> = atlas.elements_of(0).collect();
    let expected: Vec<f64> = floor
        .iter()
        .map(|&i| want(atlas.elements[i].position.as_dvec3()))
        .collect();
    for (name, b) in solve_all_at(&scene, &atlas, 4096) {
        let (mut err, mut norm) = (0.0, 0.0);
        for (&i, &w) in floor.iter().zip(&expected) {
            err += (f64::from(b[i].x) - w).powi(2);
            norm += w * w;
        }
        let nrmse = (err / norm).sqrt();
        eprintln!(
            "wall: {name} NRMSE {:.3}% against the view factor",
            nrmse * 100.0
        );
        let bound = match name {
            "reference" => 0.01,
            "rays" => 0.015,
            _ => 0.02,
        };
        assert!(
            nrmse <= bound,
            "{name}: NRMSE {nrmse} against the closed form"
        );
    }
}

/// The GPU solvers take the lights' and the sky's direct light as
/// reflected light the elements start with (issue 59): the progressive
/// solver as `lightwire bake` runs it (refinement, then its gathered
/// corrections) and the gather solver within 1% NRMSE of the reference
/// (area-weighted over the visible non-emitting elements) on a scene of
/// each new kind of light: cornell-point (a point light, hard shadows),
/// window-sun (a sun through a window and a dim sky) and courtyard (a sun
/// and a sky over open walls).
#[test]
fn the_gpu_solvers_agree_with_the_reference_under_points_sun_and_sky() {
    for (name, density) in [
        ("cornell-point.json", 0.5),
        ("window-sun.json", 0.7),
        ("courtyard.json", 0.7),
    ] {
        let (scene, atlas) = common::load(name, density);
        let poses = scene.initial_poses();
        let expected = ReferenceSolver::new(&scene, &atlas, &poses, &reference::Silent)
            .expect("small scene")
            .solve(SolveOptions::default(), &reference::Silent)
            .radiosity;
        for kind in [SolverKind::Progressive, SolverKind::Gather] {
            let solver = solved(
                name,
                kind,
                (&scene, &atlas, &poses),
                &SolverSettings::default(),
            );
            let values = solver
                .radiosity()
                .unwrap_or_else(|e| panic!("{name}, {}: {e}", kind.name()));
            let error = common::visible_accuracy(&scene, &atlas, &poses, &values, &expected);
            eprintln!(
                "{name}: {} elements, {} vs reference: {error} ({})",
                atlas.elements.len(),
                kind.name(),
                solver.summary()
            );
            assert!(error.nrmse <= 0.01, "{name}, {}: {error}", kind.name());
        }
    }
}

/// `scene` solved by a solver of `kind` (built as `bake` builds it, with
/// `settings`) to 1e-4.
fn solved<'a>(
    name: &str,
    kind: SolverKind,
    (scene, atlas, poses): (&'a Scene, &'a Atlas, &'a [lightwire_scene::Pose]),
    settings: &SolverSettings,
) -> Box<dyn solver::BatchSolver + 'a> {
    let mut solver = solver::build(kind, scene, atlas, poses, settings, &solver::Silent)
        .unwrap_or_else(|e| panic!("{name}, {}: {e}", kind.name()));
    solver
        .solve(1e-4)
        .unwrap_or_else(|e| panic!("{name}, {}: {e}", kind.name()));
    solver
}

/// A converged progressive solve from scratch of `scene` at `poses`.
fn from_scratch(scene: &Scene, atlas: &Atlas, poses: &[lightwire_scene::Pose]) -> Vec<Vec3> {
    let mut s = lightwire_solve::gpu::ProgressiveSolver::new(
        common::gpu(),
        scene,
        atlas,
        poses,
        lightwire_solve::gpu::ProgressiveOptions::default(),
    )
    .unwrap_or_else(|e| panic!("{e}"));
    s.solve(1e-4).unwrap_or_else(|e| panic!("{e}"));
    s.radiosity().unwrap_or_else(|e| panic!("{e}"))
}

/// Steps a live session until nothing is running or waiting.
fn settle(d: &mut lightwire_solve::gpu::DynamicSolver<[u64; 1]>) {
    for _ in 0..100_000 {
        if d.is_idle() {
            return;
        }
        d.step(std::time::Duration::from_millis(20))
            .unwrap_or_else(|e| panic!("{e}"));
    }
    panic!("the session never became idle");
}

/// A live session under a point light (issue 59): the box of cornell-point
/// moved (turned 30° and shifted 1 m) casts its shadow at its new place
/// and no longer at its old one. The lights' direct light a move changes
/// is no patch's shot light, so neither redistribution method moves it by
/// itself (`gpu/progressive/redistribute/lights.rs`). After one move, the
/// floor (where the shadow is) and the whole room within 2% NRMSE of a
/// from-scratch solve at the new pose, for cross and incremental; moved
/// back, the floor within 1% of a fresh session's first state.
#[test]
fn a_box_moved_under_a_point_light_takes_its_shadow_along() {
    use lightwire_solve::accuracy::accuracy_where;
    use lightwire_solve::gpu::{DynamicOptions, DynamicSolver, Redistribution};

    // The bulb low beside the left wall: the box's shadow falls across
    // the floor and up the right wall, beyond the texels next to the box
    // that gather again after a move (`progressive/regather.rs`).
    let text = std::fs::read_to_string(common::scene_path("cornell-point.json"))
        .expect("cornell-point.json");
    let text = text.replace("[2.78, 4.488, 2.796]", "[0.8, 2.6, 2.796]");
    assert!(text.contains("[0.8, 2.6, 2.796]"), "the bulb moved");
    let (scene, atlas) = common::parse_scaled(&text, 0.35);
    let start = scene.initial_poses();
    let o = scene.object_by_name("box").expect("a box") as usize;
    let mut target = start.clone();
    target[o].rotation = glam::Quat::from_rotation_y(30f32.to_radians());
    target[o].translation += Vec3::new(0.3, 0.0, 1.4);
    let fresh = |poses: &[lightwire_scene::Pose]| from_scratch(&scene, &atlas, poses);
    let expected = fresh(&target);
    let validity = lightwire_solve::validity::Validity::compute(&scene, &atlas, &target);
    let floor = |i: usize| atlas.elements[i].patch == 0;
    // The test means something: the shadow moved, so the floor at the two
    // poses differs by far more than the bound.
    let before = fresh(&start);
    let at_start = lightwire_solve::validity::Validity::compute(&scene, &atlas, &start);
    let moved = accuracy_where(&atlas, &before, &expected, floor).expect("lit");
    assert!(moved.nrmse > 0.1, "the shadow barely moved: {moved}");

    for method in [Redistribution::Cross, Redistribution::Incremental] {
        let options = DynamicOptions {
            method,
            corrections: 0,
            ..DynamicOptions::default()
        };
        let mut d = DynamicSolver::new(common::gpu(), &scene, &atlas, &start, [0u64], options)
            .unwrap_or_else(|e| panic!("{e}"));
        settle(&mut d);
        let first = d.radiosity().unwrap_or_else(|e| panic!("{e}"));
        d.set_poses(&target, [1]);
        settle(&mut d);
        let published = d.radiosity().unwrap_or_else(|e| panic!("{e}"));
        let room = common::visible_accuracy(&scene, &atlas, &target, &published, &expected);
        // Over the texels a client sees (those under the box are filled
        // from their neighbours when published).
        let keep = validity.keep();
        let on_floor =
            accuracy_where(&atlas, &published, &expected, |i| floor(i) && keep(i)).expect("lit");
        eprintln!("{method}: after the move, room {room}; floor {on_floor}");
        assert!(room.nrmse <= 0.02, "{method}: room {room}");
        assert!(on_floor.nrmse <= 0.02, "{method}: floor {on_floor}");

        d.set_poses(&start, [2]);
        settle(&mut d);
        let back = d.radiosity().unwrap_or_else(|e| panic!("{e}"));
        let keep = at_start.keep();
        let again = accuracy_where(&atlas, &back, &first, |i| floor(i) && keep(i)).expect("lit");
        eprintln!("{method}: moved back, floor against the first state {again}");
        assert!(again.nrmse <= 0.02, "{method}: floor moved back {again}");
    }
}

/// Issue 59, item 3: a texel a hard shadow edge crosses holds the area
/// average of its light, not the value at its sample. The shadow of
/// [`a_point_light_casts_a_hard_shadow`]'s blocker has its edges (x and
/// z = 1 and 3) through the middles of the texels whose samples lie on
/// them (texels stand for ±0.125 m about samples 0.25 m apart): such a
/// texel is half lit, a corner one a quarter or three quarters. Each of
/// those against its closed-form average (a 64 x 64 grid of the point
/// light's `ρ I cos θ / r²` outside the shadow) within 2% of the largest
/// value, every other texel against the closed form at its sample within
/// 1e-4 of it, for the reference, the ray solver and the GPU progressive
/// solver. With the value at the sample alone a straddling texel is 0 or
/// fully lit, about half its light off.
#[test]
fn a_texel_a_hard_shadow_edge_crosses_holds_its_area_average() {
    let (scene, atlas) = common::parse(&format!(
        r#"{{ "name": "edge", "lightmap": {{ "texel_density": 4 }},
            "materials": [{{ "name": "m", "albedo": [{RHO}, {RHO}, {RHO}] }}],
            "surfaces": [{{ "name": "floor", "material": "m",
                "quad": {{ "origin": [0, 0, 0], "u": [0, 0, 4], "v": [4, 0, 0] }} }},
              {{ "name": "blocker", "material": "m",
                "quad": {{ "origin": [1.5, 0.5, 1.5], "u": [0, 0, 1], "v": [1, 0, 0] }} }}],
            "lights": [{{ "name": "l", "type": "point", "position": [{}, {}, {}], "intensity": {INTENSITY} }}] }}"#,
        LIGHT.x, LIGHT.y, LIGHT.z
    ));
    let in_shadow = |x: f64, z: f64| (1.0..=3.0).contains(&x) && (1.0..=3.0).contains(&z);
    // The texel's mean light and lit share.
    let average = |i: usize| {
        let [s0, t0, s1, t1] = atlas.elements[i].region.map(f64::from);
        // The floor's s runs along z (its u), t along x (its v).
        let n = 64;
        let (mut sum, mut lit_cells) = (0.0, 0);
        for a in 0..n {
            for b in 0..n {
                let z = 4.0 * (s0 + (s1 - s0) * (a as f64 + 0.5) / n as f64);
                let x = 4.0 * (t0 + (t1 - t0) * (b as f64 + 0.5) / n as f64);
                if !in_shadow(x, z) {
                    sum += lit(DVec3::new(x, 0.0, z), |_| 1.0);
                    lit_cells += 1;
                }
            }
        }
        (sum / (n * n) as f64, lit_cells as f64 / (n * n) as f64)
    };
    let floor: Vec<usize> = atlas.elements_of(0).collect();
    // (straddling, expected) per floor texel.
    let expected: Vec<(bool, f64)> = floor
        .iter()
        .map(|&i| {
            let (mean, share) = average(i);
            let p = atlas.elements[i].position.as_dvec3();
            if share > 0.05 && share < 0.95 {
                (true, mean)
            } else {
                (
                    false,
                    if in_shadow(p.x, p.z) {
                        0.0
                    } else {
                        lit(p, |_| 1.0)
                    },
                )
            }
        })
        .collect();
    let max = expected.iter().map(|e| e.1).fold(0.0, f64::max);
    let straddling = expected.iter().filter(|e| e.0).count();
    assert!(straddling >= 24, "{straddling} texels straddle the edge");
    let poses = scene.initial_poses();
    let reference = ReferenceSolver::new(&scene, &atlas, &poses, &reference::Silent)
        .expect("small scene")
        .solve(SolveOptions::default(), &reference::Silent)
        .radiosity;
    let mut rays = RaySolver::new(
        &scene,
        &atlas,
        &poses,
        (rays::SIDE, lightwire_solve::direct::GRID),
        &|_, _| {},
    );
    rays.solve(&atlas, 1e-6, None, &|_, _| {});
    let mut progressive = solver::build(
        SolverKind::Progressive,
        &scene,
        &atlas,
        &poses,
        &SolverSettings::default(),
        &solver::Silent,
    )
    .unwrap_or_else(|e| panic!("{e}"));
    progressive.solve(1e-6).unwrap_or_else(|e| panic!("{e}"));
    let gpu = progressive.radiosity().unwrap_or_else(|e| panic!("{e}"));
    for (name, b) in [
        ("reference", reference),
        ("rays", rays.radiosity().to_vec()),
        ("progressive", gpu),
    ] {
        let (mut worst, mut worst_plain) = (0.0f64, 0.0f64);
        for (&i, &(straddles, want)) in floor.iter().zip(&expected) {
            let off = (f64::from(b[i].x) - want).abs() / max;
            if straddles {
                worst = worst.max(off);
            } else {
                worst_plain = worst_plain.max(off);
            }
        }
        eprintln!(
            "edge: {name}: {straddling} straddling texels at most {:.2}% of the largest value off their average, the rest {:.4}% off the closed form",
            worst * 100.0,
            worst_plain * 100.0
        );
        assert!(
            worst <= 0.02,
            "{name}: a straddling texel {:.2}% off",
            worst * 100.0
        );
        assert!(
            worst_plain <= 1e-4,
            "{name}: a texel {:.4}% off",
            worst_plain * 100.0
        );
    }
}

/// A box carried into the sun patch of `window-sun` (a dynamic box added
/// to the room) casts the sun's shadow there: after the move, cross and
/// incremental sessions within 2% NRMSE of a from-scratch solve on the
/// floor, where the shadow falls beyond the texels next to the box.
#[test]
fn a_box_carried_into_the_sun_casts_its_shadow() {
    use lightwire_solve::accuracy::accuracy_where;
    use lightwire_solve::gpu::{DynamicOptions, DynamicSolver, Redistribution};

    let text =
        std::fs::read_to_string(common::scene_path("window-sun.json")).expect("window-sun.json");
    let text = text
        .replacen(
            r#""surfaces": ["#,
            r#""objects": [{ "name": "box", "pose": { "translation": [1, 0.4, 1] } }],
  "surfaces": [
    { "name": "box", "material": "wall", "object": "box", "box": { "center": [0, 0, 0], "size": [0.5, 0.8, 0.5] } },"#,
            1,
        );
    let (scene, atlas) = common::parse_scaled(&text, 0.7);
    let start = scene.initial_poses();
    let o = scene.object_by_name("box").expect("a box") as usize;
    let mut target = start.clone();
    target[o].translation = Vec3::new(3.4, 0.4, 3.0);
    let fresh = |poses: &[lightwire_scene::Pose]| from_scratch(&scene, &atlas, poses);
    let expected = fresh(&target);
    let validity = lightwire_solve::validity::Validity::compute(&scene, &atlas, &target);
    let keep = validity.keep();
    let floor = |i: usize| {
        let e = &atlas.elements[i];
        e.object == 0 && e.position.y.abs() < 1e-4 && e.normal.y > 0.9 && keep(i)
    };
    let before = fresh(&start);
    let moved = accuracy_where(&atlas, &before, &expected, floor).expect("lit");
    assert!(
        moved.nrmse > 0.1,
        "the box casts no shadow worth the name: {moved}"
    );
    for method in [Redistribution::Cross, Redistribution::Incremental] {
        let options = DynamicOptions {
            method,
            corrections: 0,
            ..DynamicOptions::default()
        };
        let mut d = DynamicSolver::new(common::gpu(), &scene, &atlas, &start, [0u64], options)
            .unwrap_or_else(|e| panic!("{e}"));
        settle(&mut d);
        d.set_poses(&target, [1]);
        settle(&mut d);
        let published = d.radiosity().unwrap_or_else(|e| panic!("{e}"));
        let on_floor = accuracy_where(&atlas, &published, &expected, floor).expect("lit");
        eprintln!("{method}: the box in the sun, floor {on_floor} (the shadow moved {moved})");
        assert!(on_floor.nrmse <= 0.02, "{method}: floor {on_floor}");
    }
}

/// A floor of 1 m cells (a mesh: its lightmap UVs generated) at one texel
/// per metre, a point light `LOW` m over it, with `lightmap.light_detail`
/// `detail`.
fn floor_under_a_low_light(detail: f64) -> (Scene, Atlas) {
    const N: usize = 8;
    let mut positions = Vec::new();
    for i in 0..=N {
        for j in 0..=N {
            positions.push(format!("[{i}, 0, {j}]"));
        }
    }
    let at = |i: usize, j: usize| i * (N + 1) + j;
    let mut indices = Vec::new();
    for i in 0..N {
        for j in 0..N {
            let (a, b, c, d) = (at(i, j), at(i, j + 1), at(i + 1, j + 1), at(i + 1, j));
            indices.extend([a, b, c, a, c, d].map(|k| k.to_string()));
        }
    }
    common::parse(&format!(
        r#"{{ "name": "low", "lightmap": {{ "texel_density": 1, "light_detail": {detail} }},
            "materials": [{{ "name": "m", "albedo": [{RHO}, {RHO}, {RHO}] }}],
            "surfaces": [{{ "name": "floor", "material": "m",
                "mesh": {{ "positions": [{}], "indices": [{}] }} }}],
            "lights": [{{ "name": "l", "type": "point", "position": [{}, {LOW}, {}], "intensity": {INTENSITY} }}] }}"#,
        positions.join(", "),
        indices.join(", "),
        LOW_AT.0,
        LOW_AT.1,
    ))
}

/// How high the light of [`floor_under_a_low_light`] hangs, and over which
/// point `(x, z)`.
const LOW: f64 = 0.6;
const LOW_AT: (f64, f64) = (2.3, 2.7);

/// The floor's lightmap as a client reads it (the reference solution,
/// invalid texels filled, scattered into the atlas image and read
/// bilinearly at the point's patch parameters) against the closed form
/// `ρ I h / r³` at 400 points drawn within 3 m of the light's foot: the
/// NRMSE over them and the worst relative error.
fn read_under_a_low_light(scene: &Scene, atlas: &Atlas) -> (f64, f64) {
    let poses = scene.initial_poses();
    let mut values = ReferenceSolver::new(scene, atlas, &poses, &reference::Silent)
        .expect("small scene")
        .solve(SolveOptions::default(), &reference::Silent)
        .radiosity;
    lightwire_solve::validity::Validity::compute(scene, atlas, &poses).dilate(atlas, &mut values);
    let image = atlas.to_image(&values);
    // The patch that holds a floor point and its parameters there.
    let locate = |p: DVec3| -> (u32, [f64; 2]) {
        for (k, patch) in scene.patches.iter().enumerate() {
            let (o, u, v) = patch.shape.frame();
            let (o, u, v) = (o.as_dvec3(), u.as_dvec3(), v.as_dvec3());
            let d = p - o;
            let (uu, uv, vv) = (u.dot(u), u.dot(v), v.dot(v));
            let det = uu * vv - uv * uv;
            let s = (d.dot(u) * vv - d.dot(v) * uv) / det;
            let t = (d.dot(v) * uu - d.dot(u) * uv) / det;
            if patch.shape.contains(s as f32, t as f32) {
                return (k as u32, [s, t]);
            }
        }
        panic!("{p} is on no patch");
    };
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let (mut num, mut den, mut worst) = (0.0, 0.0, 0.0f64);
    let mut n = 0;
    while n < 400 {
        let (x, z) = (LOW_AT.0 + 6.0 * next() - 3.0, LOW_AT.1 + 6.0 * next() - 3.0);
        if !(0.01..7.99).contains(&x) || !(0.01..7.99).contains(&z) {
            continue;
        }
        let p = DVec3::new(x, 0.0, z);
        let r = p.distance(DVec3::new(LOW_AT.0, LOW, LOW_AT.1));
        if r > 3.0 {
            continue;
        }
        n += 1;
        let truth = RHO * INTENSITY * LOW / (r * r * r);
        let (patch, st) = locate(p);
        let read = f64::from(lightwire_solve::eye::lightmap_at(atlas, &image, patch, st).x);
        num += (read - truth).powi(2);
        den += truth * truth;
        worst = worst.max((read - truth).abs() / truth);
    }
    ((num / den).sqrt(), worst)
}

/// Texels where a point light is near (issue 58, item 4; `near_lights.rs`):
/// a floor at one texel per metre under a light 0.6 m up holds the
/// light's `1 / r³` falloff in a couple of texels and, read as a client
/// reads it, is far off the closed form near the light's foot; with the
/// default `light_detail` its generated charts there are refined (up to
/// 8 texels per metre) and the read is within issue 59's 5% at the eye.
/// The far floor keeps one texel per metre.
#[test]
fn a_generated_lightmap_near_a_point_light_gets_the_texels_its_falloff_needs() {
    let (coarse_scene, coarse) = floor_under_a_low_light(0.0);
    let (fine_scene, fine) = floor_under_a_low_light(4.0);
    let (coarse_nrmse, coarse_worst) = read_under_a_low_light(&coarse_scene, &coarse);
    let (fine_nrmse, fine_worst) = read_under_a_low_light(&fine_scene, &fine);
    let elements = |a: &Atlas| a.elements.iter().filter(|e| e.covers_surface()).count();
    eprintln!(
        "floor under a low light: light_detail 0: {} elements, NRMSE {:.2}%, worst {:.1}%; default: {} elements, NRMSE {:.2}%, worst {:.1}%",
        elements(&coarse),
        coarse_nrmse * 100.0,
        coarse_worst * 100.0,
        elements(&fine),
        fine_nrmse * 100.0,
        fine_worst * 100.0
    );
    assert!(fine_nrmse <= 0.05, "refined: NRMSE {fine_nrmse}");
    assert!(
        coarse_nrmse > 3.0 * fine_nrmse,
        "one texel per metre should be far off: {coarse_nrmse} vs {fine_nrmse}"
    );
    // The refinement is local: the triangles over 4 m from the light keep
    // the mesh's density, so the element count grows far less than the
    // 64 times a floor refined all over would.
    assert!(
        elements(&fine) < 16 * elements(&coarse),
        "{} vs {} elements",
        elements(&fine),
        elements(&coarse)
    );
}

/// Issue 59: `stats.json` accounts for the lights' power. With no emitting
/// surface, the emitted power is what the lights and the sky deliver onto
/// the surfaces (`Σ A D` of their direct light), and every solver reports
/// the same: within 1% of the reference's (3% for the path tracer, whose
/// bake reads each element at its sample point where the others average
/// a shadow edge over the texel, and which is noisy), all of it the
/// lights' part, and absorbed plus escaped within 2% of it. Before, the
/// ray solver and the path tracer said 0 W emitted, and the reference and
/// the GPU solvers counted only the reflected part of the direct light.
#[test]
fn every_solver_counts_the_power_the_lights_deliver() {
    for (name, density) in [("cornell-point.json", 0.5), ("courtyard.json", 0.7)] {
        let (scene, atlas) = common::load(name, density);
        let poses = scene.initial_poses();
        let mut reference = None;
        for kind in [
            SolverKind::Reference,
            SolverKind::Rays,
            SolverKind::Pathtrace,
            SolverKind::Progressive,
            SolverKind::Gather,
        ] {
            let settings = SolverSettings {
                spp: Some(64),
                ..SolverSettings::default()
            };
            let solver = solved(name, kind, (&scene, &atlas, &poses), &settings);
            let p = solver
                .energy_balance()
                .unwrap_or_else(|e| panic!("{name}, {}: {e}", kind.name()));
            eprintln!(
                "{name}, {}: emitted {:.2} W (lights {:.2}), absorbed {:.2}, escaped {:.2}",
                kind.name(),
                p.emitted,
                p.lights,
                p.absorbed,
                p.escaped
            );
            assert!(p.emitted > 0.0, "{name}, {}: {p:?}", kind.name());
            assert!(
                (p.lights / p.emitted - 1.0).abs() < 1e-6,
                "{name}, {}: all of it the lights': {p:?}",
                kind.name()
            );
            assert!(
                ((p.absorbed + p.escaped) / p.emitted - 1.0).abs() <= 0.02,
                "{name}, {}: balanced: {p:?}",
                kind.name()
            );
            let expected: f64 = *reference.get_or_insert(p.emitted);
            let bound = if kind == SolverKind::Pathtrace {
                0.03
            } else {
                0.01
            };
            assert!(
                (p.emitted / expected - 1.0).abs() <= bound,
                "{name}, {}: {} W emitted, the reference {expected} W",
                kind.name(),
                p.emitted
            );
        }
    }
}

/// cornell-point with a second light: the bulb as `bulb` gives it and a
/// spot as `spot` places and sets it.
fn two_lights_text(bulb: &str, spot: &str) -> String {
    let text = std::fs::read_to_string(common::scene_path("cornell-point.json"))
        .expect("cornell-point.json")
        .replace(
            r#"{ "name": "bulb", "type": "point", "position": [2.78, 4.488, 2.796], "intensity": 8 }"#,
            &format!(
                r#"{{ "name": "bulb", "type": "point", "position": [2.78, 4.488, 2.796], {bulb} }},
                   {{ "name": "spot", "type": "spot", "inner_cone_deg": 20, "outer_cone_deg": 35, {spot} }}"#
            ),
        );
    assert!(text.contains("\"spot\""), "the second light is in");
    text
}

/// Issue 60, item 2 at the solver: a light that changes is followed by
/// shooting the signed change of its direct light (`set_light`), and the
/// solution it converges to is the one of the new light. cornell-point
/// with a bulb and a spot in its left half, solved by the GPU progressive
/// solver; then the bulb dimmed to a quarter and made warm, the spot
/// switched off, the spot on again moved and turned, and the first lights
/// again. After each change, refined to 1e-4 of the emitted power: within
/// 8% NRMSE of the reference solver from scratch at the new lights
/// (measured 1.8-5.5%: the change travels by the progressive solver's
/// transport, 1-5% short here; a solver that only took the new light keeps
/// the old solution, 268% off); then corrected by two gathered rounds (as `bake` and the service do),
/// within 1% of the reference solver from scratch at the lights as they
/// are then; back at the first lights, within 0.5% of where it started.
#[test]
fn a_light_that_changes_is_followed_to_the_solution_of_the_new_light() {
    use lightwire_solve::gpu::{Correction, GatherOptions, ProgressiveOptions, ProgressiveSolver};
    let spot_at = r#""position": [1.2, 4.0, 2.0], "direction": [0.2, -1, 0.1]"#;
    let first = (
        r#""intensity": 8"#.to_string(),
        format!(r#"{spot_at}, "intensity": 10"#),
    );
    let warm = r#""intensity": 2, "color": [1, 0.8, 0.6]"#.to_string();
    let changes = [
        ("the bulb dimmed and warm", warm.clone(), first.1.clone()),
        (
            "the spot off",
            warm.clone(),
            format!(r#"{spot_at}, "intensity": 0"#),
        ),
        (
            "the spot on, moved and turned",
            warm.clone(),
            r#""position": [4.2, 3.5, 3.0], "direction": [-0.4, -1, -0.2], "intensity": 10"#
                .to_string(),
        ),
        ("the first lights again", first.0.clone(), first.1.clone()),
    ];
    let scene_of = |bulb: &str, spot: &str| common::parse_scaled(&two_lights_text(bulb, spot), 0.5);
    let (scene, atlas) = scene_of(&first.0, &first.1);
    let poses = scene.initial_poses();
    // Refinement (what it gives), then two gathered corrections with
    // `scene`'s lights.
    let settle = |solver: &mut ProgressiveSolver, scene: &Scene| {
        solver.solve(1e-4).unwrap_or_else(|e| panic!("{e}"));
        let refined = solver.radiosity().unwrap_or_else(|e| panic!("{e}"));
        let mut correction = Correction::new(
            common::gpu(),
            scene,
            &atlas,
            &poses,
            GatherOptions::default(),
        )
        .unwrap_or_else(|e| panic!("{e}"));
        for _ in 0..2 {
            correction
                .round(solver, 1e-4)
                .unwrap_or_else(|e| panic!("{e}"));
        }
        (
            refined,
            solver.radiosity().unwrap_or_else(|e| panic!("{e}")),
        )
    };
    let mut solver = ProgressiveSolver::new(
        common::gpu(),
        &scene,
        &atlas,
        &poses,
        ProgressiveOptions::default(),
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let (_, start) = settle(&mut solver, &scene);
    for (what, bulb, spot) in changes {
        let (target, _) = scene_of(&bulb, &spot);
        for (k, light) in target.lights.iter().enumerate() {
            solver
                .set_light(k, light.clone())
                .unwrap_or_else(|e| panic!("{what}: {e}"));
        }
        let (refined, followed) = settle(&mut solver, &target);
        let expected = ReferenceSolver::new(&target, &atlas, &poses, &reference::Silent)
            .expect("small scene")
            .solve(SolveOptions::default(), &reference::Silent)
            .radiosity;
        // Refinement alone already carries the change.
        let shot = common::visible_accuracy(&target, &atlas, &poses, &refined, &expected);
        eprintln!("{what}: refined, against the reference from scratch {shot}");
        assert!(shot.nrmse <= 0.08, "{what}: {shot}");
        let error = common::visible_accuracy(&target, &atlas, &poses, &followed, &expected);
        eprintln!("{what}: against the reference from scratch {error}");
        assert!(error.nrmse <= 0.01, "{what}: {error}");
    }
    let back = solver.radiosity().unwrap_or_else(|e| panic!("{e}"));
    let drift = common::visible_accuracy(&scene, &atlas, &poses, &back, &start);
    eprintln!("back at the first lights: {drift}");
    assert!(drift.nrmse <= 0.005, "{drift}");
}
