//! The GPU progressive solver against physics with known answers and
//! against the reference solver. These run on whatever adapter exists
//! (lavapipe in CI); with no adapter at all they fail with the message
//! that says what to install, they never skip.

mod common;

use std::time::Duration;

use glam::Vec3;
use lightwire_scene::Scene;
use lightwire_scene::atlas::Atlas;
use lightwire_solve::gpu::{Device, GpuError, ProgressiveOptions, ProgressiveSolver};
use lightwire_solve::reference::{ReferenceSolver, Silent, SolveOptions};

/// The device every GPU test of this binary shares.
use common::gpu;

fn solver(scene: &Scene, atlas: &Atlas) -> ProgressiveSolver {
    ProgressiveSolver::new(
        gpu(),
        scene,
        atlas,
        &scene.initial_poses(),
        ProgressiveOptions::default(),
    )
    .unwrap_or_else(|e| panic!("{e}"))
}

/// Furnace: a closed box of uniform albedo ρ and self-emission E has
/// radiosity E/(1-ρ) everywhere. Every element must be within 1%, corner
/// and edge samples included: this checks that the disk form factors of
/// all shooters seen from any element sum to one, and that edge samples
/// see their own patch in the item buffers.
#[test]
fn furnace_every_texel_within_one_percent_of_e_over_one_minus_rho() {
    let (scene, atlas) = common::load("furnace.json", 1.0);
    let material = &scene.materials[0];
    let expected = material.emission / (Vec3::ONE - material.albedo);
    let mut solver = solver(&scene, &atlas);
    let report = solver.solve(1e-4).unwrap_or_else(|e| panic!("{e}"));
    assert!(report.unshot_fraction <= 1e-4, "{report:?}");
    let b = solver.radiosity().unwrap_or_else(|e| panic!("{e}"));
    let worst = common::assert_uniform(&atlas, &b, expected, 0.01);
    eprintln!(
        "furnace: max relative error {worst:.5} after {} shots",
        report.shots
    );
}

/// A white furnace: the same closed box painted albedo 0.9, which takes
/// about ten bounces to converge, so that any power a shot fails to
/// deliver is amplified tenfold in the result. Power received must match
/// power shot within 0.1% and every texel must be within 1% of
/// E/(1-ρ) = 10. (With the disk approximation subdivided as the thesis's
/// default of 4 per unit `sqrt(A)/r`, the box received 0.26% less than it
/// shot and ended 2.4-2.7% dark.)
#[test]
fn white_furnace_receives_what_it_shoots_and_reaches_e_over_one_minus_rho() {
    let text = std::fs::read_to_string(common::scene_path("furnace.json"))
        .unwrap_or_else(|e| panic!("furnace.json: {e}"));
    let white = text.replace("\"albedo\": [0.5, 0.5, 0.5]", "\"albedo\": [0.9, 0.9, 0.9]");
    assert_ne!(white, text, "furnace.json's albedo was repainted");
    let (scene, atlas) = common::parse(&white);
    let mut solver = solver(&scene, &atlas);
    let report = solver.solve(1e-4).unwrap_or_else(|e| panic!("{e}"));
    assert!(report.unshot_fraction <= 1e-4, "{report:?}");
    let balance = solver.energy_balance().unwrap_or_else(|e| panic!("{e}"));
    let delivered = balance.received / balance.shot;
    eprintln!("white furnace: received / shot = {delivered:.5}");
    assert!(
        (delivered - 1.0).abs() < 1e-3,
        "a closed box must receive what it shoots: {balance:?}"
    );
    let b = solver.radiosity().unwrap_or_else(|e| panic!("{e}"));
    let worst = common::assert_uniform(&atlas, &b, Vec3::splat(1.0 / (1.0 - 0.9)), 0.01);
    eprintln!("white furnace: max relative error {worst:.5}");
}

/// Two directly opposed, parallel unit squares one unit apart exchange a
/// form factor of 0.19982. The emitter (E = 1, ρ = 0) shoots once; the
/// receiver (ρ = 0.5) then holds B = ρ E F, so its area-weighted mean
/// radiosity divided by ρ E is the form factor (scenes/plates.json).
#[test]
fn plates_implied_form_factor_within_two_percent_of_0_19982() {
    let (scene, atlas) = common::load("plates.json", 1.0);
    assert_eq!(scene.patches.len(), 2, "plates.json has two patches");
    let mut solver = solver(&scene, &atlas);
    solver.solve(1e-6).unwrap_or_else(|e| panic!("{e}"));
    let b = solver.radiosity().unwrap_or_else(|e| panic!("{e}"));
    let f = common::implied_form_factor(&scene, &atlas, &b);
    eprintln!("plates: implied F = {f:.5}");
    assert!((f - 0.19982).abs() / 0.19982 < 0.02, "F = {f}");
}

/// On the large Cornell box (at a test density), the progressive solver
/// agrees with the independent CPU reference solver: NRMSE
/// ([`lightwire_solve::accuracy::accuracy`]: area-weighted, over the
/// visible non-emitting elements) at most 3.5%. Issue 15 asks for 1%
/// (the progressive solver with its gathered corrections meets it,
/// `tests/accuracy.rs`); measured 3.56% on 2026-12-01 (under the old
/// all-texel metric this read 0.83%), 2.61% on 2026-12-02 with shooter
/// tiles split at contacts, 3.10% on 2026-12-03 once the reference's
/// invalid texels send their neighbours' light (`Validity::donors`): the
/// box's bottom row on the +z side reads 0.46-0.51 in the reference now
/// and 0.06 here, where an invalid floor texel's region reaches 7 cm past
/// the box and progressive shooting sends that strip dark. The bound
/// guards what is reached, it is not the target.
#[test]
fn cornell_large_nrmse_against_reference_at_most_three_and_a_half_percent() {
    let (scene, atlas) = common::load("cornell-large.json", 0.35);
    let reference = ReferenceSolver::new(&scene, &atlas, &scene.initial_poses(), &Silent)
        .unwrap_or_else(|e| panic!("{e}"));
    let expected = reference.solve(SolveOptions::default(), &Silent).radiosity;
    let mut solver = solver(&scene, &atlas);
    let report = solver.solve(1e-4).unwrap_or_else(|e| panic!("{e}"));
    let b = solver.radiosity().unwrap_or_else(|e| panic!("{e}"));
    let error = common::visible_accuracy(&scene, &atlas, &scene.initial_poses(), &b, &expected);
    eprintln!(
        "cornell-large x0.35: {} elements, {} shots, {error}",
        atlas.elements.len(),
        report.shots
    );
    assert!(error.nrmse <= 0.035, "{error}");
}

/// Energy conservation in an open scene: the unshot power only ever
/// decreases, no shot delivers more power than it took from the unshot
/// buffers, and what is absorbed plus what is still unshot never exceeds
/// what was emitted (the rest escaped through the open front).
#[test]
fn energy_is_conserved_and_unshot_power_decreases_monotonically() {
    let (scene, atlas) = common::load("cornell-low.json", 0.5);
    let mut solver = solver(&scene, &atlas);
    let mut last = solver.unshot_fraction();
    assert!((last - 1.0).abs() < 1e-4, "all power starts unshot: {last}");
    while last > 1e-3 {
        // A zero budget runs exactly one batch.
        let report = solver
            .step(Duration::ZERO)
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(report.batches, 1);
        assert!(
            report.unshot_fraction < last,
            "unshot fraction went from {last} to {}",
            report.unshot_fraction
        );
        last = report.unshot_fraction;
    }
    let balance = solver.energy_balance().unwrap_or_else(|e| panic!("{e}"));
    eprintln!("cornell-low x0.5: {balance:?}");
    assert!(
        balance.received <= balance.shot * 1.001,
        "received {} of {} shot",
        balance.received,
        balance.shot
    );
    assert!(
        balance.absorbed + balance.unshot <= balance.emitted * 1.001,
        "absorbed {} + unshot {} > emitted {}",
        balance.absorbed,
        balance.unshot,
        balance.emitted
    );
    assert!(
        balance.absorbed > 0.5 * balance.emitted,
        "most light is absorbed in the box: {balance:?}"
    );
}

/// `--adapter NAME` with a name no adapter has is an error that lists the
/// adapters that do exist.
#[test]
fn unknown_adapter_name_lists_the_available_ones() {
    gpu(); // Fails first, with the install hint, if there is no adapter.
    match Device::new(Some("no-such-adapter-name-xyz")) {
        Err(GpuError::NoMatchingAdapter { available, .. }) => {
            assert!(!available.is_empty(), "lists adapters")
        }
        other => panic!("expected NoMatchingAdapter, got {other:?}"),
    }
}

/// Indirect-only output (gems §39.4): total radiosity minus emission minus
/// the first bounce of the emitted light. Between the plates there is no
/// second bounce (the emitter reflects nothing), so the indirect light is
/// zero everywhere; in the Cornell box it is non-negative everywhere, lights
/// some of it, and is smaller than the total.
#[test]
fn indirect_only_output_removes_emission_and_the_first_bounce() {
    let options = ProgressiveOptions {
        indirect_only: true,
        ..ProgressiveOptions::default()
    };
    let (scene, atlas) = common::load("plates.json", 1.0);
    let mut plates = ProgressiveSolver::new(gpu(), &scene, &atlas, &scene.initial_poses(), options)
        .unwrap_or_else(|e| panic!("{e}"));
    plates.solve(1e-6).unwrap_or_else(|e| panic!("{e}"));
    let indirect = plates.radiosity().unwrap_or_else(|e| panic!("{e}"));
    let worst = indirect
        .iter()
        .map(|v| v.max_element())
        .fold(0.0f32, f32::max);
    assert!(worst < 1e-6, "plates have no indirect light, got {worst}");

    let (scene, atlas) = common::load("cornell-low.json", 0.5);
    let mut box_ = ProgressiveSolver::new(gpu(), &scene, &atlas, &scene.initial_poses(), options)
        .unwrap_or_else(|e| panic!("{e}"));
    box_.solve(1e-3).unwrap_or_else(|e| panic!("{e}"));
    let indirect = box_.radiosity().unwrap_or_else(|e| panic!("{e}"));
    let total = box_.total_radiosity().unwrap_or_else(|e| panic!("{e}"));
    let sum = |v: &[Vec3]| v.iter().map(|x| f64::from(x.element_sum())).sum::<f64>();
    let (i, t) = (sum(&indirect), sum(&total));
    assert!(i > 0.05 * t && i < t, "indirect {i} of total {t}");
    eprintln!(
        "cornell-low x0.5: indirect is {:.1}% of total",
        100.0 * i / t
    );
}

/// A hemicube pass drawn as one instanced draw clipped by clip distances
/// and drawn a face at a time with viewports and scissors rasterize the
/// same hemicubes: cornell-large (its box's shadows and contacts are what
/// item buffers decide) solved both ways agrees within 0.3% NRMSE, far
/// below the 3.5% the solver is allowed against the reference. lavapipe
/// has clip distances, so on it both layouts really run.
#[test]
fn hemicubes_in_one_draw_and_per_face_give_the_same_solution() {
    let (scene, atlas) = common::load("cornell-large.json", 0.35);
    let poses = scene.initial_poses();
    let solve = |one_draw: bool| {
        let options = ProgressiveOptions {
            one_draw_hemicubes: one_draw,
            ..ProgressiveOptions::default()
        };
        let mut solver = ProgressiveSolver::new(gpu(), &scene, &atlas, &poses, options)
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(
            solver.hemicubes_in_one_draw(),
            one_draw && gpu().has_clip_distances()
        );
        solver.solve(1e-4).unwrap_or_else(|e| panic!("{e}"));
        solver.radiosity().unwrap_or_else(|e| panic!("{e}"))
    };
    let per_face = solve(false);
    let one = solve(true);
    let error = common::visible_accuracy(&scene, &atlas, &poses, &one, &per_face);
    eprintln!(
        "one draw vs per face ({}; clip distances: {}): {error}",
        gpu().describe(),
        gpu().has_clip_distances()
    );
    assert!(error.nrmse <= 0.003, "{error}");
}
