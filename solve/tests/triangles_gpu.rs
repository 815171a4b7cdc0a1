//! The GPU solvers on triangle patches (issue 18, item 4): a scene whose
//! quads are cut into triangles (`Scene::triangulated`) must light like the
//! quads, and a closed triangle mesh must pass the furnace test. These run
//! on whatever adapter exists (lavapipe in CI) and never skip.
//!
//! The triangulated scene has its own atlas (square charts per triangle,
//! texels above each diagonal standing for no surface), so it is compared
//! with the quad scene as a client would see it: its lightmap, dilated,
//! sampled bilinearly at every quad element's sample point
//! (`common::resample_triangulated`), against the quad scene's solution
//! with the project's metric (`accuracy::accuracy`, over the non-emitting
//! elements valid in the quad scene).

mod common;

use glam::Vec3;
use lightwire_scene::atlas::Atlas;
use lightwire_scene::{Charts, LoadOptions, Patch, PatchLightmap, PatchShape, Scene};
use lightwire_solve::accuracy::{self, Accuracy};
use lightwire_solve::gpu::{Correction, GatherOptions, GatherSolver, ProgressiveOptions};
use lightwire_solve::gpu::{ProgressiveSolver, StepReport};
use lightwire_solve::solver::{self, SolverKind, SolverSettings};
use lightwire_solve::validity::Validity;

/// The device every GPU test of this binary shares.
use common::gpu;

/// `kind` as `lightwire bake` runs it (the progressive solver with its
/// gathered corrections), solved to 1e-4; the radiosity with the invalid
/// texels filled as a publication fills them.
fn solve(kind: SolverKind, scene: &Scene, atlas: &Atlas) -> Vec<Vec3> {
    let poses = scene.initial_poses();
    let settings = SolverSettings::default();
    let mut solver = solver::build(kind, scene, atlas, &poses, &settings, &solver::Silent)
        .unwrap_or_else(|e| panic!("{}: {e}", kind.name()));
    solver
        .solve(1e-4)
        .unwrap_or_else(|e| panic!("{}: {e}", kind.name()));
    let mut values = solver
        .radiosity()
        .unwrap_or_else(|e| panic!("{}: {e}", kind.name()));
    Validity::compute(scene, atlas, &poses).fill(atlas, &mut values);
    values
}

/// The triangulated scene's solution by `kind` against the quad scene's,
/// at the quad scene's samples.
fn triangulated_against_quads(name: &str, density_scale: f32, kind: SolverKind) -> Accuracy {
    let (scene, atlas) = common::load(name, density_scale);
    let tri = scene.triangulated();
    let tri_atlas = Atlas::build(&tri).unwrap_or_else(|e| panic!("{name} triangulated: {e}"));
    let quads = solve(kind, &scene, &atlas);
    let triangles = solve(kind, &tri, &tri_atlas);
    let resampled = common::resample_triangulated(&scene, &atlas, &tri_atlas, &triangles);
    let validity = Validity::compute(&scene, &atlas, &scene.initial_poses());
    let error = accuracy::accuracy_where(&atlas, &resampled, &quads, validity.keep())
        .unwrap_or_else(|| panic!("lengths must match and the quad scene must be lit"));
    eprintln!(
        "{name} x{density_scale}, {}: {} quad elements, {} triangle elements: {error}",
        kind.name(),
        atlas.elements.len(),
        tri_atlas.elements.len()
    );
    error
}

/// The density at which the triangulated Cornell box is compared with the
/// quads. A triangle's chart is square (its triangle the half `t <= s`,
/// `atlas.rs`), so a triangle of a quad whose chart is not square gets the
/// larger of its two texel counts along both edges: at x0.35 the floor's
/// quads hold 17 x 16 texels and its triangles 17 x 17, whose rows lie up
/// to 12 cm apart from the quad's. Both are right discretizations, but
/// beside the box, where the light changes by half within a texel, reading
/// one grid's texels between the other's samples differs by 5-20%: 1.19%
/// (progressive), 1.21% (gather) and 1.22% (the reference solver, which
/// reads the same), 85% of it on the floor rows beside the box. At x0.5
/// every quad's chart is square and each triangle carries its quad's grid
/// ([`same_grids`] checks it), so the comparison is of light at the same
/// samples: measured (lavapipe) 0.09% (progressive), 0.07% (gather), 0.11%
/// (reference). Before the solvers knew triangles (each drawn, looked up
/// and shot as its whole parallelogram) it read 16.98% and 14.17%.
const CORNELL_SCALE: f32 = 0.5;

/// Issue 18: "the triangulated Cornell box equals the quad version within
/// 1%"; half of that, as the measured values are a tenth of it.
const CORNELL_BOUND: f64 = 0.005;

/// Every triangle pair of the triangulated scene holds its quad's texel
/// grid: the charts of triangles `2p` and `2p + 1` are as wide and as tall
/// as quad `p`'s.
fn same_grids(name: &str, density_scale: f32) -> bool {
    let (scene, atlas) = common::load(name, density_scale);
    let tri_atlas = Atlas::build(&scene.triangulated()).unwrap_or_else(|e| panic!("{name}: {e}"));
    (0..scene.patches.len()).all(|p| {
        let quad = atlas.charts[p];
        [2 * p, 2 * p + 1].iter().all(|&t| {
            let tri = tri_atlas.charts[t];
            (tri.w, tri.h) == (quad.w, quad.h)
        })
    })
}

/// The triangulated Cornell box lights like the quad one under the
/// progressive solver with its corrections (issue 18; see
/// [`CORNELL_SCALE`] and [`CORNELL_BOUND`]).
#[test]
fn triangulated_cornell_large_progressive_matches_the_quads() {
    assert!(same_grids("cornell-large.json", CORNELL_SCALE));
    let error =
        triangulated_against_quads("cornell-large.json", CORNELL_SCALE, SolverKind::Progressive);
    assert!(error.nrmse <= CORNELL_BOUND, "{error}");
}

/// The same for the gather solver.
#[test]
fn triangulated_cornell_large_gather_matches_the_quads() {
    assert!(same_grids("cornell-large.json", CORNELL_SCALE));
    let error = triangulated_against_quads("cornell-large.json", CORNELL_SCALE, SolverKind::Gather);
    assert!(error.nrmse <= CORNELL_BOUND, "{error}");
}

/// The grids differ at x0.35 (the floor's quad 17 x 16, its triangles 17 x
/// 17), which is why the comparison above is made at [`CORNELL_SCALE`]:
/// [`same_grids`] can tell.
#[test]
fn a_triangle_of_a_quad_that_is_not_square_has_a_finer_grid() {
    assert!(!same_grids("cornell-large.json", 0.35));
}

/// A furnace (one material) solved by the progressive solver to `stop`
/// unshot: every surface element within 1% of E/(1-ρ)
/// ([`assert_uniform_on_surface`]); the largest error and the report.
fn progressive_furnace(scene: &Scene, atlas: &Atlas, stop: f64) -> (f32, StepReport) {
    let material = &scene.materials[0];
    let expected = material.emission / (Vec3::ONE - material.albedo);
    let poses = scene.initial_poses();
    let mut solver =
        ProgressiveSolver::new(gpu(), scene, atlas, &poses, ProgressiveOptions::default())
            .unwrap_or_else(|e| panic!("{e}"));
    let report = solver.solve(stop).unwrap_or_else(|e| panic!("{e}"));
    assert!(report.unshot_fraction <= stop, "{report:?}");
    let b = solver.radiosity().unwrap_or_else(|e| panic!("{e}"));
    (assert_uniform_on_surface(atlas, &b, expected, 0.01), report)
}

/// Every element of `b` that stands for surface within `tolerance`
/// (relative, per channel) of `expected`; returns the largest relative
/// error. (The texels above a triangle's diagonal hold whatever they
/// hold; a publication fills them.)
fn assert_uniform_on_surface(atlas: &Atlas, b: &[Vec3], expected: Vec3, tolerance: f32) -> f32 {
    let mut worst = 0.0f32;
    let mut checked = 0;
    for (i, v) in b.iter().enumerate() {
        let e = &atlas.elements[i];
        if !e.covers_surface() {
            continue;
        }
        checked += 1;
        let error = ((*v - expected) / expected).abs().max_element();
        worst = worst.max(error);
        assert!(
            error < tolerance,
            "element {i} of patch {} at texel {:?} (st {:?}): {v} vs {expected}",
            e.patch,
            e.texel,
            e.st
        );
    }
    assert!(checked > 0, "no element stands for surface");
    worst
}

/// Furnace on triangles: the closed box of `furnace.json` cut into twelve
/// triangles has radiosity E/(1-ρ) everywhere. Every element on the
/// triangles within 1%, those on the diagonal edges included: the cut
/// shooters' form factors must still sum to one (shot as parallelograms,
/// the box received 1.149 times what it shot), and samples on a diagonal
/// must see their own triangle in the item buffers. Measured on
/// 2026-12-02: largest error 0.96%, on texels along a box edge that is
/// the neighbouring triangle's diagonal (1.75% before the tiles along the
/// diagonal were split into its edge strip, `split_diagonal`).
#[test]
fn triangulated_furnace_progressive_every_texel_within_one_percent() {
    let (scene, _) = common::load("furnace.json", 1.0);
    let tri = scene.triangulated();
    assert!(tri.patches.iter().all(|p| p.shape.is_triangle()));
    let atlas = Atlas::build(&tri).unwrap_or_else(|e| panic!("furnace triangulated: {e}"));
    let (worst, report) = progressive_furnace(&tri, &atlas, 1e-4);
    eprintln!(
        "triangulated furnace, progressive: max relative error {worst:.5} after {} shots",
        report.shots
    );
}

/// The same furnace under the gather solver.
#[test]
fn triangulated_furnace_gather_every_texel_within_one_percent() {
    let (scene, _) = common::load("furnace.json", 1.0);
    let tri = scene.triangulated();
    let atlas = Atlas::build(&tri).unwrap_or_else(|e| panic!("furnace triangulated: {e}"));
    let material = &tri.materials[0];
    let expected = material.emission / (Vec3::ONE - material.albedo);
    let mut solver = GatherSolver::new(
        gpu(),
        &tri,
        &atlas,
        &tri.initial_poses(),
        GatherOptions::default(),
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let report = solver.solve(1e-4).unwrap_or_else(|e| panic!("{e}"));
    assert!(report.change_fraction <= 1e-4, "{report:?}");
    let b = solver.radiosity().unwrap_or_else(|e| panic!("{e}"));
    let worst = assert_uniform_on_surface(&atlas, &b, expected, 0.01);
    eprintln!(
        "triangulated furnace, gather: max relative error {worst:.5} after {} bounces",
        report.bounces
    );
}

/// Issue 18's UV-sphere furnace: `meshes/furnace-sphere.glb`, 960
/// triangles facing the centre, vertices shared along the seam and at the
/// poles, albedo 0.5, emission 1 W/m², so E/(1-ρ) = 2 W/m² on every texel,
/// those along the seam and around the poles' fans included. The sphere's
/// triangles are curved surface cut flat: every hemicube of every texel
/// must see the rest of the sphere without a crack between triangles.
///
/// It brings no `TEXCOORD_1`, so by default its charts are generated
/// (`scene/unwrap.rs`: a few dozen near-planar charts, texels shared by the
/// triangles they straddle, most elements a sliver of a texel); with
/// `--charts parallelograms` every triangle has its own chart (2 x 2
/// texels at this density, every texel on a triangle's edge or corner).
/// Both must hold. Measured on 2026-12-05 (lavapipe), largest errors: own
/// charts 0.57% (5,374 shots); generated 0.96% (5,069 shots), and 5-17%
/// before the form factor to a near tile of a lightmap patch was clipped
/// to the patch (a small triangle's tile is crossed by several of its
/// edges).
#[test]
fn uv_sphere_furnace_every_texel_within_one_percent() {
    for charts in [Charts::LightmapUvs, Charts::Parallelograms] {
        let options = LoadOptions {
            charts,
            ..LoadOptions::scaled(SPHERE_DENSITY_SCALE)
        };
        let path = common::scene_path("meshes/furnace-sphere.glb");
        let scene = Scene::load_with(&path, options).unwrap_or_else(|e| panic!("{e}"));
        let atlas = Atlas::build(&scene).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(scene.patches.len(), 960);
        let generated = scene
            .patches
            .iter()
            .filter(|p| p.lightmap.is_some())
            .count();
        assert_eq!(
            generated,
            if charts == Charts::LightmapUvs {
                960
            } else {
                0
            }
        );
        let (worst, report) = progressive_furnace(&scene, &atlas, 1e-3);
        eprintln!(
            "UV-sphere furnace, {charts:?}, progressive: {} elements, max relative error {worst:.5} after {} shots",
            atlas.elements.len(),
            report.shots
        );
    }
}

/// Issue 18: texels on either side of every chart seam of the atrium agree
/// within 2%. Every edge where two charts meet is a seam (a whole edge two
/// patches share, or part of one where a large merged chart meets smaller
/// ones): the lightmap is read there from both sides as a client reads it
/// (published: seams stitched and invalid texels filled, `Validity::fill`;
/// each chart sampled bilinearly at the point's own parameters), at the
/// quarter points of every patch edge that lie on another patch's edge.
/// Without the stitching (every triangle its own chart), 2,981 of 8,902
/// points differed by more than 2% (up to 58% on the floor, whose checker texture makes each side's edge texel
/// average its own side's squares; 3-7% on plain floor in the light's
/// gradient; seams along a triangle's diagonal read the texels above it).
/// One case is left, and counted apart (at most 0.1% of the points): along
/// a diagonal where the texel beside it is brighter than the two on it
/// together (the foot of an arch's soffit, lit three times more strongly
/// one texel up), a straight line along the diagonal needs negative light
/// in the texel above it, which no publication holds
/// (`negative_light_is_small_and_never_published`). Only seams between triangles that face the same way (within 1°)
/// are compared: where flat triangles meet at a crease (a column's twelve
/// facets, a box's edges), the light differs across the edge for real, as
/// the cosine to each light does. Points inside geometry (an edge under a
/// column's base, whose texels are invalid and filled from elsewhere) are
/// left out, as no client sees them. The difference is relative to the
/// brighter side, or to 2% of the 95th percentile of the scene's radiosity
/// where both are darker than that. The state compared is the progressive
/// solver's at 20% unshot (the panel and the brightest surfaces shot): a
/// seam must agree at every stage, and the direct light's penumbrae of the
/// columns and arches are on the floor by then.
///
/// Run with the default charts (a grid of cells one parallelogram: few
/// seams, the floor one chart) and with pairs only (a chart per cell: every
/// cell edge a seam, the floor's checker across them).
#[test]
fn atrium_chart_seams_agree_within_two_percent() {
    // Not a vacuous pass: the atrium has 468 seams between patches that
    // face the same way with the default charts, 1,984 with pairs alone.
    atrium_seams(Charts::Parallelograms, 400);
    atrium_seams(Charts::Pairs, 1500);
}

/// The atrium at [`ATRIUM_DENSITY_SCALE`] on `charts`, solved by the
/// progressive solver to 20% unshot, its radiosity filled as a publication
/// fills it (seams stitched, invalid texels filled), with the validity
/// that filled it and the solve's report.
fn atrium_published(charts: Charts) -> (Scene, Atlas, Validity, Vec<Vec3>, StepReport) {
    let options = LoadOptions {
        density_scale: ATRIUM_DENSITY_SCALE,
        charts,
    };
    let scene = Scene::load_with(&common::scene_path("meshes/atrium.glb"), options)
        .unwrap_or_else(|e| panic!("atrium must load: {e}"));
    let atlas = Atlas::build(&scene).unwrap_or_else(|e| panic!("atrium must fit: {e}"));
    let poses = scene.initial_poses();
    let mut solver =
        ProgressiveSolver::new(gpu(), &scene, &atlas, &poses, ProgressiveOptions::default())
            .unwrap_or_else(|e| panic!("{e}"));
    let report = solver.solve(0.2).unwrap_or_else(|e| panic!("{e}"));
    let mut b = solver.radiosity().unwrap_or_else(|e| panic!("{e}"));
    let validity = Validity::compute(&scene, &atlas, &poses);
    validity.fill(&atlas, &mut b);
    (scene, atlas, validity, b, report)
}

fn atrium_seams(charts: Charts, min_seams: usize) {
    let (scene, atlas, validity, b, report) = atrium_published(charts);

    let mut lum: Vec<f32> = b.iter().map(|v| v.max_element()).collect();
    lum.sort_by(f32::total_cmp);
    let floor = 0.02 * lum[lum.len() * 95 / 100];

    // Points on patch edges: the quarter points of every edge, and which
    // other patches of the object have the point on one of their edges
    // (the whole edge shared, or part of it where a large chart meets
    // smaller ones).
    let on_segment = |x: Vec3, a: Vec3, e: Vec3| {
        let d = e - a;
        let t = ((x - a).dot(d) / d.length_squared()).clamp(0.0, 1.0);
        (a + d * t - x).length() < 1e-4
    };
    let on_boundary = |q: usize, x: Vec3| {
        let c = scene.patches[q].shape.corners();
        (0..c.len()).any(|i| on_segment(x, c[i], c[(i + 1) % c.len()]))
    };
    // The element whose region holds (s, t), and the lightmap there.
    let element = |patch: u32, [s, t]: [f32; 2]| {
        let chart = atlas.charts[patch as usize];
        let a = (s * (chart.w - 1) as f32).round() as u32;
        let b = (t * (chart.h - 1) as f32).round() as u32;
        atlas.patch_elements[patch as usize] as usize
            + (b.min(chart.h - 1) * chart.w + a.min(chart.w - 1)) as usize
    };
    let params = |patch: u32, x: Vec3| {
        let (o, u, v) = scene.patches[patch as usize].shape.frame();
        let d = x - o;
        let (uu, uv, vv) = (u.dot(u), u.dot(v), v.dot(v));
        let det = uu * vv - uv * uv;
        let (du, dv) = (d.dot(u), d.dot(v));
        [
            ((vv * du - uv * dv) / det).clamp(0.0, 1.0),
            ((uu * dv - uv * du) / det).clamp(0.0, 1.0),
        ]
    };
    // Whether `(s, t)` lies on a triangle's diagonal between two texels
    // whose straight line needed negative light above the diagonal
    // (`Validity::dilate`), which a publication never holds: the texel
    // beside the diagonal is brighter than the two on it together.
    let clamped = |patch: u32, [s, t]: [f32; 2]| {
        let chart = atlas.charts[patch as usize];
        if !scene.patches[patch as usize].shape.is_triangle() || (s - t).abs() > 1e-4 {
            return false;
        }
        let first = atlas.patch_elements[patch as usize] as usize;
        let at = |a: u32, b: u32| first + (b * chart.w + a) as usize;
        let a = ((s * (chart.w - 1) as f32).floor() as u32).min(chart.w - 2);
        let line = b[at(a, a)] + b[at(a + 1, a + 1)] - b[at(a + 1, a)];
        line.min_element() < 0.0 && b[at(a, a + 1)].min_element() == 0.0
    };
    let mut unrepresentable = Vec::new();
    let (mut seams, mut points, mut creases) = (0, 0, 0);
    let mut worst = (0.0f32, String::new());
    let mut failures = Vec::new();
    let mut pairs = std::collections::HashSet::new();
    let mut seen = std::collections::HashSet::new();
    for (p, pa) in scene.patches.iter().enumerate() {
        let c = pa.shape.corners();
        for i in 0..c.len() {
            let (a, e) = (c[i], c[(i + 1) % c.len()]);
            for k in 1..=3 {
                let x = a + (e - a) * (k as f32 / 4.0);
                for (q, pb) in scene.patches.iter().enumerate() {
                    if q == p || pb.object != pa.object || !on_boundary(q, x) {
                        continue;
                    }
                    // Each point of a pair once (a whole shared edge has it
                    // on both sides' edges).
                    let at = (x * 1e4).round().as_ivec3().to_array();
                    if !seen.insert((p.min(q), p.max(q), at)) {
                        continue;
                    }
                    if pa.shape.normal().dot(pb.shape.normal()) < 1f32.to_radians().cos() {
                        creases += usize::from(pairs.insert((p.min(q), p.max(q), false)));
                        continue;
                    }
                    seams += usize::from(pairs.insert((p.min(q), p.max(q), true)));
                    let (p, q) = (p as u32, q as u32);
                    let (sp, sq) = (params(p, x), params(q, x));
                    let (ip, iq) = (element(p, sp), element(q, sq));
                    if validity.is_invalid(ip) || validity.is_invalid(iq) {
                        continue;
                    }
                    points += 1;
                    let (vp, vq) = (atlas.sample(&b, p, sp), atlas.sample(&b, q, sq));
                    let scale = vp.max_element().max(vq.max_element()).max(floor);
                    let diff = (vp - vq).abs().max_element() / scale;
                    let (cp, cq) = (atlas.charts[p as usize], atlas.charts[q as usize]);
                    let what = format!(
                        "{} ({}x{} st {sp:?}) | {} ({}x{} st {sq:?}) at {x}: {vp} vs {vq}",
                        pa.name, cp.w, cp.h, pb.name, cq.w, cq.h
                    );
                    let negative = clamped(p, sp) || clamped(q, sq);
                    if diff > worst.0 && !negative {
                        worst = (diff, what.clone());
                    }
                    if diff > 0.02 && negative {
                        unrepresentable.push(format!("{:.1}%: {what}", diff * 100.0));
                    } else if diff > 0.02 {
                        failures.push(format!("{:.1}%: {what}", diff * 100.0));
                    }
                }
            }
        }
    }
    eprintln!(
        "atrium: {} points where a straight diagonal would need negative light: {unrepresentable:#?}",
        unrepresentable.len()
    );
    assert!(
        unrepresentable.len() * 1000 <= points,
        "{} of {points} seam points need negative light",
        unrepresentable.len()
    );
    eprintln!(
        "atrium ({charts:?}): {} elements, {} shots; {seams} seams ({creases} creases left out), {points} points; worst {:.2}% ({})",
        atlas.elements.len(),
        report.shots,
        worst.0 * 100.0,
        worst.1
    );
    assert!(
        seams > min_seams && points > 2 * min_seams,
        "{charts:?}: {seams} seams, {points} points"
    );
    assert!(
        failures.is_empty(),
        "{charts:?}: {} of {points} seam points differ by more than 2%, e.g.\n{}",
        failures.len(),
        failures[..failures.len().min(12)].join("\n")
    );
}

/// The atrium's texel density against its default.
const ATRIUM_DENSITY_SCALE: f32 = 0.5;

/// The sphere's texel density against its default (about 72 texels/m).
const SPHERE_DENSITY_SCALE: f32 = 0.1;

/// A mesh has a patch per triangle, and the per-patch power reduction
/// once dispatched one workgroup per patch: past the adapter's 65,535
/// workgroups per dimension a 101,400-triangle mesh failed validation
/// (`lightwire bench meshes`). Workgroups now take patches in turns; with
/// five workgroups for the triangulated furnace's 12 patches the solver
/// must shoot exactly what one workgroup per patch shoots.
#[test]
fn more_patches_than_power_workgroups_select_the_same_shooters() {
    let (scene, _) = common::load("furnace.json", 0.5);
    let tri = scene.triangulated();
    let atlas = Atlas::build(&tri).unwrap_or_else(|e| panic!("furnace triangulated: {e}"));
    let run = |max_power_workgroups: u32| {
        let options = ProgressiveOptions {
            max_power_workgroups,
            ..ProgressiveOptions::default()
        };
        let mut solver = ProgressiveSolver::new(gpu(), &tri, &atlas, &tri.initial_poses(), options)
            .unwrap_or_else(|e| panic!("{e}"));
        let report = solver.solve(1e-3).unwrap_or_else(|e| panic!("{e}"));
        (
            report.shots,
            solver.radiosity().unwrap_or_else(|e| panic!("{e}")),
        )
    };
    assert!(tri.patches.len() > 5);
    let (shots, b) = run(u32::MAX);
    let (shots_in_turns, b_in_turns) = run(5);
    assert_eq!(shots, shots_in_turns);
    assert_eq!(b, b_in_turns, "the same shots give the same light");
}

/// A batch shares its free shooter slots with the next patches by power
/// (`ProgressiveOptions::shared_batch_ratio`): on a tessellated Cornell
/// box (every quad a 3 x 3 grid of cells, 216 triangles) the solve takes
/// half the batches or fewer and lights the scene as one patch per batch
/// does, within 1% (the accuracy metric, non-emitting elements). Measured
/// on lavapipe: 747 batches alone, 245 shared (3,920 and 3,973 shots), the
/// two lightmaps 0.05% apart.
#[test]
fn shared_batches_light_a_mesh_as_one_patch_per_batch_does() {
    let (scene, atlas) = tessellated(3, 1.0);
    assert_eq!(scene.patches.len(), 216);
    let run = |shared_batch_ratio: f32| {
        let options = ProgressiveOptions {
            shared_batch_ratio,
            cluster_triangles: false,
            ..ProgressiveOptions::default()
        };
        solve_to_a_thousandth(&scene, &atlas, options, 0)
    };
    let (alone, b_alone) = run(0.0);
    let (shared, b_shared) = run(0.5);
    let error = accuracy::accuracy(&atlas, &b_shared, &b_alone).expect("a lit scene");
    eprintln!(
        "tessellated Cornell box, {} elements: one patch per batch {} shots in {} batches, \
         shared {} shots in {} batches; shared vs one patch {error}",
        atlas.elements.len(),
        alone.shots,
        alone.batches,
        shared.shots,
        shared.batches
    );
    assert!(
        2 * shared.batches <= alone.batches,
        "{} batches shared, {} one patch per batch",
        shared.batches,
        alone.batches
    );
    assert!(error.nrmse <= 0.01, "{error}");
}

/// The progressive solver with `options` solved to 0.1% unshot, then
/// `corrections` gathered rounds as a bake runs them: what the solve did
/// (corrections not counted) and the radiosity, filled as published.
fn solve_to_a_thousandth(
    scene: &Scene,
    atlas: &Atlas,
    options: ProgressiveOptions,
    corrections: u32,
) -> (StepReport, Vec<Vec3>) {
    let poses = scene.initial_poses();
    let mut solver = ProgressiveSolver::new(gpu(), scene, atlas, &poses, options)
        .unwrap_or_else(|e| panic!("{e}"));
    let report = solver.solve(1e-3).unwrap_or_else(|e| panic!("{e}"));
    if corrections > 0 {
        let mut correction = Correction::new(gpu(), scene, atlas, &poses, GatherOptions::default())
            .unwrap_or_else(|e| panic!("{e}"));
        for _ in 0..corrections {
            correction
                .round(&mut solver, 1e-3)
                .unwrap_or_else(|e| panic!("{e}"));
        }
    }
    let mut b = solver.radiosity().unwrap_or_else(|e| panic!("{e}"));
    Validity::compute(scene, atlas, &poses).fill(atlas, &mut b);
    (report, b)
}

/// The tessellated Cornell box of `k x k` cells per quad, written as a
/// `.glb` and opened as a scene at `density_scale` of a `.glb`'s default.
fn tessellated(k: usize, density_scale: f32) -> (Scene, Atlas) {
    let glb = lightwire_scene::gltf::content::cornell_tessellated(k)
        .to_glb()
        .unwrap_or_else(|e| panic!("{e}"));
    let path = std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("cornell-{}.glb", 24 * k * k));
    std::fs::write(&path, glb).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let scene = Scene::load_with(
        &path,
        // Every triangle its own patch: these tests are about triangles.
        lightwire_scene::LoadOptions::unpaired(density_scale),
    )
    .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let atlas = Atlas::build(&scene).unwrap_or_else(|e| panic!("{e}"));
    (scene, atlas)
}

/// Shooting clusters (`ProgressiveOptions::cluster_triangles`): the
/// triangles of a surface shoot as a quad of the same power would, so a
/// tessellated Cornell box (every quad a 4 x 4 grid of cells, 384
/// triangles) takes half the shots and a quarter of the batches or fewer
/// than with a shot per triangle, and its light, solved to 0.1% unshot
/// and corrected as a bake corrects it (two gathered rounds), agrees with
/// the per-triangle solve within 1% (the accuracy metric, non-emitting
/// elements). Measured on lavapipe: 5,348 shots in 338 batches alone,
/// 1,331 in 35 clustered, 0.32% apart (docs/benchmarks-history.md, "shooting
/// clusters", has both against the CPU reference).
#[test]
fn clusters_light_a_mesh_as_triangles_shot_alone_do() {
    let (scene, atlas) = tessellated(4, 0.35);
    assert_eq!(scene.patches.len(), 384);
    let run = |cluster_triangles: bool| {
        let options = ProgressiveOptions {
            cluster_triangles,
            ..ProgressiveOptions::default()
        };
        solve_to_a_thousandth(&scene, &atlas, options, 2)
    };
    let (alone, b_alone) = run(false);
    let (clustered, b_clustered) = run(true);
    let error = accuracy::accuracy(&atlas, &b_clustered, &b_alone).expect("a lit scene");
    eprintln!(
        "tessellated Cornell box, {} elements: a shot per triangle {} shots in {} batches, \
         clusters {} shots in {} batches; clusters vs alone {error}",
        atlas.elements.len(),
        alone.shots,
        alone.batches,
        clustered.shots,
        clustered.batches
    );
    assert!(
        2 * clustered.shots <= alone.shots && 4 * clustered.batches <= alone.batches,
        "{} shots in {} batches clustered, {} in {} alone",
        clustered.shots,
        clustered.batches,
        alone.shots,
        alone.batches
    );
    assert!(error.nrmse <= 0.01, "{error}");
}

/// Loads `scenes/meshes/cornell-large.glb` (the quad Cornell box
/// triangulated, `TEXCOORD_1` per mesh: each wall's two triangles fill its
/// own [0, 1]²) lit on its own lightmap UVs (`--charts lightmap-uvs`):
/// each wall's UVs are affine over its two triangles, which are therefore
/// one parallelogram on the lightmap (`scene/pairs.rs`); with `triangles`,
/// split back into its two triangles on the same UVs, as a mesh whose UVs
/// are not affine over any two of its triangles is lit.
fn cornell_on_lightmap_uvs(density_scale: f32, triangles: bool) -> (Scene, Atlas) {
    let path = common::scene_path("meshes/cornell-large.glb");
    let options = LoadOptions {
        density_scale,
        charts: Charts::LightmapUvs,
    };
    let mut scene = Scene::load_with(&path, options).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(scene.patches.len(), 12);
    assert!(
        scene
            .patches
            .iter()
            .all(|p| p.lightmap.is_some() && !p.shape.is_triangle()),
        "every wall one parallelogram on its mesh's lightmap"
    );
    if triangles {
        scene.patches = scene.patches.iter().flat_map(split_on_lightmap).collect();
    }
    let atlas = Atlas::build(&scene).unwrap_or_else(|e| panic!("{e}"));
    (scene, atlas)
}

/// A parallelogram on its mesh's lightmap as the two triangles it was
/// merged from (corners and UVs in the order `PatchShape::triangle` keeps).
fn split_on_lightmap(p: &Patch) -> Vec<Patch> {
    let (PatchShape::Quad { origin: o, u, v }, Some(l)) = (p.shape, p.lightmap) else {
        return vec![p.clone()];
    };
    let [uv00, uv10, uv11] = l.uv;
    let uv01 = uv00 + uv11 - uv10;
    [
        ([o, o + u, o + u + v], [uv00, uv10, uv11]),
        ([o, o + u + v, o + v], [uv00, uv11, uv01]),
    ]
    .into_iter()
    .enumerate()
    .map(|(k, ([a, b, c], uvs))| {
        let order = PatchShape::triangle_order(a, b, c);
        Patch {
            name: format!("{}/{k}", p.name),
            shape: PatchShape::triangle(a, b, c),
            lightmap: Some(PatchLightmap {
                uv: order.map(|i| uvs[i]),
                ..l
            }),
            ..p.clone()
        }
    })
    .collect()
}

/// Issue 18, item 2: a mesh lit on its own lightmap UVs, its texels the
/// elements (`atlas/uv.rs`): as parallelograms where the UVs are affine
/// over a wall, and as the triangles themselves. The GPU solver as
/// `lightwire bake` runs it against the reference solver on the same
/// elements, with the project's metric (non-emitting elements, the invalid
/// ones left out). Measured (lavapipe, x0.5): parallelograms 4,752
/// elements, NRMSE 0.41%; triangles 9,504 elements, 0.39% (the progressive
/// solution before its two gathered corrections 2.24%).
#[test]
fn a_mesh_on_its_own_lightmap_uvs_lights_as_the_reference_does() {
    let (quads, quad_atlas) = common::load("cornell-large.json", 0.5);
    let quad_light = solve(SolverKind::Progressive, &quads, &quad_atlas);
    for triangles in [false, true] {
        let what = if triangles {
            "triangles"
        } else {
            "parallelograms"
        };
        let (scene, atlas) = cornell_on_lightmap_uvs(0.5, triangles);
        let gpu = solve(SolverKind::Progressive, &scene, &atlas);
        let reference = solve(SolverKind::Reference, &scene, &atlas);
        let validity = Validity::compute(&scene, &atlas, &scene.initial_poses());
        let error = accuracy::accuracy_where(&atlas, &gpu, &reference, validity.keep())
            .unwrap_or_else(|| panic!("lengths must match and the scene must be lit"));
        eprintln!(
            "cornell-large.glb on its lightmap UVs as {what} x0.5 ({} elements), progressive vs reference: {error}",
            atlas.elements.len()
        );
        assert!(error.nrmse <= 0.01, "{what}: {error}");

        // And the same light as the quad box's (`cornell-large.json`), read
        // bilinearly as a client reads its lightmap at each element's
        // sample. The two are different discretizations: the quads' edge
        // texels sit on the edges (thesis §4.1), the lightmap's texels
        // straddle them, so near the box and the room's corners each reads
        // the other between its samples. Measured: 2.14% on parallelograms,
        // 2.15% on triangles (p95 5.6%, 5.4%); the reference solver on both reads 1.64% (p95 3.2%), so
        // most of it is the discretization. Read against the wrong quad (the
        // floor for the box's bottom) it was 11.9%.
        let resampled: Vec<Vec3> = atlas
            .elements
            .iter()
            .map(|e| {
                let (q, st) = on_quad(&quads, e.position, e.normal)
                    .unwrap_or_else(|| panic!("{:?} lies on no quad", e.position));
                quad_atlas.sample(&quad_light, q, st)
            })
            .collect();
        let against_quads = accuracy::accuracy_where(&atlas, &gpu, &resampled, validity.keep())
            .unwrap_or_else(|| panic!("lengths must match"));
        eprintln!(
            "cornell-large.glb on its lightmap UVs as {what} x0.5 vs the quads: {against_quads}"
        );
        assert!(against_quads.nrmse <= 0.03, "{what}: {against_quads}");
    }
}

/// The quad of `scene` (at its initial poses) that world point `x` lies on
/// (within a millimetre of its plane), facing as `normal` does, and its
/// parameters there.
fn on_quad(scene: &Scene, x: Vec3, normal: Vec3) -> Option<(u32, [f32; 2])> {
    let poses = scene.initial_poses();
    scene.patches.iter().enumerate().find_map(|(p, patch)| {
        let (o, u, v) = patch
            .shape
            .transformed(&poses[patch.object as usize])
            .frame();
        let n = u.cross(v);
        let d = x - o;
        if d.dot(n.normalize()).abs() > 1e-3 || n.normalize().dot(normal) < 0.99 {
            return None;
        }
        let nn = n.length_squared();
        let s = d.dot(v.cross(n)) / nn;
        let t = d.dot(n.cross(u)) / nn;
        let tolerance = 1e-4;
        ((-tolerance..=1.0 + tolerance).contains(&s) && (-tolerance..=1.0 + tolerance).contains(&t))
            .then_some((p as u32, [s.clamp(0.0, 1.0), t.clamp(0.0, 1.0)]))
    })
}

/// Issue 18, item 3, on lightmap UVs: texels on either side of every seam
/// of the atrium's lightmap islands agree within 2% as a client reads them.
/// Run on the asset's own `TEXCOORD_1` (the default: each column's side
/// unrolled into one island, cut once at φ = 0) and on generated charts
/// (every column and arch soffit cut into near-planar charts). Independently
/// of `atlas/stitch.rs`'s seam search: every edge of a mesh's triangles is
/// matched with the other triangle of the mesh that has it (same end
/// points); where the two give the edge different lightmap UVs it is a seam,
/// and a smooth one where their faces are within 1° or the edge is one of
/// the mesh's smooth edges (the asset's normals agree, `UvMesh::smooth_edges`).
/// At the quarter points of each, the published lightmap
/// (`Validity::fill`, then `Atlas::to_image`) is read bilinearly at either
/// side's UVs; they differ by at most 2% of the brighter (or of 2% of the
/// 95th percentile, where both are darker). Points whose texel on either
/// side is invalid (inside or under geometry: a column's foot) are left out.
/// Unstitched (the same image without `Atlas::island_seams`), some seam
/// differs by more than 2%, so the test sees what stitching does.
#[test]
fn atrium_lightmap_island_seams_agree_within_two_percent() {
    atrium_island_seams(Charts::LightmapUvs, 8);
    atrium_island_seams(Charts::Generated, 100);
}

fn atrium_island_seams(charts: Charts, min_seams: usize) {
    use lightwire_scene::atlas::IslandSeams;
    let (scene, atlas, validity, b, _) = atrium_published(charts);
    let published = atlas.to_image(&b);
    let unstitched = {
        let mut plain = atlas.clone();
        plain.island_seams = IslandSeams::default();
        plain.to_image(&b)
    };
    let mut lum: Vec<f32> = published.iter().map(|p| p[0].max(p[1]).max(p[2])).collect();
    lum.sort_by(f32::total_cmp);
    let floor = 0.02 * lum[lum.len() * 95 / 100];
    let key = |x: Vec3| (x * 1e4).round().as_ivec3().to_array();
    let (mut seams, mut points) = (0usize, 0usize);
    let (mut worst, mut worst_unstitched) = ((0.0f32, String::new()), 0.0f32);
    let mut failures = Vec::new();
    for (k, mesh) in scene.uv_meshes.iter().enumerate() {
        let Some(block) = atlas.blocks.get(k).copied().flatten() else {
            continue;
        };
        let pixel =
            |uv: glam::Vec2| glam::Vec2::new(block.x as f32, block.y as f32) + uv * block.w as f32;
        let in_atlas =
            |uv: glam::Vec2| pixel(uv) / glam::Vec2::new(atlas.width as f32, atlas.height as f32);
        // No texel the bilinear read at `uv` weighs is invalid.
        let valid_at = |uv: glam::Vec2| {
            let p = (pixel(uv) - glam::Vec2::splat(0.5)).floor();
            (0..2).all(|dy| {
                (0..2).all(|dx| {
                    atlas
                        .element_at(
                            (p.x as i64 + dx).max(0) as u32,
                            (p.y as i64 + dy).max(0) as u32,
                        )
                        .is_none_or(|e| !validity.is_invalid(e as usize))
                })
            })
        };
        let smooth: std::collections::HashSet<_> = mesh
            .smooth_edges
            .iter()
            .flat_map(|&[a, b]| [(key(a), key(b)), (key(b), key(a))])
            .collect();
        // Each edge by its end points, with its triangle and corners.
        let mut by_edge: std::collections::HashMap<_, Vec<(usize, usize)>> =
            std::collections::HashMap::new();
        for (t, tri) in mesh.triangles.iter().enumerate() {
            for e in 0..3 {
                let (a, b) = (key(tri[e]), key(tri[(e + 1) % 3]));
                by_edge
                    .entry((a.min(b), a.max(b)))
                    .or_default()
                    .push((t, e));
            }
        }
        let normal = |t: usize| {
            let [a, b, c] = mesh.triangles[t];
            (b - a).cross(c - a).normalize()
        };
        // The UV of the point `f` of the way along edge `e` of `t`, from
        // the end point `from`.
        let uv_at = |t: usize, e: usize, from: Vec3, f: f32| {
            let (i, j) = (e, (e + 1) % 3);
            let (ua, ub) = (mesh.uvs[t][i], mesh.uvs[t][j]);
            if key(mesh.triangles[t][i]) == key(from) {
                ua.lerp(ub, f)
            } else {
                ub.lerp(ua, f)
            }
        };
        for list in by_edge.values() {
            let [(s, es), (t, et)] = list[..] else {
                continue;
            };
            let from = mesh.triangles[s][es];
            let to = mesh.triangles[s][(es + 1) % 3];
            let coplanar = normal(s).dot(normal(t)) >= 1f32.to_radians().cos();
            if !coplanar && !smooth.contains(&(key(from), key(to))) {
                continue;
            }
            let apart = (pixel(uv_at(s, es, from, 0.5)) - pixel(uv_at(t, et, from, 0.5))).length();
            if apart <= 0.01 {
                continue;
            }
            seams += 1;
            for q in 1..=3 {
                let f = q as f32 / 4.0;
                let (us, ut) = (uv_at(s, es, from, f), uv_at(t, et, from, f));
                if !valid_at(us) || !valid_at(ut) {
                    continue;
                }
                points += 1;
                let read = |image: &[[f32; 3]]| {
                    let (a, b) = (
                        common::filtered(image, &atlas, in_atlas(us)),
                        common::filtered(image, &atlas, in_atlas(ut)),
                    );
                    let scale = a.max_element().max(b.max_element()).max(floor);
                    ((a - b).abs().max_element() / scale, a, b)
                };
                worst_unstitched = worst_unstitched.max(read(&unstitched).0);
                let (diff, a, b) = read(&published);
                let what = format!(
                    "{} triangles {s}/{t} at {}: {a} vs {b}",
                    mesh.name,
                    from.lerp(to, f)
                );
                if diff > worst.0 {
                    worst = (diff, what.clone());
                }
                if diff > 0.02 {
                    let (unstitched, ..) = read(&unstitched);
                    failures.push(format!(
                        "{:.1}% (unstitched {:.1}%): {what}",
                        diff * 100.0,
                        unstitched * 100.0
                    ));
                }
            }
        }
    }
    eprintln!(
        "atrium ({charts:?}): {seams} island seams, {points} points; worst {:.2}% published ({}), {:.2}% unstitched",
        worst.0 * 100.0,
        worst.1,
        worst_unstitched * 100.0
    );
    assert!(
        seams >= min_seams && points >= 2 * min_seams,
        "{charts:?}: {seams} seams, {points} points"
    );
    assert!(
        worst_unstitched > 0.02,
        "{charts:?}: unstitched the seams already agree ({worst_unstitched})"
    );
    assert!(
        failures.is_empty(),
        "{charts:?}: {} of {points} seam points differ by more than 2%, e.g.\n{}",
        failures.len(),
        failures[..failures.len().min(12)].join("\n")
    );
}
