//! The reference solver is the oracle every other solver is compared with,
//! so these tests hold it to physics with known answers.

mod common;

use glam::Vec3;
use lightwire_solve::reference::{ReferenceSolver, Silent, SolveOptions};

fn solve(
    scene: &lightwire_scene::Scene,
    atlas: &lightwire_scene::atlas::Atlas,
) -> (ReferenceSolver, lightwire_solve::reference::Solution) {
    let solver = ReferenceSolver::new(scene, atlas, &scene.initial_poses(), &Silent)
        .expect("scene is small enough");
    let solution = solver.solve(SolveOptions::default(), &Silent);
    assert!(
        solution.residual_fraction < 1e-4,
        "did not converge: {}",
        solution.residual_fraction
    );
    (solver, solution)
}

/// Furnace: a closed box of uniform albedo ρ and self-emission E has
/// radiosity E/(1-ρ) everywhere (each bounce returns ρ of the light, so
/// B = E (1 + ρ + ρ² + …)).
#[test]
fn furnace_every_texel_within_half_a_percent_of_e_over_one_minus_rho() {
    let (scene, atlas) = common::load("furnace.json", 1.0);
    let material = &scene.materials[0];
    let expected = material.emission / (Vec3::ONE - material.albedo);
    let (_, solution) = solve(&scene, &atlas);
    common::assert_uniform(&atlas, &solution.radiosity, expected, 0.005);
}

/// Two directly opposed, parallel unit squares one unit apart exchange a
/// form factor of 0.19982 (DESIGN.md; Howell's catalogue C-11).
#[test]
fn plates_form_factor_within_one_percent_of_0_19982() {
    let (scene, atlas) = common::load("plates.json", 1.0);
    let solver =
        ReferenceSolver::new(&scene, &atlas, &scene.initial_poses(), &Silent).expect("small");
    assert_eq!(
        solver.patch_count(),
        2,
        "plates.json has exactly two patches"
    );
    let (a, b) = (solver.patch_elements(0), solver.patch_elements(1));
    // F_AB = (1/A_A) Σ_{i∈A} A_i Σ_{j∈B} F_ij: the area-weighted mean of
    // what each receiving sample on A sees of B.
    let area_a: f64 = a.clone().map(|i| solver.area(i)).sum();
    let f: f64 = a
        .clone()
        .map(|i| solver.area(i) * b.clone().map(|j| solver.form_factor(i, j)).sum::<f64>())
        .sum::<f64>()
        / area_a;
    assert!(
        (area_a - 1.0).abs() < 1e-6,
        "plate A has unit area, got {area_a}"
    );
    assert!((f - 0.19982).abs() / 0.19982 < 0.01, "F_AB = {f}");
}

/// Reciprocity, A_i F_ij = A_j F_ji, holds for exact form factors. The
/// solver integrates the exact point-to-region form factor over the
/// receiving region with a 1, 2×2 or 4×4 midpoint rule, whose relative
/// error for one unoccluded pair shrinks like (size/distance)²: at three
/// element sizes apart and more a pair must agree within 3%. The room is
/// convex (nothing occludes) and its walls have different texel densities,
/// so the pairs have unequal areas.
#[test]
fn reciprocity_on_random_element_pairs() {
    let (scene, atlas) = common::parse(
        r#"{
        "name": "room",
        "lightmap": { "texel_density": 5 },
        "materials": [ { "name": "grey", "albedo": [0.5, 0.5, 0.5], "emission": [1, 1, 1] } ],
        "surfaces": [
            { "name": "floor", "material": "grey", "texel_density": 7, "quad": { "origin": [0, 0, 0], "u": [3, 0, 0], "v": [0, 0, -4] } },
            { "name": "ceiling", "material": "grey", "quad": { "origin": [0, 2, 0], "u": [0, 0, -4], "v": [3, 0, 0] } },
            { "name": "left", "material": "grey", "texel_density": 3, "quad": { "origin": [0, 0, 0], "u": [0, 0, -4], "v": [0, 2, 0] } },
            { "name": "right", "material": "grey", "quad": { "origin": [3, 0, 0], "u": [0, 2, 0], "v": [0, 0, -4] } },
            { "name": "back", "material": "grey", "texel_density": 9, "quad": { "origin": [0, 0, -4], "u": [3, 0, 0], "v": [0, 2, 0] } }
        ]
    }"#,
    );
    let solver =
        ReferenceSolver::new(&scene, &atlas, &scene.initial_poses(), &Silent).expect("small");
    let n = solver.len();
    // A small deterministic LCG: reproducible "random" pairs.
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut next = || {
        state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (state >> 33) as usize
    };
    let mut checked = 0;
    let mut worst = 0.0f64;
    while checked < 3000 {
        let (i, j) = (next() % n, next() % n);
        let size = solver.area(i).max(solver.area(j)).sqrt();
        let distance = (atlas.elements[i].position - atlas.elements[j].position).length() as f64;
        if atlas.elements[i].patch == atlas.elements[j].patch || distance < 3.0 * size {
            continue;
        }
        let (gij, gji) = (
            solver.area(i) * solver.form_factor(i, j),
            solver.area(j) * solver.form_factor(j, i),
        );
        assert!(
            gij > 0.0 && gji > 0.0,
            "in a convex room, elements on different walls see each other"
        );
        let error = (gij - gji).abs() / gij.max(gji);
        worst = worst.max(error);
        assert!(
            error < 0.03,
            "pair ({i}, {j}) on patches {} and {}, {:.1} sizes apart: A_i F_ij = {gij}, A_j F_ji = {gji}",
            atlas.elements[i].patch,
            atlas.elements[j].patch,
            distance / size
        );
        checked += 1;
    }
    eprintln!("worst element-pair reciprocity error: {worst:.4}");
}

/// Summed over whole patches, reciprocity must hold even with occluders
/// and penumbrae (the Cornell box with its box and light): within 5%. The
/// largest errors are where the box stands on the floor: that contact edge
/// does not follow the floor's element grid, so floor elements straddle it
/// and the midpoint rule integrates a step.
#[test]
fn reciprocity_between_patches_with_occlusion() {
    let (scene, atlas) = common::load("cornell-low.json", 0.5);
    let solver =
        ReferenceSolver::new(&scene, &atlas, &scene.initial_poses(), &Silent).expect("small");
    // A_P F_PQ = Σ_{i∈P} Σ_{j∈Q} A_i F_ij.
    let g = |a: usize, b: usize| -> f64 {
        solver
            .patch_elements(a)
            .map(|i| {
                solver.area(i)
                    * solver
                        .patch_elements(b)
                        .map(|j| solver.form_factor(i, j))
                        .sum::<f64>()
            })
            .sum()
    };
    let mut compared = 0;
    for p in 0..solver.patch_count() {
        for q in 0..p {
            let (gpq, gqp) = (g(p, q), g(q, p));
            // Skip the box's bottom and the floor it rests on: two
            // coincident, facing planes at distance zero, which exchange
            // light only with each other, in the dark.
            let (ep, eq) = (
                &atlas.elements[solver.patch_elements(p).start],
                &atlas.elements[solver.patch_elements(q).start],
            );
            let (np, nq) = (
                scene.patches[p].shape.normal(),
                scene.patches[q].shape.normal(),
            );
            let poses = scene.initial_poses();
            let wp = poses[ep.object as usize].transform_normal(np);
            let wq = poses[eq.object as usize].transform_normal(nq);
            let gap = wp.dot(
                poses[eq.object as usize].transform_point(eq.position)
                    - poses[ep.object as usize].transform_point(ep.position),
            );
            if wp.dot(wq) < -0.999 && gap.abs() < 1e-3 {
                continue;
            }
            // Only pairs that exchange at least 1% of what leaves the
            // smaller patch: grazing slivers are all quadrature noise.
            let area = |p: usize| {
                solver
                    .patch_elements(p)
                    .map(|i| solver.area(i))
                    .sum::<f64>()
            };
            if gpq.max(gqp) < 0.01 * area(p).min(area(q)) {
                continue;
            }
            let error = (gpq - gqp).abs() / gpq.max(gqp);
            assert!(error < 0.05, "patches {p} and {q}: {gpq} vs {gqp}");
            compared += 1;
        }
    }
    assert!(compared >= 15, "only {compared} patch pairs exchange light");
}

/// In an open scene every emitted watt is either absorbed by a surface or
/// escapes through the opening: emitted + donated = absorbed + escaped
/// (`EnergyBalance::donated`: the light of the texels under the box that
/// the solver takes from their neighbours).
#[test]
fn energy_balance_in_an_open_scene_within_half_a_percent() {
    let (scene, atlas) = common::load("cornell-low.json", 0.5);
    let (solver, solution) = solve(&scene, &atlas);
    let balance = solver.energy_balance(&solution);
    eprintln!(
        "emitted {:.3} W, donated {:.3} W, absorbed {:.3} W, escaped {:.3} W",
        balance.emitted.element_sum(),
        balance.donated.element_sum(),
        balance.absorbed.element_sum(),
        balance.escaped.element_sum()
    );
    let emitted = balance.emitted.element_sum() + balance.donated.element_sum();
    let accounted = balance.absorbed.element_sum() + balance.escaped.element_sum();
    assert!(
        balance.escaped.element_sum() > 0.01 * emitted,
        "the Cornell box is open: some light escapes"
    );
    let error = (accounted - emitted).abs() / emitted;
    assert!(
        error < 0.005,
        "emitted {emitted}, absorbed + escaped {accounted} ({:.3}%)",
        error * 100.0
    );
}

/// Cross-texture interpolation (thesis §4.1): two adjacent coplanar quads
/// put their boundary samples at the same world positions, so they compute
/// the same radiosity there and light interpolates across the seam.
#[test]
fn adjacent_coplanar_quads_share_boundary_samples_and_radiosity() {
    let (scene, atlas) = common::parse(
        r#"{
        "name": "seam",
        "lightmap": { "texel_density": 6 },
        "materials": [
            { "name": "white", "albedo": [0.7, 0.7, 0.7] },
            { "name": "lamp", "albedo": [0, 0, 0], "emission": [5, 5, 5] }
        ],
        "surfaces": [
            { "name": "left", "material": "white", "quad": { "origin": [0, 0, 0], "u": [1, 0, 0], "v": [0, 0, -2] } },
            { "name": "right", "material": "white", "quad": { "origin": [1, 0, 0], "u": [1.5, 0, 0], "v": [0, 0, -2] } },
            { "name": "lamp", "material": "lamp", "quad": { "origin": [0.3, 1.5, -0.2], "u": [0, 0, -0.7], "v": [0.9, 0, 0] } }
        ]
    }"#,
    );
    let (_, solution) = solve(&scene, &atlas);
    let left = atlas.charts[0];
    let right = atlas.charts[1];
    assert_eq!(
        left.h, right.h,
        "same edge length and density give the same sample count"
    );
    // Skip the corner samples: they are moved inward on purpose.
    for b in 1..left.h - 1 {
        let l = atlas
            .element_at(left.x + left.w - 1, left.y + b)
            .expect("covered") as usize;
        let r = atlas.element_at(right.x, right.y + b).expect("covered") as usize;
        let (pl, pr) = (atlas.elements[l].position, atlas.elements[r].position);
        assert!((pl - pr).length() < 1e-6, "row {b}: {pl} vs {pr}");
        let (bl, br) = (solution.radiosity[l], solution.radiosity[r]);
        let error = ((bl - br).abs() / bl.max(br)).max_element();
        assert!(
            bl.x > 0.0 && error < 1e-4,
            "row {b}: radiosity {bl} vs {br}"
        );
    }
}
