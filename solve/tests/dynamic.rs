//! Dynamic objects (thesis ch. 3 and 4): the solver session follows moves
//! of the box by incremental radiosity with reshooting (§4.4) and by cross
//! redistribution radiosity (§4.5), and must agree with a from-scratch
//! solve at the new pose, must not drift over many moves, must only ever
//! publish complete states, and must keep negative light out of them.
//! These run on lavapipe like the other GPU tests.

mod common;

use std::time::Duration;

use glam::{Quat, Vec3};
use lightwire_scene::atlas::Atlas;
use lightwire_scene::{Pose, Scene};
use lightwire_solve::accuracy::{accuracy, accuracy_where};
use lightwire_solve::gpu::{
    DynamicOptions, DynamicSolver, ProgressiveOptions, ProgressiveSolver, Redistribution, Seed,
};
use lightwire_solve::reference::{ReferenceSolver, Silent, SolveOptions};
use lightwire_solve::validity::Validity;

/// A session whose tag is the seq of the box's pose (the box is the only
/// object that moves).
type Session = DynamicSolver<[u64; 1]>;

/// The device every GPU test of this binary shares.
use common::gpu;

/// The scene's poses with the box turned `degrees` about y and shifted.
fn box_pose(scene: &Scene, degrees: f32, shift: Vec3) -> Vec<Pose> {
    let mut poses = scene.initial_poses();
    let o = scene.object_by_name("box").expect("the scene has a box") as usize;
    poses[o].rotation = Quat::from_rotation_y(degrees.to_radians()) * poses[o].rotation;
    poses[o].translation += shift;
    poses
}

/// A converged progressive solve from scratch at `poses`.
fn from_scratch(scene: &Scene, atlas: &Atlas, poses: &[Pose]) -> Vec<Vec3> {
    from_scratch_with(scene, atlas, poses, ProgressiveOptions::default())
}

fn from_scratch_with(
    scene: &Scene,
    atlas: &Atlas,
    poses: &[Pose],
    options: ProgressiveOptions,
) -> Vec<Vec3> {
    let mut s = ProgressiveSolver::new(gpu(), scene, atlas, poses, options)
        .unwrap_or_else(|e| panic!("{e}"));
    s.solve(1e-4).unwrap_or_else(|e| panic!("{e}"));
    s.radiosity().unwrap_or_else(|e| panic!("{e}"))
}

/// How far a state after one move may be from a from-scratch solve at its
/// pose (NRMSE over the visible non-emitting elements, cornell-large x0.35).
/// Issue 15 asks for 2%. Measured on 2026-12-01 with the visibility and
/// contact changes of that day (lavapipe): incremental 3.21%, cross 11.04%
/// (cross is first-order for the moving object, thesis §4.5.2; under the
/// old all-texel metric it read 1.44%). Measured on 2026-12-02 with
/// shooter tiles split at contacts and the texels near a cross move
/// gathered again: cross 5.00% (incremental did not split tiles then, see
/// `ProgressiveOptions::split_contacts`; with the split it read 1.52%).
/// Measured on 2026-12-02 once refinement received negative light and
/// incremental sessions split tiles too: incremental 1.52%, so its bound
/// is issue 15's 2%; and once rays of the cross projection that leave the
/// scene stopped blocking light (`cross_projection_blocks_what_rays_say`):
/// cross 3.82% before the negative-light change. Measured on 2026-12-03
/// once cross tiles gathered reflected light only, took direct light per
/// texel and gathered again from the total radiosity after the move's
/// batches: cross 2.89% (3.86% before); once the moved texels at a contact
/// gathered on their own, the static texels within two texels of the move
/// (not one) regathered, and regathering read the state as published
/// (negative light as none, invalid texels filled): 2.13%; reading it
/// bilinearly, as a client does (the contact row no longer alternates
/// light and dark, and lies nearer the path tracer than this from-scratch
/// solve does, BENCHMARKS.md): 2.21%. Once refinement ran with the box in
/// place (passive: it occludes, but neither receives nor shoots), so that
/// the light a move deposits on the room gets its second bounce, and the
/// invalid texels near a move went to zero instead of keeping the -2.9 of
/// the box's two-sided shadow for refinement to shoot: cross 1.77%, so
/// its bound is issue 15's 2% too. On 2026-12-04, with incremental jobs
/// cutting patches as finely as a progressive batch: incremental 1.10%.
fn after_move_bound(method: Redistribution) -> f64 {
    match method {
        Redistribution::Incremental => 0.02,
        Redistribution::Cross => 0.02,
        Redistribution::Full => 0.02,
    }
}

/// The same, at the checkpoints of 1,000 moves (measured on 2026-12-01:
/// incremental 6.32% at move 99, cross 13.34% at move 99 and 15.58% at
/// move 499; on 2026-12-02, with the changes above, the worst cross
/// checkpoint 8.22%; once refinement received negative light and
/// incremental sessions split tiles, incremental 0.42% after the first
/// move, worst checkpoint 3.08%, 0.11% after the last; cross 6.17% worst
/// once escaping rays stopped blocking light, first move 3.58%, last
/// 3.54%, before the negative-light change; on 2026-12-03, with cross
/// tiles gathering again from the total radiosity, first move 2.69%, worst
/// checkpoint 4.60%, last 2.70% — 7.19% last while that second gather
/// still read the total radiosity of invalid texels, which keep what every
/// move hands them; with contact texels gathering on their own, first
/// move 2.61%, worst checkpoint 4.21%, last 2.51% — 6.18% at move 999
/// while they showed their own gather even where it exceeded the tiles';
/// with refinement around the passive box after every move, first move
/// 2.24%, worst checkpoint 3.52%, last 2.40%; on 2026-12-04, with
/// incremental patches cut as finely as a progressive batch cuts them,
/// incremental worst checkpoint 2.17%).
/// That error must not grow with the number of moves is asserted
/// separately (`last <= first + ...`). On 2026-12-06 the path gained a
/// jump of the teleport script every 100 moves and back (issue 57): cross
/// worst checkpoint 4.95% (at move 599, the jump at 550 having landed the
/// box elsewhere), first move 2.18%, last 2.67%; incremental worst 2.17%.
/// Cross's bound is raised to 6% for the jumps.
fn drift_bound(method: Redistribution) -> f64 {
    match method {
        Redistribution::Incremental => 0.05,
        Redistribution::Cross => 0.06,
        Redistribution::Full => 0.02,
    }
}

/// How far a published version may be from a from-scratch solve at the
/// pose it claims (cornell-low x0.5; measured on 2026-12-01 at most 5.9%
/// (8.2% in one run) for incremental and 14.9% for cross); a half-done state is further off
/// both its old and its new pose than this.
fn publish_bound(method: Redistribution) -> f64 {
    match method {
        Redistribution::Incremental => 0.10,
        Redistribution::Cross => 0.18,
        Redistribution::Full => 0.05,
    }
}

/// The static scene without its dynamic objects (cross redistribution's
/// starting point, thesis §4.5.2), solved to `threshold` unshot.
fn static_solve(scene: &Scene, atlas: &Atlas, poses: &[Pose], threshold: f64) -> ProgressiveSolver {
    static_solve_with(
        scene,
        atlas,
        poses,
        threshold,
        ProgressiveOptions::default(),
    )
}

fn static_solve_with(
    scene: &Scene,
    atlas: &Atlas,
    poses: &[Pose],
    threshold: f64,
    options: ProgressiveOptions,
) -> ProgressiveSolver {
    let absent: Vec<bool> = scene.objects.iter().map(|o| o.dynamic).collect();
    let mut s = ProgressiveSolver::with_absent(gpu(), scene, atlas, poses, &absent, options)
        .unwrap_or_else(|e| panic!("{e}"));
    s.solve(threshold).unwrap_or_else(|e| panic!("{e}"));
    s
}

fn session(scene: &Scene, atlas: &Atlas, method: Redistribution) -> Session {
    session_with(scene, atlas, method, ProgressiveOptions::default())
}

/// A session without the cross method's gathered corrections of its first
/// solve: the tests below compare it with an uncorrected from-scratch
/// solve, so that what they measure is the redistribution alone
/// (`cross_corrections_bring_a_moved_scene_near_the_reference` tests the
/// corrections).
fn session_with(
    scene: &Scene,
    atlas: &Atlas,
    method: Redistribution,
    progressive: ProgressiveOptions,
) -> Session {
    session_corrected(scene, atlas, method, progressive, 0)
}

fn session_corrected(
    scene: &Scene,
    atlas: &Atlas,
    method: Redistribution,
    progressive: ProgressiveOptions,
    corrections: u32,
) -> Session {
    let options = DynamicOptions {
        method,
        progressive,
        corrections,
        ..DynamicOptions::default()
    };
    DynamicSolver::new(gpu(), scene, atlas, &scene.initial_poses(), [0], options)
        .unwrap_or_else(|e| panic!("{e}"))
}

/// Steps until nothing is running or waiting; returns how many complete
/// states were published on the way.
fn settle(d: &mut Session) -> u64 {
    let before = d.versions();
    for _ in 0..100_000 {
        if d.is_idle() {
            return d.versions() - before;
        }
        d.step(Duration::from_millis(20))
            .unwrap_or_else(|e| panic!("{e}"));
    }
    panic!("the session never became idle");
}

fn radiosity(d: &Session) -> Vec<Vec3> {
    d.radiosity().unwrap_or_else(|e| panic!("{e}"))
}

/// Runs a new session's first solve, then one move to `target` (seq 1);
/// returns the state published for it.
fn published_after_one_move(d: &mut Session, target: &[Pose]) -> Vec<Vec3> {
    assert!(settle(d) >= 1, "the first solve publishes");
    d.set_poses(target, [1]);
    assert!(settle(d) >= 1, "the move publishes");
    assert_eq!(d.reflected(), &[1], "the state reflects the move's seq");
    radiosity(d)
}

/// How far the moved box's own faces may be from a from-scratch solve,
/// over their texels above the row that stands on the floor (NRMSE, the
/// same test). Measured on 2026-12-03: incremental 1.53%; cross 3.17%,
/// and 6.28% before its tiles gathered reflected light only, took direct
/// light per texel and gathered again from the total radiosity once the
/// move's batches had run (faces that see the box's own shadow on the
/// floor read 10-30% too bright, the lit top flat). The contact row is
/// left out: there a texel's sample lies on the floor's plane and the
/// from-scratch solve itself reads it at about half of the row above.
/// Once the static texels near the move regathered from the state as
/// published (negative light as none, invalid texels filled) and within
/// two texels instead of one, so that the box's second gather sees them
/// right: cross 2.39%, 2.62% with that regather read bilinearly (against
/// the path tracer these faces are 1.84% off, the from-scratch solve
/// 2.42%); with refinement around the passive box: cross 2.43%.
fn moved_faces_bound(method: Redistribution) -> f64 {
    match method {
        Redistribution::Incremental => 0.03,
        Redistribution::Cross => 0.03,
        Redistribution::Full => 0.02,
    }
}

/// After moving the box (turned 30° and shifted 0.5 m) the session's state
/// matches a from-scratch solve at the new pose: NRMSE
/// ([`lightwire_solve::accuracy::accuracy`]: area-weighted, non-emitting
/// elements) within [`after_move_bound`] (cornell-large at test density),
/// and on the box's faces above their contact row within
/// [`moved_faces_bound`].
fn after_a_move_matches_a_from_scratch_solve(method: Redistribution) {
    let bound = after_move_bound(method);
    let (scene, atlas) = common::load("cornell-large.json", 0.35);
    let target = box_pose(&scene, 30.0, Vec3::new(0.4, 0.0, -0.3));
    let expected = from_scratch(&scene, &atlas, &target);
    let mut d = session(&scene, &atlas, method);
    let published = published_after_one_move(&mut d, &target);
    let error = common::visible_accuracy(&scene, &atlas, &target, &published, &expected);
    eprintln!("{method}: after a move {error}");
    assert!(error.nrmse <= bound, "{method}: {error} (bound {bound})");

    let o = scene.object_by_name("box").expect("the scene has a box");
    let validity = Validity::compute(&scene, &atlas, &target);
    let keep = validity.keep();
    let faces = accuracy_where(&atlas, &published, &expected, |i| {
        let e = &atlas.elements[i];
        e.object == o && keep(i) && target[o as usize].transform_point(e.position).y > 1e-3
    })
    .expect("the box is lit");
    let bound = moved_faces_bound(method);
    eprintln!("{method}: the moved box above its contact {faces}");
    assert!(
        faces.nrmse <= bound,
        "{method}: box faces {faces} (bound {bound})"
    );
    negative_light_is_small_and_never_published(&d, &atlas, &published);
}

/// [`after_move_bound`] for the mesh box. Measured on 2026-12-02
/// (lavapipe, `cornell-dynamic.glb` x0.28, 3,450 texels of which 1,701
/// visible non-emitting): incremental 2.13% (the quad box 1.52%, issue 15's
/// 2% not met on the mesh), cross 3.78% (the quad box 3.86%); on
/// 2026-12-03, with cross tiles gathering reflected light and again from
/// the total radiosity, and direct light per texel: cross 2.98% (the quad
/// box 2.89%); with contact texels gathering on their own and the static
/// texels regathered within two texels from the state as published: cross
/// 2.35% (the quad box 2.13%); with refinement around the passive box:
/// cross 2.21% (the quad box 1.77%). On 2026-12-04, once incremental
/// jobs cut a patch into as many shooters as a progressive batch does
/// (they had half: a static patch's two hemicubes per shooter had to fit
/// one batch, and the box after a move read 4% darker than from scratch):
/// incremental 1.55% (the quad box 1.10%), so its bound is issue 18's 2%;
/// cross 2.06%. The cross bound holds the measured value with a margin; it
/// is not the target.
fn mesh_after_move_bound(method: Redistribution) -> f64 {
    match method {
        Redistribution::Incremental => 0.02,
        Redistribution::Cross => 0.03,
        Redistribution::Full => 0.02,
    }
}

/// The same contract on a triangle mesh: `cornell-dynamic.glb` (the box a
/// glTF node of twelve triangles, the room two triangles per wall) at about
/// the density of the quad test, moved as above, incremental and cross
/// against one from-scratch solve at the new pose (issue 18: a mesh
/// dynamic object converges as the quad box does; bounds in
/// [`mesh_after_move_bound`]).
#[test]
fn a_mesh_box_after_a_move_matches_a_from_scratch_solve() {
    let (scene, atlas) = common::load_triangles("meshes/cornell-dynamic.glb", 0.28);
    assert!(scene.patches.iter().all(|p| p.shape.is_triangle()));
    let b = scene.object_by_name("box").expect("the scene has a box");
    assert!(
        scene.closed_objects()[b as usize],
        "the mesh box is watertight: its cross tiles are one-sided like the quad box's"
    );
    let target = box_pose(&scene, 30.0, Vec3::new(0.4, 0.0, -0.3));
    let expected = from_scratch(&scene, &atlas, &target);
    let errors: Vec<_> = [Redistribution::Incremental, Redistribution::Cross]
        .into_iter()
        .map(|method| {
            let mut d = session(&scene, &atlas, method);
            let published = published_after_one_move(&mut d, &target);
            let error = common::visible_accuracy(&scene, &atlas, &target, &published, &expected);
            eprintln!("{method} on triangles: after a move {error}");
            (method, error)
        })
        .collect();
    for (method, error) in errors {
        let bound = mesh_after_move_bound(method);
        assert!(error.nrmse <= bound, "{method}: {error} (bound {bound})");
    }
}

/// Negative light (thesis §2.2.5): redistribution shoots negative
/// radiosity, so the GPU state may hold texels below zero where what is
/// taken back was shot with a different discretization than what was
/// given. That residue must be small: at most 2% of the lightmap's power
/// (Σ A·max(-B, 0) over Σ A·|B|; measured 1.44% for cross on 2026-12-01,
/// after visibility became fractional at shadow edges — it was under 1%
/// with binary visibility). And it must never reach a reader: the
/// published state has no negative channel.
fn negative_light_is_small_and_never_published(d: &Session, atlas: &Atlas, published: &[Vec3]) {
    let raw = d.raw_radiosity().unwrap_or_else(|e| panic!("{e}"));
    let (mut negative, mut total) = (0.0f64, 0.0f64);
    for (b, e) in raw.iter().zip(&atlas.elements) {
        let a = f64::from(e.area);
        negative += a * f64::from((-*b).max(Vec3::ZERO).element_sum());
        total += a * f64::from(b.abs().element_sum());
    }
    let fraction = negative / total;
    eprintln!("negative light: {:.5} of the power", fraction);
    assert!(
        fraction <= 0.02,
        "negative light is {fraction} of the power"
    );
    assert!(
        published.iter().all(|b| b.min_element() >= 0.0),
        "a published texel is negative"
    );
}

/// Refinement shoots negative unshot radiosity like positive (thesis
/// §2.2.5): redistribution leaves negative light in the static scene that
/// the progressive iterations after a move must carry on. A converged
/// solver given `+d` on one patch's unshot radiosity and another given
/// `-d` must change the rest of the scene by opposite amounts. (Refinement
/// used to receive only where a batch's net irradiance was positive, so
/// negative light vanished at its first receivers and every incremental
/// move created energy: on indirect-light a move that changed nothing
/// left the room 3% brighter, five 2° moves read 20% NRMSE.)
#[test]
fn refinement_carries_negative_light_like_positive() {
    let (scene, atlas) = common::load("cornell-low.json", 0.35);
    let poses = scene.initial_poses();
    let patch = scene
        .patches
        .iter()
        .position(|p| p.name == "floor")
        .expect("cornell-low has a floor") as u32;
    // Power (W, channels summed) of the elements off the floor.
    let elsewhere = |b: &[Vec3]| -> f64 {
        atlas
            .elements
            .iter()
            .zip(b)
            .filter(|(e, _)| e.patch != patch)
            .map(|(e, v)| f64::from(e.area) * f64::from(v.element_sum()))
            .sum()
    };
    let change = |sign: f32| -> f64 {
        let mut s = ProgressiveSolver::new(gpu(), &scene, &atlas, &poses, Default::default())
            .unwrap_or_else(|e| panic!("{e}"));
        s.solve(1e-4).unwrap_or_else(|e| panic!("{e}"));
        let before = elsewhere(&s.total_radiosity().unwrap_or_else(|e| panic!("{e}")));
        let delta: Vec<Vec3> = atlas
            .elements
            .iter()
            .map(|e| {
                if e.patch == patch {
                    Vec3::splat(sign * 0.5)
                } else {
                    Vec3::ZERO
                }
            })
            .collect();
        s.add_unshot(&delta).unwrap_or_else(|e| panic!("{e}"));
        s.solve(1e-4).unwrap_or_else(|e| panic!("{e}"));
        elsewhere(&s.total_radiosity().unwrap_or_else(|e| panic!("{e}"))) - before
    };
    let (up, down) = (change(1.0), change(-1.0));
    eprintln!("floor +d: {up:.4} W elsewhere, -d: {down:.4} W");
    assert!(up > 0.0, "positive light reached nothing: {up}");
    assert!(
        (up + down).abs() <= 0.02 * up,
        "negative light is not carried like positive: +d gave {up} W, -d {down} W"
    );
}

/// A cross session's first solve, corrected by gathering (the default,
/// `DynamicOptions::corrections`), carries its accuracy through a move:
/// after the box has turned and shifted, the session with two rounds is
/// nearer the CPU reference at the new pose than the one without, and
/// within `bound` of it (NRMSE over the visible non-emitting elements).
fn corrected_cross_after_a_move(file: &str, scale: f32, bound: f64) {
    let (scene, atlas) = common::load(file, scale);
    let target = box_pose(&scene, 30.0, Vec3::new(0.4, 0.0, -0.3));
    let reference =
        ReferenceSolver::new(&scene, &atlas, &target, &Silent).unwrap_or_else(|e| panic!("{e}"));
    let expected = reference.solve(SolveOptions::default(), &Silent).radiosity;
    let mut errors = Vec::new();
    for corrections in [0, 2] {
        let mut d = session_corrected(
            &scene,
            &atlas,
            Redistribution::Cross,
            ProgressiveOptions::default(),
            corrections,
        );
        let published = published_after_one_move(&mut d, &target);
        let error = common::visible_accuracy(&scene, &atlas, &target, &published, &expected);
        eprintln!("{file}: cross, {corrections} correction rounds, after a move: {error}");
        errors.push(error.nrmse);
    }
    assert!(
        errors[1] < errors[0],
        "{file}: corrections must bring the session nearer the reference: {errors:?}"
    );
    assert!(
        errors[1] <= bound,
        "{file}: corrected cross after a move: {:.2}% (bound {:.2}%)",
        errors[1] * 100.0,
        bound * 100.0
    );
}

/// [`corrected_cross_after_a_move`] on cornell-large x0.35. Measured on
/// 2026-12-04: 2.22% without, 1.86% with (at the bench's density,
/// `bench dynamic --corrections 0|2`, the gap is wider: 1.82% and 1.02%).
/// Bound: issue 15's 2% for a state a viewer sees.
#[test]
fn cross_corrections_bring_a_moved_scene_near_the_reference() {
    corrected_cross_after_a_move("cornell-large.json", 0.35, 0.02);
}

/// A cross session that lights its static set with the ray solver
/// ([`Seed::Rays`], what a level gets, where refinement took minutes
/// before the first state) is as right as one that refines it: once idle
/// (two correction rounds), its first state and its state after a move
/// are within 2% of the CPU reference at their poses (NRMSE over the
/// visible non-emitting elements, cornell-large x0.35), as the refined
/// session's are. A seed that the progressive solver did not take as
/// converged would be shot again on top (twice the light), one that
/// left the moving box's effect out would miss its shadow.
#[test]
fn a_cross_session_seeded_by_rays_is_as_right_as_a_refined_one() {
    let (scene, atlas) = common::load("cornell-large.json", 0.35);
    let start = scene.initial_poses();
    let target = box_pose(&scene, 30.0, Vec3::new(0.4, 0.0, -0.3));
    let reference_at = |poses: &[Pose]| {
        ReferenceSolver::new(&scene, &atlas, poses, &Silent)
            .unwrap_or_else(|e| panic!("{e}"))
            .solve(SolveOptions::default(), &Silent)
            .radiosity
    };
    let (at_start, at_target) = (reference_at(&start), reference_at(&target));
    let mut shots = Vec::new();
    for seed in [Seed::Refinement, Seed::Rays] {
        let options = DynamicOptions {
            method: Redistribution::Cross,
            corrections: 2,
            seed,
            ..DynamicOptions::default()
        };
        let mut d = DynamicSolver::new(gpu(), &scene, &atlas, &start, [0], options)
            .unwrap_or_else(|e| panic!("{e}"));
        assert!(settle(&mut d) >= 1, "{seed:?}: the first solve publishes");
        shots.push(d.progressive().total_shots());
        let first = radiosity(&d);
        let first = common::visible_accuracy(&scene, &atlas, &start, &first, &at_start);
        let moved = published_after_one_move_from_idle(&mut d, &target);
        let moved = common::visible_accuracy(&scene, &atlas, &target, &moved, &at_target);
        eprintln!("cross seeded by {seed:?}: first state {first}, after a move {moved}");
        assert!(first.nrmse <= 0.02, "{seed:?}: first state {first}");
        assert!(moved.nrmse <= 0.02, "{seed:?}: after a move {moved}");
    }
    // The seeded session shot only what insertion and its corrections
    // changed: its static light came from the rays (measured: 149 shots
    // against the refined session's 617).
    eprintln!(
        "shots to the first idle state: refined {}, seeded {}",
        shots[0], shots[1]
    );
    assert!(
        shots[1] * 2 < shots[0],
        "the seeded session refined as much as the other: {shots:?}"
    );
}

/// One move of an idle session to `target` (seq 1); the state once idle
/// again.
fn published_after_one_move_from_idle(d: &mut Session, target: &[Pose]) -> Vec<Vec3> {
    d.set_poses(target, [1]);
    assert!(settle(d) >= 1, "the move publishes");
    assert_eq!(d.reflected(), &[1], "the state reflects the move's seq");
    radiosity(d)
}

/// [`corrected_cross_after_a_move`] on the mesh box (`cornell-dynamic.glb`,
/// at x0.45, as loaded by default: each face's two triangles one quad
/// patch, `scene/pairs.rs`; 3,523 visible non-emitting texels):
/// issue 18's "a mesh dynamic object moved by a driver converges as the
/// quad box does (at most 2% from a from-scratch reference at the new
/// pose)", against the CPU reference. Measured on 2026-12-04: 1.87%
/// without, 1.39% with (a triangle per patch, 3,802 texels: 2.28% and
/// 1.70%). The triangles themselves are tested after a move in
/// `a_mesh_box_after_a_move_matches_a_from_scratch_solve`.
#[test]
fn cross_corrections_bring_a_moved_mesh_box_near_the_reference() {
    corrected_cross_after_a_move("meshes/cornell-dynamic.glb", 0.45, 0.02);
}

/// A closed box resting on the floor is cut into cross tiles on every face
/// but its bottom: no receiver lies in front of that face (the floor's
/// receiving points are a hair above its plane), so its tiles would gather,
/// shoot and shadow nothing. Lifted 5 cm, the bottom faces the floor and
/// is tiled again, whether it rests at the old pose or the new.
#[test]
fn a_box_resting_on_the_floor_has_no_tiles_on_its_bottom() {
    let (scene, atlas) = common::load("cornell-low.json", 0.5);
    let b = scene.object_by_name("box").expect("the scene has a box");
    assert!(scene.closed_objects()[b as usize], "the quad box is closed");
    let faces: Vec<u32> = (0..scene.patches.len() as u32)
        .filter(|&p| scene.patches[p as usize].object == b)
        .collect();
    let bottom = faces
        .iter()
        .copied()
        .find(|&p| scene.patches[p as usize].shape.normal().y < -0.99)
        .expect("the box has a bottom");
    let resting = scene.initial_poses();
    let lifted = box_pose(&scene, 0.0, Vec3::new(0.0, 0.05, 0.0));
    let turned = box_pose(&scene, 20.0, Vec3::ZERO);
    let mut s = static_solve(&scene, &atlas, &resting, 1e-2);
    let present = vec![false; scene.objects.len()];
    let others: Vec<u32> = faces.iter().copied().filter(|&p| p != bottom).collect();
    for (poses, expected) in [
        (&resting, &others),
        (&turned, &others),
        (&lifted, &faces),
        (&turned, &faces),
    ] {
        let mut mv = s
            .begin_move(poses, &present, Redistribution::Cross)
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(&mv.tiled_patches(), expected);
        s.finish_move(&mut mv).unwrap_or_else(|e| panic!("{e}"));
    }
}

/// A cross move's old pose is the last move's new one, so it copies the
/// item buffers and back hemicubes the last move drew at its tiles' new
/// pose instead of drawing them again
/// (`ProgressiveOptions::keep_old_pose_hemicubes`), but only when they are
/// the same hemicubes: the box inserted, then turned three times with
/// shifts (each move reuses), then lifted (the bottom gets tiles the last
/// move did not draw: drawn anew), then turned lifted (reuses). The light
/// equals that of a solver that draws every hemicube, to within the
/// rasterizer's rounding of a hemicube drawn into another row of the
/// target. A kept back hemicube holds element ids, shaded with the light
/// of the move that reads it: had it kept the last move's light, the
/// refinement between moves would be missing from what the box unblocks.
#[test]
fn cross_moves_reuse_the_last_moves_hemicubes_only_when_they_are_the_same() {
    let (scene, atlas) = common::load("cornell-low.json", 0.5);
    let resting = scene.initial_poses();
    let present = vec![false; scene.objects.len()];
    let moves = [
        resting.clone(),
        box_pose(&scene, 10.0, Vec3::new(0.3, 0.0, 0.0)),
        box_pose(&scene, 20.0, Vec3::new(0.6, 0.0, -0.3)),
        box_pose(&scene, 30.0, Vec3::new(0.3, 0.0, -0.6)),
        box_pose(&scene, 30.0, Vec3::new(0.3, 0.05, -0.6)),
        box_pose(&scene, 40.0, Vec3::new(0.0, 0.05, -0.3)),
    ];
    let run = |keep: bool| {
        let options = ProgressiveOptions {
            keep_old_pose_hemicubes: keep,
            ..ProgressiveOptions::default()
        };
        let mut s = static_solve_with(&scene, &atlas, &resting, 1e-2, options);
        let dynamic: Vec<bool> = scene.objects.iter().map(|o| o.dynamic).collect();
        s.set_passive(&dynamic).unwrap_or_else(|e| panic!("{e}"));
        let mut reused = Vec::new();
        for poses in &moves {
            let before = (s.kept_item_jobs(), s.kept_back_jobs());
            let mut mv = s
                .begin_move(poses, &present, Redistribution::Cross)
                .unwrap_or_else(|e| panic!("{e}"));
            s.finish_move(&mut mv).unwrap_or_else(|e| panic!("{e}"));
            // Refinement between moves, as a session runs it (the box
            // passive), changes the light the next move's back hemicubes
            // show.
            s.solve(2e-3).unwrap_or_else(|e| panic!("{e}"));
            reused.push((s.kept_item_jobs() - before.0, s.kept_back_jobs() - before.1));
        }
        let radiosity = s.radiosity().unwrap_or_else(|e| panic!("{e}"));
        (reused, radiosity)
    };
    let (reused, kept) = run(true);
    assert_eq!(
        reused,
        [(0, 0), (1, 1), (1, 1), (1, 1), (0, 0), (1, 1)],
        "cross jobs that reused item buffers and back hemicubes, per move"
    );
    let (reused, drawn) = run(false);
    assert_eq!(reused, [(0, 0); 6], "nothing kept when told not to");
    let a = accuracy(&atlas, &kept, &drawn).expect("lit elements");
    eprintln!("kept vs drawn hemicubes: NRMSE {:.3e}", a.nrmse);
    assert!(
        a.nrmse < 1e-4,
        "kept vs drawn hemicubes: NRMSE {:.3e}",
        a.nrmse
    );
}

#[test]
fn incremental_after_a_move_matches_a_from_scratch_solve_within_its_bound() {
    after_a_move_matches_a_from_scratch_solve(Redistribution::Incremental);
}

#[test]
fn cross_after_a_move_matches_a_from_scratch_solve_within_its_bound() {
    after_a_move_matches_a_from_scratch_solve(Redistribution::Cross);
}

/// No drift (thesis §3.1, §4.5.2): 1,000 redistributions along a closed
/// path (the box turns a full circle about y in 1,000 steps while it
/// wanders on a small loop), broken every 100 moves by a jump of
/// `teleport-stress.json` (mid-air, against a wall, or landing elsewhere
/// on the floor) and a jump back (issue 57: jumps, not small steps, lost a
/// cross session its light), end at the start pose:
///
/// - with each move only refined (the next pose arrives before the scene
///   holds still, so no gathered corrections run): NRMSE against a
///   from-scratch solve there of at most [`drift_bound`], no worse than
///   after the first redistribution plus 0.75 percentage points (jumps
///   leave more local error than small steps: cross measured 2.18% after
///   the first move and 2.67% after the last), and the room's total light
///   within 1% of the from-scratch solve's (before issue 57's fix of the
///   texels a box lands on, a cross session lost about 0.3% of the room's
///   light at every landing: 5.3% after 19 jumps, `examples/round_trip.rs`);
///   every 100 moves the state is compared with a from-scratch solve at
///   its pose and must stay within the same bound;
/// - then held still (its corrections run), texel by texel against a fresh
///   session at the start (`metrics::agreement`): at most 1% of the lit
///   texels more than 2% off, none beyond 5%, total light within 0.5%.
///
/// The checkpoints sit just before an incremental re-anchoring (see
/// `DynamicOptions::reanchor_every`), where its error is largest. The
/// incremental session's 1,000th move is itself a re-anchoring; the cross
/// session never re-anchors. Cornell-low at a third of its density and
/// hemicubes of 32² pixels (for the session and the reference solves
/// alike) keep the 2,000 moves within the CI budget.
fn thousand_moves_do_not_drift(method: Redistribution) {
    const STEPS: usize = 1000;
    let (scene, atlas) = common::load("cornell-low.json", 0.35);
    let start = scene.initial_poses();
    let options = ProgressiveOptions {
        hemicube_resolution: 32,
        ..ProgressiveOptions::default()
    };
    let corrections = DynamicOptions::default().corrections;
    let mut d = session_corrected(&scene, &atlas, method, options, corrections);
    // Refined, not corrected: the moves start from the state a
    // from-scratch progressive solve compares with.
    let refine = |d: &mut Session| {
        while !d.is_settled() {
            d.step(Duration::from_millis(20))
                .unwrap_or_else(|e| panic!("{e}"));
        }
    };
    refine(&mut d);
    let script = lightwire_protocol::script::Script::load(&common::scene_path(
        "scripts/teleport-stress.json",
    ))
    .unwrap_or_else(|e| panic!("{e}"));
    let o = scene.object_by_name("box").expect("the scene has a box") as usize;
    let jump = |k: usize| {
        let key = &script.keys()[1 + (k / 100) % (script.keys().len() - 2)];
        let mut poses = scene.initial_poses();
        poses[o] = Pose::from(key);
        poses
    };
    let pose_at = |k: usize| {
        if k == STEPS {
            return start.clone();
        }
        if k % 100 == 50 {
            return jump(k);
        }
        let phase = k as f32 / STEPS as f32 * std::f32::consts::TAU;
        let shift = Vec3::new(phase.sin(), 0.0, 1.0 - phase.cos()) * 0.15;
        box_pose(&scene, 360.0 * k as f32 / STEPS as f32, shift)
    };
    // NRMSE and texel agreement against a from-scratch solve at move k's
    // pose, both read as published (invalid texels filled).
    let compare = |d: &Session, k: usize| {
        let poses = pose_at(k);
        let valid = Validity::compute(&scene, &atlas, &poses);
        let mut fresh = from_scratch_with(&scene, &atlas, &poses, options);
        let mut got = radiosity(d);
        let error = common::visible_accuracy(&scene, &atlas, &poses, &got, &fresh).nrmse;
        valid.fill(&atlas, &mut fresh);
        d.progressive().validity().fill(&atlas, &mut got);
        let texels = lightwire_solve::accuracy::agreement(&atlas, &got, &fresh, valid.keep())
            .expect("the from-scratch solve is lit");
        (error, texels)
    };
    let mut first = 0.0;
    let mut worst = 0.0f64;
    let mut worst_negative = 0.0f32;
    for k in 1..=STEPS {
        d.set_poses(&pose_at(k), [k as u64]);
        refine(&mut d);
        if k == 1 {
            first = compare(&d, k).0;
        } else if k % 100 == 99 {
            let (error, texels) = compare(&d, k);
            eprintln!("{method}: NRMSE {error:.5} after {k} moves; {texels}");
            assert!(
                error <= drift_bound(method),
                "{method}: NRMSE {error} after {k} moves"
            );
            worst = worst.max(error);
            let raw = d.raw_radiosity().unwrap_or_else(|e| panic!("{e}"));
            worst_negative = raw
                .iter()
                .map(|v| v.min_element())
                .fold(worst_negative, f32::min);
        }
    }
    assert_eq!(d.poses(), start.as_slice(), "back at the start pose");
    let (last, refined) = compare(&d, STEPS);
    eprintln!(
        "{method}: NRMSE after the first move {first:.5}, worst checkpoint {worst:.5}, after {STEPS} moves {last:.5}; most negative texel {worst_negative}; refined after {STEPS} moves: {refined}"
    );
    assert!(
        last <= drift_bound(method),
        "{method}: NRMSE {last} after {STEPS} moves"
    );
    assert!(
        last <= first + 0.0075,
        "{method}: drifted from {first} after one move to {last} after {STEPS}"
    );
    assert!(
        refined.total.abs() <= 0.01,
        "{method}: after {STEPS} moves the room's light is {:+.2}% of a from-scratch solve's ({refined})",
        refined.total * 100.0
    );
    // Held still: corrected, as a fresh session is.
    settle(&mut d);
    let mut got = radiosity(&d);
    d.progressive().validity().fill(&atlas, &mut got);
    let mut fresh = session_corrected(&scene, &atlas, method, options, corrections);
    settle(&mut fresh);
    let mut expected = radiosity(&fresh);
    fresh.progressive().validity().fill(&atlas, &mut expected);
    let valid = Validity::compute(&scene, &atlas, &start);
    let texels = lightwire_solve::accuracy::agreement(&atlas, &got, &expected, valid.keep())
        .expect("the fresh session is lit");
    eprintln!("{method}: corrected after {STEPS} moves, against a fresh session: {texels}");
    assert!(
        texels.over_2 <= 0.01 && texels.over_5 == 0.0 && texels.total.abs() <= 0.005,
        "{method}: corrected after {STEPS} moves, the light did not come back: {texels}"
    );
}

#[test]
fn incremental_thousand_moves_along_a_closed_path_do_not_drift() {
    thousand_moves_do_not_drift(Redistribution::Incremental);
}

#[test]
fn cross_thousand_moves_along_a_closed_path_do_not_drift() {
    thousand_moves_do_not_drift(Redistribution::Cross);
}

/// No published state is ever half-done (thesis §4.5.3: intermediate
/// states are not consistent, so they are double-buffered). Poses stream in
/// faster than moves complete (a new pose every third 10 ms step, cycling
/// through six poses); after every step that publishes, the state must
/// have: a version one above the previous; reflected seqs that never go
/// back; no negative texel; and an NRMSE of at most 5% against a
/// from-scratch solve at the very pose its seq names. To show that the
/// last check can tell a half-done state, raw GPU states read between
/// publications, in the middle of moves, must break it at least once.
fn only_complete_states_are_published(method: Redistribution) {
    let (scene, atlas) = common::load("cornell-low.json", 0.35);
    let script: Vec<Vec<Pose>> = (0..6)
        .map(|i| box_pose(&scene, 25.0 * i as f32, Vec3::new(0.1 * i as f32, 0.0, 0.0)))
        .collect();
    let expected: Vec<Vec<Vec3>> = script
        .iter()
        .map(|p| from_scratch(&scene, &atlas, p))
        .collect();
    let pose_of_seq = |seq: u64| if seq == 0 { 0 } else { (seq as usize - 1) % 6 };
    let mut d = session(&scene, &atlas, method);
    let (mut version, mut seq, mut published, mut half_done_caught) = (0u64, 0u64, 0, 0);
    let mut last_reflected = 0u64;
    for step in 0..400 {
        if step % 3 == 0 && step < 300 {
            seq += 1;
            d.set_poses(&script[pose_of_seq(seq)], [seq]);
        }
        let report = d
            .step(Duration::from_millis(10))
            .unwrap_or_else(|e| panic!("{e}"));
        if report.completed {
            published += 1;
            assert_eq!(d.versions(), version + 1, "versions count up by one");
            version = d.versions();
            let reflected = d.reflected()[0];
            assert!(
                reflected >= last_reflected,
                "seq went back: {reflected} < {last_reflected}"
            );
            last_reflected = reflected;
            let b = radiosity(&d);
            assert!(
                b.iter().all(|v| v.min_element() >= 0.0),
                "negative texel published"
            );
            let error = accuracy(&atlas, &b, &expected[pose_of_seq(reflected)])
                .unwrap_or_else(|| panic!("lengths"))
                .nrmse;
            assert!(
                error <= publish_bound(method),
                "{method}: version {version} (seq {reflected}) is {error} off its pose"
            );
        } else if !d.is_idle() && step % 2 == 1 {
            let raw = d.raw_radiosity().unwrap_or_else(|e| panic!("{e}"));
            let claimed = &expected[pose_of_seq(d.reflected()[0])];
            let target = &expected[pose_of_seq(seq)];
            let off = |against: &[Vec3]| accuracy(&atlas, &raw, against).map_or(0.0, |a| a.nrmse);
            let (off_claimed, off_target) = (off(claimed), off(target));
            if off_claimed > publish_bound(method) && off_target > publish_bound(method) {
                half_done_caught += 1;
            }
        }
    }
    eprintln!("{method}: {published} publications, {half_done_caught} half-done states caught");
    assert!(published >= 5, "{method}: only {published} publications");
    assert_eq!(last_reflected, seq, "{method}: the last pose was published");
    assert!(
        half_done_caught > 0,
        "{method}: the NRMSE check never saw a half-done state, so it proves nothing"
    );
}

#[test]
fn incremental_publishes_only_complete_states() {
    only_complete_states_are_published(Redistribution::Incremental);
}

#[test]
fn cross_publishes_only_complete_states() {
    only_complete_states_are_published(Redistribution::Cross);
}

/// The inside of `furnace.json` (albedo 0.5, self-emission 1) with a box
/// of the same material floating in the middle: every point, the box's
/// included, has radiosity E/(1-ρ) = 2, whatever the box does. (A box
/// resting on the floor would not do: its bottom face sees nothing.)
const FURNACE_WITH_BOX: &str = r#"{
  "name": "furnace-with-box",
  "lightmap": { "texel_density": 7.5, "max_atlas_size": 256 },
  "materials": [{ "name": "grey-emitter", "albedo": [0.5, 0.5, 0.5], "emission": [1, 1, 1] }],
  "objects": [{ "name": "box", "pose": { "translation": [0.5, 0.5, 0.5] } }],
  "surfaces": [
    { "name": "room", "material": "grey-emitter",
      "box": { "center": [0.5, 0.5, 0.5], "size": [1, 1, 1], "facing": "in" } },
    { "name": "box", "material": "grey-emitter", "object": "box",
      "box": { "center": [0, 0, 0], "size": [0.3, 0.4, 0.3] } }
  ]
}"#;

/// Area-weighted mean radiosity (red) of the static and of the moving
/// elements.
fn means(scene: &Scene, atlas: &Atlas, b: &[Vec3]) -> (f64, f64) {
    let mut sums = [(0.0f64, 0.0f64); 2];
    for (e, v) in atlas.elements.iter().zip(b) {
        let s = &mut sums[usize::from(scene.objects[e.object as usize].dynamic)];
        s.0 += f64::from(e.area) * f64::from(v.x);
        s.1 += f64::from(e.area);
    }
    (sums[0].0 / sums[0].1, sums[1].0 / sums[1].1)
}

/// Cross redistribution takes the moving objects out before every round
/// of refinement and puts them back after (thesis §4.5.2). Taking them out
/// must undo putting them in: here the session refines in two rounds (to
/// 1% and to 0.1% unshot), so the box is inserted, removed and inserted
/// again, and the furnace must still be at E/(1-ρ). (A removal that took
/// back none of the box's shot light but gave back all the light it had
/// blocked once left this furnace 9% too bright.)
#[test]
fn cross_removal_undoes_insertion_in_a_furnace_with_a_box() {
    let (scene, atlas) = common::parse(FURNACE_WITH_BOX);
    // One patch per batch: in this furnace every patch holds about the
    // same power, so a shared batch shoots all twelve and halves the
    // unshot power; the static set's first round then ends so far below
    // its level that the box's insertion leaves nothing to refine, and
    // there is no second round to take the box out for.
    let one_patch = ProgressiveOptions {
        shared_batch_ratio: 0.0,
        ..ProgressiveOptions::default()
    };
    let mut d = session_with(&scene, &atlas, Redistribution::Cross, one_patch);
    let published = settle(&mut d);
    assert!(published >= 2, "two rounds of refinement: {published}");
    let (room, moving) = means(&scene, &atlas, &radiosity(&d));
    eprintln!("furnace with a box, cross: room {room:.4}, box {moving:.4} (exact 2)");
    assert!((room / 2.0 - 1.0).abs() < 0.01, "room {room}");
    assert!((moving / 2.0 - 1.0).abs() < 0.03, "box {moving}");
    // Converged as far as cross goes: the static scene is refined to the
    // last publication level (the box's one-bounce deposit is not counted).
    let last = DynamicOptions::default().publish_at[1];
    assert!(
        d.unshot_fraction() <= last,
        "a settled cross session reports {} unshot",
        d.unshot_fraction()
    );

    // And a remove-insert cycle with nothing refined in between leaves the
    // static lightmap where it was.
    let poses = scene.initial_poses();
    let dynamic: Vec<bool> = scene.objects.iter().map(|o| o.dynamic).collect();
    let mut s = static_solve(&scene, &atlas, &poses, 1e-3);
    let before = s.radiosity().unwrap_or_else(|e| panic!("{e}"));
    for absent in [vec![false; poses.len()], dynamic.clone()] {
        let mut mv = s
            .begin_move(&poses, &absent, Redistribution::Cross)
            .unwrap_or_else(|e| panic!("{e}"));
        while s.move_step(&mut mv).unwrap_or_else(|e| panic!("{e}")) {}
    }
    let after = s.radiosity().unwrap_or_else(|e| panic!("{e}"));
    // Every element of this furnace emits, and the metric leaves emitters
    // out (their B = E part is exact by construction and would flatter
    // it). What a move can change is the reflected light B - E, so compare
    // that, with every element counted as a receiver, over the static ones.
    let mut receivers = atlas.clone();
    for e in &mut receivers.elements {
        e.emission = Vec3::ZERO;
    }
    let reflected = |b: &[Vec3]| -> Vec<Vec3> {
        b.iter()
            .zip(&atlas.elements)
            .map(|(v, e)| *v - e.emission)
            .collect()
    };
    let is_static = |i: usize| !dynamic[atlas.elements[i].object as usize];
    let error = accuracy_where(
        &receivers,
        &reflected(&after),
        &reflected(&before),
        is_static,
    )
    .expect("a lit room");
    eprintln!("insert + remove: static reflected light {error}");
    assert!(
        error.nrmse < 0.01,
        "insert + remove changed the room by {error}"
    );
}

/// Cross redistribution gathers once per tile of a moving face (thesis
/// Alg. 4.5); the texels must read those values as samples at the tile
/// centres, not as a constant per tile, or every face shows its tiles as
/// bands. Along each row and column of each face of the moved box, the
/// step between the two texels on either side of a tile boundary is no
/// larger than the steps beside it (a piecewise-constant face has steps
/// only at the boundaries and none beside them).
#[test]
fn cross_light_on_a_moved_box_has_no_steps_at_tile_boundaries() {
    let (scene, atlas) = common::load("cornell-large.json", 0.35);
    let target = box_pose(&scene, 30.0, Vec3::new(0.4, 0.0, -0.3));
    let mut d = session(&scene, &atlas, Redistribution::Cross);
    settle(&mut d);
    d.set_poses(&target, [1]);
    settle(&mut d);
    let b = radiosity(&d);
    let side = ProgressiveOptions::default().cross_tile;
    let tiles = |n: u32| n.div_ceil(side).max(n.min(2));
    let object = scene.object_by_name("box").expect("a box");
    let lum = |v: Vec3| f64::from(v.x + v.y + v.z);
    let mut checked = 0;
    for (p, patch) in scene.patches.iter().enumerate() {
        if patch.object != object || patch.name.ends_with("-y") {
            continue; // the bottom rests in the dark
        }
        let chart = atlas.charts[p];
        let mut grid = vec![0.0; (chart.w * chart.h) as usize];
        for i in atlas.elements_of(p as u32) {
            let [x, y] = atlas.elements[i].texel;
            grid[((y - chart.y) * chart.w + (x - chart.x)) as usize] = lum(b[i]);
        }
        let mean = grid.iter().sum::<f64>() / grid.len() as f64;
        // Walk every row (along s) and every column (along t).
        let lines: Vec<Vec<f64>> = (0..chart.h)
            .map(|r| {
                (0..chart.w)
                    .map(|c| grid[(r * chart.w + c) as usize])
                    .collect()
            })
            .chain((0..chart.w).map(|c| {
                (0..chart.h)
                    .map(|r| grid[(r * chart.w + c) as usize])
                    .collect()
            }))
            .collect();
        for (k, line) in lines.iter().enumerate() {
            let n = line.len() as u32;
            let g = tiles(n);
            for t in 1..g {
                let x = (t * n / g) as usize; // first texel of tile t
                if x < 2 || x + 1 >= line.len() {
                    continue;
                }
                let step = (line[x] - line[x - 1]).abs();
                let beside = (line[x - 1] - line[x - 2])
                    .abs()
                    .max((line[x + 1] - line[x]).abs());
                assert!(
                    step <= 2.0 * beside + 0.01 * mean,
                    "{} line {k}: a step of {step:.4} at the tile boundary before texel {x}, \
                     {beside:.4} beside it (face mean {mean:.3})",
                    patch.name
                );
                checked += 1;
            }
        }
    }
    assert!(checked > 20, "only {checked} tile boundaries checked");
}

/// The floor a moved box uncovers gets its light back: texels that were
/// under the box (invalid, never lit) and are visible after the move hold,
/// after the redistribution settles, about what a from-scratch solve at the
/// new pose gives them (within 10% on average, none below half). Without
/// this they stay black: the dark wedges at the box's base in a view of
/// cornell-large.
///
/// Incremental redistribution reaches them by reshooting (measured 95.2%
/// of the light on average, the darkest texel 88.5%). Cross redistribution
/// did not (0.0%: the removal reaches only what the old position's
/// hemicubes saw); the texels near a cross move now gather when it
/// completes (`gpu/progressive/regather.rs`; measured 93.2%, darkest
/// 87.7%).
fn uncovered_texels_get_their_light(method: Redistribution) {
    let (scene, atlas) = common::load("cornell-large.json", 0.35);
    let start = scene.initial_poses();
    let target = box_pose(&scene, 30.0, Vec3::new(0.4, 0.0, -0.3));
    let before = Validity::compute(&scene, &atlas, &start);
    let after = Validity::compute(&scene, &atlas, &target);
    let uncovered: Vec<usize> = (0..atlas.elements.len())
        .filter(|&i| before.is_invalid(i) && !after.is_invalid(i))
        .collect();
    assert!(
        uncovered.len() > 4,
        "the move must uncover texels, or this tests nothing ({})",
        uncovered.len()
    );
    let mut d = session(&scene, &atlas, method);
    settle(&mut d);
    d.set_poses(&target, [1]);
    settle(&mut d);
    let b = radiosity(&d);
    let expected = from_scratch(&scene, &atlas, &target);
    let lum = |v: Vec3| f64::from(v.x + v.y + v.z);
    let (got, want): (f64, f64) = uncovered
        .iter()
        .map(|&i| (lum(b[i]), lum(expected[i])))
        .fold((0.0, 0.0), |(a, b), (x, y)| (a + x, b + y));
    let darkest = uncovered
        .iter()
        .map(|&i| lum(b[i]) / lum(expected[i]).max(1e-9))
        .fold(f64::INFINITY, f64::min);
    eprintln!(
        "{method}: {} uncovered texels hold {:.1}% of their from-scratch light, darkest {:.1}%",
        uncovered.len(),
        100.0 * got / want,
        100.0 * darkest
    );
    assert!(
        (got / want - 1.0).abs() < 0.1,
        "{method}: the uncovered texels hold {:.1}% of their from-scratch light",
        100.0 * got / want
    );
    assert!(
        darkest > 0.5,
        "{method}: an uncovered texel holds {:.1}% of its light",
        100.0 * darkest
    );
}

#[test]
fn incremental_lights_the_floor_a_moved_box_uncovers() {
    uncovered_texels_get_their_light(Redistribution::Incremental);
}

#[test]
fn cross_lights_the_floor_a_moved_box_uncovers() {
    uncovered_texels_get_their_light(Redistribution::Cross);
}

/// A scene with no dynamic object (cornell-blocks) is served like any
/// other: with every method the session converges to a published state
/// and goes idle. Cross redistribution removes and re-inserts the moving
/// objects around each refinement; with none, those are empty moves, which
/// used to reach passes that only a real move builds (a panic on every
/// `lightwire serve --scene scenes/cornell-blocks.json`).
#[test]
fn a_static_scene_converges_and_publishes_with_every_method() {
    let (scene, atlas) = common::load("cornell-blocks.json", 0.25);
    assert!(scene.objects.iter().all(|o| !o.dynamic), "a static scene");
    for method in [
        Redistribution::Cross,
        Redistribution::Incremental,
        Redistribution::Full,
    ] {
        let mut d = session(&scene, &atlas, method);
        let published = settle(&mut d);
        assert!(published >= 1, "{method}: nothing published");
        let b = radiosity(&d);
        assert!(
            b.iter().any(|v| v.max_element() > 0.0),
            "{method}: the published state is dark"
        );
        assert!(
            d.unshot_fraction() <= DynamicOptions::default().publish_at[1],
            "{method}: not converged ({})",
            d.unshot_fraction()
        );
    }
}

/// What cross projection blocks (thesis §3.3.2, §4.5.2: `R_x(C, C)`, the
/// light that passed where the moving object now stands) agrees with rays.
/// Cornell-large x0.35 with the box made black, so that inserting it only
/// casts shadows: the state after inserting it into the static scene
/// solved without it, minus that solution, is the shadow cross
/// redistribution deposited on each static patch (before refinement, which
/// a session runs next, carries the shadow a bounce further: the ceiling
/// and walls then lose the light the shadowed floor no longer reflects). The same first-order shadow by rays is
/// `ρ (H_with − H_without)` at every static element
/// ([`lightwire_solve::direct::gather`], 256 cosine rays and 64 samples
/// per emitting patch, the static solution on both sides, the box nowhere
/// in the second). Summed per patch, the total must agree within 10% and
/// every patch holding at least a tenth of the shadow within 25%.
/// (Measured on 2026-12-02 after rays that leave the scene through the open
/// front stopped blocking light: total +7.8%, floor +15.9%, ceiling
/// -18.7%, back wall -6.3%; before: total +32%, back wall +135%, a dark
/// wedge on the back wall behind the box. On 2026-12-03, measured on the
/// insertion alone and with the invalid texels near a move zeroed: total
/// -3.0%, floor +1.7%, ceiling -9.7%, back wall -12.5%.)
///
/// The box is closed, so its tiles cast shadows through their front
/// hemicubes only; the same box without its bottom face (hidden on the
/// floor) is open, and its tiles use back hemicubes too: both must agree
/// with rays. So must the closed box's shadow when every receiver samples
/// the coarse grid (`cross_coarse_below` 1; measured on 2026-12-04: total
/// -6.5%, floor -2.3%, ceiling -6.4%, back wall -21.0%, against -4.2%,
/// +1.5%, -5.8%, -21.2% with the default).
#[test]
fn cross_projection_blocks_what_rays_say() {
    let (scene, _) = common::load("cornell-large.json", 0.35);
    let b = scene.object_by_name("box").expect("the scene has a box");
    assert!(scene.closed_objects()[b as usize], "the box is closed");
    let mut open = scene.clone();
    open.patches.retain(|p| p.name != "box/-y");
    assert!(
        !open.closed_objects()[b as usize],
        "the box without its bottom is open"
    );
    let coarse = ProgressiveOptions {
        cross_coarse_below: 1.0,
        ..ProgressiveOptions::default()
    };
    for (what, scene, options) in [
        ("closed box", scene.clone(), ProgressiveOptions::default()),
        ("open box", open, ProgressiveOptions::default()),
        ("closed box, coarse projection everywhere", scene, coarse),
    ] {
        eprintln!("{what}:");
        let atlas = Atlas::build(&scene).unwrap_or_else(|e| panic!("{e}"));
        cross_projection_against_rays(&scene, atlas, b, options);
    }
}

fn cross_projection_against_rays(
    scene: &Scene,
    mut atlas: Atlas,
    b: u32,
    options: ProgressiveOptions,
) {
    for e in atlas.elements.iter_mut().filter(|e| e.object == b) {
        e.albedo = Vec3::ZERO;
    }
    let poses = scene.initial_poses();
    let mut solver = static_solve_with(scene, &atlas, &poses, 1e-4, options);
    let without = solver.total_radiosity().unwrap_or_else(|e| panic!("{e}"));
    let present = vec![false; poses.len()];
    let mut insertion = solver
        .begin_move(&poses, &present, Redistribution::Cross)
        .unwrap_or_else(|e| panic!("{e}"));
    while solver
        .move_step(&mut insertion)
        .unwrap_or_else(|e| panic!("{e}"))
    {}
    let with_box = solver.total_radiosity().unwrap_or_else(|e| panic!("{e}"));

    let validity = Validity::compute(scene, &atlas, &poses);
    let receivers: Vec<usize> = (0..atlas.elements.len())
        .filter(|&i| {
            let e = &atlas.elements[i];
            e.object != b && e.emission.max_element() <= 0.0 && validity.keep()(i)
        })
        .collect();
    let values: Vec<[f32; 4]> = without.iter().map(|v| [v.x, v.y, v.z, 0.0]).collect();
    let mut elsewhere = poses.clone();
    elsewhere[b as usize].translation += Vec3::new(0.0, 1.0e3, 0.0);
    let lit = |poses: &[Pose]| {
        lightwire_solve::direct::gather(
            scene,
            &atlas,
            (poses, &[]),
            &values,
            &receivers,
            16,
            8,
            lightwire_solve::direct::Lookup::Nearest,
        )
    };
    let (rays_with, rays_without) = (lit(&poses), lit(&elsewhere));

    let mut patches: std::collections::BTreeMap<u32, (f64, f64)> = Default::default();
    for (k, &i) in receivers.iter().enumerate() {
        let e = &atlas.elements[i];
        let a = f64::from(e.area);
        let sum = patches.entry(e.patch).or_default();
        sum.0 += a * f64::from((with_box[i] - without[i]).element_sum());
        sum.1 += a * f64::from((rays_with[k] - rays_without[k]).element_sum());
    }
    let (cross, rays) = patches
        .values()
        .fold((0.0, 0.0), |(c, r), (pc, pr)| (c + pc, r + pr));
    for (p, (c, r)) in &patches {
        eprintln!(
            "{:<8} shadow by cross projection {c:8.3} W, by rays {r:8.3} W ({:+.1}%)",
            scene.patches[*p as usize].name,
            100.0 * (c / r - 1.0)
        );
    }
    eprintln!("total    {cross:8.3} W vs {rays:8.3} W");
    assert!(rays < 0.0, "the box casts a shadow ({rays})");
    assert!(
        (cross / rays - 1.0).abs() <= 0.10,
        "cross projection blocks {cross} W in all, rays {rays} W"
    );
    for (p, (c, r)) in &patches {
        if r.abs() >= 0.1 * rays.abs() {
            assert!(
                (c / r - 1.0).abs() <= 0.25,
                "{}: cross projection blocks {c} W, rays {r} W",
                scene.patches[*p as usize].name
            );
        }
    }
}
