//! The solvers' direct light by next-event estimation
//! (`lightwire_solve::direct`) against closed forms: a floor point under
//! a square light, in the open and half shadowed by a black plate.

mod common;

use glam::DVec3;
use lightwire_solve::direct::{Emitters, GRID, form_factor};
use lightwire_solve::raycast::Raycaster;

/// The lamp's rectangle between `x0` and `x1` (its full width is -0.5..0.5).
fn lamp(x0: f64, x1: f64) -> [DVec3; 4] {
    [
        DVec3::new(x0, 1.5, -0.5),
        DVec3::new(x1, 1.5, -0.5),
        DVec3::new(x1, 1.5, 0.5),
        DVec3::new(x0, 1.5, 0.5),
    ]
}

/// In the open, the irradiance is E times the exact form factor wherever
/// the point is (the grid only weights visibility, and all of it is
/// visible): at the axis, under the light's edge, and far to the side.
#[test]
fn unshadowed_irradiance_is_e_times_the_exact_form_factor() {
    let (scene, atlas) = common::parse(&common::lamp_scene("lamp", common::SQUARE_LAMP, false));
    common::assert_floor_irradiance(&scene, &atlas, [(0.0, 0.0), (0.5, 0.3), (2.5, -1.0)], |x| {
        3.0 * form_factor(x, DVec3::Y, &lamp(-0.5, 0.5))
    });
}

/// Under the plate's edge the point sees exactly the half of the light
/// over x > 0 (symmetric samples: exact); 0.2 m further out it sees the
/// light from x = -0.2 on, which the 16 x 16 grid resolves to within 2%.
/// Sampling only the kernel (no exact form factor) would be off by the
/// grid's quadrature error everywhere; a missing shadow ray would double
/// the first value.
#[test]
fn half_shadowed_irradiance_follows_the_visible_part_of_the_light() {
    let (scene, atlas) = common::parse(&common::lamp_scene("lamp", common::SQUARE_LAMP, true));
    let caster = Raycaster::new(&scene, &scene.initial_poses());
    let emitters = Emitters::of(&scene);
    let at = |x: DVec3| {
        let h = emitters.irradiance(&caster, &atlas, x, DVec3::Y, GRID, |j| {
            atlas.elements[j].emission
        });
        f64::from(h.x)
    };
    let x = DVec3::new(0.0, 1e-6, 0.0);
    let half = 3.0 * form_factor(x, DVec3::Y, &lamp(0.0, 0.5));
    let got = at(x);
    assert!((got - half).abs() <= 1e-4 * half, "{got} vs {half}");

    let x = DVec3::new(0.2, 1e-6, 0.0);
    let visible = 3.0 * form_factor(x, DVec3::Y, &lamp(-0.2, 0.5));
    let got = at(x);
    assert!(
        (got - visible).abs() <= 0.02 * visible,
        "{got} vs {visible}"
    );
}
